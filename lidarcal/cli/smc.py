"""``lidarcal smc``: the uncertainty of the calibrated lidar's wind speed in a specific measurement campaign.

``lidarcal smc CERT.nc FILE.sta [FILE.sta ...] -o SMC.nc`` (or ``--conditions CONDITIONS.nc``
instead of the ``.sta`` files; ``docs/smc.md``): per 10-minute period and height the lidar's
wind speed and its combined standard uncertainty, with the contributors apart (the
certificate's certified value, the IEC 61400-50-2 and the Monte Carlo environmental routes, the
user's terms of ``--user-terms``).  The certificate's seal is checked first (its signature too
with ``--public-key``); files of another unit, of another cone angle, and a certificate whose
seal fails are refused (exit status 2).  A firmware-2.x file's ``ScanAngle=NA`` takes the
certificate's cone angle.  ``--report SMC.html`` also writes the HTML report and ``SMC.pdf``
beside it; ``lidarcal table SMC.nc`` prints the per-bin table.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import (
    add_output_options,
    add_parallel_options,
    add_progress_option,
    add_seed_option,
    execution_of,
    number,
    positive_int,
)
from lidarcal.io import check_writable, open_artefact, write_artefact
from lidarcal.readback import read_attr


def _periods_per_bin(text: str) -> int | None:
    """``--mc-periods-per-bin``: an integer >= 2, or ``all`` (None: every period)."""
    if text.strip().lower() == "all":
        return None
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 2:
        raise argparse.ArgumentTypeError(f"expected an integer >= 2 or 'all'; found {text!r}")
    return n


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``smc`` subcommand."""
    from lidarcal.smc.subsample import DEFAULT_PERIODS_PER_BIN  # deferred: only when smc is run
    p = sub.add_parser(
        "smc",
        help=COMMANDS["smc"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("certificate", metavar="CERT.nc", help="the sealed certificate of the campaign's lidar")
    p.add_argument("files", nargs="*", metavar="FILE.sta", help="the campaign's 10-minute statistics files")
    p.add_argument(
        "--conditions",
        metavar="CONDITIONS.nc",
        help="instead of .sta files: a conditions file read from them (lidarcal conditions from-sta)",
    )
    add_output_options(p, "SMC.nc", help="smc artefact to write")
    p.add_argument(
        "--report",
        metavar="SMC.html",
        help="also write the HTML report, and the PDF beside it (same name, .pdf)",
    )
    p.add_argument(
        "--public-key",
        metavar="KEY.pub",
        help="require the certificate's signature by this Ed25519 public key",
    )
    p.add_argument(
        "--user-terms",
        metavar="TERMS.yaml",
        help="the user's own terms (name, value, unit, distribution, source; docs/smc.md)",
    )
    p.add_argument(
        "--no-monte-carlo",
        dest="monte_carlo",
        action="store_false",
        help="skip the Monte Carlo route (seconds instead of minutes); the 50-2 route is quoted",
    )
    p.add_argument(
        "--min-availability",
        type=number("--min-availability", lo=0, hi=100),
        default=80.0,
        metavar="PCT",
        help="data availability (%%) a period needs at a height (default 80)",
    )
    p.add_argument(
        "--allow-gaps",
        action="store_true",
        help="read rows cut short as missing periods, with a warning naming them",
    )
    p.add_argument(
        "--max-replicas",
        type=positive_int("--max-replicas"),
        metavar="M",
        help="most Monte Carlo replicas of the periods of unsettled bins, replica 0 included "
        "(default: the certificate's own, at least 4)",
    )
    p.add_argument(
        "--mc-periods-per-bin",
        type=_periods_per_bin,
        default=DEFAULT_PERIODS_PER_BIN,
        metavar="N|all",
        help="most periods the Monte Carlo route simulates per height and wind-speed bin, a stratified "
        f"subsample whose tolerance smc.nc states (default {DEFAULT_PERIODS_PER_BIN}); 'all': every period",
    )
    add_seed_option(p, help="base seed of the Monte Carlo route")
    add_parallel_options(p)
    add_progress_option(p)
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Compute the campaign uncertainty, write the artefact (and report), print a summary."""
    from lidarcal.smc import smc, smc_dataset  # deferred: light CLI start

    check_writable(args.output, overwrite=args.overwrite)
    if args.report:
        check_writable(args.report, overwrite=args.overwrite)
        check_writable(Path(args.report).with_suffix(".pdf"), overwrite=args.overwrite)
    campaign = smc(
        args.certificate,
        args.files,
        conditions=args.conditions,
        public_key=args.public_key,
        user_terms=args.user_terms,
        monte_carlo=args.monte_carlo,
        min_availability=args.min_availability,
        allow_gaps=args.allow_gaps,
        base_seed=args.seed,
        max_replicas=args.max_replicas,
        periods_per_bin=args.mc_periods_per_bin,
        execution=execution_of(args),
    )
    ds = smc_dataset(campaign, call=command_line(args))
    path = write_artefact(ds, args.output, overwrite=args.overwrite)
    # the report and the summary read the file just written: its per-period values are lazy (computed
    # block by block from the campaign), and reading them is cheaper than computing them again
    ds = open_artefact(path, "smc", load=False)
    try:
        if args.report:
            from lidarcal.smc.report import write_report  # deferred: matplotlib only when asked

            written = write_report(ds, args.report, overwrite=args.overwrite)
            print(f"wrote {written['html']} and {written['pdf']}")
        print(summary_line(ds, args.output))
    finally:
        ds.close()
    return 0


def summary_line(ds, path) -> str:
    """Return what the command prints: status, coverage, quoted route, median relative uncertainty."""
    status = (
        "DEMONSTRATION result (from a demonstration certificate): "
        if read_attr(ds, "calibration_status", kind="smc") == "demonstration"
        else ""
    )
    rel = ds["relative_uncertainty"].values
    median = float(np.nanmedian(rel)) if np.isfinite(rel).any() else float("nan")
    return (
        f"{status}wrote {path}: {ds.sizes['time']} periods x {ds.sizes['height']} heights; "
        f"{ds.attrs['covered_periods']} of {ds.attrs['periods_with_wind_speed']} period-heights covered by "
        f"the certificate; environmental route quoted: {read_attr(ds, 'environmental_route', kind='smc')}; "
        "median relative "
        f"standard uncertainty {median:.2f} %"
    )
