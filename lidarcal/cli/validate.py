"""``lidarcal validate FILE...``: schema check plus the CF-1.11/ACDD-1.3 compliance-checker.

Every file is checked and reported.  Exit status 0 when all pass, 1 when a file has schema or
compliance problems, 2 when a file is missing or unreadable (whatever the others gave).

A certificate (or any sealed file) has its seal checked too, as ``lidarcal verify`` does
without a public key: one whose contents no longer match its seal, or that carries none, is
not ``ok``, however well formed it is.

The ACDD attributes only you can give (contact, site, programme ...; ``--attribute``) are
usually absent from every file of a run alike: with several files, the attributes absent from
all of them are listed once, after the files, with the option that gives each.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from lidarcal.certificate.seal import INTEGRITY_ATTR, verify_certificate
from lidarcal.cli import COMMANDS
from lidarcal.compliance import check_compliance, missing_attributes, missing_lines, summary_lines
from lidarcal.errors import InputError
from lidarcal.io import open_artefact
from lidarcal.readback import read_attr
from lidarcal.schema import catalogue_owners, validate_dataset


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``validate`` subcommand."""
    p = sub.add_parser("validate", help=COMMANDS["validate"].help,
                       description=__doc__)
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--kind", help="schema to apply (default: the file's lidarcal_artefact attribute)")
    p.add_argument("--no-compliance", action="store_true", help="skip the IOOS compliance-checker")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="list every finding (by default the findings of one check share one line)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Validate every file, reporting each; 2 if any could not be read, else 1 if any has a problem."""
    bad = unreadable = 0
    several = len(args.files) > 1 and not args.verbose
    absent: dict[str, list[str]] = {}  # file -> ACDD attributes absent (several files: said once, after)
    for path in args.files:
        try:
            ds = open_artefact(path, load=False, chunks={})
        except InputError as exc:  # missing, empty, not netCDF: report it and check the rest
            print(f"lidarcal validate: error: {exc}", file=sys.stderr)
            print(f"{path}: FAIL (not readable)")
            unreadable += 1
            continue
        kind = args.kind or read_attr(ds, "lidarcal_artefact")
        sealed = kind == "certificate" or INTEGRITY_ATTR in ds.attrs
        try:
            for owner in catalogue_owners(str(kind)):  # the stage whose catalogue the schema expands over
                importlib.import_module(owner)
            problems = validate_dataset(ds, args.kind, source=path)
        except InputError as exc:
            problems = [str(exc)]
        finally:
            ds.close()
        seal = _seal_lines(path, verbose=args.verbose) if sealed else []
        report = None if args.no_compliance else check_compliance(path)
        failures = problems + seal + (report.failures if report else [])
        status = "FAIL" if failures else "ok"
        print(f"{path}: {status}")
        for line in problems:
            print(f"  schema: {line}")
        for line in seal:
            print(f"  seal: {line}")
        if report:  # failures, then each documented exception and warning check on one line
            for line in summary_lines(report, verbose=args.verbose, missing=not several):
                print(f"  {line}")
            absent[path] = missing_attributes(report)
        bad += bool(failures)
    if several and absent:
        _say_absent(absent)
    return 2 if unreadable else 1 if bad else 0


def _seal_lines(path: str, *, verbose: bool = False) -> list[str]:
    """List what is wrong with the seal of the certificate ``path`` (nothing: it matches its contents).

    Its schema problems are left out (the schema check above reports them); without
    ``verbose`` at most five lines, the last saying how many more ``lidarcal verify`` lists.
    """
    try:
        report = verify_certificate(path)
    except InputError as exc:
        return [str(exc)]
    found = [p for p in report.problems if not p.startswith("schema: ")]
    if not found:
        return []
    found[-1] += " (altered after it was sealed, or never sealed: its numbers are not certified)"
    if verbose or len(found) <= 5:
        return found
    return [*found[:4], f"and {len(found) - 4} more (lidarcal verify {path} lists every one)"]


def _say_absent(absent: dict[str, list[str]]) -> None:
    """Say the ACDD attributes absent from every file once, then what some files lack besides."""
    common = [name for name in next(iter(absent.values())) if all(name in names for names in absent.values())]
    for line in missing_lines(common, f" in any of these {len(absent)} files"):
        print(line)
    besides: dict[tuple[str, ...], list[str]] = {}  # the same extra attributes: one block for their files
    for path, names in absent.items():
        extra = tuple(n for n in names if n not in common)
        if extra:
            besides.setdefault(extra, []).append(path)
    for extra, paths in besides.items():
        for line in missing_lines(list(extra), f" (besides those) in {', '.join(paths)}"):
            print(line)
