"""The global attributes lidarcal reads back from its artefacts, read through one accessor.

Each artefact kind's schema declares, under ``read_back``, the global attributes lidarcal reads
from an artefact of that kind: the type, a description, and where relevant the units, a default,
whether the attribute is required, a physical range, values that count as "not given" and
legacy names mapped at this edge (``lidar_serial_number`` for ``lidar_serial``).  A set several
kinds share is declared once and copied with ``include: [{from: KIND, into: read_back, only: [...]}]``
(``set: {required: false}`` overrides keys of the copies); the
attributes :func:`lidarcal.io.open_artefact` stamps on every artefact it reads
(``lidarcal_source_file``, ``lidarcal_source_sha256``) and the kind itself are declared in
``schemas/shared/provenance.yaml`` and belong to every kind.

:func:`read_attr` is the one accessor: it knows the declared type and default, converts what
netCDF gives (numpy scalars, numpy strings, arrays) to Python values, and raises an
:class:`~lidarcal.errors.InputError` naming the file, the attribute, what was expected and what
was found when a required attribute is missing or a value is malformed.  A name no schema
declares is a programming error (:class:`UndeclaredAttribute`, a ``KeyError``), so a misspelt
name fails the first test that reaches it rather than silently reading the default.

A typed reader per attribute (cf-xarray's accessor properties, xclim's ``cf_attrs``) would be a
second declaration of what the schema already says; one function keyed by the declared name
keeps the schema the single declaration and lets a test list every name the package reads.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.errors import InputError, SchemaError
from lidarcal.schema import list_kinds, schema_file

__all__ = ["read_attr", "declared_read_back", "read_back_names", "source_name", "UndeclaredAttribute"]

#: The shared set every kind with ``provenance: true`` reads back.
_PROVENANCE = "shared/provenance"
_MISSING = object()


class UndeclaredAttribute(KeyError):
    """A read-back attribute no schema declares (or not the kind asked): a programming error."""


@functools.cache
def _raw(kind: str) -> dict[str, Any]:
    """Return the YAML of ``kind`` (or of a ``shared/<name>`` fragment), keys checked, nothing expanded.

    A fragment has only ``kind``, ``description`` and ``read_back``.  Catalogue expansions are not
    needed here, so the read-back declarations load without the stage that registers them.
    """
    raw = schema_file(kind, required=("kind",))
    if kind.startswith("shared/") and set(raw) - {"kind", "description", "read_back"}:
        raise SchemaError(f"schema fragment {kind}.yaml may only have kind, description and read_back; "
                          f"found {sorted(raw)}")
    return raw


@functools.cache
def declared_read_back(kind: str) -> dict[str, dict[str, Any]]:
    """Return the read-back attributes of ``kind``: its own, those it includes, the provenance set."""
    raw = _raw(kind)
    out: dict[str, dict[str, Any]] = {}
    if not kind.startswith("shared/"):
        out.update(declared_read_back(_PROVENANCE))
    for entry in raw.get("include") or []:
        if entry.get("into") != "read_back":
            continue
        source = declared_read_back(entry["from"])
        only = entry.get("only", list(source))
        missing = [n for n in only if n not in source]
        if missing:
            raise SchemaError(f"schema {kind}.yaml: include from {entry['from']!r} into read_back names "
                              f"{missing}, which it does not declare; it declares {sorted(source)}")
        out.update({n: {**source[n], **(entry.get("set") or {})} for n in only})
    for name, spec in (raw.get("read_back") or {}).items():
        if name in out:
            raise SchemaError(f"schema {kind}.yaml: read_back {name!r} is declared and also included")
        out[name] = dict(spec)
    return out


@functools.cache
def read_back_names() -> dict[str, tuple[str, ...]]:
    """Every declared read-back attribute and the kinds that declare it."""
    names: dict[str, list[str]] = {}
    for kind in list_kinds():
        for name in declared_read_back(kind):
            names.setdefault(name, []).append(kind)
    return {name: tuple(kinds) for name, kinds in sorted(names.items())}


@functools.cache
def _spec(name: str, kind: str | None, found_kind: str | None) -> tuple[str, dict[str, Any]]:
    kinds = read_back_names().get(name)
    if not kinds:
        raise UndeclaredAttribute(f"no schema declares the read-back global attribute {name!r}; declare it "
                                  f"under read_back in schemas/<kind>.yaml")
    if kind is not None:
        if kind not in kinds:
            raise UndeclaredAttribute(f"schemas/{kind}.yaml declares no read-back attribute {name!r}; "
                                      f"declared by {list(kinds)}")
        return kind, declared_read_back(kind)[name]
    if found_kind in kinds:
        return str(found_kind), declared_read_back(str(found_kind))[name]
    specs = {json.dumps({k: v for k, v in declared_read_back(k)[name].items() if k != "description"},
                        sort_keys=True) for k in kinds}
    if len(specs) > 1:
        raise UndeclaredAttribute(f"the read-back attribute {name!r} is declared differently by "
                                  f"{list(kinds)}; "
                                  f"pass kind=")
    return kinds[0], declared_read_back(kinds[0])[name]


def _expected(spec: dict[str, Any]) -> str:
    kind = {"float": "a number", "int": "an integer", "str": "text", "json": "JSON text",
            "range": "two numbers lo <= hi"}[spec["type"]]
    rng = spec.get("range")
    if rng is not None:
        lo, hi = rng
        kind = f"a value in {'(' if spec.get('exclusive_min') else '['}{lo:g}, {hi:g}]"
    absent = spec.get("absent")
    if absent and any(a for a in absent):
        kind += " or " + " or ".join(repr(a) for a in absent if a)
    return kind


def _convert(raw: Any, spec: dict[str, Any]) -> Any:
    """``raw`` as the declared type; ValueError/TypeError when it is not one."""
    kind = spec["type"]
    if kind in ("str", "json"):
        value = str(np.asarray(raw).item()) if np.ndim(raw) == 0 else None
        if value is None:
            raise TypeError("not a scalar")
        return json.loads(value) if kind == "json" else value
    if kind == "range":
        pair = np.asarray(raw, dtype=float)
        if pair.shape != (2,) or not np.isfinite(pair).all() or pair[0] > pair[1]:
            raise ValueError("not a range")
        return float(pair[0]), float(pair[1])
    item = np.asarray(raw).item()
    if isinstance(item, bool):
        raise TypeError("a boolean")
    if kind == "int":
        if isinstance(item, float) and not item.is_integer():
            raise ValueError("not integral")
        return int(item)
    value = float(item)
    rng = spec.get("range")
    if rng is not None:
        lo, hi = (float(v) for v in rng)
        if not np.isfinite(value) or value < lo or value > hi or (value == lo and spec.get("exclusive_min")):
            raise ValueError("out of range")
    return value


def read_attr(obj: xr.Dataset | Mapping[str, Any], name: str, *, kind: str | None = None,
              default: Any = _MISSING, source: str | None = None) -> Any:
    """Return the global attribute ``name`` of ``obj`` (a Dataset or its ``attrs``) as its schema declares.

    ``kind`` selects the schema (default: the artefact's ``lidarcal_artefact`` when that kind
    declares ``name``, else the one declaration every declaring kind shares).  An absent
    attribute (or one of the declared ``absent`` values) falls back to its ``legacy`` names, then
    to ``default`` when given (a default that lives in code, e.g. a :class:`LidarModel` field),
    else the declared default, else None; a required one raises.  The value is converted to the
    declared type (``float``, ``int``, ``str``, ``range`` -> (lo, hi), ``json`` -> parsed).

    >>> read_attr({"coverage_factor": np.float64(2.0)}, "coverage_factor", kind="uncertainty_budget")
    2.0
    >>> read_attr({"lidar_serial_number": "WLS7-164"}, "lidar_serial", kind="bench_cube")
    'WLS7-164'
    """
    attrs = obj.attrs if isinstance(obj, xr.Dataset) else obj
    found = attrs.get("lidarcal_artefact")
    kind, spec = _spec(name, kind, str(found) if isinstance(found, str) else None)
    absent = [a for a in spec.get("absent") or []]

    def given(key: str) -> bool:
        raw = attrs.get(key)
        return raw is not None and not (isinstance(raw, str) and raw.strip().lower() in
                                        [str(a).lower() for a in absent])

    key = next((k for k in (name, *(spec.get("legacy") or [])) if given(k)), None)
    if key is None:
        if spec.get("required", False):
            where = source or _where(obj, attrs)
            raise InputError(f"{where}: global attribute {name!r} ({spec['description']}) is missing; "
                             f"expected {_expected(spec)} (a {kind} artefact carries it)")
        value = spec.get("default") if default is _MISSING else default
        return None if value is None else (_convert(value, spec) if default is _MISSING else value)
    raw = attrs[key]
    try:
        return _convert(raw, spec)
    except (TypeError, ValueError):
        where = source or _where(obj, attrs)
        found = np.asarray(raw).item() if np.ndim(raw) == 0 else raw  # 0.0, not np.float64(0.0)
        raise InputError(f"{where}: global attribute {key!r} ({spec['description']}) is {found!r}; "
                         f"expected {_expected(spec)}") from None


def _where(obj: Any, attrs: Mapping[str, Any]) -> str:
    """Return the file a dataset, or a dataset's attributes, came from (:func:`source_name`)."""
    return source_name(obj if isinstance(obj, xr.Dataset) else xr.Dataset(attrs=dict(attrs)))


def source_name(obj: object, default: str = "<dataset>") -> str:
    """Name of the file ``obj`` came from, for messages: the one answer to "which file was this?".

    A path is returned as given; a dataset gives the file name :func:`lidarcal.io.open_artefact` recorded
    (``lidarcal_source_file``), else the path xarray opened it from (``encoding["source"]``),
    else its ``id`` attribute (every lidarcal artefact has one), else ``default``; anything
    else gives ``default``.
    """
    if isinstance(obj, str | os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, xr.Dataset):
        return str(obj.attrs.get("lidarcal_source_file") or obj.encoding.get("source")
                   or obj.attrs.get("id") or default)
    return default
