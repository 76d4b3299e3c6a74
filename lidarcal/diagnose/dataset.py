"""The ``diagnosis`` artefact and the ``--json`` summary built from a :class:`DiagnosisResult`.

Layout (``schemas/diagnosis.yaml``): dims ``height``, ``variable`` (the six environmental
variables the residual is binned by), ``bin`` (quantile bins), ``candidate`` (catalogue ids).
Per-variable bin limits live in ``<variable>_bin_lower/upper`` (each in its own unit); the
fitted parameter of each candidate in ``fit_<effect>_<parameter>`` (+ ``_stderr``, ``_nominal`` and
the 95 % block-bootstrap interval ``_lower``/``_upper``); ``candidate_selected`` gives the order in
which forward selection named the candidates (0: not named) and ``candidate_minor`` flags the
strong candidates that are not named (the ``minor`` list: their ``fit_*`` values are that list's).
The corrected model is the ``lidarcal_lidar_model`` global attribute (the same attribute a
``simulated_rtd`` carries), so ``LidarModel.from_dict(ds.attrs["lidarcal_lidar_model"])`` or
:func:`corrected_model` rebuilds it; the ``--json`` object is in ``diagnosis_json``.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.sensitivity import sensitivity
from lidarcal.cf import height_coord
from lidarcal.conditions.variables import CONDITION_NAMES, variable_attrs
from lidarcal.diagnose.core import DiagnosisResult
from lidarcal.diagnose.effects import EFFECTS
from lidarcal.diagnose.stats import GAP_METRIC
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, source_name
from lidarcal.lidar import LidarModel
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs

__all__ = ["summary", "to_dataset", "corrected_model", "records_dataset", "sensitivity_statistics"]


def _num(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _effect_entry(c) -> dict[str, Any]:
    """One element of ``effects`` (docs/diagnose.md)."""
    return {
        "effect": c.effect.id,
        "parameters": {k: _num(v) for k, v in c.estimate.items()},
        "uncertainties": {k: _num(v) for k, v in c.stderr.items()},
        "intervals": {k: [_num(lo), _num(hi)] for k, (lo, hi) in c.interval.items()},
        "units": {p.name: p.units for p in c.effect.parameters},
        "change": _num(c.contribution),
        "tied": list(c.tied),
    }


def _minor_entry(c) -> dict[str, Any]:
    """One element of ``minor``: a strong candidate that is not named, and why (docs/diagnose.md)."""
    entry = _effect_entry(c)
    del entry["tied"]
    return {**entry, "score": _num(c.minor_score), "reason": c.minor}


def summary(result: DiagnosisResult) -> dict[str, Any]:
    """Return the ``--json`` object of ``docs/diagnose.md`` (listed keys exact; a few documented extras).

    ``effect`` is ``effects[0]`` (or ``none`` / ``unexplained``); ``parameters``,
    ``uncertainties`` (block-bootstrap standard errors), ``intervals`` (95 %) and ``units``
    are those of ``effects[0]``.  ``drivers`` lists where the residual lies
    (``{"variable", "range", "units", "z"}``).  ``score`` of a candidate is its ΔBIC against
    ``none`` fitted alone (lower is better; ``none`` is 0).  ``minor`` lists the strong candidates
    that are not named, with their estimates, intervals, change, ``score`` (ΔBIC alone, or given
    the named effects) and ``reason``.
    """
    effects = [_effect_entry(c) for c in result.selected]
    first = effects[0] if effects else {"parameters": {}, "uncertainties": {}, "intervals": {}, "units": {}}
    cands = [{"effect": "none", "score": 0.0}] + [
        {"effect": c.effect.id, "score": _num(c.delta_bic)} for c in result.candidates]
    cands.sort(key=lambda c: (c["score"] if c["score"] is not None else math.inf))
    heights = [float(h) for h in result.heights]
    out = {
        "effect": result.effect_id,
        "parameters": first["parameters"],
        "uncertainties": first["uncertainties"],
        "intervals": first["intervals"],
        "units": first["units"],
        "effects": effects,
        "drivers": [dict(d) for d in result.drivers],
        "tied": list(result.tied),
        "gap_before": _num(result.gap_before[0]),
        "gap_after": _num(result.gap_after[0]),
        "gap_metric": GAP_METRIC,
        "gap_noise_floor": _num(result.gap_before[2]),
        "tolerance": _num(result.tolerance),
        "candidates": cands,
        "significant": bool(result.significant),
        "p_adjusted_min": _num(result.p_min),
        "minor": [_minor_entry(c) for c in result.minor],
        "note": result.note,
        "gap_before_by_height": dict(zip(map(str, heights), map(_num, result.gap_before[1]), strict=True)),
        "gap_after_by_height": dict(zip(map(str, heights), map(_num, result.gap_after[1]), strict=True)),
    }
    return out


def records_dataset(result: DiagnosisResult, which: str) -> xr.Dataset:
    """Return records (``measured``, ``before``, ``after``) as a Dataset for the analysis stage.

    The lidar speed is rebuilt from the relative difference on the measured reference, so all
    three share the reference and the usable-period mask.
    """
    d = {"measured": result.d_measured, "before": result.d_before, "after": result.d_after}[which]
    ref = np.asarray(result.field_dataset["reference_wind_speed"].transpose("time", "height").values, float)
    ref = np.where(result.valid, ref, np.nan)
    dims = ("time", "height")
    ds = xr.Dataset(coords={"time": result.times, "height": height_coord(result.heights)})
    ds["lidar_wind_speed"] = (dims, ref * (1.0 + d), variable_attrs("lidar_wind_speed"))
    ds["reference_wind_speed"] = (dims, ref, variable_attrs("reference_wind_speed"))
    for name in CONDITION_NAMES:
        ds[name] = (dims, np.where(result.valid, result.conditions[name], np.nan), variable_attrs(name))
    ds.attrs["lidarcal_artefact"] = "field_campaign" if which == "measured" else "simulated_rtd"
    return ds


def sensitivity_statistics(result: DiagnosisResult) -> dict[str, np.ndarray]:
    """Eq. 12 statistic m·std (%) per (variable, height): measured, simulated before and after.

    Computed by :func:`lidarcal.analysis.sensitivity` on the diagnosis' own quantile bins.
    """
    out = {}
    nv, nh = len(CONDITION_NAMES), len(result.heights)
    for which in ("measured", "before", "after"):
        recs = records_dataset(result, which)
        vals = np.full((nv, nh), np.nan)
        for i, name in enumerate(CONDITION_NAMES):
            edges = result.binned_before.edges[i]
            edges = edges[np.isfinite(edges)]
            try:
                sens = sensitivity(recs, name, bins=edges, min_periods=result.settings["min_bin_count"],
                                   reference_range=None, source=result.source)
            except InputError:
                continue  # a variable without two populated bins has no slope
            vals[i] = sens["slope_times_std"].values
        out[which] = vals
    return out


def to_dataset(result: DiagnosisResult, *, call: str = "lidarcal.diagnose.diagnose(field)",
               inputs: dict | None = None, input_datasets: dict | None = None,
               with_sensitivity: bool = True) -> xr.Dataset:
    """Build the ``diagnosis`` artefact (stamped with provenance); attributes from its schema."""
    b0, b1 = result.binned_before, result.binned_after
    nb = b0.count.shape[1]
    vbh, vh = ("variable", "bin", "height"), ("variable", "height")
    pct = 100.0
    valid_r0 = np.where(result.valid, result.d_measured - result.d_before, np.nan)
    valid_r1 = np.where(result.valid, result.d_measured - result.d_after, np.nan)
    ds = xr.Dataset(coords={
        "height": height_coord(result.heights),
        "variable": ("variable", list(b0.variables), output_attrs("diagnosis", "variable")),
        "bin": ("bin", np.arange(nb, dtype=np.int32), output_attrs("diagnosis", "bin")),
        "candidate": ("candidate", ["none"] + [c.effect.id for c in result.candidates],
                      output_attrs("diagnosis", "candidate")),
    })

    def put(name: str, dims, values, **context) -> None:
        ds[name] = (dims, values, output_attrs("diagnosis", name, gap_metric=GAP_METRIC, **context))

    put("gap_before", "height", result.gap_before[1])
    put("gap_after", "height", result.gap_after[1])
    put("gap_before_overall", (), result.gap_before[0])
    put("gap_after_overall", (), result.gap_after[0])
    put("gap_noise_floor", (), result.gap_before[2])
    put("mean_residual_before", "height", pct * np.nanmean(valid_r0, axis=0))
    put("mean_residual_after", "height", pct * np.nanmean(valid_r1, axis=0))
    put("usable_periods", "height", result.valid.sum(axis=0).astype(np.int32))
    put("binned_residual_before", vbh, pct * b0.mean)
    put("binned_residual_before_stderr", vbh, pct * b0.se)
    put("binned_residual_after", vbh, pct * b1.mean)
    put("binned_residual_after_stderr", vbh, pct * b1.se)
    put("bin_count", vbh, b0.count.astype(np.int32))
    for i, name in enumerate(b0.variables):
        e = b0.edges[i]
        lower, upper = np.full(nb, np.nan), np.full(nb, np.nan)
        k = int(np.isfinite(e).sum()) - 1
        lower[:k], upper[:k] = e[:k], e[1:k + 1]
        label = name.replace("_", " ")
        put(f"{name}_bin_lower", "bin", lower, label=label)
        put(f"{name}_bin_upper", "bin", upper, label=label)
        put(f"{name}_bin_mean", ("bin", "height"), b0.center[i], label=label)
    put("disagreement_chi2", vh, result.tests["chi2"])
    put("disagreement_dof", vh, result.tests["dof"].astype(np.int32))
    put("disagreement_p_adjusted", vh, result.tests["p_adjusted"])
    put("mean_residual_p_adjusted", "height", result.tests["mean_p_adjusted"])
    put("candidate_score", "candidate", np.asarray([0.0] + [c.delta_bic for c in result.candidates], float))
    put("candidate_explained_fraction", "candidate",
        np.asarray([0.0] + [c.explained for c in result.candidates], float))
    rank = {c.effect.id: i + 1 for i, c in enumerate(result.selected)}
    put("candidate_selected", "candidate",
        np.asarray([0] + [rank.get(c.effect.id, 0) for c in result.candidates], np.int32))
    minor = {c.effect.id for c in result.minor}
    put("candidate_minor", "candidate",
        np.asarray([0] + [int(c.effect.id in minor) for c in result.candidates], np.int8))
    for c in result.candidates:
        for p in c.effect.parameters:
            base = f"fit_{c.effect.id}_{p.name}"  # long names and units: the schema's, per catalogue row
            lo, hi = c.interval.get(p.name, (np.nan, np.nan))
            put(base, (), c.estimate[p.name])
            put(f"{base}_stderr", (), c.stderr[p.name])
            put(f"{base}_nominal", (), c.nominal[p.name])
            put(f"{base}_lower", (), lo)
            put(f"{base}_upper", (), hi)
    if with_sensitivity:
        sens = sensitivity_statistics(result)
        for key, side in (("measured", "field records"), ("before", "nominal model"),
                          ("after", "corrected model")):
            put(f"sensitivity_{key}", vh, sens[key], side=side)
    return _stamped(ds, result, call=call, inputs=inputs, input_datasets=input_datasets)


def _stamped(ds: xr.Dataset, result: DiagnosisResult, *, call: str, inputs: dict | None,
             input_datasets: dict | None) -> xr.Dataset:
    """``ds`` with the diagnosis' global attributes (the answer, its JSON, both models), stamped."""
    js = summary(result)
    ds.attrs = {
        "diagnosis_effect": result.effect_id,
        "diagnosis_note": result.note,
        "diagnosis_json": json.dumps(js, sort_keys=False),
        "gap_metric": GAP_METRIC,
        "diagnosis_effects": " ".join(c.effect.id for c in result.selected) or result.effect_id,
        "diagnosis_tolerance": float(result.tolerance),
        "diagnosis_design_effect": float(result.design_effect),
        "nominal_lidar_model": result.nominal_model.to_json(),
        "lidarcal_lidar_model": result.corrected_model.to_json(),
        "lidarcal_base_seed": int(result.settings["base_seed"]),
        "field_source": str(result.source),
    }
    return stamp(
        ds, "diagnosis",
        title=f"Model-discrepancy diagnosis: {result.effect_id}",
        summary=("Residual between a field campaign and the lidarcal Monte Carlo model, binned by height and "
                 "environmental variables, catalogue effects fitted with common random numbers and ranked "
                 "by BIC; the corrected lidar model is in lidarcal_lidar_model."),
        call=call, inputs=inputs, input_datasets=input_datasets,
        config={**result.settings, "catalogue": sorted(EFFECTS)},
        seeds={"base_seed": int(result.settings["base_seed"])},
    )


def corrected_model(diagnosis: xr.Dataset | str | os.PathLike, *, cube: xr.Dataset | None = None,
                    rwf: xr.Dataset | None = None):
    """Return the corrected :class:`~lidarcal.lidar.LidarModel` of a diagnosis artefact (or path).

    Any artefact with a ``lidarcal_lidar_model`` attribute works (a ``simulated_rtd`` too);
    ``lidarcal simulate --model DIAGNOSIS.nc`` uses this.  The attribute records the bench noise
    table, the residuals and the RWF profile only by digest: ``cube`` and ``rwf`` (the bench cube
    and RWF the model was built from) restore them (:meth:`~lidarcal.lidar.LidarModel.from_dict`).
    """
    ds = diagnosis if isinstance(diagnosis, xr.Dataset) else open_artefact(diagnosis, load=False, chunks={})
    name = source_name(diagnosis)
    record = read_attr(ds, "lidarcal_lidar_model", source=os.fspath(name))
    if not isinstance(diagnosis, xr.Dataset):
        ds.close()
    if not record:
        raise InputError(f"{os.fspath(name)}: global attribute 'lidarcal_lidar_model' is missing; expected "
                         f"the JSON of a LidarModel (a diagnosis or simulated_rtd artefact)")
    return LidarModel.from_dict(record, cube=cube, rwf=rwf,
                                source=f"{os.fspath(name)}: global attribute 'lidarcal_lidar_model'")
