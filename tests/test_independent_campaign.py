"""The independent field-campaign generator (tests/independent_campaign.py) against analytic physics.

Its campaigns test ``lidarcal diagnose`` on data the engine did not make, so its own physics is
checked here against expectations written in this file, not against lidarcal.  Campaigns with
the same seed share the atmosphere, the turbulence phases and the lidar noise, so an effect is
measured as a *paired* difference with most of the turbulence cancelled.
"""

import json

import numpy as np
import pytest
from independent_campaign import EFFECT_PARAMETERS, make_field_campaign, make_field_campaign_with_truth

from lidarcal.conditions import load_conditions

N, SEED, CONE = 40, 5, 28.0
HEIGHTS = np.array([40.0, 80.0, 120.0, 160.0])


def paired(effects):
    base = make_field_campaign({}, n_periods=N, seed=SEED)
    other, truth = make_field_campaign_with_truth(effects, n_periods=N, seed=SEED)
    return base, other, truth


def test_the_campaign_follows_the_field_campaign_contract():
    ds = make_field_campaign({}, n_periods=N, seed=SEED)
    loaded = load_conditions(ds, kind="field_campaign", warn=False)
    assert loaded.sizes == {"time": N, "height": 4}
    for name in ("lidar_wind_speed", "reference_wind_speed", "cnr_gradient"):
        assert np.isfinite(loaded[name].values).all(), name
    assert ds.attrs["lidar_cone_angle"] == CONE and json.loads(ds.attrs["independent_hidden_effects"]) == {}
    # the conditions are the mast's own measurements: the cup mean is the reported speed ...
    np.testing.assert_array_equal(ds.wind_speed.values, ds.reference_wind_speed.values)
    # ... and the lidar agrees with the cup to within the known few-tenths-of-a-percent biases
    # (cup over-reading by σ_v²/2U², RWF averaging of a concave profile): |mean| < 1.5 %,
    # period scatter < 1.5 % (10-minute turbulence sampling + 0.1 m/s LOS noise)
    d = ds.lidar_wind_speed.values / ds.reference_wind_speed.values - 1.0
    assert np.all(np.abs(d.mean(axis=0)) < 0.015) and np.all(d.std(axis=0) < 0.015), d.mean(axis=0)


def test_realised_turbulence_intensity_matches_the_request():
    ds, truth = make_field_campaign_with_truth({}, n_periods=N, seed=SEED)
    ratio = ds.turbulence_intensity.values / truth["turbulence_intensity_requested"]
    # Expected 1 − (σ_v/U)²/2 ≈ 0.99 (a cup reads the horizontal magnitude); the 10-minute
    # sampling scatter of σ is ~10-15 % per period, so the mean of 40 periods has a standard
    # error of ~2 %: 5 % is 2.5 standard errors.
    assert np.all(np.abs(ratio.mean(axis=0) - 1.0) < 0.05), ratio.mean(axis=0)
    # a measured, not a copied, quantity: per-period scatter of the ratio is real
    assert np.all(ratio.std(axis=0) > 0.02)
    # the shear is measured from the cup means: close to the true exponent (turbulence in the
    # 10-minute means spreads it by a few hundredths)
    err = ds.wind_shear_exponent.values - truth["alpha"][:, None]
    assert abs(np.mean(err)) < 0.02 and np.std(err) < 0.06


def test_zero_distance_offset_gives_the_shear_bias():
    offset = 4.0
    base, other, truth = paired({"zero_distance_offset": {"offset": offset}})
    change = other.lidar_wind_speed.values / base.lidar_wind_speed.values - 1.0
    expected = truth["alpha"][:, None] * offset * np.cos(np.radians(CONE)) / HEIGHTS[None, :]
    # regression through the origin of the paired change on α·δz·cos φ/h: slope 1 to first
    # order; the power law's second order lowers it by (1 − α)/2·δz·cos φ/h ≈ 4 % at 40 m;
    # ±12 % covers that and the turbulence the moved gates see (paired, so small)
    slope = np.sum(change * expected) / np.sum(expected**2)
    assert 0.88 < slope < 1.08, slope
    # and it falls with height as 1/h
    assert change[:, 0].mean() > 2.5 * change[:, 3].mean() > 0


def test_beam_angle_offset_gives_cot_phi_times_the_offset():
    offset = 0.5
    base, other, truth = paired({"beam_angle_offset": {"offset": offset}})
    change = other.lidar_wind_speed.values / base.lidar_wind_speed.values - 1.0
    d = np.radians(offset)
    phi = np.radians(CONE)
    expected = d / np.tan(phi) - truth["alpha"][:, None] * np.tan(phi) * d  # ≈ 1.6 %
    # every height alike; 3 % of the effect covers second order (δφ²) and the turbulence
    # at the displaced gates (paired)
    np.testing.assert_allclose(change.mean(axis=0), np.full(4, expected.mean()), rtol=0.03)


def test_reference_gain_scales_the_reference_exactly():
    gain = 0.02
    base, other, _ = paired({"reference_gain": {"gain": gain}})
    # same turbulence, same cup series times (1 + gain): only rounding differs
    np.testing.assert_allclose(other.reference_wind_speed.values,
                               (1 + gain) * base.reference_wind_speed.values, rtol=1e-12)
    np.testing.assert_array_equal(other.lidar_wind_speed.values, base.lidar_wind_speed.values)
    for name in ("turbulence_intensity", "wind_shear_exponent", "wind_from_direction"):
        np.testing.assert_allclose(other[name].values, base[name].values, rtol=1e-9, atol=1e-12, err_msg=name)


def test_reference_flow_distortion_shadows_a_sector():
    fd = {"centre": 250.0, "width": 60.0, "deficit": 0.05}
    base, other, _ = paired({"reference_flow_distortion": fd})
    ratio = other.reference_wind_speed.values / base.reference_wind_speed.values
    off = np.abs((base.wind_from_direction.values - fd["centre"] + 180) % 360 - 180)
    deep, far = off < fd["width"] / 2 - 15, off > fd["width"] / 2 + 30
    assert deep.sum() >= 4 and far.sum() >= 40, (deep.sum(), far.sum())
    # deep inside, 15° from the edge (> 2 σ of the 1 Hz direction at TI ≈ 0.15), nearly every
    # sample is shadowed; far outside none is
    assert np.all(np.abs(ratio[deep] - (1 - fd["deficit"])) < 0.1 * fd["deficit"])
    assert np.all(np.abs(ratio[far] - 1) < 0.01 * fd["deficit"])
    np.testing.assert_array_equal(other.lidar_wind_speed.values, base.lidar_wind_speed.values)


def test_lidar_sector_error_is_outside_the_catalogue_and_acts_on_the_lidar_only():
    se = {"centre": 300.0, "width": 40.0, "error": 0.02}
    base, other, _ = paired({"lidar_sector_error": se})
    ratio = other.lidar_wind_speed.values / base.lidar_wind_speed.values
    inside = np.abs((base.wind_from_direction.values - se["centre"] + 180) % 360 - 180) <= se["width"] / 2
    assert inside.any() and (~inside).any()
    np.testing.assert_allclose(ratio[inside], 1 + se["error"], rtol=1e-12)
    np.testing.assert_allclose(ratio[~inside], 1.0, rtol=1e-12)
    np.testing.assert_array_equal(other.reference_wind_speed.values, base.reference_wind_speed.values)


def test_lidar_low_cnr_bias_acts_below_the_threshold_only():
    lc = {"threshold": -12.0, "error": 0.02}
    base, other, _ = paired({"lidar_low_cnr_bias": lc})
    ratio = other.lidar_wind_speed.values / base.lidar_wind_speed.values
    low = base.cnr.values < lc["threshold"]
    # the CNR model puts about a quarter of the (period, height) pairs below -12 dB
    assert 0.1 < low.mean() < 0.6, low.mean()
    np.testing.assert_allclose(ratio[low], 1 + lc["error"], rtol=1e-12)
    np.testing.assert_allclose(ratio[~low], 1.0, rtol=1e-12)
    np.testing.assert_array_equal(other.reference_wind_speed.values, base.reference_wind_speed.values)


@pytest.mark.parametrize("effects,match", [({"bogus": {}}, "unknown effect"),
                                           ({"reference_gain": {"g": 0.1}}, "needs parameters")])
def test_bad_effects_are_refused(effects, match):
    with pytest.raises(ValueError, match=match):
        make_field_campaign(effects, n_periods=2, seed=1)
    assert "reference_flow_distortion" in EFFECT_PARAMETERS and "lidar_sector_error" in EFFECT_PARAMETERS
