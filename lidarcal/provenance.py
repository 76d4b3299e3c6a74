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

from lidarcal.cf import canonical_order
from lidarcal.errors import InputError
from lidarcal.readback import read_attr

__all__ = ["sha256", "software_versions", "stamp", "read_json_attr", "jsonable", "contact", "lidar_serial",
           "contact_attributes", "merge_history", "check_text", "text_problems",
           "CONVENTIONS", "CONTACT_ENV", "SITE_ENV", "USER_ATTRIBUTES", "ACDD_SPELLINGS", "REFERENCES"]

CONVENTIONS = "CF-1.11, ACDD-1.3"

#: The lidar's serial number is the global attribute ``lidar_serial``; field campaigns and
#: conditions read from .sta files wrote it as ``lidar_serial_number`` before it had one name.
#: Files written before are read through :func:`lidar_serial`.
LEGACY_SERIAL = "lidar_serial_number"


def _lidarcal_version() -> str:
    """Return lidarcal's version from its package metadata, as ``lidarcal.__version__`` reads it.

    Read here rather than imported from the package face, so that provenance (under every
    stage) stands on the package metadata alone; a checkout run without install has none and
    says ``0.0.0+unknown``, as the package face does.
    """
    try:
        return metadata.version("lidarcal")
    except metadata.PackageNotFoundError:  # running from a checkout without install
        return "0.0.0+unknown"


__version__ = _lidarcal_version()
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

#: The measurement site (decimal degrees, WGS 84) and the environment variable that sets each;
#: ``--site-latitude``/``--site-longitude`` override them.  Given, every artefact records
#: ``geospatial_lat/lon_*`` and a point ``geospatial_bounds``, with scalar ``latitude`` and
#: ``longitude`` coordinates (CF 5.7) that those attributes describe.  Never invented: without
#: them an artefact carries the site of an input that has one, or none.
SITE_ENV = {"site_latitude": "LIDARCAL_SITE_LATITUDE", "site_longitude": "LIDARCAL_SITE_LONGITUDE"}
_SITE_RANGE = {"site_latitude": (-90.0, 90.0), "site_longitude": (-180.0, 180.0)}

#: Further ACDD-1.3 attributes only the user can know (``--attribute NAME=VALUE``): recorded as
#: given in every file written.  Attributes lidarcal computes (dates, provenance, coverage) are
#: not among them.
USER_ATTRIBUTES = ("acknowledgement", "contributor_name", "contributor_role", "program", "metadata_link",
                   "keywords_vocabulary", "platform", "platform_vocabulary", "instrument",
                   "instrument_vocabulary", "geospatial_bounds_vertical_crs", "creator_institution",
                   "publisher_institution", "references", "license")

#: Spellings of older ACDD versions -> the ACDD-1.3 name lidarcal writes.  ACDD-1.3 spells it
#: ``acknowledgement`` (ACDD-1.1: ``acknowledgment``); the compliance checker accepts either.  A
#: user's ``--attribute acknowledgment=...``, or an input file carrying that spelling, is
#: written as ``acknowledgement``.
ACDD_SPELLINGS = {"acknowledgment": "acknowledgement"}

#: Characters no text lidarcal writes may hold: the C0 controls but tab, line feed and carriage
#: return; DEL and the C1 controls; the non-characters U+FFFE and U+FFFF; lone surrogates.  XML 1.0
#: (the DCC) cannot hold the C0 ones, and a terminal obeys escape sequences (U+001B) when
#: ``ncdump -h`` or ``lidarcal verify`` prints a sealed attribute.
_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ufffe\uffff\ud800-\udfff]")


def check_text(value: Any, where: str) -> str:
    """Return ``value`` as text, refusing a control character in it (:data:`_CONTROL`).

    Every text that enters an artefact from outside (the contact options and their environment
    variables, ``--attribute``, the administrative data) passes here, and every writer
    (:func:`text_problems` in :mod:`lidarcal.io`) checks again what it is about to write.

    Raises
    ------
    InputError
        Naming ``where``, the character (U+XXXX) and its position.
    """
    text = str(value)
    found = _CONTROL.search(text)
    if found is not None:
        raise InputError(f"{where}: contains the control character U+{ord(found.group()):04X} at position "
                         f"{found.start()} of {text!r}; text written into an artefact or a certificate may "
                         "hold no control characters (tab and line breaks only)")
    return text


def text_problems(ds: xr.Dataset) -> list[str]:
    """List every attribute of ``ds`` (global or of a variable) whose text holds a control character."""
    out = []
    owners = [("global attribute", ds.attrs), *((f"variable {name!r}: attribute", var.attrs)
                                                for name, var in ds.variables.items())]
    for what, attrs in owners:
        for key, value in attrs.items():
            if isinstance(value, str) and _CONTROL.search(value):
                found = _CONTROL.search(value)
                out.append(f"{what} {key!r} contains the control character U+{ord(found.group()):04X} "
                           f"at position {found.start()} of {value!r}")
    return out


#: The method every artefact implements (ACDD ``references``).
REFERENCES = ("Black, A., Franke, K., Trabucci, D., Allain, P. E., Lopez, L., Albers, A.: Anemometer-free "
              "indoor calibration of Doppler lidar using fiber optics and Monte Carlo simulation")


def sha256(path: str | os.PathLike) -> str:
    """SHA-256 hex digest of a file, read in blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def lidar_serial(attrs: Mapping[str, Any]) -> str | None:
    """Return the lidar serial number ``attrs`` record, or None.

    ``lidar_serial``; in a file written before the name was one, ``lidar_serial_number``.

    >>> lidar_serial({"lidar_serial_number": "WLS7-164"}), lidar_serial({"title": "t"})
    ('WLS7-164', None)
    """
    return read_attr(attrs, "lidar_serial")  # the legacy name is declared in schemas/bench_cube.yaml


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
    values = {ACDD_SPELLINGS.get(k, k): v for k, v in values.items()}
    known = {*CONTACT_ENV, *SITE_ENV, *USER_ATTRIBUTES}
    unknown = set(values) - known
    if unknown:
        raise TypeError(f"unknown contact attribute(s) {sorted(unknown)}; known: {sorted(known)}")
    for key in SITE_ENV:
        if values.get(key) is not None:
            _site_value(key, values[key], f"argument {key!r}")
    for key, value in values.items():
        if value is not None:
            check_text(value, f"{key} ({'--attribute' if key in USER_ATTRIBUTES else 'option'})")
    for key, env in CONTACT_ENV.items():  # the environment's too: refused before any work
        if values.get(key) is None and os.environ.get(env):
            check_text(os.environ[env], f"{key} (environment variable {env})")
    saved = dict(_contact_override)
    _contact_override.update({k: str(v) for k, v in values.items() if v is not None})
    try:
        yield
    finally:
        _contact_override.clear()
        _contact_override.update(saved)


def contact_attributes() -> dict[str, str]:
    """Return the contact attributes :func:`stamp` would record now (options, environment, defaults)."""
    return _contact_attrs()


def _contact_attrs() -> dict[str, str]:
    out = {}
    for key, env in CONTACT_ENV.items():
        value = _contact_override.get(key) or os.environ.get(env) or _CONTACT_DEFAULTS.get(key)
        if value:
            out[key] = check_text(value, f"{key} (option or environment variable {env})")
    if out.get("creator_name") and out["creator_name"] != "lidarcal":
        out["creator_type"] = "person"
    else:
        out["creator_type"] = "institution"
    if "publisher_name" in out:
        out["publisher_type"] = "institution"
        out["publisher_institution"] = out["publisher_name"]
    if out.get("institution") and out["institution"] != _CONTACT_DEFAULTS["institution"]:
        out["creator_institution"] = out["institution"]
    return out


def _site_value(key: str, value: Any, where: str) -> float:
    lo, hi = _SITE_RANGE[key]
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    if not lo <= number <= hi:
        raise InputError(f"{where}: expected a {key.split('_')[1]} in decimal degrees in [{lo:g}, {hi:g}]; "
                         f"found {value!r}")
    return number


def _site() -> tuple[float, float] | None:
    """Return the site the user gave (options or environment), or None."""
    found = {}
    for key, env in SITE_ENV.items():
        if _contact_override.get(key) is not None:
            found[key] = _site_value(key, _contact_override[key], f"--{key.replace('_', '-')}")
        elif os.environ.get(env):
            found[key] = _site_value(key, os.environ[env], f"environment variable {env}")
    if not found:
        return None
    if len(found) == 1:
        missing = next(k for k in SITE_ENV if k not in found)
        raise InputError(f"--{missing.replace('_', '-')}: the site needs both latitude and longitude; only "
                         f"{next(iter(found)).split('_')[1]} was given")
    return found["site_latitude"], found["site_longitude"]


def _site_attrs(lat: float, lon: float) -> dict[str, Any]:
    return {"geospatial_lat_min": lat, "geospatial_lat_max": lat, "geospatial_lon_min": lon,
            "geospatial_lon_max": lon, "geospatial_lat_units": "degrees_north",
            "geospatial_lon_units": "degrees_east", "geospatial_lat_resolution": "point",
            "geospatial_lon_resolution": "point", "geospatial_bounds": f"POINT ({lat:g} {lon:g})",
            "geospatial_bounds_crs": "EPSG:4326"}


def _site_coords(ds: xr.Dataset, attrs: Mapping[str, Any]) -> xr.Dataset:
    """Scalar ``latitude``/``longitude`` coordinates of a one-point site (CF 5.7), from ``attrs``."""
    try:
        lat, lon = float(attrs["geospatial_lat_min"]), float(attrs["geospatial_lon_min"])
    except (KeyError, TypeError, ValueError):
        return ds
    top = (float(attrs.get("geospatial_lat_max", lat)), float(attrs.get("geospatial_lon_max", lon)))
    if (lat, lon) != top:
        return ds  # an area, not a site: nothing to attach
    return ds.assign_coords(
        latitude=((), lat, {"standard_name": "latitude", "long_name": "latitude of the measurement site",
                            "units": "degrees_north", "axis": "Y"}),
        longitude=((), lon, {"standard_name": "longitude", "long_name": "longitude of the measurement site",
                             "units": "degrees_east", "axis": "X"}))


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
    rec: dict[str, Any] = {"role": role, "file": read_attr(other, "lidarcal_source_file", default=""),
                           "sha256": read_attr(other, "lidarcal_source_sha256")}
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
        levels = np.unique(np.concatenate([np.ravel(v.values) for v in heights]))
        steps = np.diff(levels[np.isfinite(levels)])
        attrs["geospatial_vertical_resolution"] = (
            "point" if steps.size == 0 else f"{steps[0]:g} m" if np.ptp(steps) == 0
            else f"{steps.min():g} to {steps.max():g} m (irregular levels)")


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat().replace("+00:00", "Z")


#: Site attributes an artefact inherits from its first input that has them (a measured
#: record's location and acknowledgement describe every product derived from it).
_CARRIED = ("acknowledgement", "acknowledgment", "geospatial_lat_min", "geospatial_lat_max",
            "geospatial_lon_min", "geospatial_lon_max", "geospatial_lat_units", "geospatial_lon_units",
            "geospatial_lat_resolution", "geospatial_lon_resolution", "geospatial_bounds",
            "geospatial_bounds_crs", "geospatial_bounds_vertical_crs", "site", "location")


_TIME_COVERAGE = ("time_coverage_start", "time_coverage_end")


def _from_inputs(inputs: Mapping[str, str | os.PathLike], input_datasets: Mapping[str, xr.Dataset],
                 ) -> tuple[list[dict], list[str], dict[str, Any], dict[str, Any]]:
    """Collect what :func:`stamp` takes from the inputs: records, histories, carried attributes, coverage."""
    records = [{"role": role, "file": Path(path).name, "sha256": sha256(path)}
               for role, path in inputs.items()]
    past = []
    carried: dict[str, Any] = {}
    coverage: dict[str, Any] = {}
    for role, other in input_datasets.items():
        digest = read_attr(other, "lidarcal_source_sha256")
        given = next((r for r in records if r["role"] == role), None)
        if given is not None:  # also given as a path: add what the dataset knows (its own chain)
            extra = _input_record(role, other)
            given.update({k: v for k, v in extra.items() if k not in ("role", "file", "sha256")})
        elif digest:
            records.append(_input_record(role, other))
        if other.attrs.get("history"):
            past.append(str(other.attrs["history"]))
        for key in _CARRIED:
            name = ACDD_SPELLINGS.get(key, key)  # written with the ACDD-1.3 spelling
            if key in other.attrs and name not in carried:
                carried[name] = other.attrs[key]
        if "time_coverage_start" in other.attrs and "time_coverage_end" in other.attrs:
            coverage = coverage or {k: other.attrs[k] for k in _TIME_COVERAGE if k in other.attrs}
    return records, past, carried, coverage


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
    """Return ``ds`` with lidarcal's provenance and ACDD-1.3 attributes set, in the canonical dim order.

    Every variable's dimensions are put in lidarcal's canonical order
    (:func:`lidarcal.cf.canonical_order`: other dims, then time, then height), so every artefact
    has the same order in memory and in its file.

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
    records, past, carried, coverage = _from_inputs(inputs or {}, input_datasets or {})
    history = merge_history(*past, f"[{now}] {call} - lidarcal version: {__version__}")

    out = canonical_order(ds)
    attrs = {**carried, **{k: v for k, v in ds.attrs.items() if not k.startswith("lidarcal_source_")}}
    for old, new in ACDD_SPELLINGS.items():  # one attribute, with the ACDD-1.3 spelling
        value = attrs.pop(old, None)
        if value is not None:
            attrs.setdefault(new, value)
    if _has_time(ds) is None and "time_coverage_start" not in attrs:
        # statistics over a period (a budget over a campaign) keep the period of their source
        # data; lidarcal.io writes it as source_time_coverage_* (ACDD ties time_coverage_* to a
        # time variable such an artefact does not have)
        attrs.update(coverage)
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
            "date_metadata_modified": now,
            "references": attrs.get("references", REFERENCES),
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
    attrs.update({k: v for k, v in _contact_override.items() if k in USER_ATTRIBUTES})  # --attribute
    site = _site()
    if site is not None:  # the user's site wins over one carried from an input
        attrs.update(_site_attrs(*site))
    _coverage_attrs(ds, attrs)
    old = [n for n in ("latitude", "longitude") if n in out.coords and out[n].ndim == 0]  # an input's site
    out = _site_coords(out.drop_vars(old), attrs)
    out.attrs = attrs
    return out
