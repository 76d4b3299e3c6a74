"""A certificate's status and administrative data: who issues it, for what, when and where.

Every certificate carries ``calibration_status``: ``"demonstration"`` when any input in its
provenance chain is lidarcal's embedded sample data (recognised by SHA-256, wherever the file
was copied) or a bench run made by ``lidarcal bench simulate`` (whose control log says
``data_origin: simulated ...``, carried into the cube's ``data_origin`` attribute), or when
the user asks for it; else ``"issued"``.  An issued certificate needs an issuer: a
laboratory (``--institution`` or ``laboratory.name``) and a responsible person
(``--creator`` or ``responsible_persons``).

The administrative data (docs/certificate.md) are read from one YAML file
(:func:`load_admin`) and/or given as options; they are stored as plain string global
attributes (named by :data:`ADMIN_FILE_KEYS`), sealed with the rest of the certificate, and are what
the report and the Digital Calibration Certificate (:mod:`lidarcal.certificate.dcc.export`) show.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import uuid
from collections.abc import Iterable, Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from lidarcal import __version__
from lidarcal.data import sample_data_dir
from lidarcal.errors import InputError
from lidarcal.provenance import REFERENCES, check_text, sha256

__all__ = ["ADMIN_FILE_KEYS", "DATE_ATTRIBUTES", "STATUS_ATTR", "STATUS_REASON_ATTR",
           "DEMONSTRATION", "ISSUED", "load_admin", "parse_admin", "sample_digests",
           "demonstration_reasons", "new_certificate_id", "merge_admin", "issuer_problem",
           "certificate_attributes", "default_method_reference", "status_line"]

STATUS_ATTR = "calibration_status"
STATUS_REASON_ATTR = "calibration_status_reason"
DEMONSTRATION = "demonstration"
ISSUED = "issued"

#: Keys of the administrative-data YAML file (``group.key`` for nested ones) and the global
#: attribute each is stored as (docs/certificate.md).
ADMIN_FILE_KEYS: dict[str, str] = {
    "certificate_id": "certificate_id",
    "item.manufacturer": "item_manufacturer",
    "item.model": "item_model",
    "item.serial_number": "item_serial_number",
    "item.firmware": "item_firmware",
    "laboratory.name": "laboratory_name",
    "laboratory.address": "laboratory_address",
    "laboratory.country_code": "laboratory_country_code",
    "responsible_persons": "responsible_persons",
    "customer.name": "customer_name",
    "customer.address": "customer_address",
    "calibration_location": "calibration_location",
    "bench.id": "bench_id",
    "bench.run_id": "bench_run_id",
    "bench.operator": "bench_operator",
    "bench.run_start": "bench_run_start",
    "bench.run_end": "bench_run_end",
    "bench.rf_driver_calibration_reference": "rf_driver_calibration_reference",
    "simulation_date": "simulation_date",
    "method_reference": "method_reference",
}
DATE_ATTRIBUTES = ("bench_run_start", "bench_run_end", "simulation_date")
#: The deepest the administrative data nests: the file's mapping, then a group (``laboratory:``)
#: or the list of ``responsible_persons``, then one person's mapping.  Deeper is refused before
#: it is built: a thousand nested lists made the reader recurse until Python gave up.
MAX_ADMIN_DEPTH = 3
#: The largest administrative-data file read (bytes): a few dozen short texts need far less.
MAX_ADMIN_BYTES = 1024 * 1024
_GROUPS = {key.split(".")[0] for key in ADMIN_FILE_KEYS if "." in key}


# ------------------------------------------------------------------ the YAML file


def _date(value: Any, where: str) -> str:
    """ISO 8601 date or date-time text of ``value``; InputError naming ``where`` otherwise."""
    if isinstance(value, _dt.datetime | _dt.date):
        return value.isoformat()
    text = str(value).strip()
    try:
        _dt.datetime.fromisoformat(text.replace("Z", "+00:00") if text.endswith("Z") else text)
    except ValueError:
        raise InputError(f"{where}: expected an ISO 8601 date or date-time (e.g. 2026-03-14 or "
                         f"2026-03-14T09:30:00Z); found {value!r}") from None
    return text


def _persons(value: Any, where: str) -> str:
    """``"Name (role); Name (role)"`` from a list of ``{name, role}`` mappings or strings."""
    items = value if isinstance(value, list) else str(value).split(";") if isinstance(value, str) else [value]
    out = []
    for i, item in enumerate(items):
        if isinstance(item, Mapping):
            unknown = set(item) - {"name", "role"}
            if unknown or not str(item.get("name") or "").strip():
                raise InputError(f"{where}[{i}]: expected a mapping with keys 'name' (required) and 'role'; "
                                 f"found {dict(item)!r}")
            role = str(item.get("role") or "").strip()
            out.append(f"{str(item['name']).strip()}{f' ({role})' if role else ''}")
        elif isinstance(item, str) and item.strip():
            out.append(item.strip())
        else:
            raise InputError(f"{where}[{i}]: expected 'Name (role)' text or a mapping {{name, role}}; "
                             f"found {item!r}")
    if any(";" in p for p in out):
        raise InputError(f"{where}: a person may not contain ';' (it separates persons); found {out!r}")
    return "; ".join(out)


def _value(attr: str, value: Any, where: str) -> str:
    return check_text(_typed(attr, value, where), where)


def _typed(attr: str, value: Any, where: str) -> str:
    if attr == "laboratory_country_code":
        if not (isinstance(value, str) and len(value) == 2 and value.isascii() and value.isupper()):
            raise InputError(f"{where}: expected an ISO 3166-1 alpha-2 country code (two capital letters, "
                             f"e.g. FR); found {value!r}")
        return value
    if attr in DATE_ATTRIBUTES:
        return _date(value, where)
    if attr == "responsible_persons":
        return _persons(value, where)
    if isinstance(value, Mapping | list) or value is None or not str(value).strip():
        raise InputError(f"{where}: expected a non-empty text or number; found {value!r}")
    return str(value).strip()


def _check_depth(data: Any, source: str) -> None:
    """Refuse data nested deeper than :data:`MAX_ADMIN_DEPTH` (walked without recursion)."""
    stack = [(data, 1)]
    while stack:
        obj, depth = stack.pop()
        if isinstance(obj, Mapping | list | tuple):
            if depth > MAX_ADMIN_DEPTH:
                raise InputError(f"{source}: administrative data nested deeper than {MAX_ADMIN_DEPTH} levels "
                                 "(the file's keys, a group or the list of persons, one person's keys); "
                                 "see docs/certificate.md for its keys")
            stack.extend((v, depth + 1) for v in (obj.values() if isinstance(obj, Mapping) else obj))


def _check_yaml_depth(text: str, source: str) -> None:
    """Refuse a YAML document nested deeper than :data:`MAX_ADMIN_DEPTH`, from its events (no recursion)."""
    depth = 0
    try:
        for event in yaml.parse(text, Loader=yaml.SafeLoader):
            if isinstance(event, yaml.CollectionStartEvent):
                depth += 1
                if depth > MAX_ADMIN_DEPTH:
                    line = event.start_mark.line + 1 if event.start_mark is not None else "?"
                    raise InputError(f"{source}: line {line}: administrative data nested deeper than "
                                     f"{MAX_ADMIN_DEPTH} levels (the file's keys, a group or the list of "
                                     "persons, one person's keys); see docs/certificate.md for its keys")
            elif isinstance(event, yaml.CollectionEndEvent):
                depth -= 1
    except yaml.YAMLError as exc:
        raise InputError(f"{source}: not a readable YAML file: {exc}") from None


def parse_admin(data: Any, source: str = "<admin>") -> dict[str, str]:
    """Validate the content of an administrative-data file; return ``{attribute: text}``.

    Raises
    ------
    InputError
        Naming ``source`` and the key, for an unknown key, a bad date, a value of the
        wrong type, a control character in a text or data nested deeper than
        :data:`MAX_ADMIN_DEPTH`.
    """
    if data is None:
        return {}
    _check_depth(data, source)
    if not isinstance(data, Mapping):
        raise InputError(f"{source}: expected a mapping of administrative data (docs/certificate.md); "
                         f"found {type(data).__name__}")
    out: dict[str, str] = {}
    known = sorted({k.split(".")[0] for k in ADMIN_FILE_KEYS})
    for key, value in data.items():
        key = str(key)
        if key in _GROUPS:
            if not isinstance(value, Mapping):
                subkeys = sorted(k.split(".")[1] for k in ADMIN_FILE_KEYS if k.startswith(key + "."))
                raise InputError(f"{source}: key '{key}': expected a mapping with keys {subkeys}; "
                                 f"found {value!r}")
            for sub, inner in value.items():
                full = f"{key}.{sub}"
                if full not in ADMIN_FILE_KEYS:
                    allowed = sorted(k.split(".")[1] for k in ADMIN_FILE_KEYS if k.startswith(key + "."))
                    raise InputError(f"{source}: unknown key '{full}'; '{key}' has keys {allowed}")
                out[ADMIN_FILE_KEYS[full]] = _value(ADMIN_FILE_KEYS[full], inner, f"{source}: key '{full}'")
        elif key in ADMIN_FILE_KEYS:
            out[ADMIN_FILE_KEYS[key]] = _value(ADMIN_FILE_KEYS[key], value, f"{source}: key '{key}'")
        else:
            raise InputError(f"{source}: unknown key '{key}'; expected one of {known} (docs/certificate.md)")
    return out


def load_admin(path: str | os.PathLike) -> dict[str, str]:
    """Read and validate an administrative-data YAML file (docs/certificate.md)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: administrative-data file not found" if not path.exists()
                         else f"{path}: administrative-data path is not a file")
    if path.stat().st_size > MAX_ADMIN_BYTES:
        raise InputError(f"{path}: administrative-data file of {path.stat().st_size} bytes; expected at most "
                         f"{MAX_ADMIN_BYTES} (a few dozen short texts)")
    try:
        text = path.read_text(encoding="utf-8")
        _check_yaml_depth(text, str(path))
        data = yaml.safe_load(text)
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable YAML file: {exc}") from None
    return parse_admin(data, str(path))


def merge_admin(*parts: Mapping[str, Any], source: str = "options") -> dict[str, str]:
    """Later parts win; each value validated like a file's (dates, persons)."""
    out: dict[str, str] = {}
    for part in parts:
        for attr, value in part.items():
            if value is None:
                continue
            if attr not in ADMIN_FILE_KEYS.values():
                raise InputError(f"{source}: unknown administrative attribute {attr!r}; expected one of "
                                 f"{sorted(ADMIN_FILE_KEYS.values())}")
            out[attr] = _value(attr, value, f"{source}: {attr}")
    return out


def new_certificate_id() -> str:
    """Return a new unique certificate id (random UUID)."""
    return f"lidarcal-{uuid.uuid4()}"


# ------------------------------------------------------------------ status


@lru_cache(maxsize=1)
def _sample_digests(root: str) -> dict[str, str]:
    base = Path(root)
    return {sha256(p): p.relative_to(base).as_posix() for p in sorted(base.rglob("*"))
            if p.is_file() and not p.name.endswith((".md", ".py"))}


def sample_digests() -> dict[str, str]:
    """SHA-256 -> path (inside ``sample_data/``) of every embedded sample input file."""
    return dict(_sample_digests(str(sample_data_dir())))


def _walk(obj: Any) -> Iterable[Mapping[str, Any]]:
    if isinstance(obj, Mapping):
        yield obj
        for value in obj.values():
            yield from _walk(value)
    elif isinstance(obj, list):
        for value in obj:
            yield from _walk(value)


def demonstration_reasons(attrs: Mapping[str, Any], extra: Iterable[Mapping[str, Any]] = ()) -> list[str]:
    """Why a certificate with these global attributes is a demonstration (empty: it is not).

    Every record of the provenance (``lidarcal_provenance_chain``, ``lidarcal_inputs``,
    ``lidarcal_components`` and ``extra``), however deep, is searched for a SHA-256 of an
    embedded sample file and for a ``data_origin`` saying the bench run was simulated (the bench
    stage writes :data:`lidarcal.bench.simulator.SIMULATED_ORIGIN`; this module, beneath every
    stage, knows it by its word "simulated").
    """
    trees = []
    for name in ("lidarcal_provenance_chain", "lidarcal_inputs", "lidarcal_components"):
        try:
            trees.append(json.loads(attrs[name]))
        except (KeyError, TypeError, ValueError):
            continue
    digests = sample_digests()
    reasons: list[str] = []
    for record in _walk([*trees, *extra, dict(attrs)]):
        digest = record.get("sha256")
        if isinstance(digest, str) and digest in digests:
            name = record.get("file") or digests[digest]
            why = f"input {name} is lidarcal's embedded sample file sample_data/{digests[digest]}"
            if why not in reasons:
                reasons.append(why)
        origin = record.get("data_origin")
        if isinstance(origin, str) and "simulated" in origin:
            why = f"the bench run was {origin}"
            if why not in reasons:
                reasons.append(why)
    return reasons


def issuer_problem(attrs: Mapping[str, Any]) -> str | None:
    """Say what an issued certificate with these attributes lacks to name its issuer (None: nothing)."""
    missing = []
    if not str(attrs.get("laboratory_name") or "").strip():
        missing.append("the laboratory (--institution NAME, or laboratory.name in --admin ADMIN.yaml)")
    if not str(attrs.get("responsible_persons") or "").strip():
        missing.append("a responsible person (--creator NAME, or responsible_persons in --admin ADMIN.yaml)")
    if not missing:
        return None
    return ("an issued certificate needs an issuer: it does not name " + " nor ".join(missing)
            + "; give them, or --demonstration for a demonstration certificate")


#: Administrative attributes that the certificate's own data also state: a value given by the
#: user must agree with them.
_IDENTITY = ("item_serial_number", "bench_id", "bench_run_id", "bench_operator")


def default_method_reference(approach: str, config: Mapping[str, Any] | None = None) -> str:
    """Describe the method: the paper, lidarcal's version and the options that change the numbers."""
    cfg = {k: v for k, v in (config or {}).items()
           if k in ("periods", "base_seed", "seed", "min_periods", "los_noise_model", "los_noise", "terms",
                    "noise_terms", "fft_size", "heights") and v not in (None, {}, [])}
    options = ", ".join(f"{k}={v}" for k, v in cfg.items())
    return (f"{REFERENCES}; lidarcal {__version__}; uncertainty budget approach {approach}"
            + (f"; options {options}" if options else "")
            + "; the full configuration is in lidarcal_config and lidarcal_provenance_chain")


def certificate_attributes(attrs: Mapping[str, Any], given: Mapping[str, str] | None = None, *,
                           derived: Mapping[str, str] | None = None, demonstration: bool = False,
                           source: str = "administrative data",
                           provenance: Iterable[Mapping[str, Any]] = ()) -> dict[str, str]:
    """Status and administrative attributes of a certificate with global attributes ``attrs``.

    ``given`` (from :func:`load_admin` and the options) wins over ``derived`` (what the data
    state: lidar serial, bench id and run, dates); an identity (lidar serial, bench id, run,
    operator) that contradicts the data is refused.  ``laboratory_name`` and
    ``responsible_persons`` default to the ACDD ``institution`` and ``creator_name`` when those
    were given.  The status is ``demonstration`` when asked for or when
    :func:`demonstration_reasons` finds a reason (in ``attrs`` and the ``provenance`` records:
    a certificate's chain and components, which its attributes only point to), else ``issued``,
    which needs an issuer.

    Raises
    ------
    InputError
        A contradiction with the data, or an issued certificate without an issuer.
    """
    given = dict(given or {})
    derived = {k: v for k, v in (derived or {}).items() if v not in (None, "")}
    for key in _IDENTITY:
        if key in given and key in derived and str(given[key]) != str(derived[key]):
            raise InputError(f"{source}: {key} {given[key]!r} contradicts the certificate's data, which "
                             f"state {derived[key]!r}")
    out = {**derived, **given}
    institution, creator = attrs.get("institution"), attrs.get("creator_name")
    if institution and institution != "unspecified":
        out.setdefault("laboratory_name", str(institution))
    if creator and creator != "lidarcal":
        out.setdefault("responsible_persons", str(creator))
    out.setdefault("certificate_id", new_certificate_id())
    reasons = demonstration_reasons(attrs, provenance)
    if demonstration:
        reasons.insert(0, "demonstration status requested (--demonstration)")
    if reasons:
        out[STATUS_ATTR] = DEMONSTRATION
        out[STATUS_REASON_ATTR] = "; ".join(reasons)
    else:
        out[STATUS_ATTR] = ISSUED
        problem = issuer_problem(out)
        if problem:
            raise InputError(problem)
    return out


def status_line(attrs: Mapping[str, Any]) -> str:
    """One line saying a certificate's status first (for verify, table, report, DCC)."""
    status = attrs.get(STATUS_ATTR)
    cid = attrs.get("certificate_id")
    ident = f" {cid}" if cid else ""
    if status == DEMONSTRATION:
        why = attrs.get(STATUS_REASON_ATTR)
        return (f"DEMONSTRATION certificate{ident}: not a calibration of a real instrument"
                + (f" ({why})" if why else ""))
    if status == ISSUED:
        by = "; ".join(str(attrs[k]) for k in ("responsible_persons", "laboratory_name") if attrs.get(k))
        return f"ISSUED certificate{ident}" + (f", issued by {by}" if by else "")
    return "status not stated (a certificate written before lidarcal recorded calibration_status)"
