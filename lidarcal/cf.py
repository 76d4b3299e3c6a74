"""CF helpers: the height and time coordinates, cell bounds, the canonical dimension order, UTC text."""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr

__all__ = ["with_bounds", "height_coord", "time_coord", "canonical_dims", "canonical_order", "iso_utc"]


def height_coord(values: Any) -> xr.DataArray:
    """Return the ``height`` coordinate of the fixed contract (metres, positive up)."""
    return xr.DataArray(
        np.asarray(values, dtype=float), dims="height",
        attrs={"standard_name": "height", "long_name": "height above ground level", "units": "m",
               "positive": "up", "axis": "Z"},
    )


def with_bounds(ds: xr.Dataset, coord: str, edges: Any) -> xr.Dataset:
    """Attach CF cell bounds ``<coord>_bounds`` (dims ``(coord, nv)``) from bin ``edges``.

    ``edges`` has one more element than the coordinate (contiguous bins) or shape (n, 2).
    """
    edges = np.asarray(edges, dtype=float)
    bounds = np.stack([edges[:-1], edges[1:]], axis=-1) if edges.ndim == 1 else edges
    name = f"{coord}_bounds"
    out = ds.assign_coords({name: ((coord, "nv"), bounds, {"units": ds[coord].attrs.get("units", "1")})})
    out[coord].attrs["bounds"] = name
    return out


def iso_utc(t: Any, unit: str = "s") -> Any:
    """ISO 8601 UTC text of ``t`` (datetime64, or integer nanoseconds since 1970), ``Z``-suffixed.

    Truncated toward the past to ``unit`` (never rounded): ``"s"`` for the time coverage an
    artefact records, ``"ms"`` for the timestamps of a bench file and the messages that quote them.
    A scalar gives a ``str``, an array an array of them.

    >>> iso_utc(1_676_650_020_800_000_000), iso_utc(1_676_650_020_800_000_000, "ms")
    ('2023-02-17T16:07:00Z', '2023-02-17T16:07:00.800Z')
    """
    t = np.asarray(t)
    if t.dtype.kind in "iu":
        t = t.astype("datetime64[ns]")
    text = np.char.add(np.datetime_as_string(t, unit=unit), "Z")
    return str(text) if text.ndim == 0 else text


def time_coord(values: Any) -> xr.DataArray:
    """Return a CF ``time`` coordinate (period start times, UTC)."""
    return xr.DataArray(
        np.asarray(values, dtype="datetime64[ns]"), dims="time",
        attrs={"standard_name": "time", "long_name": "start of 10-minute period (UTC)", "axis": "T"},
    )


#: Rank of a spatio-temporal axis in the canonical order (CF §2.4: T, Z, Y, X, after every other dim).
_AXIS_RANK = {"T": 1, "Z": 2, "Y": 3, "X": 4}
_NAME_AXIS = {"time": "T", "height": "Z", "altitude": "Z", "depth": "Z", "latitude": "Y", "longitude": "X"}


def _axis(ds: xr.Dataset, dim: str) -> str | None:
    """Return the CF axis (T, Z, Y, X) of ``dim``: its coordinate's ``axis``, else its standard name."""
    if dim in ds.variables:
        attrs = ds.variables[dim].attrs
        if attrs.get("axis") in _AXIS_RANK:
            return str(attrs["axis"])
        if attrs.get("standard_name") in _NAME_AXIS:
            return _NAME_AXIS[str(attrs["standard_name"])]
        return None
    return _NAME_AXIS.get(str(dim))  # a dimension without a coordinate variable: by its name


def canonical_dims(ds: xr.Dataset, dims: tuple) -> tuple:
    """``dims`` in lidarcal's canonical order: other dims first (as given), then time, then height.

    The order is CF §2.4's recommendation: dimensions that are not spatio-temporal to the left,
    then T, Z, Y, X.  A dimension's axis comes from its coordinate (``axis``, else
    ``standard_name``), so ``budget_height`` in a certificate is a Z dimension like ``height``.
    """
    return tuple(sorted(dims, key=lambda d: (_AXIS_RANK.get(_axis(ds, d) or "", 0), dims.index(d))))


def canonical_order(ds: xr.Dataset) -> xr.Dataset:
    """Return ``ds`` with every variable's dimensions in the canonical order (:func:`canonical_dims`).

    Values are only transposed (selection by name is unaffected); a dataset already in order is
    returned as a shallow copy.  A bounds variable keeps its vertex dimension last (CF §7.1).
    :func:`lidarcal.provenance.stamp` applies it to every artefact,
    so an artefact in memory has the dimension order of its file.
    """
    out = ds.copy(deep=False)
    # CF 7.1: a bounds variable has its parent's dims, then the vertex dim (last)
    parents = {str(v.attrs[key]): v.dims for v in ds.variables.values() for key in ("bounds", "climatology")
               if str(v.attrs.get(key, "")) in ds.variables}
    for name in list(out.variables):
        var = out.variables[name]
        if name in parents:
            own = tuple(d for d in var.dims if d in parents[name])
            order = canonical_dims(ds, own) + tuple(d for d in var.dims if d not in own)
        else:
            order = canonical_dims(ds, tuple(var.dims))
        if order == tuple(var.dims):
            continue
        if name in out.coords:
            out = out.assign_coords({name: out[name].transpose(*order)})
        else:
            out[name] = out[name].transpose(*order)
    return out
