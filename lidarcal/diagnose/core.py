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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.campaign import DEFAULT_BASE_SEED
from lidarcal.campaign.settings import Execution
from lidarcal.conditions.variables import CANONICAL_UNITS, CONDITION_NAMES
from lidarcal.diagnose import fit, stats
from lidarcal.diagnose.candidates import fit_candidates
from lidarcal.diagnose.effects import EFFECTS, get_effect
from lidarcal.diagnose.inputs import check_field
from lidarcal.diagnose.problem import (
    DEFAULT_BOOTSTRAP,
    DEFAULT_MODEL_UNCERTAINTY,
    CandidateFit,
    Problem,
    Simulator,
    records_difference,
)
from lidarcal.diagnose.selection import (
    DEFAULT_MIN_SHARE,
    DEFAULT_TOLERANCE,
    adequate,
    conclude,
    minor_effects,
    range_notes,
    refine,
    select,
)

__all__ = ["diagnose", "DiagnosisResult", "DEFAULT_SEED"]

log = logging.getLogger("lidarcal.diagnose")

#: Base seed of the diagnosis simulations (the hidden-effect generator uses different ones).
DEFAULT_SEED = DEFAULT_BASE_SEED
#: Simulated record variables diagnose needs.


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
    tolerance: float = DEFAULT_TOLERANCE  # %, the practical tolerance
    minor: list[CandidateFit] = field(default_factory=list)  # strong but not material (docs/diagnose.md)
    p_min: float = float("nan")     # smallest Holm-adjusted p-value of the disagreement tests

    @property
    def effect_id(self) -> str:
        """Catalogue id of the answer (``none`` or ``unexplained`` when no effect is named)."""
        return self.chosen.effect.id if self.chosen is not None else self.answer


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
    execution: Execution | Mapping[str, Any] | None = None,
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
        θ − θ₀, added in quadrature to the bootstrap; an effect whose share derived from the
        engine's alternatives or fitted on independent campaigns is larger uses that
        (:func:`~lidarcal.diagnose.effects.model_form_share`, ``docs/diagnose.md``).
    min_wind_speed : float
        Periods with a reference below this (m s-1) are not used.
    execution : Execution or mapping, optional
        Where and how every simulation runs (:class:`~lidarcal.campaign.settings.Execution`:
        ``chunk``, ``scheduler``, ``workers``, ``workdir``, ``progress`` ...; a mapping of these
        fields).  Each step is also logged at INFO level on the ``lidarcal.diagnose`` logger.
    """
    # 0. inputs: the campaign, the nominal model, the candidates
    ds, usable, source, model = check_field(field, cube=cube, rwf=rwf, model=model, n_bins=n_bins,
                                            min_bin_count=min_bin_count, min_wind_speed=min_wind_speed)
    ids = [c for c in (candidates if candidates is not None else EFFECTS) if c != "none"]
    effects = [get_effect(c) for c in ids]
    # 1. simulate the campaign's own conditions with the nominal model
    execution = Execution.of(execution)
    simulate = Simulator(_conditions_input(ds, source), base_seed, execution, log.info)
    problem = _residual(ds, usable, model, simulate)
    problem.n_boot, problem.seed = int(n_bootstrap), int(base_seed)
    problem.model_uncertainty = float(model_uncertainty)
    problem.groups = stats.bin_groups(problem.conditions, problem.valid, n_bins,
                                      [e.drivers[:2] for e in effects if len(e.drivers) >= 2])
    # 2. where do they disagree?
    edges, drivers, binned0, tests, significant, p_min = _disagreement(problem, n_bins, min_bin_count, alpha)
    gap0 = stats.gap(problem.r, problem.groups, min_bin_count)
    log.info(f"gap before: {gap0[0]:.3f} % (noise floor {gap0[2]:.3f} %, tolerance {tolerance:g} %)")
    # 3-4. fit every candidate; when the gap is material, add effects while strong and material
    fits = fit_candidates(problem, effects)
    material = significant and gap0[0] > tolerance  # within the tolerance nothing is material: none
    chosen, steps = select(problem, fits, bic_threshold, tie_threshold, tolerance, min_share) \
        if material else ([], [])
    chosen, steps = adequate(problem, chosen, steps, gap0[0], tolerance)
    # the strong candidates that are not named (listed as minor), unless nothing explains the gap
    minor = minor_effects(problem, fits, chosen, bic_threshold, tolerance, gap0[0]) \
        if significant and (chosen or not material) else []
    corrected, after = (model, problem.base) if not chosen else refine(problem, chosen)
    steps = steps + range_notes(problem, chosen)
    fits.sort(key=lambda c: c.delta_bic)  # the refined score may reorder the table
    chosen.sort(key=lambda c: -c.contribution)  # importance: the size of the change each makes
    minor.sort(key=lambda c: c.minor_score)
    answer, note = conclude(chosen, steps, significant, gap0[0], tolerance, minor, p_min)
    # 5. the gap after adding the fitted effect(s); where the residual lies
    d_after = records_difference(after)
    r1 = np.where(problem.valid, problem.d_measured - d_after, np.nan)
    binned1 = stats.bin_residuals(r1, drivers, n_bins, edges)
    gap1 = stats.gap(r1, problem.groups, min_bin_count)
    where = [] if answer == "none" else stats.locate(problem.r, problem.groups, problem.conditions,
                                                      CANONICAL_UNITS, min_bin_count, alpha=alpha)
    log.info(f"answer: {answer}; gap after: {gap1[0]:.3f} % ({simulate.runs} campaign simulations)")
    settings = {"base_seed": int(base_seed), "n_bins": int(n_bins), "min_bin_count": int(min_bin_count),
                "alpha": float(alpha), "bic_threshold": float(bic_threshold),
                "tie_threshold": float(tie_threshold), "tolerance": float(tolerance),
                "min_share": float(min_share), "n_bootstrap": int(n_bootstrap),
                "model_uncertainty": float(model_uncertainty),
                "bootstrap_blocks": problem.clusters_label, "min_wind_speed": float(min_wind_speed),
                "candidates": ids, "simulations": simulate.runs,
                "simulate_options": execution.record(where=False)}
    return DiagnosisResult(
        heights=ds.height.values, times=ds.time.values, conditions=problem.conditions, valid=problem.valid,
        d_measured=problem.d_measured, d_before=problem.d0, d_after=d_after, binned_before=binned0,
        binned_after=binned1, tests=tests, significant=significant, candidates=fits,
        chosen=chosen[0] if chosen else None, tied=list(chosen[0].tied) if chosen else [], note=note,
        gap_before=gap0, gap_after=gap1, design_effect=problem.design_effect, nominal_model=model,
        corrected_model=corrected, settings=settings, source=source, field_dataset=ds, selected=chosen,
        answer=answer, drivers=where, tolerance=float(tolerance), minor=minor, p_min=p_min)


def _conditions_input(ds: xr.Dataset, source: str) -> xr.Dataset:
    """Return the campaign's six conditions as a plain ``conditions`` input of the simulation."""
    cond_ds = ds[list(CONDITION_NAMES)].copy()
    cond_ds.attrs = {"lidarcal_source_file": os.path.basename(source)}
    return cond_ds


def _residual(ds: xr.Dataset, usable: np.ndarray, model, simulate: Simulator) -> Problem:
    """Simulate the nominal model; residual r = d_measured − d_simulated where both are usable."""
    conditions = {n: np.asarray(ds[n].transpose("time", "height").values, dtype=float)
                  for n in CONDITION_NAMES}
    base = simulate(model, "nominal model")
    d_meas = stats.relative_difference(ds["lidar_wind_speed"].transpose("time", "height").values,
                                       ds["reference_wind_speed"].transpose("time", "height").values)
    d0 = records_difference(base)
    valid = usable & np.isfinite(d_meas) & np.isfinite(d0)
    r = np.where(valid, d_meas - d0, np.nan)
    clusters, label = fit.day_clusters(ds.time.values)
    problem = Problem(model, simulate, base, conditions, d_meas, d0, valid, r, clusters)
    problem.clusters_label = label
    return problem


def _disagreement(problem: Problem, n_bins: int, min_bin_count: int, alpha: float):
    """Bin the residual by every condition (and the gap metric's other bin groups) and test it (Holm).

    Returns the bin edges and drivers per condition, the binned residual, the tests, whether
    the disagreement is significant at ``alpha`` and the smallest Holm-adjusted p-value.
    """
    valid, conditions = problem.valid, problem.conditions
    edges = {n: stats.bin_edges(conditions[n][valid], n_bins) for n in CONDITION_NAMES}
    drivers = {n: np.where(valid, conditions[n], np.nan) for n in CONDITION_NAMES}
    binned0 = stats.bin_residuals(problem.r, drivers, n_bins, edges)
    tests = stats.disagreement_tests(binned0, min_bin_count, residual=problem.r)
    # the family also holds the direction sectors and the joint-driver bins of the gap metric (an
    # effect in the product of shear and CNR gradient averages out in every one-variable bin)
    extra = [n for n in problem.groups.names if n not in CONDITION_NAMES]
    p_extra = stats.group_p_values(problem.r, problem.groups, min_bin_count, tuple(extra))
    p_all = stats.holm(np.concatenate([tests["p_value"].ravel(), tests["mean_p_value"], p_extra.ravel()]))
    p_min = float(np.nanmin(p_all)) if np.isfinite(p_all).any() else 1.0
    significant = p_min < alpha
    log.info(f"disagreement {'significant' if significant else 'not significant'} (min Holm p = {p_min:.3g})")
    return edges, drivers, binned0, tests, significant, p_min

