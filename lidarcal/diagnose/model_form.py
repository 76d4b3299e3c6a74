r"""Each catalogue effect's model-form share, derived from the engine's own model-form alternatives.

The budget's model-form term (:mod:`lidarcal.analysis.model_form`) is the spread of the certified
value across the defensible alternatives of :data:`lidarcal.lidar.model_form.ALTERNATIVES`
(reference-turbulence convention, IEC coherence, Kaimal length scale, RWF shape), each one end of
a rectangular range whose other end is the nominal model.  Diagnose fits an effect with the
nominal model's response; if the truth is an alternative model, the response it should have used
is that model's.  This module measures how far apart the two are, with the same common random
numbers (every model simulated with the same ``base_seed``: the same Fourier, noise and
availability draws per period).

For an effect at strength θ (the catalogue's ``realistic`` value) and a model *m*, the change is
Δ_m = d(m with the effect) − d(m), d = (L − R)/R per (period, height): from the effect's exact
shortcut on *m*'s records, or from a re-simulation of ``effect.apply(m, θ)``.  Diagnose regresses
the residual on the smoothed nominal response S Δ_nom (:func:`lidarcal.diagnose.fit.smooth_response`,
in the fit's noise weights w; S is the weighted least-squares projection on the effect's drivers);
a residual that is Δ_a, the change under alternative *a*, is therefore fitted as

    k_a = Σ w Δ_a S Δ_nom / Σ w (S Δ_nom)²

times the true change θ − θ₀ (k_nom = 1 exactly).  r_a = k_a − 1 is the relative error of the
fitted change if *a* were the truth.  As in the budget, the true response lies anywhere between
the nominal one and *a*'s (rectangular, rms distance |r_a|/√3) and the aspects are independent, so
the share — a standard uncertainty of the fitted change as a share of itself — is

    u = √(Σ_a r_a² / 3).

It is the budget's u_mf applied to the effect's change instead of the certified value.  Its Monte
Carlo standard error is the delta method over periods (clusters of heights): each period's
influence on k_a is ψ_a = Σ_heights w (Δ_a − Δ_nom − r_a S Δ_nom) S Δ_nom / Σ w (S Δ_nom)², on u
Σ_a r_a ψ_a / 3u.  Effects that act after the turbulence is sampled and only on the reference
(``reference_gain``, ``reference_overspeeding``, ``reference_flow_distortion``) scale R by a
factor the alternatives do not touch: their change is (L/R)·(1/s − 1), which moves only with
L/R, and their share comes out near 0 — a result, not a default.

Simulating (1 + number of alternatives) × (1 + effects without a shortcut) campaigns is too dear
for every diagnosis (16 for the ideal lidar; about 9 ms CPU per period × height each), so the
shares are computed once, by ``benchmarks/diagnose_form_shares.py``, and recorded in the catalogue
(``Effect.derived_form``, :data:`lidarcal.diagnose.effects.DERIVED_FORM_SOURCE`);
``tests/test_diagnose_form.py`` recomputes one on other conditions and seeds.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.settings import Execution
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.diagnose import fit
from lidarcal.diagnose.effects import EFFECTS, Effect, realistic_strengths
from lidarcal.diagnose.problem import RECORD_NAMES, records_difference
from lidarcal.errors import InputError
from lidarcal.lidar import LidarModel
from lidarcal.lidar.model_form import alternative_models

__all__ = ["DerivedShare", "response_ratio", "combine_ratios", "derived_shares"]


@dataclass(frozen=True)
class DerivedShare:
    """One effect's model-form share from the alternatives, with its Monte Carlo standard error."""

    effect: str
    share: float                    #: u = √(Σ_a r_a² / 3)
    standard_error: float           #: delta-method standard error of ``share`` over periods
    ratios: dict[str, float] = field(default_factory=dict)          #: k_a per alternative
    ratio_errors: dict[str, float] = field(default_factory=dict)    #: standard error of each k_a
    change: float = float("nan")    #: rms change of (L − R)/R (%) the effect makes, nominal model
    cells: int = 0                  #: (period, height) cells used
    parameters: dict[str, float] = field(default_factory=dict)      #: the strength θ


def response_ratio(delta_alt: np.ndarray, delta_nom: np.ndarray, conditions: Mapping[str, np.ndarray],
                   drivers: Sequence[str], valid: np.ndarray, weights: np.ndarray
                   ) -> tuple[float, np.ndarray]:
    """k_a of ``delta_alt`` against the smoothed ``delta_nom`` and each period's influence on it.

    All arrays are (periods × heights); ``weights`` the fit's noise weights.  S is a weighted
    least-squares projection per height, so Σ w Δ_nom S Δ_nom = Σ w (S Δ_nom)² and
    k_a − 1 = Σ w (Δ_a − Δ_nom) S Δ_nom / Σ w (S Δ_nom)²: a ratio of sums over periods, whose
    influences ψ (one per period, summed over its heights) carry only the difference the
    alternative makes, not how well the drivers' quadratic smooths the nominal change.
    Returns (k_a, ψ), Σψ² the variance of k_a.
    """
    s = fit.smooth_response(delta_nom, dict(conditions), tuple(drivers), valid, weights=weights)
    ok = valid & np.isfinite(s) & np.isfinite(delta_alt) & np.isfinite(delta_nom)
    w = np.where(ok, weights, 0.0)
    s0 = np.where(ok, s, 0.0)
    diff = np.where(ok, delta_alt - delta_nom, 0.0)
    den = float(np.sum(w * s0 * s0))
    if not den > 0:
        return float("nan"), np.full(delta_alt.shape[0], np.nan)
    r = float(np.sum(w * diff * s0)) / den
    psi = np.sum(w * (diff - r * s0) * s0, axis=1) / den
    return 1.0 + r, psi


def combine_ratios(ratios: Mapping[str, float], influences: Mapping[str, np.ndarray]) -> tuple[float, float]:
    """Return the share √(Σ_a (k_a − 1)² / 3) and its delta-method standard error (per-period influences)."""
    r = {a: float(k) - 1.0 for a, k in ratios.items()}
    u = float(np.sqrt(sum(v * v for v in r.values()) / 3.0))
    if not r:
        return 0.0, 0.0
    if u == 0.0:  # the derivative is undefined at 0: the error of the rms of independent noise
        return u, float(np.sqrt(sum(float(np.sum(influences[a] ** 2)) for a in r) / 3.0))
    psi = sum(r[a] * influences[a] for a in r) / (3.0 * u)
    return u, float(np.sqrt(np.sum(psi**2)))


def _records(sim: xr.Dataset) -> dict[str, np.ndarray]:
    return {n: np.asarray(sim[n].transpose("time", "height").values, dtype=float) for n in RECORD_NAMES}


def derived_shares(
    conditions: xr.Dataset,
    model: LidarModel | None = None,
    effects: Iterable[str] | None = None,
    params: Mapping[str, Mapping[str, float]] | None = None,
    *,
    base_seed: int = 1,
    execution: Execution | Mapping[str, Any] | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict[str, DerivedShare]:
    """Derive the model-form share of each effect from ``model``'s alternatives (module docstring).

    Parameters
    ----------
    conditions : xarray.Dataset
        A ``conditions`` record (e.g. :func:`lidarcal.diagnose.generate.hidden_effect_conditions`).
    model : LidarModel, optional
        The nominal lidar (default the ideal lidar); its alternatives are
        :func:`lidarcal.lidar.model_form.alternative_models`.
    effects : iterable of str, optional
        Catalogue ids (default every effect but ``none``).
    params : mapping, optional
        Strength per effect id (default the catalogue's realistic strengths).
    base_seed : int
        Seed of every simulation (common random numbers across the models).
    execution, progress
        How the simulations run; a callable given one line per simulation.

    Returns
    -------
    dict
        ``{effect id: DerivedShare}``.
    """
    model = LidarModel.ideal() if model is None else model
    ids = [e for e in (effects if effects is not None else EFFECTS) if e != "none"]
    strengths = {**realistic_strengths(), **dict(params or {})}
    chosen: list[Effect] = []
    for e in ids:
        if e not in EFFECTS:
            raise InputError(f"unknown effect {e!r}; catalogue ids: {', '.join(EFFECTS)}")
        chosen.append(EFFECTS[e])
    models = {"nominal": model, **alternative_models(model)}
    run = Execution.of(execution)
    say = progress or (lambda line: None)

    def simulate(m: LidarModel, label: str) -> dict[str, np.ndarray]:
        say(f"simulating {conditions.sizes['time']} periods x {conditions.sizes['height']} heights: {label}")
        return _records(simulate_campaign(conditions, m, base_seed=int(base_seed), execution=run))

    cond = {n: np.asarray(conditions[n].transpose("time", "height").values, dtype=float)
            for n in CONDITION_NAMES}
    changes: dict[str, dict[str, np.ndarray]] = {e.id: {} for e in chosen}
    d_nominal = None
    theta = {e.id: _strength(e, model, strengths[e.id]) for e in chosen}
    for name, m in models.items():
        base = simulate(m, f"{name} model")
        d_base = records_difference(base)
        if name == "nominal":
            d_nominal = d_base
        for e in chosen:
            if e.shortcut is not None:
                with_effect = {**base, **e.shortcut(base, cond, e.nominal(m), theta[e.id])}
            else:
                with_effect = simulate(e.apply(m, theta[e.id]), f"{name} model with {e.id}")
            changes[e.id][name] = records_difference(with_effect) - d_base
    out = {}
    for e in chosen:
        delta = changes[e.id]
        valid = np.isfinite(d_nominal) & np.logical_and.reduce([np.isfinite(v) for v in delta.values()])
        for n in e.drivers:
            valid &= np.isfinite(cond[n])
        weights = fit.noise_weights(d_nominal, cond, valid)
        ratios, errors, influences = {}, {}, {}
        for name in models:
            if name == "nominal":
                continue
            k, psi = response_ratio(delta[name], delta["nominal"], cond, e.drivers, valid, weights)
            ratios[name], influences[name] = k, psi
            errors[name] = float(np.sqrt(np.sum(psi**2)))
        u, se = combine_ratios(ratios, influences)
        x = delta["nominal"][valid]
        out[e.id] = DerivedShare(e.id, u, se, ratios, errors, 100.0 * float(np.sqrt(np.mean(x**2))),
                                 int(valid.sum()), dict(theta[e.id]))
    return out


def _strength(effect: Effect, model: LidarModel, wanted: Mapping[str, float]) -> dict[str, float]:
    """``wanted``, except a linear parameter the model already has there takes its probe value.

    (A measured-RWF model is CNR-weighted at scale 1 already, the realistic strength of
    ``cnr_gradient_weighting``: its change is then measured at the probe, scale 2.)
    """
    nominal, probe = effect.nominal(model), effect.probe(model)
    out = {k: float(v) for k, v in wanted.items()}
    for p in effect.linear_parameters:
        if out[p.name] == nominal[p.name]:
            out[p.name] = probe[p.name]
    return out
