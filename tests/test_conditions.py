"""Tests of lidarcal.conditions: kernels, the loader of docs/contracts.md, synthetic and real sample data."""

import subprocess
import sys
import warnings

import numpy as np
import pytest
import xarray as xr
from analysis_factories import var_attrs

from lidarcal.cf import height_coord, time_coord
from lidarcal.conditions import (
    SkippedPeriodsWarning,
    cnr_gradient_along_beam,
    load_conditions,
    sample_conditions_path,
    shear_exponent,
    synthetic_conditions,
    vertical_gradient,
)
from lidarcal.conditions.kernels import neighbour_pairs
from lidarcal.errors import InputError, MissingVariableError, UnitError
from lidarcal.lidar import LidarModel, lidar_attributes

LIDARCAL = [sys.executable, "-c", "import sys; from lidarcal.cli import main; sys.exit(main())"]


def make_conditions(n=6, heights=(40.0, 60.0, 80.0), seed=0):
    rng = np.random.default_rng(np.random.SeedSequence([seed, 11]))
    shape = (n, len(heights))
    return xr.Dataset(
        {
            "wind_speed": (
                ("time", "height"),
                rng.uniform(4, 12, shape),
                var_attrs("ws", "m s-1", "wind_speed"),
            ),
            "wind_from_direction": (
                ("time", "height"),
                rng.uniform(0, 360, shape),
                var_attrs("wd", "degree"),
            ),
            "turbulence_intensity": (("time", "height"), rng.uniform(0.05, 0.2, shape), var_attrs("TI", "1")),
            "wind_shear_exponent": (("time", "height"), rng.uniform(0, 0.3, shape), var_attrs("shear", "1")),
            "cnr": (("time", "height"), rng.uniform(-25, -10, shape), var_attrs("CNR", "dB")),
            "cnr_gradient": (("time", "height"), rng.uniform(-0.05, 0.05, shape), var_attrs("g", "dB m-1")),
        },
        coords={
            "time": time_coord(np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")),
            "height": height_coord(heights),
        },
    )


# -- kernels ---------------------------------------------------------------------------------


def test_neighbour_pairs_follow_paper_section_3_3():
    lo, hi = neighbour_pairs(np.array([40.0, 60.0, 80.0, 100.0]))
    # ends: one neighbour (and the height itself); interior: the two nearest neighbours
    assert lo.tolist() == [0, 0, 1, 2] and hi.tolist() == [1, 2, 3, 3]


def test_shear_exponent_recovers_power_law_and_uses_neighbours():
    z = np.array([40.0, 60.0, 80.0, 120.0])
    alpha = np.array([[0.0], [0.2], [-0.1]])
    u = 8.0 * (z / 80.0) ** alpha
    # a pure power law gives its exponent at every height (float round-off only)
    np.testing.assert_allclose(shear_exponent(u, z), np.broadcast_to(alpha, u.shape), atol=1e-12)
    # non power-law profile: value at 60 m must be ln(U80/U40)/ln(2), not involving U60
    prof = np.array([5.0, 100.0, 6.0, 7.0])
    a = shear_exponent(prof, z)
    assert a[1] == pytest.approx(np.log(6.0 / 5.0) / np.log(2.0), rel=1e-14)
    assert a[0] == pytest.approx(np.log(100.0 / 5.0) / np.log(60.0 / 40.0), rel=1e-14)
    assert a[3] == pytest.approx(np.log(7.0 / 6.0) / np.log(120.0 / 80.0), rel=1e-14)
    # non-positive or missing speeds give NaN, never a number
    assert np.isnan(shear_exponent(np.array([0.0, 5.0, 6.0]), z[:3])[:2]).all()


def test_cnr_gradient_is_along_the_beam_hand_computed():
    # CNR falling linearly by 0.09 dB per metre of HEIGHT.  Along a beam tilted 28 deg from the
    # vertical one metre of range climbs cos 28 deg = 0.882948 m, so the CNR falls
    # 0.09 * 0.882948 = 0.0794653 dB per metre of RANGE (the contract's unit) at every height.
    z = np.array([40.0, 60.0, 100.0, 200.0])
    cnr = -12.0 - 0.09 * (z - 40.0)
    np.testing.assert_allclose(cnr_gradient_along_beam(cnr, z, 28.0), -0.0794653, rtol=1e-6)
    # a 45 deg beam gives 0.09 / sqrt(2) = 0.0636396
    np.testing.assert_allclose(cnr_gradient_along_beam(cnr, z, 45.0), -0.0636396, rtol=1e-6)
    # vertical beam: the height derivative itself
    np.testing.assert_allclose(cnr_gradient_along_beam(cnr, z, 0.0), -0.09, rtol=1e-12)


def test_synthetic_cnr_gradient_uses_the_default_lidar_cone_angle():
    # without a cone angle (and no base record giving lidar_cone_angle) the along-beam gradient is
    # for LidarModel's default cone (28 deg): cos 28 deg times the vertical derivative of the CNR
    ds = synthetic_conditions(3, (40, 80, 120), seed=1)
    assert LidarModel().cone_angle == 28.0 == ds.attrs["lidarcal_synthetic_cone_angle"]
    np.testing.assert_allclose(ds.cnr_gradient.values,
                               cnr_gradient_along_beam(ds.cnr.values, ds.height.values, 28.0), rtol=1e-12)


def test_cnr_model_gradient_crosses_zero_near_the_focus_as_figure_3():
    # paper Figure 3 (right): the CNR gradient changes sign near 110 m, the focal distance.
    # Mean over many periods (AR(1) lapse scatter averages out): positive below, negative above.
    from lidarcal.conditions.kernels import cnr_model

    z = np.arange(40.0, 201.0, 10.0)
    hours = np.arange(20000) * (10 / 60) % 24
    cnr = cnr_model(hours, z, np.random.default_rng(1))
    g = cnr_gradient_along_beam(cnr, z, 28.0).mean(axis=0)
    assert (g[z <= 90] > 0.02).all() and (g[z >= 130] < -0.02).all()
    crossing = np.interp(0.0, -g, z)  # g decreases through zero
    assert 95.0 < crossing < 115.0
    # and within the figure's extremes of +-0.1 dB/m
    assert np.abs(g).max() < 0.1


def test_vertical_gradient_is_exact_for_linear_profiles():
    z = np.array([40.0, 80.0, 100.0, 200.0])
    np.testing.assert_allclose(vertical_gradient(-10.0 - 0.03 * z, z), -0.03, atol=1e-15)


# -- loader ------------------------------------------------------------------------------------


def test_load_canonical_units_sorted_heights_and_checksum(tmp_path):
    ds = make_conditions().isel(height=[2, 0, 1]).transpose("height", "time")
    ds["wind_speed"] = ds.wind_speed * (3600 / 1852)
    ds["wind_speed"].attrs = var_attrs("ws", "knot", "wind_speed")
    ds["turbulence_intensity"] = ds.turbulence_intensity * 100
    ds["turbulence_intensity"].attrs["units"] = "%"
    ds.to_netcdf(tmp_path / "c.nc")
    out = load_conditions(tmp_path / "c.nc")
    ref = make_conditions()
    assert out.height.values.tolist() == [40.0, 60.0, 80.0]
    assert out.wind_speed.dims == ("time", "height") and out.wind_speed.attrs["units"] == "m s-1"
    # knot -> m/s and % -> 1 are exact up to float round-off
    np.testing.assert_allclose(out.wind_speed, ref.wind_speed, rtol=1e-13)
    np.testing.assert_allclose(out.turbulence_intensity, ref.turbulence_intensity, rtol=1e-13)
    assert out.attrs["lidarcal_skipped_count"] == 0 and int(out.input_complete.sum()) == 18
    # the checksum is of content: a file and the same data as a dataset agree
    ref.to_netcdf(tmp_path / "ref.nc")
    assert (
        load_conditions(tmp_path / "ref.nc").attrs["lidarcal_conditions_checksum"]
        == load_conditions(ref).attrs["lidarcal_conditions_checksum"]
    )


def test_a_file_written_before_names_the_serial_as_lidar_serial_once_loaded(tmp_path):
    # lidar_serial is the one name; .sta-derived files written before said lidar_serial_number
    old = make_conditions().assign_attrs(lidar_serial_number="WLS7-164", lidar_site="a field")
    old.to_netcdf(tmp_path / "old.nc")
    out = load_conditions(tmp_path / "old.nc")
    assert out.attrs["lidar_serial"] == "WLS7-164" and "lidar_serial_number" not in out.attrs
    assert out.attrs["lidar_site"] == "a field"
    new = load_conditions(make_conditions().assign_attrs(lidar_serial="WLS866-001"))
    assert new.attrs["lidar_serial"] == "WLS866-001" and "lidar_serial_number" not in new.attrs


def test_wind_speed_in_kelvin_refused_naming_file_and_variable(tmp_path):
    ds = make_conditions()
    ds.wind_speed.attrs["units"] = "K"
    ds.to_netcdf(tmp_path / "bad.nc")
    with pytest.raises(UnitError, match=r"bad\.nc: variable 'wind_speed' has units 'K'.*expected.*'m s-1'"):
        load_conditions(tmp_path / "bad.nc")


def test_missing_variable_named(tmp_path):
    ds = make_conditions().drop_vars("cnr_gradient")
    ds.to_netcdf(tmp_path / "m.nc")
    with pytest.raises(MissingVariableError, match=r"m\.nc: required variable\(s\) \['cnr_gradient'\]"):
        load_conditions(tmp_path / "m.nc")
    with pytest.raises(MissingVariableError, match="lidar_wind_speed"):
        load_conditions(make_conditions(), kind="field_campaign")


def test_negative_wind_speed_refused_with_count_and_first_location():
    ds = make_conditions()
    ds.wind_speed[2, 1] = -1.0
    ds.wind_speed[4, 0] = -0.5
    with pytest.raises(InputError, match=r"'wind_speed' has 2 value\(s\) outside \[0, 80\].*first -1 m s-1 "
                       r"at .*index 2\), height=60 m"):
        load_conditions(ds)


def test_turbulence_intensity_above_one_refused():
    ds = make_conditions()
    ds.turbulence_intensity[3, 2] = 12.0  # percent written with units "1"
    with pytest.raises(
        InputError, match=r"turbulence_intensity' has 1 value\(s\) outside \[0, 1\].*height=80 m"
    ):
        load_conditions(ds)


def test_nan_periods_are_skipped_and_reported_not_fatal():
    ds = make_conditions()
    ds.cnr[1, 0] = np.nan
    ds.wind_speed[4, :] = np.nan
    with pytest.warns(SkippedPeriodsWarning, match=r"4 \(period, height\) value\(s\) in 2 period\(s\)"):
        out = load_conditions(ds)
    assert out.input_complete.values[1].tolist() == [0, 1, 1]
    assert out.input_complete.values[4].tolist() == [0, 0, 0]
    assert out.attrs["lidarcal_skipped_count"] == 4


def test_height_coordinate_checks():
    ds = make_conditions()
    ds.height.attrs["positive"] = "down"
    with pytest.raises(InputError, match="positive='down'; expected 'up'"):
        load_conditions(ds)
    ds = make_conditions().assign_coords(height=height_coord([0.0, 60.0, 80.0]))
    with pytest.raises(InputError, match="must be finite and > 0 m"):
        load_conditions(ds)
    ds = make_conditions()
    ds["height"].attrs["units"] = "ft"
    out = load_conditions(ds)
    np.testing.assert_allclose(out.height, np.array([40.0, 60.0, 80.0]) * 0.3048)


def test_field_campaign_and_lidar_from_attrs():
    ds = make_conditions()
    ds["lidar_wind_speed"] = ds.wind_speed * 1.01
    ds["reference_wind_speed"] = ds.wind_speed.copy()
    ds["reference_wind_speed"][0, 0] = np.nan
    with pytest.warns(SkippedPeriodsWarning):
        out = load_conditions(ds, kind="field_campaign")
    assert out.input_complete.values[0, 0] == 0 and out.lidar_wind_speed.attrs["units"] == "m s-1"
    # the defaults of docs/contracts.md (LidarModel's field defaults)
    assert lidar_attributes(out) == {
        "lidar_cone_angle": 28.0,
        "lidar_hybrid_weight": 2 / 3,
        "lidar_rwf_fwhm": 30.0,
        "lidar_los_noise_std": 0.1,
        "lidar_beam_period": 1.0,
    }
    out.attrs.update(lidar_cone_angle=30.0, lidar_hybrid_weight=0.5, lidar_los_noise_std=0.2)
    model = LidarModel.from_attrs(out)
    assert (model.cone_angle, model.hybrid_weight, model.los_noise_std) == (30.0, 0.5, 0.2)
    assert model.azimuths == (0.0, 90.0, 180.0, 270.0)
    # a Gaussian RWF of FWHM 30 m: node spread std = 30 / (2 sqrt(2 ln 2)) = 12.74 m
    w, s = np.asarray(model.rwf_weights), np.asarray(model.rwf_offsets)
    assert np.sqrt(np.sum(w * s**2)) == pytest.approx(30 / (2 * np.sqrt(2 * np.log(2))), rel=1e-9)
    out.attrs["lidar_hybrid_weight"] = 1.5
    with pytest.raises(InputError, match=r"'lidar_hybrid_weight'.*1\.5; expected a value in \[0, 1\]"):
        lidar_attributes(out)


# -- synthetic ---------------------------------------------------------------------------------


def test_synthetic_is_seeded_valid_and_power_law():
    z = (40, 60, 80, 100, 120, 140, 160, 200)
    a = synthetic_conditions(500, z, seed=3)
    b = synthetic_conditions(500, z, seed=3)
    c = synthetic_conditions(500, z, seed=4)
    xr.testing.assert_equal(a, b)  # same values (each artefact has its own id and creation date)
    assert a.attrs["lidarcal_artefact"] == "conditions" and a.attrs["lidarcal_seeds"] == '{"seed": 3}'
    assert not np.array_equal(a.wind_speed.values, c.wind_speed.values)
    out = load_conditions(a)
    assert out.attrs["lidarcal_skipped_count"] == 0
    # each period is an exact power law: the exponent is the same at every height
    alpha = out.wind_shear_exponent.values
    np.testing.assert_allclose(alpha, alpha[:, :1].repeat(8, axis=1), atol=1e-12)
    # sigma_u constant with height: TI * U is the same at all heights
    sig = out.turbulence_intensity.values * out.wind_speed.values
    unclipped = (out.turbulence_intensity.values > 0.0101).all(1) & (
        out.turbulence_intensity.values < 0.599
    ).all(1)
    np.testing.assert_allclose(sig[unclipped], sig[unclipped][:, :1].repeat(8, axis=1), rtol=1e-12)
    # the CNR gradient is along the 28 deg beam: cos 28 deg times the vertical difference quotient
    # of neighbouring heights, written out by hand here (40 m: 40/60, 60 m: 40/80, ...)
    cnr, zz = out.cnr.values, out.height.values
    lo = np.array([0, 0, 1, 2, 3, 4, 5, 6])
    hi = np.array([1, 2, 3, 4, 5, 6, 7, 7])
    dcdz = (cnr[:, hi] - cnr[:, lo]) / (zz[hi] - zz[lo])
    np.testing.assert_allclose(out.cnr_gradient, dcdz * np.cos(np.radians(28.0)), rtol=1e-12, atol=1e-15)
    assert out.attrs["lidarcal_synthetic_cone_angle"] == 28.0
    # median speed at the 80 m reference is near the requested 8 m/s (lognormal AR(1) with
    # sigma 0.45 over 500 correlated periods: generous 35 % band)
    assert 8 * 0.65 < float(np.median(out.wind_speed.sel(height=80))) < 8 * 1.35


def test_synthetic_extrapolates_real_sample_with_period_shear():
    base = load_conditions(sample_conditions_path(), warn=False).isel(time=slice(0, 300))
    ext = synthetic_conditions(300, (40, 80, 120, 200), seed=0, base=base)
    u = base.wind_speed.values
    np.testing.assert_allclose(ext.wind_speed.values[:, :2], u[:, [0, 2]], rtol=1e-12)
    alpha80 = base.wind_shear_exponent.values[:, 2]
    expect = u[:, 2] * (200 / 80) ** alpha80
    ok = np.isfinite(ext.wind_speed.values[:, 3])
    np.testing.assert_allclose(ext.wind_speed.values[ok, 3], expect[ok], rtol=1e-12)
    # missing stays missing, never invented
    assert np.isnan(ext.wind_speed.values[np.isnan(u[:, 2]), 2:]).all()


# -- the real sample ---------------------------------------------------------------------------


def test_real_sample_file():
    path = sample_conditions_path()
    assert path.stat().st_size < 3e6
    with pytest.warns(SkippedPeriodsWarning):
        ds = load_conditions(path)
    assert ds.sizes == {"time": 13248, "height": 3}
    assert ds.height.values.tolist() == [40.0, 60.0, 80.0]
    assert str(ds.time.values[0])[:16] == "2016-06-01T00:00"
    assert "MIT" in ds.attrs["source_data"] and "brightwind" in ds.attrs["source_data"]
    assert "rows" in ds.attrs["source_rows"]
    # summer 2016 at the demo mast: median speed 5-8 m/s, median TI 0.08-0.2, mean shear 0-0.3
    assert 5 < float(ds.wind_speed.median()) < 8
    assert 0.08 < float(ds.turbulence_intensity.median()) < 0.2
    assert 0 < float(ds.wind_shear_exponent.mean()) < 0.3
    # quality control: calm (< 1 m/s) speeds were set missing, not invented
    assert float(ds.wind_speed.min()) >= 1.0
    assert 0 < ds.attrs["lidarcal_skipped_count"] < 0.1 * ds.wind_speed.size


def test_cli_conditions_synthetic_and_check(tmp_path):
    out = tmp_path / "c.nc"
    cmd = [
        *LIDARCAL,
        "conditions",
        "synthetic",
        "-n",
        "50",
        "--heights",
        "40",
        "100",
        "200",
        "--seed",
        "2",
        "-o",
        str(out),
    ]
    subprocess.run(cmd, check=True, capture_output=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = load_conditions(out)
    xr.testing.assert_equal(ds.wind_speed, synthetic_conditions(50, (40, 100, 200), seed=2).wind_speed)
    again = subprocess.run(cmd, capture_output=True, text=True)
    assert again.returncode == 2 and "file exists" in again.stderr
    res = subprocess.run(
        [*LIDARCAL, "conditions", "check", str(out)], capture_output=True, text=True, check=True
    )
    assert "50 periods" in res.stdout and "skipped (period, height) pairs: 0" in res.stdout


def test_a_field_campaign_artefact_is_accepted_as_conditions(tmp_path):
    # `lidarcal simulate --conditions FIELD.nc`: a field campaign is a superset of conditions
    from lidarcal.diagnose import generate_field_campaign, hidden_effect_conditions
    from lidarcal.io import write_artefact

    cond = hidden_effect_conditions(8, (80.0, 120.0), 1)
    field = generate_field_campaign(cond, "none", {}, base_seed=5,
                                    execution={"scheduler": "synchronous"})
    path = write_artefact(field, tmp_path / "field.nc")
    assert field.attrs["lidarcal_artefact"] == "field_campaign"
    loaded = load_conditions(path)
    assert loaded.sizes == {"time": 8, "height": 2}
    assert load_conditions(path, kind="field_campaign").sizes == {"time": 8, "height": 2}
