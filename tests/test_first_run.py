"""A first run that says what it is doing (issue 27, section 5).

Progress without a terminal (a line at a steady interval: periods done, chunks, time left), what
Ctrl-C keeps and the command that resumes, the resumed run saying what it reused, the dask
dashboard named once, and ``calibrate`` checking every input before it writes anything.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import shlex
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.progress import Progress, duration_text
from lidarcal.campaign.settings import Execution
from lidarcal.cli import build_parser, interrupted, main
from lidarcal.cli.options import progress_of
from lidarcal.conditions import synthetic_conditions
from lidarcal.io import open_artefact
from lidarcal.lidar import LidarModel

LIDARCAL = [sys.executable, "-c", "import sys; from lidarcal.cli import main; sys.exit(main())"]
#: A progress line: "<label>: <n> of <N> periods (<p> %), <c> of <C> chunks; <t> so far, ..."
LINE = re.compile(r"(?P<label>[^:]+): (?P<done>\d+) of (?P<total>\d+) periods \((?P<pct>\d+) %\), "
                  r"(?P<chunks>\d+) of (?P<of>\d+) chunks; (?P<so_far>.+?) so far, (?P<rest>.+)$")


class _Lines(logging.Handler):
    def __init__(self):
        super().__init__(logging.INFO)
        self.lines: list[str] = []

    def emit(self, record):
        self.lines.append(record.getMessage())


@pytest.fixture
def progress_log():
    handler = _Lines()
    logger = logging.getLogger("lidarcal.campaign")
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    yield handler.lines
    logger.removeHandler(handler)
    logger.setLevel(level)


def test_duration_text():
    assert [duration_text(s) for s in (0.4, 45, 125, 3599, 3780)] == ["0 s", "45 s", "2 min 05 s",
                                                                       "59 min 59 s", "1 h 03 min"]


def test_without_a_terminal_the_default_is_a_line_at_a_steady_interval(monkeypatch, progress_log):
    """Under tee, nohup or CI (stderr not a terminal) the default is lines, not a silent bar."""
    class Stderr:
        def __init__(self, tty):
            self.tty = tty

        def isatty(self):
            return self.tty

    args = build_parser(["simulate"]).parse_args(["simulate", "-o", "x.nc", "--progress-interval", "0.05"])
    monkeypatch.setattr("sys.stderr", Stderr(False))
    assert progress_of(args) == Progress("lines", 0.05)
    monkeypatch.setattr("sys.stderr", Stderr(True))
    assert progress_of(args).mode == "bar"
    assert progress_of(argparse.Namespace(progress=False)).mode == "off"
    monkeypatch.undo()
    # 4 chunks of 10 periods: one done, then a pause of several intervals, then the rest
    with Progress("lines", 0.05, "replicas 4-7 (of at most 30)").tracker(40, 4) as tracker:
        time.sleep(0.3)  # no chunk done yet: the lines still come, without an estimate
        tracker.done(10)
        time.sleep(1.2)  # one chunk (10 periods) in <= ~1.2 s: 30 periods left take about 3.6 s more
        tracker.done(10)
        tracker.done(10)
        tracker.done(10)
    parsed = [LINE.match(line) for line in progress_log]
    assert all(parsed), progress_log
    assert {m["label"] for m in parsed} == {"replicas 4-7 (of at most 30)"}
    # steady: ~1.5 s / 0.05 s = 30 lines; thread scheduling on a loaded machine may lose a few
    assert len(parsed) >= 10, progress_log
    assert parsed[0]["done"] == "0" and parsed[0]["rest"] == "no chunk finished yet to estimate the time left"
    quarter = [m for m in parsed if m["done"] == "10"]
    assert quarter and all(m["total"] == "40" and m["pct"] == "25" and m["chunks"] == "1" and m["of"] == "4"
                           for m in quarter)
    # the estimate: 30 periods at the rate of the first 10 (taken over >= 1.2 s: it is not known
    # from the first chunk alone) is 3 x the time since the start, i.e. a few seconds
    left = [re.fullmatch(r"about (\d+) s left", m["rest"]) for m in quarter]
    assert all(left) and all(1 <= int(x[1]) <= 15 for x in left), [m["rest"] for m in quarter]
    assert parsed[-1]["done"] == "40" and parsed[-1]["rest"] == "done"  # the last line says it ended


def test_short_sets_of_tasks_still_get_a_line_at_the_interval(progress_log):
    """The model-form alternatives and small replica batches each run shorter than the interval.

    The interval runs across them (one Progress for the command): three sets of 0.15 s with an
    interval of 0.2 s give a line during the second or third.  Each set's own clock never
    reached 0.2 s, so none was printed: a default run was silent through its model-form runs.
    """
    progress = Progress("lines", 0.2)
    for i in (1, 2, 3):
        with progress.labelled(f"model form alt{i} ({i} of 3)").tracker(10, 1) as tracker:
            time.sleep(0.15)
            tracker.done(10)
    parsed = [LINE.match(line) for line in progress_log]
    assert parsed and all(parsed), progress_log
    assert {m["label"] for m in parsed} <= {"model form alt2 (2 of 3)", "model form alt3 (3 of 3)"}


def test_ctrl_c_says_what_it_kept_and_the_resumed_run_what_it_reused(tmp_path):
    """A real SIGINT (Ctrl-C: to the whole process group) during ``lidarcal simulate --workdir``."""
    cond = synthetic_conditions(96, (40.0, 80.0), seed=7)
    cpath, work, out, err = tmp_path / "c.nc", tmp_path / "work", tmp_path / "sim.nc", tmp_path / "stderr.txt"
    cond.to_netcdf(cpath)
    argv = ["simulate", "--conditions", str(cpath), "--scheduler", "synchronous", "--chunk", "4",
            "--workdir", str(work), "--progress-interval", "0.2", "-o", str(out)]
    with open(err, "w") as stderr:  # a file: not a terminal, so progress comes as lines
        proc = subprocess.Popen([*LIDARCAL, *argv], start_new_session=True, stdout=subprocess.DEVNULL,
                                stderr=stderr)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if len(list(work.glob("chunk-*.npz"))) >= 4 and " periods (" in err.read_text():
                break
            time.sleep(0.01)
        assert proc.poll() is None, "the run finished before it could be interrupted"
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=60) == 130
    said = err.read_text().splitlines()
    assert "Traceback" not in err.read_text()
    kept = len(list(work.glob("chunk-*.npz")))
    assert 4 <= kept < 24 and not out.exists()
    # progress lines came while it ran: periods of the 96 done, chunks of the 24
    lines = [m for line in said if (m := LINE.match(line.removeprefix("lidarcal simulate: ")))]
    assert lines and all(m["total"] == "96" and m["of"] == "24" for m in lines), said
    assert said[-2] == f"lidarcal simulate: interrupted; {kept} finished simulation chunk(s) kept in {work}"
    resume = said[-1].removeprefix("lidarcal simulate: resume with: ")
    assert shlex.split(resume) == ["lidarcal", *argv]  # the exact command (its output not written yet)
    # the resumed run says what it reused, and ends as the uninterrupted run would, bit for bit
    again = subprocess.run([*LIDARCAL, *shlex.split(resume)[1:]], capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"lidarcal simulate: simulation: reusing {kept} of 24 chunks finished earlier (kept in {work})" \
        in again.stderr.splitlines()
    resumed = open_artefact(out)
    whole = simulate_campaign(cond, LidarModel.from_attrs(cond),
                              execution=Execution(scheduler="synchronous", chunk=24))
    for name in ("lidar_wind_speed", "reference_wind_speed", "availability"):
        np.testing.assert_array_equal(resumed[name].values, whole[name].values)


def test_interrupted_calibrate_names_its_chunks_and_the_command_with_overwrite(tmp_path):
    argv = ["calibrate", "-o", str(tmp_path / "run 1"), "--periods", "144"]
    args = build_parser(["calibrate"]).parse_args(argv)
    args.argv = argv
    chunks = tmp_path / "run 1" / ".simulation-chunks"
    (chunks / "replica-0001").mkdir(parents=True)
    for name in ("chunk-0000000-0000064-0123456789abcdef.npz", "chunk-0000064-0000128-0123456789abcdef.npz",
                 "replica-0001/chunk-0000000-0000064-fedcba9876543210.npz"):
        (chunks / name).write_bytes(b"")
    (chunks / ".chunk-0000128-0000144-0.npz.host-1.x.part").write_bytes(b"")  # a temporary: not kept
    assert interrupted(args) == [
        f"interrupted; 3 finished simulation chunk(s) kept in {chunks}",
        f"resume with: lidarcal calibrate -o '{tmp_path / 'run 1'}' --periods 144 --overwrite",
    ]
    # a command that keeps nothing says so; a simulation without --workdir names the option
    assert interrupted(argparse.Namespace(command="validate", argv=["validate", "x.nc"])) == ["interrupted"]
    args = build_parser(["simulate"]).parse_args(["simulate", "-o", "s.nc"])
    args.argv = ["simulate", "-o", "s.nc"]
    assert interrupted(args) == [
        "interrupted; no finished chunk was kept (only --workdir DIR keeps them for a resume)",
        "run it again with: lidarcal simulate -o s.nc --workdir DIR",
    ]


def test_the_dask_dashboard_is_named_once_per_command(progress_log):
    """``calibrate --scheduler ADDRESS`` runs replica 0 and every batch of replicas on the cluster."""
    from lidarcal.campaign.scheduler import _log_dashboard

    class Client:  # what _log_dashboard asks of a distributed.Client
        dashboard_link = "http://127.0.0.1:8787/status"

        def scheduler_info(self, n_workers=0):
            return {"services": {"dashboard": 8787}}

    progress = Progress("off")
    for batch in ("replica 0", "replicas 1-3", "replicas 4-7"):
        _log_dashboard(Client(), progress.labelled(batch))
    assert progress_log == ["dask dashboard: http://127.0.0.1:8787/status"]


def test_calibrate_help_states_the_default_sample(capsys):
    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "two weeks of a real met-mast record" in text and "three months" not in text.split("--periods")[0]


def test_calibrate_checks_every_input_before_writing_anything(tmp_path, capsys):
    """``--conditions budget.nc`` wrote cube.nc and rwf.nc before refusing the conditions."""
    from analysis_factories import make_records

    from lidarcal.analysis import budget
    from lidarcal.io import write_artefact

    make_records(n=200).to_netcdf(tmp_path / "records.nc")
    bud = write_artefact(budget(open_artefact(tmp_path / "records.nc")), tmp_path / "budget.nc")
    out = tmp_path / "run"
    assert main(["calibrate", "-o", str(out), "--conditions", str(bud), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "budget.nc" in err and "wind_speed" in err, err
    assert not out.exists()  # nothing written, not even the directory
    # a bad RWF after a good cube: the cube is not written either
    (tmp_path / "rwf.nc").write_text("not netCDF")
    assert main(["calibrate", "-o", str(out), "--rwf", str(tmp_path / "rwf.nc"), "--no-progress"]) == 2
    assert "rwf.nc" in capsys.readouterr().err
    assert not out.exists()


# ---- lidarcal validate: one spelling of acknowledgement, the block the files share said once ----


def test_acknowledgement_is_settable_in_the_acdd_1_3_spelling(tmp_path, capsys):
    """validate called acknowledgment 'not settable by an option' while --attribute listed it."""
    import netCDF4

    from lidarcal.compliance import check_compliance, supplied_by
    from lidarcal.data import sample_file

    # compliance-checker asks for either spelling; lidarcal names the option, in ACDD-1.3's
    assert supplied_by("acknowledgment/acknowledgement") == "--attribute acknowledgement=VALUE"
    written = {}
    for spelling in ("acknowledgement", "acknowledgment"):  # ACDD-1.3, and ACDD-1.1's accepted too
        out = tmp_path / f"rwf-{spelling}.nc"
        assert main(["rwf", "-o", str(out), "--attribute", f"{spelling}=Funded by a test grant"]) == 0
        with netCDF4.Dataset(out) as nc:
            written[spelling] = {k: nc.getncattr(k) for k in nc.ncattrs() if k.startswith("acknowledg")}
        report = check_compliance(out)
        assert not any("acknowledg" in w for w in report.warnings), report.warnings
    assert written == {s: {"acknowledgement": "Funded by a test grant"} for s in written}
    # an input carrying the ACDD-1.1 spelling (the sample conditions) passes it on in the 1.3 one
    argv = ["conditions", "synthetic", "--periods", "6", "--from-sample", "-o", str(tmp_path / "c.nc")]
    assert main(argv) == 0
    with netCDF4.Dataset(sample_file("conditions/conditions.nc")) as nc:
        assert "acknowledgment" in nc.ncattrs()
    with netCDF4.Dataset(tmp_path / "c.nc") as nc:
        names = {k: nc.getncattr(k) for k in nc.ncattrs() if k.startswith("acknowledg")}
    assert names == {"acknowledgement": "brightwind developers for publishing the demo met-mast record"}
    capsys.readouterr()


def test_validate_says_the_attributes_every_file_lacks_once(tmp_path, capsys):
    files = []
    for i in range(3):
        out = tmp_path / f"rwf{i}.nc"
        extra = ["--attribute", "program=Test programme"] if i == 2 else []
        assert main(["rwf", "-o", str(out), *extra]) == 0
        files.append(str(out))
    capsys.readouterr()
    assert main(["validate", *files]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line for line in out if line.endswith(": ok")] == [f"{f}: ok" for f in files]
    blocks = [i for i, line in enumerate(out) if "ACDD attribute(s) not present" in line]
    # once for the three files, after them; then what two of them lack besides (program)
    assert len(blocks) == 2 and blocks[0] > max(out.index(f"{f}: ok") for f in files)
    common = out[blocks[0]]
    assert re.fullmatch(r"warning: (\d+) ACDD attribute\(s\) not present in any of these 3 files; "
                        r"give them with:", common)
    assert int(common.split()[1]) >= 20  # contact, site, programme ...: a run without user details
    assert "acknowledgement" in " ".join(out[blocks[0]:blocks[1]])  # settable: under --attribute
    assert not any("not settable" in line for line in out)
    assert out[blocks[1]] == (f"warning: 1 ACDD attribute(s) not present (besides those) in {files[0]}, "
                              f"{files[1]}; give them with:")
    assert out[blocks[1] + 1] == "  --attribute NAME=VALUE: program"
    # one file: its block in its own section, as before
    assert main(["validate", files[0]]) == 0
    one = capsys.readouterr().out.splitlines()
    assert one[0] == f"{files[0]}: ok" and any("ACDD attribute(s) not present;" in line for line in one)
