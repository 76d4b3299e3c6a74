"""Name effects: forward selection, pruning, refinement, and the answer with its note.

:func:`select` adds the candidate that lowers the BIC most while it is strong and material,
:func:`adequate` keeps the named effects only if together they explain the disagreement,
:func:`refine` re-simulates at the estimates and corrects them, :func:`range_notes` and
:func:`answer` say what was found (``docs/diagnose.md``).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lidarcal.diagnose import fit
from lidarcal.diagnose.candidates import (
    bootstrap,
    columns,
    contribution,
    fitted,
    grid_scan,
    joint_fit,
    range_verdict,
)
from lidarcal.diagnose.problem import CandidateFit, Problem, records_difference

__all__ = ["select", "adequate", "refine", "range_notes", "minor_effects", "conclude", "DEFAULT_TOLERANCE",
           "DEFAULT_MIN_SHARE", "TIE_RESAMPLE_SHARE"]

log = logging.getLogger("lidarcal.diagnose")

#: Practical tolerance (%): a tenth of the ~1 % standard uncertainty of a lidar calibration
#: (docs/diagnose.md); smaller changes of (L−R)/R are not worth naming.
DEFAULT_TOLERANCE = 0.1
#: Share of the systematic residual (the gap metric's square) an added effect must explain.  0 by
#: default: the share is reported, but it does not gate, because it is not additive when effects
#: overlap with opposite signs (removing a mast shadow that offsets an over-speeding cup's
#: negative bias widens the gap the cup leaves in every other bin).
DEFAULT_MIN_SHARE = 0.0


@dataclass
class _Trial:
    """One candidate fitted together with the effects already named (a step of forward selection)."""

    cand: CandidateFit
    dbic: float                 # ΔBIC against the current model, unconstrained fit
    res: fit.FitResult
    contribution: float         # rms change of (L−R)/R at the estimate (inside the range), %
    share: float
    g2: float                   # gap² left at the estimates (inside the range)
    g2_free: float              # gap² left at the unconstrained fit
    estimates: dict[str, tuple[dict, dict, dict, dict]]
    beyond: list[str]           # parameters beyond their physical range by more than their uncertainty
    reasons: list[str] = field(default_factory=list)  # why it may not be added (empty: it may)

    @property
    def id(self) -> str:
        return self.cand.effect.id


def _snapshot(cands: Sequence[CandidateFit]) -> dict[str, tuple[dict, dict, dict, dict]]:
    return {x.effect.id: (dict(x.estimate), dict(x.stderr), dict(x.free), dict(x.free_se)) for x in cands}


def _restore(cands: Sequence[CandidateFit], snap: Mapping[str, tuple[dict, dict, dict, dict]]) -> None:
    for x in cands:
        x.estimate, x.stderr, x.free, x.free_se = (dict(v) for v in snap[x.effect.id])


def range_notes(problem: Problem, chosen: Sequence[CandidateFit]) -> list[str]:
    """Note lines for named parameters at a bound of their physical range (or, after refining, beyond it).

    Judged with the final (bootstrap + model-form) uncertainties; a parameter the data push beyond
    its range by more than that is held at the bound, and the note says so.
    """
    if not chosen:
        return []
    beyond, at_bound = range_verdict(problem, chosen, {c.effect.id: c.stderr for c in chosen})
    held = "held at the bound, so the named value is not what the data ask for"
    return at_bound + [f"{line}; {held}" for line in beyond]


def _try(problem: Problem, chosen: list[CandidateFit], c: CandidateFit, rss_cur: float, g0: float,
         g_cur: float, bic_threshold: float, tolerance: float, min_share: float) -> _Trial | None:
    """Fit ``c`` together with ``chosen`` and say why it may not be added (None: collinear with them).

    The estimates of ``chosen`` and ``c`` are restored afterwards; the trial keeps its own.
    """
    tol2 = tolerance**2
    if c.effect.grid_parameters and chosen:  # re-scan the grid on what is left
        scan = grid_scan(problem, c.effect, chosen)
        c.estimate, c.response, c.interval = scan.estimate, scan.response, scan.interval
        c.stderr = scan.stderr
    trial = chosen + [c]
    saved = _snapshot(trial)
    clipped = c.clipped
    res = joint_fit(problem, trial)
    if not np.all(np.isfinite(res.stderr)):  # collinear with what is chosen: nothing to add
        _restore(trial, saved)
        c.clipped = clipped
        return None
    dbic = fit.delta_bic(res.rss_free, rss_cur, c.effect.n_parameters, problem.n_eff)
    g2 = problem.gap2(problem.r - np.where(problem.valid, fitted(trial), 0.0))
    g2_free = problem.gap2(problem.r - np.where(problem.valid, fitted(trial, free=True), 0.0))
    share = (g_cur - g2) / g0 if g0 > 0 else 0.0
    beyond, _ = range_verdict(problem, trial)
    t = _Trial(c, dbic, res, contribution(problem, c), share, g2, g2_free, _snapshot(trial), beyond)
    if dbic > -bic_threshold:
        t.reasons.append(f"ΔBIC {dbic:.1f} > -{bic_threshold:g}")
    crosses = g_cur > tol2 >= g2
    if t.contribution < tolerance and not crosses and not beyond:
        small = f"changes (L-R)/R by only {t.contribution:.3f} % < tolerance {tolerance:g} %"
        t.reasons.append(small + (f" and leaves a gap of {np.sqrt(g2):.3f} % (above the tolerance)"
                                  if g2 > tol2 else ""))
    t.reasons += beyond
    if min_share > 0 and share < min_share:
        t.reasons.append(f"explains {100 * share:.0f} % < {100 * min_share:.0f} % of the systematic "
                         "residual")
    _restore(trial, saved)
    c.clipped = clipped
    return t


#: A runner-up is tied with the pick when, within its model-form allowance, it fits the residual
#: at least as well in at least this share of the day-block bootstrap resamples (one side of 95 %).
TIE_RESAMPLE_SHARE = 0.025


def _indistinct(problem: Problem, chosen: Sequence[CandidateFit], a: _Trial, b: _Trial, rss_cur: float,
                tie_threshold: float) -> bool:
    """Tell whether ``b`` cannot be told from ``a`` given ``chosen`` (``rss_cur``: the RSS before either).

    Within ``tie_threshold`` BIC units; or ``b`` fitting worse than ``a`` by less than an error of
    b's own response model would cost (the catalogue's responses are models: a response wrong by
    its model-form share u of itself adds about u² of the explained sum of squares; at 95 %,
    (1.96 u)² of it) — e.g. a hybrid weight and a TI-proportional cup over-speeding; or the data
    not deciding: in at least :data:`TIE_RESAMPLE_SHARE` of the day-block bootstrap resamples
    ``b`` fits within that allowance of ``a``.  b's share, not a's: an imprecise response of the
    pick does not make every other effect plausible, an imprecise response of the runner-up can
    hide that it is the right one.
    """
    allowance = (1.96 * problem.form_share(b.cand.effect)) ** 2
    if b.dbic - a.dbic < tie_threshold or b.res.rss_free - a.res.rss_free <= allowance * max(
            rss_cur - a.res.rss_free, 0.0):
        return True
    rss = fit.bootstrap_rss(problem.r, [columns(chosen)[0], columns([*chosen, a.cand])[0],
                                        columns([*chosen, b.cand])[0]],
                            problem.weights, problem.clusters, problem.n_boot, problem.seed)
    within = rss[:, 2] - rss[:, 1] <= allowance * np.maximum(rss[:, 0] - rss[:, 1], 0.0)
    return bool(np.mean(within) >= TIE_RESAMPLE_SHARE)


def select(problem: Problem, fits: list[CandidateFit], bic_threshold: float, tie_threshold: float,
            tolerance: float, min_share: float) -> tuple[list[CandidateFit], list[str]]:
    """Forward selection: add the effect that lowers the BIC most while it is strong and material.

    At each step every remaining candidate is fitted together with those already chosen (the
    score is the unconstrained fit: what the data ask for).  It may be added when

    - its ΔBIC against the current model is ≤ −``bic_threshold`` (strong);
    - it is material: its fitted change of (L − R)/R is at least ``tolerance`` % rms, or its
      addition takes the gap from above the tolerance to below it (the diagnosis's own
      definition of a material gap);
    - no parameter of the joint fit wants to leave its physical range by more than its
      uncertainty (a fit at a bound within its uncertainty is an answer, held at the bound);
    - it removes at least ``min_share`` of the initial systematic residual (when asked).

    The best-scoring candidate is never silently replaced: when it may not be added the step
    says why, and a runner-up that may is added alone only if it explains the gap comparably —
    it cannot be told from the refused one (below) or leaves less than the tolerance more gap
    (in quadrature) than the refused one's unconstrained fit would; otherwise the two are
    ``tied``.  Candidates within ``tie_threshold`` of the one added that qualify too, or fitting
    worse by less than a model-form error would cost, are recorded as tied with it.
    Returns the chosen effects (most important first) and one line per step for the note.
    """
    chosen: list[CandidateFit] = []
    steps: list[str] = []
    rss_cur = float(np.sum(np.where(problem.valid, problem.weights * np.nan_to_num(problem.r) ** 2, 0.0)))
    g0 = problem.gap2(problem.r)
    g_cur = g0
    while True:
        tried = (_try(problem, chosen, c, rss_cur, g0, g_cur, bic_threshold, tolerance, min_share)
                 for c in fits if c not in chosen)
        trials = [t for t in tried if t is not None]
        if not trials:
            break
        trials.sort(key=lambda t: t.dbic)
        ok = [t for t in trials if not t.reasons]
        if not ok:
            steps.append(f"next best {trials[0].id} not added ({'; '.join(trials[0].reasons)})")
            break
        pick = ok[0]

        # the better-scoring candidates that may not be added: say why; the best-scoring one is tied
        # with the pick unless the pick explains the gap comparably
        forced = []
        for t in trials[:trials.index(pick)]:
            extra = float(np.sqrt(max(pick.g2 - t.g2_free, 0.0)))
            line = (f"{t.id} scores better (ΔBIC {t.dbic:.1f} against {pick.dbic:.1f} for {pick.id}) but is "
                    f"not added ({'; '.join(t.reasons)})")
            if t is not trials[0]:
                steps.append(line)
            elif extra < tolerance:
                steps.append(f"{line}; {pick.id} explains the gap comparably (it leaves {extra:.3f} % more, "
                             f"in quadrature, < tolerance {tolerance:g} %)")
            elif _indistinct(problem, chosen, t, pick, rss_cur, tie_threshold):
                steps.append(f"{line}; {pick.id} explains the gap comparably (these data cannot tell it from "
                             f"{t.id})")
            else:
                forced.append(t.id)
                steps.append(f"{line}; {pick.id} explains the gap less well (it leaves {extra:.3f} % more, "
                             f"in quadrature, >= tolerance {tolerance:g} %): the two are tied")
        best = pick.cand
        _restore(chosen + [best], pick.estimates)
        best.clipped = pick.res.clipped
        best.tied = forced + [t.id for t in ok[1:]
                              if _indistinct(problem, chosen, pick, t, rss_cur, tie_threshold)]
        best.contribution, best.share = pick.contribution, pick.share
        chosen.append(best)
        steps.append(f"{best.effect.id}: ΔBIC {pick.dbic:.1f}, changes (L-R)/R by {pick.contribution:.3f} % "
                     f"rms, explains {100 * pick.share:.0f} % of the systematic residual"
                     + (f" and takes the gap from {np.sqrt(g_cur):.3f} % to {np.sqrt(pick.g2):.3f} %, below "
                        f"the tolerance" if pick.contribution < tolerance else "")
                     + (f"; cannot be told apart from {', '.join(best.tied)}" if best.tied else ""))
        rss_cur, g_cur = pick.res.rss, pick.g2
    if chosen:
        joint_fit(problem, chosen)  # the trials after the last step moved the estimates
    return _prune(problem, chosen, steps, bic_threshold, tolerance)


def _prune(problem: Problem, chosen: list[CandidateFit], steps: list[str], bic_threshold: float,
           tolerance: float) -> tuple[list[CandidateFit], list[str]]:
    """Drop named effects that, given the others, no longer pass the test they were added by.

    With several effects named, each must, given all the others, still be strong (lower the BIC
    by at least ``bic_threshold``) and material (change (L − R)/R by at least the tolerance rms
    at the joint fit, or take the gap from above the tolerance — the others alone — to within
    it): forward selection judged each given only those named before it.  The weakest effect
    that fails (the highest ΔBIC) is dropped and the test repeated.  How much of the gap an
    effect removes given the others is reported, not gated on: an effect whose own change
    exceeds the tolerance is a finding whatever gap happens to be left (``docs/diagnose.md``).
    """
    tol2 = tolerance**2
    while len(chosen) > 1:
        res_all = joint_fit(problem, chosen)
        g_all = problem.gap2(problem.r - np.where(problem.valid, fitted(chosen), 0.0))
        change = {c.effect.id: contribution(problem, c) for c in chosen}
        failing = []
        for c in chosen:
            others = [x for x in chosen if x is not c]
            res_wo = joint_fit(problem, others)
            g_wo = problem.gap2(problem.r - np.where(problem.valid, fitted(others), 0.0))
            dbic = fit.delta_bic(res_all.rss_free, res_wo.rss, c.effect.n_parameters, problem.n_eff)
            closes = g_wo > tol2 >= g_all
            why = []
            if dbic > -bic_threshold:
                why.append(f"lowers the BIC by only {-dbic:.1f} < {bic_threshold:g}")
            if change[c.effect.id] < tolerance and not closes:
                why.append(f"changes (L-R)/R by only {change[c.effect.id]:.3f} % < tolerance {tolerance:g} % "
                           f"and does not take the gap below the tolerance")
            if why:
                failing.append((dbic, c, why))
        joint_fit(problem, chosen)
        if not failing:
            break
        _, weak, why = max(failing, key=lambda f: f[0])
        steps.append(f"{weak.effect.id} dropped: given the others it {' and '.join(why)}")
        chosen = [c for c in chosen if c is not weak]
        joint_fit(problem, chosen)
    return chosen, steps


def minor_effects(problem: Problem, fits: Sequence[CandidateFit], chosen: Sequence[CandidateFit],
                  bic_threshold: float, tolerance: float, gap: float) -> list[CandidateFit]:
    """Candidates that are strong but not material: the ``minor`` list (``docs/diagnose.md``).

    With no effect named (the gap before within the tolerance), every candidate that alone lowers
    the BIC by at least ``bic_threshold`` and is not out of its physical range, with its alone fit
    (estimate, block-bootstrap interval).  With effects named, every other candidate that,
    fitted together with them, lowers the BIC by as much and stays in its range, with that joint
    fit's estimate and block-bootstrap interval; the named effects' values are left as they were.
    Each gets ``minor`` (why it is not named), ``minor_score`` (its ΔBIC: alone, or given the
    named effects) and ``contribution`` (its change of (L − R)/R at that estimate).
    """
    out: list[CandidateFit] = []
    if not chosen:
        for c in fits:
            if c.delta_bic <= -bic_threshold and not range_verdict(problem, [c])[0]:
                c.minor = (f"the gap before ({gap:.3f} %) is within the tolerance ({tolerance:g} %), so no "
                           f"effect is material")
                c.minor_score = c.delta_bic
                out.append(c)
        return out
    res = joint_fit(problem, list(chosen))
    g0 = problem.gap2(problem.r)
    g_cur = problem.gap2(problem.r - np.where(problem.valid, fitted(chosen), 0.0))
    kept = _snapshot(chosen)
    intervals = {c.effect.id: dict(c.interval) for c in chosen}
    for c in fits:
        if c in chosen:
            continue
        t = _try(problem, list(chosen), c, res.rss, g0, g_cur, bic_threshold, tolerance, 0.0)
        if t is None or t.dbic > -bic_threshold or t.beyond:
            continue
        _restore([c], {c.effect.id: t.estimates[c.effect.id]})
        _restore(chosen, {k: v for k, v in t.estimates.items() if k != c.effect.id})
        bootstrap(problem, list(chosen) + [c])
        c.contribution = contribution(problem, c)
        c.minor = "; ".join(t.reasons) or "not named"
        c.minor_score = t.dbic
        out.append(c)
        _restore(chosen, kept)
        for x in chosen:
            x.interval = dict(intervals[x.effect.id])
    return out


def refine(problem: Problem, chosen: list[CandidateFit]) -> tuple[Any, dict[str, np.ndarray]]:
    """Re-simulate at the estimates and correct them; return (corrected model, its records).

    One effect with one parameter: the response is re-measured on the secant [θ₀, θ̂] and the
    parameter refitted (exact for a response linear in θ, much better than the probe otherwise).
    Several: one Gauss–Newton step with the probe responses on the residual left at the
    estimates.  Either way the model is simulated once more if the estimate moved by more than
    half a standard error.  Uncertainties then come from the block bootstrap of the last fit.
    """
    label = " + ".join(c.effect.id for c in chosen)
    model1, rec1 = problem.records_with(chosen, f"{label} at estimate")
    before = [dict(c.estimate) for c in chosen]
    if len(chosen) == 1 and chosen[0].effect.n_parameters == 1:
        c = chosen[0]
        name = c.effect.parameters[0].name
        h = c.estimate[name] - c.nominal[name]
        if abs(h) > 1e-12:
            c.response = [problem.smooth(c.effect, (records_difference(rec1) - problem.d0) / h)]
            res = joint_fit(problem, [c])
            c.delta_bic = fit.delta_bic(res.rss_free, res.rss0, 1, problem.n_eff)
            c.explained = 1.0 - res.rss_free / res.rss0 if res.rss0 > 0 else 0.0
        bootstrap(problem, [c])
    else:
        r1 = np.where(problem.valid, problem.d_measured - records_difference(rec1), np.nan)
        res = fit.fit_linear(r1, columns(chosen)[0], problem.weights)
        k = 0
        for c in chosen:
            for p in c.effect.linear_parameters:
                lo, hi = p.bounds
                step = float(res.delta[k])
                c.free[p.name] = c.estimate[p.name] + step  # the linear model's unconstrained optimum
                c.estimate[p.name] = float(np.clip(c.estimate[p.name] + step, lo, hi))
                k += 1
        bootstrap(problem, chosen, r=np.where(problem.valid, problem.r, np.nan))
    moved = any(abs(c.estimate[p.name] - b[p.name]) > 0.5 * c.stderr[p.name]
                for c, b in zip(chosen, before, strict=True) for p in c.effect.linear_parameters)
    for c in chosen:
        c.contribution = contribution(problem, c)
        log.info(f"refined {c.effect.id}: " + ", ".join(
            f"{k} = {v:.4g} ± {c.stderr[k]:.2g} (95 % {c.interval[k][0]:.4g} to {c.interval[k][1]:.4g})"
            for k, v in c.estimate.items()))
    if moved:  # the estimate moved: simulate where it landed
        model1, rec1 = problem.records_with(chosen, f"{label} at refined estimate")
    else:  # the records stay those simulated half a standard error away; the model takes the estimate
        for c in chosen:
            model1 = c.effect.apply(model1, c.estimate)
    return model1, rec1


def adequate(problem: Problem, chosen: list[CandidateFit], steps: list[str], gap: float,
              tolerance: float) -> tuple[list[CandidateFit], list[str]]:
    """Keep the named effects only if together they explain the disagreement.

    A correct explanation removes most of the systematic residual: if the gap left by the named
    effects (linearised) is above the tolerance *and* above half the gap before, they only
    absorb part of something the catalogue does not hold (a lidar error in one direction sector
    fitted as a constant or a TI-proportional bias), and the answer is ``unexplained``.
    """
    if not chosen:
        return chosen, steps
    left = np.sqrt(problem.gap2(problem.r - np.where(problem.valid, fitted(chosen), 0.0)))
    if left > tolerance and left > 0.5 * gap:
        ids = ", ".join(c.effect.id for c in chosen)
        return [], steps + [f"the effects that qualified ({ids}) leave a gap of {left:.3f} % of {gap:.3f} % "
                            f"(more than half, above the tolerance): they do not explain the disagreement"]
    return chosen, steps


def conclude(chosen: Sequence[CandidateFit], steps: list[str], significant: bool, gap: float,
             tolerance: float, minor: Sequence[CandidateFit] = (),
             p_min: float = float("nan")) -> tuple[str, str]:
    """Return the answer (first effect, ``none`` or ``unexplained``) and its one-paragraph note.

    The note ends with ``named: <ids>`` (or ``named: none``): the same effects as the answer's
    ``effects``, in the same order; the strong candidates that are not named are listed as
    ``minor: <id> (...)`` with the reason (``tests/test_diagnose.py`` parses both).
    """
    p_text = f"min Holm p = {p_min:.3g}" if np.isfinite(p_min) else "Holm-corrected"
    lines = [f"minor: {c.effect.id} (ΔBIC {c.minor_score:.1f}, changes (L-R)/R by {c.contribution:.3f} % "
             f"rms: {c.minor})" for c in minor]
    if not significant:
        return "none", ("no significant disagreement between measurement and nominal model in any height or "
                        f"environmental bin ({p_text}); named: none")
    if chosen:
        named = ", ".join(c.effect.id for c in chosen)
        return chosen[0].effect.id, "; ".join([*steps, *lines, f"named: {named}"])
    if not gap > tolerance:
        return "none", "; ".join([f"the disagreement is significant ({p_text}) but the gap {gap:.3f} % is "
                                  f"within the tolerance {tolerance:g} %: no effect is material", *lines,
                                  "named: none"])
    return "unexplained", "; ".join(
        [f"the disagreement is significant ({p_text}) and material (gap {gap:.3f} % > tolerance "
         f"{tolerance:g} %) but no catalogue effect explains it", *steps[-1:],
         "drivers lists where the residual lies", "named: none"])
