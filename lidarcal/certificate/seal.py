"""The certificate's seal: an integrity record, an optional Ed25519 signature, and their check.

:func:`write_certificate` writes a certificate atomically and seals it; :func:`integrity_record`
defines the canonical byte forms the seal digests (so the record can be re-checked with any
netCDF library); :func:`verify_certificate` (``lidarcal verify``) recomputes them and checks a
signature against a trusted public key.  Building the certificate itself is
:mod:`lidarcal.certificate`.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

from lidarcal.certificate.signing import (
    ALGORITHM,
    fingerprint,
    load_private_key,
    load_public_key,
    sign,
    verify_signature,
)
from lidarcal.errors import InputError, SealError
from lidarcal.io import (
    atomic_path,
    check_input_file,
    check_writable,
    open_artefact,
    open_image,
    read_image,
    write_into,
)
from lidarcal.readback import read_attr
from lidarcal.schema import validate_dataset

INTEGRITY_ATTR = "lidarcal_integrity"
#: Signature attributes: the signature itself is not covered by the seal (it signs the seal);
#: the key it claims and the algorithm are.
SIGNATURE_ATTR = "lidarcal_signature"
SIGNATURE_KEY_ATTR = "lidarcal_signature_key"
SIGNATURE_PUBLIC_KEY_ATTR = "lidarcal_signature_public_key"
SIGNATURE_ALGORITHM_ATTR = "lidarcal_signature_algorithm"
CANONICAL_FORM = (
    "data: sha256(json({dims, dtype, shape}) + newline + values), values read without masking or "
    "scaling, numeric in little-endian C order, strings UTF-8 joined by NUL; attributes: "
    "sha256(json(sorted {name: value}, strings as is, numbers as {dtype, values})); "
    "global attributes: one digest each, excluding lidarcal_integrity and lidarcal_signature"
)
#: The seal's second form (``"format": 2``), written since the seal had to read as text in
#: ``ncdump -h``: the same digests as :data:`CANONICAL_FORM`, but ``lidarcal_integrity`` keeps only
#: their root and each variable carries its own digests.  Certificates sealed in the first form
#: (the whole record in ``lidarcal_integrity``) verify as before.
CANONICAL_FORM_2 = (
    CANONICAL_FORM + ", " + "lidarcal_integrity_attributes and every variable's lidarcal_sha256 and "
    "lidarcal_bounds_sha256 (a bounds variable's digests, on its parent) "
    "(the stored digests, which only locate a change); root: sha256(json(sorted {dimensions: {name: "
    "length}, variables: {name: {data, attributes}}, global_attributes: {name: digest}})); each "
    "variable's lidarcal_sha256 is 'data <hex> attributes <hex>', lidarcal_integrity_attributes "
    "'<name> <first 12 hex>' joined by '; '"
)
SEAL_FORMAT = 2
#: Per-variable digests (second form), and the global attributes' digest prefixes.
VARIABLE_DIGEST_ATTR = "lidarcal_sha256"
#: A bounds variable's digests sit on its parent (CF 7.1: bounds carry no attributes of their own).
BOUNDS_DIGEST_ATTR = "lidarcal_bounds_sha256"
_DIGEST_ATTRS = (VARIABLE_DIGEST_ATTR, BOUNDS_DIGEST_ATTR)
ATTRIBUTE_DIGESTS_ATTR = "lidarcal_integrity_attributes"
_PREFIX = 12

# ------------------------------------------------------------------ integrity


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _canonical_attr(value: Any) -> Any:
    if isinstance(value, str):
        return value
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    arr = np.asarray(value)
    values = arr.tolist()
    return {
        "dtype": arr.dtype.newbyteorder("<").str if arr.dtype.kind in "iuf" else arr.dtype.kind,
        "values": values if not (arr.dtype.kind == "f") else [repr(float(v)) for v in np.ravel(arr)],
    }


def _attrs_digest(obj, names: Iterable[str]) -> str:
    canon = {n: _canonical_attr(obj.getncattr(n)) for n in sorted(names)}
    return _sha(json.dumps(canon, sort_keys=True, ensure_ascii=False).encode("utf-8"))


def _data_digest(var) -> str:
    var.set_auto_maskandscale(False)
    if hasattr(var, "set_auto_chartostring"):
        var.set_auto_chartostring(False)
    data = np.asarray(var[...])
    shape = list(var.shape)
    if data.dtype.kind in "OU":
        payload = b"\0".join(str(x).encode("utf-8") for x in data.ravel(order="C"))
        dtype = "str"
    else:
        arr = np.ascontiguousarray(data)
        if arr.dtype.kind in "iuf" and arr.dtype.byteorder == ">":
            arr = arr.astype(arr.dtype.newbyteorder("<"))
        dtype = arr.dtype.newbyteorder("<").str if arr.dtype.kind in "iuf" else arr.dtype.str
        payload = arr.tobytes(order="C")
    header = json.dumps({"dims": list(var.dimensions), "dtype": dtype, "shape": shape}, sort_keys=True)
    return _sha(header.encode("utf-8") + b"\n" + payload)


def integrity_record(path: str | os.PathLike) -> dict[str, Any]:
    """Compute the integrity record of a netCDF file as stored (see :data:`CANONICAL_FORM`)."""
    import netCDF4

    with netCDF4.Dataset(path, "r") as nc:
        return _record(nc, path)


def _record(nc, path: str | os.PathLike) -> dict[str, Any]:
    """Compute the integrity record of the open netCDF file ``nc`` (read from ``path``)."""
    if nc.groups:
        raise InputError(f"{path}: has netCDF groups; a lidarcal certificate is flat")
    variables = {
        name: {"data": _data_digest(var),
               "attributes": _attrs_digest(var, [n for n in var.ncattrs() if n not in _DIGEST_ATTRS])}
        for name, var in nc.variables.items()
    }
    unsealed = (INTEGRITY_ATTR, SIGNATURE_ATTR, ATTRIBUTE_DIGESTS_ATTR)
    glob = {n: _attrs_digest(nc, [n]) for n in nc.ncattrs() if n not in unsealed}
    dims = {name: len(d) for name, d in nc.dimensions.items()}
    return {
        "algorithm": "sha256",
        "canonical_form": CANONICAL_FORM,
        "dimensions": dims,
        "variables": variables,
        "global_attributes": glob,
    }


def seal_root(record: Mapping[str, Any]) -> str:
    """Return the root digest of an integrity record (what a second-form seal stores, a signature covers)."""
    body = {key: record[key] for key in ("dimensions", "variables", "global_attributes")}
    return _sha(json.dumps(body, sort_keys=True, ensure_ascii=False).encode("utf-8"))


def _bounds_parents(nc) -> dict[str, str]:
    """Map each bounds variable of an open netCDF file to the variable whose ``bounds`` names it."""
    return {str(var.getncattr("bounds")): name for name, var in nc.variables.items()
            if "bounds" in var.ncattrs() and str(var.getncattr("bounds")) in nc.variables}


def _seal(path: str | os.PathLike) -> str:
    """Seal the file at ``path`` in the second form and return the text of its ``lidarcal_integrity``."""
    import netCDF4

    record = integrity_record(path)
    with netCDF4.Dataset(path, "a") as nc:
        parents = _bounds_parents(nc)
        for name, digests in record["variables"].items():
            text = f"data {digests['data']} attributes {digests['attributes']}"
            if name in parents:
                nc[parents[name]].setncattr(BOUNDS_DIGEST_ATTR, text)
            else:
                nc[name].setncattr(VARIABLE_DIGEST_ATTR, text)
        nc.setncattr(ATTRIBUTE_DIGESTS_ATTR, "; ".join(
            f"{name} {digest[:_PREFIX]}" for name, digest in sorted(record["global_attributes"].items())))
    return json.dumps({"format": SEAL_FORMAT, "algorithm": "sha256", "canonical_form": CANONICAL_FORM_2,
                       "dimensions": record["dimensions"], "variables": len(record["variables"]),
                       "global_attributes": len(record["global_attributes"]), "root": seal_root(record)},
                      sort_keys=True)


def write_certificate(cert: xr.Dataset, path: str | os.PathLike, *, overwrite: bool = False,
                      signing_key: str | os.PathLike | Ed25519PrivateKey | None = None) -> Path:
    """Validate, write atomically and seal a certificate; never replaces a file silently.

    With ``signing_key`` (an Ed25519 private key or the path of one, see :mod:`lidarcal.certificate.signing`)
    the seal is also signed: the key's fingerprint and public key are written first (so the
    seal covers them), then the seal, then the signature of the seal's text.
    """
    import netCDF4

    if signing_key is not None and not isinstance(signing_key, Ed25519PrivateKey):
        signing_key = load_private_key(signing_key)

    if (kind := read_attr(cert, "lidarcal_artefact")) != "certificate":
        raise InputError(
            f"{path}: dataset is a {kind!r} artefact, not a certificate"
        )
    path = check_writable(path, overwrite=overwrite)
    with atomic_path(path, overwrite=overwrite) as tmp:
        write_into(cert, tmp, target=path)  # into this temporary: never a temporary of it
        if signing_key is not None:
            public = signing_key.public_key().public_bytes(Encoding.Raw, PublicFormat.Raw)
            with netCDF4.Dataset(tmp, "a") as nc:
                nc.setncattr(SIGNATURE_ALGORITHM_ATTR, ALGORITHM)
                nc.setncattr(SIGNATURE_KEY_ATTR, fingerprint(signing_key))
                nc.setncattr(SIGNATURE_PUBLIC_KEY_ATTR, base64.b64encode(public).decode("ascii"))
        seal = _seal(tmp)
        with netCDF4.Dataset(tmp, "a") as nc:
            nc.setncattr(INTEGRITY_ATTR, seal)
            if signing_key is not None:
                nc.setncattr(SIGNATURE_ATTR, sign(signing_key, seal))
    return path


@dataclass
class VerificationReport:
    """Outcome of :func:`verify_certificate`."""

    path: str
    problems: list[str] = field(default_factory=list)
    variables_checked: int = 0
    attributes_checked: int = 0
    #: fingerprint of the key whose valid signature the seal carries; None when unsigned
    signed_by: str | None = None
    #: True when that key is the public key the caller gave (not only the one in the file)
    key_trusted: bool = False
    #: True when a public key was given but the certificate carries no signature at all (the
    #: one problem then: its seal may match its contents)
    unsigned: bool = False

    @property
    def intact_but_unsigned(self) -> bool:
        """True when the only problem is the missing signature a public key asked for: the seal holds."""
        return self.unsigned and len(self.problems) == 1

    @property
    def ok(self) -> bool:
        """True when nothing was altered and the schema is satisfied."""
        return not self.problems


def _check_signature(report: VerificationReport, attrs: Mapping[str, Any],
                     trusted: Ed25519PublicKey | None) -> None:
    """Check the signature of the seal ``attrs[INTEGRITY_ATTR]`` (see :func:`verify_certificate`)."""
    signature, claimed = attrs.get(SIGNATURE_ATTR), attrs.get(SIGNATURE_KEY_ATTR)
    if signature is None:
        if claimed is not None:
            report.problems.append(f"global attribute {SIGNATURE_ATTR!r} is missing, but the certificate "
                                   f"names a signing key ({claimed}): the signature was removed")
        elif trusted is not None:
            report.unsigned = True
            report.problems.append(f"unsigned (integrity only), but a public key was given: expected a "
                                   f"signature by {fingerprint(trusted)}")
        return
    key = trusted
    if key is None:
        try:
            embedded = base64.b64decode(str(attrs.get(SIGNATURE_PUBLIC_KEY_ATTR, "")))
            key = Ed25519PublicKey.from_public_bytes(embedded)
        except ValueError:
            report.problems.append(f"signed, but global attribute {SIGNATURE_PUBLIC_KEY_ATTR!r} is not an "
                                   "Ed25519 public key; pass the signer's public key (--public-key)")
            return
    if claimed != fingerprint(key):
        whose = "the given public key" if trusted is not None else "the public key stored in the file"
        report.problems.append(f"signed by {claimed}, not by {whose} ({fingerprint(key)})")
    elif not verify_signature(key, str(attrs.get(INTEGRITY_ATTR)), str(signature)):
        report.problems.append(f"signature by {claimed} does not match the seal: the file was re-sealed "
                               "or the signature altered")
    else:
        report.signed_by, report.key_trusted = claimed, trusted is not None


def _changes(exp_vars: Mapping[str, Any], exp_glob: Mapping[str, Any], found: Mapping[str, Any]) -> list[str]:
    """Name every variable and global attribute whose digest differs from the sealed one."""
    problems = []
    for name in sorted(set(exp_vars) | set(found["variables"])):
        if name not in found["variables"]:
            problems.append(f"variable {name!r} was removed")
        elif name not in exp_vars:
            problems.append(f"variable {name!r} was added")
        else:
            if exp_vars[name]["data"] != found["variables"][name]["data"]:
                problems.append(f"variable {name!r}: values altered")
            if exp_vars[name]["attributes"] != found["variables"][name]["attributes"]:
                problems.append(f"variable {name!r}: attributes altered")
    for name in sorted(set(exp_glob) | set(found["global_attributes"])):
        if name not in found["global_attributes"]:
            problems.append(f"global attribute {name!r} was removed")
        elif name not in exp_glob:
            problems.append(f"global attribute {name!r} was added")
        elif exp_glob[name] != found["global_attributes"][name]:
            problems.append(f"global attribute {name!r} altered")
    return problems


def _changes_against_root(nc, expected: Mapping[str, Any], found: Mapping[str, Any]) -> list[str]:
    """Check a second-form seal of the open file ``nc``.

    The root decides; the stored per-item digests say what changed.
    """
    if seal_root(found) == expected["root"]:
        return []
    exp_vars: dict[str, Any] = {}
    parents = _bounds_parents(nc)
    for name, var in nc.variables.items():
        holder, attr = ((nc[parents[name]], BOUNDS_DIGEST_ATTR) if name in parents
                        else (var, VARIABLE_DIGEST_ATTR))
        text = str(holder.getncattr(attr)) if attr in holder.ncattrs() else ""
        parts = text.split()
        if len(parts) == 4 and parts[0] == "data" and parts[2] == "attributes":
            exp_vars[name] = {"data": parts[1], "attributes": parts[3]}
    listed = str(nc.getncattr(ATTRIBUTE_DIGESTS_ATTR)) if ATTRIBUTE_DIGESTS_ATTR in nc.ncattrs() else ""
    exp_glob = dict(item.rsplit(" ", 1) for item in listed.split("; ") if " " in item)
    found_glob = {name: digest[:_PREFIX] for name, digest in found["global_attributes"].items()}
    problems = _changes(exp_vars, exp_glob,
                        {"variables": found["variables"], "global_attributes": found_glob})
    missing = int(expected["variables"]) - len(exp_vars)
    if missing > 0:
        problems.append(f"{missing} variable(s) removed ({expected['variables']} sealed, "
                        f"{len(exp_vars)} of them found)")
    if not problems:  # the stored digests were rewritten to match: only the root can tell
        problems.append("contents do not match the seal's root digest (the per-variable digests were "
                        "rewritten too)")
    return problems


def verify_certificate(path: str | os.PathLike, *,
                       public_key: str | os.PathLike | Ed25519PublicKey | None = None,
                       image: bytes | None = None) -> VerificationReport:
    """Recompute a certificate's checksums, signature and schema; list everything that changed.

    An unsigned certificate is checked for integrity only (a re-sealed file passes).  A signed
    one is checked against ``public_key`` (a path or key) when given -- the only check a
    forger cannot pass -- else against the public key stored in the file, which shows the
    file is as that key's holder sealed it but not who that is (compare ``signed_by`` with a
    fingerprint you trust).  With ``public_key`` an unsigned file is a problem.  ``image``: the
    file's bytes when the caller has read them already (:func:`lidarcal.io.read_image`), so the
    bytes checked are the bytes it uses.

    Raises
    ------
    InputError
        If ``path`` is missing, unreadable or not a lidarcal certificate.
    """
    path = check_input_file(path, "certificate file")  # missing, a directory, a FIFO: refused here
    # one read of the file, every check on those bytes in memory: a second open of the file on
    # disk while the caller holds one (open_certificate, a Dataset passed to result_table) can
    # crash netCDF-C (io.open_image), and the bytes checked are the bytes read
    image = read_image(path, "certificate file") if image is None else image
    with open_image(path, image) as nc:
        kind = nc.getncattr("lidarcal_artefact") if "lidarcal_artefact" in nc.ncattrs() else None
        if kind != "certificate":
            what = (f"a {kind!r} artefact" if kind
                    else "not a lidarcal artefact (no 'lidarcal_artefact' attribute)")
            raise InputError(f"{path}: not a lidarcal certificate: it is {what}")
        report = _verify_open(nc, path, public_key)
    if report.variables_checked:  # the seal could be read: the schema too
        ds = open_artefact(path, load=False, chunks={}, image=image)
        try:
            report.problems.extend(f"schema: {p}" for p in validate_dataset(ds, "certificate",
                                                                              source=str(path)))
        finally:
            ds.close()
    return report


def _verify_open(nc, path: Path, public_key) -> VerificationReport:
    """Check the seal and signature of the open file ``nc`` (:func:`verify_certificate`)."""
    stored = nc.getncattr(INTEGRITY_ATTR) if INTEGRITY_ATTR in nc.ncattrs() else None
    signature_attrs = {n: nc.getncattr(n) for n in nc.ncattrs() if n.startswith(SIGNATURE_ATTR)}
    trusted = public_key
    if trusted is not None and not isinstance(trusted, Ed25519PublicKey):
        trusted = load_public_key(trusted)
    report = VerificationReport(str(path))
    if stored is None:
        report.problems.append(
            f"global attribute {INTEGRITY_ATTR!r} is missing: the certificate was never "
            "sealed or the seal was removed"
        )
        return report
    try:
        expected = json.loads(stored)
        if not isinstance(expected, dict):
            raise TypeError(type(expected))
        if expected.get("format") == SEAL_FORMAT:
            expected["root"], int(expected["variables"]), int(expected["global_attributes"])
        else:
            exp_vars, exp_glob = expected["variables"], expected["global_attributes"]
    except (ValueError, KeyError, TypeError):
        report.problems.append(f"global attribute {INTEGRITY_ATTR!r} is not a valid integrity record")
        return report
    found = _record(nc, path)
    if expected.get("format") == SEAL_FORMAT:
        report.problems.extend(_changes_against_root(nc, expected, found))
    else:
        report.problems.extend(_changes(exp_vars, exp_glob, found))
    if expected.get("dimensions") not in (None, found["dimensions"]):
        report.problems.append(f"dimensions changed: {expected['dimensions']} -> {found['dimensions']}")
    report.variables_checked = len(found["variables"])
    report.attributes_checked = len(found["global_attributes"])
    _check_signature(report, {**signature_attrs, INTEGRITY_ATTR: stored}, trusted)
    return report


# ------------------------------------------------------------------ showing a certificate's numbers


def _certificate_file(obj: str | os.PathLike | xr.Dataset, source: str | os.PathLike | None) -> Path | None:
    if source is not None:
        return Path(source)
    if isinstance(obj, str | os.PathLike):
        return Path(obj)
    found = obj.encoding.get("source")
    return Path(found) if found else None


def require_valid_seal(obj: str | os.PathLike | xr.Dataset, *, source: str | os.PathLike | None = None,
                       public_key: str | os.PathLike | Ed25519PublicKey | None = None,
                       allow_invalid: bool = False, image: bytes | None = None) -> VerificationReport | None:
    """Check a certificate's seal before any of its numbers are shown; refuse a broken one.

    Every command and function that displays a certificate's values (``lidarcal table``, the
    HTML report, exports) calls this first.  ``obj`` is the certificate file or a Dataset read
    from one (its file is ``source``, else the path xarray opened it from); the file is checked
    as :func:`verify_certificate` does (with ``public_key`` when given).  A Dataset that was
    never sealed and came from no file (a certificate being built, before
    :func:`write_certificate`) has nothing to check: None is returned.  ``image``: the file's
    bytes, already read by the caller (:func:`verify_certificate`).

    Returns
    -------
    VerificationReport or None
        The report; with ``allow_invalid`` it may list problems, and the caller must show
        :func:`invalid_seal_banner` with the numbers.

    Raises
    ------
    SealError
        The seal or signature does not match the contents, the file is not sealed, or a sealed
        Dataset's file cannot be found to check (unless ``allow_invalid``).
    InputError
        The file is missing, unreadable or not a certificate.
    """
    path = _certificate_file(obj, source)
    if path is None:
        if isinstance(obj, xr.Dataset) and INTEGRITY_ATTR not in obj.attrs:
            return None  # in memory, not yet sealed: built here, nothing altered it
        report = VerificationReport(path="<dataset>", problems=[
            "sealed certificate read from no known file: its seal cannot be checked (pass source=)"])
    else:
        report = verify_certificate(path, public_key=public_key, image=image)
    if report.ok or allow_invalid:
        return report
    raise SealError(f"{report.path}: refusing to show this certificate's numbers: {seal_problems(report)}; "
                    "to show them anyway, marked as invalid, pass --allow-invalid (allow_invalid=True)")


def seal_problems(report: VerificationReport) -> str:
    """Say in one sentence what is wrong with a seal (the first five problems) and how to see them all."""
    shown = "; ".join(report.problems[:5]) + (f"; and {len(report.problems) - 5} more"
                                              if len(report.problems) > 5 else "")
    return (f"its seal does not match its contents ({len(report.problems)} problem(s): {shown}); it was "
            f"altered after it was sealed, or never sealed. See lidarcal verify {report.path}")


def invalid_seal_banner(report: VerificationReport) -> str:
    """One line saying the numbers shown come from a certificate whose seal does not hold."""
    return (f"WARNING: INVALID CERTIFICATE {report.path}: its seal does not match its contents "
            f"({len(report.problems)} problem(s), e.g. {report.problems[0]}); these numbers are NOT "
            "certified (lidarcal verify lists every problem)")
