"""The residual diagnose explains and what every candidate fit shares (common random numbers).

:class:`Problem` holds the per-period residual r = (L−R)/R measured − (L−R)/R simulated of a
field campaign, the nominal model's records it was formed from, the conditions, the usable
periods, the day blocks of the bootstrap and the fit weights; :class:`Simulator` re-simulates
the campaign's conditions with the same seeds; :class:`CandidateFit` is one catalogue effect
fitted to the residual (:mod:`.candidates`, :mod:`.selection`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.settings import Execution
from lidarcal.diagnose import fit, stats
from lidarcal.diagnose.effects import Effect, model_form_share

__all__ = ["Problem", "Simulator", "CandidateFit", "records_difference", "RECORD_NAMES", "DEFAULT_BOOTSTRAP",
           "DEFAULT_MODEL_UNCERTAINTY"]

#: Simulated record variables diagnose needs.
RECORD_NAMES = ("lidar_wind_speed", "reference_wind_speed", "lidar_wind_speed_scalar",
                "lidar_wind_speed_vector")
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
    clipped: bool = False
    response: list[np.ndarray] = field(default_factory=list, repr=False)  # ∂d/∂θ per parameter
    interval: dict[str, tuple[float, float]] = field(default_factory=dict)  # 95 % bootstrap interval
    contribution: float = float("nan")  # rms change of (L−R)/R the effect makes, %
    share: float = float("nan")         # share of the systematic residual it explains
    tied: list[str] = field(default_factory=list)  # catalogue ids it cannot be told from
    free: dict[str, float] = field(default_factory=dict)     # unconstrained fit of each linear parameter
    free_se: dict[str, float] = field(default_factory=dict)  # its (sandwich) standard error
    minor: str = ""             # why a strong candidate is not named (empty: not a minor effect)
    minor_score: float = float("nan")  # its ΔBIC: alone, or given the named effects

    @property
    def bounds(self) -> list[tuple[float, float]]:
        """Limits of θ − θ₀ for every linear parameter (the catalogue bounds minus the nominal value)."""
        return [(p.bounds[0] - self.nominal[p.name], p.bounds[1] - self.nominal[p.name])
                for p in self.effect.linear_parameters]


class Simulator:
    """Simulate the campaign's conditions with common random numbers; count and log the runs."""

    def __init__(self, conditions: xr.Dataset, base_seed: int, execution: Execution,
                 progress: Callable[[str], None]):
        self.conditions = conditions
        self.base_seed = int(base_seed)
        self.execution = execution
        self.progress = progress
        self.runs = 0

    def __call__(self, model, label: str) -> dict[str, np.ndarray]:
        """Simulate the conditions with ``model``; return the records of :data:`RECORD_NAMES`."""
        n_t, n_h = self.conditions.sizes['time'], self.conditions.sizes['height']
        self.progress(f"simulating {n_t} periods x {n_h} "
                      f"heights: {label}")
        sim = simulate_campaign(self.conditions, model, base_seed=self.base_seed, execution=self.execution)
        self.runs += 1
        return {n: np.asarray(sim[n].transpose("time", "height").values, dtype=float) for n in RECORD_NAMES}


def records_difference(records: Mapping[str, np.ndarray]) -> np.ndarray:
    """(L − R)/R of simulated ``records`` (:func:`lidarcal.diagnose.stats.relative_difference`)."""
    return stats.relative_difference(records["lidar_wind_speed"], records["reference_wind_speed"])


@dataclass
class Problem:
    """The residual to explain and what every candidate fit shares (common random numbers)."""

    model: Any
    simulate: Simulator
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
        if effect.shortcut is not None:
            nominal = effect.nominal(self.model)
            return {**self.base, **effect.shortcut(self.base, self.conditions, nominal, params)}
        return self.simulate(effect.apply(self.model, params), label)

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
        """Model-form share of the fitted change (:func:`~lidarcal.diagnose.effects.model_form_share`)."""
        return max([model_form_share(e, self.model_uncertainty) for e in effects] or [self.model_uncertainty])

    def gap2(self, r: np.ndarray) -> float:
        """Square of the gap metric (%²) of a residual."""
        g = stats.gap(r, self.groups)[0]
        return g * g if np.isfinite(g) else 0.0
