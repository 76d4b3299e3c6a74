"""Pure numpy kernels of the bench stage: matching samples to bins, robust rejection.

Per-cell statistics go through :func:`lidarcal.binning.group_statistics`, the engine shared
with the analysis and diagnose stages.

No files, no xarray, no units: times are int64 nanoseconds, velocities m s-1, CNR dB.
Everything is vectorised (``searchsorted``, ``lexsort``, ``bincount``); nothing loops over
samples in Python.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "USED", "OUTSIDE", "TRANSITION", "LOS_MISMATCH", "REJECTED",
    "match_to_bins", "group_median", "robust_location", "reject_outliers", "between_run_stats",
    "pad_groups",
]

#: Sample status codes returned by :func:`match_to_bins` / set by :func:`reject_outliers`.
USED, OUTSIDE, TRANSITION, LOS_MISMATCH, REJECTED = 0, 1, 2, 3, 4


def match_to_bins(
    t_ns: np.ndarray,
    los: np.ndarray,
    start_ns: np.ndarray,
    end_ns: np.ndarray,
    bin_los: np.ndarray,
    settling_ns: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Assign each sample to the programmed bin whose ``[start, end)`` interval contains it.

    Bins must be sorted by start and must not overlap.  Returns ``(bin_index, status)``:
    ``bin_index`` is −1 for samples outside every bin; ``status`` is :data:`OUTSIDE`,
    :data:`TRANSITION` (within ``settling_ns`` of the bin start), :data:`LOS_MISMATCH`
    (the lidar's beam is not the one the bench feeds) or :data:`USED`.
    """
    idx = np.searchsorted(start_ns, t_ns, side="right") - 1
    j = np.clip(idx, 0, None)
    inside = (idx >= 0) & (t_ns < end_ns[j])
    status = np.full(t_ns.shape, USED, dtype=np.int8)
    status[~inside] = OUTSIDE
    status[inside & (t_ns - start_ns[j] < settling_ns)] = TRANSITION
    status[(status == USED) & (los != bin_los[j])] = LOS_MISMATCH
    return np.where(inside, idx, -1), status


def group_median(values: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """Median of ``values`` per group label in ``0..n_groups-1`` (NaN for empty groups)."""
    order = np.lexsort((values, groups))
    v = values[order]
    counts = np.bincount(groups, minlength=n_groups)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    lo = np.minimum(first + (counts - 1) // 2, max(len(v) - 1, 0))
    hi = np.minimum(first + counts // 2, max(len(v) - 1, 0))
    if len(v) == 0:
        return np.full(n_groups, np.nan)
    return np.where(counts > 0, 0.5 * (v[lo] + v[hi]), np.nan)


def robust_location(
    values: np.ndarray, groups: np.ndarray, n_groups: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Count, median and robust scale (1.4826 · MAD) of ``values`` per group (NaN where empty)."""
    count = np.bincount(groups, minlength=n_groups)
    center = group_median(values, groups, n_groups)
    if len(values) == 0:
        return count, center, np.full(n_groups, np.nan)
    scale = 1.4826 * group_median(np.abs(values - center[groups]), groups, n_groups)
    return count, center, scale


def reject_outliers(
    residual: np.ndarray,
    cell: np.ndarray,
    n_cells: int,
    *,
    rule: str = "mad",
    k: float = 4.0,
    threshold: float = 3.0,
    min_scale: float = 0.005,
) -> np.ndarray:
    """Boolean mask of samples kept by the bad-estimate rule, applied per cell.

    ``"mad"``: reject ``|r − median| > k · max(1.4826 · MAD, min_scale)`` within the cell,
    where ``r`` is measured − programmed (robust to up to half the samples being bad).
    ``"fixed"``: reject ``|r| > threshold``.  ``"none"``: keep everything.
    """
    if rule == "none":
        return np.ones(residual.shape, dtype=bool)
    if rule == "fixed":
        return np.abs(residual) <= threshold
    if rule != "mad":
        raise ValueError(f"unknown outlier rule {rule!r}; expected 'mad', 'fixed' or 'none'")
    center = group_median(residual, cell, n_cells)[cell]
    dev = np.abs(residual - center)
    scale = 1.4826 * group_median(dev, cell, n_cells)[cell]
    return dev <= k * np.maximum(scale, min_scale)


def pad_groups(values: np.ndarray, groups: np.ndarray, n_groups: int) -> np.ndarray:
    """Values per group label as rows of a NaN-padded ``(n_groups, max count)`` array.

    Each row holds its group's values in their input order (a stable sort), then NaN; the
    width is the largest group's count (at least 1, so an empty input gives one NaN column).
    """
    values = np.asarray(values, dtype=float)
    groups = np.asarray(groups, dtype=np.intp)
    count = np.bincount(groups, minlength=n_groups)
    out = np.full((n_groups, max(int(count.max(initial=0)), 1)), np.nan)
    order = np.argsort(groups, kind="stable")
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    rank = np.arange(len(order)) - first[groups[order]]
    out[groups[order], rank] = values[order]
    return out


def between_run_stats(
    bias: np.ndarray, std: np.ndarray, count: np.ndarray, *, min_samples: int = 144
) -> dict[str, np.ndarray]:
    """ISO 5725-4 style per-bin statistics over runs (axis 0).

    A bin is *eligible* when every run has more than ``min_samples`` samples in it.
    Returns grand means of bias and std over runs and their between-run standard
    deviations (ddof=1), NaN where the bin is not eligible, plus the ``eligible`` mask.
    """
    if bias.shape[0] < 2:
        raise ValueError("between-run statistics need at least two runs")
    eligible = np.all(count > min_samples, axis=0) & np.all(np.isfinite(bias) & np.isfinite(std), axis=0)
    out = {
        "grand_mean_bias": bias.mean(axis=0),
        "grand_mean_std": std.mean(axis=0),
        "between_run_std_bias": bias.std(axis=0, ddof=1),
        "between_run_std_std": std.std(axis=0, ddof=1),
    }
    for key, value in out.items():
        out[key] = np.where(eligible, value, np.nan)
    out["eligible"] = eligible
    return out
