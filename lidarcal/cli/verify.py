"""``lidarcal verify CERT.nc...``: recompute a certificate's checksums and schema.

Prints what was altered (values or attributes of which variable, which global attribute) and
exits with status 1 if anything was; a file that is not a certificate is an error (status 2).
"""

from __future__ import annotations

import argparse

from lidarcal.certificate import verify_certificate


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``verify`` subcommand."""
    p = sub.add_parser(
        "verify", help="check a certificate's integrity record and schema", description=__doc__
    )
    p.add_argument("files", nargs="+", metavar="CERT.nc")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Verify every file; 1 if any was altered."""
    bad = 0
    for path in args.files:
        report = verify_certificate(path)
        if report.ok:
            print(
                f"{path}: OK ({report.variables_checked} variables and {report.attributes_checked} global "
                "attributes match their SHA-256; schema valid)"
            )
        else:
            print(f"{path}: ALTERED or invalid ({len(report.problems)} problem(s))")
            for line in report.problems:
                print(f"  - {line}")
            bad += 1
    return 1 if bad else 0
