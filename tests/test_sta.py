"""WindCube .sta reading: files of both dialects written here from the format description alone.

The writers below follow the description in the STA issue (Latin-1, LF or CRLF, tabs;
``HeaderSize=N`` / ``HeaderLength=N``, column names on line N + 2; newer groups
``<h>m Wind Speed (m/s)`` ... each followed by an empty column; older ``Vhm<i>`` ... with the
un-indexed ``CNRm dCNR CNRmax CNRmin`` repeated in every group).  Expected values are computed
here from the written numbers (finite differences, power law), not by lidarcal.
"""

import json
import re
import warnings

import numpy as np
import pandas as pd
import pytest

from lidarcal.cli import main
from lidarcal.conditions import load_conditions
from lidarcal.conditions.sta import sta_conditions
from lidarcal.conditions.stafile import read_sta
from lidarcal.errors import InputError
from lidarcal.provenance import sha256

PHI = 28.0  # scan (cone) angle written in the files, degree
NEWER_QUANTITIES = [
    "Wind Speed (m/s)", "Wind Speed Dispersion (m/s)", "Wind Speed min (m/s)", "Wind Speed max (m/s)",
    "Wind Direction (°)", "Z-wind (m/s)", "Z-wind Dispersion (m/s)", "CNR (dB)", "CNR min (dB)",
    "Dopp Spect Broad (m/s)", "Data Availability (%)",
]
NEWER_STATION = ["Int Temp (°C)", "Ext Temp (°C)", "Pressure (hPa)", "Rel Humidity (%)", "Wiper count",
                 "Vbatt (V)"]
OLDER_INDEXED_HEAD = ["Vhm", "dVh", "VhMax", "VhMin", "Azim", "um", "du", "vm", "dv", "wm", "dw"]


def make_values(n, z, seed=0, alpha=None):
    """Known 10-minute values on (period, height), rounded as they are written to the file."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x57A]))
    z = np.asarray(z, float)
    alpha = rng.uniform(0.05, 0.3, n) if alpha is None else np.full(n, alpha)
    u80 = rng.uniform(5.0, 12.0, n)
    speed = np.round(u80[:, None] * (z / 80.0) ** alpha[:, None], 2)
    disp = np.round(speed * rng.uniform(0.05, 0.15, speed.shape), 2)
    direction = np.round(rng.uniform(0, 359.9, speed.shape), 1)
    cnr = np.round(-12.0 - 0.06 * (z - 40.0)[None, :] + rng.normal(0, 1.0, speed.shape), 1)
    avail = np.full(speed.shape, 100.0)
    return {"speed": speed, "disp": disp, "dir": direction, "cnr": cnr, "avail": avail, "alpha": alpha}


def _num(x, fmt):
    return "NaN" if not np.isfinite(x) else format(x, fmt)


def _avail(x):
    # availability is written as an integer or with two decimals
    return "NaN" if not np.isfinite(x) else (f"{x:.0f}" if float(x).is_integer() else f"{x:.2f}")


def write_newer(path, end, z, v, *, eol="\n", serial="WLS866-001", location=("Location", "Test site"),
                scan_key="ScanAngle (°)", alt_key="Altitudes (m)", size_delta=0, drop_group=None,
                first_column="Timestamp (end of interval)", size_key="HeaderSize"):
    header = [
        "Version=2.0.0",
        f"ID System={serial}",
        f"{location[0]}={location[1]}",
        "GPS Location=Lat:55.600000°N, Long:12.100000°E",
        "****************************************",
        "Configuration",
        f"{scan_key}={PHI:.3f}",
        "CNRThreshold=-22",
        f"{alt_key}=" + "\t".join(f"{h:g}" for h in z),
        "****************************************",
    ]
    names = [first_column, *NEWER_STATION]
    for k, h in enumerate(z):
        if k != drop_group:
            names += [f"{h:g}m {q}" for q in NEWER_QUANTITIES] + [""]
    rows = []
    for t in range(len(end)):
        stamp = pd.Timestamp(end[t]).strftime("%Y/%m/%d %H:%M")
        cells = [stamp, "30.1", "12.4", "1013.2", "80.5", "0", "24.1"]
        for k in range(len(z)):
            if k == drop_group:
                continue
            s, d, w, c, a = (v["speed"][t, k], v["disp"][t, k], v["dir"][t, k], v["cnr"][t, k],
                             v["avail"][t, k])
            cells += [_num(s, ".2f"), _num(d, ".2f"), _num(s - 2 * d, ".2f"), _num(s + 2 * d, ".2f"),
                      _num(w, ".1f"), _num(0.1 * d, ".2f"), _num(0.5 * d, ".2f"), _num(c, ".1f"),
                      _num(c - 3, ".1f"), _num(1.5 + 0 * s, ".2f"), _avail(a), ""]
        rows.append(cells)
    lines = [f"{size_key}={len(header) + size_delta}", *header, "\t".join(names)]
    lines += ["\t".join(r) for r in rows]
    path.write_bytes((eol.join(lines) + eol).encode("latin-1"))
    return path


def write_older(path, end, z, v, *, eol="\n", serial="WLS7-164", location=("Localisation", "Site B"),
                scan_key="ScanAngle(°)", alt_key="Altitudes(m)", size_delta=0, drop_group=None):
    header = [
        f"ID System={serial}",
        f"{location[0]}={location[1]}",
        "GPS Localisation=N 55°36' E 12°06'",
        "****",
        f"{scan_key}={PHI:.2f}",
        "CNRThreshold=-22",
        f"{alt_key}=" + "\t".join(f"{h:g}" for h in z),
        "Version=1.0",
    ]
    names = ["Date", "WiperCount", "Tm"]
    for k in range(len(z)):
        if k != drop_group:
            i = k + 1
            names += [f"{q}{i}" for q in OLDER_INDEXED_HEAD]
            names += ["CNRm", "dCNR", "CNRmax", "CNRmin", "spectral_broadening", "dspectral_broadening",
                      f"Avail.{i}", ""]
    rows = []
    for t in range(len(end)):
        cells = [pd.Timestamp(end[t]).strftime("%d/%m/%Y %H:%M:%S"), "0", "12.4"]
        for k in range(len(z)):
            if k == drop_group:
                continue
            s, d, w, c, a = (v["speed"][t, k], v["disp"][t, k], v["dir"][t, k], v["cnr"][t, k],
                             v["avail"][t, k])
            # um/vm etc. are filler with distinct values so a column mix-up cannot go unnoticed
            cells += [_num(s, ".2f"), _num(d, ".2f"), _num(s + 2 * d, ".2f"), _num(s - 2 * d, ".2f"),
                      _num(w, ".1f"), _num(0.7 * s, ".2f"), _num(d, ".2f"), _num(0.6 * s, ".2f"),
                      _num(d, ".2f"), _num(0.01 * s, ".2f"), _num(0.3, ".2f"),
                      _num(c, ".1f"), _num(0.9, ".1f"), _num(c + 2, ".1f"), _num(c - 2, ".1f"),
                      _num(1.5, ".2f"), _num(0.2, ".2f"), _avail(a), ""]
        rows.append(cells)
    lines = [f"HeaderLength={len(header) + size_delta}", *header, "\t".join(names)]
    lines += ["\t".join(r) for r in rows]
    path.write_bytes((eol.join(lines) + eol).encode("latin-1"))
    return path


def ends(n, start="2024-03-01T00:10"):
    return np.datetime64(start, "ns") + np.arange(n) * np.timedelta64(600, "s")


def expected_neighbour(values, z, f):
    """Brute force: at each height f(lower, upper) with the nearest neighbours (ends: one neighbour)."""
    out = np.empty_like(values)
    n = len(z)
    for k in range(n):
        lo, hi = max(k - 1, 0), min(k + 1, n - 1)
        out[:, k] = f(values[:, lo], values[:, hi], z[lo], z[hi])
    return out


def grad_along_beam(lo, hi, z_lo, z_hi):
    return (hi - lo) / (z_hi - z_lo) * np.cos(np.radians(PHI))


def shear(lo, hi, z_lo, z_hi):
    return np.log(hi / lo) / np.log(z_hi / z_lo)


Z = np.array([40.0, 58.0, 78.0, 98.0, 118.0])


@pytest.fixture
def newer(tmp_path):
    v = make_values(8, Z, seed=1)
    v["avail"][2, 1] = 79.99  # just below the 80 % default: NaN at 58 m in period 2
    v["avail"][3, 2] = 80.0  # exactly at the threshold: kept
    v["avail"][4, 0] = 95.25
    for key in ("speed", "disp", "dir", "cnr"):
        v[key][5:, 4] = np.nan  # above the signal's reach: all NaN with 0 % availability
    v["avail"][5:, 4] = 0.0
    return write_newer(tmp_path / "new.sta", ends(8), Z, v), v


@pytest.mark.parametrize("eol", ["\n", "\r\n"])
@pytest.mark.parametrize("dialect", ["newer", "older"])
def test_round_trip_every_variable(tmp_path, eol, dialect):
    z = Z[:4] if dialect == "older" else Z
    v = make_values(6, z, seed=2)
    v["avail"][1, 2] = 50.0
    writer = write_newer if dialect == "newer" else write_older
    path = writer(tmp_path / f"{dialect}.sta", ends(6), z, v, eol=eol)
    out = tmp_path / "c.nc"
    assert main(["conditions", "from-sta", str(path), "-o", str(out)]) == 0
    ds = load_conditions(out)
    raw = open_raw(out)
    mask = v["avail"] < 80
    speed = np.where(mask, np.nan, v["speed"])
    cnr = np.where(mask, np.nan, v["cnr"])
    # values are written with 2 (speed), 1 (direction, CNR) decimals and read back exactly
    # up to float parsing: 1e-12 relative
    tol = {"rtol": 1e-12, "atol": 0}
    np.testing.assert_allclose(ds.wind_speed.values, speed, **tol)
    np.testing.assert_allclose(ds.wind_from_direction.values, np.where(mask, np.nan, v["dir"]), **tol)
    np.testing.assert_allclose(ds.turbulence_intensity.values, np.where(mask, np.nan, v["disp"]) / speed,
                               **tol)
    np.testing.assert_allclose(ds.cnr.values, cnr, **tol)
    np.testing.assert_allclose(ds.cnr_gradient.values, expected_neighbour(cnr, z, grad_along_beam), **tol)
    np.testing.assert_allclose(ds.wind_shear_exponent.values, expected_neighbour(speed, z, shear), **tol)
    # against the power law the file was made from: speeds rounded to 0.005 m/s of >= 4 m/s
    # over ln(z_hi/z_lo) >= ln(118/98) move alpha by at most 2*0.005/4/0.186 = 0.014
    good = ~np.isnan(ds.wind_shear_exponent.values)
    assert good.sum() >= 20
    np.testing.assert_allclose(ds.wind_shear_exponent.values[good],
                               np.broadcast_to(v["alpha"][:, None], speed.shape)[good], atol=0.014)
    # the masked (50 % availability) value at height 2 poisons its neighbours' shear (they use
    # it), not its own (heights 1 and 3 give it), nor any other period
    assert np.isnan(ds.wind_shear_exponent.values[1, [1, 3]]).all()
    assert np.isfinite(ds.wind_shear_exponent.values[1, [0, 2]]).all()
    assert np.isfinite(ds.wind_shear_exponent.values[0]).all()
    np.testing.assert_array_equal(ds.height.values, z)
    np.testing.assert_array_equal(ds.time.values, ends(6) - np.timedelta64(600, "s"))
    np.testing.assert_array_equal(raw.time_bounds.values[:, 0], ds.time.values)
    np.testing.assert_array_equal(raw.time_bounds.values[:, 1], ends(6))
    assert raw.time.attrs["bounds"] == "time_bounds"
    a = raw.attrs
    assert a["lidar_serial"] == ("WLS866-001" if dialect == "newer" else "WLS7-164")
    assert "lidar_serial_number" not in a  # one name (files written before are read through it too)
    assert a["lidar_cone_angle"] == PHI and a["lidar_scan_angle"] == PHI
    assert a["lidar_site"] == ("Test site" if dialect == "newer" else "Site B")
    assert "55" in a["lidar_gps_location"] and "°" in a["lidar_gps_location"]  # Latin-1 degree sign
    assert a["lidar_cnr_threshold"] == -22
    assert a["lidar_firmware_version"] == ("2.0.0" if dialect == "newer" else "1.0")
    files = json.loads(a["sta_files"])
    assert files[0]["sha256"] == sha256(path) and files[0]["dialect"] == dialect
    assert any(r["sha256"] == sha256(path) for r in json.loads(a["lidarcal_inputs"]))


def open_raw(path):
    import xarray as xr

    with xr.open_dataset(path) as ds:
        return ds.load()


def test_newer_availability_threshold_and_unreached_heights(newer, tmp_path):
    path, v = newer
    ds = sta_conditions([path])
    assert np.isnan(ds.wind_speed.values[2, 1]) and np.isnan(ds.cnr.values[2, 1])  # 79.99 < 80
    assert ds.wind_speed.values[3, 2] == v["speed"][3, 2]  # 80.00 is kept
    assert ds.data_availability.values[4, 0] == 95.25  # two-decimal availability read as written
    assert np.isnan(ds.wind_speed.values[5:, 4]).all() and (ds.data_availability.values[5:, 4] == 0).all()
    assert ds.attrs["sta_below_availability_count"] == 1 + 3
    lower = sta_conditions([path], min_availability=70)
    assert lower.wind_speed.values[2, 1] == v["speed"][2, 1]
    out = tmp_path / "c70.nc"
    assert main(["conditions", "from-sta", str(path), "-o", str(out), "--min-availability", "70"]) == 0
    assert load_conditions(out, warn=False).wind_speed.values[2, 1] == v["speed"][2, 1]


def test_header_key_spellings_and_latin1(tmp_path):
    v = make_values(3, Z[:3], seed=3)
    p = write_newer(tmp_path / "a.sta", ends(3), Z[:3], v, scan_key="ScanAngle(°)", alt_key="Altitudes(m)",
                    location=("Localisation", "Høvsøre"))
    sta = read_sta(p)
    assert sta.scan_angle == PHI and sta.get("location", "localisation") == "Høvsøre"
    assert p.read_bytes().count(b"\xb0") >= 5  # degree sign is the single Latin-1 byte 0xB0


def test_two_files_join_along_time_sorted(tmp_path):
    v1, v2 = make_values(4, Z, seed=4), make_values(5, Z, seed=5)
    a = write_newer(tmp_path / "day2.sta", ends(4, "2024-03-02T00:10"), Z, v1, eol="\r\n")
    b = write_newer(tmp_path / "day1.sta", ends(5, "2024-03-01T00:10"), Z, v2)
    out = tmp_path / "c.nc"
    assert main(["conditions", "from-sta", str(a), str(b), "-o", str(out)]) == 0
    ds = load_conditions(out, warn=False)
    assert ds.sizes["time"] == 9
    np.testing.assert_array_equal(ds.time.values[:5], ends(5, "2024-03-01T00:00"))
    np.testing.assert_array_equal(ds.time.values[5:], ends(4, "2024-03-02T00:00"))
    np.testing.assert_allclose(ds.wind_speed.values, np.vstack([v2["speed"], v1["speed"]]), rtol=1e-12)
    files = json.loads(ds.attrs["sta_files"])
    assert [f["sha256"] for f in files] == [sha256(a), sha256(b)]


# -- bad files: exit 2, message names file, line (and column), nothing written ----------------


def _run_bad(tmp_path, files, capsys, *expect):
    out = tmp_path / "bad.nc"
    assert main(["conditions", "from-sta", *map(str, files), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    for text in expect:
        assert text in err, err
    assert not out.exists()
    assert not list(tmp_path.glob(".bad.nc*"))
    return err


def test_bad_unknown_dialect_first_line(tmp_path, capsys):
    p = write_newer(tmp_path / "x.sta", ends(3), Z, make_values(3, Z), size_key="HeaderLines")
    _run_bad(tmp_path, [p], capsys, f"{p}: line 1, column 1", "unknown STA dialect")


def test_bad_unknown_dialect_first_column(tmp_path, capsys):
    p = write_newer(tmp_path / "x.sta", ends(3), Z, make_values(3, Z), first_column="Time")
    _run_bad(tmp_path, [p], capsys, f"{p}: line 12, column 1", "unknown STA dialect", "'Time'")


def test_bad_header_length_past_the_data(tmp_path, capsys):
    p = write_older(tmp_path / "x.sta", ends(3), Z, make_values(3, Z), size_delta=100)
    _run_bad(tmp_path, [p], capsys, f"{p}: line 1, column 1", "HeaderLength=108 points past the data")


def test_bad_header_length_into_the_data(tmp_path, capsys):
    # header too long by one: 'line N + 2' is the first data row
    p = write_newer(tmp_path / "x.sta", ends(3), Z, make_values(3, Z), size_delta=1)
    _run_bad(tmp_path, [p], capsys, f"{p}: line 13, column 1", "looks like a data row")


@pytest.mark.parametrize("dialect", ["newer", "older"])
def test_bad_height_group_missing(tmp_path, capsys, dialect):
    writer = write_newer if dialect == "newer" else write_older
    p = writer(tmp_path / "x.sta", ends(3), Z, make_values(3, Z), drop_group=2)
    line = 12 if dialect == "newer" else 10
    # the third group would start after station columns and two groups (+ empty columns)
    col = 1 + len(NEWER_STATION) + 2 * 12 + 1 if dialect == "newer" else 3 + 2 * 19 + 1
    err = _run_bad(tmp_path, [p], capsys, f"{p}: line {line}, column {col}", "height group missing", "78 m")
    assert ("'78m Wind Speed (m/s)'" if dialect == "newer" else "'Vhm3'") in err


def test_bad_mixed_serials(tmp_path, capsys):
    a = write_newer(tmp_path / "a.sta", ends(3), Z, make_values(3, Z))
    b = write_newer(tmp_path / "b.sta", ends(3, "2024-03-02T00:10"), Z, make_values(3, Z),
                    serial="WLS866-002")
    _run_bad(tmp_path, [a, b], capsys, f"{b}: line 3", "WLS866-002", "WLS866-001", f"{a} (line 3)")


def test_bad_mixed_altitudes(tmp_path, capsys):
    a = write_older(tmp_path / "a.sta", ends(3), Z, make_values(3, Z))
    z2 = Z + np.array([0, 0, 0, 0, 2.0])
    b = write_older(tmp_path / "b.sta", ends(3, "2024-03-02T00:10"), z2, make_values(3, z2))
    _run_bad(tmp_path, [a, b], capsys, f"{b}: line 8", "Altitudes", "120.0", "118.0")


def test_bad_duplicated_timestamp_across_files(tmp_path, capsys):
    a = write_newer(tmp_path / "a.sta", ends(4), Z, make_values(4, Z))
    b = write_newer(tmp_path / "b.sta", ends(3, "2024-03-01T00:40"), Z, make_values(3, Z, seed=9))
    # b's first row (line 13) ends at 00:40, a's fourth row (line 16)
    _run_bad(tmp_path, [a, b], capsys, f"{b}: line 13, column 1", "duplicated timestamp", f"{a}, line 16")


def test_bad_duplicated_timestamp_in_one_file(tmp_path, capsys):
    e = ends(4)
    e[3] = e[1]
    p = write_older(tmp_path / "a.sta", e, Z, make_values(4, Z))
    _run_bad(tmp_path, [p], capsys, f"{p}: line 14, column 1", "duplicated timestamp", "also line 12")


def test_bad_cell_names_line_and_column(tmp_path, capsys):
    p = write_newer(tmp_path / "a.sta", ends(3), Z, make_values(3, Z))
    text = p.read_bytes().decode("latin-1").split("\n")
    cells = text[13].split("\t")  # line 14: third data row
    col = 1 + len(NEWER_STATION) + 12 + 1  # 58m Wind Speed
    cells[col - 1] = "fast"
    text[13] = "\t".join(cells)
    p.write_bytes("\n".join(text).encode("latin-1"))
    _run_bad(tmp_path, [p], capsys, f"{p}: line 14, column {col} ('58m Wind Speed (m/s)')", "'fast'")


def test_reader_errors_are_input_errors(tmp_path):
    p = tmp_path / "empty.sta"
    p.write_bytes(b"")
    with pytest.raises(InputError, match="line 1"):
        read_sta(p)


# -- field campaign ----------------------------------------------------------------------------


def write_mast(path, starts, heights, speed, std):
    cols = {"Timestamp": [pd.Timestamp(t).strftime("%Y-%m-%d %H:%M:%S") for t in starts]}
    for k, h in enumerate(heights):
        cols[f"Spd{h:g}mN"] = speed[:, k]
        cols[f"Spd{h:g}mNStd"] = std[:, k]
    pd.DataFrame(cols).to_csv(path, index=False, na_rep="NaN")
    return path


def test_field_from_sta_with_mast(tmp_path):
    z = np.array([40.0, 60.0, 80.0, 100.0])
    n = 8
    v = make_values(n, z, seed=7)
    sta = write_older(tmp_path / "l.sta", ends(n), z, v)
    starts = ends(n) - np.timedelta64(600, "s")
    mast_speed = np.round(v["speed"][:, [1, 2]] * 1.02, 3)
    mast_std = np.round(mast_speed * 0.1, 3)
    # the mast misses period 0 and records one period the lidar does not have
    keep = np.arange(1, n)
    extra_t = np.append(starts[keep], starts[-1] + np.timedelta64(600, "s"))
    mast = write_mast(tmp_path / "mast.csv", extra_t, [60, 80], np.vstack([mast_speed[keep], [9, 9]]),
                      np.vstack([mast_std[keep], [1, 1]]))
    out = tmp_path / "field.nc"
    argv = ["field", "from-sta", str(sta), "--reference", str(mast), "--reference-columns",
            "80=Spd80mN,60=Spd60mN", "--reference-std", "80=Spd80mNStd", "-o", str(out)]
    assert main(argv) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = load_conditions(out, kind="field_campaign")
    np.testing.assert_array_equal(ds.height.values, [60.0, 80.0])
    np.testing.assert_allclose(ds.lidar_wind_speed.values, v["speed"][:, [1, 2]], rtol=1e-12)
    assert np.isnan(ds.reference_wind_speed.values[0]).all()
    np.testing.assert_allclose(ds.reference_wind_speed.values[1:], mast_speed[1:], rtol=1e-12)
    # TI: mast std / mast mean at 80 m, lidar dispersion / lidar speed at 60 m
    np.testing.assert_allclose(ds.turbulence_intensity.values[1:, 1], mast_std[1:, 1] / mast_speed[1:, 1],
                               rtol=1e-12)
    np.testing.assert_allclose(ds.turbulence_intensity.values[:, 0], v["disp"][:, 1] / v["speed"][:, 1],
                               rtol=1e-12)
    # shear and CNR gradient from the lidar's neighbouring altitudes (40/80 m around 60 m)
    np.testing.assert_allclose(ds.wind_shear_exponent.values,
                               expected_neighbour(v["speed"], z, shear)[:, [1, 2]], rtol=1e-12)
    np.testing.assert_allclose(ds.cnr_gradient.values,
                               expected_neighbour(v["cnr"], z, grad_along_beam)[:, [1, 2]], rtol=1e-12)
    assert ds.attrs["lidar_cone_angle"] == PHI
    roles = {r["role"]: r["sha256"] for r in json.loads(ds.attrs["lidarcal_inputs"])}
    assert roles["reference"] == sha256(mast) and roles["sta_1"] == sha256(sta)
    # end-of-interval mast stamps: shifted back 10 min, so the mast matches one period later
    out2 = tmp_path / "field_end.nc"
    assert main([*argv[:-2], "--reference-timestamp", "end", "-o", str(out2), "--overwrite"]) == 0
    end = load_conditions(out2, kind="field_campaign", warn=False)
    np.testing.assert_allclose(end.reference_wind_speed.values[:-1], mast_speed[1:], rtol=1e-12)


def test_field_mast_height_not_a_lidar_altitude(tmp_path, capsys):
    z = np.array([40.0, 60.0, 80.0])
    v = make_values(3, z)
    sta = write_newer(tmp_path / "l.sta", ends(3), z, v)
    mast = write_mast(tmp_path / "m.csv", ends(3) - np.timedelta64(600, "s"), [75], v["speed"][:, :1],
                      v["disp"][:, :1])
    out = tmp_path / "f.nc"
    assert main(["field", "from-sta", str(sta), "--reference", str(mast), "--reference-columns", "75=Spd75mN",
                 "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "mast height(s) ['75'] m are not among the lidar's altitudes ['40', '60', '80']" in err
    assert not out.exists()


def test_single_period_time_and_bounds_share_units(tmp_path):
    # with one period xarray would pick different units for time and its bounds on its own
    import netCDF4

    p = write_newer(tmp_path / "one.sta", ends(1), Z, make_values(1, Z))
    out = tmp_path / "one.nc"
    assert main(["conditions", "from-sta", str(p), "-o", str(out)]) == 0
    with netCDF4.Dataset(out) as nc:
        assert nc["time"].units.startswith("minutes since 1970-01-01")
        assert getattr(nc["time_bounds"], "units", nc["time"].units) == nc["time"].units
        np.testing.assert_array_equal(nc["time_bounds"][:] - nc["time"][:][:, None], [[0, 10]])


def test_sample_files_read():
    from lidarcal.data import sample_file

    new = read_sta(sample_file("sta/example_newer.sta"))
    old = read_sta(sample_file("sta/example_older.sta"))
    assert (new.dialect, new.values["speed"].shape, new.scan_angle) == ("newer", (12, 5), 28.0)
    assert (old.dialect, old.values["speed"].shape, old.scan_angle) == ("older", (8, 4), 27.8)
    assert b"\r\n" in sample_file("sta/example_newer.sta").read_bytes()


@pytest.mark.parametrize("case", ["missing_column", "bad_time", "bad_number", "duplicate", "no_overlap",
                                  "std_without_mean"])
def test_field_bad_mast_records(tmp_path, capsys, case):
    z = np.array([40.0, 60.0, 80.0])
    v = make_values(4, z)
    sta = write_newer(tmp_path / "l.sta", ends(4), z, v)
    starts = ends(4) - np.timedelta64(600, "s")
    if case == "no_overlap":
        starts = starts + np.timedelta64(1, "D")
    mast = write_mast(tmp_path / "m.csv", starts, [60, 80], v["speed"][:, 1:], v["disp"][:, 1:])
    lines = mast.read_text().splitlines()
    if case == "bad_time":
        lines[2] = "yesterday" + lines[2][lines[2].index(","):]
    elif case == "bad_number":
        cells = lines[3].split(",")
        cells[1] = "n/a?"
        lines[3] = ",".join(cells)
    elif case == "duplicate":
        lines[4] = lines[1]
    mast.write_text("\n".join(lines) + "\n")
    cols, std = "80=Spd80mN,60=Spd60mN", "80=Spd80mNStd"
    if case == "missing_column":
        cols = "80=Spd80mN,60=Spd60mS"
    if case == "std_without_mean":
        std = "40=Spd80mNStd"
    out = tmp_path / "f.nc"
    assert main(["field", "from-sta", str(sta), "--reference", str(mast), "--reference-columns", cols,
                 "--reference-std", std, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    expect = {
        "missing_column": f"{mast}: column(s) ['Spd60mS'] not found",
        "bad_time": f"{mast}: line 3, column 1 ('Timestamp'): expected a timestamp; found 'yesterday'",
        "bad_number": f"{mast}: line 4, column 2 ('Spd60mN'): expected a number; found 'n/a?'",
        "duplicate": f"{mast}: line 5, column 1 ('Timestamp'): duplicated timestamp",
        "no_overlap": f"{mast}: no mast interval start matches a lidar interval start",
        "std_without_mean": "--reference-std: height(s) ['40'] m have no mean column",
    }[case]
    assert expect in err, err
    assert not out.exists()


@pytest.mark.slow
def test_diagnose_accepts_the_sample_field_campaign(tmp_path, capsys):
    from lidarcal.data import sample_file

    field = tmp_path / "field.nc"
    assert main(["field", "from-sta", str(sample_file("sta/example_older.sta")), "--reference",
                 str(sample_file("sta/example_mast.csv")), "--reference-columns", "80=Spd80mN,60=Spd60mN",
                 "--reference-std", "80=Spd80mNStd,60=Spd60mNStd", "-o", str(field)]) == 0
    capsys.readouterr()
    # 8 periods: 2 bins x 3 periods is the most the sample supports
    assert main(["diagnose", str(field), "-o", str(tmp_path / "d.nc"), "--json", "--bins", "2",
                 "--min-bin-count", "3", "--scheduler", "synchronous"]) == 0
    answer = json.loads(capsys.readouterr().out)
    assert answer["effect"] in ("none", "unexplained") or answer["effects"]
    assert np.isfinite(answer["gap_before"])


def test_sample_outputs_pass_validate(tmp_path, capsys):
    from lidarcal.data import sample_file

    cond, field = tmp_path / "c.nc", tmp_path / "f.nc"
    assert main(["conditions", "from-sta", str(sample_file("sta/example_newer.sta")), "-o", str(cond)]) == 0
    assert main(["field", "from-sta", str(sample_file("sta/example_older.sta")), "--reference",
                 str(sample_file("sta/example_mast.csv")), "--reference-columns", "80=Spd80mN,60=Spd60mN",
                 "-o", str(field)]) == 0
    capsys.readouterr()
    assert main(["validate", str(cond), str(field)]) == 0, capsys.readouterr().out
    report = capsys.readouterr().out
    assert "compliance:" not in report  # only the documented dB / standard_name exceptions remain


# -- one missing-value rule for .sta files and mast CSVs ------------------------------------------


def _with_cell(path, line, column, text):
    """Rewrite one cell (1-based file line and column) of a tab- or comma-separated file."""
    raw = path.read_bytes().decode("latin-1")
    sep = "\t" if path.suffix == ".sta" else ","
    lines = raw.split("\n")
    cells = lines[line - 1].split(sep)
    cells[column - 1] = text
    lines[line - 1] = sep.join(cells)
    path.write_bytes("\n".join(lines).encode("latin-1"))


def _sta_and_mast(tmp_path):
    z = np.array([40.0, 60.0, 80.0])
    v = make_values(4, z, seed=3)
    sta = write_older(tmp_path / "l.sta", ends(4), z, v)
    starts = ends(4) - np.timedelta64(600, "s")
    mast = write_mast(tmp_path / "mast.csv", starts, [80], v["speed"][:, [2]], v["disp"][:, [2]])
    return sta, mast, v


@pytest.mark.parametrize("marker", ["", "NaN", "nan", "NA", "n/a", "N/A", "null", "None", "-", " NaN "])
def test_missing_markers_mean_missing_in_sta_files_and_mast_csvs_alike(tmp_path, marker):
    from lidarcal.conditions.mast import read_reference_csv

    sta, mast, v = _sta_and_mast(tmp_path)
    first = read_sta(sta).lines[0]  # file line of the first data row
    _with_cell(sta, first + 1, 4, marker)  # Vhm1 (speed at 40 m) of the second period
    _with_cell(mast, 3, 2, marker)  # Spd80mN of the second period
    speed = read_sta(sta).values["speed"]
    assert np.isnan(speed[1, 0]) and np.isfinite(np.delete(speed.ravel(), 3)).all()
    _, means, _, _ = read_reference_csv(mast, {80.0: "Spd80mN"})
    assert np.isnan(means[80.0][1]) and np.isfinite(np.delete(means[80.0], 1)).all()


@pytest.mark.parametrize("text", ["inf", "-Infinity", "12.5.1", "n/a?", "missing"])
def test_other_text_is_refused_in_sta_files_and_mast_csvs_alike(tmp_path, text):
    from lidarcal.conditions.mast import read_reference_csv

    sta, mast, _ = _sta_and_mast(tmp_path)
    first = read_sta(sta).lines[0]
    _with_cell(sta, first + 1, 4, text)
    _with_cell(mast, 3, 2, text)
    found = re.escape(f"expected a number; found '{text}'")
    with pytest.raises(InputError, match=rf"line {first + 1}, column 4 \('Vhm1'\): {found}"):
        read_sta(sta)
    with pytest.raises(InputError, match=rf"line 3, column 2 \('Spd80mN'\): {found}"):
        read_reference_csv(mast, {80.0: "Spd80mN"})


def test_sentinels_are_refused_not_read_as_missing_in_both(tmp_path):
    from lidarcal.conditions.mast import read_reference_csv

    sta, mast, _ = _sta_and_mast(tmp_path)
    first = read_sta(sta).lines[0]
    _with_cell(sta, first + 1, 4, "9999")
    _with_cell(mast, 3, 2, "-999")
    with pytest.raises(InputError, match="9999 is a missing-data code"):
        read_sta(sta)
    with pytest.raises(InputError, match="-999 is a missing-data code"):
        read_reference_csv(mast, {80.0: "Spd80mN"})


def test_sta_and_field_functions_return_stamped_artefacts(tmp_path):
    from lidarcal.conditions.mast import sta_field_campaign
    from lidarcal.schema import validate_dataset

    sta, mast, _ = _sta_and_mast(tmp_path)
    cond = sta_conditions([sta])
    field = sta_field_campaign([sta], mast, {80.0: "Spd80mN"})
    for ds, kind in ((cond, "conditions"), (field, "field_campaign")):
        assert ds.attrs["lidarcal_artefact"] == kind
        assert validate_dataset(ds, kind) == []
    assert cond.wind_speed.attrs["coverage_content_type"] == "physicalMeasurement"
    assert cond.data_availability.attrs["comment"] == "periods below 80 % are missing in every other variable"
    assert field.wind_speed.attrs["comment"].startswith("mast 10-minute mean")
    assert field.reference_wind_speed.attrs["long_name"] == (
        "reference anemometer 10-minute mean wind speed (measured)")
