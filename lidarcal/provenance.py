"""Provenance: ACDD-1.3 discovery attributes, history lines, checksums and configuration.

Every artefact lidarcal writes goes through :func:`stamp`, which records what produced it:
the artefact kind, the software versions, the full configuration, the seeds and the SHA-256
of every input file, and appends a ``history`` line in the xclim style
(``[timestamp] call - lidarcal version``) after the inputs' own history.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import uuid
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal import __version__

__all__ = ["sha256", "software_versions", "stamp", "read_json_attr", "jsonable", "CONVENTIONS"]

CONVENTIONS = "CF-1.11, ACDD-1.3"
_PACKAGES = ("lidarcal", "numpy", "scipy", "xarray", "dask", "netCDF4", "pint", "pint-xarray",
             "cf-xarray", "pyconturb")


def sha256(path: str | os.PathLike) -> str:
    """SHA-256 hex digest of a file, read in blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def software_versions() -> dict[str, str]:
    """Installed versions of lidarcal and the libraries that shape its numbers."""
    out = {}
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


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")


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
    for role, other in (input_datasets or {}).items():
        digest = other.attrs.get("lidarcal_source_sha256")
        if digest and not any(r["role"] == role for r in records):
            records.append({"role": role, "file": other.attrs.get("lidarcal_source_file", ""),
                            "sha256": digest})
        if other.attrs.get("history"):
            past.append(str(other.attrs["history"]).strip())
    history = "\n".join([*past, f"[{now}] {call} - lidarcal version: {__version__}"])

    out = ds.copy()
    attrs = {k: v for k, v in ds.attrs.items() if not k.startswith("lidarcal_source_")}
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
            "creator_name": os.environ.get("LIDARCAL_CREATOR", "lidarcal"),
            "creator_type": "institution",
            "institution": os.environ.get("LIDARCAL_INSTITUTION", "unspecified"),
            "project": "lidarcal anemometer-free lidar calibration",
            "source": f"lidarcal {__version__}",
            "processing_level": kind,
            "product_version": __version__,
            "license": attrs.get("license", "CC-BY-4.0"),
            "standard_name_vocabulary": "CF Standard Name Table v93",
            "history": history,
            "lidarcal_artefact": kind,
            "lidarcal_version": __version__,
            "lidarcal_software": json.dumps(software_versions(), sort_keys=True),
            "lidarcal_inputs": json.dumps(records, sort_keys=True),
            "lidarcal_config": json.dumps(jsonable(dict(config or {})), sort_keys=True),
            "lidarcal_seeds": json.dumps(jsonable(dict(seeds or {})), sort_keys=True),
        }
    )
    out.attrs = attrs
    return out
