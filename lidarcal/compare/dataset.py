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
from lidarcal.cf import height_coord, var_attrs, with_bounds
from lidarcal.compare.core import CORRECTION, Comparison
from lidarcal.conditions.variables import CANONICAL_UNITS
from lidarcal.provenance import stamp

__all__ = ["to_dataset", "summary", "slope_units"]

_SIDES = {"measured": "field records", "simulated": "virtual lidar in the campaign's conditions"}
_FLAG = {"flag_values": np.array([0, 1], dtype=np.int8), "flag_meanings": "not_significant significant"}


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
    ds = xr.Dataset(
        coords={
            "variable": (
                "variable",
                np.array(variables, dtype=object),
                {"long_name": "environmental variable of the sensitivity"},
            ),
            "height": height_coord(heights),
        }
    )
    for i, v in enumerate(variables):
        units, label = slope_units(v), v.replace("_", " ")
        for side in ("measured", "simulated"):
            ds[f"{v}_{side}_slope"] = (
                "height",
                cells[f"{side}_slope"][i],
                var_attrs(
                    f"sensitivity slope of the relative lidar minus reference difference to {label}, "
                    f"{_SIDES[side]}",
                    units,
                    comment="IEC 61400-50-2 binning, weighted least squares of bin means",
                ),
            )
            ds[f"{v}_{side}_slope_stderr"] = (
                "height",
                cells[f"{side}_slope_standard_error"][i],
                var_attrs(f"standard error of the {side} slope against {label}", units),
            )
        ds[f"{v}_slope_difference"] = (
            "height",
            cells["difference"][i],
            var_attrs(f"measured minus simulated slope against {label}", units),
        )
        ds[f"{v}_slope_difference_stderr"] = (
            "height",
            cells["stderr"][i],
            var_attrs(
                f"combined standard error of the slope difference against {label}",
                units,
                comment="sqrt(measured_stderr**2 + simulated_stderr**2): the two sides are independent",
            ),
        )
    for side in ("measured", "simulated"):
        ds[f"{side}_bins_used"] = (
            vh,
            np.nan_to_num(cells[f"{side}_bins_used"]).astype(np.int32),
            var_attrs(f"bins in the {side} regression", "1", coverage_content_type="auxiliaryInformation"),
        )
        ds[f"{side}_correlation"] = (
            vh,
            cells[f"{side}_correlation"],
            var_attrs(f"correlation coefficient R of the {side} regression", "1"),
        )
        ds[f"{side}_slope_times_std"] = (
            vh,
            cells[f"{side}_slope_times_std"],
            var_attrs(f"Eq. 12 statistic m * std, {_SIDES[side]}", "%"),
        )
        ds[f"{side}_slope_times_std_times_r"] = (
            vh,
            cells[f"{side}_slope_times_std_times_r"],
            var_attrs(f"Eq. 13 statistic m * std * R, {_SIDES[side]}", "%"),
        )
        for eq, thr in (("eq12", "|m * std| > 0.5 %"), ("eq13", "|m * std * R| > 0.1 %")):
            flag = cells[f"{side}_significant_{eq}"]
            ds[f"{side}_significant_{eq}"] = (
                vh,
                np.nan_to_num(flag).astype(np.int8),
                var_attrs(
                    f"{thr} ({eq.replace('eq', 'Eq. ')}), {side}",
                    "1",
                    coverage_content_type="qualityInformation",
                    **_FLAG,
                ),
            )
    ds["slope_z"] = (
        vh,
        cells["z"],
        var_attrs(
            "slope difference over its combined standard error",
            "1",
            coverage_content_type="qualityInformation",
        ),
    )
    ds["slope_p_value"] = (
        vh,
        cells["p_value"],
        var_attrs(
            "two-sided p-value of equal measured and simulated slopes (normal z-test)",
            "1",
            coverage_content_type="qualityInformation",
        ),
    )
    ds["slope_p_adjusted"] = (
        vh,
        cells["p_adjusted"],
        var_attrs(
            "Holm-adjusted p-value over every tested cell (height x variable)",
            "1",
            coverage_content_type="qualityInformation",
        ),
    )
    ds["agree"] = (
        vh,
        cells["agree"].astype(np.int8),
        var_attrs(
            "measured and simulated slopes agree at the family-wise alpha",
            "1",
            coverage_content_type="qualityInformation",
            flag_values=np.array([0, 1, 2], dtype=np.int8),
            flag_meanings="disagree agree not_tested",
            comment="not_tested: fewer than three bins with enough periods on one side",
        ),
    )
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
    out = ds.assign_coords(
        wind_speed=(
            "wind_speed",
            centres,
            {
                "long_name": "centre of reference wind speed bin",
                "units": "m s-1",
                "standard_name": "wind_speed",
                "coverage_content_type": "coordinate",
            },
        )
    )
    out = with_bounds(out, "wind_speed", edges)
    label = {
        "measured": "IEC field approach, measured pair",
        "simulated": "Monte Carlo approach, simulated pair",
    }
    for side, b in (("measured", meas), ("simulated", sim)):
        out = out.assign_coords(
            {
                f"{side}_contributor": (
                    f"{side}_contributor",
                    np.array(b["contributor"].values, dtype=object),
                    {"long_name": f"uncertainty contributor, {label[side]}"},
                )
            }
        )
        out[f"{side}_uncertainty"] = (
            hw,
            b["uncertainty"].values,
            var_attrs(f"combined standard uncertainty, {label[side]}", "m s-1", "wind_speed standard_error"),
        )
        out[f"{side}_relative_uncertainty"] = (
            hw,
            b["relative_uncertainty"].values,
            var_attrs(
                f"combined standard uncertainty relative to the bin mean reference wind speed, {label[side]}",
                "%",
            ),
        )
        out[f"{side}_contribution"] = (
            ("height", "wind_speed", f"{side}_contributor"),
            b["contribution"].transpose("height", "wind_speed", "contributor").values,
            var_attrs(
                f"standard uncertainty contribution, {label[side]}", "m s-1", "wind_speed standard_error"
            ),
        )
        out[f"{side}_sample_count"] = (
            hw,
            np.nan_to_num(b["sample_count"].values).astype(np.int32),
            var_attrs(
                f"periods in the bin, {label[side]}", "1", coverage_content_type="auxiliaryInformation"
            ),
        )
        out[f"{side}_mean_reference_wind_speed"] = (
            hw,
            b["mean_reference_wind_speed"].values,
            var_attrs(f"mean reference wind speed in the bin, {label[side]}", "m s-1", "wind_speed"),
        )
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
    return json.loads(ds.attrs["comparison_json"])
