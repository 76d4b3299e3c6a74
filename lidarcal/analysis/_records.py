"""Reading lidar/reference records (``simulated_rtd`` or ``field_campaign``) at the boundary.

Units are checked here, once; the returned arrays are in canonical units and stay lazy
when the records are Dask-backed (conversion is an affine map applied to the DataArray).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.conditions.variables import CANONICAL_UNITS
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.units import LOG_UNITS, convert_values


def checked(ds: xr.Dataset, name: str, *, source: str, expected: str | None = None) -> xr.DataArray:
    """``ds[name]`` on dims (time, height) in ``expected`` units.

    The default is the canonical unit of a conditions variable or of the measured pair
    (:data:`lidarcal.conditions.variables.CANONICAL_UNITS`), else the variable's own unit.
    """
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
