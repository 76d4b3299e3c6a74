"""Pure numpy kernels of the analysis stage: bin edges, regression, significance, quadrature.

Binning itself is :func:`lidarcal.binning.binned_statistics`, the engine shared with the
bench and diagnose stages.

Nothing here knows about files, xarray or units: arguments are plain float arrays in SI
(or the caller's) units.  Functions that take data arrays work over the **last** axis and
broadcast over any leading axes, so the dataset layer can hand them ``(..., time)`` blocks.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from lidarcal.binning import bin_index

__all__ = [
    "edges_from_width",
    "centred_edges",
    "linear_regression",
    "bin_mean_weights",
    "weighted_linear_regression",
    "significance",
    "std_in_kept_bins",
    "quadrature",
]


def edges_from_width(lo: float, hi: float, width: float) -> np.ndarray:
    """Contiguous bin edges at integer multiples of ``width`` covering ``[lo, hi]``.

    >>> edges_from_width(0.03, 0.21, 0.05).round(2).tolist()
    [0.0, 0.05, 0.1, 0.15, 0.2, 0.25]
    """
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"cannot place bins: data range [{lo}, {hi}] is not finite")
    if not width > 0:
        raise ValueError(f"bin width must be positive; got {width}")
    first = np.floor(lo / width + 1e-9)
    last = np.floor(hi / width + 1e-9) + 1
    return np.arange(first, last + 1) * width


def centred_edges(lo: float, hi: float, width: float) -> np.ndarray:
    """Edges of bins *centred* on integer multiples of ``width`` (IEC 61400-12-1 style).

    A 0.5 m s-1 bin centred on 8 m s-1 covers [7.75, 8.25).

    >>> centred_edges(7.8, 8.3, 0.5).tolist()
    [7.75, 8.25, 8.75]
    """
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"cannot place bins: data range [{lo}, {hi}] is not finite")
    if not width > 0:
        raise ValueError(f"bin width must be positive; got {width}")
    first = np.floor(lo / width + 0.5 + 1e-9)
    last = np.floor(hi / width + 0.5 + 1e-9)
    return (np.arange(first, last + 2) - 0.5) * width


def linear_regression(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
    """Unweighted least-squares line ``y = slope * x + intercept`` over the last axis.

    Points where ``x`` or ``y`` is NaN are left out.  Equivalent to
    :func:`scipy.stats.linregress` on the finite points, vectorised over leading axes.

    Returns
    -------
    slope, intercept, r, slope_stderr : float arrays (...)
        NaN where fewer than two distinct ``x`` remain (``r`` and the stderr also NaN when
        fewer than three points or when ``y`` is constant).
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    x, y = np.broadcast_arrays(x, y)
    ok = np.isfinite(x) & np.isfinite(y)
    n = ok.sum(axis=-1)
    xz = np.where(ok, x, 0.0)
    yz = np.where(ok, y, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx = xz.sum(axis=-1) / n
        my = yz.sum(axis=-1) / n
        dx = np.where(ok, x - mx[..., None], 0.0)
        dy = np.where(ok, y - my[..., None], 0.0)
        sxx = (dx * dx).sum(axis=-1)
        syy = (dy * dy).sum(axis=-1)
        sxy = (dx * dy).sum(axis=-1)
        valid = (n >= 2) & (sxx > 0)
        slope = np.where(valid, sxy / sxx, np.nan)
        intercept = np.where(valid, my - slope * mx, np.nan)
        r = np.where(valid & (syy > 0), sxy / np.sqrt(sxx * syy), np.nan)
        r = np.clip(r, -1.0, 1.0)
        resid = np.maximum(syy - slope * sxy, 0.0)
        stderr = np.where(valid & (n > 2), np.sqrt(resid / np.maximum(n - 2, 1) / sxx), np.nan)
    return slope, intercept, r, stderr


def bin_mean_weights(count: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Inverse-variance weights ``1 / SE² = n / s²`` of bin means, over the last (bin) axis.

    ``count`` and ``std`` (ddof = 1) are per bin.  A bin whose own spread is unusable —
    fewer than two values, or ``s = 0`` (identical values: a spread of zero is a sampling
    accident, not an infinitely precise mean) — takes the **pooled** within-bin variance of
    its row, ``s_p² = Σ (n_i − 1) s_i² / Σ (n_i − 1)`` over the bins with a usable spread,
    so every non-empty bin gets a finite positive weight.  Empty bins (and rows without any
    usable spread) get weight 0 or NaN respectively.

    >>> bin_mean_weights(np.array([4, 1, 9]), np.array([2.0, np.nan, 1.0])).round(4).tolist()
    [1.0, 0.55, 9.0]
    """
    n = np.asarray(count, dtype=float)
    s = np.asarray(std, dtype=float)
    usable = (n >= 2) & np.isfinite(s) & (s > 0)
    dof = np.where(usable, n - 1.0, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        pooled = (dof * np.where(usable, s * s, 0.0)).sum(axis=-1) / dof.sum(axis=-1)
        var = np.where(usable, s * s, pooled[..., None])
        return np.where(n > 0, n / var, 0.0)


def weighted_linear_regression(x: np.ndarray, y: np.ndarray, w: np.ndarray,
                               confidence: float = 0.95) -> dict[str, np.ndarray]:
    """Weighted least-squares line ``y = slope x + intercept`` over the last axis.

    ``w`` are inverse variances of ``y`` (e.g. :func:`bin_mean_weights`); points where ``x``,
    ``y`` or ``w`` is not finite, or ``w <= 0``, are left out.  With ``k`` points,
    ``S = Σ w (x − x̄_w)²`` and ``χ²_ν = Σ w r² / (k − 2)`` of the residuals ``r``:

    * ``stderr = sqrt(max(1, χ²_ν) / S)``: the weights' own error scale, inflated by the
      Birge ratio when the bin means scatter more about the line than their errors allow
      (curvature, or spreads underestimated from few periods); never deflated below it;
    * ``ci_low, ci_high = slope ∓ t(1 − (1 − confidence)/2; k − 2) · stderr`` (Student t);
    * ``r`` is the weighted Pearson correlation coefficient (the R of Eq. 13).

    Returns a dict of arrays (...): ``slope, intercept, r, stderr, ci_low, ci_high,
    chi2_reduced, n_points``; NaN where fewer than two distinct ``x`` remain (stderr, CI and
    χ² also where ``k < 3``).  With equal weights ``slope``, ``intercept`` and ``r`` equal
    :func:`linear_regression`'s.
    """
    x, y, w = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (x, y, w)))
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(w) & (w > 0)
    wz = np.where(ok, w, 0.0)
    xz = np.where(ok, x, 0.0)
    yz = np.where(ok, y, 0.0)
    k = ok.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        sw = wz.sum(axis=-1)
        mx = (wz * xz).sum(axis=-1) / sw
        my = (wz * yz).sum(axis=-1) / sw
        dx = np.where(ok, x - mx[..., None], 0.0)
        dy = np.where(ok, y - my[..., None], 0.0)
        sxx = (wz * dx * dx).sum(axis=-1)
        syy = (wz * dy * dy).sum(axis=-1)
        sxy = (wz * dx * dy).sum(axis=-1)
        valid = (k >= 2) & (sxx > 0)
        slope = np.where(valid, sxy / sxx, np.nan)
        intercept = np.where(valid, my - slope * mx, np.nan)
        r = np.clip(np.where(valid & (syy > 0), sxy / np.sqrt(sxx * syy), np.nan), -1.0, 1.0)
        dof = np.where(k > 2, k - 2, 1)
        chi2 = np.where(valid & (k > 2), np.maximum(syy - slope * sxy, 0.0) / dof, np.nan)
        stderr = np.where(valid & (k > 2), np.sqrt(np.maximum(1.0, chi2) / sxx), np.nan)
        tq = stats.t.ppf(0.5 + confidence / 2.0, dof)
    return {"slope": slope, "intercept": intercept, "r": r, "stderr": stderr,
            "ci_low": slope - tq * stderr, "ci_high": slope + tq * stderr,
            "chi2_reduced": chi2, "n_points": k}


def significance(
    slope: np.ndarray, std: np.ndarray, r: np.ndarray, *, threshold_12: float = 0.5, threshold_13: float = 0.1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Significance tests of the paper's Eqs. 12 and 13 (IEC 61400-50-2 style).

    ``|m·std| > threshold_12`` (Eq. 12, 0.5 %) and ``|m·std·R| > threshold_13`` (Eq. 13,
    0.1 %), with ``m`` in % per unit of the variable and ``std`` in that unit.

    Returns
    -------
    m_std, m_std_r : float arrays
        The two test statistics (signed, in %).
    sig_12, sig_13 : bool arrays
        Whether each test is passed (strictly greater); False where the statistic is NaN.

    >>> significance(np.array([10.0]), np.array([0.06]), np.array([0.2]))[2:]
    (array([ True]), array([ True]))
    """
    slope, std, r = (np.asarray(a, dtype=float) for a in (slope, std, r))
    m_std = slope * std
    m_std_r = m_std * r
    with np.errstate(invalid="ignore"):
        sig_12 = np.abs(m_std) > threshold_12
        sig_13 = np.abs(m_std_r) > threshold_13
    return m_std, m_std_r, sig_12, sig_13


def std_in_kept_bins(
    x: np.ndarray, y: np.ndarray, keep: np.ndarray, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Sample standard deviation (ddof = 1) of ``x`` over the pairs that fall in kept bins.

    Parameters
    ----------
    x, y : array, shape (..., n)
        Binning variable and values; a pair counts only if ``y`` is finite and ``x`` falls in
        a bin of ``edges`` (the rule of :mod:`lidarcal.binning`) whose ``keep`` is True.
    keep : bool array, shape (..., nbins)
        Which bins are used (e.g. those with enough samples).
    edges : array, shape (nbins + 1,)

    Returns
    -------
    std : float array (...)
        NaN where fewer than two pairs count.
    n : int array (...)
        Number of pairs that count.

    >>> std_in_kept_bins(np.array([0.1, 0.2, 1.5]), np.ones(3), np.array([True, False]),
    ...                  np.array([0.0, 1.0, 2.0]))[1]
    np.int64(2)
    """
    idx = bin_index(x, edges)
    k = np.take_along_axis(keep, np.maximum(idx, 0), axis=-1) & (idx >= 0) & np.isfinite(y)
    n = k.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = np.where(k, x, 0.0).sum(axis=-1) / n
        ss = (np.where(k, x - m[..., None], 0.0) ** 2).sum(axis=-1)
        return np.where(n > 1, np.sqrt(ss / (n - 1)), np.nan), n


def quadrature(*terms: np.ndarray, axis: int | None = None) -> np.ndarray:
    """Root sum of squares of uncertainty terms (NaN if any term is NaN).

    With ``axis`` a single array is combined along that axis.

    >>> float(quadrature(np.array(3.0), np.array(4.0)))
    5.0
    """
    if axis is not None:
        (arr,) = terms
        arr = np.asarray(arr, dtype=float)
        return np.sqrt((arr * arr).sum(axis=axis))
    total = np.zeros(np.broadcast_shapes(*(np.shape(t) for t in terms)))
    for t in terms:
        t = np.asarray(t, dtype=float)
        total = total + t * t
    return np.sqrt(total)
