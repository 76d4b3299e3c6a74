"""Full-factorial ``conditions`` for a classification-style sweep (paper §4, Discussion a and b).

Like IEC 61400-50-1's anemometer classification (about 10^5 model runs over the full range
of environmental conditions), the virtual lidar can be run on a **full-factorial grid** of
conditions — wind speed, turbulence intensity, shear exponent, CNR, CNR gradient and wind
direction — instead of the correlated conditions a test site happens to offer.

:func:`sweep_conditions` turns a grid into a ``conditions`` Dataset with one period per
(grid point, replicate), the replicates of one grid point consecutive and the last variable
varying fastest: period = grid_index × repeats + replicate.  :func:`grid_values` checks and
converts a grid; :func:`lidarcal.analysis.sweep.analyse_sweep` reads the simulated records
back onto the grid.
"""

from __future__ import annotations

import itertools
import json
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pint
import xarray as xr

from lidarcal.cf import height_coord, time_coord
from lidarcal.conditions.variables import CANONICAL_UNITS, variable_attrs
from lidarcal.errors import InputError, UnitError
from lidarcal.units import LOG_UNITS, to_magnitude

__all__ = ["SWEEP_VARIABLES", "DEFAULT_GRID", "grid_values", "sweep_conditions"]

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


def grid_values(grid: Mapping[str, Any] | None) -> dict[str, np.ndarray]:
    """Sorted grid values of every swept variable in canonical units.

    ``grid`` maps swept variables to their values (quantities, or bare floats for the
    dimensionless variables and the dB ones); missing variables take :data:`DEFAULT_GRID`.
    """
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

    ``grid`` is as for :func:`grid_values`.
    """
    if int(repeats) < 1:
        raise InputError(f"repeats must be >= 1; got {repeats}")
    values = grid_values(grid)
    points = np.array(list(itertools.product(*(values[n] for n in SWEEP_VARIABLES))), dtype=float)
    points = np.repeat(points, int(repeats), axis=0)
    n, nh = len(points), len(heights)
    data = {
        name: (
            ("time", "height"),
            np.repeat(points[:, i : i + 1], nh, axis=1),
            variable_attrs(name, content="auxiliaryInformation",
                           comment="value of the full-factorial grid (lidarcal.conditions.grid)"),
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
