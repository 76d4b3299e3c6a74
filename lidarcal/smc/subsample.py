"""The Monte Carlo route's stratified subsample of a long campaign, and the tolerance it gives.

A year of ten-minute periods at twelve heights is 630,720 (period, height) cells; the virtual
lidar costs milliseconds of CPU per cell, so simulating every one takes hours on two cores.
The route's per-bin statistics (mean deviation and spread per height and wind-speed bin) do not
need every period: :func:`select` takes, per height and wind-speed bin of the periods' own
speed, at most ``n`` periods, stratified over the bin's conditions, and every period of a bin
that has fewer.  What that subsample costs in accuracy is stated per bin
(:func:`standard_errors`), from the subsample itself.

**Selection** (numpy only, deterministic from the base seed): the periods of one (height, bin)
with a wind speed, in time order (their ``period_key``), are given a class per condition — the
bin's terciles of turbulence intensity, shear exponent and CNR (a missing value its own class)
and the wind direction's 90-degree sector — and sorted by those classes in serpentine order
(each class's sub-order reversed every other step, so neighbours in the order are alike in every
condition), ties by a uniform draw; ``n`` periods are then taken systematically,
``floor((k + u0) · N / n)`` for k = 0 … n − 1 with one uniform start ``u0``: every class gets
its proportional share of the subsample within one period (implicit stratification).  The
draws of a (height, bin) come from ``SeedSequence([base_seed, round(height_m * 1000),
round(centre_m_s * 1000)], spawn_key=(0x5AB5,))`` — a spawn key no period stream has — so the
subsample depends on the base seed, the campaign's conditions and ``n`` only: never on the
workers, the scheduler or the chunk size (docs/seeds.md).  A simulated cell is the same
(period, height) problem as in the full campaign (its seed is the period's own), so the
subsample's trials are bit for bit the full campaign's at those cells.

**Tolerance** (:func:`standard_errors`): per bin of the budget, over the distinct periods of
its trials (a period's replicas averaged first: periods, not trials, are what the subsample
samples), the standard error of the mean deviation and of the spread that subsampling ``m``
of the bin's ``N`` campaign periods adds, with the finite-population correction
√(1 − m/N) (zero where every period is simulated):

* mean: SE(d̄) = s / √m · √(1 − m/N);
* spread (delta method on s²): SE(s) = √((m₄ − s⁴) / m) / (2 s) · √(1 − m/N), m₄ the fourth
  central moment of the periods' deviations — or, where larger, with m₄ = κ s⁴ and κ the height's
  pooled standardised fourth moment (the deviations are skewed by rare bad estimates, and a
  bin's few periods can miss them all).

Simple random sampling's variance; the stratified systematic sample's is at most that up to
terms of order 1/m (proportional allocation).  Both are normal approximations: a subsampled bin
with fewer than :data:`MIN_PERIODS` simulated periods (one the reference speeds spill into from a
subsampled neighbour) states none (NaN).
"""

from __future__ import annotations

import numpy as np

__all__ = ["DEFAULT_PERIODS_PER_BIN", "MIN_PERIODS", "SPAWN_KEY", "select", "select_height", "select_bin",
           "standard_errors"]

#: Periods simulated per (height, wind-speed bin) by default: a year of 12 heights in <= 15 min on 2
#: cores with the default replicas (docs/performance.md), a mean deviation to s / 10.
DEFAULT_PERIODS_PER_BIN = 100
#: Spawn key of the selection's streams (no period or height stream has one).
SPAWN_KEY = 0x5AB5
#: Fewest simulated periods of a subsampled bin whose standard errors are stated (the delta method's
#: normal approximation needs them; a bin whose every period is simulated has none to state).
MIN_PERIODS = 10
#: Quantile classes of turbulence intensity, shear exponent and CNR inside a bin.
CLASSES = 3


def _classes(x: np.ndarray, k: int) -> np.ndarray:
    """Quantile class 0 … k − 1 of each value among the finite ones (by rank); k for a missing value."""
    x = np.asarray(x, dtype=float)
    out = np.full(x.size, k, dtype=np.int64)
    ok = np.isfinite(x)
    m = int(ok.sum())
    if m:
        rank = np.empty(m, dtype=np.int64)
        rank[np.argsort(x[ok], kind="stable")] = np.arange(m)
        out[ok] = rank * k // m
    return out


def _serpentine(classes: list[np.ndarray], sizes: list[int]) -> np.ndarray:
    """One sort key from nested classes, each level's order reversed where the level above is odd."""
    key = np.zeros(classes[0].size, dtype=np.int64)
    for c, size in zip(classes, sizes, strict=True):
        c = np.where(key % 2 == 1, size - 1 - c, c)
        key = key * size + c
    return key


def select_bin(
    conditions: np.ndarray, direction: np.ndarray, n: int, seed: np.random.SeedSequence
) -> np.ndarray:
    """Return the indices (sorted) of at most ``n`` of a bin's periods, stratified over their conditions.

    ``conditions`` (period, variable): the bin's periods in time order (turbulence intensity,
    shear, CNR, …), ``direction`` (period,) degrees.  All of them when there are ``n`` or fewer.

    >>> c = np.arange(12.0)[:, None]; d = np.zeros(12)
    >>> select_bin(c, d, 20, np.random.SeedSequence(1)).tolist() == list(range(12))
    True
    >>> np.bincount(select_bin(c, d, 6, np.random.SeedSequence(1)) * 3 // 12).tolist()  # 2 per tercile
    [2, 2, 2]
    """
    conditions = np.asarray(conditions, dtype=float).reshape(np.shape(direction)[0], -1)
    size = conditions.shape[0]
    if size <= n:
        return np.arange(size)
    rng = np.random.default_rng(seed)
    u0, tie = rng.random(), rng.random(size)
    sector = np.asarray(direction, dtype=float) % 360.0 // 90.0
    sector = np.where(np.isfinite(sector), sector, 4).astype(np.int64)
    classes = [_classes(conditions[:, j], CLASSES) for j in range(conditions.shape[1])] + [sector]
    key = _serpentine(classes, [CLASSES + 1] * conditions.shape[1] + [5])
    order = np.lexsort((tie, key))
    picks = np.floor((np.arange(n) + u0) * size / n).astype(np.int64)
    return np.sort(order[picks])


def select(
    speed: np.ndarray,
    conditions: np.ndarray,
    direction: np.ndarray,
    period_key: np.ndarray,
    heights: np.ndarray,
    edges: np.ndarray,
    n: int | None,
    base_seed: int,
) -> np.ndarray:
    """(time, height) bool: the periods the Monte Carlo route simulates at each height.

    ``speed`` (time, height) the periods' own wind speeds, ``conditions`` (time, height, variable)
    what the bin is stratified over, ``direction`` (time, height) degrees, ``period_key`` (time,),
    ``heights`` (height,) m, ``edges`` the wind-speed bins (m s-1).  ``n`` None: every period with
    a wind speed.  See the module docstring; :func:`select_height` is one height's.
    """
    speed = np.asarray(speed, dtype=float)
    return np.stack(
        [select_height(speed[:, j], np.asarray(conditions)[:, j], np.asarray(direction)[:, j], period_key, z,
                       edges, n, base_seed) for j, z in enumerate(np.asarray(heights, dtype=float))],
        axis=1,
    ).reshape(speed.shape)


def select_height(
    speed: np.ndarray,
    conditions: np.ndarray,
    direction: np.ndarray,
    period_key: np.ndarray,
    height: float,
    edges: np.ndarray,
    n: int | None,
    base_seed: int,
) -> np.ndarray:
    """(time,) bool: the periods the Monte Carlo route simulates at one height (:func:`select`'s column).

    ``speed`` (time,), ``conditions`` (time, variable), ``direction`` (time,) at ``height`` (m):
    the route takes a long campaign one height at a time.
    """
    speed = np.asarray(speed, dtype=float)
    inside = np.isfinite(speed) & (speed >= edges[0]) & (speed < edges[-1])
    if n is None:
        return inside
    out = np.zeros(speed.shape, dtype=bool)
    centres = 0.5 * (edges[:-1] + edges[1:])
    order = np.argsort(np.asarray(period_key, dtype=np.int64), kind="stable")  # time order, not file order
    s = speed[order]
    b = np.where(inside[order], np.searchsorted(edges, s, side="right") - 1, -1)
    for k in np.unique(b[b >= 0]):
        rows = np.flatnonzero(b == k)
        seed = np.random.SeedSequence(
            [int(base_seed), int(round(float(height) * 1000)), int(round(centres[k] * 1000))],
            spawn_key=(SPAWN_KEY,),
        )
        pick = select_bin(conditions[order[rows]], direction[order[rows]], int(n), seed)
        out[order[rows[pick]]] = True
    return out


def standard_errors(
    deviation: np.ndarray, period: np.ndarray, bins: np.ndarray, n_bins: int, population: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bin: (periods simulated m, SE of the mean deviation, SE of the spread), m s-1.

    ``deviation``, ``period`` and ``bins`` (trial,): each trial's lidar − reference deviation,
    its period and its bin (-1: none); ``population`` (bin,) the campaign's periods in each bin
    (N; at least m is used).  NaN where fewer than 2 periods (module docstring).

    >>> d = np.arange(1.0, 13.0); p = np.arange(12); b = np.zeros(12, int)
    >>> m, se_mean, se_sd = standard_errors(d, p, b, 1, np.array([12]))  # every period: no error
    >>> int(m[0]), float(se_mean[0]), float(se_sd[0])
    (12, 0.0, 0.0)
    >>> round(float(standard_errors(d, p, b, 1, np.array([48]))[1][0]), 6)  # s / sqrt(12) * sqrt(1 - 12/48)
    0.901388
    """
    d, p, b = (np.asarray(a) for a in (deviation, period, bins))
    ok = (b >= 0) & np.isfinite(d)
    d, p, b = d[ok].astype(float), p[ok].astype(np.int64), b[ok].astype(np.int64)
    # one value per (bin, period): the mean of its replicas
    pair, inv = np.unique(np.stack([b, p]), axis=1, return_inverse=True)
    inv = np.ravel(inv)
    per = np.bincount(inv, weights=d, minlength=pair.shape[1]) / np.bincount(inv, minlength=pair.shape[1])
    pb = pair[0]
    m = np.bincount(pb, minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(pb, weights=per, minlength=n_bins) / m
        c = per - mean[pb]
        var = np.bincount(pb, weights=c**2, minlength=n_bins) / (m - 1)
        m4 = np.bincount(pb, weights=c**4, minlength=n_bins) / m
        fpc = np.sqrt(np.clip(1.0 - m / np.maximum(np.asarray(population, dtype=float), m), 0.0, 1.0))
        se_mean = np.sqrt(var / m) * fpc
        sd = np.sqrt(var)
        se_sd = np.sqrt(np.maximum(m4 - var**2, 0.0) / m) / (2.0 * sd) * fpc
        # the height's pooled standardised fourth moment, where larger: a bin's few periods can miss the
        # rare large deviations (bad estimates) that set its own
        z4 = (c / sd[pb]) ** 4
        pooled = np.nanmean(z4[m[pb] >= MIN_PERIODS]) if (m >= MIN_PERIODS).any() else np.nan
        se_pooled = sd * np.sqrt(np.maximum(pooled - 1.0, 0.0) / (4.0 * m)) * fpc
        se_sd = np.fmax(se_sd, se_pooled)
    few = (m < MIN_PERIODS) & (fpc > 0)  # a subsampled bin of few periods: no error is stated
    se_mean = np.where(fpc == 0, 0.0, se_mean)
    se_sd = np.where(fpc == 0, 0.0, se_sd)
    return m, np.where(few | (m < 2), np.nan, se_mean), np.where(few | (m < 2), np.nan, se_sd)
