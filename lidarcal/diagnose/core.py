"""The diagnose workflow: find the gap, name the effect, add it, re-run (``docs/diagnose.md``).

:func:`diagnose` takes a ``field_campaign`` (measured lidar/reference pair + conditions) and

1. builds the nominal model (the file's ``lidar_*`` attributes, or a bench cube / RWF) and
   simulates the campaign's own conditions with it;
2. forms the per-period residual r = (L−R)/R measured − (L−R)/R simulated, bins it per height
   by every environmental variable and tests whether it is zero (:mod:`.stats`);
3. for every catalogue effect (:mod:`.effects`) re-simulates at a probe value with the SAME
   seeds (common random numbers), smooths the response on the effect's drivers and fits the
   parameter by weighted least squares, scoring it by ΔBIC against ``none`` (:mod:`.fit`);
4. names the best effect — or ``none`` when nothing significant is found or nothing explains a
   significant part of it — refines its parameter by one re-simulation at the estimate, and
5. re-simulates with the fitted effect to report the gap before and after.

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
from lidarcal.conditions import load_conditions
from lidarcal.diagnose import fit, stats
from lidarcal.diagnose.effects import CONDITION_VARIABLES, EFFECTS, Effect, get_effect
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import open_artefact, source_name
from lidarcal.lidar import LidarModel
from lidarcal.lidar.geometry import check_reachable

__all__ = ["diagnose", "check_field", "DiagnosisResult", "CandidateFit", "DEFAULT_SEED", "RECORD_NAMES",
           "min_periods"]

log = logging.getLogger("lidarcal.diagnose")

#: Base seed of the diagnosis simulations (the hidden-effect generator uses different ones).
DEFAULT_SEED = DEFAULT_BASE_SEED
#: Simulated record variables diagnose needs.
RECORD_NAMES = ("lidar_wind_speed", "reference_wind_speed", "lidar_wind_speed_scalar",
                "lidar_wind_speed_vector")
MEASURED = ("lidar_wind_speed", "reference_wind_speed")


def min_periods(n_bins: int, min_bin_count: int) -> int:
    """Usable periods a height needs: enough to fill every bin of every variable."""
    return int(n_bins) * int(min_bin_count)


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

    @property
    def effect_id(self) -> str:
        """Catalogue id of the answer (``none`` when nothing was found)."""
        return self.chosen.effect.id if self.chosen is not None else "none"


# -- input ------------------------------------------------------------------------------------

def load_field(field: str | os.PathLike | xr.Dataset, *, n_bins: int, min_bin_count: int,
               min_wind_speed: float) -> tuple[xr.Dataset, np.ndarray, str]:
    """Open and check a field campaign; return (dataset, usable mask (time, height), source).

    A period is usable at a height when the measured pair and all six conditions are finite
    and the reference is at least ``min_wind_speed``.  Heights with fewer than
    :func:`min_periods` usable periods are dropped (with a log message); none left is an error.
    """
    source = source_name(field, "<field campaign>")
    raw = field if isinstance(field, xr.Dataset) else open_artefact(field)
    missing = [n for n in MEASURED if n not in raw.variables]
    if missing:
        raise MissingVariableError(
            f"{source}: the measured pair is incomplete: variable(s) {missing} missing; a field_campaign "
            f"needs 'lidar_wind_speed' and 'reference_wind_speed' (m s-1) on (time, height); found "
            f"{sorted(map(str, raw.data_vars))}")
    for name in MEASURED:
        if not np.isfinite(np.asarray(raw[name].values, dtype=float)).any():
            raise InputError(f"{source}: variable {name!r} is NaN everywhere; expected measured 10-minute "
                             f"wind speeds (m s-1) in at least {min_periods(n_bins, min_bin_count)} periods")
    ds = load_conditions(raw, kind="field_campaign", warn=False)
    ref = ds["reference_wind_speed"].values
    usable = np.asarray(ds["input_complete"].values, dtype=bool) & (ref >= min_wind_speed)
    need = min_periods(n_bins, min_bin_count)
    counts = usable.sum(axis=0)
    keep = counts >= need
    if not keep.any():
        raise InputError(
            f"{source}: too few usable periods: at most {int(counts.max())} per height have the measured "
            f"pair, "
            f"all six conditions and reference_wind_speed >= {min_wind_speed:g} m s-1; diagnose needs at "
            f"least {need} per height ({n_bins} bins x {min_bin_count} periods)")
    if not keep.all():
        log.warning("%s: dropping height(s) %s m: fewer than %d usable periods (%s)", source,
                    ds.height.values[~keep].tolist(), need, counts[~keep].tolist())
    ds = ds.isel(height=np.flatnonzero(keep))
    usable = usable[:, keep]
    rows = usable.any(axis=1)
    return ds.isel(time=np.flatnonzero(rows)), usable[rows], source


def nominal_model(ds: xr.Dataset, *, cube: xr.Dataset | None = None, rwf: xr.Dataset | None = None):
    """Return the nominal lidar: the file's ``lidar_*`` attributes, configured from cube/RWF if given."""
    return LidarModel.from_attrs(ds, cube=cube, rwf=rwf)


def check_field(field: str | os.PathLike | xr.Dataset, *, cube: xr.Dataset | None = None,
                rwf: xr.Dataset | None = None, model: Any = None, n_bins: int = 6, min_bin_count: int = 10,
                min_wind_speed: float = 3.0) -> tuple[xr.Dataset, np.ndarray, str, Any]:
    """Every check :func:`diagnose` makes of its inputs before simulating: the one field_campaign check.

    :func:`load_field` (contract, measured pair, enough usable periods per height), the nominal
    model from the ``lidar_*`` attributes (or ``cube``/``rwf``, or ``model``) and the heights
    the lidar can reach.  ``lidarcal conditions check --kind field_campaign`` runs it with
    diagnose's defaults.  Returns (dataset, usable mask, source, nominal model).
    """
    ds, usable, source = load_field(field, n_bins=n_bins, min_bin_count=min_bin_count,
                                    min_wind_speed=min_wind_speed)
    if model is None:
        model = nominal_model(ds, cube=cube, rwf=rwf)
    _check_reachable(model, ds.height.values, source)
    return ds, usable, source, model


def _check_reachable(model, heights: np.ndarray, source: str) -> None:
    """Refuse heights whose range gate (with the RWF's extent) would reach below the lidar."""
    problems = check_reachable(model, heights)
    if problems:
        raise InputError(f"{source}: variable 'height': heights the lidar cannot measure with this RWF and "
                         f"geometry: " + "; ".join(problems))


# -- simulation -------------------------------------------------------------------------------

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

def _fit(effect: Effect, r, d0, d_probe, theta0, theta_probe, conditions, valid, w, n_eff):
    """Linearised fit of ``effect`` from one probe; returns (estimate, stderr, ΔBIC, explained, clipped)."""
    p = effect.parameters[0]
    h = theta_probe - theta0
    J = fit.smooth_response((d_probe - d0) / h, conditions, effect.drivers, valid, weights=w)
    lo, hi = p.bounds
    res = fit.fit_linear(r, J, w, bounds=[(lo - theta0, hi - theta0)])
    dbic = fit.delta_bic(res.rss, res.rss0, effect.n_parameters, n_eff)
    explained = 1.0 - res.rss / res.rss0 if res.rss0 > 0 else 0.0
    return theta0 + float(res.delta[0]), float(res.stderr[0]), dbic, explained, res.clipped


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
    weights: np.ndarray | None = None
    n_eff: float = 0.0
    design_effect: float = 1.0

    def records_at(self, effect: Effect, params: Mapping[str, float], label: str) -> dict[str, np.ndarray]:
        """Return the records of the model with ``effect`` at ``params`` (shortcut or re-simulation)."""
        return _records_at(effect, params, self.model, self.base, self.conditions, self.simulate, label)

    def fit(self, effect: Effect, d_probe: np.ndarray, theta0: float, theta_probe: float):
        """Linearised fit of ``effect`` from the response ``d_probe`` at ``theta_probe``."""
        return _fit(effect, self.r, self.d0, d_probe, theta0, theta_probe, self.conditions, self.valid,
                    self.weights, self.n_eff)


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
        Base seed of every simulation (common random numbers across candidates).
    n_bins, min_bin_count : int
        Quantile bins per environmental variable, and the minimum periods a bin needs to be
        tested and to count in the gap.  A height needs ``n_bins × min_bin_count`` usable periods.
    alpha : float
        Family-wise false-alarm rate of the disagreement tests (Holm over heights × variables).
    bic_threshold : float
        An effect is named only if it lowers the BIC by more than this against ``none``
        (6 = "strong evidence", Kass & Raftery 1995).
    tie_threshold : float
        Candidates within this ΔBIC of the best cannot be told apart (named in ``tied``).
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
    # 2. where do they disagree?
    edges, drivers, binned0, tests, significant, gap0 = _disagreement(problem, n_bins, min_bin_count, alpha)
    # 3-4. fit every candidate from one probe, name the best and refine it
    fits = _fit_candidates(problem, effects)
    chosen, tied, note = _choose(fits, significant, bic_threshold, tie_threshold)
    corrected, after = (model, problem.base) if chosen is None else _refine(problem, chosen)
    fits.sort(key=lambda c: c.delta_bic)  # the refined score may reorder the table
    # 5. the gap after adding the fitted effect
    d_after = _d(after)
    binned1 = stats.bin_residuals(np.where(problem.valid, problem.d_measured - d_after, np.nan), drivers,
                                  n_bins, edges)
    gap1 = stats.gap(binned1, min_bin_count)
    log.info(f"answer: {chosen.effect.id if chosen else 'none'}; gap after: {gap1[0]:.3f} % "
             f"({simulate.runs} campaign simulations)")
    settings = {"base_seed": int(base_seed), "n_bins": int(n_bins), "min_bin_count": int(min_bin_count),
                "alpha": float(alpha), "bic_threshold": float(bic_threshold),
                "tie_threshold": float(tie_threshold), "min_wind_speed": float(min_wind_speed),
                "candidates": ids, "simulations": simulate.runs,
                "simulate_options": {k: v for k, v in (simulate_options or {}).items() if k != "scheduler"}}
    return DiagnosisResult(
        heights=ds.height.values, times=ds.time.values, conditions=problem.conditions, valid=problem.valid,
        d_measured=problem.d_measured, d_before=problem.d0, d_after=d_after, binned_before=binned0,
        binned_after=binned1, tests=tests, significant=significant, candidates=fits, chosen=chosen,
        tied=tied, note=note, gap_before=gap0, gap_after=gap1, design_effect=problem.design_effect,
        nominal_model=model, corrected_model=corrected, settings=settings, source=source, field_dataset=ds)


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
    d_meas = stats.relative_difference(ds["lidar_wind_speed"].values, ds["reference_wind_speed"].values)
    d0 = _d(base)
    valid = usable & np.isfinite(d_meas) & np.isfinite(d0)
    r = np.where(valid, d_meas - d0, np.nan)
    return _Problem(model, simulate, base, conditions, d_meas, d0, valid, r)


def _disagreement(problem: _Problem, n_bins: int, min_bin_count: int, alpha: float):
    """Bin the residual by every condition and test it (Holm).

    Returns the bin edges and drivers per condition, the binned residual, the tests, whether the
    disagreement is significant at ``alpha`` and the gap before correction.
    """
    valid, conditions = problem.valid, problem.conditions
    edges = {n: stats.bin_edges(conditions[n][valid], n_bins) for n in CONDITION_VARIABLES}
    drivers = {n: np.where(valid, conditions[n], np.nan) for n in CONDITION_VARIABLES}
    binned0 = stats.bin_residuals(problem.r, drivers, n_bins, edges)
    tests = stats.disagreement_tests(binned0, min_bin_count, residual=problem.r)
    p_all = np.concatenate([tests["p_adjusted"].ravel(), tests["mean_p_adjusted"]])
    p_min = float(np.nanmin(p_all)) if np.isfinite(p_all).any() else 1.0
    significant = p_min < alpha
    gap0 = stats.gap(binned0, min_bin_count)
    log.info(f"gap before: {gap0[0]:.3f} % (noise floor {gap0[2]:.3f} %); disagreement "
             f"{'significant' if significant else 'not significant'} (min Holm p = {p_min:.3g})")
    return edges, drivers, binned0, tests, significant, gap0


def _fit_candidates(problem: _Problem, effects: Sequence[Effect]) -> list[CandidateFit]:
    """Fit every effect from one probe re-simulation (common random numbers); sorted by ΔBIC."""
    problem.weights = fit.noise_weights(problem.d0, problem.conditions, problem.valid)
    problem.design_effect = fit.design_effect(np.where(problem.valid, problem.r, 0.0), problem.weights)
    problem.n_eff = float(problem.valid.sum()) / problem.design_effect
    fits: list[CandidateFit] = []
    for eff in effects:
        theta0 = eff.nominal(problem.model)
        probe = eff.probe(problem.model)
        d_probe = _d(problem.records_at(eff, probe, f"{eff.id} probe {probe}"))
        name = eff.parameters[0].name
        est, se, dbic, expl, clipped = problem.fit(eff, d_probe, theta0[name], probe[name])
        fits.append(CandidateFit(eff, theta0, {name: est}, {name: se}, dbic, expl, probe, clipped=clipped))
        log.info(f"  {eff.id}: {name} = {est:.4g} ± {se:.2g}, ΔBIC = {dbic:.1f}, explains {100 * expl:.1f} %")
    fits.sort(key=lambda c: c.delta_bic)
    return fits


def _refine(problem: _Problem, chosen: CandidateFit) -> tuple[Any, dict[str, np.ndarray]]:
    """Re-simulate at the estimate, refit on the secant over [θ0, θ1]; return (corrected model, records)."""
    eff = chosen.effect
    name = eff.parameters[0].name
    theta0, theta1 = chosen.nominal[name], chosen.estimate[name]
    rec1 = problem.records_at(eff, {name: theta1}, f"{eff.id} at estimate")
    after, final = rec1, theta1
    if abs(theta1 - theta0) > 1e-12:
        est2, se2, dbic2, expl2, clipped2 = problem.fit(eff, _d(rec1), theta0, theta1)
        chosen.stderr = {name: se2}
        chosen.refined = True
        if abs(est2 - theta1) > 0.5 * se2:  # the estimate moved: simulate where it landed
            final = est2
            after = problem.records_at(eff, {name: est2}, f"{eff.id} at refined estimate")
        chosen.estimate = {name: final}
        chosen.delta_bic, chosen.explained, chosen.clipped = dbic2, expl2, clipped2
        log.info(f"refined {eff.id}: {name} = {final:.4g} ± {se2:.2g}")
    return eff.apply(problem.model, chosen.estimate), after


def _choose(fits: list[CandidateFit], significant: bool, bic_threshold: float,
            tie_threshold: float) -> tuple[CandidateFit | None, list[str], str]:
    """Apply the decision rule; return (chosen or None, tied ids, note)."""
    if not fits:
        return None, [], "no candidate effect was tried"
    best = fits[0]
    if not significant:
        return None, [], ("no significant disagreement between measurement and nominal model in any "
                          "height or environmental bin (Holm-corrected)")
    if best.delta_bic > -bic_threshold:
        return None, [], (f"the disagreement is significant but no catalogue effect explains a significant "
                          f"part of it (best: {best.effect.id}, ΔBIC {best.delta_bic:.1f} > "
                          f"-{bic_threshold:g})")
    tied = [c.effect.id for c in fits[1:] if c.delta_bic - best.delta_bic < tie_threshold
            and c.delta_bic <= -bic_threshold]
    if tied:
        note = (f"{best.effect.id} and {', '.join(tied)} cannot be told apart with these data "
                f"(ΔBIC within {tie_threshold:g}); {best.effect.id} is reported as marginally better")
    else:
        runner = fits[1] if len(fits) > 1 else None
        note = (f"{best.effect.id} explains {100 * best.explained:.1f} % of the weighted residual sum of "
                "squares")
        if runner is not None:
            gap = runner.delta_bic - best.delta_bic
            note += f"; next best {runner.effect.id} is {gap:.1f} BIC units behind"
    return best, tied, note
