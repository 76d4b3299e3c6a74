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


def test_binned_residuals_against_direct_computation():
    g = rng(1)
    x, r = g.uniform(0, 1, (200, 2)), g.normal(0, 1, (200, 2))
    binned = stats.bin_residuals(r, {"wind_speed": x}, n_bins=4)
    edges = binned.edges[0]
    assert np.array_equal(edges, stats.bin_edges(x, 4))  # quantiles pooled over heights
    assert binned.count[0].sum() == 400  # every finite value lands in one bin, the maximum included
    for j in range(2):  # each height binned on its own
        sel = (x[:, j] >= edges[1]) & (x[:, j] < edges[2])
        assert binned.count[0, 1, j] == sel.sum()
        assert binned.mean[0, 1, j] == pytest.approx(r[sel, j].mean())
        assert binned.se[0, 1, j] == pytest.approx(r[sel, j].std(ddof=1) / np.sqrt(sel.sum()))
        assert binned.center[0, 1, j] == pytest.approx(x[sel, j].mean())


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
    overall, per_height, floor = stats.gap(r, stats.bin_groups(drv, np.ones((n, m), bool), 5))
    # every bin mean is 2 % +- 0.01/sqrt(120) = 0.09 %: the noise-corrected rms is within 0.3 % of 2 %
    assert overall == pytest.approx(2.0, abs=0.3)
    assert per_height.shape == (2,) and np.allclose(per_height, 2.0, atol=0.3)
    assert floor == pytest.approx(100 * 0.01 / np.sqrt(120), rel=0.15)  # se of a 120-period bin
    # bins with fewer than min_bin_count periods do not count: none has all n
    assert np.isnan(stats.gap(r, stats.bin_groups(drv, np.ones((n, m), bool), 5), min_bin_count=n + 1)[0])


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
    assert res.delta[0] == 1.0 and res.clipped and res.at_bound[0]
    # the unconstrained fit is kept: what the data ask for, to be judged against the range
    assert res.delta_free[0] == pytest.approx(3.0, abs=0.05) and res.rss_free < res.rss
    # a fit that explains nothing costs k ln(n_eff)
    assert fit.delta_bic(1.0, 1.0, 1, 100.0) == pytest.approx(np.log(100.0))
    assert fit.delta_bic(0.5, 1.0, 1, 100.0) == pytest.approx(100 * np.log(0.5) + np.log(100))


def test_fit_linear_bounded_is_the_constrained_optimum():
    # two correlated responses, the first pushed beyond its bound: holding it at the bound and
    # refitting the other is the constrained optimum (clipping each on its own is not) — checked
    # against a brute-force search of the weighted RSS on a fine grid of the box
    g = rng(10)
    n, m = 300, 2
    J1 = g.uniform(0.5, 1.5, (n, m))
    J2 = 0.7 * J1 + 0.3 * g.uniform(0.0, 1.0, (n, m))
    w = g.uniform(0.5, 1.5, (n, m))
    r = 1.6 * J1 - 0.4 * J2 + g.normal(0, 0.05, (n, m))
    bounds = [(-1.0, 1.0), (-1.0, 1.0)]
    res = fit.fit_linear(r, [J1, J2], w, bounds=bounds)
    assert res.delta_free[0] > 1.0 and list(res.at_bound) == [True, False] and res.delta[0] == 1.0
    a = np.linspace(-1, 1, 2001)[:, None]
    b = np.linspace(-1, 1, 2001)[None, :]
    # the weighted RSS on the grid, expanded in the sums of products (exact, no (grid x data) array)
    S = {k: float(np.sum(w * x)) for k, x in {"rr": r * r, "r1": r * J1, "r2": r * J2, "11": J1 * J1,
                                              "12": J1 * J2, "22": J2 * J2}.items()}
    rss = (S["rr"] - 2 * a * S["r1"] - 2 * b * S["r2"] + a * a * S["11"] + 2 * a * b * S["12"]
           + b * b * S["22"])
    i, j = np.unravel_index(np.argmin(rss), rss.shape)
    assert res.delta == pytest.approx([a[i, 0], b[0, j]], abs=0.002)
    assert res.rss == pytest.approx(float(rss.min()), rel=1e-4)
    clipped_each = np.clip(res.delta_free, -1.0, 1.0)
    assert res.rss < float(np.sum(w * (r - clipped_each[0] * J1 - clipped_each[1] * J2) ** 2))
    # a fit inside its bounds is untouched
    inside = fit.fit_linear(r, [J1, J2], w, bounds=[(-5.0, 5.0), (-5.0, 5.0)])
    assert not inside.clipped and np.array_equal(inside.delta, inside.delta_free)


def test_noise_weights_follow_turbulence():
    g = rng(9)
    n, m = 400, 2
    drv = drivers_for(g, n, m)
    d = g.normal(size=(n, m)) * 0.05 * drv["turbulence_intensity"]  # std proportional to TI
    w = fit.noise_weights(d, drv, np.ones((n, m), bool))
    assert w.mean() == pytest.approx(1.0)
    lo, hi = drv["turbulence_intensity"] < 0.08, drv["turbulence_intensity"] > 0.2
    assert w[lo].mean() > 3 * w[hi].mean()  # variance ratio (0.2/0.08)^2 ~ 6, floored model


def test_day_block_bootstrap_covers_where_the_period_sandwich_does_not():
    # A misfit that persists for a day: the residual's noise and the response both carry a
    # day-level component (weather regimes), so periods of one day are not independent.  The
    # per-period sandwich treats them as independent and under-covers; resampling whole days
    # keeps the correlation.  30 days x 10 periods x 2 heights, 200 replicates.
    reps, inside_boot, inside_sand = 200, 0, 0
    times = np.datetime64("2024-05-01") + (np.arange(300) // 10) * np.timedelta64(1, "D")
    clusters, label = fit.day_clusters(times)
    assert label == "30 days" and clusters.max() == 29
    for k in range(reps):
        g = rng(10, k)
        day_j = np.repeat(g.normal(0, 1.0, 30), 10)[:, None]
        day_e = np.repeat(g.normal(0, 1.0, 30), 10)[:, None]
        J = 0.01 * (1.0 + day_j + 0.3 * g.normal(size=(300, 2)))
        r = 2.0 * J + 0.01 * (day_e * day_j + 0.3 * g.normal(size=(300, 2)))
        w = np.ones_like(r)
        full, samples = fit.bootstrap_fit(r, [J], w, clusters, n_boot=300, seed=k)
        lo, hi = full[0] + np.quantile(samples[:, 0] - full[0], [0.025, 0.975])
        inside_boot += lo <= 2.0 <= hi
        res = fit.fit_linear(r, J, w)
        inside_sand += abs(res.delta[0] - 2.0) < 1.96 * res.stderr[0]
    # nominal 95 %; binomial 3 sigma over 200 replicates = 4.6 %; a 30-cluster bootstrap runs a
    # little short of nominal (about 92-93 %), hence one more sigma of slack
    assert inside_boot / reps > 0.95 - 0.046 - 0.015, inside_boot
    assert inside_sand / reps < inside_boot / reps - 0.1, (inside_sand, inside_boot)  # the reason for it


def test_day_clusters_fall_back_to_blocks_on_a_short_record():
    times = np.datetime64("2024-05-01") + np.arange(200) * np.timedelta64(600, "s")  # 1.4 days
    lab, label = fit.day_clusters(times)
    assert label == "20 blocks of consecutive periods" and np.all(np.diff(lab) >= 0)
    assert np.bincount(lab).tolist() == [10] * 20


def test_gap_removes_the_noise_and_sees_a_product_of_drivers():
    g = rng(11)
    n, m = 2000, 2
    drv = drivers_for(g, n, m)
    drv["wind_from_direction"] = g.uniform(0, 360, (n, m))
    valid = np.ones((n, m), bool)
    groups = stats.bin_groups(drv, valid, 6, [("wind_shear_exponent", "cnr_gradient")])
    noise = g.normal(0, 0.01, (n, m))
    # pure noise: the raw rms of the bin means would be ~ the floor (the rms standard error); the
    # noise-corrected gap is √max(mean(m² − se²), 0), whose mean term scatters by ~√(2/K)·se² over
    # K ≈ 90 bins (fewer independent ones: the groups share periods), so √ of it is ~0.4 floor at
    # 1 sigma; 0.7 floor is ~3 sigma
    gap0, _, floor = stats.gap(noise, groups)
    assert gap0 < 0.7 * floor
    # an effect in the product of (centred) shear and CNR gradient: invisible in 1-D bins of either
    prod = (drv["wind_shear_exponent"] - 0.175) * drv["cnr_gradient"]
    r = noise + 0.5 * prod / prod.std()
    one_d = stats.gap(r, stats.bin_groups({k: drv[k] for k in ("wind_shear_exponent", "cnr_gradient")},
                                                 valid, 6))[0]
    joint = stats.group_p_values(r, groups, names=("wind_shear_exponent x cnr_gradient",))
    assert np.all(joint < 1e-6)  # the joint bins see it at every height
    assert stats.gap(r, groups)[0] > 2 * one_d  # and the gap metric grows with them
