"""``lidarcal validate FILE...``: schema check plus the CF-1.11/ACDD-1.3 compliance-checker."""

from __future__ import annotations

import argparse

from lidarcal.compliance import check_compliance
from lidarcal.errors import InputError
from lidarcal.io import open_artefact
from lidarcal.schema import validate_dataset


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``validate`` subcommand."""
    p = sub.add_parser("validate", help="check artefacts against their schema and CF/ACDD",
                       description=__doc__)
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--kind", help="schema to apply (default: the file's lidarcal_artefact attribute)")
    p.add_argument("--no-compliance", action="store_true", help="skip the IOOS compliance-checker")
    p.add_argument("-v", "--verbose", action="store_true", help="also list medium/low-priority findings")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Validate every file; exit 1 if any has a problem."""
    bad = 0
    for path in args.files:
        try:
            ds = open_artefact(path, load=False, chunks={})
            problems = validate_dataset(ds, args.kind, source=path)
            ds.close()
        except InputError as exc:
            problems = [str(exc)]
        report = None if (args.no_compliance or problems and "not a readable" in problems[0]) \
            else check_compliance(path)
        failures = problems + (report.failures if report else [])
        status = "FAIL" if failures else "ok"
        print(f"{path}: {status}")
        for line in problems:
            print(f"  schema: {line}")
        if report:
            for line in report.failures:
                print(f"  compliance: {line}")
            for line in report.exceptions:
                print(f"  documented exception: {line}")
            if args.verbose:
                for line in report.warnings:
                    print(f"  warning: {line}")
        bad += bool(failures)
    return 1 if bad else 0
