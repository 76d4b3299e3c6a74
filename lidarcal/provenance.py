"""Provenance: ACDD-1.3 discovery attributes, history lines, checksums and configuration.

Every artefact lidarcal writes goes through :func:`stamp`, which records what produced it:
the artefact kind, the software versions, the full configuration, the seeds and the SHA-256
of every input file, and appends a ``history`` line in the xclim style
(``[timestamp] call - lidarcal version``) after the inputs' own history.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import platform
import re
import uuid
from collections.abc import Iterator, Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal import __version__

__all__ = ["sha256", "software_versions", "stamp", "read_json_attr", "jsonable", "contact", "merge_history",
           "CONVENTIONS", "CONTACT_ENV"]

CONVENTIONS = "CF-1.11, ACDD-1.3"
_PACKAGES = ("lidarcal", "numpy", "scipy", "pandas", "xarray", "dask", "distributed", "netCDF4", "pint",
             "pint-xarray", "cf-xarray", "pyconturb")

#: Contact attributes (ACDD-1.3) and the environment variable that sets each one; the
#: ``--institution``/``--creator``/... options of every writing command override them
#: (:func:`contact`).  Unset ones are left out rather than filled with placeholders, except
#: ``creator_name`` ("lidarcal") and ``institution`` ("unspecified").
CONTACT_ENV = {
    "creator_name": "LIDARCAL_CREATOR",
    "creator_email": "LIDARCAL_CREATOR_EMAIL",
    "creator_url": "LIDARCAL_CREATOR_URL",
    "institution": "LIDARCAL_INSTITUTION",
    "publisher_name": "LIDARCAL_PUBLISHER",
    "publisher_email": "LIDARCAL_PUBLISHER_EMAIL",
    "publisher_url": "LIDARCAL_PUBLISHER_URL",
}
_CONTACT_DEFAULTS = {"creator_name": "lidarcal", "institution": "unspecified"}
_contact_override: dict[str, str] = {}


def sha256(path: str | os.PathLike) -> str:
    """SHA-256 hex digest of a file, read in blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def software_versions() -> dict[str, str]:
    """Installed versions of lidarcal and the libraries that shape its numbers."""
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def jsonable(obj: Any, *, strict: bool = False) -> Any:
    """``obj`` with numpy scalars and arrays, paths, bytes and pint quantities made JSON-ready.

    Mappings (keys become strings), lists and tuples are converted recursively; a pint
    quantity becomes ``"<magnitude> <cf unit>"``.  With ``strict`` non-finite floats become
    the strings ``"nan"``, ``"inf"``, ``"-inf"``, so that :func:`json.dumps` writes standard
    JSON (the certificate's attributes); without it they stay floats (``NaN`` in the text).
    """
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v, strict=strict) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v, strict=strict) for v in obj]
    if isinstance(obj, np.ndarray | np.generic):
        return jsonable(obj.tolist(), strict=strict)
    if isinstance(obj, bytes):
        return obj.decode("utf-8", "replace")
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if hasattr(obj, "magnitude") and hasattr(obj, "units"):
        return f"{obj.magnitude} {obj.units:~cf}"
    if strict and isinstance(obj, float) and not np.isfinite(obj):
        return str(obj)
    return obj


def read_json_attr(ds: xr.Dataset, name: str, default: Any = None) -> Any:
    """Decode a JSON-valued global attribute (as written by :func:`stamp`).

    Returns ``default`` when the attribute is absent and the text itself when it is not JSON
    (an attribute of a file lidarcal did not write), so provenance records never fail on it.
    """
    text = ds.attrs.get(name)
    if text is None:
        return default
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        return text


@contextlib.contextmanager
def contact(**values: str | None) -> Iterator[None]:
    """Make :func:`stamp` record these contact attributes within the block.

    Keys are those of :data:`CONTACT_ENV` (``creator_name``, ``creator_email``, ``institution``,
    ``publisher_name`` ...); they win over the environment variables; ``None`` is ignored.
    """
    unknown = set(values) - set(CONTACT_ENV)
    if unknown:
        raise TypeError(f"unknown contact attribute(s) {sorted(unknown)}; known: {sorted(CONTACT_ENV)}")
    saved = dict(_contact_override)
    _contact_override.update({k: str(v) for k, v in values.items() if v is not None})
    try:
        yield
    finally:
        _contact_override.clear()
        _contact_override.update(saved)


def _contact_attrs() -> dict[str, str]:
    out = {}
    for key, env in CONTACT_ENV.items():
        value = _contact_override.get(key) or os.environ.get(env) or _CONTACT_DEFAULTS.get(key)
        if value:
            out[key] = value
    if out.get("creator_name") and out["creator_name"] != "lidarcal":
        out["creator_type"] = "person"
    else:
        out["creator_type"] = "institution"
    if "publisher_name" in out:
        out["publisher_type"] = "institution"
    return out


_STAMP = re.compile(r"^\[(\d{4}-\d\d-\d\dT[0-9:]+Z?)\]")


def merge_history(*texts: str) -> str:
    """Join ``history`` texts: each line once, in time order.

    A line without a ``[timestamp]`` keeps its place after the line before it.
    """
    seen, lines = set(), []
    for text in texts:
        for line in str(text or "").splitlines():
            line = line.rstrip()
            if line and line not in seen:
                seen.add(line)
                lines.append(line)
    keyed, last = [], ""
    for i, line in enumerate(lines):
        m = _STAMP.match(line)
        last = m.group(1) if m else last
        keyed.append((last, i, line))
    return "\n".join(line for _, _, line in sorted(keyed))


def _input_record(role: str, other: xr.Dataset) -> dict[str, Any]:
    """Record an input artefact: file, checksum, licence and its own inputs (the chain)."""
    rec: dict[str, Any] = {"role": role, "file": other.attrs.get("lidarcal_source_file", ""),
                           "sha256": other.attrs.get("lidarcal_source_sha256")}
    for key, attr in (("kind", "lidarcal_artefact"), ("license", "license"), ("source", "source_data"),
                      ("source_license", "source_license"), ("source_file", "source_file"),
                      ("source_file_sha256", "source_file_sha256")):
        if other.attrs.get(attr):
            rec[key] = str(other.attrs[attr])
    seeds = read_json_attr(other, "lidarcal_seeds")
    if isinstance(seeds, dict) and seeds:
        rec["seeds"] = seeds
    nested = read_json_attr(other, "lidarcal_inputs")
    if isinstance(nested, list) and nested:
        rec["inputs"] = nested
    return rec


def _has_time(ds: xr.Dataset) -> str | None:
    for name, var in ds.variables.items():
        if var.dtype.kind == "M" and var.ndim == 1 and var.size and var.dims == (name,):
            return str(name)
    return None


def _iso(t: np.datetime64) -> str:
    return str(np.datetime_as_string(np.datetime64(t, "s"))) + "Z"


def _coverage_attrs(ds: xr.Dataset, attrs: dict[str, Any]) -> None:
    """ACDD time coverage from the time variable and vertical coverage from the heights."""
    name = _has_time(ds)
    if name is not None:  # (without one, lidarcal.io writes time_coverage_* as source_time_coverage_*)
        t = np.sort(ds[name].values)
        step = np.median(np.diff(t)) if t.size > 1 else None
        end = t[-1] + step if step is not None else t[-1]
        attrs["time_coverage_start"] = _iso(t[0])
        attrs["time_coverage_end"] = _iso(end)
        attrs["time_coverage_duration"] = f"PT{int((end - t[0]) / np.timedelta64(1, 's'))}S"
        if step is not None:
            attrs["time_coverage_resolution"] = f"PT{int(step / np.timedelta64(1, 's'))}S"
    heights = [v for v in ds.variables.values()
               if v.attrs.get("standard_name") == "height" and v.dtype.kind in "fiu" and v.size]
    if heights:
        attrs["geospatial_vertical_min"] = float(min(np.nanmin(v.values) for v in heights))
        attrs["geospatial_vertical_max"] = float(max(np.nanmax(v.values) for v in heights))
        attrs["geospatial_vertical_units"] = "m"
        attrs["geospatial_vertical_positive"] = "up"


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")


#: Site attributes an artefact inherits from its first input that has them (a measured
#: record's location and acknowledgment describe every product derived from it).
_CARRIED = ("acknowledgment", "geospatial_lat_min", "geospatial_lat_max", "geospatial_lon_min",
            "geospatial_lon_max", "geospatial_bounds", "geospatial_bounds_crs", "site", "location")


def stamp(
    ds: xr.Dataset,
    kind: str,
    *,
    title: str,
    summary: str,
    call: str,
    inputs: Mapping[str, str | os.PathLike] | None = None,
    input_datasets: Mapping[str, xr.Dataset] | None = None,
    config: Mapping[str, Any] | None = None,
    seeds: Mapping[str, Any] | None = None,
    keywords: str = "Doppler lidar, wind speed, calibration, uncertainty",
) -> xr.Dataset:
    """Return ``ds`` with lidarcal's provenance and ACDD-1.3 attributes set.

    Parameters
    ----------
    ds : xarray.Dataset
        The artefact.
    kind : str
        Artefact kind, the name of its schema in ``schemas/``.
    title, summary : str
        ACDD human-readable description.
    call : str
        What produced it, e.g. ``"lidarcal bench ingest rtd.csv control.csv"``.
    inputs : mapping of role to path, optional
        Input files; each is recorded with its SHA-256.
    input_datasets : mapping of role to Dataset, optional
        Input artefacts already opened; their ``history`` is carried over and their own
        recorded checksum (``lidarcal_source_sha256``) is used when they came from a file.
    config : mapping, optional
        The full configuration, recorded as JSON.
    seeds : mapping, optional
        Random seeds used, recorded as JSON.
    """
    now = _now()
    records = []
    for role, path in (inputs or {}).items():
        records.append({"role": role, "file": Path(path).name, "sha256": sha256(path)})
    past = []
    carried: dict[str, Any] = {}
    for role, other in (input_datasets or {}).items():
        digest = other.attrs.get("lidarcal_source_sha256")
        given = next((r for r in records if r["role"] == role), None)
        if given is not None:  # also given as a path: add what the dataset knows (its own chain)
            extra = _input_record(role, other)
            given.update({k: v for k, v in extra.items() if k not in ("role", "file", "sha256")})
        elif digest:
            records.append(_input_record(role, other))
        if other.attrs.get("history"):
            past.append(str(other.attrs["history"]))
        for key in _CARRIED:
            if key in other.attrs and key not in carried:
                carried[key] = other.attrs[key]
    history = merge_history(*past, f"[{now}] {call} - lidarcal version: {__version__}")

    out = ds.copy()
    attrs = {**carried, **{k: v for k, v in ds.attrs.items() if not k.startswith("lidarcal_source_")}}
    serial = attrs.get("lidar_serial")
    attrs.update(
        {
            "Conventions": CONVENTIONS,
            "title": title,
            "summary": summary,
            "keywords": keywords,
            "id": attrs.get("id", str(uuid.uuid4())),
            "naming_authority": "org.lidarcal",
            "date_created": now,
            "date_modified": now,
            "date_issued": now,
            **_contact_attrs(),
            "project": "lidarcal anemometer-free lidar calibration",
            "source": f"lidarcal {__version__}",
            "processing_level": kind,
            "product_version": __version__,
            "license": attrs.get("license", "CC-BY-4.0"),
            "standard_name_vocabulary": "CF Standard Name Table v93",
            "comment": attrs.get("comment", f"lidarcal {kind} artefact; its provenance (inputs with "
                                            "SHA-256, configuration, seeds, software) is in the "
                                            "lidarcal_* attributes"),
            "instrument": attrs.get("instrument", "pulsed Doppler wind lidar"
                                    + (f", serial {serial}" if serial else "")),
            "platform": attrs.get("platform", "fiber-optic calibration bench and Monte Carlo virtual lidar"),
            "history": history,
            "lidarcal_artefact": kind,
            "lidarcal_version": __version__,
            "lidarcal_software": json.dumps(software_versions(), sort_keys=True),
            "lidarcal_inputs": json.dumps(jsonable(records, strict=True), sort_keys=True),
            "lidarcal_config": json.dumps(jsonable(dict(config or {})), sort_keys=True),
            "lidarcal_seeds": json.dumps(jsonable(dict(seeds or {})), sort_keys=True),
        }
    )
    _coverage_attrs(ds, attrs)
    out.attrs = attrs
    return out
