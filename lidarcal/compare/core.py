"""The paper's validation on a user's own campaign: measured beside simulated (``lidarcal compare``).

:func:`compare` takes a ``field_campaign`` (measured lidar/reference pair + conditions) and

1. builds the lidar to simulate — the nominal lidar of the file's ``lidar_*`` attributes, the
   bench-calibrated one (``cube``/``rwf``) or a diagnosis's corrected model (``diagnosis``) —
   and simulates the campaign's own conditions with it, with the campaign seed scheme of
   ``docs/seeds.md`` (the same base seed gives the same records as ``lidarcal diagnose``'s
   nominal simulation);
2. selects the periods once: usable conditions, both pairs finite, the *measured* reference in
   the IEC range (4–16 m s-1 by default); both sides use exactly these periods;
3. per environmental variable and height, the IEC 61400-50-2 sensitivity
   (:func:`lidarcal.analysis.sensitivity`, Eqs. 12–13) of the measured pair and of the
   simulated pair, with the measured side's bins, the same regression and minimum per bin;
   the slope difference, its combined standard error, ``z`` and its normal p-value,
   Holm-adjusted over every tested cell: a cell
   agrees when its adjusted p-value is at least ``alpha``;
4. the uncertainty budgets per height and 0.5 m s-1 bin (:func:`lidarcal.analysis.budget`):
   the IEC field approach on the measured pair, the Monte Carlo approach on the simulated pair
   (the paper's Figure 9).

The result is a ``comparison`` artefact (:mod:`.dataset`); ``docs/compare.md`` documents the
method and the ``--json`` object.
"""

from __future__ import annotations

import logging
import os
import shlex
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import xarray as xr
from scipy import stats as st

from lidarcal.analysis.budget import DEFAULT_MIN_PERIODS, budget
from lidarcal.analysis.sensitivity import (
    DEFAULT_REFERENCE_RANGE,
    REGRESSIONS,
    sensitivity,
)
from lidarcal.campaign import DEFAULT_BASE_SEED, simulate_campaign
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import load_conditions
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.diagnose.dataset import corrected_model
from lidarcal.diagnose.inputs import MEASURED, open_field
from lidarcal.diagnose.stats import holm
from lidarcal.errors import InputError
from lidarcal.io import source_name
from lidarcal.lidar import LidarModel
from lidarcal.lidar.geometry import check_reachable
from lidarcal.lidar.model import RwfProfileDigest
from lidarcal.units import to_magnitude

__all__ = [
    "compare",
    "Comparison",
    "DEFAULT_VARIABLES",
    "VARIABLES",
    "DEFAULT_ALPHA",
    "DEFAULT_REFERENCE_UNCERTAINTY",
    "CORRECTION",
    "slope_test",
    "lidar_to_simulate",
]

log = logging.getLogger("lidarcal.compare")

#: Environmental variables compared by default: those of the paper's Figure 8 that a lidar's
#: measurement model must reproduce (shear through the probe volume and the zero distance,
#: turbulence through the scalar/vector averaging and the cup, the CNR gradient through Eq. 2).
DEFAULT_VARIABLES = ("wind_shear_exponent", "turbulence_intensity", "cnr_gradient")
#: Variables a comparison may use: every conditions variable with a linear sensitivity (a slope
#: against the wind direction, a circular variable, has no meaning).
VARIABLES = tuple(n for n in CONDITION_NAMES if n != "wind_from_direction")
#: Family-wise false-alarm rate of the slope comparison.
DEFAULT_ALPHA = 0.05
#: Standard uncertainty of the reference anemometer in the IEC field budget (m s-1).
DEFAULT_REFERENCE_UNCERTAINTY = 0.1
#: How the family of cells (height x variable) is corrected, recorded in the artefact.
CORRECTION = "holm"


class Comparison(dict):
    """What :func:`compare` computed before it is written (:func:`lidarcal.compare.dataset.to_dataset`).

    A plain mapping: ``field`` (the checked campaign), ``measured`` and ``simulated``
    (records on the same periods), ``sensitivity`` ({side: {variable: artefact or None}}),
    ``budget`` ({side: artefact}), ``cells`` (arrays on (variable, height)), ``model``,
    ``model_origin``, ``settings``, ``source`` and ``next`` (the diagnose command).
    """


def slope_test(slope_a, se_a, slope_b, se_b) -> dict[str, np.ndarray]:
    """Two-sided z-test that two independent slopes are equal.

    ``d = a − b``, ``se = sqrt(se_a² + se_b²)``, ``z = d / se``, ``p = 2 Φ(−|z|)``.  A sensitivity
    slope's standard error is the larger of its weights' own scale and the Birge-inflated one
    (:func:`lidarcal.analysis.kernels.weighted_linear_regression`), so ``|z|`` is at most the
    known-variance statistic and the normal reference holds (``docs/compare.md`` gives its
    calibration with bin variances estimated from 10 periods).  NaN where either slope or its
    standard error is missing.
    """
    a, sa, b, sb = (np.asarray(x, dtype=float) for x in (slope_a, se_a, slope_b, se_b))
    with np.errstate(invalid="ignore", divide="ignore"):
        diff = a - b
        se = np.hypot(sa, sb)
        z = diff / se
        ok = np.isfinite(z) & (se > 0)
        p = np.where(ok, 2.0 * st.norm.sf(np.abs(np.where(ok, z, 0.0))), np.nan)
    nan = np.where(ok, 0.0, np.nan)
    return {"difference": diff + nan, "stderr": se + nan, "z": z + nan, "p_value": p}


def _load(field: str | os.PathLike | xr.Dataset, min_periods: int) -> tuple[xr.Dataset, np.ndarray, str]:
    """Open and check a field campaign; return (dataset, usable mask (time, height), source)."""
    raw, source = open_field(field)
    ds = load_conditions(raw, kind="field_campaign", warn=False)
    usable = np.asarray(ds["input_complete"].transpose("time", "height").values, dtype=bool)
    for name in MEASURED:
        usable &= np.isfinite(np.asarray(ds[name].transpose("time", "height").values, dtype=float))
    need = 3 * int(min_periods)
    if usable.sum(axis=0).max(initial=0) < need:
        raise InputError(
            f"{source}: too few usable periods: at most {int(usable.sum(axis=0).max(initial=0))} per height "
            f"have the measured pair and all six conditions; a slope needs three bins of at least "
            f"{min_periods} periods ({need} periods at one height at least)"
        )
    return ds, usable, source


def lidar_to_simulate(ds: xr.Dataset, source: str, *, cube, rwf, model, diagnosis,
                      los_noise_model) -> tuple[Any, str]:
    """Return the lidar to simulate (``compare``'s arguments) and a description of where it came from."""
    if diagnosis is not None:
        found = corrected_model(diagnosis, cube=cube) if model is None else None
        # an rwf only restores the RWF profile the diagnosis records by digest (checked against it)
        if model is not None or (rwf is not None and not isinstance(found.rwf_profile, RwfProfileDigest)):
            raise InputError(
                "give either a diagnosis (its corrected model) or the lidar's rwf/model, not both"
            )
        name = source_name(diagnosis, "<diagnosis>")
        if rwf is not None:
            found = found.with_rwf(rwf)
        return found, f"corrected model of the diagnosis {os.path.basename(name)}"
    if model is not None:
        return model, "the model given"
    if cube is not None or rwf is not None:
        parts = [w for w, x in (("bench cube", cube), ("rwf", rwf)) if x is not None]
        return LidarModel.from_attrs(
            ds, cube=cube, rwf=rwf, source=source, los_noise_model=los_noise_model
        ), (
            f"bench-calibrated lidar ({' and '.join(parts)}; the field file's lidar_* attributes "
            "for the rest)"
        )
    return LidarModel.from_attrs(ds, source=source, los_noise_model=los_noise_model), (
        "nominal lidar of the field file's lidar_* attributes"
    )


def _records(
    ds: xr.Dataset, lidar: np.ndarray, reference: np.ndarray, keep: np.ndarray, kind: str, source: str
) -> xr.Dataset:
    """Return records for the analysis stage: the conditions and one pair, NaN outside ``keep``."""
    out = ds[list(CONDITION_NAMES)].copy()
    for name, values in (("lidar_wind_speed", lidar), ("reference_wind_speed", reference)):
        out[name] = (("time", "height"), np.where(keep, values, np.nan), dict(ds[name].attrs))
    out.attrs = {"lidarcal_artefact": kind, "lidarcal_source_file": source}
    return out


def _pair(ds: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    return tuple(np.asarray(ds[n].transpose("time", "height").values, dtype=float) for n in MEASURED)


def _edges(sens: xr.Dataset) -> np.ndarray:
    b = np.asarray(sens["bin_bounds"].values, dtype=float)
    return np.append(b[:, 0], b[-1, 1])


def compare(
    field: str | os.PathLike | xr.Dataset,
    *,
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
    model: Any = None,
    diagnosis: str | os.PathLike | xr.Dataset | None = None,
    variables: Sequence[str] = DEFAULT_VARIABLES,
    alpha: float = DEFAULT_ALPHA,
    reference_uncertainty: Any = DEFAULT_REFERENCE_UNCERTAINTY,
    base_seed: int = DEFAULT_BASE_SEED,
    min_periods: int = DEFAULT_MIN_PERIODS,
    regression: str = "weighted",
    bin_widths: Mapping[str, Any] | None = None,
    reference_range: tuple[float, float] = DEFAULT_REFERENCE_RANGE,
    budget_bin_width: Any = "0.5 m s-1",
    terms: xr.Dataset | None = None,
    los_noise_model: str | None = None,
    execution: Execution | Mapping[str, Any] | None = None,
    inputs: Mapping[str, str | os.PathLike] | None = None,
) -> Comparison:
    """Compare a field campaign with the virtual lidar simulated in its own conditions.

    Parameters
    ----------
    field : path or xarray.Dataset
        A ``field_campaign`` (``docs/contracts.md``).
    cube, rwf : xarray.Dataset, optional
        Bench cube / RWF artefacts: simulate the bench-calibrated lidar (else the file's
        ``lidar_*`` attributes).  With ``diagnosis``, ``cube`` restores the bench residuals of
        the corrected model.
    model : LidarModel, optional
        Simulate this lidar instead.
    diagnosis : path or xarray.Dataset, optional
        A ``diagnosis`` artefact: simulate its corrected model (``lidarcal_lidar_model``).
    variables : sequence of str
        Environmental variables to compare (:data:`VARIABLES`; default :data:`DEFAULT_VARIABLES`).
    alpha : float
        Family-wise false-alarm rate of the slope comparison (Holm over every tested cell).
    reference_uncertainty : quantity, str or float
        Standard uncertainty of the reference anemometer in the IEC budget (a float is m s-1).
    base_seed : int
        Base seed of the simulation (``docs/seeds.md``).
    min_periods, regression, bin_widths
        Of the sensitivities (:func:`lidarcal.analysis.sensitivity`); the same on both sides.
        ``bin_widths`` maps a variable to its bin width (default the IEC widths).
    reference_range : (float, float)
        Measured reference speeds (m s-1) of the periods used in the sensitivities.
    budget_bin_width : quantity or str
        Wind-speed bin of the budgets (0.5 m s-1).
    terms : xarray.Dataset, optional
        ``uncertainty_terms`` artefact for the Monte Carlo budget (default: the paper's inputs).
    los_noise_model : {None, "mixture", "residuals", "gaussian"}
        LOS error model of the bench-calibrated lidar (:meth:`lidarcal.lidar.LidarModel.from_attrs`).
    execution : Execution or mapping, optional
        Where and how the simulation runs (:class:`~lidarcal.campaign.settings.Execution`:
        ``chunk``, ``scheduler``, ``workers``, ``progress`` ...; a mapping of these fields).
    inputs : mapping of role to path, optional
        The files behind ``field``/``cube``/``rwf``/``diagnosis``: recorded with their checksums,
        and used to write the ``lidarcal diagnose`` command of ``next``.
    """
    variables, u_ref, (lo, hi) = _checked(variables, regression, alpha, min_periods, reference_uncertainty,
                                          reference_range)

    # 1. the campaign and the lidar to simulate
    ds, usable, source = _load(field, int(min_periods))
    sim_model, origin = lidar_to_simulate(
        ds, source, cube=cube, rwf=rwf, model=model, diagnosis=diagnosis, los_noise_model=los_noise_model
    )
    problems = check_reachable(sim_model, ds.height.values)
    if problems:
        raise InputError(
            f"{source}: variable 'height': heights the lidar cannot measure with this RWF and "
            f"geometry: " + "; ".join(problems)
        )
    cond = ds[list(CONDITION_NAMES)].copy()
    cond.attrs = {"lidarcal_source_file": os.path.basename(source)}
    log.info(f"simulating {ds.sizes['time']} periods x {ds.sizes['height']} heights with the {origin}")
    execution = Execution.of(execution)
    sim = simulate_campaign(cond, sim_model, base_seed=int(base_seed), execution=execution)
    sim = sim.transpose("time", "height")

    # 2. the same periods on both sides
    lid_m, ref_m = _pair(ds)
    lid_s, ref_s = _pair(sim)
    keep = usable & np.isfinite(lid_s) & np.isfinite(ref_s) & (ref_m > lo) & (ref_m <= hi)
    measured = _records(ds, lid_m, ref_m, keep, "field_campaign", source)
    simulated = _records(ds, lid_s, ref_s, keep, "simulated_rtd", source)
    log.info(f"{int(keep.sum())} period-heights with the measured reference in ({lo:g}, {hi:g}] m s-1")

    # 3. sensitivities on the same bins, and the cell tests
    opts = {"min_periods": int(min_periods), "regression": regression, "reference_range": None,
            "source": source}
    sens = _sensitivities(measured, simulated, variables, bin_widths, opts)
    cells = _cells(sens, variables, ds.sizes["height"], float(alpha))

    # 4. the budgets (Figure 9)
    common = {"bin_width": budget_bin_width, "source": source}
    budgets = {
        "measured": budget(measured, approach="iec", reference_uncertainty=f"{u_ref!r} m s-1", **common),
        "simulated": budget(simulated, approach="monte_carlo", terms=terms, **common),
    }

    verdict = _verdict(cells, variables, ds.height.values, source, int(min_periods), float(alpha), (lo, hi))
    settings = {
        "base_seed": int(base_seed),
        "alpha": float(alpha),
        "correction": CORRECTION,
        "variables": variables,
        "min_periods": int(min_periods),
        "regression": regression,
        "bin_widths": {
            v: (None if (bin_widths or {}).get(v) is None else str(bin_widths[v])) for v in variables
        },
        "reference_range_m_s-1": [lo, hi],
        "reference_uncertainty_m_s-1": u_ref,
        "budget_bin_width": str(budget_bin_width),
        "simulate_options": execution.record(where=False),
    }
    return Comparison(
        field=ds,
        measured=measured,
        simulated=simulated,
        sensitivity=sens,
        budget=budgets,
        cells=cells,
        model=sim_model,
        model_origin=origin,
        settings=settings,
        source=source,
        verdict=verdict,
        keep=keep,
        next=None if verdict == "agree" else diagnose_command(source, inputs, int(base_seed)),
    )


def _checked(variables: Sequence[str], regression: str, alpha: float, min_periods: int,
             reference_uncertainty: Any, reference_range: tuple[float, float]
             ) -> tuple[list[str], float, tuple[float, float]]:
    """Check :func:`compare`'s arguments; return the variables (once each), u_ref (m s-1) and the range."""
    bad = [v for v in variables if v not in VARIABLES]
    if bad or not variables:
        raise InputError(f"argument 'variables': expected some of {list(VARIABLES)}; found {list(variables)}")
    if regression not in REGRESSIONS:
        raise InputError(
            f"argument 'regression': expected one of {sorted(REGRESSIONS)}; found {regression!r}"
        )
    if not 0.0 < float(alpha) < 1.0:
        raise InputError(f"argument 'alpha': expected a probability in (0, 1); found {alpha!r}")
    if int(min_periods) < 2:
        raise InputError(f"argument 'min_periods': expected at least 2 (a bin's spread); found {min_periods}")
    u_ref = float(
        to_magnitude(reference_uncertainty, "m s-1", name="reference_uncertainty")
        if not isinstance(reference_uncertainty, int | float)
        else reference_uncertainty
    )
    if not (np.isfinite(u_ref) and u_ref >= 0):
        raise InputError(
            f"argument 'reference_uncertainty': expected >= 0 m s-1; found {reference_uncertainty!r}"
        )
    lo, hi = (float(x) for x in reference_range)
    return list(dict.fromkeys(variables)), u_ref, (lo, hi)


def _sensitivities(measured: xr.Dataset, simulated: xr.Dataset, variables: Sequence[str],
                   bin_widths: Mapping[str, Any] | None, opts: Mapping[str, Any]
                   ) -> dict[str, dict[str, xr.Dataset | None]]:
    """Sensitivity artefacts of both sides per variable, the simulated side on the measured side's bins.

    None where a side has no height with two populated bins (no slope: the cells are untested).
    """
    sens: dict[str, dict[str, xr.Dataset | None]] = {"measured": {}, "simulated": {}}
    for v in variables:
        width = (bin_widths or {}).get(v)
        try:
            sm = sensitivity(measured, v, bin_width=width, **opts)
        except InputError as exc:  # no height with two populated bins: no slope, the cells are untested
            log.warning(f"{v}: no measured slope ({exc})")
            sens["measured"][v] = sens["simulated"][v] = None
            continue
        sens["measured"][v] = sm
        try:
            sens["simulated"][v] = sensitivity(simulated, v, bins=_edges(sm), **opts)
        except InputError as exc:
            log.warning(f"{v}: no simulated slope ({exc})")
            sens["simulated"][v] = None
    return sens


def _verdict(cells: Mapping[str, np.ndarray], variables: Sequence[str], heights: np.ndarray, source: str,
             min_periods: int, alpha: float, reference_range: tuple[float, float]) -> str:
    """Return ``agree`` or ``disagree``; refuse a comparison without one tested cell; log the untested."""
    lo, hi = reference_range
    tested = np.isfinite(cells["p_adjusted"])
    if not tested.any():
        raise InputError(
            f"{source}: no (height, variable) has three bins with at least {min_periods} periods on both "
            f"sides, so no slope can be compared (variables {variables}, measured reference in "
            f"({lo:g}, {hi:g}] m s-1); supply more periods or lower min_periods (--min-periods)"
        )
    if not tested.all():
        skipped = [
            f"{v} at {h:g} m"
            for i, v in enumerate(variables)
            for j, h in enumerate(heights)
            if not tested[i, j]
        ]
        log.warning(f"not tested (fewer than three bins of {min_periods} periods): {', '.join(skipped)}")
    disagree = int((cells["agree"] == 0).sum())
    verdict = "disagree" if disagree else "agree"
    log.info(
        f"verdict: {verdict} ({disagree} of {int(tested.sum())} cells disagree at alpha {alpha:g}, Holm)"
    )
    return verdict


def _cells(
    sens: Mapping[str, Mapping[str, xr.Dataset | None]],
    variables: Sequence[str],
    n_heights: int,
    alpha: float,
) -> dict[str, np.ndarray]:
    """Per (variable, height): both sides' slopes and Eq. 12-13 statistics, the test and the flag."""
    names = (
        "slope",
        "slope_standard_error",
        "bins_used",
        "slope_times_std",
        "slope_times_std_times_r",
        "correlation",
        "significant_eq12",
        "significant_eq13",
    )
    out: dict[str, np.ndarray] = {}
    for side in ("measured", "simulated"):
        for name in names:
            arr = np.full((len(variables), n_heights), np.nan)
            for i, v in enumerate(variables):
                s = sens[side][v]
                if s is not None:
                    arr[i] = np.asarray(s[name].transpose("height").values, dtype=float)
            out[f"{side}_{name}"] = arr
    test = slope_test(
        out["measured_slope"],
        out["measured_slope_standard_error"],
        out["simulated_slope"],
        out["simulated_slope_standard_error"],
    )
    out.update(test)
    out["p_adjusted"] = holm(test["p_value"])
    out["agree"] = np.where(
        np.isfinite(out["p_adjusted"]), (out["p_adjusted"] >= alpha).astype(np.int8), 2
    ).astype(np.int8)
    return out


def diagnose_command(source: str, inputs: Mapping[str, str | os.PathLike] | None, base_seed: int) -> str:
    """Return the ``lidarcal diagnose`` command to run next on this campaign (``next`` of the JSON)."""
    inputs = dict(inputs or {})
    field = os.fspath(inputs.get("field", source))
    stem = os.path.splitext(os.path.basename(field))[0] or "field"
    argv = ["lidarcal", "diagnose", field]
    for role in ("cube", "rwf"):
        if role in inputs:
            argv += [f"--{role}", os.fspath(inputs[role])]
    if base_seed != DEFAULT_BASE_SEED:
        argv += ["--seed", str(base_seed)]
    argv += ["-o", f"{stem}-diagnosis.nc", "--json"]
    return shlex.join(argv)
