"""Physics tests of the virtual DBS lidar and the virtual reference (lidarcal.lidar)."""

import json

import numpy as np
import pytest
import xarray as xr
from scipy.integrate import quad

from lidarcal.errors import InputError, UnitError
from lidarcal.lidar import LidarModel, NoiseTable, simulate_period
from lidarcal.lidar.quadrature import gaussian_rwf_sigma

PHI = np.radians(28.0)
CALM = dict(turbulence_intensity=0.0, wind_shear_exponent=0.0, cnr=-15.0, cnr_gradient=0.0)


def run(model, heights=(100.0,), **kw):
    args = dict(wind_speed=10.0, wind_from_direction=0.0, seed=(7, 3), **CALM)
    args.update(kw)
    return simulate_period(model, heights=np.asarray(heights, float), **args)


def make_cube(bias=0.0, std=0.0, nan_bins=()):
    """A small bench_cube Dataset with the CONTRIBUTING.md names; bias may be per LOS (5,)."""
    cnr = np.arange(-28.0, -4.0, 2.0)
    vel = np.arange(-18.0, 19.0, 1.0)
    shape = (5, cnr.size, vel.size)
    b = np.broadcast_to(np.asarray(bias, float).reshape(-1, 1, 1) if np.ndim(bias) else bias, shape).copy()
    s = np.full(shape, float(std))
    for idx in nan_bins:
        b[idx] = np.nan
        s[idx] = np.nan
    return xr.Dataset(
        {"los_bias": (("los", "cnr", "velocity"), b, {"units": "m s-1"}),
         "los_std": (("los", "cnr", "velocity"), s, {"units": "m s-1"}),
         "sample_count": (("los", "cnr", "velocity"), np.full(shape, 500, np.int32), {"units": "1"})},
        coords={"los": ["0", "90", "180", "270", "V"],
                "los_azimuth": ("los", [0.0, 90.0, 180.0, 270.0, 0.0], {"units": "degree"}),
                "los_elevation": ("los", [62.0, 62.0, 62.0, 62.0, 90.0], {"units": "degree"}),
                "cnr": ("cnr", cnr, {"units": "dB"}), "velocity": ("velocity", vel, {"units": "m s-1"})},
        attrs={"lidarcal_artefact": "bench_cube", "lidarcal_source_file": "cube.nc"},
    )


def make_rwf(sigma_left=12.0, sigma_right=12.0):
    s = np.linspace(-120.0, 120.0, 2401)
    g = np.where(s < 0, np.exp(-0.5 * (s / sigma_left) ** 2), np.exp(-0.5 * (s / sigma_right) ** 2))
    grads = np.array([-0.1, 0.0, 0.1])
    table = g[:, None] * 10 ** (grads[None, :] * s[:, None] / 20)
    table /= np.trapezoid(table, s, axis=0)
    return xr.Dataset({"rwf": (("range_offset", "cnr_gradient"), table, {"units": "m-1"}),
                       "zero_distance": ((), 0.0, {"units": "m"})},
                      coords={"range_offset": ("range_offset", s, {"units": "m"}),
                              "cnr_gradient": ("cnr_gradient", grads, {"units": "dB m-1"})},
                      attrs={"lidarcal_artefact": "rwf", "lidarcal_source_file": "rwf.nc"})


def test_calm_uniform_noiseless_lidar_equals_reference():
    out = run(LidarModel.ideal(los_noise_std=0.0), heights=(40.0, 100.0, 200.0), wind_from_direction=33.0)
    # no turbulence, shear or noise: every LOS is exact, only rounding remains
    np.testing.assert_allclose(out["lidar_wind_speed"], 10.0, atol=1e-12, rtol=0)
    ref = out["reference_wind_speed"]
    np.testing.assert_allclose(out["lidar_wind_speed_scalar"], ref, atol=1e-12, rtol=0)
    np.testing.assert_allclose(out["lidar_wind_speed_vector"], ref, atol=1e-12, rtol=0)
    np.testing.assert_array_equal(out["availability"], 1.0)


@pytest.mark.parametrize(("height", "alpha"), [(100.0, 0.2), (40.0, 0.3), (60.0, 0.14)])
def test_shear_bias_equals_rwf_average_of_power_law(height, alpha):
    out = run(LidarModel.ideal(los_noise_std=0.0), heights=(height,), wind_shear_exponent=alpha,
              wind_from_direction=250.0)
    # independent prediction: Gaussian RWF (FWHM 30 m) averaging of U (z/h)^alpha along the beam,
    # z = (R + s) cos(phi), integrated adaptively (not with the simulator's quadrature nodes)
    sig, rng = gaussian_rwf_sigma(30.0), height / np.cos(PHI)
    pdf = lambda s: np.exp(-0.5 * (s / sig) ** 2) / (np.sqrt(2 * np.pi) * sig)  # noqa: E731
    mean = quad(lambda s: pdf(s) * ((rng + s) / rng) ** alpha, -rng + 1e-9, 12 * sig,
                epsabs=1e-13, limit=200)[0]
    predicted = 10.0 * (mean - 1.0)
    assert abs(predicted) > 0.005  # the effect is real: several mm/s to 10 cm/s
    # 5 Gauss nodes reproduce the RWF average to < 1 mm/s (quadrature contract)
    assert out["lidar_wind_speed"][0] - out["reference_wind_speed"][0] == pytest.approx(predicted, abs=1e-3)


def test_cone_angle_error_bias_first_order():
    delta = 1.0
    out = run(LidarModel.ideal(los_noise_std=0.0, beam_angle_offset=delta))
    rel = out["lidar_wind_speed"][0] / out["reference_wind_speed"][0] - 1
    # exact: sin(phi + d) / sin(phi) - 1 (true cone wider than the reconstruction assumes -> over-reads)
    assert rel == pytest.approx(np.sin(PHI + np.radians(delta)) / np.sin(PHI) - 1, abs=1e-12)
    # first order U cot(phi) dphi (Eq. 9), positive for a positive offset; second-order term
    # -dphi^2/2 = -1.5e-4 bounds the difference
    assert rel == pytest.approx(np.radians(delta) / np.tan(PHI), abs=2e-4)
    # with shear the gate also drops by h tan(phi) dphi: (cot(phi) - alpha tan(phi)) dphi
    base = run(LidarModel.ideal(los_noise_std=0.0), wind_shear_exponent=0.2)
    tilted = run(LidarModel.ideal(los_noise_std=0.0, beam_angle_offset=delta), wind_shear_exponent=0.2)
    rel = tilted["lidar_wind_speed"][0] / base["lidar_wind_speed"][0] - 1
    assert rel == pytest.approx((1 / np.tan(PHI) - 0.2 * np.tan(PHI)) * np.radians(delta), abs=3e-4)


@pytest.mark.parametrize("height", [60.0, 100.0])
def test_zero_distance_offset_follows_eq11(height):
    alpha, dz = 0.2, 2.0
    base = run(LidarModel.ideal(los_noise_std=0.0), heights=(height,), wind_shear_exponent=alpha)
    moved = run(LidarModel.ideal(los_noise_std=0.0, zero_distance_offset=dz), heights=(height,),
                wind_shear_exponent=alpha)
    rel = moved["lidar_wind_speed"][0] / base["lidar_wind_speed"][0] - 1
    # Eq. 11 with the height shift dz cos(phi): alpha dz cos(phi) / h.  Eq. 11 is for a point; the
    # RWF averages z^(alpha-1) over sigma_z = sigma cos(phi), which changes the slope by
    # (1-alpha)(2-alpha)/2 (sigma_z/h)^2 (3.3 % at 60 m, 1.2 % at 100 m): relative tolerance 1.2x that
    sigma_z = gaussian_rwf_sigma(30.0) * np.cos(PHI)
    tol = 1.2 * (1 - alpha) * (2 - alpha) / 2 * (sigma_z / height) ** 2
    assert rel == pytest.approx(alpha * dz * np.cos(PHI) / height, rel=tol)
    # the reference does not move
    assert moved["reference_wind_speed"][0] == base["reference_wind_speed"][0]


def test_hybrid_between_vector_and_scalar():
    model = LidarModel.ideal(hybrid_weight=2 / 3)
    out = run(model, heights=(40.0, 80.0, 140.0), turbulence_intensity=0.15, wind_shear_exponent=0.2)
    s, v, h = out["lidar_wind_speed_scalar"], out["lidar_wind_speed_vector"], out["lidar_wind_speed"]
    assert np.all(v < s)  # turbulence spreads the direction: |mean vector| < mean |vector|
    assert np.all((v <= h) & (h <= s))
    np.testing.assert_allclose(h, 2 / 3 * s + 1 / 3 * v, rtol=1e-14)  # p multiplies the scalar mean


def test_constant_los_bias_cancels_and_single_beam_bias_shifts_u():
    b = 0.2
    clean = run(LidarModel.from_artefacts(cube=make_cube(0.0), cnr_weighting_scale=0.0))
    everywhere = run(LidarModel.from_artefacts(cube=make_cube(b)))
    # the same bias on all beams cancels in S1 - S3 and S2 - S4 (to rounding)
    np.testing.assert_allclose(everywhere["lidar_wind_speed"], clean["lidar_wind_speed"], atol=1e-12)
    one = run(LidarModel.from_artefacts(cube=make_cube([b, 0, 0, 0, 0])), wind_from_direction=180.0)
    # wind from the south blows toward azimuth 0: u (toward 0 deg) shifts by b / (2 sin phi)
    assert one["lidar_wind_speed"][0] == pytest.approx(10.0 + b / (2 * np.sin(PHI)), abs=1e-12)
    cross = run(LidarModel.from_artefacts(cube=make_cube([b, 0, 0, 0, 0])), wind_from_direction=270.0)
    assert cross["lidar_wind_speed"][0] == pytest.approx(np.hypot(10.0, b / (2 * np.sin(PHI))), abs=1e-12)


def test_cube_noise_std_propagates_to_los():
    out = run(LidarModel.from_artefacts(cube=make_cube(0.05, 0.3)), return_los=True, heights=(100.0,))
    los, beam = out["los"][0], out["los_beam"]
    # wind from 0 deg blows toward 180 deg: v_r = -U sin(phi) cos(azimuth), positive away from the lidar
    expected = np.array([-10.0 * np.sin(PHI) * np.cos(np.radians(a)) for a in (0, 90, 180, 270)])[beam]
    resid = los - expected  # calm uniform wind: the only error is the bench noise
    # 600 draws: mean within 4 * 0.3 / sqrt(600) = 0.049, std within 4 * 0.3 / sqrt(1200) = 0.035
    assert resid.mean() == pytest.approx(0.05, abs=0.049)
    assert resid.std(ddof=1) == pytest.approx(0.3, abs=0.035)


def test_noise_table_lookup_bilinear_clamped_and_nan_filled():
    cube = make_cube(0.0, 0.1, nan_bins=[(1, 3, 10), (1, 4, 10)])
    vel = cube.velocity.values
    cube["los_bias"][:] = (0.01 * vel)[None, None, :] + 0.001 * cube.cnr.values[None, :, None]
    cube["los_bias"][1, 3, 10] = np.nan
    table = LidarModel.from_artefacts(cube=cube).noise_table
    bias, std = table.lookup(0, -15.0, np.array([-30.0, 0.5, 30.0]))
    # linear in velocity between centres, clamped to the +/-18 m/s edge bins; linear in CNR
    np.testing.assert_allclose(bias, [-0.18 - 0.015, 0.005 - 0.015, 0.18 - 0.015], atol=1e-12)
    np.testing.assert_allclose(std, 0.1)
    # the empty bins of beam 90 take the nearest populated bin's values: no NaN anywhere
    assert np.all(np.isfinite(np.asarray(table.bias))) and np.all(np.isfinite(np.asarray(table.std)))


def test_seed_reproducible_and_heights_independent():
    model = LidarModel.ideal()
    kw = dict(wind_speed=[7.0, 9.0, 11.0], turbulence_intensity=0.12, wind_shear_exponent=0.15,
              wind_from_direction=[10.0, 20.0, 30.0], seed=(5, 11))
    a = run(model, heights=(60.0, 100.0, 160.0), **kw)
    b = run(model, heights=(60.0, 100.0, 160.0), **kw)
    alone = run(model, heights=(100.0,), **{**kw, "wind_speed": 9.0, "wind_from_direction": 20.0})
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])  # bit-identical
        assert a[name][1] == alone[name][0]
    other = run(model, heights=(100.0,),
                **{**kw, "wind_speed": 9.0, "wind_from_direction": 20.0, "seed": (5, 12)})
    assert other["lidar_wind_speed"][0] != alone["lidar_wind_speed"][0]


def test_availability_drops_samples_and_nan_conditions_give_nan():
    out = run(LidarModel.ideal(availability=0.5), heights=(80.0, 120.0), wind_speed=[8.0, np.nan],
              turbulence_intensity=0.1)
    # binomial(600, 0.5): 4 sigma = 0.082
    assert out["availability"][0] == pytest.approx(0.5, abs=0.082)
    assert np.isfinite(out["lidar_wind_speed"][0])
    assert all(np.isnan(out[name][1]) for name in out)


def test_reference_overspeeding_scales_reference():
    base = run(LidarModel.ideal(), turbulence_intensity=0.1)
    over = run(LidarModel.ideal(reference_overspeeding=0.05), turbulence_intensity=0.1)
    ref = base["reference_wind_speed"][0]
    assert over["reference_wind_speed"][0] == pytest.approx(ref * 1.005, rel=1e-14)
    assert over["lidar_wind_speed"][0] == base["lidar_wind_speed"][0]


def test_reference_gain_and_mast_shadow_scale_the_reference():
    base = run(LidarModel.ideal(), turbulence_intensity=0.1, wind_from_direction=250.0)
    gain = run(LidarModel.ideal(reference_gain=0.02), turbulence_intensity=0.1, wind_from_direction=250.0)
    ref = base["reference_wind_speed"][0]
    assert gain["reference_wind_speed"][0] == pytest.approx(ref * 1.02, rel=1e-14)
    # a 60-degree shadow of 5 % centred 20 degrees from the period's direction, TI 0.1: the
    # instantaneous direction is Gaussian with sigma = 0.8 x 0.1 rad = 4.58 degrees, so the
    # shadowed fraction is P(-50 < theta' < 10 degrees), integrated here by brute force
    shadow = LidarModel.ideal(reference_flow_distortion_centre=270.0, reference_flow_distortion_width=60.0,
                              reference_flow_distortion_deficit=0.05)
    out = run(shadow, turbulence_intensity=0.1, wind_from_direction=250.0)
    sigma = np.degrees(0.08)
    frac = quad(lambda x: np.exp(-0.5 * (x / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi)), -50.0, 10.0)[0]
    assert 0.98 < frac < 0.99
    assert out["reference_wind_speed"][0] == pytest.approx(ref * (1 - 0.05 * frac), rel=1e-9)
    assert out["lidar_wind_speed"][0] == base["lidar_wind_speed"][0]
    # far outside the sector (100 degrees from its centre) the cup is not shadowed
    far = run(shadow, turbulence_intensity=0.1, wind_from_direction=170.0)
    plain = run(LidarModel.ideal(), turbulence_intensity=0.1, wind_from_direction=170.0)
    assert far["reference_wind_speed"][0] == pytest.approx(plain["reference_wind_speed"][0], rel=1e-12)


def test_cnr_gradient_weighting_shifts_speed_under_shear():
    alpha, g, h = 0.2, 0.1, 100.0
    off = run(LidarModel.ideal(los_noise_std=0.0), wind_shear_exponent=alpha, cnr_gradient=g)
    on = run(LidarModel.ideal(los_noise_std=0.0, cnr_weighting_scale=1.0), wind_shear_exponent=alpha,
             cnr_gradient=g)
    # Eq. 2 tilts a Gaussian RWF: its centroid moves by sigma^2 * ln(10) g / 20 along the beam,
    # i.e. the height by that times cos(phi); first order alpha * dz / h (Eq. 11)
    shift = gaussian_rwf_sigma(30.0) ** 2 * np.log(10) * g / 20 * np.cos(PHI)
    rel = on["lidar_wind_speed"][0] / off["lidar_wind_speed"][0] - 1
    assert rel == pytest.approx(alpha * shift / h, rel=0.02)  # curvature of z^alpha: ~1 %


def test_from_artefacts_rwf_nodes_and_units():
    model = LidarModel.from_artefacts(rwf=make_rwf(12.0, 12.0))
    sig = 12.0
    x, w = np.polynomial.hermite.hermgauss(5)
    np.testing.assert_allclose(model.rwf_offsets, np.sqrt(2) * sig * x, atol=1e-6)  # tabulated Gaussian
    np.testing.assert_allclose(model.rwf_weights, w / np.sqrt(np.pi), atol=1e-8)
    assert model.cnr_weighting_scale == 1.0  # a bench RWF is CNR-weighted by default (Eq. 2)
    # the lidar applies its zero distance (the barycentre, 6*sqrt(2/pi) m for these half-widths),
    # so the nodes are re-centred on it; the asymmetry stays in the third moment
    skewed = make_rwf(10.0, 16.0)
    skewed["zero_distance"] = ((), 6 * np.sqrt(2 / np.pi), {"units": "m"})
    skew = LidarModel.from_artefacts(rwf=skewed)
    assert np.dot(skew.rwf_offsets, skew.rwf_weights) == pytest.approx(0.0, abs=1e-6)
    assert np.dot(np.asarray(skew.rwf_offsets) ** 3, skew.rwf_weights) > 100.0
    shifted = make_rwf(10.0, 16.0)
    shifted["zero_distance"] = ((), 6 * np.sqrt(2 / np.pi) - 0.5, {"units": "m"})
    moved = LidarModel.from_artefacts(rwf=shifted)  # a recorded Zd 0.5 m short of the barycentre
    assert np.dot(moved.rwf_offsets, moved.rwf_weights) == pytest.approx(0.5, rel=1e-3)
    bad = make_rwf()
    bad["range_offset"].attrs["units"] = "s"
    with pytest.raises(UnitError, match=r"rwf.nc: variable 'range_offset' has units 's'"):
        LidarModel.from_artefacts(rwf=bad)
    cube = make_cube().drop_sel(los="90")
    with pytest.raises(InputError, match="cube.nc.*los_azimuth.*90"):
        LidarModel.from_artefacts(cube=cube)


def test_model_roundtrip_json():
    cube, rwf = make_cube(0.01, 0.1), make_rwf(10, 14)
    model = LidarModel.from_artefacts(cube=cube, rwf=rwf, hybrid_weight=0.5, beam_angle_offset=0.3)
    text = json.dumps(model.to_dict())
    back = LidarModel.from_dict(json.loads(text), cube=cube, rwf=rwf)
    assert back == model and isinstance(back.noise_table, NoiseTable)
    assert LidarModel.from_dict(model.to_json(), cube=cube, rwf=rwf) == model
    # the full form (what workers get) needs nothing else
    assert LidarModel.from_dict(json.loads(json.dumps(model.to_dict(residuals=True)))) == model
    with pytest.raises(InputError, match="unknown field"):
        LidarModel.from_dict({"cone": 28})


def test_model_record_holds_bench_data_by_digest():
    """The attribute form names the cube's table and the RWF profile by SHA-256, computed here."""
    import hashlib

    cube, rwf = make_cube(np.array([0.01, 0.02, 0.03, 0.04, 0.0]), 0.1), make_rwf(10, 14)
    model = LidarModel.from_artefacts(cube=cube, rwf=rwf)
    record = json.loads(model.to_json())
    table = record["noise_table"]
    assert sorted(table) == ["cnr", "table_sha256", "velocity"]
    rows = cube.los_bias.values[:4], cube.los_std.values[:4]  # the four oblique beams, bins already sorted
    expected = hashlib.sha256(np.ascontiguousarray(rows[0], "<f8").tobytes()
                              + np.ascontiguousarray(rows[1], "<f8").tobytes()).hexdigest()
    assert table["table_sha256"] == expected
    prof = np.asarray(model.rwf_profile, dtype="<f8")
    assert record["rwf_profile"] == {"sha256": hashlib.sha256(prof.tobytes()).hexdigest(),
                                     "count": prof.shape[1]}
    assert len(model.to_json()) < 4000 and len(json.dumps(model.to_dict(residuals=True))) > 20_000
    # without the artefacts the model is rebuilt but refuses to simulate or travel: never a silent default
    bare = LidarModel.from_dict(model.to_json(), source="sim.nc: global attribute 'lidarcal_lidar_model'")
    assert bare.noise_table.needs_table and bare != model
    with pytest.raises(InputError, match=r"sim\.nc: .* records the RWF profile only by digest: no RWF given; "
                                         r"pass the RWF artefact the model was built from \(--rwf\)"):
        run(bare)
    with pytest.raises(InputError, match=r"records the bench noise table \(los_bias, los_std\) only by dig"):
        run(bare.with_rwf(rwf))
    with pytest.raises(InputError, match="only by digest"):
        bare.with_rwf(rwf).to_dict(residuals=True)
    # the right artefacts restore it bit for bit; wrong ones are refused naming both digests
    assert bare.with_rwf(rwf).with_residuals(cube) == model
    np.testing.assert_array_equal(run(bare.with_rwf(rwf).with_residuals(cube))["lidar_wind_speed"],
                                  run(model)["lidar_wind_speed"])
    with pytest.raises(InputError, match=f"the RWF rwf.nc is not the one the model was built from: .*"
                                         f"expected sha256 {record['rwf_profile']['sha256']}"):
        bare.with_rwf(make_rwf(10, 15))
    with pytest.raises(InputError, match=f"the bench cube cube.nc is not the one the model was built from: "
                                         f"its noise table .*expected sha256 {table['table_sha256']}"):
        bare.with_residuals(make_cube(0.02, 0.1))


def test_model_records_written_before_digests_still_read():
    """A record of the earlier form (bias, std and the RWF profile inline) reads without artefacts."""
    cube, rwf = make_cube(0.01, 0.1), make_rwf(10, 14)
    model = LidarModel.from_artefacts(cube=cube, rwf=rwf)
    old = model.to_dict(residuals=True)
    del old["noise_table"]["table_sha256"]  # the earlier form had the values and no digest
    back = LidarModel.from_dict(json.dumps(old))
    assert back == model and not back.noise_table.needs_table
    assert json.loads(back.to_json()) == json.loads(model.to_json())  # re-recorded in the digest form


def test_bad_inputs_raise_named_errors():
    with pytest.raises(InputError, match="'wind_speed' must be > 0"):
        run(LidarModel.ideal(), wind_speed=0.0)
    with pytest.raises(InputError, match="'cnr' has shape"):
        run(LidarModel.ideal(), heights=(60.0, 80.0), cnr=[-10.0, -12.0, -14.0])
    with pytest.raises(InputError, match="heights"):
        run(LidarModel.ideal(), heights=(-5.0,))
    with pytest.raises(InputError, match="availability"):
        LidarModel.ideal(availability=0.0)
    with pytest.raises(InputError, match="below the ground"):
        run(LidarModel.ideal(n_nodes=7), heights=(40.0,))


def test_turbulent_reference_and_vector_mean_over_periods():
    ti, U, n = 0.15, 10.0, 40
    model = LidarModel.ideal(los_noise_std=0.0)
    res = [run(model, heights=(100.0,), wind_speed=U, turbulence_intensity=ti, wind_from_direction=25.0,
               seed=(11, i)) for i in range(n)]
    ref = np.array([r["reference_wind_speed"][0] for r in res]) / U - 1
    vec = np.array([r["lidar_wind_speed_vector"][0] for r in res]) / U - 1
    # a cup averages |(U+u, v)|; u averages to 0 in each period, so to second order the excess is
    # sigma_v^2 / (2 U^2) = 0.32 TI^2 = 0.0072; tolerance 4 standard errors of the 40-period mean
    assert ref.mean() == pytest.approx(0.32 * ti**2, abs=4 * ref.std(ddof=1) / np.sqrt(n))
    assert 4 * ref.std(ddof=1) / np.sqrt(n) < 0.2 * 0.32 * ti**2  # resolves the effect to 20 %
    # the vector mean of a DBS lidar in homogeneous turbulence (no shear) is unbiased: 4 SE
    assert vec.mean() == pytest.approx(0.0, abs=4 * vec.std(ddof=1) / np.sqrt(n))
    assert vec.std(ddof=1) < 0.02


def test_cnr_filter_of_a_bench_calibrated_lidar():
    from lidarcal.lidar import DEFAULT_CNR_THRESHOLD

    model = LidarModel.from_artefacts(cube=make_cube(0.0, 0.05))
    assert model.cnr_threshold == DEFAULT_CNR_THRESHOLD == -23.0
    # one height above, one below the filter: the low-CNR one is unavailable, not simulated
    out = run(model, heights=(80.0, 120.0), cnr=np.array([-15.0, -25.0]))
    assert np.isfinite(out["lidar_wind_speed"][0]) and out["availability"][0] == 1.0
    assert np.isnan(out["lidar_wind_speed"][1]) and np.isnan(out["reference_wind_speed"][1])
    assert out["availability"][1] == 0.0
    # the height above the filter is unaffected by the other one (its own seed stream)
    alone = run(model, heights=(80.0,), cnr=-15.0)
    assert out["lidar_wind_speed"][0] == alone["lidar_wind_speed"][0]
    everything = run(model.replace(cnr_threshold=None), heights=(120.0,), cnr=-25.0)
    assert np.isfinite(everything["lidar_wind_speed"][0])
    assert LidarModel.ideal().cnr_threshold is None  # the ideal lidar (docs/contracts.md) keeps every period
    with pytest.raises(InputError, match="cnr_threshold"):
        LidarModel.ideal(cnr_threshold=float("nan"))
