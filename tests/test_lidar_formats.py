"""The registry of lidar file formats and firmware-2.x ``.sta`` files (``NA`` header values, --cone-angle).

The firmware-2.x sample is checked against an independent parse written here with the ``csv``
module: every value of every height group is read exactly, whatever the environmental columns
and the empty column between groups.
"""

import csv
import io

import numpy as np
import pytest
from test_sta import PHI, ends, make_values, write_newer

from lidarcal.cli import main
from lidarcal.conditions import load_conditions
from lidarcal.conditions.formats import FORMATS, LidarFormat, format_of, read_lidar_files
from lidarcal.conditions.sta import sta_conditions
from lidarcal.data import sample_file
from lidarcal.errors import InputError

FIRMWARE2 = sample_file("sta/example_firmware2.sta")


def test_every_registered_format_is_complete_and_reads_its_sample(tmp_path):
    samples = {"windcube_sta": [FIRMWARE2, sample_file("sta/example_older.sta")]}
    assert set(FORMATS) == set(samples)  # a new format brings a sample read here
    for name, fmt in FORMATS.items():
        assert isinstance(fmt, LidarFormat) and fmt.name == name and fmt.description and fmt.suffixes
        for path in samples[name]:
            assert format_of(path) is fmt
            head = path.read_bytes()[:256]
            assert fmt.recognise(head) and not fmt.recognise(b"Timestamp,Spd80\n")
            files = read_lidar_files([path], cone_angle=28.0 if path == FIRMWARE2 else None)
            assert files[0].serial and files[0].end.size >= 8


def test_a_file_no_format_claims_is_refused_naming_the_formats(tmp_path):
    path = tmp_path / "record.txt"
    path.write_text("Timestamp,Spd80mN\n2024-01-01 00:00,8.1\n")
    with pytest.raises(InputError, match=r"record.txt: line 1: not a lidar file format.*windcube_sta"):
        read_lidar_files([path])
    with pytest.raises(InputError, match="no lidar file given"):
        read_lidar_files([])


def _independent(path):
    """The firmware-2.x sample parsed with csv: (heights, {quantity: (time, height)}, header dict)."""
    lines = path.read_bytes().decode("latin-1").split("\r\n")
    n = int(lines[0].split("=")[1])
    header = dict(line.split("=", 1) for line in lines[1 : n + 1] if "=" in line)
    rows = list(csv.reader(io.StringIO("\n".join(lines[n + 1 :])), delimiter="\t"))
    names, data = rows[0], [r for r in rows[1:] if r]
    z = [float(h) for h in header["Altitudes (m)"].split()]
    out = {}
    for q in (
        "Wind Speed (m/s)",
        "Wind Speed Dispersion (m/s)",
        "Wind Direction (°)",
        "CNR (dB)",
        "Data Availability (%)",
    ):
        cols = [names.index(f"{h:g}m {q}") for h in z]
        out[q] = np.array([[float(r[c]) for c in cols] for r in data])
    return np.array(z), out, header


def test_firmware2_sample_is_read_exactly_with_the_cone_angle_given(tmp_path):
    z, raw, header = _independent(FIRMWARE2)
    assert header["ScanAngle (°)"] == "NA" and header["Pulses / Line of Sight"] == "NA"
    ds = sta_conditions([FIRMWARE2], cone_angle=28.0)
    low = raw["Data Availability (%)"] < 80.0
    speed = np.where(low, np.nan, raw["Wind Speed (m/s)"])
    np.testing.assert_array_equal(ds.height.values, z)
    np.testing.assert_array_equal(ds.wind_speed.values, speed)  # exactly: the same decimal text
    np.testing.assert_array_equal(ds.cnr.values, np.where(low, np.nan, raw["CNR (dB)"]))
    np.testing.assert_array_equal(
        ds.wind_from_direction.values, np.where(low, np.nan, raw["Wind Direction (°)"])
    )
    np.testing.assert_allclose(
        ds.turbulence_intensity.values,
        np.where(low, np.nan, raw["Wind Speed Dispersion (m/s)"]) / speed,
        rtol=1e-15,
    )
    # the CNR gradient along the beam uses the cone angle given: dCNR/dz cos(28 degree)
    cnr = ds.cnr.values
    grad = (cnr[:, 2] - cnr[:, 0]) / (z[2] - z[0]) * np.cos(np.radians(28.0))
    np.testing.assert_allclose(ds.cnr_gradient.values[:, 1], grad, rtol=1e-12)
    assert ds.attrs["lidar_cone_angle"] == 28.0
    assert ds.attrs["lidar_cone_angle_source"] == "--cone-angle (the file header says 'NA')"
    assert ds.sizes["time"] == 144 and (ds.time.values[0] == np.datetime64("2024-06-01T00:00"))


def test_cone_angle_option_on_the_command_line(tmp_path, capsys):
    out = tmp_path / "c.nc"
    assert main(["conditions", "from-sta", str(FIRMWARE2), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "example_firmware2.sta: line 17 ('ScanAngle (°)=NA')" in err and "--cone-angle DEGREES" in err
    assert not out.exists()
    assert main(["conditions", "from-sta", str(FIRMWARE2), "--cone-angle", "28", "-o", str(out)]) == 0
    assert load_conditions(out).attrs["lidar_cone_angle_source"].startswith("--cone-angle")
    # a file stating its angle: the option must agree, or the file is refused
    z = np.array([40.0, 60.0, 80.0])
    stated = write_newer(tmp_path / "s.sta", ends(4), z, make_values(4, z))
    assert (
        main(["conditions", "from-sta", str(stated), "--cone-angle", "30", "-o", str(tmp_path / "d.nc")]) == 2
    )
    err = capsys.readouterr().err
    assert "s.sta: line 8" in err and f"{PHI:g} degree differs from 30 degree given by --cone-angle" in err
    assert (
        main(["conditions", "from-sta", str(stated), "--cone-angle", str(PHI), "-o", str(tmp_path / "e.nc")])
        == 0
    )
    assert load_conditions(tmp_path / "e.nc").attrs["lidar_cone_angle_source"] == "file header"
    with pytest.raises(SystemExit) as exc:  # refused by argparse before any work
        main(["conditions", "from-sta", str(FIRMWARE2), "--cone-angle", "95", "-o", str(tmp_path / "f.nc")])
    assert exc.value.code == 2
    assert "--cone-angle expects a finite number in (0, 90)" in capsys.readouterr().err
