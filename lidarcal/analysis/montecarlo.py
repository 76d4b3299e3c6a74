r"""JCGM 101 on Monte Carlo output: coverage intervals (§7.7) and numerical tolerances (§7.9).

Pure numpy/scipy: numbers in, numbers out.

**The output distribution of a bin.**  The trials of a bin (lidar minus reference, one per
simulated 10-minute period and replica) are a sample of the error the simulation models.  The
contributors it does not simulate (the Table 4 terms, the statistical term, ...) are normal with
standard deviation σ and independent of it, so the distribution of the measurand is the
empirical distribution of the n trials d_i convolved with N(0, σ²):

    G(x) = (1/n) Σ Φ((x − d_i) / σ).

Its quantiles are found deterministically (:func:`mixture_quantile`: G is smooth and strictly
increasing for σ > 0; safeguarded Newton steps on the exact bracket
[min d + σ z_p, max d + σ z_p]) rather than by drawing more normal deviates, which would add
noise for nothing.  With σ = 0 the distribution is the trials' own and the coverage interval
follows JCGM 101 §7.7.2's order statistics.

**Coverage interval** (JCGM 101 §7.7, :func:`coverage_interval`): probabilistically symmetric
by default, [G⁻¹((1 − p)/2), G⁻¹((1 + p)/2)]; the shortest on request (the α minimising
G⁻¹(α + p) − G⁻¹(α), found on a grid of α and refined).

**Numerical uncertainty of a value** (JCGM 101 §7.9): two estimates, of which the larger counts.

- From the h replicas (independent re-runs of the same periods): s/√h, s the standard deviation of
  the h replica values, with the Student factor t₀.₉₇₅(h − 1) instead of JCGM 101's 2, since s
  rests on h − 1 degrees of freedom (:func:`replica_half_width`).  Needs h ≥ 2.
- From all n trials at once by the delta method: each value is linearised through the
  influence of each trial on it (:func:`influence_quantile` for an endpoint; the mean's and the
  variance's are d − y and (d − y)² − s², the latter bringing in the fourth moment), and its
  standard deviation is that of the mean influence, with the variance taken *within* periods
  (:func:`stratified_sd`): a period's trials differ only by their seeds, while the spread between
  periods is the atmosphere's, fixed by the conditions record (the statistical term's business,
  not the Monte Carlo's noise).  This sees the heavy tail of a skewed bin through all its trials,
  where a few replica values can agree by luck.

A value reached the tolerance δ = ½·10^ℓ, ℓ the smallest integer with δ ≥ the larger half-width
(:func:`tolerance_exponent`, JCGM 101 §7.9.2).
"""

from __future__ import annotations

import functools
import math
import warnings

import numpy as np
from scipy import optimize, special, stats

__all__ = [
    "COVERAGE_PROBABILITY",
    "coverage_interval",
    "influence_quantile",
    "mixture_cdf",
    "mixture_quantile",
    "stratified_sd",
    "replica_half_width",
    "replicas_needed",
    "student_factor",
    "tolerance_exponent",
    "z_factor",
]

#: Coverage probability of the certified intervals.
COVERAGE_PROBABILITY = 0.95

_SQRT_2PI = math.sqrt(2.0 * math.pi)


def _padded(samples) -> np.ndarray:
    """Return ``samples`` as a float array (..., n), at least 1-D; NaN marks an absent trial."""
    return np.atleast_1d(np.asarray(samples, dtype=float))


def _count(d: np.ndarray) -> np.ndarray:
    return np.isfinite(d).sum(axis=-1)


def mixture_cdf(x, samples, sigma) -> np.ndarray:
    """G(x) = (1/n) Σ Φ((x − d_i)/σ) over the finite trials of ``samples`` (..., n).

    ``x`` is (..., P) (or broadcasts to it), ``sigma`` (...); σ = 0 gives the empirical
    (right-continuous) CDF.

    >>> float(mixture_cdf(0.0, [-1.0, 1.0], 1.0)[0])
    0.5
    """
    d = _padded(samples)
    s = np.asarray(sigma, dtype=float)[..., None, None]
    x = np.atleast_1d(np.asarray(x, dtype=float))
    x = np.broadcast_to(x, (*d.shape[:-1], x.shape[-1]))
    ok = np.isfinite(d)[..., None, :]
    diff = x[..., :, None] - np.where(np.isfinite(d), d, 0.0)[..., None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        phi = np.where(s > 0, special.ndtr(diff / np.where(s > 0, s, 1.0)), (diff >= 0).astype(float))
        return np.where(ok, phi, 0.0).sum(axis=-1) / _count(d)[..., None]


def mixture_quantile(samples, sigma, probs) -> np.ndarray:
    """G⁻¹(p) for every p of ``probs`` (..., P) or (P,), ``samples`` (..., n), σ (...) > 0.

    Newton steps on Φ⁻¹(G(x)) = Φ⁻¹(p) (nearly linear in x, also in the tails, where G itself is
    flat), started from the trials' own quantile widened by √(1 + σ²/var); a step leaving the
    bracket known so far is replaced by bisection.  The first bracket is exact: G lies between
    the normals centred on the smallest and largest trial, so its p-quantile lies in
    [min d + σ Φ⁻¹(p), max d + σ Φ⁻¹(p)].  Converged to about 1e-13 of the spread; groups are
    iterated only until each has converged.  NaN for a group without trials.

    >>> round(float(mixture_quantile([0.0], 2.0, [0.975])[0]), 6)  # one trial: a normal
    3.919928
    """
    d = _padded(samples)
    batch = d.shape[:-1]
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), batch).reshape(-1)
    npr = np.shape(probs)[-1]
    p = np.broadcast_to(np.asarray(probs, dtype=float), (*batch, npr)).reshape(-1, npr)
    d = d.reshape(-1, d.shape[-1])
    n = _count(d)
    if np.any(~(sig > 0) & (n > 0)):
        raise ValueError("mixture_quantile needs sigma > 0")
    out = np.full(p.shape, np.nan)
    has = n > 0
    if not has.any():
        return out.reshape(*batch, npr)
    ok = np.isfinite(d[has])
    d0, n, sig, p = np.where(ok, d[has], 0.0), n[has], sig[has], p[has]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = d0.sum(axis=-1) / n
        var = np.where(ok, (d0 - mean[:, None]) ** 2, 0.0).sum(axis=-1) / n
    # each group's own p-quantile (linear interpolation between its sorted trials)
    srt = np.sort(np.where(ok, d0, np.inf), axis=-1)
    pos = p * (n - 1)[:, None]
    i0 = np.clip(np.floor(pos).astype(int), 0, (n - 1)[:, None])
    i1 = np.minimum(i0 + 1, (n - 1)[:, None])
    rows = np.arange(n.size)[:, None]
    own = srt[rows, i0] + (pos - i0) * (srt[rows, i1] - srt[rows, i0])
    dmin = np.where(ok, d0, np.inf).min(axis=-1)
    dmax = np.where(ok, d0, -np.inf).max(axis=-1)
    zp = special.ndtri(p)
    lo, hi = dmin[:, None] + sig[:, None] * zp, dmax[:, None] + sig[:, None] * zp
    widen = np.sqrt((var + sig**2) / np.where(var > 0, var, np.inf))[:, None]
    x = np.clip(np.where(np.isfinite(widen), mean[:, None] + (own - mean[:, None]) * widen, lo), lo, hi)
    tol = np.broadcast_to((1e-13 * (np.sqrt(var + sig**2) + np.maximum(np.abs(dmin), np.abs(dmax))))[:, None],
                          p.shape)
    # one row per (group, probability), iterated while not converged
    grp = np.broadcast_to(np.arange(n.size)[:, None], p.shape).reshape(-1)
    x, lo, hi, zp, pf, tol = (a.reshape(-1).copy() for a in (x, lo, hi, zp, p, tol))
    active = np.arange(x.size)
    for _ in range(200):
        g = grp[active]
        z = (x[active, None] - d0[g]) / sig[g, None]
        w = ok[g] / n[g, None]
        big_g = (special.ndtr(z) * w).sum(axis=-1)
        dens = (np.exp(-0.5 * z * z) * w).sum(axis=-1) / (sig[g] * _SQRT_2PI)
        lo[active] = np.where(big_g <= pf[active], x[active], lo[active])
        hi[active] = np.where(big_g >= pf[active], x[active], hi[active])
        zz = special.ndtri(np.clip(big_g, 1e-300, 1 - 1e-16))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            new = x[active] - (zz - zp[active]) * np.exp(-0.5 * zz * zz) / (_SQRT_2PI * dens)
        outside = ~np.isfinite(new) | (new < lo[active]) | (new > hi[active])
        new = np.where(outside, 0.5 * (lo[active] + hi[active]), new)
        done = (np.abs(new - x[active]) <= tol[active]) | (hi[active] - lo[active] <= tol[active])
        x[active] = new
        active = active[~done]
        if not active.size:
            break
    out[has] = x.reshape(-1, npr)
    return out.reshape(*batch, npr)


def _order_statistic_interval(d: np.ndarray, p: float, shortest: bool) -> tuple[float, float]:
    """JCGM 101 §7.7.2 on sorted values: [ỹ_r, ỹ_(r+q)], q = pM rounded; NaN when M < 1/(1 − p)."""
    m = d.size
    q = int(round(p * m)) if float(p * m).is_integer() else int(p * m + 0.5)
    if q >= m or m < 1.0 / (1.0 - p):
        return math.nan, math.nan
    if shortest:
        r0 = int(np.argmin(d[q:] - d[: m - q]))
    else:
        r = (m - q) // 2 if (m - q) % 2 == 0 else (m - q + 1) // 2  # 1-based r of §7.7.2
        r0 = max(r - 1, 0)
    return float(d[r0]), float(d[r0 + q])


def _shortest(d: np.ndarray, sigma: float, p: float) -> tuple[float, float]:
    """Shortest interval of probability ``p`` of one group (finite trials ``d``, σ > 0)."""
    eps = 1e-9
    grid = np.linspace(eps, 1 - p - eps, 41)
    q = mixture_quantile(d, sigma, np.concatenate([grid, grid + p]))
    widths = q[grid.size:] - q[: grid.size]
    k = int(np.argmin(widths))
    a, b = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]

    def width(alpha: float) -> float:
        lo_hi = mixture_quantile(d, sigma, [alpha, alpha + p])
        return float(lo_hi[1] - lo_hi[0])

    best = optimize.minimize_scalar(width, bounds=(a, b), method="bounded",
                                    options={"xatol": 1e-10 * (1 - p)})
    alpha = float(best.x) if best.fun <= widths[k] else float(grid[k])
    lo, hi = mixture_quantile(d, sigma, [alpha, alpha + p])
    return float(lo), float(hi)


def coverage_interval(samples, sigma, p: float = COVERAGE_PROBABILITY, *,
                      shortest: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Coverage interval for probability ``p`` of G (JCGM 101 §7.7), per group of ``samples`` (..., n).

    Probabilistically symmetric ([G⁻¹((1−p)/2), G⁻¹((1+p)/2)]) by default; ``shortest`` gives the
    shortest interval of probability ``p``.  Where σ = 0, the order statistics of JCGM 101
    §7.7.2.  NaN for a group without trials (or, for σ = 0, with fewer than 1/(1 − p)).
    Returns (low, high), each of shape (...) (floats for 1-D ``samples``).

    >>> [round(v, 4) for v in coverage_interval([0.0], 1.0)]
    [-1.96, 1.96]
    """
    d = _padded(samples)
    if d.ndim == 1:
        lo, hi = coverage_interval(d[None], np.atleast_1d(sigma), p, shortest=shortest)
        return float(lo[0]), float(hi[0])
    batch = d.shape[:-1]
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), batch)
    smooth = (sig > 0) & (_count(d) > 0)
    lo, hi = np.full(batch, np.nan), np.full(batch, np.nan)
    if smooth.any() and not shortest:
        q = mixture_quantile(d[smooth], sig[smooth], [(1 - p) / 2, (1 + p) / 2])
        lo[smooth], hi[smooth] = q[:, 0], q[:, 1]
    for idx in zip(*np.nonzero((_count(d) > 0) & (~smooth | shortest)), strict=True):
        one = np.sort(d[idx][np.isfinite(d[idx])])
        if sig[idx] > 0:
            lo[idx], hi[idx] = _shortest(one, float(sig[idx]), p)
        else:
            lo[idx], hi[idx] = _order_statistic_interval(one, p, shortest)
    return lo, hi


def influence_quantile(samples, sigma, x, p: float) -> np.ndarray:
    """Influence of each trial on the p-quantile ``x`` (...) of G: (p − Φ((x − d)/σ)) / g(x).

    ``samples`` (..., n), σ (...) > 0; g the density of G at x.  The estimator solves
    G_n(x) = p; linearised, its error is the mean of these values (NaN where a trial is absent).
    Where σ = 0 the step 1{d ≤ x} replaces Φ and g is the Siddiqui–Bloch–Gastwirth estimate
    2m/(n·(d_(r+m) − d_(r−m))), m = √(np(1 − p)).
    """
    d = _padded(samples)
    batch = d.shape[:-1]
    sig = np.broadcast_to(np.asarray(sigma, dtype=float), batch)[..., None]
    x = np.broadcast_to(np.asarray(x, dtype=float), batch)[..., None]
    ok = np.isfinite(d)
    n = _count(d)[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        z = (x - d) / np.where(sig > 0, sig, 1.0)
        dens = np.where(ok, np.exp(-0.5 * z * z), 0.0).sum(axis=-1, keepdims=True) / (n * sig * _SQRT_2PI)
        out = (p - special.ndtr(z)) / dens
    if np.any(~(sig > 0)):
        srt = np.sort(np.where(ok, d, np.inf), axis=-1)
        m = np.maximum(1, np.ceil(np.sqrt(n * p * (1 - p)))).astype(int)
        r = np.clip(np.round(p * n).astype(int), 0, n - 1)
        hi = np.take_along_axis(srt, np.minimum(r + m, n - 1), axis=-1)
        lo = np.take_along_axis(srt, np.maximum(r - m, 0), axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            step = (p - (d <= x)) * n * (hi - lo) / (np.minimum(r + m, n - 1) - np.maximum(r - m, 0))
        out = np.where(sig > 0, out, step)
    return np.where(ok, out, np.nan)


def stratified_sd(influence, strata) -> np.ndarray:
    """Return the standard deviation of a statistic from its trials' ``influence`` (..., n) in ``strata``.

    The statistic is linearised as its value plus the mean of the influences.  Trials of one
    stratum (one simulated period) differ only in their seeds; the strata themselves are fixed
    inputs, so the Monte Carlo's own scatter is the spread *within* strata: √(s_w²/n), s_w² the
    pooled within-stratum variance of the influences (one-way analysis of variance).  Where no
    stratum holds two trials, the total variance of the influences is used instead (it includes
    the between-strata spread, so it errs on the large side).  ``strata`` (..., n) are integer
    labels, -1 for an absent trial; ``influence`` may carry leading dims of its own (several
    statistics of the same trials).  NaN for fewer than two trials.

    >>> inf = np.array([[1.0, 3.0, 10.0, 12.0]])  # two strata, each spread by +-1 about its mean
    >>> round(float(stratified_sd(inf, np.array([[0, 0, 1, 1]]))[0]), 6)  # sqrt((4/2) / 4)
    0.707107
    """
    f = _padded(influence)
    lab = np.asarray(strata, dtype=np.int64)
    lab = np.broadcast_to(lab, f.shape[f.ndim - max(lab.ndim, 1):])
    lead, batch = f.shape[: f.ndim - lab.ndim], lab.shape[:-1]
    lab2 = lab.reshape(-1, lab.shape[-1])
    ng = lab2.shape[0]
    present = lab2 >= 0
    groups = np.broadcast_to(np.arange(ng)[:, None], lab2.shape)[present]
    labels = lab2[present]
    out = np.full((int(np.prod(lead, dtype=int)), ng), np.nan)
    if labels.size:
        labels = labels - labels.min()
        key = groups * (int(labels.max()) + 1) + labels  # one integer per (group, stratum)
        uniq, inv = np.unique(key, return_inverse=True)
        pair_group = uniq // (int(labels.max()) + 1)
        for m, fm in enumerate(f.reshape(-1, *lab2.shape)):
            x = fm[present]
            w = np.isfinite(x).astype(float)
            x = np.where(w > 0, x, 0.0)
            cnt, s1, s2 = np.bincount(inv, w), np.bincount(inv, x), np.bincount(inv, x * x)
            with np.errstate(invalid="ignore", divide="ignore"):
                ss = np.where(cnt > 0, np.maximum(s2 - s1 * s1 / cnt, 0.0), 0.0)
            ss_w = np.bincount(pair_group, ss, minlength=ng)
            dof_w = np.bincount(pair_group, np.maximum(cnt - 1, 0), minlength=ng)
            n = np.bincount(groups, w, minlength=ng)
            t1, t2 = np.bincount(groups, x, minlength=ng), np.bincount(groups, x * x, minlength=ng)
            with np.errstate(invalid="ignore", divide="ignore"):
                total = np.maximum(t2 - t1 * t1 / n, 0.0) / (n - 1)
                var = np.where(dof_w > 0, ss_w / dof_w, total)
                out[m] = np.where(n >= 2, np.sqrt(var / n), np.nan)
    return out.reshape(tuple(lead) + tuple(batch))


@functools.lru_cache(maxsize=8)
def _student_table(p: float, size: int) -> np.ndarray:
    """t_((1+p)/2)(h − 1) for h = 0 … size − 1 (NaN below h = 2)."""
    h = np.arange(size, dtype=float)
    out = np.full(size, np.nan)
    out[2:] = stats.t.ppf(0.5 * (1 + p), h[2:] - 1)
    return out


def student_factor(h, p: float = COVERAGE_PROBABILITY) -> np.ndarray:
    """t_((1+p)/2)(h − 1): the factor of s/√h for h replicas (NaN where h < 2).

    >>> round(float(student_factor(4)), 3)
    3.182
    """
    h = np.asarray(h, dtype=float)
    whole = np.isfinite(h) & (h == np.floor(h)) & (h >= 0) & (h < 4096)
    if np.all(whole):  # replica counts: from a table computed once
        return _student_table(float(p), 4096)[h.astype(int)]
    with np.errstate(invalid="ignore"):
        return np.where(h >= 2, stats.t.ppf(0.5 * (1 + p), np.maximum(h - 1, 1)), np.nan)


def z_factor(p: float = COVERAGE_PROBABILITY) -> float:
    """Φ⁻¹((1 + p)/2): the factor of a delta-method standard deviation (1.96 for p = 0.95)."""
    return float(special.ndtri(0.5 * (1 + p)))


def replica_half_width(values, p: float = COVERAGE_PROBABILITY) -> tuple[np.ndarray, np.ndarray]:
    """t_((1+p)/2)(h − 1)·s/√h of the replica ``values`` (..., replica), NaN ignored; and h.

    NaN where fewer than two replicas have a value.
    """
    v = np.asarray(values, dtype=float)
    h = np.isfinite(v).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.maximum(h, 1)
        mean = np.where(h > 0, np.nansum(v, axis=-1) / n, np.nan)
        dev = np.where(np.isfinite(v), v - mean[..., None], 0.0)
        s = np.sqrt((dev**2).sum(axis=-1) / np.maximum(h - 1, 1))
        w = student_factor(h, p) * s / np.sqrt(n)
    return np.where(h >= 2, w, np.nan), h


def tolerance_exponent(spread) -> np.ndarray:
    """Smallest integer ℓ with ½·10^ℓ ≥ ``spread``; −inf where it is 0, NaN where NaN.

    >>> tolerance_exponent(np.array([0.04, 0.05, 0.051, 0.3])).astype(int).tolist()
    [-1, -1, 0, 0]
    """
    spread = np.asarray(spread, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ell = np.ceil(np.log10(2.0 * spread) - 1e-12)
    return np.where(spread > 0, ell, np.where(spread == 0, -np.inf, np.nan))


def replicas_needed(h, replica_sd, delta_sd, target, max_replicas: int,
                    p: float = COVERAGE_PROBABILITY) -> np.ndarray:
    """Fewest replicas H (h < H ≤ ``max_replicas``) at which a value is expected to settle.

    ``h`` (...) is the replicas done, ``replica_sd`` the standard deviation of one replica's
    value (s, from the h done), ``delta_sd`` the delta-method standard deviation of the value
    from the trials of the h replicas, ``target`` the tolerance δ it must reach.  With H
    replicas the half-widths are expected to be t(H − 1)·s/√H and z·``delta_sd``·√(h/H) (the
    trials grow in proportion); the smallest H meeting both is returned (Stein's two-stage idea,
    Wübbeler et al. 2010, with the estimate refreshed at every batch), ``max_replicas`` when
    none does (NaN inputs count as no constraint).

    >>> int(replicas_needed(4, np.array([0.1]), np.array([0.0]), np.array([0.05]), 30)[0])
    18
    """
    s = np.asarray(replica_sd, dtype=float)
    h = np.broadcast_to(np.asarray(h, dtype=float), s.shape)
    dsd = np.broadcast_to(np.asarray(delta_sd, dtype=float), s.shape)
    tgt = np.broadcast_to(np.asarray(target, dtype=float), s.shape)
    hs = np.arange(1, int(max_replicas) + 1, dtype=float)
    t = student_factor(hs, p)
    with np.errstate(invalid="ignore", divide="ignore"):
        rep_ok = ~(t * s[..., None] / np.sqrt(hs) > tgt[..., None])
        delta_ok = ~(z_factor(p) * dsd[..., None] * np.sqrt(h[..., None] / hs) > tgt[..., None])
    ok = rep_ok & delta_ok & (hs > h[..., None])
    return np.where(ok.any(axis=-1), hs[np.argmax(ok, axis=-1)], float(max_replicas)).astype(int)
