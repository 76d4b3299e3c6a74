"""The one binning engine: per-bin count, mean and standard deviation (pure numpy).

Every stage that bins (the bench cube, the analysis sensitivity fits, the diagnose residuals)
goes through these two functions, so they share one edge rule, one treatment of missing
values and one variance formula.  Nothing here knows about files, xarray or units.

Edge rule
    Bin *i* of ``edges`` (increasing, ``n_bins + 1`` values) is the half-open interval
    ``[edges[i], edges[i+1])``, except the last bin, which is closed ``[edges[-2], edges[-1]]``:
    the rule of :func:`numpy.histogram`.  A value on an inner edge belongs to the bin it
    starts; the largest value of a sample binned by its own quantiles (``edges[-1] = max``)
    is counted, not dropped.  Values below ``edges[0]``, above ``edges[-1]`` or NaN are in no bin.
Missing values
    A pair counts only if its label is a bin (``>= 0``) and its value is finite.
Variance
    Two-pass: the bin mean first, then the sum of squared deviations from it, so a bin of
    values ``1e8 + small`` keeps its small spread (a one-pass ``E[y²] − E[y]²`` would cancel).

Why not :func:`scipy.stats.binned_statistic`: it takes one statistic per call over 1-D
bins, its ``"std"`` has ``ddof = 0`` and it treats NaN as a value; ``np.bincount`` with
weights gives count, sums and squared deviations for any number of rows in three passes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bin_index", "group_statistics", "binned_statistics"]


def bin_index(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin of every value of ``x`` under the module's edge rule; ``-1`` outside or NaN.

    >>> bin_index(np.array([0.0, 0.5, 1.0, 2.0, 2.5, np.nan]), np.array([0.0, 1.0, 2.0])).tolist()
    [0, 0, 1, 1, -1, -1]
    """
    x = np.asarray(x, dtype=float)
    edges = np.asarray(edges, dtype=float)
    n_bins = edges.size - 1
    idx = np.searchsorted(edges, x, side="right") - 1
    idx = np.where(x == edges[-1], n_bins - 1, idx)  # last bin closed, like numpy.histogram
    return np.where((idx >= 0) & (idx < n_bins) & ~np.isnan(x), idx, -1)


def group_statistics(
    values: np.ndarray, labels: np.ndarray, n_groups: int, *, ddof: int = 1,
    means_of: tuple[np.ndarray, ...] = (), standard_error: bool = False,
) -> tuple[np.ndarray, ...]:
    """Count, mean and standard deviation of ``values`` per integer label, over the last axis.

    Parameters
    ----------
    values : array, shape (..., n)
        Values; NaN values are ignored.
    labels : int array, broadcastable to ``values``
        Group of every value in ``0 .. n_groups - 1``; ``-1`` (or any negative) is no group.
    n_groups : int
        Number of groups.
    ddof : int
        Delta degrees of freedom of the standard deviation (1: sample std).
    means_of : tuple of arrays like ``values``
        Further arrays whose per-group means over the same counted pairs are returned too
        (e.g. the binning variable itself, for bin centres).
    standard_error : bool
        Return the standard error of the mean, ``sqrt(ss / (count - ddof) / count)`` with ``ss``
        the sum of squared deviations, in place of the standard deviation.

    Returns
    -------
    count : int64 array (..., n_groups)
    mean, std : float arrays (..., n_groups)
        NaN where a group is empty (``std`` also where ``count <= ddof``); ``std`` is the
        standard error of the mean with ``standard_error``.
    *means : float arrays (..., n_groups), one per ``means_of``

    >>> c, m, s = group_statistics(np.array([1.0, 3.0, 5.0, np.nan]), np.array([0, 0, 1, 1]), 2)
    >>> c.tolist(), m.tolist(), s.tolist()
    ([2, 1], [2.0, 5.0], [1.4142135623730951, nan])
    """
    values = np.asarray(values, dtype=float)
    values, labels = np.broadcast_arrays(values, np.asarray(labels))
    lead = values.shape[:-1]
    nrow = int(np.prod(lead)) if lead else 1
    v2 = values.reshape(nrow, -1)
    lab = labels.reshape(nrow, -1)
    ok = (lab >= 0) & np.isfinite(v2)
    flat = (np.arange(nrow)[:, None] * n_groups + lab)[ok]
    size = nrow * n_groups
    count = np.bincount(flat, minlength=size).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(flat, weights=v2[ok], minlength=size) / count
        dev = v2[ok] - mean[flat]  # two-pass: deviations from the group mean
        spread = np.bincount(flat, weights=dev * dev, minlength=size) / (count - ddof)
        std = np.sqrt(spread / count if standard_error else spread)
        extra = [np.bincount(flat, weights=np.broadcast_to(np.asarray(a, dtype=float), values.shape)
                             .reshape(nrow, -1)[ok], minlength=size) / count for a in means_of]
    std = np.where(count > ddof, std, np.nan)
    shape = (*lead, n_groups)
    return (count.reshape(shape), mean.reshape(shape), std.reshape(shape),
            *(e.reshape(shape) for e in extra))


def binned_statistics(
    x: np.ndarray, y: np.ndarray, edges: np.ndarray, *, ddof: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-bin count, mean and standard deviation of ``y`` binned by ``x``, and the mean of ``x``.

    ``x`` and ``y`` have shape ``(..., n)`` (broadcast against each other); bins follow the
    module's edge rule; a pair counts only if both are finite and ``x`` falls in a bin.
    Returns ``count`` (int64), ``mean_y``, ``std_y``, ``mean_x``, each ``(..., n_bins)``.

    >>> n, m, s, mx = binned_statistics(np.array([0.1, 0.2, 2.0]), np.array([1., 3., 5.]),
    ...                                 np.array([0., 1., 2.]))
    >>> n.tolist(), m.tolist(), mx.tolist()
    ([2, 1], [2.0, 5.0], [0.15000000000000002, 2.0])
    """
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    edges = np.asarray(edges, dtype=float)
    count, mean, std, mean_x = group_statistics(y, bin_index(x, edges), edges.size - 1, ddof=ddof,
                                                means_of=(x,))
    return count, mean, std, mean_x
