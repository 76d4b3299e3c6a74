"""The ``comparison`` artefact and the ``--json`` object of ``lidarcal compare`` (``docs/compare.md``).

Layout (``schemas/comparison.yaml``): dims ``variable`` (the environmental variables compared),
``height``, ``wind_speed`` (the budgets' 0.5 m s-1 reference bins, CF bounds) and one contributor
dim per budget approach.  A slope has the units of "% per unit of its variable", so each
variable's slopes are their own CF variables (``<variable>_measured_slope``, ``..._stderr``,
``<variable>_simulated_slope``, ``<variable>_slope_difference`` ...); everything dimensionless
(z, p-values, the ``agree`` flag, the Eq. 12–13 statistics in %) is on (variable, height).
The measured side's budget is the IEC field approach, the simulated side's the Monte Carlo one.
The JSON object is also stored in the ``comparison_json`` attribute; the simulated lidar is
``lidarcal_lidar_model``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.sensitivity import per_unit
from lidarcal.cf import height_coord, with_bounds
from lidarcal.compare.core import CORRECTION, Comparison
from lidarcal.conditions.variables import CANONICAL_UNITS
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs

__all__ = ["to_dataset", "summary", "slope_units"]


def slope_units(variable: str) -> str:
    """Units of a sensitivity slope of the relative difference (%) against ``variable``."""
    return per_unit("%", CANONICAL_UNITS[variable])


def _num(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def to_dataset(
    result: Comparison,
    *,
    call: str = "lidarcal.compare.compare(field)",
    inputs: Mapping[str, Any] | None = None,
) -> xr.Dataset:
    """Build the ``comparison`` artefact (stamped with provenance) from :func:`lidarcal.compare.compare`."""
    cells = result["cells"]
    variables = list(result["settings"]["variables"])
    heights = result["field"].height.values
    vh = ("variable", "height")
    ds = xr.Dataset(coords={
        "variable": ("variable", np.array(variables, dtype=object), output_attrs("comparison", "variable")),
        "height": height_coord(heights),
    })

    def put(name: str, dims, values, **context) -> None:
        ds[name] = (dims, values, output_attrs("comparison", name, **context))

    for i, v in enumerate(variables):
        label = v.replace("_", " ")
        for side in ("measured", "simulated"):
            put(f"{v}_{side}_slope", "height", cells[f"{side}_slope"][i], label=label)
            put(f"{v}_{side}_slope_stderr", "height", cells[f"{side}_slope_standard_error"][i], label=label)
        put(f"{v}_slope_difference", "height", cells["difference"][i], label=label)
        put(f"{v}_slope_difference_stderr", "height", cells["stderr"][i], label=label)
    for side in ("measured", "simulated"):
        put(f"{side}_bins_used", vh, np.nan_to_num(cells[f"{side}_bins_used"]).astype(np.int32))
        put(f"{side}_correlation", vh, cells[f"{side}_correlation"])
        put(f"{side}_slope_times_std", vh, cells[f"{side}_slope_times_std"])
        put(f"{side}_slope_times_std_times_r", vh, cells[f"{side}_slope_times_std_times_r"])
        for eq in ("eq12", "eq13"):
            flag = np.nan_to_num(cells[f"{side}_significant_{eq}"]).astype(np.int8)
            put(f"{side}_significant_{eq}", vh, flag)
    put("slope_z", vh, cells["z"])
    put("slope_p_value", vh, cells["p_value"])
    put("slope_p_adjusted", vh, cells["p_adjusted"])
    put("agree", vh, cells["agree"].astype(np.int8))
    ds = _budgets(ds, result["budget"])
    js = summary_object(ds, result)
    settings = result["settings"]
    ds.attrs = {
        "comparison_verdict": result["verdict"],
        "comparison_alpha": float(settings["alpha"]),
        "comparison_correction": CORRECTION,
        "comparison_next": result["next"] or "",
        "comparison_json": json.dumps(js),
        "lidarcal_lidar_model": result["model"].to_json(),
        "lidar_model_origin": result["model_origin"],
        "lidarcal_base_seed": int(settings["base_seed"]),
        "field_source": str(result["source"]),
        "reference_uncertainty": float(settings["reference_uncertainty_m_s-1"]),
    }
    return stamp(
        ds,
        "comparison",
        title=f"Field campaign against the virtual lidar: {result['verdict']}",
        summary=(
            "IEC 61400-50-2 sensitivity slopes of the measured and of the simulated lidar-reference pair "
            "per height and environmental variable, their difference with a Holm-corrected test, and the "
            "IEC field and Monte Carlo uncertainty budgets side by side (the paper's Figures 8 and 9 "
            "for this campaign)."
        ),
        call=call,
        inputs=dict(inputs or {}),
        input_datasets={"field": result["field"]},
        config=settings,
        seeds={"base_seed": int(settings["base_seed"])},
    )


def _budgets(ds: xr.Dataset, budgets: Mapping[str, xr.Dataset]) -> xr.Dataset:
    """Add both budgets on the union of their wind-speed bins (centres are multiples of the width)."""
    meas, sim = (budgets[k].transpose("height", "wind_speed", ...) for k in ("measured", "simulated"))
    meas, sim = xr.align(meas, sim, join="outer", exclude={"contributor"})
    centres = meas["wind_speed"].values
    width = float(np.median(np.diff(np.asarray(budgets["measured"]["wind_speed_bounds"].values[0]))))
    edges = np.append(centres - width / 2, centres[-1] + width / 2)
    hw = ("height", "wind_speed")
    out = ds.assign_coords(wind_speed=("wind_speed", centres, output_attrs("comparison", "wind_speed")))
    out = with_bounds(out, "wind_speed", edges)
    for side, b in (("measured", meas), ("simulated", sim)):
        dim = f"{side}_contributor"
        out = out.assign_coords({dim: (dim, np.array(b["contributor"].values, dtype=object),
                                       output_attrs("comparison", dim))})
        contribution = b["contribution"].transpose("height", "wind_speed", "contributor").values
        values = {
            f"{side}_uncertainty": (hw, b["uncertainty"].values),
            f"{side}_relative_uncertainty": (hw, b["relative_uncertainty"].values),
            f"{side}_contribution": (("height", "wind_speed", dim), contribution),
            f"{side}_sample_count": (hw, np.nan_to_num(b["sample_count"].values).astype(np.int32)),
            f"{side}_mean_reference_wind_speed": (hw, b["mean_reference_wind_speed"].values),
        }
        for name, (dims, data) in values.items():
            out[name] = (dims, data, output_attrs("comparison", name))
    out.attrs["budget_approaches"] = "measured: iec; simulated: monte_carlo"
    return out


def summary_object(ds: xr.Dataset, result: Comparison) -> dict[str, Any]:
    """Build the ``--json`` object (``docs/compare.md``) from the artefact's variables."""
    cells = []
    for v in ds.variable.values:
        v = str(v)
        for h in ds.height.values:
            flag = int(ds["agree"].sel(variable=v, height=h))
            if flag == 2:
                continue
            at = {"variable": v, "height": h}
            cells.append(
                {
                    "height": float(h),
                    "variable": v,
                    "measured_slope": _num(ds[f"{v}_measured_slope"].sel(height=h)),
                    "measured_se": _num(ds[f"{v}_measured_slope_stderr"].sel(height=h)),
                    "simulated_slope": _num(ds[f"{v}_simulated_slope"].sel(height=h)),
                    "simulated_se": _num(ds[f"{v}_simulated_slope_stderr"].sel(height=h)),
                    "z": _num(ds["slope_z"].sel(at)),
                    "agree": flag == 1,
                    "p_adjusted": _num(ds["slope_p_adjusted"].sel(at)),
                    "units": slope_units(v),
                    "measured_significant": bool(
                        ds["measured_significant_eq12"].sel(at) or ds["measured_significant_eq13"].sel(at)
                    ),
                    "simulated_significant": bool(
                        ds["simulated_significant_eq12"].sel(at) or ds["simulated_significant_eq13"].sel(at)
                    ),
                }
            )
    untested = [
        {"height": float(h), "variable": str(v)}
        for v in ds.variable.values
        for h in ds.height.values
        if int(ds["agree"].sel(variable=v, height=h)) == 2
    ]
    by_height = {}
    for h in ds.height.values:
        by_height[str(float(h))] = {
            side: [_num(x) for x in ds[f"{side}_relative_uncertainty"].sel(height=h).values]
            for side in ("measured", "simulated")
        }
    return {
        "verdict": result["verdict"],
        "alpha": float(result["settings"]["alpha"]),
        "correction": CORRECTION,
        "cells": cells,
        "budgets": {
            "quantity": "combined standard uncertainty relative to the bin mean reference wind speed",
            "units": "%",
            "measured_approach": "iec",
            "simulated_approach": "monte_carlo",
            "wind_speed": [float(w) for w in ds.wind_speed.values],
            "heights": by_height,
        },
        "next": result["next"],
        "untested": untested,
        "model": result["model_origin"],
    }


def summary(ds: xr.Dataset) -> dict[str, Any]:
    """Return the ``--json`` object stored in a ``comparison`` artefact."""
    return read_attr(ds, "comparison_json", kind="comparison")
