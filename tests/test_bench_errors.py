"""Bad bench input: every case fails with a message naming the file and problem, and writes nothing."""

import gzip

import numpy as np
import pandas as pd
import pytest

from lidarcal.bench.ingest import ingest
from lidarcal.bench.simulator import simulate_run
from lidarcal.cli import main
from lidarcal.errors import InputError, MissingVariableError, UnitError
from lidarcal.units import ureg


@pytest.fixture(scope="module")
def run_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("bench_src")
    run = simulate_run(seed=4, accumulation_time="20 s", cnr=[-16.0, -10.0],
                       velocity=ureg.Quantity(np.arange(-3.0, 4.0), "m s-1"))
    rtd, control = run.write(d)
    return rtd.read_text(), control.read_text()


@pytest.fixture
def case(tmp_path, run_files):
    """Write (possibly modified) RTD and control texts; return a function running the CLI ingest."""
    rtd_text, control_text = run_files

    def make(rtd=rtd_text, control=control_text):
        (tmp_path / "rtd.csv").write_text(rtd)
        (tmp_path / "control_log.csv").write_text(control)
        return tmp_path / "rtd.csv", tmp_path / "control_log.csv"

    return make


def _edit_rtd(text, fn):
    lines = text.splitlines()
    header, rows = lines[0].split(","), [line.split(",") for line in lines[1:]]
    header, rows = fn(header, rows)
    return "\n".join([",".join(header)] + [",".join(r) for r in rows]) + "\n"


def _run_cli(rtd, control, capsys):
    out = rtd.parent / "cube.nc"
    before = sorted(p.name for p in rtd.parent.iterdir())
    old = out.read_bytes() if out.exists() else None
    rc = main(["bench", "ingest", str(rtd), str(control), "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert (out.read_bytes() if out.exists() else None) == old  # nothing written or replaced
    assert sorted(p.name for p in rtd.parent.iterdir()) == before  # no partial or temporary file
    return err


def test_good_files_ingest(case, capsys):
    rtd, control = case()
    assert main(["bench", "ingest", str(rtd), str(control), "-o", str(rtd.parent / "cube.nc")]) == 0
    assert (rtd.parent / "cube.nc").exists()
    # a second run refuses to overwrite
    err = _run_cli(rtd, control, capsys)
    assert "file exists" in err and "--overwrite" in err


def test_missing_column(case, capsys):
    def drop_serial(h, rows):
        return h[:-1], [r[:-1] for r in rows]
    rtd, control = case(rtd=_edit_rtd(_rtd_text(case), drop_serial))
    err = _run_cli(rtd, control, capsys)
    assert "rtd.csv" in err and "'lidar_serial' is missing" in err


def _rtd_text(make):
    rtd, _ = make()
    return rtd.read_text()


def test_nan_in_rtd(case, capsys):
    def nan(h, rows):
        rows[10][2] = "NaN"
        rows[20][2] = ""
        return h, rows
    rtd, control = case(rtd=_edit_rtd(_rtd_text(case), nan))
    err = _run_cli(rtd, control, capsys)
    assert "rtd.csv" in err and "'radial_wind_speed_m_s' has 2 missing, NaN" in err and "data row 11" in err


def test_km_per_hour_is_converted(case):
    rtd, control = case()
    reference = ingest(rtd, control)
    df = pd.read_csv(rtd, dtype={"los": str})
    df["radial_wind_speed_m_s"] = (df["radial_wind_speed_m_s"] * 3.6).round(4)
    df = df.rename(columns={"radial_wind_speed_m_s": "radial_wind_speed_km_h"})
    df.to_csv(rtd, index=False)
    converted = ingest(rtd, control)
    # 4 decimals in km/h = rounding <= 1.4e-5 m/s per sample
    np.testing.assert_allclose(converted.los_bias.values, reference.los_bias.values, atol=2e-5,
                               equal_nan=True)
    np.testing.assert_array_equal(converted.sample_count.values, reference.sample_count.values)


@pytest.mark.parametrize("column,expected", [("radial_wind_speed_K", "units 'K'"),
                                             ("radial_wind_speed_bogus_unit", "cannot be parsed")])
def test_unconvertible_unit_refused(case, capsys, column, expected):
    def rename(h, rows):
        h[2] = column
        return h, rows
    rtd, control = case(rtd=_edit_rtd(_rtd_text(case), rename))
    err = _run_cli(rtd, control, capsys)
    assert "rtd.csv" in err and column in err and expected in err
    with pytest.raises(UnitError):
        ingest(rtd, control)


def test_cnr_must_be_db(case, capsys):
    def rename(h, rows):
        h[3] = "cnr_W"
        return h, rows
    rtd, control = case(rtd=_edit_rtd(_rtd_text(case), rename))
    assert "expected 'dB'" in _run_cli(rtd, control, capsys)


def test_unknown_los(case, capsys):
    def los45(h, rows):
        rows[5][1] = "45"
        return h, rows
    rtd, control = case(rtd=_edit_rtd(_rtd_text(case), los45))
    err = _run_cli(rtd, control, capsys)
    assert "rtd.csv" in err and "unknown LOS id(s) ['45']" in err and "data row 6" in err


@pytest.mark.parametrize("kind", ["swap", "duplicate"])
def test_timestamps_out_of_order_or_duplicated(case, capsys, kind):
    def edit(h, rows):
        if kind == "swap":
            rows[7], rows[8] = rows[8], rows[7]
        else:
            rows[8][0] = rows[7][0]
        return h, rows
    rtd, control = case(rtd=_edit_rtd(_rtd_text(case), edit))
    err = _run_cli(rtd, control, capsys)
    word = "out of order" if kind == "swap" else "duplicated"
    assert "rtd.csv" in err and "strictly increasing" in err and "data row 9" in err and word in err


def test_control_log_not_overlapping(case, capsys):
    _, control = case()
    shifted = control.read_text().replace("2023-02-17", "2023-03-17")
    rtd, control = case(control=shifted)
    err = _run_cli(rtd, control, capsys)
    assert "control_log.csv" in err and "does not overlap the RTD" in err


@pytest.mark.parametrize("which,text,expected", [
    ("rtd", "", "RTD file is empty"),
    ("control", "", "control log file is empty"),
    ("rtd", "timestamp_utc,los,radial_wind_speed_m_s,cnr_dB,lidar_serial\n", "header but no data rows"),
    ("control", "# only a comment\n", "no header row"),
])
def test_empty_files(case, capsys, which, text, expected):
    rtd, control = case(**{which: text})
    err = _run_cli(rtd, control, capsys)
    assert expected in err and ("rtd.csv" if which == "rtd" else "control_log.csv") in err


def test_control_metadata_and_serial(case, capsys):
    _, control = case()
    text = control.read_text()
    no_operator = "\n".join(line for line in text.splitlines() if not line.startswith("# operator"))
    rtd, control = case(control=no_operator + "\n")
    err = _run_cli(rtd, control, capsys)
    assert "lacks metadata ['operator']" in err
    rtd, control = case(control=text.replace("lidar_serial: WLS866-0195", "lidar_serial: WLS7-9982"))
    err = _run_cli(rtd, control, capsys)
    assert "'WLS866-0195'" in err and "'WLS7-9982'" in err and "same lidar" in err


def test_control_velocity_off_grid(case):
    _, control = case()
    text = control.read_text().replace(",-3.000,", ",-25.000,", 1)
    rtd, control = case(control=text)
    expected = r"control_log.csv.*'programmed_velocity_m_s' row 1 is -25 m s-1 \(after unit"
    with pytest.raises(InputError, match=expected):
        ingest(rtd, control)


def test_missing_control_column(case):
    _, control = case()
    text = control.read_text().replace("programmed_cnr_dB", "cnr")
    rtd, control = case(control=text)
    with pytest.raises(MissingVariableError, match=r"control_log.csv.*'programmed_cnr_<unit>'"):
        ingest(rtd, control)


@pytest.mark.parametrize("damage,expected", [
    ("truncated", r"not a valid gzip file \(corrupt or truncated\).*EOFError"),
    ("flipped", r"not a valid gzip file \(corrupt or truncated\).*CRC check failed"),
    ("not_gzip", r"named '\.gz' but is not gzip-compressed"),
])
def test_corrupt_gzip_rtd(case, capsys, damage, expected):
    rtd, control = case()
    plain = rtd.read_bytes()
    data = gzip.compress(plain, mtime=0)
    mid = len(data) // 2
    data = {"truncated": data[:mid],
            "flipped": data[:mid] + bytes(b ^ 0xFF for b in data[mid:mid + 64]) + data[mid + 64:],
            "not_gzip": plain}[damage]
    gz = rtd.parent / "rtd.csv.gz"
    gz.write_bytes(data)
    err = _run_cli(gz, control, capsys)
    assert "rtd.csv.gz: RTD file" in err
    with pytest.raises(InputError, match=r"rtd\.csv\.gz: RTD file .*" + expected):
        ingest(gz, control)


def test_gzip_rtd_ingests_like_plain(case):
    rtd, control = case()
    gz = rtd.parent / "rtd.csv.gz"
    gz.write_bytes(gzip.compress(rtd.read_bytes(), mtime=0))
    a, b = ingest(rtd, control), ingest(gz, control)
    np.testing.assert_array_equal(a.los_bias.values, b.los_bias.values)
