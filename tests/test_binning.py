"""The one binning engine (lidarcal.binning) against a brute-force per-bin loop written here."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarcal.binning import bin_index, binned_statistics, group_statistics


def brute_force(x, y, edges, ddof=1):
    """Per-bin count, mean, std (ddof), mean of x by plain Python loops over every pair.

    Edge rule written out: bin i holds edges[i] <= x < edges[i+1], the last bin also x == edges[-1];
    a pair counts only if x and y are both finite.
    """
    nb = len(edges) - 1
    members = [[] for _ in range(nb)]
    for xi, yi in zip(x, y, strict=True):
        if not (math.isfinite(xi) and math.isfinite(yi)):
            continue
        for i in range(nb):
            last = i == nb - 1
            if edges[i] <= xi < edges[i + 1] or (last and xi == edges[-1]):
                members[i].append((xi, yi))
                break
    count, mean, std, mean_x = [], [], [], []
    for m in members:
        n = len(m)
        count.append(n)
        my = sum(v for _, v in m) / n if n else math.nan
        mean.append(my)
        mean_x.append(sum(u for u, _ in m) / n if n else math.nan)
        std.append(math.sqrt(sum((v - my) ** 2 for _, v in m) / (n - ddof)) if n > ddof else math.nan)
    return np.array(count), np.array(mean), np.array(std), np.array(mean_x)


def test_edges_nan_and_out_of_range_follow_numpy_histogram():
    edges = np.array([0.0, 1.0, 2.0, 3.0])
    x = np.array([-0.5, 0.0, 1.0, 1.0, 2.999, 3.0, 3.5, np.nan, 2.0, np.inf, -np.inf])
    np.testing.assert_array_equal(bin_index(x, edges), [-1, 0, 1, 1, 2, 2, -1, -1, 2, -1, -1])
    # the counts are those of numpy.histogram (which drops NaN/inf too)
    finite = x[np.isfinite(x)]
    count = binned_statistics(x, np.ones_like(x), edges)[0]
    np.testing.assert_array_equal(count, np.histogram(finite, edges)[0])


def test_values_on_edges_and_nans_against_brute_force():
    edges = np.array([0.0, 0.5, 1.0, 1.5])
    x = np.array([0.0, 0.5, 0.5, 1.0, 1.5, 1.5, 0.25, np.nan, 0.75, 1.2, 1.6, -0.1])
    y = np.array([1.0, 2.0, 4.0, 8.0, 3.0, 5.0, np.nan, 7.0, 6.0, 2.5, 9.0, 9.0])
    got = binned_statistics(x, y, edges)
    want = brute_force(x, y, edges)
    np.testing.assert_array_equal(got[0], want[0])
    for g, w in zip(got[1:], want[1:], strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-14, equal_nan=True)  # a few roundings apart
    np.testing.assert_array_equal(got[0], [1, 3, 4])  # 1.5 (the last edge) twice in the last bin


def test_two_pass_variance_keeps_small_spread_on_a_large_offset():
    # one-pass E[y^2] - E[y]^2 loses every digit at 1e9 +- 1e-3; the two-pass form keeps them
    y = 1e9 + np.array([-1e-3, 0.0, 1e-3])
    std = group_statistics(y, np.zeros(3, dtype=int), 1)[2]
    # float64 spacing at 1e9 is 1.2e-7, so each offset is stored within 6e-8 (6e-5 of 1e-3)
    assert std[0] == pytest.approx(1e-3, rel=2e-4)
    one_pass = np.sqrt((np.sum(y * y) - y.size * y.mean() ** 2) / 2)
    assert not one_pass == pytest.approx(1e-3, rel=2e-4)  # the formula this engine replaced fails here


def test_leading_axes_are_independent_rows():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 3, size=(2, 4, 50))
    y = rng.normal(size=(2, 4, 50))
    edges = np.array([0.0, 1.0, 2.0, 3.0])
    got = binned_statistics(x, y, edges, ddof=0)
    for i in range(2):
        for j in range(4):
            want = brute_force(x[i, j], y[i, j], edges, ddof=0)
            for g, w in zip(got, want, strict=True):
                np.testing.assert_allclose(g[i, j], w, rtol=1e-12, equal_nan=True)


def test_negative_labels_are_no_group():
    c, m, s = group_statistics(np.array([1.0, 2.0, 10.0]), np.array([0, 0, -1]), 2)
    np.testing.assert_array_equal(c, [2, 0])
    assert m[0] == 1.5 and np.isnan(m[1]) and np.isnan(s[1])


def test_standard_error_of_the_mean_instead_of_the_std():
    y, lab = np.array([1.0, 3.0, 8.0, 5.0, 9.0]), np.array([0, 0, 1, 1, 1])
    c, m, se = group_statistics(y, lab, 2, standard_error=True)
    std = group_statistics(y, lab, 2)[2]
    want = [np.std([1.0, 3.0], ddof=1) / np.sqrt(2), np.std([8.0, 5.0, 9.0], ddof=1) / np.sqrt(3)]
    np.testing.assert_allclose(se, want, rtol=1e-15)
    np.testing.assert_allclose(se, std / np.sqrt(c), rtol=1e-15)
    one = group_statistics(np.array([1.0]), np.array([0]), 1, standard_error=True)
    assert np.isnan(one[2][0])  # no spread from one value


finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
maybe_nan = st.one_of(finite, st.just(math.nan))


@settings(max_examples=150, deadline=None)
@given(
    pairs=st.lists(st.tuples(st.one_of(maybe_nan, st.sampled_from([-1.0, 0.0, 0.5, 2.0])), maybe_nan),
                   max_size=40),
    inner=st.lists(st.floats(-2, 3, allow_nan=False), min_size=1, max_size=5, unique=True),
)
def test_property_matches_brute_force(pairs, inner):
    # x drawn partly from the edges themselves, so values on edges are exercised every run
    edges = np.array(sorted({-1.0, 2.0, *inner}))
    x = np.array([p[0] for p in pairs], dtype=float)
    y = np.array([p[1] for p in pairs], dtype=float)
    got = binned_statistics(x, y, edges)
    want = brute_force(x, y, edges)
    np.testing.assert_array_equal(got[0], want[0])
    assert got[0].sum() == np.histogram(x[np.isfinite(x) & np.isfinite(y)], edges)[0].sum()
    # sums of <= 40 values of magnitude <= 1e3 agree to ~1e-12 absolute between summation orders
    for g, w in zip(got[1:], want[1:], strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-9, atol=1e-9, equal_nan=True)
