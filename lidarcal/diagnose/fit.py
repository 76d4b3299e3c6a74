"""Fitting a catalogue effect to the residual: pure numpy, no files, no xarray.

The workflow (see :mod:`lidarcal.diagnose.core`) simulates the campaign with the nominal model
θ₀ and again at a probe value θ₀ + h with the *same seeds* (common random numbers), so the
difference ``Δd = d_sim(θ₀+h) − d_sim(θ₀)`` of the simulated relative differences carries the
effect with most of the Monte Carlo noise cancelled.  What is left of the noise would bias a
regression on ``Δd`` towards zero (errors in variables), so the response is first *smoothed*:
per height, ``Δd/h`` is regressed on a quadratic in the effect's environmental drivers
(:func:`smooth_response`), which estimates E[∂d/∂θ | conditions] — the quantity that links the
model to independent field data.

The parameter is then fitted by weighted least squares of the per-period residual
``r = d_meas − d_sim(θ₀)`` on that response (:func:`fit_linear`), with

- weights from a noise model estimated on the *simulation* (independent of the field data and
  of the effect sought): per height, the squared scatter of ``d_sim`` about its smooth mean
  regressed on [1, TI²] (:func:`noise_weights`);
- a standard error that is robust to heteroscedasticity and to the correlation between the
  heights of one period (a cluster-robust sandwich estimator, clusters = periods);
- a BIC on the weighted residual sum of squares with the number of observations replaced by
  an effective number ``n / deff``, where the design effect ``deff = 1 + (m − 1)·ρ`` comes from
  the intra-period correlation ρ of the residuals over m heights (:func:`design_effect`);
  treating correlated heights as independent would inflate every ΔBIC by up to a factor m and
  give false alarms.

The reported uncertainties come from a block bootstrap over days (:func:`bootstrap_fit`):
whole days of periods are resampled with replacement and the weighted least-squares fit is
repeated on the same responses.  Weather persists for hours, so a misfit of the model (a
structure in the residual no catalogue effect has) is correlated within a day; resampling
days keeps that correlation, where the per-period sandwich treats it as independent noise
and under-states the uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

__all__ = [
    "features", "smooth_response", "noise_weights", "design_effect", "FitResult", "fit_linear",
    "delta_bic", "day_clusters", "bootstrap_fit", "bootstrap_rss", "bootstrap_grid",
]


def features(drivers: list[np.ndarray]) -> np.ndarray:
    """Quadratic design matrix [1, xᵢ, xᵢ², xᵢ·xⱼ] of 1-D driver arrays, standardised."""
    n = drivers[0].size if drivers else 0
    cols = [np.ones(n)] if drivers else []
    std = []
    for x in drivers:
        x = np.asarray(x, dtype=float)
        s = np.nanstd(x)
        std.append((x - np.nanmean(x)) / (s if s > 0 else 1.0))
    cols += std
    cols += [x**2 for x in std]
    cols += [a * b for a, b in combinations(std, 2)]
    return np.column_stack(cols) if cols else np.ones((0, 1))


def smooth_response(dy: np.ndarray, drivers: dict[str, np.ndarray], names: tuple[str, ...],
                    valid: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Per height, the (weighted) least-squares fit of ``dy`` (periods × heights) on :func:`features`.

    With no drivers the response is the per-height mean.  Entries outside ``valid`` are NaN.
    Use the weights of the later parameter fit: the smoothed response is then the projection
    of the true response on the feature space *in the fit's inner product*, so the fitted
    parameter stays unbiased even where the features do not capture every dependence.
    """
    out = np.full(dy.shape, np.nan)
    for j in range(dy.shape[1]):
        ok = valid[:, j] & np.isfinite(dy[:, j])
        if weights is not None:
            ok &= weights[:, j] > 0
        for name in names:
            ok &= np.isfinite(drivers[name][:, j])
        if not ok.any():
            continue
        cols = [drivers[name][ok, j] for name in names]
        X = features(cols) if cols else np.ones((int(ok.sum()), 1))
        if X.shape[1] >= ok.sum():  # too few periods for the quadratic: fall back to the mean
            X = np.ones((int(ok.sum()), 1))
        sw = np.sqrt(weights[ok, j]) if weights is not None else np.ones(int(ok.sum()))
        beta, *_ = np.linalg.lstsq(X * sw[:, None], dy[ok, j] * sw, rcond=None)
        out[ok, j] = X @ beta
    return out


def noise_weights(d_sim: np.ndarray, drivers: dict[str, np.ndarray], valid: np.ndarray) -> np.ndarray:
    """Inverse-variance weights (periods × heights, mean 1 over ``valid``) from the simulation.

    Per height: the scatter of the simulated relative difference about its smooth mean in all
    drivers is squared and regressed on [1, TI²]; the fitted variance is floored at a quarter of
    its median so that no period gets an extreme weight.
    """
    names = tuple(drivers)
    smooth = smooth_response(d_sim, drivers, names, valid)
    var = np.full(d_sim.shape, np.nan)
    ti = drivers["turbulence_intensity"]
    for j in range(d_sim.shape[1]):
        ok = valid[:, j] & np.isfinite(smooth[:, j]) & np.isfinite(ti[:, j])
        if ok.sum() < 3:
            continue
        e2 = (d_sim[ok, j] - smooth[ok, j]) ** 2
        X = np.column_stack([np.ones(ok.sum()), ti[ok, j] ** 2])
        beta, *_ = np.linalg.lstsq(X, e2, rcond=None)
        v = X @ beta
        floor = 0.25 * np.median(e2) if np.median(e2) > 0 else np.mean(e2)
        var[ok, j] = np.maximum(v, max(floor, 1e-12))
    w = np.where(np.isfinite(var), 1.0 / var, 0.0)
    w[~valid] = 0.0
    mean = w[w > 0].mean() if (w > 0).any() else 1.0
    return w / mean


def design_effect(r: np.ndarray, w: np.ndarray) -> float:
    """Design effect 1 + (m̄ − 1)·ρ of per-period clusters of heights (≥ 1).

    ρ is the intra-period correlation of the standardised residuals ``r·√w`` (zero-mean model:
    the mean residual is removed first); m̄ the mean number of usable heights per period.
    """
    e = np.where(w > 0, r * np.sqrt(w), np.nan)
    e = e - np.nanmean(e)
    e = np.where(np.isfinite(e), e, 0.0)
    m = (w > 0).sum(axis=1)
    keep = m >= 2
    if not keep.any():
        return 1.0
    e, m = e[keep], m[keep]
    total = (e**2).sum()
    cross = (e.sum(axis=1) ** 2 - (e**2).sum(axis=1)).sum()
    pairs = (m * (m - 1)).sum()
    if total <= 0 or pairs <= 0:
        return 1.0
    rho = (cross / pairs) / (total / m.sum())
    mbar = m.mean()
    return float(max(1.0, 1.0 + (mbar - 1.0) * rho))


@dataclass
class FitResult:
    """Outcome of a weighted least-squares fit of the residual on the response(s).

    ``delta``/``rss`` are the fit *inside* the bounds (the constrained optimum: parameters that
    leave their range are held at the bound they cross and the others refitted);
    ``delta_free``/``stderr_free``/``rss_free`` the unconstrained fit — what the data ask for,
    which a caller compares with the bounds (``docs/diagnose.md``: a fit at a bound within its
    uncertainty is an answer, one beyond it by more is out of range).
    """

    delta: np.ndarray       # fitted θ − θ₀ per parameter, inside the bounds
    stderr: np.ndarray      # cluster-robust standard error per parameter
    rss: float              # weighted residual sum of squares with the fit
    rss0: float             # ... without it (the `none` model)
    clipped: bool           # some parameter is held at a bound (``at_bound``)
    delta_free: np.ndarray | None = None   # unconstrained θ − θ₀
    stderr_free: np.ndarray | None = None  # its cluster-robust standard error
    rss_free: float = float("nan")         # weighted RSS of the unconstrained fit
    at_bound: np.ndarray | None = None     # per parameter: held at a bound

    def __post_init__(self):
        if self.delta_free is None:
            self.delta_free = np.array(self.delta, dtype=float)
        if self.stderr_free is None:
            self.stderr_free = np.array(self.stderr, dtype=float)
        if not np.isfinite(self.rss_free):
            self.rss_free = self.rss
        if self.at_bound is None:
            self.at_bound = np.zeros(np.size(self.delta), dtype=bool)


def _bounded_solve(A: np.ndarray, b: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimise δᵀAδ − 2bᵀδ within lo ≤ δ ≤ hi (A positive definite, a handful of parameters).

    An active-set loop: solve for the free parameters, hold the one furthest outside its range at
    the bound it crosses, repeat; a held parameter whose gradient points back inside is released.
    Exact for one parameter (the clip); for several it is the constrained optimum, where clipping
    each parameter on its own is not.  Returns (δ, held-at-bound mask).
    """
    k = b.size
    held = np.zeros(k, dtype=bool)
    delta = np.zeros(k)
    for _ in range(4 * k + 4):
        delta = np.where(held, np.clip(delta, lo, hi), 0.0)
        free = ~held
        if free.any():
            rhs = b[free] - A[np.ix_(free, held)] @ delta[held]
            delta[free] = np.linalg.solve(A[np.ix_(free, free)], rhs)
        over = np.maximum(lo - delta, delta - hi)
        over[held] = -np.inf
        if free.any() and np.max(over) > 0:
            j = int(np.argmax(over))
            held[j] = True
            delta[j] = np.clip(delta[j], lo[j], hi[j])
            continue
        # release a held parameter whose optimum moves back inside its range
        grad = b - A @ delta  # descent direction of the objective (up to a factor 2)
        release = held & (((delta <= lo) & (grad > 0)) | ((delta >= hi) & (grad < 0)))
        if not release.any():
            break
        held[int(np.flatnonzero(release)[0])] = False
    return delta, held


def fit_linear(r: np.ndarray, J: np.ndarray | list[np.ndarray], w: np.ndarray,
               bounds: list[tuple[float, float]] | None = None) -> FitResult:
    """Fit ``r ≈ Σₖ δₖ·Jₖ`` by weighted least squares (periods × heights arrays).

    ``bounds`` are limits on δ (θ bounds minus θ₀): the fit is then the constrained optimum (see
    :func:`_bounded_solve`), and the unconstrained one is kept in ``delta_free`` with its
    standard error.  Observations with zero weight or a non-finite value are ignored.
    """
    Js = [J] if isinstance(J, np.ndarray) else list(J)
    ok = (w > 0) & np.isfinite(r)
    for Jk in Js:
        ok &= np.isfinite(Jk)
    rows, _ = np.nonzero(ok)
    y = r[ok]
    ww = w[ok]
    X = np.column_stack([Jk[ok] for Jk in Js])
    rss0 = float(np.sum(ww * y**2))
    A = X.T @ (ww[:, None] * X)
    if y.size <= X.shape[1] or np.linalg.cond(A) > 1e12:
        k = X.shape[1]
        return FitResult(np.zeros(k), np.full(k, np.inf), rss0, rss0, False)
    b = X.T @ (ww * y)
    free = np.linalg.solve(A, b)
    delta, held = free, np.zeros(free.size, dtype=bool)
    if bounds is not None:
        lo = np.array([bd[0] for bd in bounds], dtype=float)
        hi = np.array([bd[1] for bd in bounds], dtype=float)
        if np.any((free < lo) | (free > hi)):
            delta, held = _bounded_solve(A, b, lo, hi)
    _, inv = np.unique(rows, return_inverse=True)
    G = int(inv.max()) + 1
    Ainv = np.linalg.inv(A)

    def sandwich(d: np.ndarray) -> tuple[float, np.ndarray]:
        # cluster-robust (periods) sandwich covariance, with the small-sample factor G/(G-1)
        e = y - X @ d
        S = np.zeros((G, X.shape[1]))
        np.add.at(S, inv, X * (ww * e)[:, None])
        cov = Ainv @ (S.T @ S) @ Ainv * (G / max(G - 1, 1))
        return float(np.sum(ww * e**2)), np.sqrt(np.diag(cov))

    rss_free, se_free = sandwich(free)
    rss, se = sandwich(delta) if held.any() else (rss_free, se_free)
    return FitResult(delta, se, rss, rss0, bool(held.any()), delta_free=free,
                     stderr_free=se_free, rss_free=rss_free, at_bound=held)


def delta_bic(rss: float, rss0: float, n_params: int, n_eff: float) -> float:
    """BIC of a fit minus BIC of the `none` model: n_eff·ln(RSS/RSS₀) + k·ln(n_eff)."""
    if rss0 <= 0 or rss <= 0:
        return 0.0
    return float(n_eff * np.log(rss / rss0) + n_params * np.log(n_eff))


def day_clusters(times: np.ndarray, min_days: int = 8, n_blocks: int = 20) -> tuple[np.ndarray, str]:
    """Cluster label of every period for the block bootstrap, and a description of the blocks.

    Calendar days (UTC) of ``times`` when there are at least ``min_days`` of them; otherwise
    (a short or timeless record) ``n_blocks`` blocks of consecutive periods.
    """
    t = np.asarray(times)
    n = t.size
    if np.issubdtype(t.dtype, np.datetime64):
        day = t.astype("datetime64[D]")
        _, lab = np.unique(day, return_inverse=True)
        if lab.max(initial=-1) + 1 >= min_days:
            return lab.astype(int), f"{int(lab.max()) + 1} days"
    k = max(2, min(int(n_blocks), n // 5 if n >= 10 else 2))
    lab = np.minimum((np.arange(n) * k) // max(n, 1), k - 1)
    return lab, f"{k} blocks of consecutive periods"


def bootstrap_fit(r: np.ndarray, J: list[np.ndarray], w: np.ndarray, clusters: np.ndarray,
                  n_boot: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Block bootstrap of the fit ``r ≈ Σₖ δₖ·Jₖ``: (δ on all data, δ of each of ``n_boot`` resamples).

    ``clusters`` labels each period (row); clusters are drawn with replacement as many times as
    there are clusters.  The fit is linear, so each cluster's normal equations (XᵀWX, XᵀWy) are
    summed once and a resample is a weighted sum of them: hundreds of refits cost milliseconds.
    """
    ok = (w > 0) & np.isfinite(r)
    for Jk in J:
        ok &= np.isfinite(Jk)
    rows, _ = np.nonzero(ok)
    X = np.column_stack([Jk[ok] for Jk in J])
    y, ww = r[ok], w[ok]
    _, g = np.unique(np.asarray(clusters)[rows], return_inverse=True)
    G, k = int(g.max()) + 1 if g.size else 0, X.shape[1]
    if G == 0:
        return np.full(k, np.nan), np.full((0, k), np.nan)
    A = np.zeros((G, k, k))
    b = np.zeros((G, k))
    np.add.at(A, g, X[:, :, None] * X[:, None, :] * ww[:, None, None])
    np.add.at(b, g, X * (ww * y)[:, None])
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xB007]))
    counts = rng.multinomial(G, np.full(G, 1.0 / G), size=int(n_boot)).astype(float)
    At = np.einsum("bg,gij->bij", counts, A)
    bt = counts @ b
    full = np.linalg.lstsq(A.sum(axis=0), b.sum(axis=0), rcond=None)[0]
    good = np.linalg.cond(At) < 1e12
    samples = np.full((int(n_boot), k), np.nan)
    samples[good] = np.linalg.solve(At[good], bt[good][:, :, None])[:, :, 0]
    return full, samples


def bootstrap_rss(r: np.ndarray, alternatives: list[list[np.ndarray]], w: np.ndarray, clusters: np.ndarray,
                  n_boot: int = 400, seed: int = 0) -> np.ndarray:
    """Weighted RSS (n_boot, n_alternatives) of least-squares fits of ``r`` in block-bootstrap resamples.

    ``alternatives[i]`` are the response columns of alternative ``i`` (fitted unconstrained in
    each resample; no column: the RSS of ``r`` itself).  Only periods where every column is
    finite count, for all alternatives alike.  Per alternative and cluster the normal equations
    and yᵀWy are summed once; a resample's RSS is Σc·yᵀWy − bᵀA⁻¹b with the cluster counts c.
    The same resamples (seed) as :func:`bootstrap_fit`.
    """
    ok = (w > 0) & np.isfinite(r)
    for cols in alternatives:
        for Jk in cols:
            ok &= np.isfinite(Jk)
    rows, _ = np.nonzero(ok)
    _, g = np.unique(np.asarray(clusters)[rows], return_inverse=True)
    G = int(g.max()) + 1 if g.size else 0
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xB007]))
    counts = rng.multinomial(G, np.full(G, 1.0 / max(G, 1)), size=int(n_boot)).astype(float)
    y, ww = r[ok], w[ok]
    yy = np.zeros(G)
    np.add.at(yy, g, ww * y * y)
    rss = np.empty((int(n_boot), len(alternatives)))
    for i, cols in enumerate(alternatives):
        rss[:, i] = counts @ yy
        if not cols:
            continue
        X = np.column_stack([Jk[ok] for Jk in cols])
        k = X.shape[1]
        A = np.zeros((G, k, k))
        b = np.zeros((G, k))
        np.add.at(A, g, X[:, :, None] * X[:, None, :] * ww[:, None, None])
        np.add.at(b, g, X * (ww * y)[:, None])
        At = np.einsum("bg,gij->bij", counts, A) + 1e-30 * np.eye(k)
        bt = counts @ b
        beta = np.linalg.solve(At, bt[:, :, None])[:, :, 0]
        rss[:, i] -= np.einsum("bk,bk->b", bt, beta)
    return rss


def bootstrap_grid(r: np.ndarray, responses: list[list[np.ndarray]], w: np.ndarray, clusters: np.ndarray,
                   n_boot: int = 400, seed: int = 0) -> np.ndarray:
    """Index of the best grid point (least weighted RSS) in each block-bootstrap resample.

    ``responses[i]`` are the response columns of grid point ``i`` (the linear parameters are fitted
    at each point; :func:`bootstrap_rss`).
    """
    return np.argmin(bootstrap_rss(r, responses, w, clusters, n_boot, seed), axis=1)
