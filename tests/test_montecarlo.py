"""JCGM 101 on Monte Carlo output (issue 24 section 2): coverage intervals and the stopping rules.

Every reference here is computed independently in the test: scipy's exact quantiles of known
distributions, numerical integration of their convolution with a normal, the order statistics
of JCGM 101 7.7.2 by hand, Student's t from scipy, brute-force re-simulation for the
delta-method standard deviations, and a normal toy for the stopping rule's coverage.
"""

import math

import numpy as np
import pytest
from scipy import integrate, optimize, stats

from lidarcal.analysis.certification import (
    SETTLED_VALUES,
    certified_bins,
    certified_statement,
    effective_dof,
    numerical_state,
    settle_target,
    thin_bin_factor,
)
from lidarcal.analysis.montecarlo import (
    coverage_interval,
    influence_quantile,
    mixture_cdf,
    mixture_quantile,
    replica_half_width,
    replicas_needed,
    stratified_sd,
    student_factor,
    tolerance_exponent,
)


def _rng(*key):
    return np.random.default_rng(np.random.SeedSequence([24, *key]))


def _convolved_quantile(dist, sigma, p):
    """p-quantile of dist + N(0, sigma²): CDF by quadrature, root by brentq (independent of lidarcal)."""
    def cdf(x):
        return integrate.quad(lambda t: dist.pdf(t) * stats.norm.cdf((x - t) / sigma), *dist.support(),
                              limit=200)[0]

    lo, hi = dist.ppf(1e-9) - 8 * sigma, dist.ppf(1 - 1e-9) + 8 * sigma
    return optimize.brentq(lambda x: cdf(x) - p, lo, hi, xtol=1e-12)


def test_mixture_quantile_solves_the_mixture_cdf_exactly():
    """G(x) = p to rounding, G evaluated here term by term with math.erf."""
    d = np.array([-1.3, -0.2, 0.0, 0.4, 2.5, 7.0])  # skewed, with a far trial
    for sigma in (0.05, 0.7, 3.0):
        probs = np.array([0.001, 0.025, 0.5, 0.975, 0.999])
        x = mixture_quantile(d, sigma, probs)
        for xi, p in zip(x, probs, strict=True):
            g = sum(0.5 * (1 + math.erf((xi - di) / (sigma * math.sqrt(2)))) for di in d) / d.size
            assert abs(g - p) < 1e-13, (sigma, p, g)
    # one trial: the normal's own quantile
    np.testing.assert_allclose(mixture_quantile([2.0], 0.5, [0.975]), 2.0 + 0.5 * stats.norm.ppf(0.975),
                               rtol=1e-13)
    # groups of unequal size at once (NaN-padded rows) give what each gives alone
    rows = np.array([[1.0, 2.0, np.nan], [0.0, 5.0, 9.0]])
    both = mixture_quantile(rows, np.array([0.3, 1.1]), [0.025, 0.975])
    np.testing.assert_allclose(both[0], mixture_quantile([1.0, 2.0], 0.3, [0.025, 0.975]), rtol=1e-13)
    np.testing.assert_allclose(both[1], mixture_quantile([0.0, 5.0, 9.0], 1.1, [0.025, 0.975]), rtol=1e-13)


def test_symmetric_interval_of_a_skewed_sample_matches_scipy_quantiles():
    """Gamma(shape 2) trials: the interval's ends are the exact 2.5 % and 97.5 % quantiles.

    Tolerance: 4 times the asymptotic standard deviation of a sample quantile, √(p(1−p)/n)/f(q),
    from scipy's exact density (the test fails by chance about once in 16,000).
    """
    dist = stats.gamma(2.0)
    n = 40_000
    d = dist.rvs(n, random_state=_rng(1))
    lo, hi = coverage_interval(d, 0.0)
    for got, p in ((lo, 0.025), (hi, 0.975)):
        q = dist.ppf(p)
        assert abs(got - q) < 4 * math.sqrt(p * (1 - p) / n) / dist.pdf(q), (p, got, q)
    # convolved with a normal: the quantiles of gamma + N(0, 0.8²), integrated numerically
    sigma = 0.8
    lo, hi = coverage_interval(d, sigma)
    for got, p in ((lo, 0.025), (hi, 0.975)):
        q = _convolved_quantile(dist, sigma, p)
        # the smoothed quantile scatters less than a raw one: the raw bound holds with room
        dens = integrate.quad(lambda t, q=q: dist.pdf(t) * stats.norm.pdf((q - t) / sigma) / sigma,
                              0, np.inf)[0]
        assert abs(got - q) < 4 * math.sqrt(p * (1 - p) / n) / dens, (p, got, q)


def test_shortest_interval_of_a_lognormal_matches_the_exact_one():
    """The shortest 95 % interval of a lognormal: f(a) = f(b) and F(b) − F(a) = 0.95, solved here."""
    dist = stats.lognorm(0.6)

    def width(a_prob):
        return dist.ppf(a_prob + 0.95) - dist.ppf(a_prob)

    best = optimize.minimize_scalar(width, bounds=(1e-9, 0.05 - 1e-9), method="bounded",
                                    options={"xatol": 1e-12})
    a, b = dist.ppf(best.x), dist.ppf(best.x + 0.95)
    assert dist.pdf(a) == pytest.approx(dist.pdf(b), rel=1e-4)  # the shortest: equal density at both ends
    n = 40_000
    d = dist.rvs(n, random_state=_rng(2))
    lo, hi = coverage_interval(d, 0.0, shortest=True)
    # ends of the shortest interval scatter more than a fixed quantile (the level moves too): 6 sigma of
    # the fixed quantile's standard deviation at those levels
    for got, q, p in ((lo, a, best.x), (hi, b, best.x + 0.95)):
        assert abs(got - q) < 6 * math.sqrt(p * (1 - p) / n) / dist.pdf(q), (got, q)
    sym = coverage_interval(d, 0.0)
    assert hi - lo < sym[1] - sym[0]  # shorter than the symmetric interval of the skewed sample
    # with sigma > 0 the shortest interval still holds 95 % of G and is shorter than the symmetric one
    lo, hi = coverage_interval(d[:3000], 0.3, shortest=True)
    g = mixture_cdf([lo, hi], d[:3000], 0.3)
    assert g[1] - g[0] == pytest.approx(0.95, abs=1e-9)
    s_lo, s_hi = coverage_interval(d[:3000], 0.3)
    assert hi - lo < s_hi - s_lo


def test_order_statistics_follow_jcgm_101_7_7_2():
    """M = 50 sorted values: q = int(47.5 + 1/2) = 48, r = (50 − 48)/2 = 1: [y_1, y_49]."""
    d = np.arange(1.0, 51.0) ** 2  # skewed spacing
    assert coverage_interval(d, 0.0) == (1.0, 49.0**2)
    # shortest: r minimising y_(r+48) − y_r over r = 1, 2: r = 1 (the squares widen)
    assert coverage_interval(d, 0.0, shortest=True) == (1.0, 49.0**2)
    # mirrored, the narrow end is at the top: r = 2 gives 2400 against r = 1's 2496
    assert coverage_interval(-d, 0.0, shortest=True) == (-(49.0**2), -1.0)
    # too few trials for a 95 % interval from order statistics (M < 1/(1 - p) = 20)
    assert all(math.isnan(v) for v in coverage_interval(d[:19], 0.0))


def test_student_factor_stopping_by_hand():
    """Four replica values; t_0.975(3) = 3.182 where JCGM 101 has 2: settled with 2, not with t."""
    values = np.array([[1.50, 1.54, 1.46, 1.50]])
    s = math.sqrt((0 + 0.04**2 + 0.04**2 + 0) / 3)  # = 0.032660
    w, h = replica_half_width(values)
    assert int(h[0]) == 4
    assert float(w[0]) == pytest.approx(3.182446305 * s / 2, rel=1e-8)  # = 0.05197
    assert 2 * s / 2 <= 0.05 < float(w[0])  # JCGM 101's 2 s/sqrt(h) = 0.0327 would have stopped
    assert float(student_factor(2)) == pytest.approx(12.7062047, rel=1e-7)
    assert math.isnan(float(student_factor(1)))
    assert tolerance_exponent(np.array([0.03266, 0.05197])).tolist() == [-1.0, 0.0]
    # the same through numerical_state, every value of the bin given these replicas
    target = settle_target(np.array([1.5]), 2)  # 0.05
    reps = {n: values for n in SETTLED_VALUES}
    delta = {n: np.array([0.001]) for n in SETTLED_VALUES}
    st = numerical_state({n: np.array([1.5]) for n in SETTLED_VALUES}, reps, delta, target, np.array([True]),
                         max_replicas=30)
    assert st["flag"].tolist() == [1] and st["tolerance_mean_difference"].tolist() == [0.5]
    # six replicas with the same spread: t(5) s / sqrt(6) = 2.571 * 0.0298 / 2.449 = 0.0313: settled
    six = np.array([[1.50, 1.54, 1.46, 1.50, 1.54, 1.46]])
    pooled = {n: np.array([1.5]) for n in SETTLED_VALUES}
    st = numerical_state(pooled, {n: six for n in SETTLED_VALUES}, delta, target, np.array([True]))
    assert st["flag"].tolist() == [0] and st["tolerance_expanded_uncertainty"].tolist() == [0.05]
    # the delta-method half-width counts too: 1.96 * 0.03 = 0.059 > 0.05 keeps it open
    wide = {n: np.array([0.03]) for n in SETTLED_VALUES}
    assert numerical_state(pooled, {n: six for n in SETTLED_VALUES}, wide, target,
                           np.array([True]))["flag"].tolist() == [1]
    # one replica: no spread, cannot settle; a bin not assessed is not_certified
    st = numerical_state({n: np.array([1.5, 1.5]) for n in SETTLED_VALUES},
                         {n: np.array([[1.5, np.nan], [1.5, 1.5]]) for n in SETTLED_VALUES},
                         {n: np.array([0.0, 0.0]) for n in SETTLED_VALUES}, np.array([0.05, 0.05]),
                         np.array([True, False]))
    assert st["flag"].tolist() == [1, 2] and math.isnan(st["tolerance_mean_difference"][0])


def test_student_rule_keeps_its_coverage_where_the_normal_rule_does_not():
    """A normal toy: replica values N(0, 1), checks at h = 2, 4, 8, 16, 24, 30, δ = 0.5.

    Stopping when t(h − 1)·s/√h ≤ δ leaves |mean| ≤ δ in about 94.4 % of 4,000 runs (95 % less what
    stopping early costs); JCGM 101's 2·s/√h from h = 2 in about 82 %.  Binomial standard error
    0.0036: the bounds below sit 4 and 15 standard errors from those values.
    """
    rng = _rng(3)
    runs = rng.normal(0.0, 1.0, (4000, 30))

    def coverage(factor):
        hit = 0
        for v in runs:
            for h in (2, 4, 8, 16, 24, 30):
                w = factor(h) * v[:h].std(ddof=1) / math.sqrt(h)
                if w <= 0.5 or h == 30:
                    break
            hit += abs(v[:h].mean()) <= 0.5
        return hit / runs.shape[0]

    assert coverage(lambda h: float(student_factor(h))) >= 0.93  # the factor replica_half_width applies
    assert coverage(lambda h: 2.0) <= 0.88


def test_replicas_needed_on_a_normal_toy():
    """The two-stage count: the fewest H > h with t(H − 1) s/√H ≤ δ and 1.96 sd √(h/H) ≤ δ, by brute force."""
    cases = ((4, 0.1, 0.0, 0.05), (2, 0.3, 0.01, 0.05), (8, 0.02, 0.04, 0.05), (4, 5.0, 0.0, 0.05))
    for h, s, sd, delta in cases:
        brute = 30
        for big_h in range(h + 1, 31):
            if (stats.t.ppf(0.975, big_h - 1) * s / math.sqrt(big_h) <= delta
                    and 1.959964 * sd * math.sqrt(h / big_h) <= delta):
                brute = big_h
                break
        got = int(replicas_needed(h, np.array([s]), np.array([sd]), np.array([delta]), 30)[0])
        assert got == brute, (h, s, sd, delta, got, brute)
    # the toy run: 18 replicas of a value with s = 0.1 reach delta = 0.05 (t(17) = 2.110: 0.0497)
    assert int(replicas_needed(4, np.array([0.1]), np.array([0.0]), np.array([0.05]), 30)[0]) == 18


def test_stratified_sd_is_the_seed_to_seed_scatter():
    """Periods with their own means, seeds adding N(0, 0.2²): the mean's scatter over re-runs.

    Brute force: 2,000 re-runs of 40 periods x 5 replicas with the period means fixed; the
    standard deviation of the mean over them is 0.2/√200 = 0.01414.  stratified_sd estimates it
    from one run (within-period spread, 160 degrees of freedom: relative standard error 5.6 %);
    the total spread (period means scattered by 1.0) would say 0.073.
    """
    rng = _rng(4)
    means = rng.normal(0.0, 1.0, 40)
    strata = np.repeat(np.arange(40), 5)
    one = means[strata] + rng.normal(0.0, 0.2, strata.size)
    est = float(stratified_sd(one - one.mean(), strata))
    reruns = np.array([(means[strata] + rng.normal(0.0, 0.2, strata.size)).mean() for _ in range(2000)])
    assert est == pytest.approx(reruns.std(), rel=0.2)
    assert est == pytest.approx(0.2 / math.sqrt(200), rel=0.2)
    # no stratum with two trials: the total spread, which over-states it (the safe side)
    alone = float(stratified_sd(one - one.mean(), np.arange(strata.size)))
    assert alone == pytest.approx(one.std(ddof=1) / math.sqrt(strata.size), rel=1e-12)


def test_quantile_influence_gives_the_scatter_of_the_interval_end():
    """Delta method against brute force: the 97.5 % end of G for 400 gamma trials, 3,000 re-draws."""
    dist, sigma, n = stats.gamma(2.0), 0.5, 400
    rng = _rng(5)
    ends = [coverage_interval(dist.rvs(n, random_state=rng), sigma)[1] for _ in range(3000)]
    d = dist.rvs(n, random_state=rng)
    x = coverage_interval(d, sigma)[1]
    inf = influence_quantile(d, sigma, x, 0.975)
    est = float(stratified_sd(inf, np.arange(n)))  # every trial its own period: iid
    # one sample's estimate of a standard deviation: about 10 % scatter at n = 400
    assert est == pytest.approx(np.std(ends), rel=0.25)


def test_effective_degrees_of_freedom_and_thin_bin_factor_by_hand():
    # u_std = 0.3 (9 dof), u_stat = 0.1 (9 dof), u_vref = 0.65 (Type B)
    u2 = 0.3**2 + 0.1**2 + 0.65**2
    nu = u2**2 / ((0.3**4 + 0.1**4) / 9)
    got = effective_dof({"std": np.array(0.3), "stat": np.array(0.1), "vref": np.array(0.65)},
                        {"std": np.array(9.0), "stat": np.array(9.0)})
    assert float(got) == pytest.approx(nu, rel=1e-12)
    assert float(thin_bin_factor(9.0)) == pytest.approx(2.262157163 / 1.959963985, rel=1e-8)
    assert float(thin_bin_factor(np.inf)) == 1.0


def test_certified_statement_and_flags():
    cov = np.array([0.95, 0.9749, 0.9499, 0.976])
    assert certified_statement(cov, np.ones(4, bool)).tolist() == [0, 0, 1, 1]
    flags = certified_bins(np.array([8.0, 8.0, 3.0, 8.0]), np.array([20, 20, 20, 5]),
                           settled=np.array([True, False, False, False]))
    assert flags.tolist() == [0, 4, 3, 1]  # not_settled only where everything else certifies
    assert settle_target(np.array([1.24, 0.62, 8.2, 12.0]), 2).tolist() == [0.05, 0.005, 0.05, 0.5]
