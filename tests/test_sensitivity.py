"""Sensitivity analysis (paper §3.3, Eqs. 12-13) on constructed records with known slopes."""

import numpy as np
import pytest
import scipy.stats
import xarray as xr
from analysis_factories import make_records
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarcal.analysis import compare_slopes, sensitivity
from lidarcal.analysis.kernels import bin_statistics, edges_from_width, linear_regression, significance
from lidarcal.cf import height_coord, time_coord, var_attrs
from lidarcal.cli import main
from lidarcal.errors import InputError, MissingVariableError, UnitError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.schema import validate_dataset

# ---------------------------------------------------------------- kernels


def test_bin_statistics_matches_brute_force():
    rng = np.random.default_rng(np.random.SeedSequence([7, 1]))
    x = rng.uniform(0, 1, (3, 200))
    y = rng.normal(0, 1, (3, 200))
    y[0, :5] = np.nan
    edges = np.linspace(0, 1, 6)
    n, m, s, mx = bin_statistics(x, y, edges)
    for row in range(3):
        for b in range(5):
            sel = (x[row] >= edges[b]) & (x[row] < edges[b + 1]) & np.isfinite(y[row])
            assert n[row, b] == sel.sum()
            # float64 sums of ~40 values: agreement to 1e-12 relative is rounding only
            np.testing.assert_allclose(m[row, b], y[row, sel].mean(), rtol=1e-12)
            np.testing.assert_allclose(s[row, b], y[row, sel].std(ddof=1), rtol=1e-12)
            np.testing.assert_allclose(mx[row, b], x[row, sel].mean(), rtol=1e-12)


def test_edges_are_multiples_of_width():
    np.testing.assert_allclose(
        edges_from_width(0.03, 0.21, 0.05), [0, 0.05, 0.1, 0.15, 0.2, 0.25], atol=1e-12
    )
    with pytest.raises(ValueError, match="not finite"):
        edges_from_width(np.nan, 1.0, 0.1)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-10, 10), st.floats(-100, 100)), min_size=3, max_size=30))
def test_regression_equals_scipy_linregress(points):
    x = np.array([p[0] for p in points])
    y = np.array([p[1] for p in points])
    if np.ptp(x) < 1e-3 or np.ptp(y) < 1e-6:
        return  # degenerate: scipy warns/returns nan; covered in the NaN test below
    ref = scipy.stats.linregress(x, y)
    slope, intercept, r, stderr = linear_regression(x, y)
    # same closed form, different summation order: agreement to ~1e-9 relative of the scale
    np.testing.assert_allclose(slope, ref.slope, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(intercept, ref.intercept, rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(r, ref.rvalue, rtol=1e-7, atol=1e-9)
    # near-perfect fits: both stderrs are cancellation noise ~1e-8 relative to the slope scale
    np.testing.assert_allclose(stderr, ref.stderr, rtol=1e-6, atol=1e-6 * (abs(ref.slope) + 1))


def test_regression_ignores_nan_and_needs_two_points():
    slope, intercept, r, _ = linear_regression(
        np.array([0.0, 1.0, 2.0, 3.0]), np.array([1.0, 3.0, np.nan, 7.0])
    )
    assert slope == pytest.approx(2.0) and intercept == pytest.approx(1.0) and r == pytest.approx(1.0)
    assert np.isnan(linear_regression(np.array([1.0, 2.0]), np.array([1.0, np.nan]))[0])


@pytest.mark.parametrize(
    ("m", "std", "r", "eq12", "eq13"),
    [
        (10.0, 0.0501, 1.0, True, True),  # m*std = 0.501 > 0.5
        (10.0, 0.0499, 1.0, False, True),  # m*std = 0.499 < 0.5, m*std*R = 0.499 > 0.1
        (-10.0, 0.0499, 0.2005, False, True),  # |m*std*R| = 0.10005 > 0.1 (sign does not matter)
        (10.0, 0.0499, 0.2003, False, False),  # m*std*R = 0.09995 < 0.1
        (100.0, 0.0100, 0.05, True, False),  # 1.0 > 0.5 but m*std*R = 0.05
        (np.nan, 0.05, 0.5, False, False),  # no regression -> not significant
    ],
)
def test_significance_thresholds(m, std, r, eq12, eq13):
    _, _, s12, s13 = significance(np.array(m), np.array(std), np.array(r))
    assert bool(s12) is eq12 and bool(s13) is eq13


# ---------------------------------------------------------------- constructed records


def exact_records(
    bin_means_pct, centres, per_bin=5, heights=(100.0,), spread=0.004, ref=8.0, name="exact.nc"
):
    """Records whose relative difference in each shear bin is exactly ``bin_means_pct``.

    In every bin the shear values are centre +/- spread (symmetric), and the differences
    are mean +/- 0.2 % (symmetric), so bin means are exact.
    """
    bin_means_pct = np.atleast_2d(np.asarray(bin_means_pct, dtype=float))  # (height, bin)
    alpha, diff = [], []
    offs = np.linspace(-spread, spread, per_bin)
    doffs = np.linspace(-0.2, 0.2, per_bin)
    for b, c in enumerate(centres):
        alpha.append(c + offs)
        diff.append(bin_means_pct[:, b][:, None] + doffs[None, :])
    alpha = np.concatenate(alpha)
    diff = np.concatenate(diff, axis=1).T  # (time, height)
    n = len(alpha)
    alpha2 = np.repeat(alpha[:, None], len(heights), axis=1)
    refv = np.full((n, len(heights)), ref)
    ds = xr.Dataset(
        {
            "wind_shear_exponent": (("time", "height"), alpha2, var_attrs("shear", "1")),
            "reference_wind_speed": (("time", "height"), refv, var_attrs("ref", "m s-1", "wind_speed")),
            "lidar_wind_speed": (("time", "height"), refv * (1 + diff / 100), var_attrs("lidar", "m s-1")),
        },
        coords={
            "time": time_coord(np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")),
            "height": height_coord(heights),
        },
        attrs={"lidarcal_source_file": name},
    )
    return ds, alpha2


def test_known_slope_is_recovered_exactly():
    centres = np.array([0.025, 0.075, 0.125, 0.175, 0.225])
    slopes = np.array([4.0, -2.5])
    means = slopes[:, None] * centres[None, :] + np.array([[0.3], [-0.1]])
    recs, alpha = exact_records(means, centres, heights=(80.0, 140.0))
    s = sensitivity(recs, "wind_shear_exponent", bin_width=0.05, reference_range=None)
    assert s.sizes == {"height": 2, "bin": 5, "nv": 2}
    np.testing.assert_allclose(s.bin.values, centres, atol=1e-12)
    np.testing.assert_allclose(s.bin_bounds.values[:, 0], centres - 0.025, atol=1e-12)
    # bin means are exact by construction up to float rounding of 100*(ref*(1+d/100)-ref)/ref
    np.testing.assert_allclose(s.mean_difference.values, means, atol=1e-10)
    np.testing.assert_allclose(s.slope.values, slopes, atol=1e-9)
    np.testing.assert_allclose(s.intercept.values, [0.3, -0.1], atol=1e-9)
    np.testing.assert_allclose(s.correlation.values, [1.0, -1.0], atol=1e-12)
    # std of the variable over all 25 periods, computed independently
    expected_std = np.sqrt(np.sum((alpha[:, 0] - alpha[:, 0].mean()) ** 2) / (len(alpha) - 1))
    np.testing.assert_allclose(s.variable_std.values, expected_std, rtol=1e-12)
    np.testing.assert_allclose(s.slope_times_std.values, slopes * expected_std, rtol=1e-9)
    assert s.sample_count.values.tolist() == [[5] * 5, [5] * 5]
    assert s.slope.attrs["units"] == "%" and s.bin.attrs["units"] == "1"
    assert s.periods_used.values.tolist() == [25, 25]


def _scaled_case(target_stat, which):
    """Bin means with R < 1, scaled so that the Eq. `which` statistic equals target_stat."""
    centres = np.array([0.025, 0.075, 0.125, 0.175, 0.225])
    base = 3.0 * centres + np.array([0.05, -0.04, 0.03, 0.02, -0.05])  # R < 1
    recs, alpha = exact_records(base, centres)
    s0 = sensitivity(recs, "wind_shear_exponent", bin_width=0.05, reference_range=None)
    # independent expectation: scipy on the bin means, std of alpha by formula
    reg = scipy.stats.linregress(centres, base)
    std = np.std(alpha[:, 0], ddof=1)
    stat = reg.slope * std if which == 12 else reg.slope * std * reg.rvalue
    np.testing.assert_allclose(s0.slope.values[0], reg.slope, rtol=1e-9)
    np.testing.assert_allclose(s0.correlation.values[0], reg.rvalue, rtol=1e-9)
    scale = target_stat / stat  # slope scales with the differences; R and std do not
    recs2, _ = exact_records(base * scale, centres)
    return sensitivity(recs2, "wind_shear_exponent", bin_width=0.05, reference_range=None)


@pytest.mark.parametrize(
    ("which", "target", "flag12", "flag13"),
    [
        (12, 0.5005, 1, 1),  # just above Eq. 12 (R ~ 0.99 so Eq. 13 passes too)
        (12, 0.4995, 0, 1),  # just below Eq. 12
        (13, 0.1001, 0, 1),  # just above Eq. 13 only
        (13, 0.0999, 0, 0),  # just below both
    ],
)
def test_significance_just_above_and_below(which, target, flag12, flag13):
    s = _scaled_case(target, which)
    stat = s.slope_times_std if which == 12 else s.slope_times_std_times_r
    np.testing.assert_allclose(stat.values[0], target, rtol=1e-8)  # margins are 1e-3 relative
    assert int(s.significant_eq12[0]) == flag12
    assert int(s.significant_eq13[0]) == flag13
    assert int(s.significant[0]) == (flag12 | flag13)


def test_thin_bins_are_dropped_but_kept_in_table():
    centres = np.array([0.025, 0.075, 0.125, 0.175])
    means = 2.0 * centres
    recs, _ = exact_records(means, centres)
    # add two periods in a fifth bin far off the line: must not influence the regression
    extra = recs.isel(time=[0, 1]).copy(deep=True)
    extra["time"] = extra.time + np.timedelta64(1, "D")
    extra["wind_shear_exponent"][:] = 0.225
    extra["lidar_wind_speed"][:] = 8.0 * 1.5  # +50 %
    recs = xr.concat([recs, extra], dim="time")
    s = sensitivity(recs, "wind_shear_exponent", bin_width=0.05, reference_range=None, min_samples=3)
    assert s.sample_count.values[0].tolist() == [5, 5, 5, 5, 2]
    assert s.bin_flag.values[0].tolist() == [0, 0, 0, 0, 1]
    assert np.isnan(s.mean_difference.values[0, 4])
    np.testing.assert_allclose(s.slope.values[0], 2.0, atol=1e-9)
    assert int(s.periods_used[0]) == 20 and int(s.bins_used[0]) == 4
    s2 = sensitivity(recs, "wind_shear_exponent", bin_width=0.05, reference_range=None, min_samples=2)
    assert s2.slope.values[0] > 10  # the outlier bin now pulls the slope


def test_noisy_records_recover_slope_within_statistics():
    recs = make_records(n=3000, shear_slope=(2.0, -1.0), noise=0.5, seed=3)
    s = sensitivity(recs, "wind_shear_exponent")
    # 6 bins of ~500 periods: bin-mean noise 0.5/sqrt(500) = 0.022 %; slope stderr ~0.022/0.085/sqrt(6)
    # ~ 0.1 % per unit alpha; allow 4 sigma
    np.testing.assert_allclose(s.slope.values, [2.0, -1.0], atol=0.45)
    assert (np.abs(s.slope.values - [2.0, -1.0]) < 4 * s.slope_standard_error.values + 1e-9).all()
    # std of a uniform(0, 0.3) shear is 0.3/sqrt(12) = 0.0866; 3000 samples -> ~1 % sampling error
    np.testing.assert_allclose(s.variable_std.values, 0.3 / np.sqrt(12), rtol=0.04)


def test_dask_records_give_identical_result():
    recs = make_records(n=500)
    eager = sensitivity(recs, "turbulence_intensity")
    lazy = sensitivity(recs.chunk(time=100), "turbulence_intensity")
    for name in ("mean_difference", "sample_count", "slope", "correlation", "variable_std"):
        np.testing.assert_array_equal(eager[name].values, lazy[name].values)


def test_units_are_converted_at_the_boundary():
    recs = make_records(n=400)
    kmh = recs.copy()
    for name in ("lidar_wind_speed", "reference_wind_speed"):
        kmh[name] = recs[name] * 3.6
        kmh[name].attrs = {**recs[name].attrs, "units": "km h-1"}
    a = sensitivity(recs, "wind_shear_exponent")
    b = sensitivity(kmh, "wind_shear_exponent")
    np.testing.assert_allclose(a.slope.values, b.slope.values, rtol=1e-9)
    bad = recs.copy()
    bad["reference_wind_speed"].attrs["units"] = "K"
    with pytest.raises(UnitError, match="'reference_wind_speed' has units 'K'"):
        sensitivity(bad, "wind_shear_exponent")
    with pytest.raises(MissingVariableError, match="'cnr_gradient'"):
        sensitivity(recs.drop_vars("cnr_gradient"), "cnr_gradient")


def test_too_few_samples_for_any_bin_is_a_clear_error(tmp_path):
    recs = make_records(n=10, heights=(80.0,))
    recs.attrs["lidarcal_source_file"] = "tiny.nc"
    with pytest.raises(
        InputError,
        match=r"tiny.nc: variable 'wind_shear_exponent': no bin has at least "
        r"min_samples=5",
    ):
        sensitivity(recs, "wind_shear_exponent", min_samples=5)
    path = tmp_path / "tiny.nc"
    recs.to_netcdf(path)
    out = tmp_path / "sens.nc"
    rc = main(
        ["sensitivity", str(path), "--variable", "wind_shear_exponent", "--min-samples", "5", "-o", str(out)]
    )
    assert rc == 2 and not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["tiny.nc"]


def test_height_not_in_records():
    with pytest.raises(InputError, match=r"height\(s\) 100 m not in the records; available heights: 80, 120"):
        sensitivity(make_records(n=50), "wind_shear_exponent", heights=[100.0])


def test_cli_several_variables_and_valid_artefacts(tmp_path, capsys):
    path = tmp_path / "records.nc"
    make_records(n=600).to_netcdf(path)
    pattern = str(tmp_path / "sens_{variable}.nc")
    rc = main(
        [
            "sensitivity",
            str(path),
            "--variable",
            "wind_shear_exponent",
            "--variable",
            "cnr",
            "--bin-width",
            "cnr=2",
            "-o",
            pattern,
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "sens_cnr.nc" in text and "Eq12" in text
    s = open_artefact(tmp_path / "sens_cnr.nc", "sensitivity")
    assert s.slope.attrs["units"] == "% dB-1" and s.bin.attrs["units"] == "dB"
    np.testing.assert_allclose(np.diff(s.bin.values), 2.0)
    assert validate_dataset(s) == []
    # refuses to overwrite
    assert main(["sensitivity", str(path), "--variable", "cnr", "-o", str(tmp_path / "sens_cnr.nc")]) == 2
    # several variables need {variable} in the output name
    assert (
        main(
            [
                "sensitivity",
                str(path),
                "--variable",
                "cnr",
                "--variable",
                "wind_speed",
                "-o",
                str(tmp_path / "x.nc"),
            ]
        )
        == 2
    )


def test_written_artefact_passes_compliance(tmp_path):
    from lidarcal.compliance import check_compliance

    s = sensitivity(make_records(n=400), "cnr_gradient")
    path = write_artefact(s, tmp_path / "s.nc")
    report = check_compliance(path)
    assert report.passed, report.failures
    assert s.slope.attrs["units"] == "% m dB-1"  # per (dB m-1): the documented per-dB exception


def test_compare_slopes_lines_up_simulated_and_measured():
    sim = sensitivity(make_records(n=600, heights=(80.0, 120.0), seed=1), "wind_shear_exponent")
    meas = sensitivity(make_records(n=600, heights=(80.0, 100.0), seed=2), "wind_shear_exponent")
    both = compare_slopes({"simulated": sim, "measured": meas})
    assert both.slope.dims == ("source", "height")
    assert both.height.values.tolist() == [80.0, 100.0, 120.0]
    assert np.isnan(both.slope.sel(source="simulated", height=100.0))
    assert float(both.slope.sel(source="measured", height=80.0)) == float(meas.slope.sel(height=80.0))
    with pytest.raises(InputError, match="different variables"):
        compare_slopes({"a": sim, "b": sensitivity(make_records(n=600), "turbulence_intensity")})
