"""Damaged lidar and mast files, and other inputs a user can get wrong (issue 20, items 2, 5, 6, 9).

Every case starts from the packaged example files (``sample_data/sta``), damages one thing the
way a logger, an export or a user does, and checks the CLI's answer: exit status 2 with one
message naming the input file, the line and the column, no traceback, no output file (or, where
the user allows it, a warning naming what was skipped).  Expected numbers (km/h -> m/s, ratios)
are computed here by hand, not by lidarcal.
"""

from __future__ import annotations

import asyncio
import gc
import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from lidarcal.cli import main
from lidarcal.data import sample_data_dir

STA = sample_data_dir() / "sta"
OLDER = STA / "example_older.sta"
NEWER = STA / "example_newer.sta"
MAST = STA / "example_mast.csv"
MAST_COLUMNS = "80=Spd80mN,60=Spd60mN"


def _lines(path: Path) -> list[str]:
    return path.read_bytes().decode("latin-1").split("\n")


def _write(path: Path, lines: list[str]) -> Path:
    path.write_bytes("\n".join(lines).encode("latin-1"))
    return path


def _set_cell(lines: list[str], line: int, column: int, value: str) -> None:
    """Replace the cell at 1-based file ``line`` and 1-based ``column``."""
    cells = lines[line - 1].split("\t")
    cells[column - 1] = value
    lines[line - 1] = "\t".join(cells)


def _fails(capsys, argv, *expected) -> str:
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    for text in expected:
        assert text in err, (text, err)
    return err


def _conditions(tmp_path, *files, extra=()) -> list[str]:
    return ["conditions", "from-sta", *map(str, files), "-o", str(tmp_path / "c.nc"), *extra]


def _field(tmp_path, reference, columns=MAST_COLUMNS, extra=()) -> list[str]:
    return ["field", "from-sta", str(OLDER), "--reference", str(reference), "--reference-columns", columns,
            "-o", str(tmp_path / "f.nc"), *extra]


# ---- item 5: statistics not 10 minutes apart, truncated rows -----------------------------------

def test_statistics_one_minute_apart_are_refused(tmp_path, capsys):
    lines = _lines(OLDER)  # older dialect: header 8 lines, column names line 10, data from line 11
    for k, line in enumerate(range(11, 19)):  # end stamps 00:01, 00:02, ... instead of 00:10, 00:20 ...
        _set_cell(lines, line, 1, f"02/03/2024 00:{k + 1:02d}:00")
    bad = _write(tmp_path / "minute.sta", lines)
    _fails(capsys, _conditions(tmp_path, bad), f"{bad}: line 12, column 1", "60 s after",
           "whole multiples of 600 s")
    assert not (tmp_path / "c.nc").exists()


def test_two_files_overlapping_by_five_minutes_are_refused(tmp_path, capsys):
    a = _write(tmp_path / "a.sta", _lines(OLDER))
    lines = _lines(OLDER)
    for k, line in enumerate(range(11, 19)):  # a second file shifted by 5 minutes: overlapping periods
        _set_cell(lines, line, 1, (pd.Timestamp("2024-03-02 01:25") + pd.Timedelta(minutes=10 * k))
                  .strftime("%d/%m/%Y %H:%M:%S"))
    b = _write(tmp_path / "b.sta", lines)
    _fails(capsys, _conditions(tmp_path, a, b), f"{b}: line 11, column 1", "300 s after", f"({a}, line 18)")


def test_gaps_of_whole_periods_are_accepted(tmp_path, capsys):
    lines = _lines(OLDER)
    del lines[12:14]  # two missing periods (lines 13-14): a gap, not a spacing error
    ok = _write(tmp_path / "gap.sta", lines)
    assert main(_conditions(tmp_path, ok)) == 0
    assert xr.open_dataset(tmp_path / "c.nc").sizes["time"] == 6


def test_declared_averaging_period_other_than_ten_minutes_is_refused(tmp_path, capsys):
    lines = _lines(NEWER)
    lines.insert(8, "Averaging Period (s)=60")  # a header key inside the header (HeaderSize grows by 1)
    lines[0] = "HeaderSize=11"
    bad = _write(tmp_path / "p.sta", lines)
    _fails(capsys, _conditions(tmp_path, bad), f"{bad}: line 9", "60 s statistics", "600 s")
    lines[8] = "Averaging Period (s)=600"
    assert main(_conditions(tmp_path, _write(tmp_path / "ok.sta", lines))) == 0


def test_rows_cut_mid_number_are_refused_with_file_and_line(tmp_path, capsys):
    lines = _lines(OLDER)
    lines[12] = lines[12][:100]  # line 13 cut mid-row (and mid-number)
    lines[15] = lines[15][:37]
    bad = _write(tmp_path / "cut.sta", lines)
    _fails(capsys, _conditions(tmp_path, bad), f"{bad}: 2 truncated row(s)", "line 13 (", "line 16 (",
           "--allow-gaps")
    assert not (tmp_path / "c.nc").exists()


def test_allow_gaps_reads_truncated_rows_as_missing_with_a_warning(tmp_path, capsys):
    lines = _lines(OLDER)
    lines[12] = lines[12][:100]  # line 13: the third period (interval ending 00:30)
    bad = _write(tmp_path / "cut.sta", lines)
    assert main(_conditions(tmp_path, bad, extra=["--allow-gaps"])) == 0
    err = capsys.readouterr().err
    assert f"{bad}: 1 truncated row(s)" in err and "line 13 (" in err
    ds = xr.open_dataset(tmp_path / "c.nc")
    assert np.isnan(ds["wind_speed"].isel(time=2)).all()  # the cut row is a gap ...
    assert np.isfinite(ds["wind_speed"].isel(time=[0, 1, 3])).all()  # ... the others are read
    # the cell cut mid-number ("-12.7" -> "-1" or similar) never became a value
    assert ds["wind_speed"].isel(time=1, height=0) == pytest.approx(7.46)


# ---- item 6: sentinels, negative speeds, swapped columns name file, line, column -------------

@pytest.mark.parametrize(("value", "expected"), [
    ("9999", "9999 is a missing-data code (sentinel)"),
    ("-999", "-999 is a missing-data code (sentinel)"),
    ("-3.2", "negative wind speed -3.2 m/s"),
])
def test_sta_bad_speed_names_input_file_line_and_column(tmp_path, capsys, value, expected):
    lines = _lines(OLDER)
    _set_cell(lines, 14, 23, value)  # line 14, column 23: Vhm2 (60 m)
    bad = _write(tmp_path / "bad.sta", lines)
    err = _fails(capsys, _conditions(tmp_path, bad), f"{bad}: line 14, column 23 ('Vhm2'): {expected}")
    assert "c.nc" not in err  # the input is named, not the output


def test_sta_swapped_speed_and_direction_columns(tmp_path, capsys):
    lines = _lines(NEWER)
    names = lines[11].split("\t")  # newer dialect: HeaderSize=10, column names on line 12
    i, j = names.index("58m Wind Speed (m/s)"), names.index("58m Wind Direction (°)")
    names[i], names[j] = names[j], names[i]
    lines[11] = "\t".join(names)
    bad = _write(tmp_path / "swapped.sta", lines)
    _fails(capsys, _conditions(tmp_path, bad), f"{bad}: line 13, column {j + 1} ('58m Wind Speed (m/s)')",
           "looks like a wind direction: are the column names swapped?")


@pytest.mark.parametrize(("value", "expected"), [
    ("9999", "9999 is a missing-data code (sentinel)"),
    ("-999", "-999 is a missing-data code (sentinel)"),
    ("-1.5", "negative wind speed -1.5"),
])
def test_mast_bad_speed_names_input_file_line_and_column(tmp_path, capsys, value, expected):
    df = pd.read_csv(MAST, dtype=str)
    df.loc[3, "Spd60mN"] = value  # line 5 of the file
    bad = tmp_path / "mast.csv"
    df.to_csv(bad, index=False)
    _fails(capsys, _field(tmp_path, bad), f"{bad}: line 5, column 4 ('Spd60mN'): {expected}")


def test_mast_swapped_column_names(tmp_path, capsys):
    df = pd.read_csv(MAST, dtype=str)
    df["Dir80mN"] = ["251.3", "249.0", "248.7", "252.2", "250.1", "247.9", "249.5", "250.0"]
    df = df.rename(columns={"Spd80mN": "Dir80mN", "Dir80mN": "Spd80mN"})  # the logger swapped the names
    bad = tmp_path / "mast.csv"
    df.to_csv(bad, index=False)
    _fails(capsys, _field(tmp_path, bad), f"{bad}: line 2, column 6 ('Spd80mN')",
           "outside the physical range", "are the column names swapped?")


# ---- item 2: mast units and the lidar / reference ratio -----------------------------------------

def _kmh_mast(tmp_path, names) -> Path:
    df = pd.read_csv(MAST)
    for c in df.columns[1:]:
        df[c] = (df[c] * 3.6).round(3)
    df.columns = ["Timestamp", *names]
    path = tmp_path / "kmh.csv"
    df.to_csv(path, index=False)
    return path


def test_km_per_hour_mast_without_a_unit_is_refused_naming_the_ratio(tmp_path, capsys):
    kmh = _kmh_mast(tmp_path, ["Spd80mN", "Spd80mNStd", "Spd60mN", "Spd60mNStd"])
    lidar = xr.open_dataset(_reference_field(tmp_path))["lidar_wind_speed"].values
    ref = pd.read_csv(kmh)[["Spd60mN", "Spd80mN"]].to_numpy()  # heights ascending: 60, 80
    ratio = np.median(lidar / ref)  # the same 8 periods, matched on interval start
    assert 0.2 < ratio < 0.35
    _fails(capsys, _field(tmp_path, kmh), f"{kmh}: the median lidar / reference wind speed ratio is "
           f"{ratio:.3f}", "outside the plausible [0.8, 1.25]", "--reference-units", "--skip-ratio-check")
    assert not (tmp_path / "f.nc").exists()


def _reference_field(tmp_path) -> Path:
    out = tmp_path / "ms" / "f.nc"
    out.parent.mkdir(exist_ok=True)
    assert main(["field", "from-sta", str(OLDER), "--reference", str(MAST), "--reference-columns",
                 MAST_COLUMNS, "-o", str(out)]) == 0
    return out


@pytest.mark.parametrize(("names", "extra"), [
    (["Spd80mN", "Spd80mNStd", "Spd60mN", "Spd60mNStd"], ["--reference-units", "km/h"]),
    (["Spd80mN_kmh", "Spd80mNStd_kmh", "Spd60mN_kmh", "Spd60mNStd_kmh"], []),
    (["Spd80mN (km/h)", "Spd80mNStd (km/h)", "Spd60mN (km/h)", "Spd60mNStd (km/h)"], []),
])
def test_km_per_hour_mast_with_its_unit_becomes_metres_per_second(tmp_path, capsys, names, extra):
    kmh = _kmh_mast(tmp_path, names)
    cols = f"80={names[0]},60={names[2]}"
    std = f"80={names[1]},60={names[3]}"
    assert main(_field(tmp_path, kmh, cols, [*extra, "--reference-std", std])) == 0
    ds = xr.open_dataset(tmp_path / "f.nc")
    raw = pd.read_csv(kmh)[[names[2], names[0]]].to_numpy()
    np.testing.assert_allclose(ds["reference_wind_speed"].values, raw * 1000.0 / 3600.0, rtol=1e-12)
    assert ds["reference_wind_speed"].attrs["units"] == "m s-1"
    assert 0.8 < ds.attrs["lidar_reference_median_ratio"] < 1.25
    sd = pd.read_csv(kmh)[[names[3], names[1]]].to_numpy() / 3.6
    np.testing.assert_allclose(ds["turbulence_intensity"].values, sd / (raw / 3.6), rtol=1e-9)


def test_unit_in_the_column_name_and_option_must_agree(tmp_path, capsys):
    kmh = _kmh_mast(tmp_path, ["Spd80mN_kmh", "Spd80mNStd_kmh", "Spd60mN_kmh", "Spd60mNStd_kmh"])
    _fails(capsys, _field(tmp_path, kmh, "80=Spd80mN_kmh,60=Spd60mN_kmh", ["--reference-units", "m/s"]),
           f"{kmh}: column 2 ('Spd80mN_kmh'): the column name declares 'km/h' but --reference-units is 'm/s'")


def test_a_unit_that_is_not_a_speed_is_refused(tmp_path, capsys):
    _fails(capsys, _field(tmp_path, MAST, extra=["--reference-units", "degC"]), f"{MAST}: column",
           "'degC'", "expected units convertible to 'm s-1'")


def test_skip_ratio_check_accepts_and_records_the_ratio(tmp_path, capsys):
    kmh = _kmh_mast(tmp_path, ["Spd80mN", "Spd80mNStd", "Spd60mN", "Spd60mNStd"])
    assert main(_field(tmp_path, kmh, extra=["--skip-ratio-check"])) == 0
    ds = xr.open_dataset(tmp_path / "f.nc")
    assert ds.attrs["lidar_reference_median_ratio"] == pytest.approx(0.277, abs=0.01)
    assert ds.attrs["lidar_reference_ratio_checked"].startswith("no (--skip-ratio-check)")


# ---- item 9: one clear message instead of a traceback or a hang --------------------------------

def test_mast_with_mixed_utc_offsets(tmp_path, capsys):
    lines = MAST.read_text().splitlines()
    lines = [lines[0]] + [ln.replace(",", "+00:00," if k < 4 else "+01:00,", 1)
                          for k, ln in enumerate(lines[1:])]
    bad = tmp_path / "tz.csv"
    bad.write_text("\n".join(lines) + "\n")
    _fails(capsys, _field(tmp_path, bad), f"{bad}: line 6, column 1 ('Timestamp')", "UTC offset '+01:00'",
           "line 2 has '+00:00'")


def test_latin1_mast_with_a_malformed_row(tmp_path, capsys):
    lines = MAST.read_text().splitlines()
    lines[0] += ",Temp (°C)"
    lines = [lines[0]] + [ln + ",4.5" for ln in lines[1:]]
    lines[4] += ",1,2"  # line 5 has two fields too many
    bad = tmp_path / "latin.csv"
    bad.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    _fails(capsys, _field(tmp_path, bad), f"{bad}: not a readable CSV table", "line 5")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="FIFOs are POSIX")
def test_verify_and_readers_refuse_a_fifo(tmp_path, capsys):
    fifo = tmp_path / "cert.nc"
    os.mkfifo(fifo)
    # in a child process with a deadline: the failure this test exists for is a hang in C code
    code = "import sys; from lidarcal.cli import main; sys.exit(main())"
    try:
        run = subprocess.run([sys.executable, "-c", code, "verify", str(fifo)], capture_output=True,
                             text=True, timeout=90)
    except subprocess.TimeoutExpired:
        pytest.fail("lidarcal verify on a FIFO hangs")
    assert run.returncode == 2, run.stderr
    assert f"{fifo}: is a FIFO (named pipe)" in run.stderr and "NOT CHECKED" in run.stdout
    _fails(capsys, _conditions(tmp_path, fifo), f"{fifo}: is a FIFO (named pipe)")
    _fails(capsys, _field(tmp_path, fifo), f"{fifo}: is a FIFO (named pipe)")


def test_workdir_that_is_a_file(tmp_path, capsys):
    from lidarcal.conditions import synthetic_conditions

    cond = tmp_path / "c4.nc"
    synthetic_conditions(2, (40.0, 80.0), seed=3).to_netcdf(cond)
    work = tmp_path / "work"
    work.write_text("not a directory")
    _fails(capsys, ["simulate", "--conditions", str(cond), "--workdir", str(work), "--scheduler",
                    "synchronous", "-o", str(tmp_path / "s.nc")], f"{work}: --workdir must be a directory",
           "it is a file")
    _fails(capsys, ["simulate", "--conditions", str(cond), "--workdir", str(work / "sub"), "--scheduler",
                    "synchronous", "-o", str(tmp_path / "s.nc")], "one of its parents is a file")
    assert not (tmp_path / "s.nc").exists()


def test_an_abandoned_gather_leaves_no_allexit_traceback():
    """The mechanism behind the 1-in-4 ``AllExit`` traceback after 'every dask worker ... is gone'.

    When the fetch of a result is given up (its worker died), distributed's gather task later
    fails with ``AllExit`` and nobody retrieves it; asyncio logs "Task exception was never
    retrieved" with the traceback.  Reproduced here with the real exception class on a real
    event loop; after ``simulate_campaign``'s distributed path has run, no such record reaches a
    handler.
    """
    from distributed.client import AllExit

    from lidarcal.campaign.workers import quiet_orphaned_gathers

    records: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record)

    def orphan():
        loop = asyncio.new_event_loop()

        async def gather_step():
            raise AllExit()

        task = loop.create_task(gather_step())
        loop.run_until_complete(asyncio.sleep(0.01))
        loop.close()
        del task
        gc.collect()

    handler = Keep()
    logger = logging.getLogger("asyncio")
    logger.addHandler(handler)
    saved = list(logger.filters)
    try:
        for f in saved:
            logger.removeFilter(f)
        orphan()
        assert any("never retrieved" in r.getMessage() for r in records)  # the noise exists ...
        records.clear()
        quiet_orphaned_gathers()
        orphan()
        assert records == []  # ... and is gone
        assert re.search("AllExit", "".join(r.getMessage() for r in records)) is None
    finally:
        logger.removeHandler(handler)
        for f in saved:
            if f not in logger.filters:
                logger.addFilter(f)
