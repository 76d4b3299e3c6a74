"""Where do measurement and model disagree?  Pure numpy statistics on (period, height) arrays.

All arrays are ``(n_periods, n_heights)``; NaN marks an unusable period at a height.  The
*residual* is the measured relative difference minus the simulated one,
``r = (L_meas − R_meas)/R_meas − (L_sim − R_sim)/R_sim`` (a fraction; reported in %).

Significance (:func:`disagreement_tests`): per height and per environmental variable the
residual is binned (quantile bins shared by all heights), each bin mean gets a one-sample
t statistic (periods are independent 10-minute trials, so the bin's standard error is
std/√n), converted to an equivalent standard-normal score through the t distribution
(exact for small bins), and the bin scores are summed in squares into a chi-square with one
degree of freedom per populated bin: a test of "all bin means are zero" that sees constant
biases and trends alike.  The family of (height × variable) tests is Holm–Bonferroni
corrected, so the family-wise false-alarm rate on a campaign the model explains is ``alpha``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats as _st

from lidarcal.binning import binned_statistics

__all__ = [
    "relative_difference", "bin_edges", "binned_means", "BinnedResiduals", "bin_residuals",
    "holm", "disagreement_tests", "gap", "GAP_METRIC",
]

#: The definition of the gap reported by ``diagnose`` (``gap_metric`` in ``docs/diagnose.md``).
GAP_METRIC = (
    "rms, over heights, environmental variables and their quantile bins (bins with at least "
    "min_bin_count periods), of the bin-mean residual r = (L-R)/R measured minus (L-R)/R "
    "simulated, in %; per height: the same rms over that height's bins"
)


def relative_difference(lidar: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(lidar − reference)/reference, NaN where either is missing or the reference is ≤ 0."""
    lidar = np.asarray(lidar, dtype=float)
    reference = np.asarray(reference, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = (lidar - reference) / reference
    out[~(reference > 0)] = np.nan
    return out


def bin_edges(x: np.ndarray, n_bins: int) -> np.ndarray:
    """Quantile bin edges of the finite values of ``x`` (duplicates merged, ≥ 1 bin)."""
    finite = np.asarray(x, dtype=float)[np.isfinite(x)]
    if finite.size == 0:
        return np.array([0.0, 1.0])
    edges = np.unique(np.quantile(finite, np.linspace(0.0, 1.0, n_bins + 1)))
    if edges.size < 2:
        edges = np.array([edges[0] - 0.5, edges[0] + 0.5])
    return edges


def binned_means(r: np.ndarray, x: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per bin of ``x`` (1-D arrays): count, mean of ``r``, its standard error, mean of ``x``.

    Bins, missing values and the (two-pass) variance are those of :mod:`lidarcal.binning`; the
    last bin includes ``edges[-1]``, the largest value when ``edges`` are quantiles of ``x``.
    """
    count, mean, std, xmean = binned_statistics(x, r, edges)
    with np.errstate(invalid="ignore"):
        se = std / np.sqrt(count)
    return count.astype(float), mean, se, xmean


@dataclass
class BinnedResiduals:
    """Binned residuals: arrays ``(n_variables, n_bins, n_heights)``; edges ``(n_variables, n_bins+1)``."""

    variables: tuple[str, ...]
    edges: np.ndarray
    count: np.ndarray
    mean: np.ndarray
    se: np.ndarray
    center: np.ndarray


def bin_residuals(r: np.ndarray, drivers: dict[str, np.ndarray], n_bins: int = 6,
                  edges: dict[str, np.ndarray] | None = None) -> BinnedResiduals:
    """Bin the residual ``r`` (periods × heights) by every driver, separately per height.

    Bin edges are quantiles of each driver pooled over heights (or given in ``edges``, so
    residuals before and after a correction share the same bins).
    """
    names = tuple(drivers)
    n_h = r.shape[1]
    all_edges = np.full((len(names), n_bins + 1), np.nan)
    shape = (len(names), n_bins, n_h)
    count, mean, se, center = (np.full(shape, np.nan) for _ in range(4))
    count[:] = 0.0
    for i, name in enumerate(names):
        e = edges[name] if edges is not None else bin_edges(drivers[name], n_bins)
        nb = e.size - 1
        all_edges[i, : e.size] = e
        for j in range(n_h):
            c, m, s, xm = binned_means(r[:, j], drivers[name][:, j], e)
            count[i, :nb, j], mean[i, :nb, j], se[i, :nb, j], center[i, :nb, j] = c, m, s, xm
    return BinnedResiduals(names, all_edges, count, mean, se, center)


def holm(p: np.ndarray) -> np.ndarray:
    """Holm–Bonferroni adjusted p-values (same shape as ``p``; NaN entries stay NaN)."""
    p = np.asarray(p, dtype=float)
    flat = p.ravel()
    ok = np.isfinite(flat)
    vals = flat[ok]
    order = np.argsort(vals)
    m = vals.size
    adj = np.empty(m)
    running = 0.0
    for rank, k in enumerate(order):
        running = max(running, (m - rank) * vals[k])
        adj[k] = min(1.0, running)
    out = np.full(flat.shape, np.nan)
    out[ok] = adj
    return out.reshape(p.shape)


def _t_to_z(t: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Equivalent standard-normal score of a t statistic with n − 1 degrees of freedom."""
    return np.clip(_st.norm.isf(_st.t.sf(np.abs(t), np.maximum(n - 1, 1))) * np.sign(t), -40, 40)


def disagreement_tests(binned: BinnedResiduals, min_bin_count: int = 10,
                       residual: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Chi-square test per (variable, height) that all bin means are zero, Holm-adjusted.

    Returns ``chi2``, ``dof``, ``p_value`` and ``p_adjusted`` arrays of shape
    ``(n_variables, n_heights)`` and ``z`` (per bin, NaN for thin bins).  With ``residual``
    (periods × heights) the family also holds one t-test per height that the mean residual
    is zero (``mean_z``, ``mean_p_value``, ``mean_p_adjusted``): a constant bias is one degree
    of freedom, which the binned chi-square spreads over all bins.
    """
    n = binned.count
    ok = (n >= min_bin_count) & np.isfinite(binned.se) & (binned.se > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(ok, _t_to_z(binned.mean / binned.se, n), np.nan)
    chi2 = np.nansum(np.where(ok, z**2, 0.0), axis=1)
    dof = ok.sum(axis=1)
    p = np.where(dof > 0, _st.chi2.sf(chi2, np.maximum(dof, 1)), np.nan)
    out = {"chi2": chi2, "dof": dof, "p_value": p, "z": z}
    if residual is None:
        out["p_adjusted"] = holm(p)
        return out
    cnt = np.isfinite(residual).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.nanmean(residual, axis=0) / (np.nanstd(residual, axis=0, ddof=1) / np.sqrt(cnt))
        mz = np.where(cnt >= min_bin_count, _t_to_z(t, cnt), np.nan)
    mp = np.where(np.isfinite(mz), 2.0 * _st.norm.sf(np.abs(mz)), np.nan)
    adj = holm(np.concatenate([p.ravel(), mp]))
    out.update(p_adjusted=adj[: p.size].reshape(p.shape), mean_z=mz, mean_p_value=mp,
               mean_p_adjusted=adj[p.size:])
    return out


def gap(binned: BinnedResiduals, min_bin_count: int = 10) -> tuple[float, np.ndarray, float]:
    """Return the gap (see :data:`GAP_METRIC`) in %: overall, per height, and its noise floor.

    The noise floor is the rms of the bins' standard errors: the gap a perfect model would
    show on average with this many periods.
    """
    ok = (binned.count >= min_bin_count) & np.isfinite(binned.mean)
    sq = np.where(ok, binned.mean**2, 0.0)
    se2 = np.where(ok, binned.se**2, 0.0)
    with np.errstate(invalid="ignore"):
        per_height = 100.0 * np.sqrt(sq.sum(axis=(0, 1)) / ok.sum(axis=(0, 1)))
        overall = 100.0 * float(np.sqrt(sq.sum() / ok.sum())) if ok.any() else float("nan")
        floor = 100.0 * float(np.sqrt(se2.sum() / ok.sum())) if ok.any() else float("nan")
    return overall, per_height, floor
