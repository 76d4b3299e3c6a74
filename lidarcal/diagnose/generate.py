"""Hidden-effect field campaigns: simulated "measurements" with one catalogue effect switched on.

:func:`generate_field_campaign` simulates a conditions record with the nominal lidar plus one
catalogue effect at a chosen strength (or none) and writes the result through the public
``field_campaign`` contract (``docs/contracts.md``): the six conditions, the measured pair
``lidar_wind_speed`` / ``reference_wind_speed`` and the *nominal* ``lidar_*`` attributes — the
file does not reveal the effect except in ``lidarcal_hidden_effect`` (JSON, for tests and
benchmarks; :func:`lidarcal.diagnose.diagnose` never reads it).  The simulations use
:data:`GENERATOR_SEED`, not the diagnosis seed, so the "measured" Monte Carlo noise is
independent of the simulated one, as for a real campaign.

:func:`hidden_effect_conditions` makes a suitable conditions record with
:func:`lidarcal.conditions.synthetic_conditions` and a CNR model whose gradient changes sign at
the telescope focus (110 m, paper Figure 3), ±0.05 dB/m typical, with period-to-period
variability: the realistic setting in which a CNR-weighted RWF can be told from a Zd error.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import synthetic_conditions
from lidarcal.conditions.variables import CONDITION_NAMES, FIELD_NAMES, variable_attrs
from lidarcal.diagnose.effects import get_effect, realistic_strengths
from lidarcal.errors import InputError
from lidarcal.lidar import LidarModel
from lidarcal.provenance import stamp

__all__ = ["GENERATOR_SEED", "REALISTIC_STRENGTHS", "DIAGNOSIS_CNR_MODEL", "hidden_effect_conditions",
           "generate_field_campaign"]

#: Base seed of the hidden-effect simulations (the diagnosis uses core.DEFAULT_SEED).
GENERATOR_SEED = 777_000_001

#: Realistic strengths of each effect (units of ``docs/diagnose.md``), from the catalogue.
REALISTIC_STRENGTHS: dict[str, dict[str, float]] = realistic_strengths()

#: CNR model (lidarcal.conditions.kernels.cnr_model parameters) for hidden-effect campaigns:
#: no mean lapse, a 3 dB focus bump at 110 m (vertical gradient +0.03 dB/m below, -0.03 dB/m above
#: the focus) and a period-to-period lapse of 0.03 dB/m, so gradients span about ±0.05 dB/m per
#: metre of height, ±0.045 dB/m along the 28° beam (the ``cnr_gradient`` written, cos φ times).
DIAGNOSIS_CNR_MODEL = {"lapse": 0.0, "lapse_std": 0.03, "noise_phi": 0.9, "focus_gain": 3.0,
                       "focus_height": 110.0, "focus_width": 60.0}


def hidden_effect_conditions(n_periods: int, heights: Sequence[float] = (40.0, 80.0, 120.0, 160.0),
                             seed: int = 11, *, turbulence_reference: float = 0.10, median_speed: float = 8.0,
                             speed_range: tuple[float, float] = (4.0, 16.0), ref_height: float = 80.0,
                             pool: int = 40) -> xr.Dataset:
    """Make a synthetic ``conditions`` record for hidden-effect campaigns (see module docstring).

    A short campaign cut from one synthetic time series sees only a few days of weather (its
    wind-speed AR(1) has a correlation time of ~200 periods), so ``pool × n_periods`` periods
    are generated and ``n_periods`` of them drawn at random (kept in time order) among those
    whose speed at ``ref_height`` lies in ``speed_range`` (m s-1, the IEC calibration range):
    a campaign of a few hundred periods then spans the conditions of a season.
    ``turbulence_reference`` is the synthetic generator's I_ref (default 0.10: TI ≈ 0.08–0.2
    at 80 m); raise it for campaigns where the hybrid weight must matter.
    """
    n = int(n_periods)
    full = synthetic_conditions(n * int(pool), heights, seed, turbulence_reference=turbulence_reference,
                                median_speed=median_speed, ref_height=ref_height,
                                cnr_params=DIAGNOSIS_CNR_MODEL)
    ref = full["wind_speed"].sel(height=ref_height, method="nearest").values
    eligible = np.flatnonzero((ref >= speed_range[0]) & (ref <= speed_range[1])
                              & np.isfinite(full["wind_speed"].values).all(axis=1))
    if eligible.size < n:
        raise InputError(f"hidden_effect_conditions: only {eligible.size} of {full.sizes['time']} synthetic "
                         f"periods have {speed_range} m s-1 at {ref_height:g} m; need {n}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0xD1A6]))
    pick = np.sort(rng.choice(eligible, size=n, replace=False))
    out = full.isel(time=pick)
    out.attrs["lidarcal_synthetic_selection"] = (
        f"{n} periods drawn at random from {full.sizes['time']} with {speed_range[0]:g}-{speed_range[1]:g} "
        f"m s-1 at {ref_height:g} m")
    return out


def generate_field_campaign(
    conditions: xr.Dataset,
    effect: str = "none",
    params: Mapping[str, float] | None = None,
    *,
    model: Any = None,
    base_seed: int = GENERATOR_SEED,
    execution: Execution | Mapping[str, Any] | None = None,
    call: str | None = None,
) -> xr.Dataset:
    """Simulate a ``field_campaign`` whose lidar (or reference) has ``effect`` at ``params``.

    Parameters
    ----------
    conditions : xarray.Dataset
        A ``conditions`` record (e.g. :func:`hidden_effect_conditions`).
    effect : str
        Catalogue id; ``"none"`` for an effect-free campaign.
    params : mapping, optional
        Effect parameters (default :data:`REALISTIC_STRENGTHS`).
    model : LidarModel, optional
        The nominal lidar (default the ideal lidar of ``docs/contracts.md``); its configuration is written
        to the ``lidar_*`` attributes, the effect is not.
    base_seed : int
        Seed of the "measurement" simulation (default :data:`GENERATOR_SEED`).
    execution : Execution or mapping, optional
        Where and how the simulation runs (:class:`~lidarcal.campaign.settings.Execution`).
    """
    eff = get_effect(effect)
    params = dict(REALISTIC_STRENGTHS[eff.id] if params is None else params)
    nominal = model if model is not None else LidarModel.ideal()
    truth = eff.apply(nominal, params)
    sim = simulate_campaign(conditions, truth, base_seed=int(base_seed), execution=execution)
    out = sim[list(CONDITION_NAMES)].copy()
    simulated = (sim["simulated"].values == 1 if "simulated" in sim
                 else np.ones(out.wind_speed.shape, bool))
    for name in FIELD_NAMES:  # the measured pair, declared in schemas/field_campaign.yaml
        out[name] = (sim[name].dims, np.where(simulated, sim[name].values, np.nan), variable_attrs(
            name, comment="synthetic measurement: lidarcal virtual lidar with a hidden effect "
                          "(lidarcal_hidden_effect)"))
    fwhm = _rwf_fwhm(nominal)
    out.attrs = {
        "lidar_cone_angle": float(nominal.cone_angle),
        "lidar_hybrid_weight": float(nominal.hybrid_weight),
        "lidar_rwf_fwhm": fwhm,
        "lidar_los_noise_std": float(nominal.los_noise_std),
        "lidar_beam_period": float(nominal.beam_period),
        "lidarcal_hidden_effect": json.dumps({"effect": eff.id, "parameters": params}),
        "comment": ("Synthetic field campaign for testing lidarcal diagnose: simulated with one hidden "
                    "catalogue effect; lidar_* attributes describe the nominal (uncorrected) lidar."),
    }
    return stamp(
        out, "field_campaign",
        title=f"Synthetic field campaign with hidden effect {eff.id}",
        summary="Simulated lidar/reference pair with one catalogue effect switched on, for diagnose tests.",
        call=call or f"lidarcal.diagnose.generate_field_campaign(conditions, {eff.id!r}, {params!r})",
        input_datasets={"conditions": conditions},
        config={"effect": eff.id, "parameters": params, "nominal_model": nominal.to_dict()},
        seeds={"base_seed": int(base_seed)},
    )


def _rwf_fwhm(model: Any) -> float:
    """FWHM (m) of the Gaussian RWF with the same second moment as the model's quadrature."""
    x = np.asarray(model.rwf_offsets, dtype=float)
    w = np.asarray(model.rwf_weights, dtype=float)
    mean = np.sum(w * x) / np.sum(w)
    sigma = np.sqrt(np.sum(w * (x - mean) ** 2) / np.sum(w))
    return float(round(2.0 * np.sqrt(2.0 * np.log(2.0)) * sigma, 9))
