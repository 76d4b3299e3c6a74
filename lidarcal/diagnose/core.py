"""The diagnose workflow: find the gap, name the effect(s), add them, re-run (``docs/diagnose.md``).

:func:`diagnose` takes a ``field_campaign`` (measured lidar/reference pair + conditions) and

1. builds the nominal model (the file's ``lidar_*`` attributes, or a bench cube / RWF) and
   simulates the campaign's own conditions with it;
2. forms the per-period residual r = (L−R)/R measured − (L−R)/R simulated, bins it per height
   by every environmental variable and tests whether it is zero (:mod:`.stats`);
3. for every catalogue effect (:mod:`.effects`) measures the response to each parameter with the
   SAME seeds (common random numbers; grid parameters scanned), fits it alone by weighted least
   squares and scores it by ΔBIC against ``none`` (:mod:`.fit`);
4. names effects by forward selection while each addition is strong (ΔBIC) and material (it
   changes (L−R)/R by more than the practical tolerance and explains a share of the systematic
   residual) — or answers ``none`` (nothing significant, or below the tolerance) or
   ``unexplained`` (material, but no catalogue effect qualifies; ``drivers`` then says where the
   residual lies) — refines the named effects by one re-simulation and gives their parameters
   day-block bootstrap intervals, and
5. re-simulates with the fitted effects to report the gap (:data:`.stats.GAP_METRIC`) before and after.

The result is a ``diagnosis`` artefact (:mod:`.dataset`) whose ``lidarcal_lidar_model``
attribute is the corrected model; :func:`summary` gives the ``--json`` object.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.campaign import DEFAULT_BASE_SEED, simulate_campaign
from lidarcal.conditions.variables import CONDITIONS
from lidarcal.diagnose import fit, stats
from lidarcal.diagnose.effects import CONDITION_VARIABLES, EFFECTS, Effect, get_effect
from lidarcal.diagnose.inputs import check_field, min_periods
from lidarcal.errors import InputError

__all__ = ["diagnose", "check_field", "DiagnosisResult", "CandidateFit", "DEFAULT_SEED", "RECORD_NAMES",
           "min_periods", "DEFAULT_TOLERANCE", "DEFAULT_MIN_SHARE", "DEFAULT_BOOTSTRAP",
           "DEFAULT_MODEL_UNCERTAINTY"]

log = logging.getLogger("lidarcal.diagnose")

#: Base seed of the diagnosis simulations (the hidden-effect generator uses different ones).
DEFAULT_SEED = DEFAULT_BASE_SEED
#: Simulated record variables diagnose needs.
RECORD_NAMES = ("lidar_wind_speed", "reference_wind_speed", "lidar_wind_speed_scalar",
                "lidar_wind_speed_vector")
#: Practical tolerance (%): a tenth of the ~1 % standard uncertainty of a lidar calibration
#: (docs/diagnose.md); smaller changes of (L−R)/R are not worth naming.
DEFAULT_TOLERANCE = 0.1
#: Share of the systematic residual (the gap metric's square) an added effect must explain.  0 by
#: default: the share is reported, but it does not gate, because it is not additive when effects
#: overlap with opposite signs (removing a mast shadow that offsets an over-speeding cup's
#: negative bias widens the gap the cup leaves in every other bin).
DEFAULT_MIN_SHARE = 0.0
#: Block-bootstrap resamples of the parameter fits.
DEFAULT_BOOTSTRAP = 400
#: Model-form standard uncertainty of a fitted parameter, as a share of its fitted change θ − θ₀.
DEFAULT_MODEL_UNCERTAINTY = 0.075


@dataclass
class CandidateFit:
    """One catalogue effect fitted to the residual."""

    effect: Effect
    nominal: dict[str, float]
    estimate: dict[str, float]
    stderr: dict[str, float]
    delta_bic: float
    explained: float            # 1 − RSS/RSS_none
    probe: dict[str, float]
    refined: bool = False
    clipped: bool = False
    response: list[np.ndarray] = field(default_factory=list, repr=False)  # ∂d/∂θ per parameter
    interval: dict[str, tuple[float, float]] = field(default_factory=dict)  # 95 % bootstrap interval
    contribution: float = float("nan")  # rms change of (L−R)/R the effect makes, %
    share: float = float("nan")         # share of the systematic residual it explains
    tied: list[str] = field(default_factory=list)  # catalogue ids it cannot be told from
    free: dict[str, float] = field(default_factory=dict)     # unconstrained fit of each linear parameter
    free_se: dict[str, float] = field(default_factory=dict)  # its (sandwich) standard error

    @property
    def bounds(self) -> list[tuple[float, float]]:
        """Limits of θ − θ₀ for every linear parameter (the catalogue bounds minus the nominal value)."""
        return [(p.bounds[0] - self.nominal[p.name], p.bounds[1] - self.nominal[p.name])
                for p in self.effect.linear_parameters]


@dataclass
class DiagnosisResult:
    """Everything :func:`diagnose` found (turned into a Dataset by :mod:`.dataset`)."""

    heights: np.ndarray
    times: np.ndarray
    conditions: dict[str, np.ndarray]
    valid: np.ndarray
    d_measured: np.ndarray
    d_before: np.ndarray
    d_after: np.ndarray
    binned_before: stats.BinnedResiduals
    binned_after: stats.BinnedResiduals
    tests: dict[str, np.ndarray]
    significant: bool
    candidates: list[CandidateFit]
    chosen: CandidateFit | None
    tied: list[str]
    note: str
    gap_before: tuple[float, np.ndarray, float]
    gap_after: tuple[float, np.ndarray, float]
    design_effect: float
    nominal_model: Any
    corrected_model: Any
    settings: dict[str, Any] = field(default_factory=dict)
    source: str = "<field campaign>"
    field_dataset: xr.Dataset | None = None
    selected: list[CandidateFit] = field(default_factory=list)  # named effects, most important first
    answer: str = "none"            # effects[0] id, "none" or "unexplained"
    drivers: list[dict] = field(default_factory=list)  # where the residual lies (stats.locate)
    tolerance: float = 0.1          # %, the practical tolerance

    @property
    def effect_id(self) -> str:
        """Catalogue id of the answer (``none`` or ``unexplained`` when no effect is named)."""
        return self.chosen.effect.id if self.chosen is not None else self.answer


# -- input ------------------------------------------------------------------------------------

class _Simulator:
    """Simulate the campaign's conditions with common random numbers; count and log the runs."""

    def __init__(self, conditions: xr.Dataset, base_seed: int, options: Mapping[str, Any],
                 progress: Callable[[str], None]):
        self.conditions = conditions
        self.base_seed = int(base_seed)
        self.options = dict(options)
        self.progress = progress
        self.runs = 0

    def __call__(self, model, label: str) -> dict[str, np.ndarray]:
        n_t, n_h = self.conditions.sizes['time'], self.conditions.sizes['height']
        self.progress(f"simulating {n_t} periods x {n_h} "
                      f"heights: {label}")
        sim = simulate_campaign(self.conditions, model, base_seed=self.base_seed, **self.options)
        self.runs += 1
        return {n: np.asarray(sim[n].transpose("time", "height").values, dtype=float) for n in RECORD_NAMES}


def _records_at(effect: Effect, params: Mapping[str, float], model0, base: dict[str, np.ndarray],
                conditions: dict[str, np.ndarray], simulate: _Simulator, label: str) -> dict[str, np.ndarray]:
    """Return the records of the model with ``effect`` at ``params``: exact shortcut or re-simulation."""
    if effect.shortcut is not None:
        return {**base, **effect.shortcut(base, conditions, effect.nominal(model0), params)}
    return simulate(effect.apply(model0, params), label)


def _d(records: Mapping[str, np.ndarray]) -> np.ndarray:
    return stats.relative_difference(records["lidar_wind_speed"], records["reference_wind_speed"])


# -- fitting ----------------------------------------------------------------------------------

@dataclass
class _Problem:
    """The residual to explain and what every candidate fit shares (common random numbers)."""

    model: Any
    simulate: _Simulator
    base: dict[str, np.ndarray]
    conditions: dict[str, np.ndarray]
    d_measured: np.ndarray
    d0: np.ndarray
    valid: np.ndarray
    r: np.ndarray
    clusters: np.ndarray
    weights: np.ndarray | None = None
    n_eff: float = 0.0
    design_effect: float = 1.0
    groups: stats.BinGroups | None = None
    clusters_label: str = ""
    n_boot: int = DEFAULT_BOOTSTRAP
    seed: int = 0
    model_uncertainty: float = 0.0

    def records_at(self, effect: Effect, params: Mapping[str, float], label: str) -> dict[str, np.ndarray]:
        """Return the records of the model with ``effect`` at ``params`` (shortcut or re-simulation)."""
        return _records_at(effect, params, self.model, self.base, self.conditions, self.simulate, label)

    def records_with(self, cands: Sequence[CandidateFit], label: str) -> tuple[Any, dict[str, np.ndarray]]:
        """Return (model, records) with every effect of ``cands`` at its estimate.

        Effects without a shortcut are applied to the model and simulated together (one run);
        the shortcuts (which act after the turbulence is sampled) are then applied in turn.
        """
        model, records = self.model, self.base
        sims = [c for c in cands if c.effect.shortcut is None]
        for c in sims:
            model = c.effect.apply(model, c.estimate)
        if sims:
            records = self.simulate(model, label)
        for c in cands:
            if c.effect.shortcut is not None:
                nominal = c.effect.nominal(self.model)
                records = {**records, **c.effect.shortcut(records, self.conditions, nominal, c.estimate)}
                model = c.effect.apply(model, c.estimate)
        return model, records

    def smooth(self, effect: Effect, dy: np.ndarray) -> np.ndarray:
        """E[dy | the effect's drivers] per height, in the fit's weighting (:func:`fit.smooth_response`)."""
        return fit.smooth_response(dy, self.conditions, effect.drivers, self.valid, weights=self.weights)

    def form_share(self, *effects: Effect) -> float:
        """Model-form share of the fitted change: the diagnosis' own, or an effect's larger one."""
        return max([self.model_uncertainty] + [e.model_form for e in effects if e.model_form is not None])

    def gap2(self, r: np.ndarray) -> float:
        """Square of the gap metric (%²) of a residual."""
        g = stats.joint_gap(r, self.groups)[0]
        return g * g if np.isfinite(g) else 0.0


def _responses(problem: _Problem, eff: Effect, at: Mapping[str, float] | None = None) -> CandidateFit:
    """Measure ∂d/∂θ of every linear parameter of ``eff`` by one probe each (common random numbers).

    ``at`` fixes the grid parameters (a :meth:`Effect.grid_points` entry).  The response of an
    effect with grid parameters is exact (a shortcut on the same records, e.g. the hard-edged
    mast-shadow sector) and is used as it is; smoothing it on its drivers would blur the edge.
    """
    at = dict(at or {})
    theta0 = eff.nominal(problem.model)
    probe = eff.probe(problem.model, at=at) if at else eff.probe(problem.model)
    d_at = problem.d0 if not at else _d(problem.records_at(eff, {**theta0, **at}, f"{eff.id} at {at}"))
    Js = []
    for p in eff.linear_parameters:
        params = {**theta0, **at, p.name: probe[p.name]}
        d_probe = _d(problem.records_at(eff, params, f"{eff.id} probe {p.name}={probe[p.name]:g}"))
        dy = (d_probe - d_at) / (probe[p.name] - theta0[p.name])
        Js.append(np.where(problem.valid, dy, np.nan) if eff.grid_parameters else problem.smooth(eff, dy))
    return CandidateFit(eff, theta0, {**theta0, **at}, {p.name: np.nan for p in eff.parameters}, np.nan, 0.0,
                        probe, response=Js)


def _grid_scan(problem: _Problem, eff: Effect, others: Sequence[CandidateFit]) -> CandidateFit:
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
    cands = [_responses(problem, eff, at=pt) for pt in points]
    fixed = _fitted(others) if others else 0.0
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


def _columns(cands: Sequence[CandidateFit]) -> tuple[list[np.ndarray], list[tuple[float, float]]]:
    Js, bounds = [], []
    for c in cands:
        Js += c.response
        bounds += c.bounds
    return Js, bounds


def _joint_fit(problem: _Problem, cands: Sequence[CandidateFit],
               r: np.ndarray | None = None) -> fit.FitResult:
    """Fit ``r`` (default the residual) on the responses of ``cands`` together; set their estimates."""
    Js, bounds = _columns(cands)
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


def _fitted(cands: Sequence[CandidateFit], free: bool = False) -> np.ndarray:
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


def _range_verdict(problem: _Problem, cands: Sequence[CandidateFit],
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


def _contribution(problem: _Problem, cand: CandidateFit) -> float:
    """Rms change (%) of (L − R)/R over the usable periods that ``cand`` at its estimate makes."""
    x = _fitted([cand])
    x = np.asarray(x)[problem.valid] if np.ndim(x) else np.zeros(1)
    x = x[np.isfinite(x)]
    return 100.0 * float(np.sqrt(np.mean(x**2))) if x.size else 0.0


def _bootstrap(problem: _Problem, cands: Sequence[CandidateFit], r: np.ndarray | None = None) -> None:
    """Set the standard uncertainties and 95 % intervals of the linear parameters of ``cands``.

    The block bootstrap (days as blocks) gives the statistical part; a model-form part,
    ``problem.model_uncertainty`` × |θ̂ − θ₀| (the catalogue's responses are models of the physics:
    on an independent simulator the fitted parameters of strong effects move by 5–15 % of their
    size; an effect may declare a larger share, ``Effect.model_form``), is added in quadrature to
    the standard error and to each side of the interval.
    """
    Js, _ = _columns(cands)
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


def _fit_candidates(problem: _Problem, effects: Sequence[Effect]) -> list[CandidateFit]:
    """Fit every effect alone from one probe per parameter; score it against ``none``; sort by ΔBIC."""
    problem.weights = fit.noise_weights(problem.d0, problem.conditions, problem.valid)
    problem.design_effect = fit.design_effect(np.where(problem.valid, problem.r, 0.0), problem.weights)
    problem.n_eff = float(problem.valid.sum()) / problem.design_effect
    fits: list[CandidateFit] = []
    for eff in effects:
        c = _grid_scan(problem, eff, []) if eff.grid_parameters else _responses(problem, eff)
        res = _joint_fit(problem, [c])
        # the score is what the data ask for (the unconstrained fit); whether that lies in the
        # physical range is judged apart (_range_verdict) and said in the note
        c.delta_bic = fit.delta_bic(res.rss_free, res.rss0, eff.n_parameters, problem.n_eff)
        c.explained = 1.0 - res.rss_free / res.rss0 if res.rss0 > 0 else 0.0
        c.contribution = _contribution(problem, c)
        _bootstrap(problem, [c])
        fits.append(c)
        log.info(f"  {eff.id}: "
                 + ", ".join(f"{k} = {v:.4g} ± {c.stderr[k]:.2g}" for k, v in c.estimate.items())
                 + f", ΔBIC = {c.delta_bic:.1f}, explains {100 * c.explained:.1f} %, "
                 f"changes (L-R)/R by {c.contribution:.3f} % rms")
    fits.sort(key=lambda c: c.delta_bic)
    return fits


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


def _range_notes(problem: _Problem, chosen: Sequence[CandidateFit]) -> list[str]:
    """Note lines for named parameters at a bound of their physical range (or, after refining, beyond it).

    Judged with the final (bootstrap + model-form) uncertainties; a parameter the data push beyond
    its range by more than that is held at the bound, and the note says so.
    """
    if not chosen:
        return []
    beyond, at_bound = _range_verdict(problem, chosen, {c.effect.id: c.stderr for c in chosen})
    held = "held at the bound, so the named value is not what the data ask for"
    return at_bound + [f"{line}; {held}" for line in beyond]


def _select(problem: _Problem, fits: list[CandidateFit], bic_threshold: float, tie_threshold: float,
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
    tol2 = tolerance**2
    while True:
        trials: list[_Trial] = []
        for c in fits:
            if c in chosen:
                continue
            if c.effect.grid_parameters and chosen:  # re-scan the grid on what is left
                scan = _grid_scan(problem, c.effect, chosen)
                c.estimate, c.response, c.interval = scan.estimate, scan.response, scan.interval
                c.stderr = scan.stderr
            trial = chosen + [c]
            saved = _snapshot(trial)
            clipped = c.clipped
            res = _joint_fit(problem, trial)
            if not np.all(np.isfinite(res.stderr)):  # collinear with what is chosen: nothing to add
                _restore(trial, saved)
                c.clipped = clipped
                continue
            dbic = fit.delta_bic(res.rss_free, rss_cur, c.effect.n_parameters, problem.n_eff)
            g2 = problem.gap2(problem.r - np.where(problem.valid, _fitted(trial), 0.0))
            g2_free = problem.gap2(problem.r - np.where(problem.valid, _fitted(trial, free=True), 0.0))
            share = (g_cur - g2) / g0 if g0 > 0 else 0.0
            beyond, _ = _range_verdict(problem, trial)
            t = _Trial(c, dbic, res, _contribution(problem, c), share, g2, g2_free, _snapshot(trial), beyond)
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
            trials.append(t)
            _restore(trial, saved)
            c.clipped = clipped
        if not trials:
            break
        trials.sort(key=lambda t: t.dbic)
        ok = [t for t in trials if not t.reasons]
        if not ok:
            steps.append(f"next best {trials[0].id} not added ({'; '.join(trials[0].reasons)})")
            break
        pick = ok[0]

        def indistinct(a: _Trial, b: _Trial, rss_cur: float = rss_cur) -> bool:
            # within tie_threshold BIC units, or b fitting worse than a by less than an error of b's
            # own response model would cost (the catalogue's responses are models: a response wrong by
            # model_uncertainty of itself adds about that share squared of the explained sum of squares;
            # at 95 %, (1.96 u)² of it) — e.g. a hybrid weight and a TI-proportional cup over-speeding.
            # b's share, not a's: an imprecise response of the pick does not make every other effect
            # plausible, an imprecise response of the runner-up can hide that it is the right one
            u = problem.form_share(b.cand.effect)
            slack = (1.96 * u) ** 2 * max(rss_cur - a.res.rss_free, 0.0)
            return b.dbic - a.dbic < tie_threshold or b.res.rss_free - a.res.rss_free <= slack

        # the better-scoring candidates that may not be added: say why; the best-scoring one is tied
        # with the pick unless the pick explains the gap comparably
        forced = []
        for t in trials[:trials.index(pick)]:
            extra = float(np.sqrt(max(pick.g2 - t.g2_free, 0.0)))
            line = (f"{t.id} scores better (ΔBIC {t.dbic:.1f} against {pick.dbic:.1f} for {pick.id}) but is "
                    f"not added ({'; '.join(t.reasons)})")
            if t is not trials[0]:
                steps.append(line)
            elif indistinct(t, pick) or extra < tolerance:
                steps.append(f"{line}; {pick.id} explains the gap comparably (it leaves {extra:.3f} % more, "
                             f"in quadrature, < tolerance {tolerance:g} %)")
            else:
                forced.append(t.id)
                steps.append(f"{line}; {pick.id} explains the gap less well (it leaves {extra:.3f} % more, "
                             f"in quadrature, >= tolerance {tolerance:g} %): the two are tied")
        best = pick.cand
        _restore(chosen + [best], pick.estimates)
        best.clipped = pick.res.clipped
        best.tied = forced + [t.id for t in ok[1:] if indistinct(pick, t)]
        best.contribution, best.share = pick.contribution, pick.share
        chosen.append(best)
        steps.append(f"{best.effect.id}: ΔBIC {pick.dbic:.1f}, changes (L-R)/R by {pick.contribution:.3f} % "
                     f"rms, explains {100 * pick.share:.0f} % of the systematic residual"
                     + (f" and takes the gap from {np.sqrt(g_cur):.3f} % to {np.sqrt(pick.g2):.3f} %, below "
                        f"the tolerance" if pick.contribution < tolerance else "")
                     + (f"; cannot be told apart from {', '.join(best.tied)}" if best.tied else ""))
        rss_cur, g_cur = pick.res.rss, pick.g2
    if chosen:
        _joint_fit(problem, chosen)  # the trials after the last step moved the estimates
    return _prune(problem, chosen, steps, tolerance)


def _prune(problem: _Problem, chosen: list[CandidateFit], steps: list[str],
           tolerance: float) -> tuple[list[CandidateFit], list[str]]:
    """Drop named effects that explain no material part of the systematic residual given the others.

    With several effects named, each must be material given the others: remove at least the
    tolerance (in quadrature) from the gap the others leave, ``sqrt(gap(others)² − gap(all)²) ≥
    tolerance``, **or** take the gap from above the tolerance (the others alone) to at most the
    tolerance (all together) — by the diagnosis's own definition a gap above the tolerance is
    material, so the effect that closes it is too.  An effect that is strong by ΔBIC and changes
    (L − R)/R by more than the tolerance but leaves every bin mean as it was only fits the
    model-form mismatch between the catalogue's responses and the data (e.g. a hybrid weight
    added to a beam-angle offset).  The weakest effect that is not material is dropped and the
    test repeated.
    """
    tol2 = tolerance**2
    kept_lines: dict[str, str] = {}
    while len(chosen) > 1:
        kept_lines = {}
        g_all = problem.gap2(problem.r - np.where(problem.valid, _fitted(chosen), 0.0))
        unique, material = [], []
        for c in chosen:
            others = [x for x in chosen if x is not c]
            _joint_fit(problem, others)
            g_wo = problem.gap2(problem.r - np.where(problem.valid, _fitted(others), 0.0))
            u = float(np.sqrt(max(g_wo - g_all, 0.0)))
            closes = g_wo > tol2 >= g_all
            unique.append(u)
            material.append(u >= tolerance or closes)
            if closes and u < tolerance:
                kept_lines[c.effect.id] = (
                    f"{c.effect.id} kept: given the others it removes only {u:.3f} % of the gap (in "
                    f"quadrature), but without it the gap is {np.sqrt(g_wo):.3f} % > tolerance "
                    f"{tolerance:g} % and with it {np.sqrt(g_all):.3f} % <= tolerance: it closes a "
                    f"material gap")
        _joint_fit(problem, chosen)
        weak = [k for k in range(len(chosen)) if not material[k]]
        if not weak:
            break
        k = min(weak, key=lambda j: unique[j])
        steps.append(f"{chosen[k].effect.id} dropped: given the others it removes only {unique[k]:.3f} % "
                     f"of the gap (in quadrature) < tolerance {tolerance:g} % and does not take the gap "
                     f"below the tolerance")
        chosen = chosen[:k] + chosen[k + 1:]
        _joint_fit(problem, chosen)
    if len(chosen) > 1:
        steps += list(kept_lines.values())
    return chosen, steps


def _refine(problem: _Problem, chosen: list[CandidateFit]) -> tuple[Any, dict[str, np.ndarray]]:
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
            c.response = [problem.smooth(c.effect, (_d(rec1) - problem.d0) / h)]
            res = _joint_fit(problem, [c])
            c.delta_bic = fit.delta_bic(res.rss_free, res.rss0, 1, problem.n_eff)
            c.explained = 1.0 - res.rss_free / res.rss0 if res.rss0 > 0 else 0.0
            c.refined = True
        _bootstrap(problem, [c])
    else:
        r1 = np.where(problem.valid, problem.d_measured - _d(rec1), np.nan)
        res = fit.fit_linear(r1, _columns(chosen)[0], problem.weights)
        k = 0
        for c in chosen:
            for p in c.effect.linear_parameters:
                lo, hi = p.bounds
                step = float(res.delta[k])
                c.free[p.name] = c.estimate[p.name] + step  # the linear model's unconstrained optimum
                c.estimate[p.name] = float(np.clip(c.estimate[p.name] + step, lo, hi))
                k += 1
            c.refined = True
        _bootstrap(problem, chosen, r=np.where(problem.valid, problem.r, np.nan))
    moved = any(abs(c.estimate[p.name] - b[p.name]) > 0.5 * c.stderr[p.name]
                for c, b in zip(chosen, before, strict=True) for p in c.effect.linear_parameters)
    for c in chosen:
        c.contribution = _contribution(problem, c)
        log.info(f"refined {c.effect.id}: " + ", ".join(
            f"{k} = {v:.4g} ± {c.stderr[k]:.2g} (95 % {c.interval[k][0]:.4g} to {c.interval[k][1]:.4g})"
            for k, v in c.estimate.items()))
    if moved:  # the estimate moved: simulate where it landed
        model1, rec1 = problem.records_with(chosen, f"{label} at refined estimate")
    else:  # the records stay those simulated half a standard error away; the model takes the estimate
        for c in chosen:
            model1 = c.effect.apply(model1, c.estimate)
    return model1, rec1


def diagnose(
    field: str | os.PathLike | xr.Dataset,
    *,
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
    model: Any = None,
    candidates: Sequence[str] | None = None,
    base_seed: int = DEFAULT_SEED,
    n_bins: int = 6,
    min_bin_count: int = 10,
    alpha: float = 0.01,
    bic_threshold: float = 6.0,
    tie_threshold: float = 2.0,
    tolerance: float = DEFAULT_TOLERANCE,
    min_share: float = DEFAULT_MIN_SHARE,
    n_bootstrap: int = DEFAULT_BOOTSTRAP,
    model_uncertainty: float = DEFAULT_MODEL_UNCERTAINTY,
    min_wind_speed: float = 3.0,
    simulate_options: Mapping[str, Any] | None = None,
    progress: bool = False,
) -> DiagnosisResult:
    """Diagnose the discrepancy between a field campaign and the nominal model.

    Parameters
    ----------
    field : path or xarray.Dataset
        A ``field_campaign`` (``docs/contracts.md``).
    cube, rwf : xarray.Dataset, optional
        Bench cube / RWF artefacts configuring the nominal model (else the file's attributes).
    model : LidarModel, optional
        Use this nominal model instead (overrides ``cube``/``rwf``/attributes).
    candidates : sequence of str, optional
        Catalogue ids to try (default: all but ``none``).
    base_seed : int
        Base seed of every simulation (common random numbers across candidates) and of the bootstrap.
    n_bins, min_bin_count : int
        Quantile bins per environmental variable, and the minimum periods a bin needs to be
        tested and to count in the gap.  A height needs ``n_bins × min_bin_count`` usable periods.
    alpha : float
        Family-wise false-alarm rate of the disagreement tests (Holm over heights × variables).
    bic_threshold : float
        An effect is added only if it lowers the BIC by more than this (6 = "strong evidence",
        Kass & Raftery 1995).
    tie_threshold : float
        Candidates within this ΔBIC of the one added cannot be told apart (named in ``tied``).
    tolerance : float
        Practical tolerance, % of wind speed: an effect must change (L − R)/R by at least this
        (rms), and a residual gap below it is ``none`` (``docs/diagnose.md``).
    min_share : float
        Share of the systematic residual (gap metric squared) an added effect must explain.
    n_bootstrap : int
        Block-bootstrap resamples (days) for the uncertainties and 95 % intervals.
    model_uncertainty : float
        Model-form standard uncertainty of a fitted parameter as a share of its fitted change
        θ − θ₀, added in quadrature to the bootstrap (``docs/diagnose.md``).
    min_wind_speed : float
        Periods with a reference below this (m s-1) are not used.
    simulate_options : mapping, optional
        Extra keyword arguments of :func:`lidarcal.campaign.simulate_campaign`
        (``chunk``, ``scheduler``, ``workdir`` ...).
    progress : bool
        Show a progress bar (tqdm, stderr) during each simulation.  Each step is also
        logged at INFO level on the ``lidarcal.diagnose`` logger.
    """
    # 0. inputs: the campaign, the nominal model, the candidates
    ds, usable, source, model = check_field(field, cube=cube, rwf=rwf, model=model, n_bins=n_bins,
                                            min_bin_count=min_bin_count, min_wind_speed=min_wind_speed)
    ids = [c for c in (candidates if candidates is not None else EFFECTS) if c != "none"]
    effects = [get_effect(c) for c in ids]
    # 1. simulate the campaign's own conditions with the nominal model
    simulate = _Simulator(_conditions_input(ds, source), base_seed,
                          {"progress": progress, **(simulate_options or {})}, log.info)
    problem = _residual(ds, usable, model, simulate)
    problem.n_boot, problem.seed = int(n_bootstrap), int(base_seed)
    problem.model_uncertainty = float(model_uncertainty)
    problem.groups = stats.bin_groups(problem.conditions, problem.valid, n_bins,
                                      [e.drivers[:2] for e in effects if len(e.drivers) >= 2])
    # 2. where do they disagree?
    edges, drivers, binned0, tests, significant = _disagreement(problem, n_bins, min_bin_count, alpha)
    gap0 = stats.joint_gap(problem.r, problem.groups, min_bin_count)
    log.info(f"gap before: {gap0[0]:.3f} % (noise floor {gap0[2]:.3f} %, tolerance {tolerance:g} %)")
    # 3-4. fit every candidate, add effects while strong and material, refine them
    fits = _fit_candidates(problem, effects)
    chosen, steps = _select(problem, fits, bic_threshold, tie_threshold, tolerance, min_share) \
        if significant else ([], [])
    chosen, steps = _adequate(problem, chosen, steps, gap0[0], tolerance)
    corrected, after = (model, problem.base) if not chosen else _refine(problem, chosen)
    steps = steps + _range_notes(problem, chosen)
    fits.sort(key=lambda c: c.delta_bic)  # the refined score may reorder the table
    chosen.sort(key=lambda c: -c.contribution)  # importance: the size of the change each makes
    answer, note = _answer(chosen, steps, significant, gap0[0], tolerance)
    # 5. the gap after adding the fitted effect(s); where the residual lies
    d_after = _d(after)
    r1 = np.where(problem.valid, problem.d_measured - d_after, np.nan)
    binned1 = stats.bin_residuals(r1, drivers, n_bins, edges)
    gap1 = stats.joint_gap(r1, problem.groups, min_bin_count)
    where = [] if answer == "none" else stats.locate(problem.r, problem.groups, problem.conditions, UNITS,
                                                      min_bin_count, alpha=alpha)
    log.info(f"answer: {answer}; gap after: {gap1[0]:.3f} % ({simulate.runs} campaign simulations)")
    settings = {"base_seed": int(base_seed), "n_bins": int(n_bins), "min_bin_count": int(min_bin_count),
                "alpha": float(alpha), "bic_threshold": float(bic_threshold),
                "tie_threshold": float(tie_threshold), "tolerance": float(tolerance),
                "min_share": float(min_share), "n_bootstrap": int(n_bootstrap),
                "model_uncertainty": float(model_uncertainty),
                "bootstrap_blocks": problem.clusters_label, "min_wind_speed": float(min_wind_speed),
                "candidates": ids, "simulations": simulate.runs,
                "simulate_options": {k: v for k, v in (simulate_options or {}).items() if k != "scheduler"}}
    return DiagnosisResult(
        heights=ds.height.values, times=ds.time.values, conditions=problem.conditions, valid=problem.valid,
        d_measured=problem.d_measured, d_before=problem.d0, d_after=d_after, binned_before=binned0,
        binned_after=binned1, tests=tests, significant=significant, candidates=fits,
        chosen=chosen[0] if chosen else None, tied=list(chosen[0].tied) if chosen else [], note=note,
        gap_before=gap0, gap_after=gap1, design_effect=problem.design_effect, nominal_model=model,
        corrected_model=corrected, settings=settings, source=source, field_dataset=ds, selected=chosen,
        answer=answer, drivers=where, tolerance=float(tolerance))


UNITS = {name: v.units for name, v in CONDITIONS.items()}


def _conditions_input(ds: xr.Dataset, source: str) -> xr.Dataset:
    """Return the campaign's six conditions as a plain ``conditions`` input of the simulation."""
    cond_ds = ds[list(CONDITION_VARIABLES)].copy()
    cond_ds.attrs = {"lidarcal_source_file": os.path.basename(source)}
    return cond_ds


def _residual(ds: xr.Dataset, usable: np.ndarray, model, simulate: _Simulator) -> _Problem:
    """Simulate the nominal model; residual r = d_measured − d_simulated where both are usable."""
    conditions = {n: np.asarray(ds[n].transpose("time", "height").values, dtype=float)
                  for n in CONDITION_VARIABLES}
    base = simulate(model, "nominal model")
    d_meas = stats.relative_difference(ds["lidar_wind_speed"].transpose("time", "height").values,
                                       ds["reference_wind_speed"].transpose("time", "height").values)
    d0 = _d(base)
    valid = usable & np.isfinite(d_meas) & np.isfinite(d0)
    r = np.where(valid, d_meas - d0, np.nan)
    clusters, label = fit.day_clusters(ds.time.values)
    problem = _Problem(model, simulate, base, conditions, d_meas, d0, valid, r, clusters)
    problem.clusters_label = label
    return problem


def _disagreement(problem: _Problem, n_bins: int, min_bin_count: int, alpha: float):
    """Bin the residual by every condition (and the gap metric's other bin groups) and test it (Holm).

    Returns the bin edges and drivers per condition, the binned residual, the tests and whether
    the disagreement is significant at ``alpha``.
    """
    valid, conditions = problem.valid, problem.conditions
    edges = {n: stats.bin_edges(conditions[n][valid], n_bins) for n in CONDITION_VARIABLES}
    drivers = {n: np.where(valid, conditions[n], np.nan) for n in CONDITION_VARIABLES}
    binned0 = stats.bin_residuals(problem.r, drivers, n_bins, edges)
    tests = stats.disagreement_tests(binned0, min_bin_count, residual=problem.r)
    # the family also holds the direction sectors and the joint-driver bins of the gap metric (an
    # effect in the product of shear and CNR gradient averages out in every one-variable bin)
    extra = [n for n in problem.groups.names if n not in CONDITION_VARIABLES]
    p_extra = stats.group_p_values(problem.r, problem.groups, min_bin_count, tuple(extra))
    p_all = stats.holm(np.concatenate([tests["p_value"].ravel(), tests["mean_p_value"], p_extra.ravel()]))
    p_min = float(np.nanmin(p_all)) if np.isfinite(p_all).any() else 1.0
    significant = p_min < alpha
    log.info(f"disagreement {'significant' if significant else 'not significant'} (min Holm p = {p_min:.3g})")
    return edges, drivers, binned0, tests, significant


def _adequate(problem: _Problem, chosen: list[CandidateFit], steps: list[str], gap: float,
              tolerance: float) -> tuple[list[CandidateFit], list[str]]:
    """Keep the named effects only if together they explain the disagreement.

    A correct explanation removes most of the systematic residual: if the gap left by the named
    effects (linearised) is above the tolerance *and* above half the gap before, they only
    absorb part of something the catalogue does not hold (a lidar error in one direction sector
    fitted as a constant or a TI-proportional bias), and the answer is ``unexplained``.
    """
    if not chosen:
        return chosen, steps
    left = np.sqrt(problem.gap2(problem.r - np.where(problem.valid, _fitted(chosen), 0.0)))
    if left > tolerance and left > 0.5 * gap:
        ids = ", ".join(c.effect.id for c in chosen)
        return [], steps + [f"the effects that qualified ({ids}) leave a gap of {left:.3f} % of {gap:.3f} % "
                            f"(more than half, above the tolerance): they do not explain the disagreement"]
    return chosen, steps


def _answer(chosen: list[CandidateFit], steps: list[str], significant: bool, gap: float,
            tolerance: float) -> tuple[str, str]:
    """Return the answer (first effect, ``none`` or ``unexplained``) and its one-paragraph note."""
    if not significant:
        return "none", ("no significant disagreement between measurement and nominal model in any height or "
                        "environmental bin (Holm-corrected)")
    if chosen:
        return chosen[0].effect.id, "; ".join(steps)
    if not gap > tolerance:
        return "none", (f"the disagreement is significant but below the tolerance: gap {gap:.3f} % <= "
                        f"{tolerance:g} %" + (f"; {steps[-1]}" if steps else ""))
    return "unexplained", (f"the disagreement is significant and material (gap {gap:.3f} % > tolerance "
                           f"{tolerance:g} %) but no catalogue effect explains it"
                           + (f"; {steps[-1]}" if steps else "") + "; drivers lists where the residual lies")
