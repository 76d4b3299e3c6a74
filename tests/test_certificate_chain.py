"""Every input's provenance chain must agree with the files given, with or without ``--records``.

Issue 20, item 1: ``lidarcal certificate --budget budget.nc --cube cube2.nc ...`` exited 0 and
``verify`` said OK although the budget's own provenance names ``cube1.nc`` (the records it was
computed from were simulated with cube1); likewise an RWF of another pulse width.  The
refusal must exit 2, name both files and both SHA-256 checksums, and write nothing.
"""

from __future__ import annotations

import pytest
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.bench import build_cube, simulate_run
from lidarcal.cli import main
from lidarcal.io import open_artefact, write_artefact
from lidarcal.provenance import sha256, stamp
from lidarcal.rwf import range_weighting_function
from lidarcal.units import Q_

SERIAL = "WLS7-TEST"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("chain")
    out = {}
    for name, seed in (("cube1", 3), ("cube2", 4)):  # two bench runs of the same lidar
        run = simulate_run(seed=seed, accumulation_time="20 s", lidar_serial=SERIAL)
        cube, _ = build_cube(run.rtd, run.control)
        cube = stamp(cube, "bench_cube", title="cube", summary="test cube", call="test")
        out[name] = write_artefact(cube, d / f"{name}.nc")
    for name, length in (("rwf1", 25.0), ("rwf2", 35.0)):  # pulses of another width
        out[name] = write_artefact(range_weighting_function(pulse_length=Q_(length, "m")), d / f"{name}.nc")
    # records simulated with cube1 and rwf1: recorded as simulate_campaign(inputs=...) records them
    records = stamp(make_records(n=300, lidar_serial=SERIAL), "simulated_rtd", title="records",
                    summary="test records", call="lidarcal simulate --cube cube1.nc --rwf rwf1.nc",
                    inputs={"cube": out["cube1"], "rwf": out["rwf1"]})
    records.to_netcdf(d / "records.nc")
    out["records"] = d / "records.nc"
    rec = open_artefact(out["records"])
    out["budget"] = write_artefact(budget(rec), d / "budget.nc")
    out["sens"] = write_artefact(sensitivity(rec, "wind_shear_exponent"), d / "sens.nc")
    return out


def _certificate(files, tmp_path, capsys, *extra):
    out = tmp_path / "cert.nc"
    capsys.readouterr()
    code = main(["certificate", "--budget", str(files["budget"]), "--sensitivity", str(files["sens"]),
                 *map(str, extra), "-o", str(out), "--demonstration"])
    err = capsys.readouterr().err
    if code != 0:
        assert not out.exists() and "Traceback" not in err
    return code, err


@pytest.mark.parametrize("with_records", [False, True])
def test_inputs_the_budget_was_computed_from_are_accepted(files, tmp_path, capsys, with_records):
    extra = ["--records", files["records"]] if with_records else []
    code, err = _certificate(files, tmp_path, capsys, "--cube", files["cube1"], "--rwf", files["rwf1"],
                             *extra)
    assert code == 0, err
    assert main(["verify", str(tmp_path / "cert.nc")]) == 0


@pytest.mark.parametrize("with_records", [False, True])
@pytest.mark.parametrize(("role", "used", "given"), [("cube", "cube1", "cube2"), ("rwf", "rwf1", "rwf2")])
def test_another_cube_or_rwf_is_refused(files, tmp_path, capsys, with_records, role, used, given):
    chosen = {"cube": files["cube1"], "rwf": files["rwf1"], role: files[given]}
    extra = ["--records", files["records"]] if with_records else []
    code, err = _certificate(files, tmp_path, capsys, "--cube", chosen["cube"], "--rwf", chosen["rwf"],
                             *extra)
    assert code == 2, err
    assert "inputs disagree" in err
    # both files and both checksums, in full
    assert f"{role} '{used}.nc' (sha256 {sha256(files[used])})" in err, err
    assert f"the {role} given is '{given}.nc' (sha256 {sha256(files[given])})" in err, err
    if not with_records:  # found through the budget's (or sensitivity's) own chain
        assert f"records 'records.nc' (sha256 {sha256(files['records'])}), which was computed from" in err
