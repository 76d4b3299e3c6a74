"""Classification-style sweep over the full parameter space (paper §4, Discussion a and b).

Like IEC 61400-50-1's anemometer classification (about 10^5 model runs over the full range
of environmental conditions), the virtual lidar is run on a **full-factorial grid** of
conditions — wind speed, turbulence intensity, shear exponent, CNR, CNR gradient and wind
direction — instead of the correlated conditions a test site happens to offer.  The result:

- ``deviation`` — the mean relative lidar−reference deviation (%) at every grid point and
  height (averaged over ``repeats`` Monte Carlo replicates with different seeds);
- ``max_abs_deviation`` — its maximum magnitude over the grid per height (the class-style
  figure of Discussion a) and the conditions where it occurs;
- sensitivity slopes of the deviation to every swept variable (Discussion b), from
  :func:`lidarcal.analysis.sensitivity` with one bin per grid value: in a full-factorial
  design a bin mean is the marginal effect of that variable.

Grid period *i* is simulated with seed ``(base_seed, i)`` as in any campaign, with the
replicates of one grid point consecutive: period = grid_index × repeats + replicate.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pint
import xarray as xr

from lidarcal.analysis._records import CANONICAL_UNITS, STANDARD_NAMES
from lidarcal.analysis.sensitivity import sensitivity
from lidarcal.cf import height_coord, time_coord, var_attrs
from lidarcal.errors import InputError, UnitError
from lidarcal.provenance import stamp
from lidarcal.units import LOG_UNITS, to_magnitude

__all__ = ["SWEEP_VARIABLES", "DEFAULT_GRID", "sweep_conditions", "analyse_sweep", "sweep"]

#: Swept variables, in the order of the grid dimensions.
SWEEP_VARIABLES = (
    "wind_speed",
    "turbulence_intensity",
    "wind_shear_exponent",
    "cnr",
    "cnr_gradient",
    "wind_from_direction",
)

#: Default grid (canonical units): 4 x 3 x 3 x 2 x 3 x 3 = 648 points.  Directions cover
#: 0-45 degree because DBS geometry repeats every 90 degree and mirrors about 45 degree.
DEFAULT_GRID: dict[str, tuple[float, ...]] = {
    "wind_speed": (4.0, 8.0, 12.0, 16.0),
    "turbulence_intensity": (0.05, 0.12, 0.20),
    "wind_shear_exponent": (0.0, 0.2, 0.4),
    "cnr": (-20.0, -10.0),
    "cnr_gradient": (-0.05, 0.0, 0.05),
    "wind_from_direction": (0.0, 22.5, 45.0),
}

_RANGES = {
    "wind_speed": (0.5, 60.0),
    "turbulence_intensity": (0.0, 1.0),
    "wind_shear_exponent": (-1.0, 1.5),
    "cnr": (-60.0, 20.0),
    "cnr_gradient": (-5.0, 5.0),
    "wind_from_direction": (-360.0, 720.0),
}


def _values(name: str, value: Any) -> np.ndarray:
    """Grid values of one variable in canonical units (quantities converted; dB as floats)."""
    unit = CANONICAL_UNITS[name]
    if isinstance(value, pint.Quantity | str):
        arr = np.atleast_1d(np.asarray(to_magnitude(value, unit, name=name), dtype=float))
    elif unit in LOG_UNITS or unit == "1":
        arr = np.atleast_1d(np.asarray(value, dtype=float))
    else:
        raise UnitError(
            f"grid {name!r}: got bare numbers {value!r}; give a quantity in units convertible to "
            f"{unit!r}, e.g. Q_([4, 8], {unit!r})"
        )
    if arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise InputError(f"grid {name!r}: expected a non-empty 1-D list of finite values; got {arr.tolist()}")
    if len(np.unique(arr)) != arr.size:
        raise InputError(f"grid {name!r}: values must be distinct; got {arr.tolist()}")
    lo, hi = _RANGES[name]
    if arr.min() < lo or arr.max() > hi:
        raise InputError(f"grid {name!r}: values {arr.tolist()} {unit} outside the range [{lo}, {hi}] {unit}")
    return np.sort(arr)


def _grid(grid: Mapping[str, Any] | None) -> dict[str, np.ndarray]:
    grid = dict(grid or {})
    unknown = sorted(set(grid) - set(SWEEP_VARIABLES))
    if unknown:
        raise InputError(f"grid: unknown variable(s) {unknown}; sweepable: {list(SWEEP_VARIABLES)}")
    out = {}
    for name in SWEEP_VARIABLES:
        if name in grid:
            out[name] = _values(name, grid[name])
        else:
            out[name] = np.asarray(DEFAULT_GRID[name], dtype=float)
    return out


def sweep_conditions(
    grid: Mapping[str, Any] | None = None, *, heights: Sequence[float] = (100.0,), repeats: int = 1
) -> xr.Dataset:
    """``conditions`` Dataset with one period per (grid point, replicate), same at every height.

    ``grid`` maps swept variables to their values (quantities, or bare floats for the
    dimensionless variables and the dB ones); missing variables take :data:`DEFAULT_GRID`.
    """
    if int(repeats) < 1:
        raise InputError(f"repeats must be >= 1; got {repeats}")
    values = _grid(grid)
    points = np.array(list(itertools.product(*(values[n] for n in SWEEP_VARIABLES))), dtype=float)
    points = np.repeat(points, int(repeats), axis=0)
    n, nh = len(points), len(heights)
    data = {
        name: (
            ("time", "height"),
            np.repeat(points[:, i : i + 1], nh, axis=1),
            var_attrs(
                name.replace("_", " "),
                CANONICAL_UNITS[name],
                STANDARD_NAMES.get(name),
                coverage_content_type="auxiliaryInformation",
            ),
        )
        for i, name in enumerate(SWEEP_VARIABLES)
    }
    ds = xr.Dataset(
        data,
        coords={
            "time": time_coord(np.datetime64("2000-01-01T00:00") + np.arange(n) * np.timedelta64(600, "s")),
            "height": height_coord(heights),
        },
    )
    ds.attrs["lidarcal_sweep_grid"] = json.dumps({k: v.tolist() for k, v in values.items()})
    ds.attrs["lidarcal_sweep_repeats"] = int(repeats)
    ds["time"].attrs["comment"] = "synthetic period start times: one period per grid point and replicate"
    return ds


def _edges(values: np.ndarray) -> np.ndarray:
    mid = 0.5 * (values[1:] + values[:-1])
    return np.concatenate([[values[0] - (mid[0] - values[0])], mid, [values[-1] + (values[-1] - mid[-1])]])


def analyse_sweep(records: xr.Dataset, grid: Mapping[str, Any], *, repeats: int = 1) -> xr.Dataset:
    """Turn simulated records of :func:`sweep_conditions` into a ``sweep`` artefact."""
    values = _grid(grid)
    shape = tuple(len(values[n]) for n in SWEEP_VARIABLES)
    n_grid = int(np.prod(shape))
    nt = records.sizes["time"]
    if nt != n_grid * repeats:
        raise InputError(f"records have {nt} periods; the grid has {n_grid} points x {repeats} repeats")
    lidar = records["lidar_wind_speed"].transpose("time", "height").values
    ref = records["reference_wind_speed"].transpose("time", "height").values
    heights = records["height"].values
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = 100.0 * (lidar - ref) / ref
    rel = rel.reshape(n_grid, repeats, len(heights))
    with np.errstate(invalid="ignore"):
        dev = np.nanmean(rel, axis=1) if repeats > 1 else rel[:, 0]
        spread = np.nanstd(rel, axis=1, ddof=1) if repeats > 1 else np.full_like(dev, np.nan)
    if not np.isfinite(dev).any():
        raise InputError("no grid point has a finite simulated deviation (all periods skipped?)")
    dev_grid = np.moveaxis(dev.reshape(*shape, len(heights)), -1, 0)
    spread_grid = np.moveaxis(spread.reshape(*shape, len(heights)), -1, 0)
    absdev = np.where(np.isfinite(dev), np.abs(dev), -np.inf)
    where = np.argmax(absdev, axis=0)  # per height, flat grid index of the largest |deviation|
    at = np.array(np.unravel_index(where, shape))  # (variable, height)

    gdims = ("height", *SWEEP_VARIABLES)
    data = {
        "deviation": (
            gdims,
            dev_grid,
            var_attrs(
                "mean relative lidar minus reference wind speed deviation at grid point",
                "%",
                comment=f"100 % (lidar - reference) / reference, mean over {repeats} replicate(s)",
            ),
        ),
        "deviation_replicate_std": (
            gdims,
            spread_grid,
            var_attrs("standard deviation of the deviation over replicates (ddof=1)", "%"),
        ),
        "max_abs_deviation": (
            "height",
            np.take_along_axis(np.abs(dev), where[None, :], 0)[0],
            var_attrs("maximum magnitude of the mean deviation over the grid (class-style figure)", "%"),
        ),
        "max_deviation": (
            "height",
            np.take_along_axis(dev, where[None, :], 0)[0],
            var_attrs("signed mean deviation at the grid point of maximum magnitude", "%"),
        ),
        "mean_deviation": ("height", np.nanmean(dev, axis=0), var_attrs("mean deviation over the grid", "%")),
    }
    for i, name in enumerate(SWEEP_VARIABLES):
        data[f"max_deviation_{name}"] = (
            "height",
            values[name][at[i]],
            var_attrs(
                f"{name.replace('_', ' ')} at the grid point of maximum deviation magnitude",
                CANONICAL_UNITS[name],
                STANDARD_NAMES.get(name),
                coverage_content_type="auxiliaryInformation",
            ),
        )

    swept = [n for n in SWEEP_VARIABLES if len(values[n]) > 1]
    stats = {
        k: np.full((len(swept), len(heights)), np.nan)
        for k in ("slope_times_std", "slope_times_std_times_r", "correlation")
    }
    flags = np.zeros((len(swept), len(heights)), dtype=np.int8)
    for j, name in enumerate(swept):
        s = sensitivity(records, name, bins=_edges(values[name]), min_samples=1, reference_range=None)
        for k in stats:
            stats[k][j] = s[k].values
        flags[j] = s["significant"].values
        data[f"slope_{name}"] = (
            "height",
            s["slope"].values,
            var_attrs(
                f"sensitivity slope of the deviation to {name.replace('_', ' ')} over the grid",
                s.slope.attrs["units"],
                comment="unweighted regression of per-value mean deviations on the grid values",
            ),
        )
    vd = ("variable", "height")
    if swept:
        data.update(
            {
                "slope_times_std": (
                    vd,
                    stats["slope_times_std"],
                    var_attrs("Eq. 12 statistic m * std over the grid", "%"),
                ),
                "slope_times_std_times_r": (
                    vd,
                    stats["slope_times_std_times_r"],
                    var_attrs("Eq. 13 statistic m * std * R over the grid", "%"),
                ),
                "correlation": (
                    vd,
                    stats["correlation"],
                    var_attrs("correlation coefficient R of the regression", "1"),
                ),
                "significant": (
                    vd,
                    flags,
                    var_attrs(
                        "sensitivity significant by Eq. 12 or 13",
                        "1",
                        coverage_content_type="qualityInformation",
                        flag_values=np.array([0, 1], dtype=np.int8),
                        flag_meanings="not_significant significant",
                    ),
                ),
            }
        )
    coords = {"height": records["height"].variable.copy()}
    for name in SWEEP_VARIABLES:
        coords[name] = (
            name,
            values[name],
            var_attrs(
                f"swept {name.replace('_', ' ')}",
                CANONICAL_UNITS[name],
                STANDARD_NAMES.get(name),
                coverage_content_type="coordinate",
            ),
        )
    if swept:
        coords["variable"] = (
            "variable",
            np.array(swept, dtype=object),
            {"long_name": "swept environmental variable of the sensitivity statistics"},
        )
    ds = xr.Dataset(data, coords=coords)
    ds["height"].attrs = dict(records["height"].attrs)
    ds.attrs = {
        "sweep_grid": json.dumps({k: v.tolist() for k, v in values.items()}),
        "sweep_repeats": int(repeats),
        "sweep_points": n_grid,
        "deviation_definition": "100 % * (lidar_wind_speed - reference_wind_speed) / reference_wind_speed",
    }
    for key in ("lidarcal_lidar_model", "lidarcal_base_seed"):
        if key in records.attrs:
            ds.attrs[key] = records.attrs[key]
    return ds


def sweep(
    model: Any,
    *,
    grid: Mapping[str, Any] | None = None,
    heights: Sequence[float] = (100.0,),
    repeats: int = 1,
    base_seed: int | None = None,
    scheduler: Any = None,
    workers: int | None = None,
    chunk: int = 64,
    workdir: Any = None,
    progress: bool = False,
    call: str | None = None,
    inputs: Mapping[str, Any] | None = None,
) -> tuple[xr.Dataset, xr.Dataset]:
    """Simulate the grid with ``model`` and analyse it.

    Returns
    -------
    (sweep, records)
        The ``sweep`` artefact and the ``simulated_rtd`` records it was computed from.
    """
    from lidarcal.campaign import DEFAULT_BASE_SEED, simulate_campaign

    values = _grid(grid)
    conditions = sweep_conditions(grid, heights=heights, repeats=repeats)
    seed = DEFAULT_BASE_SEED if base_seed is None else int(base_seed)
    records = simulate_campaign(
        conditions,
        model,
        base_seed=seed,
        scheduler=scheduler,
        workers=workers,
        chunk=chunk,
        workdir=workdir,
        progress=progress,
        inputs=dict(inputs or {}),
    )
    ds = analyse_sweep(records, grid, repeats=repeats)
    n = int(np.prod([len(v) for v in values.values()]))
    config = {
        "grid": {k: v.tolist() for k, v in values.items()},
        "heights": [float(h) for h in heights],
        "repeats": int(repeats),
        "chunk": chunk,
        "lidar_model": json.loads(model.to_json()),
    }
    out = stamp(
        ds,
        "sweep",
        title="Classification-style sweep of the virtual lidar over a full grid of conditions",
        summary=(
            f"Virtual lidar simulated on a full-factorial grid of {n} condition points x {repeats} "
            "replicate(s): mean relative deviation from the virtual reference at every point, its maximum "
            "magnitude over the grid, and sensitivity slopes (paper Discussion a-b)."
        ),
        call=call or "lidarcal.analysis.sweep",
        inputs=dict(inputs or {}),
        config=config,
        seeds={
            "base_seed": seed,
            "scheme": "SeedSequence([base_seed, grid_index * repeats + replicate, round(height_m * 1000)])",
        },
    )
    return out, records
