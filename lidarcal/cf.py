"""Small helpers that give variables complete CF/ACDD attributes in one call."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

__all__ = ["var_attrs", "with_bounds", "height_coord", "time_coord", "Param", "declared_attrs"]


def var_attrs(
    long_name: str,
    units: str,
    standard_name: str | None = None,
    coverage_content_type: str = "modelResult",
    **extra: Any,
) -> dict[str, Any]:
    """Attributes for a data variable: ``long_name``, ``units``, ACDD content type.

    ``coverage_content_type`` is one of ISO 19115-1's codes (``physicalMeasurement``,
    ``modelResult``, ``qualityInformation``, ``auxiliaryInformation``, ``coordinate`` ...).
    """
    attrs = {"long_name": long_name, "units": units, "coverage_content_type": coverage_content_type}
    if standard_name:
        attrs["standard_name"] = standard_name
    attrs.update(extra)
    return attrs


@dataclass(frozen=True)
class Param:
    """Placeholder in a declared-attributes table: the context value ``key`` as it is (not as text)."""

    key: str


def declared_attrs(table: Mapping[str, Mapping[str, Any]], name: str, **context: Any) -> dict[str, Any]:
    """Attributes of output variable ``name`` from a declarative ``table`` (output metadata declared once).

    An entry holds ``long_name`` and ``units`` and optionally ``standard_name``,
    ``coverage_content_type`` and any further attribute, in the order they are written.  String
    values are templates filled from ``context`` (``"mean {xname} in bin"``); a :class:`Param`
    is replaced by the context value itself; arrays are copied.  The result is :func:`var_attrs`
    of the filled entry, so an empty ``standard_name`` is left out.
    """
    filled = {}
    for key, value in table[name].items():
        if isinstance(value, str):
            value = value.format_map(context)
        elif isinstance(value, Param):
            value = context[value.key]
        elif isinstance(value, np.ndarray):
            value = value.copy()
        filled[key] = value
    return var_attrs(filled.pop("long_name"), filled.pop("units"), filled.pop("standard_name", None),
                     filled.pop("coverage_content_type", "modelResult"), **filled)


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


def time_coord(values: Any) -> xr.DataArray:
    """Return a CF ``time`` coordinate (period start times, UTC)."""
    return xr.DataArray(
        np.asarray(values, dtype="datetime64[ns]"), dims="time",
        attrs={"standard_name": "time", "long_name": "start of 10-minute period (UTC)", "axis": "T"},
    )
