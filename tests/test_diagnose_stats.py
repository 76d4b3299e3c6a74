"""Pure-maths tests of the diagnose statistics and fitting kernels (no engine involved)."""

import numpy as np
import pytest

from lidarcal.diagnose import fit, stats


def rng(*key):
    return np.random.default_rng(np.random.SeedSequence([4242, *key]))


def drivers_for(g, n, m):
    return {
        "wind_speed": g.uniform(4, 16, (n, m)),
        "turbulence_intensity": g.uniform(0.04, 0.25, (n, m)),
        "wind_shear_exponent": g.uniform(-0.05, 0.4, (n, m)),
        "cnr_gradient": g.normal(0, 0.04, (n, m)),
    }


def test_holm_matches_hand_computation():
    # sorted p = 0.01, 0.02, 0.04 (m = 3) -> 0.03, 0.04, 0.04 (monotone), NaN kept
    p = np.array([0.04, 0.01, np.nan, 0.02])
    np.testing.assert_allclose(stats.holm(p), [0.04, 0.03, np.nan, 0.04])


def test_relative_difference_masks_bad_reference():
    d = stats.relative_difference([10.5, 3.0, 1.0], [10.0, 0.0, np.nan])
    assert d[0] == pytest.approx(0.05) and np.isnan(d[1]) and np.isnan(d[2])


def test_binned_means_against_direct_computation():
    g = rng(1)
    x, r = g.uniform(0, 1, 200), g.normal(0, 1, 200)
    edges = stats.bin_edges(x, 4)
    count, mean, se, xm = stats.binned_means(r, x, edges)
    assert count.sum() == 200  # every finite value lands in one bin, the maximum included
    sel = (x >= edges[1]) & (x < edges[2])
    assert mean[1] == pytest.approx(r[sel].mean())
    assert se[1] == pytest.approx(r[sel].std(ddof=1) / np.sqrt(sel.sum()))
    assert xm[1] == pytest.approx(x[sel].mean())


def test_no_false_alarm_rate_above_alpha_on_null_residuals():
    # 200 campaigns of pure noise, 300 periods x 4 heights, heights correlated within a period
    # (rho = 0.5) like a shared turbulence box; heavy-ish tails (t with 6 dof).
    alpha, reps, alarms = 0.05, 200, 0
    for k in range(reps):
        g = rng(2, k)
        n, m = 300, 4
        common = g.standard_t(6, (n, 1))
        r = 0.01 * (np.sqrt(0.5) * common + np.sqrt(0.5) * g.standard_t(6, (n, m)))
        binned = stats.bin_residuals(r, drivers_for(g, n, m), n_bins=6)
        alarms += bool(np.nanmin(stats.disagreement_tests(binned)["p_adjusted"]) < alpha)
    # binomial: the alarm rate must not exceed alpha + 3 sigma = 0.05 + 3*sqrt(.05*.95/200) = 0.096
    assert alarms / reps <= alpha + 3 * np.sqrt(alpha * (1 - alpha) / reps)


def test_disagreement_found_for_a_trend_in_one_variable():
    g = rng(3)
    n, m = 300, 3
    drv = drivers_for(g, n, m)
    # -0.08 x TI: 0.3 % across the TI range against 1 % noise per period
    r = g.normal(0, 0.01, (n, m)) - 0.08 * (drv["turbulence_intensity"] - 0.145)
    tests = stats.disagreement_tests(stats.bin_residuals(r, drv))
    i = list(drv).index("turbulence_intensity")
    assert np.all(tests["p_adjusted"][i] < 1e-3)


def test_gap_of_a_constant_bias_and_its_noise_floor():
    g = rng(4)
    n, m = 600, 2
    drv = drivers_for(g, n, m)
    r = 0.02 + g.normal(0, 0.01, (n, m))
    binned = stats.bin_residuals(r, drv, n_bins=5)
    overall, per_height, floor = stats.gap(binned)
    # every bin mean is 2 % +- 0.01/sqrt(120) = 0.09 %: rms within 0.3 % (3 sigma) of 2 %
    assert overall == pytest.approx(2.0, abs=0.3)
    assert per_height.shape == (2,) and np.allclose(per_height, 2.0, atol=0.3)
    assert floor == pytest.approx(100 * 0.01 / np.sqrt(120), rel=0.15)  # se of a 120-period bin


def test_smooth_response_recovers_a_quadratic_in_the_drivers():
    g = rng(5)
    n, m = 200, 2
    drv = drivers_for(g, n, m)
    truth = 0.3 * drv["wind_shear_exponent"] - 2.0 * drv["wind_shear_exponent"] * drv["cnr_gradient"]
    valid = np.ones((n, m), bool)
    out = fit.smooth_response(truth + 0.0, drv, ("wind_shear_exponent", "cnr_gradient"), valid)
    np.testing.assert_allclose(out, truth, atol=1e-10)  # exact: truth lies in the feature space


def test_design_effect_of_perfectly_and_un_correlated_heights():
    g = rng(6)
    w = np.ones((500, 4))
    same = np.repeat(g.normal(size=(500, 1)), 4, axis=1)
    assert fit.design_effect(same, w) == pytest.approx(4.0, rel=0.02)
    # independent heights: rho ~ 0 +- 1/sqrt(500*6) -> deff within 1 + 3*0.018*3
    assert fit.design_effect(g.normal(size=(500, 4)), w) < 1.17


def test_fit_linear_recovers_parameter_and_honest_stderr():
    # coverage of the cluster-robust standard error with correlated heights
    inside, reps = 0, 200
    for k in range(reps):
        g = rng(7, k)
        n, m = 250, 3
        J = 0.01 * g.uniform(0.0, 2.0, (n, m))
        noise = 0.01 * (0.8 * g.normal(size=(n, 1)) + 0.6 * g.normal(size=(n, m)))
        r = 1.5 * J + noise
        res = fit.fit_linear(r, J, np.ones((n, m)))
        inside += abs(res.delta[0] - 1.5) < 1.96 * res.stderr[0]
        assert res.rss < res.rss0
    # nominal 95 % coverage; binomial 3 sigma over 200 replicates = 4.6 %
    assert inside / reps > 0.95 - 0.046


def test_fit_linear_clips_to_bounds_and_bic_penalises():
    g = rng(8)
    J = g.uniform(0, 1, (100, 2))
    r = 3.0 * J + g.normal(0, 0.1, (100, 2))
    res = fit.fit_linear(r, J, np.ones((100, 2)), bounds=[(-1.0, 1.0)])
    assert res.delta[0] == 1.0 and res.clipped
    # a fit that explains nothing costs k ln(n_eff)
    assert fit.delta_bic(1.0, 1.0, 1, 100.0) == pytest.approx(np.log(100.0))
    assert fit.delta_bic(0.5, 1.0, 1, 100.0) == pytest.approx(100 * np.log(0.5) + np.log(100))


def test_noise_weights_follow_turbulence():
    g = rng(9)
    n, m = 400, 2
    drv = drivers_for(g, n, m)
    d = g.normal(size=(n, m)) * 0.05 * drv["turbulence_intensity"]  # std proportional to TI
    w = fit.noise_weights(d, drv, np.ones((n, m), bool))
    assert w.mean() == pytest.approx(1.0)
    lo, hi = drv["turbulence_intensity"] < 0.08, drv["turbulence_intensity"] > 0.2
    assert w[lo].mean() > 3 * w[hi].mean()  # variance ratio (0.2/0.08)^2 ~ 6, floored model
