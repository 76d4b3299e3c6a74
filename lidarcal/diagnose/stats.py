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
import scipy.stats

from lidarcal.binning import bin_index, binned_statistics, group_statistics

__all__ = [
    "relative_difference", "bin_edges", "BinnedResiduals", "bin_residuals", "holm", "disagreement_tests",
    "GAP_METRIC", "BinGroups", "bin_groups", "gap", "locate", "group_p_values",
]

#: The definition of the gap reported by ``diagnose`` (``gap_metric`` in ``docs/diagnose.md``).
GAP_METRIC = (
    "systematic rms, in %, of the bin-mean residual r = (L-R)/R measured minus (L-R)/R simulated "
    "over heights and bins holding at least min_bin_count periods: quantile bins of each of the six "
    "conditions variables, wind-direction sectors 360/(2 x bins) degree wide (30 degree for 6 bins) "
    "and, for every candidate effect with two drivers, the joint quantile bins of those drivers "
    "(3 x 3); systematic = "
    "sqrt(max(mean(bin mean^2 - bin standard error^2), 0)), i.e. the noise of the bin means removed; "
    "per height: the same over that height's bins"
)

#: Bins per driver of the joint (two-driver) bin groups of the gap metric.
JOINT_BINS = 3


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
        n, m, std, xm = binned_statistics(drivers[name].T, r.T, e)  # (heights, bins)
        with np.errstate(invalid="ignore"):
            count[i, :nb], mean[i, :nb], se[i, :nb], center[i, :nb] = n.T, m.T, (std / np.sqrt(n)).T, xm.T
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
    p = scipy.stats.t.sf(np.abs(t), np.maximum(n - 1, 1))
    return np.clip(scipy.stats.norm.isf(p) * np.sign(t), -40, 40)


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
    p = np.where(dof > 0, scipy.stats.chi2.sf(chi2, np.maximum(dof, 1)), np.nan)
    out = {"chi2": chi2, "dof": dof, "p_value": p, "z": z}
    if residual is None:
        out["p_adjusted"] = holm(p)
        return out
    cnt = np.isfinite(residual).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.nanmean(residual, axis=0) / (np.nanstd(residual, axis=0, ddof=1) / np.sqrt(cnt))
        mz = np.where(cnt >= min_bin_count, _t_to_z(t, cnt), np.nan)
    mp = np.where(np.isfinite(mz), 2.0 * scipy.stats.norm.sf(np.abs(mz)), np.nan)
    adj = holm(np.concatenate([p.ravel(), mp]))
    out.update(p_adjusted=adj[: p.size].reshape(p.shape), mean_z=mz, mean_p_value=mp,
               mean_p_adjusted=adj[p.size:])
    return out


@dataclass
class BinGroups:
    """Labelled groups of bins: ``labels[g]`` is an int array (periods × heights), −1 outside any bin.

    ``names[g]`` names the group (e.g. ``"wind_shear_exponent x cnr_gradient"``), ``n_labels[g]`` its
    number of bins.  The labels are fixed once (from the usable periods) so residuals before and
    after a correction are binned alike.
    """

    names: tuple[str, ...]
    labels: tuple[np.ndarray, ...]
    n_labels: tuple[int, ...]


def _quantile_labels(x: np.ndarray, valid: np.ndarray, n_bins: int) -> tuple[np.ndarray, int]:
    edges = bin_edges(x[valid], n_bins)
    return np.where(valid, bin_index(x, edges), -1), edges.size - 1


def bin_groups(conditions: dict[str, np.ndarray], valid: np.ndarray, n_bins: int,
               joint: list[tuple[str, str]] = ()) -> BinGroups:
    """Bin groups of the gap metric (:data:`GAP_METRIC`).

    One group of ``n_bins`` quantile bins per conditions variable, direction sectors
    ``360/(2·n_bins)`` degree wide, and for every pair in ``joint`` the
    :data:`JOINT_BINS` × :data:`JOINT_BINS` joint quantile bins of that pair of drivers.
    """
    names, labels, sizes = [], [], []
    for name, x in conditions.items():
        lab, k = _quantile_labels(x, valid, n_bins)
        names.append(name), labels.append(lab), sizes.append(k)
    if "wind_from_direction" in conditions:
        n_sec = 2 * int(n_bins)
        d = np.mod(conditions["wind_from_direction"], 360.0)
        lab = np.floor(d / (360.0 / n_sec)).astype(int)
        lab = np.where(valid & np.isfinite(d), np.clip(lab, 0, n_sec - 1), -1)
        names.append("wind_from_direction sectors"), labels.append(lab), sizes.append(n_sec)
    for a, b in dict.fromkeys(tuple(p) for p in joint):
        la, ka = _quantile_labels(conditions[a], valid, JOINT_BINS)
        lb, kb = _quantile_labels(conditions[b], valid, JOINT_BINS)
        lab = np.where((la >= 0) & (lb >= 0), la * kb + lb, -1)
        names.append(f"{a} x {b}"), labels.append(lab), sizes.append(ka * kb)
    return BinGroups(tuple(names), tuple(labels), tuple(sizes))


def _group_stats(r: np.ndarray, lab: np.ndarray, k: int) -> tuple[np.ndarray, ...]:
    """Per (bin, height): count, mean and standard error of ``r`` by the labels ``lab`` (periods × heights).

    :func:`lidarcal.binning.group_statistics` bins each height (a row of ``r.T``).
    """
    stats_by_height = group_statistics(r.T, lab.T, k, standard_error=True)
    return tuple(np.ascontiguousarray(a.T, dtype=float) for a in stats_by_height)


def gap(r: np.ndarray, groups: BinGroups, min_bin_count: int = 10) -> tuple[float, np.ndarray, float]:
    """Return the gap of :data:`GAP_METRIC` in %: overall, per height, and its noise floor.

    Over every bin (of every group, at every height) with at least ``min_bin_count`` periods:
    gap = √max(mean(m² − se²), 0) — the rms of the bin means with their sampling noise removed
    (an unbiased estimate of the systematic part) — and noise floor = √mean(se²), the rms a
    perfect model would show.
    """
    n_h = r.shape[1]
    sq, se2, cnt = np.zeros(n_h), np.zeros(n_h), np.zeros(n_h)
    for lab, k in zip(groups.labels, groups.n_labels, strict=True):
        c, m, s = _group_stats(r, lab, k)
        ok = (c >= min_bin_count) & np.isfinite(m) & np.isfinite(s)
        sq += np.where(ok, m**2, 0.0).sum(axis=0)
        se2 += np.where(ok, s**2, 0.0).sum(axis=0)
        cnt += ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_height = 100.0 * np.sqrt(np.maximum(sq - se2, 0.0) / cnt)
    if cnt.sum() == 0:
        return float("nan"), per_height, float("nan")
    overall = 100.0 * float(np.sqrt(max(sq.sum() - se2.sum(), 0.0) / cnt.sum()))
    floor = 100.0 * float(np.sqrt(se2.sum() / cnt.sum()))
    return overall, per_height, floor


def locate(r: np.ndarray, groups: BinGroups, conditions: dict[str, np.ndarray], units: dict[str, str],
           min_bin_count: int = 10, z_min: float = 2.0, max_drivers: int = 3,
           alpha: float = 1.0) -> list[dict]:
    """Where the residual lies: up to ``max_drivers`` ``{"variable", "range", "units", "z"}`` entries.

    Per one-variable group (the direction sectors stand for ``wind_from_direction``), each bin's
    mean residual is scored z = mean/se per height and the heights combined as Σz/√m; the group
    scores χ² = Σ z² over its bins.  The strongest groups (one per variable) are reported, each
    with the range of the contiguous bins around its largest |z| whose z has the same sign and
    |z| ≥ ``z_min``; ``z`` is that largest combined score (its sign is the sign of the residual).
    Only groups whose χ² p-value is below ``alpha`` are kept (but always the strongest one).
    """
    found = []
    for name, lab, k in zip(groups.names, groups.labels, groups.n_labels, strict=True):
        var = "wind_from_direction" if name == "wind_from_direction sectors" else name
        if var not in conditions or (var == "wind_from_direction" and name == var):
            continue  # direction: the sectors locate better than the quantile bins
        c, m, s = _group_stats(r, lab, k)
        ok = (c >= min_bin_count) & (s > 0) & np.isfinite(m)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(ok, m / s, 0.0)
        zc = z.sum(axis=1) / np.sqrt(np.maximum(ok.sum(axis=1), 1))
        chi2 = float((z**2).sum())
        dof = int(ok.sum())
        if dof == 0:
            continue
        p = float(scipy.stats.chi2.logsf(chi2, dof))  # log: a strong driver's p underflows to 0
        b = int(np.argmax(np.abs(zc)))
        sign = np.sign(zc[b])
        lo = hi = b
        while lo - 1 >= 0 and np.sign(zc[lo - 1]) == sign and abs(zc[lo - 1]) >= z_min:
            lo -= 1
        while hi + 1 < k and np.sign(zc[hi + 1]) == sign and abs(zc[hi + 1]) >= z_min:
            hi += 1
        x = conditions[var]
        if name == "wind_from_direction sectors":
            width = 360.0 / k
            rng = [lo * width, (hi + 1) * width]
        else:
            sel = np.isin(lab, np.arange(lo, hi + 1)) & np.isfinite(x)
            rng = [float(np.min(x[sel])), float(np.max(x[sel]))] if sel.any() else [np.nan, np.nan]
        found.append((p, {"variable": var, "range": [float(v) for v in rng], "units": units.get(var, ""),
                          "z": float(zc[b])}))
    found.sort(key=lambda t: t[0])
    keep = [f for i, (p, f) in enumerate(found) if p < np.log(alpha) or i == 0]
    return keep[:max_drivers]


def group_p_values(r: np.ndarray, groups: BinGroups, min_bin_count: int = 10,
                   names: tuple[str, ...] | None = None) -> np.ndarray:
    """Raw p-values (groups × heights) of the chi-square "all bin means are zero" per bin group.

    The same test as :func:`disagreement_tests` (t scores of the bin means turned into normal
    scores, squared and summed) on the groups named in ``names`` (default all): the direction
    sectors and joint-driver bins see effects the one-variable bins average out.
    """
    out = []
    for name, lab, k in zip(groups.names, groups.labels, groups.n_labels, strict=True):
        if names is not None and name not in names:
            continue
        c, m, s = _group_stats(r, lab, k)
        ok = (c >= min_bin_count) & (s > 0) & np.isfinite(m)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(ok, _t_to_z(m / s, c), 0.0)
        dof = ok.sum(axis=0)
        out.append(np.where(dof > 0, scipy.stats.chi2.sf((z**2).sum(axis=0), np.maximum(dof, 1)), np.nan))
    return np.array(out).reshape(len(out), r.shape[1])
