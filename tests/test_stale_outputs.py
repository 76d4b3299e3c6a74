"""Nothing outlives its run: no stale certificate beside new artefacts, no temporaries of killed writers.

Issue 20, item 4.  An interrupted ``calibrate --overwrite`` left the previous run's
``certificate.nc`` (still verifying) beside the new run's cube, RWF and records; and SIGKILLs
of ``lidarcal certificate`` left nested ``..cert.nc.*.part.*.part`` temporaries that no later
writer removed.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time

import pytest
from analysis_factories import make_records

import lidarcal.pipeline
from lidarcal.analysis import budget, sensitivity
from lidarcal.certificate import make_certificate
from lidarcal.certificate.seal import write_certificate
from lidarcal.io import open_artefact, part_path, remove_stale_parts, write_artefact
from lidarcal.pipeline import CalibrationConfig, calibrate
from lidarcal.provenance import sha256

KILLS = 4


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("stale-inputs")
    make_records(n=300).to_netcdf(d / "records.nc")
    records = open_artefact(d / "records.nc")
    return {"budget": write_artefact(budget(records), d / "budget.nc"),
            "sens": write_artefact(sensitivity(records, "wind_shear_exponent"), d / "sens.nc")}


class _Interrupted(BaseException):
    """What a Ctrl-C or a kill does to the run: it stops where it is."""


def test_interrupted_calibrate_overwrite_leaves_no_previous_certificate(inputs, tmp_path, monkeypatch,
                                                                        caplog):
    out = tmp_path / "run"
    out.mkdir()
    # a previous run's sealed certificate and its report
    old = make_certificate(budget=open_artefact(inputs["budget"]),
                           sensitivities=[open_artefact(inputs["sens"])], demonstration=True)
    write_certificate(old, out / "certificate.nc")
    (out / "report.html").write_text("<html>previous run</html>")
    (out / "cube.nc").write_bytes(b"previous cube")
    old_sha = sha256(out / "certificate.nc")

    def interrupted(*args, **kwargs):
        raise _Interrupted  # stopped during the simulation: cube, RWF, conditions already new

    monkeypatch.setattr(lidarcal.pipeline, "simulate_campaign", interrupted)
    cfg = CalibrationConfig(periods=8, heights=(60.0, 120.0), workers=1)
    with caplog.at_level(logging.WARNING, logger="lidarcal.pipeline"), pytest.raises(_Interrupted):
        calibrate(out, cfg, overwrite=True)
    assert (out / "cube.nc").read_bytes() != b"previous cube"  # this run's artefacts were published
    assert open_artefact(out / "cube.nc", "bench_cube").sizes
    assert not (out / "certificate.nc").exists()  # ... and no certificate they were not built from
    assert not (out / "report.html").exists()
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "removed the previous run's certificate" in said and old_sha in said


@pytest.mark.slow
def test_calibrate_writes_the_certificate_last(inputs, tmp_path, monkeypatch):
    """The report comes before the certificate: a certificate present always has its run complete."""
    order = []
    real_cert, real_report = lidarcal.pipeline.write_certificate, lidarcal.pipeline.write_report
    monkeypatch.setattr(lidarcal.pipeline, "write_certificate",
                        lambda *a, **k: (order.append("certificate"), real_cert(*a, **k))[1])
    monkeypatch.setattr(lidarcal.pipeline, "write_report",
                        lambda *a, **k: (order.append("report"), real_report(*a, **k))[1])
    cfg = CalibrationConfig(periods=24, heights=(60.0, 120.0), workers=1, chunk=24, min_periods=3,
                            scheduler="synchronous", max_replicas=1)
    calibrate(tmp_path / "run", cfg)
    assert order == ["report", "certificate"]


def test_nested_temporaries_of_dead_writers_are_removed(tmp_path):
    """The ``..cert.nc.*.part.*.part`` files older versions left are recognised as cert.nc's."""
    path = tmp_path / "cert.nc"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    outer = part_path(path)
    inner = part_path(outer)
    stale_outer = outer.with_name(outer.name.replace(f"-{os.getpid()}.", f"-{dead.pid}."))
    stale_inner = inner.with_name(inner.name.replace(f"-{os.getpid()}.", f"-{dead.pid}."))
    outer.rename(stale_outer)
    inner.rename(stale_inner)
    live = part_path(part_path(path))  # this process is alive: its (nested) temporary stays
    assert stale_inner.name.startswith("..cert.nc.") and stale_inner.name.endswith(".part")
    removed = remove_stale_parts(path)
    assert sorted(removed) == sorted([stale_outer, stale_inner])
    assert live.exists()


def _part_files(d):
    return sorted(p.name for p in d.iterdir() if ".part" in p.name)


@pytest.mark.slow  # a few Python start-ups (~12 s on the loaded 2-core machine)
def test_sigkilled_certificate_writers_leave_no_temporaries(inputs, tmp_path):
    """Real SIGKILLs of ``lidarcal certificate`` while it writes; the next writer cleans up."""
    out = tmp_path / "cert.nc"
    cmd = [sys.executable, "-m", "lidarcal", "certificate", "--budget", str(inputs["budget"]),
           "--sensitivity", str(inputs["sens"]), "-o", str(out), "--overwrite", "--demonstration"]
    killed = 0
    for _ in range(KILLS):  # bounded: each run is killed as soon as it has a temporary, or ends
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if _part_files(tmp_path):
                time.sleep(0.02)  # let it get into the HDF5 writing and the seal
                break
            time.sleep(0.002)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            killed += 1
        proc.wait(timeout=60)
        assert not any(name.startswith("..") for name in _part_files(tmp_path)), _part_files(tmp_path)
    assert killed, "no run could be killed while writing"
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert _part_files(tmp_path) == []  # every killed writer's temporary was removed
