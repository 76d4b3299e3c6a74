"""Numpy kernels of the campaign uncertainty: the 50-2 route, the expected deviation, the groups.

Plain numbers in, plain numbers out (SI floats; relative deviations in %); nothing here knows
files or metadata.

* :func:`iec_deviations` — the 50-2 route: each significant slope times the difference between
  a period's condition and the calibration's mean of it (``docs/smc.md`` gives the formula and
  its sources);
* :func:`within_bin_fit` / :func:`expected_deviation` — the Monte Carlo route's deviation
  expected of a period given its conditions: per wind-speed bin the mean simulated deviation,
  and pooled within-bin least-squares slopes on the conditions;
* :func:`group_of` — the JCGM 101 §7.9 sequences the trials of a bin are split into;
* :func:`quadrature` — root-sum-square, NaN where any part is NaN.
"""

from __future__ import annotations

import numpy as np

from lidarcal.binning import bin_index

__all__ = [
    "binned_quantiles",
    "quadrature",
    "iec_deviations",
    "within_bin_fit",
    "expected_deviation",
    "expected_deviation_se",
    "binned_mean_uncertainty",
    "binned_mean_sums",
    "binned_mean_finish",
    "group_of",
    "bin_index",
    "SEQUENCES",
]

#: Sequences (h of JCGM 101 §7.9.4) the trials of a bin are split into for its numerical tolerance.
SEQUENCES = 4


def quadrature(*parts: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Root-sum-square of ``parts`` (or of ``parts[0]`` along ``axis``); NaN where any part is NaN.

    >>> float(quadrature(np.array(3.0), np.array(4.0)))
    5.0
    """
    if axis is not None:
        a = np.asarray(parts[0], dtype=float)
        return np.sqrt(np.sum(a * a, axis=axis))
    total = np.zeros(np.broadcast_shapes(*(np.shape(p) for p in parts)))
    for p in parts:
        total = total + np.square(np.asarray(p, dtype=float))
    return np.sqrt(total)


def iec_deviations(x: np.ndarray, slope: np.ndarray, calibration_mean: np.ndarray) -> np.ndarray:
    """Deviation each variable's slope predicts for each period: ``m_j · (x_j − x̄_j,cal)``.

    ``x`` (variable, ...) the periods' conditions, ``slope`` the slopes in units of the deviation
    per unit of their variable and ``calibration_mean`` the calibration's mean of each variable
    over the periods its regression used, both broadcastable to ``x`` (e.g. (variable, 1,
    height)).  NaN where a condition is missing.

    >>> iec_deviations(np.array([[0.15, 0.05]]), np.array([[-10.0]]), np.array([[0.10]])).round(6).tolist()
    [[-0.5, 0.5]]
    """
    return np.asarray(slope, dtype=float) * (
        np.asarray(x, dtype=float) - np.asarray(calibration_mean, dtype=float)
    )


def within_bin_fit(
    deviation: np.ndarray, conditions: np.ndarray, bins: np.ndarray, n_bins: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-bin means and pooled within-bin slopes of ``deviation`` on ``conditions``.

    ``deviation`` (trial,), ``conditions`` (trial, variable), ``bins`` (trial,) the bin index of
    each trial (-1: outside every bin).  Rows with a NaN are left out.  Returns
    ``(count (bin,), mean deviation (bin,), mean conditions (bin, variable), slopes (variable,))``:
    the least-squares fit of ``d − d̄_b = Σ_j β_j (x_j − x̄_j,b)`` over all trials, each variable
    scaled to unit within-bin spread first (a variable without spread inside any bin gets β = 0).

    >>> b = np.array([0, 0, 1, 1]); x = np.array([[1.0], [3.0], [1.0], [3.0]])
    >>> n, m, xm, beta = within_bin_fit(np.array([1.0, 2.0, 5.0, 6.0]), x, b, 2)
    >>> n.tolist(), m.tolist(), xm.ravel().tolist(), beta.tolist()
    ([2, 2], [1.5, 5.5], [2.0, 2.0], [0.5])
    """
    d = np.asarray(deviation, dtype=float)
    x = np.asarray(conditions, dtype=float).reshape(d.size, -1)
    b = np.asarray(bins)
    ok = (b >= 0) & np.isfinite(d) & np.isfinite(x).all(axis=1)
    d, x, b = d[ok], x[ok], b[ok]
    p = x.shape[1]
    count = np.bincount(b, minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_d = np.bincount(b, weights=d, minlength=n_bins) / count
        mean_x = (
            np.stack([np.bincount(b, weights=x[:, j], minlength=n_bins) for j in range(p)], axis=-1)
            / count[:, None]
            if p
            else np.zeros((n_bins, 0))
        )
    beta = np.zeros(p)
    if d.size and p:
        dc = d - mean_d[b]
        xc = x - mean_x[b]
        scale = np.sqrt(np.mean(xc * xc, axis=0))
        use = scale > 0
        if use.any():
            coef, *_ = np.linalg.lstsq(xc[:, use] / scale[use], dc, rcond=None)
            beta[use] = coef / scale[use]
    return count, mean_d, mean_x, beta


def expected_deviation(
    conditions: np.ndarray,
    bins: np.ndarray,
    mean_d: np.ndarray,
    mean_x: np.ndarray,
    beta: np.ndarray,
    usable: np.ndarray,
) -> np.ndarray:
    """``d̄_b + Σ_j β_j (x_j − x̄_j,b)`` for each period (``conditions`` (period, variable), ``bins``).

    NaN where the period is outside every bin, its bin is not ``usable`` (bin,) or a condition
    is missing.
    """
    x = np.asarray(conditions, dtype=float)
    b = np.asarray(bins)
    inside = b >= 0
    bi = np.where(inside, b, 0)
    out = mean_d[bi] + ((x - mean_x[bi]) * np.asarray(beta)[None, :]).sum(axis=1)
    return np.where(inside & np.asarray(usable)[bi], out, np.nan)


def expected_deviation_se(
    deviation: np.ndarray,
    conditions: np.ndarray,
    bins: np.ndarray,
    at: np.ndarray,
    at_bins: np.ndarray,
) -> np.ndarray:
    """Return the standard error of :func:`expected_deviation` at each period (the fitted value's).

    The fit of :func:`within_bin_fit` on the trials (``deviation``, ``conditions`` (trial,
    variable), ``bins``), evaluated at ``at`` (period, variable) in ``at_bins``:
    ``σ √(1/n_b + (x − x̄_b)ᵀ (X_cᵀ X_c)⁻¹ (x − x̄_b))`` with X_c the trials' conditions centred in
    their bins, σ² the residual variance on (trials − bins − slopes) degrees of freedom (ordinary
    least squares, trials taken as independent).  Variables without spread inside any bin have no
    slope and add nothing.  NaN where the bin has fewer than 2 trials or a condition is missing.

    >>> b = np.array([0, 0, 0, 0]); x = np.array([[0.0], [1.0], [2.0], [3.0]])
    >>> d = np.array([0.0, 1.1, 1.9, 3.0])  # slope 0.98, residual sum of squares 0.018 on 2 dof
    >>> round(float(expected_deviation_se(d, x, b, np.array([[1.5]]), np.array([0]))[0]), 6)  # sqrt(0.009/4)
    0.047434
    """
    d = np.asarray(deviation, dtype=float)
    x = np.asarray(conditions, dtype=float).reshape(d.size, -1)
    b = np.asarray(bins)
    ok = (b >= 0) & np.isfinite(d) & np.isfinite(x).all(axis=1)
    d, x, b = d[ok], x[ok], b[ok]
    at = np.asarray(at, dtype=float).reshape(np.shape(at_bins)[0], -1)
    ab = np.asarray(at_bins)
    n_bins = int(max(b.max(initial=-1), ab.max(initial=-1))) + 1
    count = np.bincount(b, minlength=n_bins)
    out = np.full(ab.size, np.nan)
    if not d.size:
        return out
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_d = np.bincount(b, weights=d, minlength=n_bins) / count
        mean_x = np.stack([np.bincount(b, weights=x[:, j], minlength=n_bins) for j in range(x.shape[1])],
                          axis=-1) / count[:, None]
    xc = x - mean_x[b]
    use = np.sqrt(np.mean(xc * xc, axis=0)) > 0
    xc = xc[:, use]
    dc = d - mean_d[b]
    if use.any():
        coef, *_ = np.linalg.lstsq(xc, dc, rcond=None)
        resid = dc - xc @ coef
        inv = np.linalg.pinv(xc.T @ xc)
    else:
        resid, inv = dc, np.zeros((0, 0))
    dof = d.size - int((count > 0).sum()) - int(use.sum())
    if dof < 1:
        return out
    sigma2 = float(resid @ resid) / dof
    inside = (ab >= 0) & np.isfinite(at).all(axis=1)
    bi = np.where(inside, ab, 0)
    dx = (at - mean_x[bi])[:, use]
    lever = np.einsum("ij,jk,ik->i", dx, inv, dx) if use.any() else 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        se = np.sqrt(sigma2 * (1.0 / count[bi] + lever))
    return np.where(inside & (count[bi] >= 2), se, np.nan)


def binned_mean_uncertainty(
    correlated: np.ndarray, random: np.ndarray, bins: np.ndarray, n_bins: int
) -> tuple[np.ndarray, np.ndarray]:
    """Return the standard uncertainty of a bin's mean of its periods per contributor, and the counts.

    ``correlated`` and ``random`` (contributor, period): each period's standard uncertainty split
    into a part fully correlated across periods and a part independent between them; ``bins``
    (period,) each period's bin (-1: left out; a period with a NaN in any part is left out too).
    For the mean of n periods, ū = Σ u(t) / n: a fully correlated part adds linearly,
    ``Σ c(t) / n``, an independent one in quadrature, ``√(Σ r(t)²) / n``, and the two combine in
    quadrature (GUM 5.2).

    >>> c = np.array([[1.0, 1.0, 1.0, 1.0]]); r = np.array([[2.0, 2.0, 2.0, 2.0]])
    >>> u, n = binned_mean_uncertainty(c, r, np.zeros(4, int), 1)
    >>> float(u[0, 0]), int(n[0])  # sqrt(1 + (sqrt(16) / 4)^2)
    (1.4142135623730951, 4)
    """
    n, s1, s2 = binned_mean_sums(correlated, random, bins, n_bins)
    return binned_mean_finish(n[None, :], s1, s2), n


def binned_mean_sums(
    correlated: np.ndarray, random: np.ndarray, bins: np.ndarray, n_bins: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return what :func:`binned_mean_uncertainty` adds up: per bin n, Σ c(t) and Σ r(t)² per contributor.

    Sums of several blocks of periods add, so :func:`binned_mean_finish` of their totals is the
    uncertainty of the bin's mean over every period (``correlated``, ``random`` and ``bins`` as
    for :func:`binned_mean_uncertainty`; n (bin,), the sums (contributor, bin)).
    """
    c = np.asarray(correlated, dtype=float)
    r = np.asarray(random, dtype=float)
    b = np.asarray(bins)
    ok = (b >= 0) & np.isfinite(c).all(axis=0) & np.isfinite(r).all(axis=0)
    n = np.bincount(b[ok], minlength=n_bins)
    s1 = np.array([np.bincount(b[ok], weights=c[k, ok], minlength=n_bins) for k in range(c.shape[0])])
    s2 = np.array([np.bincount(b[ok], weights=r[k, ok] ** 2, minlength=n_bins) for k in range(c.shape[0])])
    return n, s1.reshape(c.shape[0], n_bins), s2.reshape(c.shape[0], n_bins)


def binned_mean_finish(n: np.ndarray, s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """ū = √((Σ c / n)² + Σ r² / n²) from :func:`binned_mean_sums`' totals; NaN where n is 0."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt((s1 / n) ** 2 + s2 / n**2), np.nan)


def group_of(period_key: np.ndarray, replica: np.ndarray, sequences: int = SEQUENCES) -> np.ndarray:
    """Return the sequence (0 … h − 1) of each trial: ``(period_key // 600 + replica) mod h``.

    Consecutive periods alternate, and the replicas of one period go to different sequences,
    so every sequence samples the campaign's conditions alike; a trial is in exactly one.

    >>> group_of(np.array([0, 600, 1200, 1800, 2400, 0]), np.array([0, 0, 0, 0, 0, 1])).tolist()
    [0, 1, 2, 3, 0, 1]
    """
    k = np.asarray(period_key, dtype=np.int64) // 600
    return np.asarray((k + np.asarray(replica, dtype=np.int64)) % int(sequences), dtype=np.int64)


def binned_quantiles(bounds: np.ndarray, counts: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Quantiles ``q`` of a distribution known by its bin table, linear inside each bin.

    ``bounds`` (bin, 2) the bins' edges, ``counts`` (bin,) the values in each.  NaN without any
    value.

    >>> b = np.array([[-1.0, 0.0], [0.0, 1.0], [1.0, 2.0], [2.0, 3.0]])
    >>> binned_quantiles(b, np.array([0, 1, 3, 0]), np.array([0.0, 0.25, 0.5, 1.0])).tolist()
    [0.0, 1.0, 1.3333333333333333, 2.0]
    """
    bounds = np.asarray(bounds, dtype=float)
    counts = np.asarray(counts, dtype=float)
    filled = np.flatnonzero(counts > 0)
    if not filled.size:
        return np.full(np.shape(q), np.nan)
    bounds, counts = bounds[filled[0]:filled[-1] + 1], counts[filled[0]:filled[-1] + 1]  # no empty ends
    edges = np.append(bounds[:, 0], bounds[-1, 1])
    cdf = np.append(0.0, np.cumsum(counts)) / counts.sum()
    keep = np.append(True, np.diff(cdf) > 0)  # an empty bin inside has no inverse: its start stands
    return np.interp(np.asarray(q, dtype=float), cdf[keep], edges[keep])
