"""Uncertainty budget (paper §3.4) against values computed by hand on tiny record sets."""

import math

import numpy as np
import pytest
import xarray as xr
from analysis_factories import make_records, var_attrs

from lidarcal.analysis import budget
from lidarcal.analysis.rule import CertificationRule
from lidarcal.analysis.terms import PAPER_INPUTS, uncertainty_terms
from lidarcal.cf import height_coord, time_coord
from lidarcal.cli import main
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.schema import validate_dataset
from lidarcal.units import Q_

# Seven periods at one height: four in the 8 m/s bin [7.75, 8.25), none in 8.5, one in 9.0,
# two in 9.5.  Differences chosen so the statistics are easy by hand.
REF = [7.9, 8.0, 8.1, 8.2, 9.1, 9.4, 9.6]
DIFF = [0.1, -0.1, 0.2, 0.0, 0.3, 0.05, 0.15]


def tiny_records(heights=(120.0,)):
    ref = np.array(REF)[:, None] * np.ones(len(heights))
    lid = ref + np.array(DIFF)[:, None]
    n = len(REF)
    return xr.Dataset(
        {
            "reference_wind_speed": (("time", "height"), ref, var_attrs("ref", "m s-1", "wind_speed")),
            "lidar_wind_speed": (("time", "height"), lid, var_attrs("lidar", "m s-1", "wind_speed")),
        },
        coords={
            "time": time_coord(np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")),
            "height": height_coord(heights),
        },
        attrs={"lidarcal_source_file": "tiny.nc", "lidarcal_artefact": "simulated_rtd"},
    )


def linear_terms():
    """An uncertainty_terms-like dataset whose total is 0.04 + 0.001 U m/s (easy to evaluate)."""
    ws = np.arange(2.0, 21.0)
    return xr.Dataset(
        {"total": ("wind_speed", 0.04 + 0.001 * ws, var_attrs("total", "m s-1"))},
        coords={"wind_speed": ("wind_speed", ws, {"units": "m s-1"})},
        attrs={"lidarcal_source_file": "terms.nc"},
    )


def test_monte_carlo_budget_matches_hand_computation():
    b = budget(tiny_records(), terms=linear_terms(), rule=CertificationRule(min_periods=3))
    assert b.wind_speed.values.tolist() == [8.0, 8.5, 9.0, 9.5]
    np.testing.assert_allclose(b.wind_speed_bounds.values[0], [7.75, 8.25])
    assert b.contributor.values.tolist() == [
        "virtual_reference",
        "mean_difference",
        "std_difference",
        "statistical",
    ]
    bin8 = b.sel(height=120, wind_speed=8)
    # by hand: diffs 0.1, -0.1, 0.2, 0.0 -> mean 0.05; deviations 0.05 -0.15 0.15 -0.05,
    # sum of squares 0.05, sample variance 0.05/3, std 0.129099; sigma/sqrt(4) = 0.0645497
    std = math.sqrt(0.05 / 3)
    expected = [0.04 + 0.001 * 8.0, 0.05, std, std / 2]
    # float64 sums of four numbers: 1e-12 relative
    np.testing.assert_allclose(bin8.contribution.values, expected, rtol=1e-12)
    combined = math.sqrt(0.048**2 + 0.05**2 + std**2 + (std / 2) ** 2)  # = 0.16033...
    np.testing.assert_allclose(float(bin8.uncertainty), combined, rtol=1e-12)
    mean_ref = (7.9 + 8.0 + 8.1 + 8.2) / 4  # 8.05
    np.testing.assert_allclose(float(bin8.relative_uncertainty), 100 * combined / mean_ref, rtol=1e-12)
    np.testing.assert_allclose(float(bin8.expanded_uncertainty), 2 * combined, rtol=1e-12)
    np.testing.assert_allclose(
        float(bin8.relative_expanded_uncertainty), 200 * combined / mean_ref, rtol=1e-12
    )
    np.testing.assert_allclose(
        bin8.relative_contribution.values, 100 * np.array(expected) / mean_ref, rtol=1e-12
    )
    # certified but for the Monte Carlo: without replicas nothing can settle (JCGM 101 7.9 needs h >= 2)
    assert int(bin8.sample_count) == 4 and int(bin8.bin_flag) == 4
    # 9.5 bin: diffs 0.05, 0.15 -> mean 0.1, std sqrt(0.005) (2 periods: thin, but defined)
    bin95 = b.sel(height=120, wind_speed=9.5)
    s95 = math.sqrt(2 * 0.05**2 / 1)
    np.testing.assert_allclose(bin95.contribution.values, [0.0495, 0.1, s95, s95 / math.sqrt(2)], rtol=1e-12)
    assert int(bin95.bin_flag) == 1 and int(bin95.sample_count) == 2
    # 9.0 bin: one period -> std undefined, combined NaN, flagged thin, not dropped
    bin9 = b.sel(height=120, wind_speed=9.0)
    assert int(bin9.sample_count) == 1 and int(bin9.bin_flag) == 1
    np.testing.assert_allclose(float(bin9.mean_difference), 0.3, rtol=1e-12)
    assert np.isnan(float(bin9.uncertainty))
    # 8.5 bin: empty
    bin85 = b.sel(height=120, wind_speed=8.5)
    assert int(bin85.sample_count) == 0 and int(bin85.bin_flag) == 2
    assert b.bin_flag.attrs["flag_meanings"] == ("certified too_few_periods empty outside_certified_range "
                                                 "not_settled")
    # one record per period: trials are periods; no replica, so no certified value is settled
    assert (b.period_count == b.sample_count).all()
    assert int(bin8.numerical_flag) == 1 and np.isnan(float(bin8.numerical_tolerance))
    assert b.attrs["monte_carlo_replicas"] == 1 and b.attrs["monte_carlo_trials"] == int(b.sample_count.sum())


def test_certified_rule_is_range_and_distinct_periods():
    """The default rule: centre in 4-16 m/s and >= 10 distinct periods; the others say why not."""
    b = budget(tiny_records(), terms=linear_terms())  # 4 periods at most: nothing certified by default
    assert not (b.bin_flag == 0).any()
    assert int(b.bin_flag.sel(height=120, wind_speed=8)) == 1  # too_few_periods
    b = budget(tiny_records(), terms=linear_terms(),
               rule=CertificationRule(min_periods=2, certified_range=(8.4, 9.6)))
    flags = b.bin_flag.sel(height=120).values.tolist()
    # 8: outside the range, 8.5: empty, 9: one period, 9.5: certified but for its Monte Carlo values,
    # which cannot settle without replicas
    assert flags == [3, 2, 1, 4]
    with pytest.raises(InputError, match="min_periods must be >= 2"):
        budget(tiny_records(), terms=linear_terms(), rule=CertificationRule(min_periods=1))


def test_iec_budget_matches_hand_computation():
    b = budget(
        tiny_records(),
        approach="iec",
        reference_uncertainty="0.1 m s-1",
        reference_relative_uncertainty="0.5 %",
        mounting=Q_(0.2, "%"),
        separation=0.003,
    )
    assert b.contributor.values.tolist() == [
        "reference_sensor",
        "mean_difference",
        "statistical",
        "mounting",
        "separation",
        "flow_inhomogeneity",
    ]
    bin8 = b.sel(height=120, wind_speed=8.0)
    u = 8.05
    std = math.sqrt(0.05 / 3)
    expected = [math.sqrt(0.1**2 + (0.005 * u) ** 2), 0.05, std / 2, 0.002 * u, 0.003 * u, 0.0]
    np.testing.assert_allclose(bin8.contribution.values, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(float(bin8.uncertainty), math.sqrt(sum(e * e for e in expected)), rtol=1e-12)
    assert b.attrs["approach"] == "iec"
    with pytest.raises(InputError, match="reference_uncertainty"):
        budget(tiny_records(), approach="iec")
    with pytest.raises(InputError, match="fraction"):
        budget(tiny_records(), approach="iec", reference_uncertainty="0.1 m s-1", mounting=2.0)


def test_default_terms_follow_table4_at_each_height():
    b = budget(tiny_records(heights=(100.0, 50.0)))
    vref = b.contribution.sel(contributor="virtual_reference")
    for h in (100.0, 50.0):
        expected = uncertainty_terms(
            Q_(b.wind_speed.values, "m s-1"), **{**PAPER_INPUTS, "height": Q_(h, "m")}
        )
        np.testing.assert_allclose(vref.sel(height=h).values, expected.total.values, rtol=1e-12)
    # Eq. 11 grows as 1/z, so the lower height has the larger virtual reference term
    assert (vref.sel(height=50.0) > vref.sel(height=100.0)).all()


def test_selection_and_plotting_interface():
    b = budget(make_records(n=800, heights=(80.0, 120.0)))
    point = b.sel(height=121, wind_speed=8.1, method="nearest")
    assert float(point.height) == 120.0 and float(point.wind_speed) == 8.0
    assert point.uncertainty.attrs["units"] == "m s-1" and b.relative_uncertainty.attrs["units"] == "%"
    import hvplot.xarray  # noqa: F401

    plot = b.sel(height=120).uncertainty.hvplot()
    assert [d.name for d in plot.kdims] == ["wind_speed"]
    assert len(plot.data) == b.sizes["wind_speed"]


def test_height_not_simulated_is_refused():
    with pytest.raises(
        InputError, match=r"tiny.nc: height\(s\) 100 m not in the records; available heights: 120"
    ):
        budget(tiny_records(), terms=linear_terms(), heights=[100.0])


def test_terms_must_cover_the_bins():
    terms = linear_terms().sel(wind_speed=slice(2, 9))
    with pytest.raises(
        InputError,
        match=r"terms.nc: variable 'total' covers wind speeds 2-9 m s-1; the budget "
        r"needs 8-9.5 m s-1",
    ):
        budget(tiny_records(), terms=terms)


def test_real_terms_artefact_and_cli(tmp_path, capsys):
    from lidarcal.analysis.terms import TABLE4_WIND_SPEEDS

    terms_path = write_artefact(uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS), tmp_path / "terms.nc")
    rec = tmp_path / "rec.nc"
    make_records(n=600).to_netcdf(rec)
    out = tmp_path / "budget.nc"
    assert main(["budget", str(rec), "--terms", str(terms_path), "-o", str(out)]) == 0
    assert "monte_carlo budget" in capsys.readouterr().out
    b = open_artefact(out, "uncertainty_budget")
    assert validate_dataset(b) == []
    roles = {r["role"]: r for r in __import__("json").loads(b.attrs["lidarcal_inputs"])}
    assert set(roles) == {"records", "terms"} and roles["terms"]["file"] == "terms.nc"
    t = open_artefact(terms_path)
    np.testing.assert_allclose(
        b.contribution.sel(contributor="virtual_reference", height=80).values,
        np.interp(b.wind_speed.values, t.wind_speed.values, t.total.values),
        rtol=1e-12,
    )
    # refuses to overwrite; IEC without the reference uncertainty is a clear error (exit 2, no file)
    assert main(["budget", str(rec), "-o", str(out)]) == 2
    assert main(["budget", str(rec), "--approach", "iec", "-o", str(tmp_path / "iec.nc")]) == 2
    assert not (tmp_path / "iec.nc").exists()
    assert (
        main(
            [
                "budget",
                str(rec),
                "--approach",
                "iec",
                "--reference-uncertainty",
                "0.1 m s-1",
                "--mounting",
                "0.5 %",
                "-o",
                str(tmp_path / "iec.nc"),
            ]
        )
        == 0
    )


def test_budget_file_passes_compliance(tmp_path):
    from lidarcal.compliance import check_compliance

    path = write_artefact(budget(make_records(n=300)), tmp_path / "b.nc")
    report = check_compliance(path)
    assert report.passed, report.failures


def test_dask_records_same_budget():
    recs = make_records(n=500)
    a = budget(recs)
    b = budget(recs.chunk(time=128, height=1))
    xr.testing.assert_identical(a.drop_attrs(), b.drop_attrs())



def test_noise_terms_option_reaches_the_budget():
    # without a terms file the budget computes Table 4 itself, in the form asked for
    b = budget(tiny_records(heights=(100.0,)), noise_terms="derived")
    vref = b.contribution.sel(contributor="virtual_reference", height=100.0).values
    u = Q_(b.wind_speed.values, "m s-1")
    inputs = {**PAPER_INPUTS, "height": Q_(100.0, "m")}
    np.testing.assert_allclose(vref, uncertainty_terms(u, **inputs, noise_terms="derived").total.values,
                               rtol=1e-12)
    # Eq. 6 0.041 -> 0.0035 outweighs Eq. 7 0.0026 -> 0.032 in the quadrature sum
    assert (vref < uncertainty_terms(u, **inputs).total.values).all()
    # a terms artefact of the other form is refused, not silently mixed
    with pytest.raises(InputError, match="noise_terms='printed'; asked for 'derived'"):
        budget(tiny_records(heights=(100.0,)), terms=uncertainty_terms(u, **inputs), noise_terms="derived")


def test_monte_carlo_distribution_of_a_bin_by_hand():
    """The 8 m/s bin of the tiny records: its JCGM 101 values computed here from the definitions.

    Trials d = (0.1, -0.1, 0.2, 0.0) m/s, N = 4 periods; the terms the trials do not carry
    (virtual reference 0.048 m/s, statistical s/2) convolve them as one normal; all in % of
    8.05 m/s.  Interval ends by brentq on the mixture CDF written with math.erf, widened by
    t_0.975(nu_eff)/1.96 (Welch-Satterthwaite: s and s/2 on 3 degrees of freedom).
    """
    from scipy import optimize, stats

    b = budget(tiny_records(), terms=linear_terms(),
               rule=CertificationRule(min_periods=3)).sel(height=120, wind_speed=8)
    pct = 100 / 8.05
    d = [v * pct for v in (0.1, -0.1, 0.2, 0.0)]
    s = math.sqrt(0.05 / 3) * pct
    vref, stat = 0.048 * pct, s / 2
    sigma = math.sqrt(vref**2 + stat**2)
    y = sum(d) / 4
    u = math.sqrt(s**2 + sigma**2)
    nu = (s**2 + stat**2 + vref**2) ** 2 / ((s**4 + stat**4) / 3)
    c = stats.t.ppf(0.975, nu) / stats.norm.ppf(0.975)

    def g(x):
        return sum(0.5 * (1 + math.erf((x - di) / (sigma * math.sqrt(2)))) for di in d) / 4

    lo = optimize.brentq(lambda x: g(x) - 0.025, -10, 10, xtol=1e-14)
    hi = optimize.brentq(lambda x: g(x) - 0.975, -10, 10, xtol=1e-14)
    assert float(b.relative_mean_difference) == pytest.approx(y, rel=1e-12)
    assert float(b.relative_error_standard_uncertainty) == pytest.approx(u, rel=1e-12)
    assert float(b.error_standard_uncertainty) == pytest.approx(u / pct, rel=1e-12)
    assert float(b.effective_degrees_of_freedom) == pytest.approx(nu, rel=1e-12)
    assert float(b.relative_coverage_interval_lower) == pytest.approx(y + c * (lo - y), rel=1e-9)
    assert float(b.relative_coverage_interval_upper) == pytest.approx(y + c * (hi - y), rel=1e-9)
    assert float(b.coverage_interval_upper) == pytest.approx((y + c * (hi - y)) / pct, rel=1e-9)
    # the k = 2 value is 2 sqrt(y^2 + u^2): the mean difference counted as one more contributor
    big_u = 2 * math.sqrt(y**2 + u**2)
    assert float(b.relative_expanded_uncertainty) == pytest.approx(big_u, rel=1e-12)
    coverage = g(y + (big_u - y) / c) - g(y + (-big_u - y) / c)
    assert float(b.expanded_uncertainty_coverage) == pytest.approx(100 * coverage, rel=1e-9)
    # not certified (no replica: nothing settles), so it certifies nothing
    assert int(b.certified_statement) == 2 and int(b.replica_count) == 1


def test_thin_bin_with_spread_of_its_own_certifies_the_widened_interval():
    """GUM G.4: a bin of 10 periods whose spread dominates U under-covers at k = 2.

    Ten periods, each with its own error (N(0, 1 %): the atmosphere's spread) and, in each of 8
    replicas, a seed's N(0, 0.5 %) on top; a Table 4 total of 0.1 %.  The spread rests on 9
    degrees of freedom: ν_eff is about 11, the distribution is widened by t_0.975(ν_eff)/1.96
    (about 1.14) and ±U covers well under 95 % of it, so the bin certifies the interval.  Its ends
    are checked against the mixture quantiles computed here (brentq on math.erf) widened by
    that factor.  One significant digit, so the values settle.
    """
    from scipy import optimize, stats

    from lidarcal.campaign.adaptive import with_trials
    from lidarcal.schema import output_attrs

    rng = np.random.default_rng(np.random.SeedSequence([24, 11]))
    n, reps = 10, 8
    ref = np.full(n, 10.0) + rng.uniform(-0.2, 0.2, n)
    base = rng.normal(0, 1.0, n)
    errors = [base + rng.normal(0, 0.5, n) for _ in range(reps)]  # %, replica 0 first
    records = xr.Dataset(
        {"reference_wind_speed": (("time", "height"), ref[:, None], var_attrs("ref", "m s-1", "wind_speed")),
         "lidar_wind_speed": (("time", "height"), (ref * (1 + errors[0] / 100))[:, None],
                              var_attrs("lidar", "m s-1", "wind_speed")),
         "period_key": ("time", np.arange(n, dtype=np.int64), output_attrs("simulated_rtd", "period_key"))},
        coords={"time": time_coord(np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")),
                "height": height_coord([120.0])},
        attrs={"lidarcal_source_file": "thin.nc", "lidarcal_artefact": "simulated_rtd"})
    records = with_trials(records, [{"replica": r, "period": np.arange(n), "height": np.full(n, 120.0),
                                     "lidar_wind_speed": ref * (1 + errors[r] / 100),
                                     "reference_wind_speed": ref} for r in range(1, reps)])
    total = 0.01  # m/s at 10 m/s: 0.1 %
    terms = xr.Dataset({"total": ("wind_speed", np.full(19, total), var_attrs("total", "m s-1"))},
                       coords={"wind_speed": ("wind_speed", np.arange(2.0, 21.0), {"units": "m s-1"})},
                       attrs={"lidarcal_source_file": "terms.nc"})
    b = budget(records, terms=terms,
               rule=CertificationRule(significant_digits=1)).sel(height=120, wind_speed=10)
    assert int(b.period_count) == 10 and int(b.sample_count) == 80 and int(b.bin_flag) == 0
    # by hand: the trials in % of the bin mean reference, s and s/sqrt(10) on 9 degrees of freedom
    mean_ref = ref.mean()
    d = np.concatenate([100 * ref * e / 100 / mean_ref for e in errors])
    s = d.std(ddof=1)
    vref, stat = 100 * total / mean_ref, s / math.sqrt(10)
    nu = (s**2 + stat**2 + vref**2) ** 2 / ((s**4 + stat**4) / 9)
    assert float(b.effective_degrees_of_freedom) == pytest.approx(nu, rel=1e-9)
    assert 9 < nu < 12
    sigma = math.sqrt(vref**2 + stat**2)

    def g(x):
        return sum(0.5 * (1 + math.erf((x - di) / (sigma * math.sqrt(2)))) for di in d) / d.size

    y = d.mean()
    c = stats.t.ppf(0.975, nu) / stats.norm.ppf(0.975)
    for end, p in (("lower", 0.025), ("upper", 0.975)):
        raw = optimize.brentq(lambda x, p=p: g(x) - p, -20, 20, xtol=1e-14)
        assert float(b[f"relative_coverage_interval_{end}"]) == pytest.approx(y + c * (raw - y), rel=1e-9)
    big_u = float(b.relative_expanded_uncertainty)
    coverage = g(y + (big_u - y) / c) - g(y + (-big_u - y) / c)
    assert float(b.expanded_uncertainty_coverage) == pytest.approx(100 * coverage, rel=1e-9)
    assert coverage < 0.94 and int(b.certified_statement) == 1  # k = 2 under-covers: the interval it is
    half = 0.5 * float(b.relative_coverage_interval_upper - b.relative_coverage_interval_lower)
    assert half > big_u  # the certified interval is wider than +-U (by 6 % here)


def test_statistical_term_counts_periods_not_trials():
    """Replicas add trials, not periods of the atmosphere: sigma/sqrt(N) with N = period_count."""
    records = make_records(n=300, heights=(80.0,), replicas=4)
    b = budget(records, rule=CertificationRule(significant_digits=1))
    stat = b.contribution.sel(contributor="statistical")
    filled = b.period_count >= 2
    assert bool((b.sample_count.where(filled) == 4 * b.period_count.where(filled)).where(filled, True).all())
    expected = b.std_difference / np.sqrt(b.period_count)
    np.testing.assert_allclose(stat.where(filled).values, expected.where(filled).values, rtol=1e-12)


def test_shortest_interval_on_request():
    """JCGM 101 7.7: the shortest 95 % interval is no wider than the symmetric one; the choice is recorded."""
    records = make_records(n=400, heights=(80.0,), replicas=4, shear_slope=(8.0,))
    sym = budget(records, rule=CertificationRule(significant_digits=1))
    short = budget(records, rule=CertificationRule(significant_digits=1, coverage_interval="shortest"))
    width = {k: (b.relative_coverage_interval_upper - b.relative_coverage_interval_lower)
             for k, b in (("sym", sym), ("short", short))}
    filled = np.isfinite(width["sym"])
    assert int(filled.sum()) >= 10
    assert bool((width["short"] <= width["sym"] + 1e-9).where(filled, True).all())
    assert float((width["sym"] - width["short"]).where(filled).max()) > 0  # a flat-topped, skewed bin differs
    assert short.attrs["coverage_interval"] == "shortest" and sym.attrs["coverage_interval"] == "symmetric"
    assert "shortest" in short.relative_coverage_interval_upper.attrs["long_name"]
    with pytest.raises(InputError, match="coverage_interval must be one of"):
        budget(records, rule=CertificationRule(coverage_interval="narrow"))
