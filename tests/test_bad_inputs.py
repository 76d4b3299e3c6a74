"""Every bad input a hostile user tried, in one table: exit 2, one message naming the culprit.

Each row is a command line (with ``{d}`` the directory of prepared inputs, ``{o}`` a fresh empty
directory for outputs, ``{ro}`` a directory nothing can be written to, even as root) and a fragment
the error message must contain.  For every row: exit status 2, the fragment in stderr, no
traceback, and no file left behind (no output, no hidden ``.part``), in the output directory or
among the inputs.  The CLI runs in-process (:func:`lidarcal.cli.main`).
"""

from __future__ import annotations

import os
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from analysis_factories import var_attrs

from lidarcal.bench.simulator import simulate_run
from lidarcal.cf import height_coord, time_coord
from lidarcal.cli import main
from lidarcal.units import ureg

#: A directory no process can create files in, root included (procfs refuses new files).
RO = "/proc"


def conditions(n: int = 80, heights=(40.0, 80.0), seed: int = 0) -> xr.Dataset:
    """A valid conditions input: n 10-minute periods at ``heights`` with plausible values."""
    rng = np.random.default_rng(seed)
    shape = (n, len(heights))
    dims = ("time", "height")
    return xr.Dataset(
        {
            "wind_speed": (dims, rng.uniform(4, 12, shape), var_attrs("ws", "m s-1", "wind_speed")),
            "wind_from_direction": (dims, rng.uniform(0, 360, shape), var_attrs("wd", "degree")),
            "turbulence_intensity": (dims, rng.uniform(0.05, 0.2, shape), var_attrs("TI", "1")),
            "wind_shear_exponent": (dims, rng.uniform(0, 0.3, shape), var_attrs("shear", "1")),
            "cnr": (dims, rng.uniform(-25, -10, shape), var_attrs("CNR", "dB")),
            "cnr_gradient": (dims, rng.uniform(-0.05, 0.05, shape), var_attrs("g", "dB m-1")),
        },
        coords={"time": time_coord(np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")),
                "height": height_coord(heights)},
    )


def field(**attrs) -> xr.Dataset:
    """A field campaign (conditions + the measured pair) with extra global attributes."""
    ds = conditions()
    ds["lidar_wind_speed"] = ds.wind_speed * 1.01
    ds["reference_wind_speed"] = ds.wind_speed.copy()
    for name in ("lidar_wind_speed", "reference_wind_speed"):
        ds[name].attrs = var_attrs(name, "m s-1", "wind_speed")
    ds.attrs.update(attrs)
    return ds


def _edit_csv_row(text: str, row: int, column: str, value: str) -> str:
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    header = lines[start].split(",")
    cells = lines[start + 1 + row].split(",")
    cells[header.index(column)] = value
    lines[start + 1 + row] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """Every input file the table refers to, built once."""
    d = tmp_path_factory.mktemp("bad_inputs")
    # bench: a small sweep with 60-s bins, and the control log of the same sweep with 30-s bins
    # (the mismatch); CNR -16/-10 dB, where the lidar resolves the 1 m/s grid
    small = {"cnr": [-16.0, -10.0], "velocity": ureg.Quantity(np.arange(-3.0, 4.0), "m s-1")}
    simulate_run(seed=4, accumulation_time="60 s", **small).write(d)
    (d / "m30").mkdir()
    simulate_run(seed=4, accumulation_time="30 s", **small).write(d / "m30")
    rtd = (d / "rtd.csv").read_text()
    (d / "rtd_1e30.csv").write_text(_edit_csv_row(rtd, 40, "radial_wind_speed_m_s", "1e30"))
    (d / "rtd_nan.csv").write_text(_edit_csv_row(rtd, 7, "radial_wind_speed_m_s", "nan"))
    (d / "rtd_los.csv").write_text(_edit_csv_row(rtd, 3, "los", "45"))
    (d / "empty.csv").write_text("")
    # conditions and field campaigns
    conditions().to_netcdf(d / "c.nc")
    for name, edit in {
        "dir1000": lambda ds: ds.wind_from_direction.__setitem__((3, 1), 1000.0),
        "dir1e30": lambda ds: ds.wind_from_direction.__setitem__((3, 1), 1e30),
        "dirinf": lambda ds: ds.wind_from_direction.__setitem__((5, 0), np.inf),
        "tineg": lambda ds: ds.turbulence_intensity.__setitem__((2, 0), -0.1),
    }.items():
        ds = conditions()
        edit(ds)
        ds.to_netcdf(d / f"c_{name}.nc")
    ds = conditions()
    t = ds.time.values.copy()
    t[5] = t[4]
    ds.assign_coords(time=time_coord(t)).to_netcdf(d / "c_dup.nc")
    t = ds.time.values.copy()
    t[5], t[6] = t[6], t[5]
    ds.assign_coords(time=time_coord(t)).to_netcdf(d / "c_unsorted.nc")
    conditions().isel(time=slice(0, 0)).to_netcdf(d / "c_empty.nc")
    field(lidar_cone_angle=95.0).to_netcdf(d / "f_cone.nc")
    field(lidar_hybrid_weight="two thirds").to_netcdf(d / "f_weight.nc")
    conditions(heights=(5.0, 80.0)).assign_attrs(lidar_rwf_fwhm=60.0).to_netcdf(d / "c_low.nc")
    # pulse files: netCDF bytes, a constant intensity
    shutil.copy(d / "c.nc", d / "pulse.nc")
    (d / "const.csv").write_text("time_ns,intensity\n" + "".join(f"{t},1.0\n" for t in range(-100, 101, 5)))
    xr.Dataset({"x": ("a", np.arange(3.0))}).to_netcdf(d / "foreign.nc")
    (d / "adir").mkdir()
    (d / "afile").write_text("not a directory\n")
    return d


#: (id, command line, fragment of the one error message)
CASES = [
    # 1. mismatched bench files
    ("bench-30s-log-60s-rtd", "bench ingest {d}/rtd.csv {d}/m30/control_log.csv -o {o}/cube.nc",
     "do not describe the same run"),
    ("bench-log-past-rtd", "bench ingest {d}/m30/rtd.csv {d}/control_log.csv -o {o}/cube.nc",
     "the RTD does not cover the programmed bin"),
    ("bench-rtd-1e30", "bench ingest {d}/rtd_1e30.csv {d}/control_log.csv -o {o}/cube.nc",
     "'radial_wind_speed_m_s' data row 41 is 1e+30 m s-1"),
    ("bench-rtd-nan", "bench ingest {d}/rtd_nan.csv {d}/control_log.csv -o {o}/cube.nc",
     "first at data row 8"),
    ("bench-rtd-unknown-los", "bench ingest {d}/rtd_los.csv {d}/control_log.csv -o {o}/cube.nc", "['45']"),
    ("bench-rtd-empty", "bench ingest {d}/empty.csv {d}/control_log.csv -o {o}/cube.nc", "RTD file is empty"),
    ("bench-rtd-dir", "bench ingest {d}/adir {d}/control_log.csv -o {o}/cube.nc", "RTD path is a directory"),
    ("bench-control-dir", "bench ingest {d}/rtd.csv {d}/adir -o {o}/cube.nc",
     "control log path is a directory"),
    # 4. directions and times
    ("direction-1000", "conditions check {d}/c_dir1000.nc", "first 1000 degree at time=2024-01-01T00:30"),
    ("direction-1e30", "conditions check {d}/c_dir1e30.nc", "first 1e+30 degree"),
    ("direction-inf", "conditions check {d}/c_dirinf.nc",
     "'wind_from_direction' has 1 infinite value(s), first inf"),
    ("direction-inf-simulate", "simulate --conditions {d}/c_dirinf.nc -o {o}/sim.nc", "infinite value"),
    ("ti-negative", "conditions check {d}/c_tineg.nc", "first -0.1 at time=2024-01-01T00:20"),
    ("time-duplicate", "conditions check {d}/c_dup.nc", "index 5: 2024-01-01T00:40:00.000000000 repeats"),
    ("time-unsorted", "conditions check {d}/c_unsorted.nc",
     "index 6: 2024-01-01T00:50:00.000000000 comes before"),
    ("time-empty-check", "conditions check {d}/c_empty.nc", "dimension 'time' has length 0"),
    ("time-empty-simulate", "simulate --conditions {d}/c_empty.nc -o {o}/sim.nc",
     "dimension 'time' has length 0"),
    # 5. one check for field_campaign (as diagnose) and for conditions (as simulate)
    ("field-cone-95", "conditions check {d}/f_cone.nc --kind field_campaign", "'lidar_cone_angle'"),
    ("field-weight-words", "conditions check {d}/f_weight.nc --kind field_campaign", "'lidar_hybrid_weight'"),
    ("field-cone-95-diagnose", "diagnose {d}/f_cone.nc -o {o}/d.nc", "'lidar_cone_angle'"),
    ("conditions-cone-95", "conditions check {d}/f_cone.nc", "'lidar_cone_angle'"),
    ("conditions-unreachable", "conditions check {d}/c_low.nc", "the RWF would extend below the lidar"),
    ("field-missing-pair", "conditions check {d}/c.nc --kind field_campaign", "'lidar_wind_speed'"),
    # 9. read-only output directory, output that is a directory or a file
    ("ro-bench-simulate", "bench simulate -o {ro} --accumulation-time 20", "is not writable"),
    ("ro-bench-ingest", "bench ingest {d}/rtd.csv {d}/control_log.csv -o {ro}/cube.nc", "is not writable"),
    ("ro-bench-repeatability", "bench repeatability {d}/c.nc {d}/c.nc -o {ro}/rep.nc", "is not writable"),
    ("ro-rwf", "rwf -o {ro}/rwf.nc", "is not writable"),
    ("ro-terms", "terms -o {ro}/terms.nc", "is not writable"),
    ("ro-conditions-synthetic", "conditions synthetic -n 5 -o {ro}/c.nc", "is not writable"),
    ("ro-turbulence", "turbulence --wind-speed 8 --ti 0.1 --height 80 -o {ro}/t.nc", "is not writable"),
    ("ro-simulate", "simulate --conditions {d}/c.nc -o {ro}/sim.nc", "is not writable"),
    ("ro-sensitivity", "sensitivity {d}/c.nc --variable cnr -o {ro}/s.nc", "is not writable"),
    ("ro-budget", "budget {d}/c.nc -o {ro}/b.nc", "is not writable"),
    ("ro-certificate", "certificate --budget {d}/c.nc -o {ro}/cert.nc", "is not writable"),
    ("ro-sweep", "sweep -o {ro}/sweep.nc", "is not writable"),
    ("ro-diagnose-generate", "diagnose generate -o {ro}/f.nc", "is not writable"),
    ("ro-calibrate", "calibrate -o {ro}/lidarcal-out", "cannot create the output directory"),
    ("output-is-dir-rwf", "rwf -o {d}/adir --overwrite", "output is a directory"),
    ("output-is-dir-terms", "terms -o {d}/adir --overwrite", "output is a directory"),
    ("output-is-dir-simulate", "simulate --conditions {d}/c.nc -o {d}/adir --overwrite",
     "output is a directory"),
    ("calibrate-output-is-file", "calibrate -o {d}/afile --overwrite", "output directory is a file"),
    ("pulse-netcdf", "rwf --pulse-file {d}/pulse.nc -o {o}/rwf.nc", "not a UTF-8 CSV text file"),
    ("pulse-constant", "rwf --pulse-file {d}/const.csv -o {o}/rwf.nc", "found a constant intensity"),
    ("pulse-dir", "rwf --pulse-file {d}/adir -o {o}/rwf.nc", "pulse file path is a directory"),
    ("conditions-dir", "conditions check {d}/adir", "is a directory"),
    # 10. numeric options, checked when parsed and named
    ("option-alpha", "diagnose {d}/c.nc -o {o}/d.nc --alpha 2",
     "--alpha expects a finite number in (0, 1); got '2'"),
    ("option-workers", "simulate -o {o}/sim.nc --workers 0",
     "--workers expects a whole number >= 1; got '0'"),
    ("option-coverage", "budget {d}/c.nc -o {o}/b.nc --coverage-factor -2", "--coverage-factor expects"),
    ("option-bin-width-0", "sensitivity {d}/c.nc --variable cnr --bin-width 0 -o {o}/s.nc",
     "--bin-width expects a quantity > 0; got '0'"),
    ("option-bin-width-var", "sensitivity {d}/c.nc --variable cnr --bin-width cnr=-1 -o {o}/s.nc",
     "--bin-width expects a quantity > 0"),
    ("option-budget-bin-width", "budget {d}/c.nc -o {o}/b.nc --bin-width '0 m s-1'", "--bin-width expects"),
    ("option-seed", "simulate -o {o}/sim.nc --seed -1", "--seed expects a whole number >= 0"),
    ("option-heights", "simulate -o {o}/sim.nc --heights 80 0", "--heights expects a finite number > 0"),
    ("option-nan", "terms -o {o}/t.nc --height nan", "--height expects a finite number > 0; got 'nan'"),
    ("option-ti", "turbulence --wind-speed 8 --ti 1.5 --height 80 -o {o}/t.nc", "--ti expects"),
    ("option-cone", "terms -o {o}/t.nc --cone-angle 95", "--cone-angle expects a finite number in (0, 90)"),
    ("option-settling", "bench ingest {d}/rtd.csv {d}/control_log.csv -o {o}/c.nc --settling-time -1",
     "--settling-time expects"),
    # 11. errors name the input
    ("certificate-foreign-budget", "certificate --budget {d}/foreign.nc -o {o}/cert.nc",
     "foreign.nc: expected"),
    ("certificate-wrong-kind", "certificate --budget {d}/c.nc -o {o}/cert.nc",
     "c.nc: expected a certificate or an uncertainty_budget; found a file with no lidarcal_artefact"),
]


def _run(argv: list[str], capsys) -> tuple[int, str]:
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse refusals
        rc = exc.code
    return rc, capsys.readouterr().err


def _listing(*dirs: Path) -> dict[str, list[str]]:
    return {str(d): sorted(p.name for p in d.rglob("*")) for d in dirs}


@pytest.mark.parametrize(("argv", "fragment"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_exits_2_naming_the_culprit(argv, fragment, inputs, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    out = tmp_path / "out"
    out.mkdir()
    args = [a.format(d=inputs, o=out, ro=RO) for a in shlex.split(argv)]
    before = _listing(inputs, out)
    rc, err = _run(args, capsys)
    assert rc == 2, err
    assert fragment in err, err
    assert "Traceback" not in err
    assert _listing(inputs, out) == before  # no output, no hidden .part left, inputs untouched


def test_the_sample_bench_run_still_ingests(tmp_path, capsys):
    """The agreement check refuses the mismatch above, not the sample run (60-s bins, 13+ records)."""
    from lidarcal.data import sample_file

    rtd, control = sample_file("bench/rtd.csv.gz"), sample_file("bench/control_log.csv")
    assert main(["bench", "ingest", str(rtd), str(control), "-o", str(tmp_path / "cube.nc")]) == 0
    assert (tmp_path / "cube.nc").exists()


def test_good_small_run_ingests_so_the_mismatch_rows_are_meaningful(inputs, tmp_path, capsys):
    """Both halves of the mismatch case are good runs on their own: only their pairing is refused."""
    for sub in ("", "m30/"):
        rc = main(["bench", "ingest", f"{inputs}/{sub}rtd.csv", f"{inputs}/{sub}control_log.csv",
                   "-o", str(tmp_path / f"cube{len(sub)}.nc")])
        assert rc == 0, capsys.readouterr().err


def test_verify_and_validate_report_every_file(inputs, tmp_path, capsys):
    """A missing file does not stop the others from being checked; exit 2 names it, the rest are reported."""
    missing = tmp_path / "missing.nc"
    rc, err = _run(["validate", "--no-compliance", str(missing), str(inputs / "c_tineg.nc"),
                    str(inputs / "foreign.nc")], capsys)
    assert rc == 2 and f"{missing}: file not found" in err and "Traceback" not in err
    rc, err = _run(["verify", str(missing), str(inputs / "c.nc")], capsys)
    assert rc == 2 and "Traceback" not in err
    assert f"{missing}: file not found" in err
    assert "c.nc: not a lidarcal certificate" in err  # the second file was checked too


def test_validate_reports_each_file_on_stdout(inputs, tmp_path, capsys):
    missing = tmp_path / "missing.nc"
    main(["validate", "--no-compliance", str(missing), str(inputs / "c_tineg.nc")])
    out = capsys.readouterr().out
    assert f"{missing}: FAIL" in out and f"{inputs / 'c_tineg.nc'}: FAIL" in out


def test_sample_directions_nan_stays_missing(tmp_path, capsys):
    """NaN is "missing" (the period is skipped), unlike inf or 1000 degree."""
    ds = conditions()
    ds.wind_from_direction[3, 1] = np.nan
    ds.to_netcdf(tmp_path / "c.nc")
    assert main(["conditions", "check", str(tmp_path / "c.nc")]) == 0
    assert "skipped (period, height) pairs: 1" in capsys.readouterr().out


def test_no_case_is_forgotten():
    """Every command that writes a file has a read-only row (9 of them used to crash)."""
    ro = [c[0] for c in CASES if c[0].startswith("ro-")]
    assert len(ro) == 14, ro
    assert os.path.isdir(RO)


def test_synthetic_below_the_lowest_base_height_stays_valid(tmp_path, capsys):
    """sigma_u is held below the lowest measured height (the fuzz found TI = -0.58 at 40 m from 80/120 m)."""
    base = conditions(n=6, heights=(80.0, 120.0))
    base["wind_speed"][:, 1] = base.wind_speed[:, 0] * 1.5**0.2  # a power-law profile, alpha = 0.2
    # sigma_u 1.7 times larger at 120 m: carried linearly in log-height to 40 m (w = -1.71) it would be
    # (1 + 1.71 - 1.71 * 1.7) = -0.2 times sigma_u(80 m), a negative TI
    base["turbulence_intensity"][:, 1] = base.turbulence_intensity[:, 0] * 1.7 / 1.5**0.2
    base.to_netcdf(tmp_path / "base.nc")
    out = tmp_path / "c.nc"
    rc = main(["conditions", "synthetic", "--base", str(tmp_path / "base.nc"), "--heights", "40", "80",
               "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    ti = xr.open_dataset(out).turbulence_intensity.sel(height=40.0).values
    # sigma_u held at its 80-m value over a smaller speed: TI(40 m) = TI(80 m) * 2**0.2 exactly
    ti80 = xr.open_dataset(tmp_path / "base.nc").turbulence_intensity.sel(height=80.0).values
    np.testing.assert_allclose(ti, ti80 * 2**0.2, rtol=1e-12)
    assert main(["validate", "--no-compliance", str(out)]) == 0
