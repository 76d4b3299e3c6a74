"""``lidarcal verify CERT.nc...``: recompute a certificate's checksums and schema.

Prints what was altered (values or attributes of which variable, which global attribute) and
exits with status 1 if anything was.  Every file is checked and reported; a file that is
missing, unreadable or not a certificate is an error (status 2, whatever the other files gave).

What OK promises depends on the signature, and each file's line says which applies:

* ``unsigned: integrity only`` -- nothing changed since the seal was computed.  Protects
  against accidents, not forgery: whoever can rewrite the file can recompute the seal.
* ``signed by <fingerprint>`` with ``--public-key KEY.pub`` -- the file is exactly as sealed
  by the holder of the matching private key (``lidarcal keygen``, ``--sign``); a re-sealed,
  re-signed or unsigned file fails.
* ``NOT SIGNED by KEY.pub: intact but unsigned`` with ``--public-key`` -- the seal matches the
  contents, but the file carries no signature, so it is not one signed by that key (status 1).
* ``signed by <fingerprint>`` without ``--public-key`` -- the signature matches the public key
  stored in the file: consistent, but anyone can sign with a key of their own; compare the
  fingerprint with one you trust, or pass ``--public-key``.
"""

from __future__ import annotations

import argparse
import sys

import netCDF4

from lidarcal.certificate.admin import status_line
from lidarcal.certificate.seal import verify_certificate
from lidarcal.certificate.signing import load_public_key
from lidarcal.cli import COMMANDS
from lidarcal.errors import LidarcalError


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``verify`` subcommand."""
    p = sub.add_parser(
        "verify", help=COMMANDS["verify"].help, description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("files", nargs="+", metavar="CERT.nc")
    p.add_argument("--public-key", metavar="KEY.pub",
                   help="require a valid signature by this Ed25519 public key (lidarcal keygen)")
    p.set_defaults(handler=run)


def _signature_line(report, public_key: str | None) -> str:
    if report.signed_by is None:
        return "unsigned: integrity only (whoever can rewrite the file can re-seal it)"
    if report.key_trusted:
        return f"signed by {report.signed_by} (checked against {public_key})"
    return (f"signed by {report.signed_by} (against the key stored in the file; pass --public-key "
            "to check it is a key you trust)")


def _status(path: str) -> str:
    with netCDF4.Dataset(path) as nc:
        attrs = {k: nc.getncattr(k) for k in nc.ncattrs()}
    return status_line(attrs)


def run(args: argparse.Namespace) -> int:
    """Verify every file, reporting each; 2 if any could not be checked, else 1 if any was altered."""
    # The seal check reads the file through dask.  Given a scheduler by name (or none), dask
    # imports distributed to look for a client (0.2-0.3 s of CPU) before reading one small file;
    # given the synchronous scheduler's function, it does not.
    import dask
    from dask.local import get_sync

    with dask.config.set(scheduler=get_sync):
        return _verify_all(args)


def _verify_all(args: argparse.Namespace) -> int:
    bad = failed = 0
    key = load_public_key(args.public_key) if args.public_key else None
    for path in args.files:
        try:
            report = verify_certificate(path, public_key=key)
        except LidarcalError as exc:  # missing, unreadable, not a certificate: report it, check the rest
            print(f"lidarcal verify: error: {exc}", file=sys.stderr)
            print(f"{path}: NOT CHECKED (see the error above)")
            failed += 1
            continue
        print(f"{path}: {_status(path)}")  # the status first: a demonstration is never mistaken for more
        if report.ok:
            print(
                f"{path}: OK ({report.variables_checked} variables and {report.attributes_checked} global "
                f"attributes match their SHA-256; schema valid); {_signature_line(report, args.public_key)}"
            )
        elif report.intact_but_unsigned:  # exit 1 all the same: it is not what --public-key asked for
            print(f"{path}: NOT SIGNED by {args.public_key}: intact but unsigned (its "
                  f"{report.variables_checked} variables and {report.attributes_checked} global attributes "
                  "match their SHA-256: integrity only, since whoever can rewrite the file can re-seal it)")
            print(f"  - {report.problems[0]}")
            bad += 1
        else:
            print(f"{path}: ALTERED or invalid ({len(report.problems)} problem(s))")
            for line in report.problems:
                print(f"  - {line}")
            bad += 1
    return 2 if failed else 1 if bad else 0
