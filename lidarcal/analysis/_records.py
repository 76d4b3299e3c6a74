"""Reading lidar/reference records (``simulated_rtd`` or ``field_campaign``) at the boundary.

Units are checked here, once; the returned arrays are in canonical units and stay lazy
when the records are Dask-backed (conversion is an affine map applied to the DataArray).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.conditions.variables import CANONICAL_UNITS as _VARIABLE_UNITS
from lidarcal.conditions.variables import CONDITIONS
from lidarcal.conditions.variables import STANDARD_NAMES as _STANDARD_NAMES
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import source_name  # noqa: F401  (imported from here by the analysis modules)
from lidarcal.units import LOG_UNITS, convert_values

#: Canonical units of the variables an analysis may use (docs/contracts.md): the declared
#: conditions variables and measured pair, plus the simulated scalar and vector speeds.
CANONICAL_UNITS = {
    **_VARIABLE_UNITS,
    "lidar_wind_speed_scalar": "m s-1",
    "lidar_wind_speed_vector": "m s-1",
}

#: CF standard names of the conditions variables.
STANDARD_NAMES = {n: s for n, s in _STANDARD_NAMES.items() if n in CONDITIONS}


def checked(ds: xr.Dataset, name: str, *, source: str, expected: str | None = None) -> xr.DataArray:
    """``ds[name]`` on dims (time, height) in ``expected`` units (default: canonical)."""
    if name not in ds.variables:
        raise MissingVariableError(
            f"{source}: required variable {name!r} is missing; found {sorted(map(str, ds.data_vars))}"
        )
    da = ds[name]
    if set(da.dims) != {"time", "height"}:
        raise InputError(
            f"{source}: variable {name!r} has dims {tuple(da.dims)}; expected ('time', 'height')")
    expected = expected or CANONICAL_UNITS.get(name) or da.attrs.get("units")
    where = f"{source}: variable {name!r}"
    if expected in LOG_UNITS:
        convert_values([0.0], da.attrs.get("units"), expected, where=where)  # string check only
        out = da
    else:
        a, b = convert_values([0.0, 1.0], da.attrs.get("units"), expected, where=where)
        out = da if (a == 0.0 and b == 1.0) else da * (b - a) + a
    out = out.transpose("time", "height").astype(float)
    out.attrs = {**da.attrs, "units": expected}
    return out.rename(name)


def select_heights(ds: xr.Dataset, heights, *, source: str) -> xr.Dataset:
    """Restrict to ``heights`` (metres, matched to 1 mm); a height not present is an error."""
    if "height" not in ds.coords:
        raise MissingVariableError(f"{source}: coordinate 'height' is missing")
    if heights is None:
        return ds
    wanted = np.atleast_1d(np.asarray(heights, dtype=float))
    have = np.asarray(ds["height"].values, dtype=float)
    missing = [h for h in wanted if not np.any(np.abs(have - h) < 1e-3)]
    if missing:
        raise InputError(
            f"{source}: height(s) {', '.join(f'{h:g} m' for h in missing)} not in the records; "
            f"available heights: {', '.join(f'{h:g}' for h in have)} m"
        )
    idx = [int(np.argmin(np.abs(have - h))) for h in wanted]
    return ds.isel(height=idx)
