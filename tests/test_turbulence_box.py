"""The turbulence_box artefact and the ``lidarcal turbulence`` command."""

import json

import numpy as np
import pytest

from lidarcal.cli import main
from lidarcal.compliance import check_compliance
from lidarcal.errors import UnitError
from lidarcal.io import open_artefact
from lidarcal.lidar import LidarModel
from lidarcal.lidar.box import lidar_turbulence_box
from lidarcal.lidar.geometry import period_points
from lidarcal.schema import validate_dataset
from lidarcal.turbulence.box import turbulence_box
from lidarcal.units import Q_


def test_cli_writes_valid_box_and_refuses_overwrite(tmp_path, capsys):
    out = tmp_path / "box.nc"
    argv = ["turbulence", "--wind-speed", "8", "--ti", "0.1", "--height", "100", "--direction", "0",
            "--seed", "1", "-o", str(out)]
    assert main(argv) == 0
    ds = open_artefact(out, "turbulence_box")
    assert validate_dataset(ds) == []
    report = check_compliance(out)
    assert report.passed, report.failures
    assert [w for w in report.warnings if w.startswith("cf")] == []  # (point, time): CF 2.4's order
    assert ds.u.dims == ("point", "time")
    assert dict(ds.sizes) == {"time": 600, "point": 21}  # 4 beams x 5 RWF nodes + the reference
    assert ds.u.attrs["units"] == "m s-1" and ds.z.attrs["units"] == "m"
    assert json.loads(ds.attrs["lidarcal_seeds"])["seed"] == [1]
    assert ds.attrs["lidarcal_sigma_u"] == pytest.approx(0.8)
    # wind from 0 deg along beams 0/180: their nodes lie on the cross-wind axis y = 0
    beam0 = ds.point_label.str.startswith("beam0_")
    np.testing.assert_allclose(ds.y.where(beam0, drop=True), 0.0, atol=1e-9)
    assert main(argv) == 2  # exists: refused
    assert "file exists" in capsys.readouterr().err


def test_box_points_are_the_simulators_rwf_nodes_and_reference():
    # simulate_period draws its LOS signals from their continuous-RWF cross-spectra
    # (lidarcal.lidar.spectral), so the box no longer holds its exact series; it holds the
    # turbulence at the lidar's RWF quadrature nodes and the reference of that height
    model = LidarModel.ideal(los_noise_std=0.0)
    box = lidar_turbulence_box(model, height=Q_(80.0, "m"), wind_speed=Q_(9.0, "m/s"),
                               turbulence_intensity=0.14, wind_from_direction=Q_(37.0, "degree"), seed=(4, 2))
    pts = period_points(model, 80.0, 37.0)
    np.testing.assert_array_equal(box.point_label.values, pts["label"])
    np.testing.assert_allclose(np.stack([box.x.values, box.y.values, box.z.values], axis=-1), pts["wind"],
                               atol=1e-9)


def test_pyconturb_generator_same_layout():
    model = LidarModel.ideal()
    box = lidar_turbulence_box(model, height=Q_(100.0, "m"), wind_speed=Q_(8.0, "m/s"),
                               turbulence_intensity=0.1, wind_from_direction=Q_(10.0, "degree"), seed=3,
                               generator="pyconturb",
                               duration=Q_(120.0, "s"))
    assert dict(box.sizes) == {"time": 120, "point": 21}
    assert box.attrs["lidarcal_generator"] == "pyconturb"
    assert validate_dataset(box) == []
    # gen_turb's fixed amplitudes give exactly sigma (ddof=1) at the first point it factorises,
    # the lowest (y, z); the frozen-turbulence delay only rotates its (tiny) Nyquist term: 1e-3
    first = int(np.lexsort((box.z.values, box.y.values))[0])
    std = box[["u", "v", "w"]].isel(point=first).std("time", ddof=1).to_array().values
    np.testing.assert_allclose(std, [0.8, 0.64, 0.4], rtol=1e-3)


def test_bare_numbers_refused():
    with pytest.raises(UnitError, match="argument 'wind_speed'"):
        turbulence_box(np.array([[0.0, 0.0, 80.0]]), wind_speed=8.0, turbulence_intensity=0.1, seed=0)
