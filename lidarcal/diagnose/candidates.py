"""Fit the catalogue's effects to the residual: responses, joint least squares, bootstrap intervals.

Every linear parameter's response ∂d/∂θ is measured by one probe with the campaign's own seeds
(:func:`responses`); grid parameters are scanned (:func:`grid_scan`); the responses of several
effects are fitted together by weighted least squares inside the physical ranges
(:func:`joint_fit`); their uncertainties come from a day-block bootstrap plus a model-form share
(:func:`bootstrap`).  :func:`fit_candidates` fits every effect alone and scores it by ΔBIC.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence

import numpy as np

from lidarcal.diagnose import fit
from lidarcal.diagnose.effects import Effect
from lidarcal.diagnose.problem import CandidateFit, Problem, records_difference
from lidarcal.errors import InputError

__all__ = ["responses", "grid_scan", "columns", "joint_fit", "fitted", "range_verdict", "contribution",
           "bootstrap", "fit_candidates"]

log = logging.getLogger("lidarcal.diagnose")


def responses(problem: Problem, eff: Effect, at: Mapping[str, float] | None = None) -> CandidateFit:
    """Measure ∂d/∂θ of every linear parameter of ``eff`` by one probe each (common random numbers).

    ``at`` fixes the grid parameters (a :meth:`Effect.grid_points` entry).  The response of an
    effect with grid parameters is exact (a shortcut on the same records, e.g. the hard-edged
    mast-shadow sector) and is used as it is; smoothing it on its drivers would blur the edge.
    """
    at = dict(at or {})
    theta0 = eff.nominal(problem.model)
    probe = eff.probe(problem.model, at=at) if at else eff.probe(problem.model)
    d_at = problem.d0 if not at else records_difference(
        problem.records_at(eff, {**theta0, **at}, f"{eff.id} at {at}"))
    Js = []
    for p in eff.linear_parameters:
        params = {**theta0, **at, p.name: probe[p.name]}
        label = f"{eff.id} probe {p.name}={probe[p.name]:g}"
        d_probe = records_difference(problem.records_at(eff, params, label))
        dy = (d_probe - d_at) / (probe[p.name] - theta0[p.name])
        Js.append(np.where(problem.valid, dy, np.nan) if eff.grid_parameters else problem.smooth(eff, dy))
    return CandidateFit(eff, theta0, {**theta0, **at}, {p.name: np.nan for p in eff.parameters}, np.nan, 0.0,
                        probe, response=Js)


def grid_scan(problem: Problem, eff: Effect, others: Sequence[CandidateFit]) -> CandidateFit:
    """Scan the grid parameters of ``eff`` (fitted with ``others``); return the best point's candidate.

    Every point's linear parameters are fitted by least squares together with ``others``; the
    point with the least weighted RSS wins.  The grid parameters' 95 % intervals come from the
    same day-block bootstrap: the spread of the winning point over the resamples, widened by
    half the grid spacing on each side (the grid's own resolution).
    """
    if eff.shortcut is None:
        raise InputError(f"effect {eff.id!r}: grid parameters need an exact shortcut (no re-simulation "
                         f"per grid point)")
    points = eff.grid_points()
    cands = [responses(problem, eff, at=pt) for pt in points]
    fixed = fitted(others) if others else 0.0
    r = problem.r - np.where(problem.valid, fixed, 0.0)
    rss = []
    for c in cands:
        res = fit.fit_linear(r, c.response, problem.weights, bounds=c.bounds)
        rss.append(res.rss if np.all(np.isfinite(res.stderr)) else np.inf)
    best = cands[int(np.argmin(rss))]
    picks = fit.bootstrap_grid(r, [c.response for c in cands], problem.weights, problem.clusters,
                               problem.n_boot, problem.seed)
    for p in eff.grid_parameters:
        vals = np.array([points[i][p.name] for i in picks])
        est = best.estimate[p.name]
        dev = vals - est
        if p.units == "degree" and p.bounds == (0.0, 360.0):  # a direction: deviations on the circle
            dev = np.mod(dev + 180.0, 360.0) - 180.0
        lo, hi = np.quantile(dev, [0.025, 0.975])
        # the grid resolves the parameter only to its spacing: widen by half a step each side
        step = float(np.median(np.diff(np.unique(p.grid)))) if len(p.grid) > 1 else 0.0
        best.stderr[p.name] = float(np.sqrt(np.var(dev, ddof=1) + step**2 / 12.0))
        best.interval[p.name] = (est + float(lo) - step / 2, est + float(hi) + step / 2)
    return best


def columns(cands: Sequence[CandidateFit]) -> tuple[list[np.ndarray], list[tuple[float, float]]]:
    """Responses and bounds of the linear parameters of ``cands``, in order (the fit's columns)."""
    Js, bounds = [], []
    for c in cands:
        Js += c.response
        bounds += c.bounds
    return Js, bounds


def joint_fit(problem: Problem, cands: Sequence[CandidateFit],
               r: np.ndarray | None = None) -> fit.FitResult:
    """Fit ``r`` (default the residual) on the responses of ``cands`` together; set their estimates."""
    Js, bounds = columns(cands)
    res = fit.fit_linear(problem.r if r is None else r, Js, problem.weights, bounds=bounds)
    k = 0
    for c in cands:
        for p in c.effect.linear_parameters:
            c.estimate[p.name] = c.nominal[p.name] + float(res.delta[k])
            c.stderr[p.name] = float(res.stderr[k])
            c.free[p.name] = c.nominal[p.name] + float(res.delta_free[k])
            c.free_se[p.name] = float(res.stderr_free[k])
            k += 1
        c.clipped = res.clipped
    return res


def fitted(cands: Sequence[CandidateFit], free: bool = False) -> np.ndarray:
    """Σ (θ − θ₀)·∂d/∂θ over the parameters of ``cands``: the linearised change of d.

    ``free``: at the unconstrained fit (what the data ask for) instead of the estimate, which
    stays inside the physical range.
    """
    out = 0.0
    for c in cands:
        for p, J in zip(c.effect.linear_parameters, c.response, strict=True):
            theta = c.free.get(p.name, c.estimate[p.name]) if free else c.estimate[p.name]
            out = out + (theta - c.nominal[p.name]) * J
    return out


def range_verdict(problem: Problem, cands: Sequence[CandidateFit],
                   stderr: Mapping[str, Mapping[str, float]] | None = None) -> tuple[list[str], list[str]]:
    """Where the unconstrained fits of ``cands`` lie against their physical ranges.

    Returns (``beyond``, ``at_bound``): one sentence per linear parameter whose unconstrained
    fit leaves its range by more than its uncertainty (out of range: not an estimate of that
    effect), and one per parameter that leaves it by less (an answer at the bound; its interval
    is truncated there).  The uncertainty is the expanded (95 %) one: 1.96 × the standard
    uncertainty, which combines the sandwich standard error of the last joint fit with the
    model-form share of the fitted change — or, given ``stderr`` (effect id → parameter →
    combined standard uncertainty, the bootstrap's), that one.
    """
    beyond, at_bound = [], []
    for c in cands:
        for p in c.effect.linear_parameters:
            v = c.free.get(p.name, c.estimate[p.name])
            lo, hi = p.bounds
            if lo <= v <= hi or not np.isfinite(v):
                continue
            if stderr is not None:
                u = float(stderr.get(c.effect.id, {}).get(p.name, np.nan))
            else:
                u = float(np.hypot(c.free_se.get(p.name, np.nan),
                                   problem.form_share(c.effect) * abs(v - c.nominal[p.name])))
            U = 1.96 * u if np.isfinite(u) else 0.0
            side, bound = ("upper", hi) if v > hi else ("lower", lo)
            if abs(v - bound) <= U:
                at_bound.append(f"{c.effect.id} {p.name} = {bound:g} at the {side} bound of its physical "
                                f"range {p.describe_range()}: the unconstrained fit {v:.4g} +- {U:.2g} "
                                f"(95 %) reaches it within its uncertainty; its interval is truncated at "
                                f"the bound")
            else:
                beyond.append(f"{c.effect.id} wants {p.name} = {v:.4g} +- {U:.2g} (95 %), beyond its "
                              f"physical range {p.describe_range()} by more than its uncertainty")
    return beyond, at_bound


def contribution(problem: Problem, cand: CandidateFit) -> float:
    """Rms change (%) of (L − R)/R over the usable periods that ``cand`` at its estimate makes."""
    x = fitted([cand])
    x = np.asarray(x)[problem.valid] if np.ndim(x) else np.zeros(1)
    x = x[np.isfinite(x)]
    return 100.0 * float(np.sqrt(np.mean(x**2))) if x.size else 0.0


def bootstrap(problem: Problem, cands: Sequence[CandidateFit], r: np.ndarray | None = None) -> None:
    """Set the standard uncertainties and 95 % intervals of the linear parameters of ``cands``.

    The block bootstrap (days as blocks) gives the statistical part; a model-form part,
    ``problem.model_uncertainty`` × |θ̂ − θ₀| (the catalogue's responses are models of the physics:
    on an independent simulator the fitted parameters of strong effects move by 5–15 % of their
    size; an effect's share derived from the engine's alternatives or fitted on independent
    campaigns replaces it when larger: :func:`~lidarcal.diagnose.effects.model_form_share`), is
    added in quadrature to the standard error and to each side of the interval.
    """
    Js, _ = columns(cands)
    full, samples = fit.bootstrap_fit(problem.r if r is None else r, Js, problem.weights, problem.clusters,
                                      problem.n_boot, problem.seed)
    dev = samples - full
    k = 0
    for c in cands:
        for p in c.effect.linear_parameters:
            col = dev[:, k][np.isfinite(dev[:, k])]
            est = c.estimate[p.name]
            blo, bhi = p.bounds
            # held at a bound: the interval is the unconstrained fit's, truncated at the range
            centre = c.free.get(p.name, est) if est in (blo, bhi) else est
            if col.size >= 10:
                lo, hi = np.quantile(col, [0.025, 0.975])
                # model-form (Type B) standard uncertainty, a fixed share of the fitted change
                u_m = problem.form_share(c.effect) * abs(centre - c.nominal[p.name])
                c.stderr[p.name] = float(np.sqrt(np.var(col, ddof=1) + u_m**2))
                lower = centre - float(np.hypot(lo, 1.96 * u_m))
                upper = centre + float(np.hypot(hi, 1.96 * u_m))
                c.interval[p.name] = (min(max(lower, blo), est), max(min(upper, bhi), est))
            else:
                c.interval[p.name] = (np.nan, np.nan)
            k += 1


def fit_candidates(problem: Problem, effects: Sequence[Effect]) -> list[CandidateFit]:
    """Fit every effect alone from one probe per parameter; score it against ``none``; sort by ΔBIC."""
    problem.weights = fit.noise_weights(problem.d0, problem.conditions, problem.valid)
    problem.design_effect = fit.design_effect(np.where(problem.valid, problem.r, 0.0), problem.weights)
    problem.n_eff = float(problem.valid.sum()) / problem.design_effect
    fits: list[CandidateFit] = []
    for eff in effects:
        c = grid_scan(problem, eff, []) if eff.grid_parameters else responses(problem, eff)
        res = joint_fit(problem, [c])
        # the score is what the data ask for (the unconstrained fit); whether that lies in the
        # physical range is judged apart (range_verdict) and said in the note
        c.delta_bic = fit.delta_bic(res.rss_free, res.rss0, eff.n_parameters, problem.n_eff)
        c.explained = 1.0 - res.rss_free / res.rss0 if res.rss0 > 0 else 0.0
        c.contribution = contribution(problem, c)
        bootstrap(problem, [c])
        fits.append(c)
        log.info(f"  {eff.id}: "
                 + ", ".join(f"{k} = {v:.4g} ± {c.stderr[k]:.2g}" for k, v in c.estimate.items())
                 + f", ΔBIC = {c.delta_bic:.1f}, explains {100 * c.explained:.1f} %, "
                 f"changes (L-R)/R by {c.contribution:.3f} % rms")
    fits.sort(key=lambda c: c.delta_bic)
    return fits
