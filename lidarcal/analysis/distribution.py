r"""The Monte Carlo output distribution of each bin (JCGM 101 §7.5-7.7): estimate, u, coverage interval.

Pure numpy/scipy.  The measurand of a bin is the error of one 10-minute mean of the lidar at
that height and wind-speed bin.  Its distribution is that of the bin's trials (lidar −
reference of each simulated period and replica, here in % of the bin's mean reference speed)
convolved with a normal whose standard deviation σ is the quadrature sum of the contributors
the trials do not represent (the Table 4 terms, the statistical term σ_diff/√N, ...;
:mod:`lidarcal.analysis.budget` decides which).  From it (:func:`bin_values`):

- the estimate y: the mean of the trials (the mean lidar − reference difference);
- its standard uncertainty u(y) = √(s² + σ²), s the standard deviation of the trials;
- the 95 % coverage interval (:func:`lidarcal.analysis.montecarlo.coverage_interval`),
  probabilistically symmetric or shortest, widened about y by the thin-bin factor
  t₀.₉₇₅(ν_eff)/1.96 (GUM G.4: the spread of a bin rests on its N distinct periods; 1 for
  large ν_eff);
- the probability this distribution (widened alike) gives to ±U, U the k = 2 expanded
  uncertainty of the IEC-style tables, which decides the certified statement
  (:func:`lidarcal.analysis.certification.certified_statement`).

:func:`delta_sds` gives the delta-method standard deviation of each of these values from the
trials, within periods (:mod:`lidarcal.analysis.montecarlo`); :func:`grouped` packs trials into
one NaN-padded row per bin.
"""

from __future__ import annotations

import warnings

import numpy as np

from lidarcal.analysis.certification import thin_bin_factor
from lidarcal.analysis.montecarlo import (
    COVERAGE_PROBABILITY,
    coverage_interval,
    influence_quantile,
    mixture_cdf,
    stratified_sd,
)

__all__ = ["bin_values", "delta_sds", "grouped"]


def grouped(values: np.ndarray, group: np.ndarray, ngroups: int, fill: float = np.nan) -> np.ndarray:
    """Return the ``values`` of each group 0 … ``ngroups`` − 1 as rows of a padded (ngroups, nmax) array.

    >>> grouped(np.array([1.0, 2.0, 3.0]), np.array([1, 0, 1]), 3).tolist()
    [[2.0, nan], [1.0, 3.0], [nan, nan]]
    """
    group = np.asarray(group, dtype=np.int64)
    counts = np.bincount(group, minlength=ngroups) if group.size else np.zeros(ngroups, dtype=np.int64)
    values = np.asarray(values)
    out = np.full((ngroups, max(int(counts.max(initial=0)), 1)), fill, dtype=values.dtype)
    order = np.argsort(group, kind="stable")
    g = group[order]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out[g, np.arange(g.size) - starts[g]] = values[order]
    return out


def _buckets(n: np.ndarray, use: np.ndarray):
    """Yield (row indices, width) of the rows of ``use`` grouped by trial count within a factor of 2.

    Rows are NaN-padded on the right, so a bucket's rows need only its largest count of columns.
    """
    idx = np.flatnonzero(np.asarray(use).ravel())
    if not idx.size:
        return
    counts = np.asarray(n).ravel()[idx]
    level = np.floor(np.log2(np.maximum(counts, 1))).astype(int)
    for lv in np.unique(level):
        rows = idx[level == lv]
        yield np.unravel_index(rows, np.shape(n)), int(np.asarray(n).ravel()[rows].max())


def bin_values(samples: np.ndarray, sigma: np.ndarray, expanded: np.ndarray, nu: np.ndarray, *,
               p: float = COVERAGE_PROBABILITY, shortest: bool = False) -> dict[str, np.ndarray]:
    """Return the JCGM 101 values of each row of ``samples`` (..., n; NaN-padded trials).

    ``sigma`` (...) is the standard uncertainty of the terms not simulated, ``expanded`` (...)
    the k = 2 expanded uncertainty U, ``nu`` (...) the effective degrees of freedom of u(y), all in
    the units of the trials.  Returns ``mean_difference`` (y), ``error_standard_uncertainty``
    (u(y)), ``coverage_interval_lower`` / ``_upper`` (widened for thin bins), ``coverage`` (the
    probability of [−U, U]), ``factor`` (the thin-bin factor) and ``raw_lower`` / ``raw_upper``
    (the interval before widening).
    """
    d = np.asarray(samples, dtype=float)
    sig = np.asarray(sigma, dtype=float)
    n = np.isfinite(d).sum(axis=-1)
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        y = np.nanmean(d, axis=-1)
        var = np.where(n >= 2, np.nanvar(d, axis=-1, ddof=1), np.nan)
    u = np.sqrt(var + sig**2)
    usable = (n >= 2) & np.isfinite(sig) & (sig >= 0) & np.isfinite(u)
    lo, hi = np.full(y.shape, np.nan), np.full(y.shape, np.nan)
    for rows, width in _buckets(n, usable):  # rows of like size, so that little padding is iterated
        lo[rows], hi[rows] = coverage_interval(d[rows][..., :width], sig[rows], p, shortest=shortest)
    c = thin_bin_factor(nu, p)
    lower, upper = y + c * (lo - y), y + c * (hi - y)
    big_u = np.asarray(expanded, dtype=float)
    coverage = np.full(y.shape, np.nan)
    for rows, width in _buckets(n, usable & np.isfinite(big_u)):
        yr, ur, cr = y[rows], big_u[rows], c[rows]
        at = np.stack([yr + (ur - yr) / cr, yr + (-ur - yr) / cr], axis=-1)
        g = mixture_cdf(at, d[rows][..., :width], sig[rows])
        coverage[rows] = g[..., 0] - g[..., 1]
    return {"mean_difference": y, "error_standard_uncertainty": u, "coverage_interval_lower": lower,
            "coverage_interval_upper": upper, "coverage": coverage, "factor": c, "raw_lower": lo,
            "raw_upper": hi}


def delta_sds(samples: np.ndarray, strata: np.ndarray, sigma: np.ndarray, values: dict[str, np.ndarray],
              periods: np.ndarray, combined: np.ndarray, k: float, *,
              p: float = COVERAGE_PROBABILITY) -> dict[str, np.ndarray]:
    """Delta-method standard deviation of each value of :func:`bin_values` from its trials.

    Each value is linearised through the influence of each trial on it, and its standard
    deviation is that of the mean influence within periods (``strata``: the trial's period, −1
    where absent; :func:`lidarcal.analysis.montecarlo.stratified_sd`):

    - y: d − y;
    - u(y) = √(s²(1 + 1/N) + σ₀²) (the statistical term s/√N is part of σ, N = ``periods``):
      (1 + 1/N)·((d − y)² − s²)/(2u);
    - an endpoint y + c(x − y), x a quantile of G: (1 − c)·(d − y) + c·(p − Φ((x − d)/σ))/g(x);
    - U = k·√(y² + u²) (``combined`` = U/k): k(y·IF_y + u·IF_u)/``combined``.
    """
    d = np.asarray(samples, dtype=float)
    sig = np.asarray(sigma, dtype=float)
    y, u, c = (values[n][..., None] for n in ("mean_difference", "error_standard_uncertainty", "factor"))
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        s2 = np.nanvar(d, axis=-1, ddof=1)[..., None]
        inf_y = d - y
        inf_u = (1.0 + 1.0 / np.asarray(periods, dtype=float)[..., None]) * (inf_y**2 - s2) / (2.0 * u)
        influences = {"mean_difference": inf_y, "error_standard_uncertainty": inf_u}
        for name, raw, level in (("coverage_interval_lower", "raw_lower", 0.5 * (1 - p)),
                                 ("coverage_interval_upper", "raw_upper", 0.5 * (1 + p))):
            x = values[raw]
            inf_x = np.full(d.shape, np.nan)
            ok = np.isfinite(x) & np.isfinite(sig)
            if ok.any():
                inf_x[ok] = influence_quantile(d[ok], sig[ok], x[ok], level)
            influences[name] = (1.0 - c) * inf_y + c * inf_x
        combined = np.asarray(combined, dtype=float)[..., None]
        influences["expanded_uncertainty"] = k * (y * inf_y + u * inf_u) / combined
    names = list(influences)
    sds = stratified_sd(np.stack([influences[n] for n in names]), strata)  # one pairing of trials and periods
    return dict(zip(names, sds, strict=True))
