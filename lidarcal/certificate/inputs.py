"""Checking that a certificate's inputs belong together before they are bundled.

Every input must be of the kind its role expects (:func:`check_kind`); inputs that name a lidar
must name the same one, and the budget and every sensitivity must have been computed from the
same records, following each input's provenance chain to any depth (:func:`check_consistent`),
so that a budget computed from records simulated with another bench cube or RWF is refused even
without the records themselves.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import xarray as xr

from lidarcal.errors import InputError
from lidarcal.provenance import lidar_serial, read_json_attr
from lidarcal.readback import read_attr

__all__ = ["check_kind", "check_consistent", "input_label"]


def input_label(role: str, ds: xr.Dataset) -> str:
    """Name an input in a message: its role and, when it came from a file, the file."""
    src = read_attr(ds, "lidarcal_source_file")
    return f"{role} ({src})" if src else role


def _find_key(obj: Any, key: str) -> Any:
    if isinstance(obj, Mapping):
        if key in obj:
            return obj[key]
        for v in obj.values():
            found = _find_key(v, key)
            if found is not None:
                return found
    elif isinstance(obj, list):
        for v in obj:
            found = _find_key(v, key)
            if found is not None:
                return found
    return None


def _serial(ds: xr.Dataset) -> str | None:
    if serial := lidar_serial(ds.attrs):
        return serial
    model = read_json_attr(ds, "lidarcal_lidar_model")
    found = _find_key(model, "lidar_serial") if model is not None else None
    return str(found) if found else None


def _records_of(ds: xr.Dataset) -> tuple[str | None, str] | None:
    """``(file, sha256)`` of the records ``ds`` was computed from, if it recorded them."""
    recorded = read_json_attr(ds, "lidarcal_inputs")
    for rec in recorded if isinstance(recorded, list) else []:
        if isinstance(rec, Mapping) and rec.get("role") == "records" and rec.get("sha256"):
            return rec.get("file"), str(rec["sha256"])
    return None


def check_consistent(inputs: Mapping[str, xr.Dataset]) -> str | None:
    """Refuse inputs that describe different lidars or were derived from other files.

    With or without the records themselves: every input naming a lidar must name the same
    one, and once any input names one, the budget and every sensitivity must name it too (a
    budget of unknown lidar cannot be vouched for with another lidar's cube); the budget and
    every sensitivity must have been computed from the same records file (by checksum).
    """
    serials = {role: s for role, ds in inputs.items() if (s := _serial(ds))}
    distinct = sorted(set(serials.values()))
    if len(distinct) > 1:
        pairs = [f"{input_label(r, inputs[r])} has lidar_serial {s!r}" for r, s in serials.items()]
        raise InputError("inputs disagree on the lidar: " + "; ".join(pairs))
    unnamed = [r for r in inputs if r not in serials and (r == "budget" or r.startswith("sensitivity_"))]
    if distinct and unnamed:
        named = ", ".join(f"{input_label(r, inputs[r])}" for r in serials)
        raise InputError(
            f"inputs may describe different lidars: {', '.join(input_label(r, inputs[r]) for r in unnamed)} "
            f"name(s) no lidar serial (their records did not record one), but {named} describe(s) "
            f"lidar {distinct[0]!r}; simulate the records with that lidar's cube (lidarcal simulate "
            "--cube) so that the budget and sensitivities carry its lidar_serial"
        )
    chains = {r: found for r, ds in inputs.items() if r != "records" and (found := _records_of(ds))}
    if len({sha for _, sha in chains.values()}) > 1:
        parts = [f"{input_label(r, inputs[r])} was computed from records {f!r} (sha256 {sha[:12]}...)"
                 for r, (f, sha) in chains.items()]
        raise InputError("inputs disagree on the records: " + "; ".join(parts))
    _check_chains(inputs)
    return distinct[0] if distinct else None


def _chain(recorded: Any, via: tuple[Mapping[str, Any], ...] = ()
           ) -> Iterable[tuple[tuple[Mapping[str, Any], ...], Mapping[str, Any]]]:
    """Every record of a provenance chain (``lidarcal_inputs``), with the records leading to it."""
    for rec in recorded if isinstance(recorded, list) else []:
        if isinstance(rec, Mapping):
            yield via, rec
            yield from _chain(rec.get("inputs"), (*via, rec))


def _check_chains(inputs: Mapping[str, xr.Dataset]) -> None:
    """Refuse an input whose provenance chain names another file in a role that was given.

    The chain is followed to any depth, so a budget computed from records simulated with
    another bench cube or RWF is refused without the records themselves (``--records``).
    """
    known = {role: str(sha) for role, ds in inputs.items()
             if (sha := read_attr(ds, "lidarcal_source_sha256"))}
    for role, ds in inputs.items():
        for via, rec in _chain(read_json_attr(ds, "lidarcal_inputs")):
            other, sha = rec.get("role"), rec.get("sha256")
            if other not in known or other == role or not sha or str(sha) == known[other]:
                continue
            steps = "".join(f"{hop.get('role')} {hop.get('file')!r} (sha256 {hop.get('sha256')}), which was "
                            "computed from " for hop in via)
            raise InputError(
                f"inputs disagree: {input_label(role, ds)} was computed from {steps}{other} "
                f"{rec.get('file')!r} (sha256 {sha}), but the {other} given is "
                f"{read_attr(inputs[other], 'lidarcal_source_file')!r} (sha256 {known[other]}); give the "
                f"{other} it was computed from, or recompute it from this one"
            )


def check_kind(role: str, ds: xr.Dataset, kinds: Iterable[str]) -> None:
    """Refuse an input stamped as another kind of artefact than ``kinds``."""
    kinds = tuple(kinds)
    found = read_attr(ds, "lidarcal_artefact")
    if found is not None and found not in kinds:
        raise InputError(
            f"{input_label(role, ds)}: is a {found!r} artefact; expected {' or '.join(map(repr, kinds))}"
        )
