"""``lidarcal certificate --budget B.nc --sensitivity S.nc ... -o CERT.nc [--report CERT.html]``.

Bundle a calibration (budget, sensitivities, bench cube, RWF and Zd, Table 4 terms) with the
provenance of every input into one sealed netCDF certificate; check it later with
``lidarcal verify CERT.nc``.  An existing certificate is never replaced without ``--overwrite``.

The seal (SHA-256 of every value and attribute) detects alteration, not forgery: anyone who can
rewrite the file can recompute it.  ``--sign KEY`` (from ``lidarcal keygen``) adds an Ed25519
signature of the seal; ``lidarcal verify CERT.nc --public-key KEY.pub`` then fails for any file
not sealed by the holder of KEY.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lidarcal.certificate import make_certificate
from lidarcal.certificate.admin import status_line
from lidarcal.certificate.document import seal_statement
from lidarcal.certificate.report import write_report
from lidarcal.certificate.seal import write_certificate
from lidarcal.certificate.signing import fingerprint, load_private_key
from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import add_admin_options, add_output_options, admin_from_args
from lidarcal.errors import DiskFullError, LidarcalError
from lidarcal.io import check_writable, open_artefact


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``certificate`` subcommand."""
    p = sub.add_parser(
        "certificate",
        help=COMMANDS["certificate"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--budget", required=True, metavar="BUDGET.nc", help="uncertainty_budget artefact")
    p.add_argument(
        "--sensitivity",
        action="append",
        default=[],
        metavar="SENS.nc",
        help="sensitivity artefact (repeatable, one per variable)",
    )
    p.add_argument("--cube", metavar="CUBE.nc", help="bench_cube artefact")
    p.add_argument("--rwf", metavar="RWF.nc", help="rwf artefact (RWF and zero distance)")
    p.add_argument("--terms", metavar="TERMS.nc", help="uncertainty_terms artefact (Table 4)")
    p.add_argument(
        "--records", metavar="RECORDS.nc", help="simulated_rtd / field_campaign records (summarised)"
    )
    add_output_options(p, "CERT.nc")
    add_admin_options(p)
    p.add_argument("--report", metavar="CERT.html",
                   help="also write the HTML report and, beside it, the certificate document (CERT.pdf, A4)")
    p.add_argument("--sign", metavar="KEY",
                   help="sign the seal with this Ed25519 private key (lidarcal keygen); without it the "
                   "certificate is sealed for integrity only")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Open the inputs, build, seal and (optionally) report."""
    check_writable(args.output, overwrite=args.overwrite)
    if args.report:
        check_writable(args.report, overwrite=args.overwrite)
        check_writable(Path(args.report).with_suffix(".pdf"), overwrite=args.overwrite)
    key = load_private_key(args.sign) if args.sign else None  # a bad key fails before any work
    admin = admin_from_args(args)  # a bad --admin file fails before any work
    budget = open_artefact(args.budget, "uncertainty_budget")
    sens = [open_artefact(path, "sensitivity") for path in args.sensitivity]
    optional = {
        name: open_artefact(path, kind) if path else None
        for name, path, kind in (
            ("cube", args.cube, "bench_cube"),
            ("rwf", args.rwf, "rwf"),
            ("terms", args.terms, "uncertainty_terms"),
            ("records", args.records, None),
        )
    }
    config = {k: v for k, v in vars(args).items() if k != "handler"}
    call = command_line(args)
    cert = make_certificate(budget=budget, sensitivities=sens, config=config, call=call, admin=admin,
                            demonstration=args.demonstration, **optional)
    path = write_certificate(cert, args.output, overwrite=args.overwrite, signing_key=key)
    how = (f"sealed and signed by {fingerprint(key)} (check with: lidarcal verify {path} --public-key "
           f"{args.sign}.pub)" if key else f"sealed, unsigned (check with: lidarcal verify {path})")
    print(f"{path}: {status_line(cert.attrs)}")
    print(f"{path}: certificate with components {cert.attrs['certificate_components']}; {how}")
    if args.report:  # the certificate as sealed just now: the document states its seal
        try:
            written = write_report(args.report, certificate=cert, overwrite=args.overwrite,
                                   seal=seal_statement(fingerprint(key) if key else None, Path(path).name,
                                                       f"{args.sign}.pub" if key else None))
        except BaseException as exc:  # the set is whole or absent: withdraw the certificate too
            path.unlink(missing_ok=True)
            if isinstance(exc, LidarcalError | OSError):
                html = Path(args.report)
                note = (f"; {path}, published before the report failed, was removed too, so none of "
                        f"{path.name}, {html.name} and {html.with_suffix('.pdf').name} was written"
                        + (" (the earlier files --overwrite replaced are gone)" if args.overwrite else ""))
                raise (DiskFullError if isinstance(exc, DiskFullError) else LidarcalError)(
                    f"{exc}{note}") from None
            raise
        print(f"{args.report}: HTML report with {len(written['figures'])} interactive plots; "
              f"{written['pdf']}: certificate document ({written['pages']} pages, A4)")
    return 0
