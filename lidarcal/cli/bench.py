"""``lidarcal bench``: simulate a SAFO-MV run, ingest RTD + control log, repeatability analysis.

Subcommands::

    lidarcal bench simulate -o DIR [--seed N] [--accumulation-time S] [--compress] [--serial ...]
    lidarcal bench ingest RTD.csv[.gz] CONTROL.csv -o cube.nc [--settling-time S] [--outlier-rule mad]
    lidarcal bench repeatability CUBE.nc CUBE.nc ... [--exclude RUN] -o rep.nc
"""

from __future__ import annotations

import argparse

from lidarcal.bench.ingest import ingest
from lidarcal.bench.repeatability import repeatability
from lidarcal.bench.simulator import BenchRun, simulate_run
from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import add_output_options, finite, nonnegative, nonnegative_int, positive
from lidarcal.io import check_writable, write_artefact


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``bench`` command and its subcommands."""
    p = sub.add_parser("bench", help=COMMANDS["bench"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.set_defaults(handler=lambda args: (p.print_help(), 1)[1])
    bsub = p.add_subparsers(dest="bench_command", metavar="SUBCOMMAND")

    s = bsub.add_parser("simulate", help="write a simulated bench run (rtd.csv[.gz], control_log.csv)")
    add_output_options(s, "DIR", help="existing output directory")
    s.add_argument("--seed", type=nonnegative_int("--seed"), default=0,
                   help="SeedSequence entropy (default 0)")
    s.add_argument("--accumulation-time", type=positive("--accumulation-time"), default=650.0, metavar="S",
                   help="seconds per programmed bin (default 650, the paper's; full sweep ≈ 400 h)")
    s.add_argument("--serial", default="WLS866-0195", help="lidar serial number")
    s.add_argument("--operator", default="A", help="bench operator")
    s.add_argument("--run-id", default="1", help="run identifier")
    s.add_argument("--bench-id", default="SAFO-MV-01", help="bench identifier")
    s.add_argument("--start", default="2023-02-17T16:07:00Z", help="start of the first bin (ISO 8601 UTC)")
    s.add_argument("--bias-scale", type=nonnegative("--bias-scale"), default=1.0,
                   help="scale of the true-response bias model")
    s.add_argument("--compress", action="store_true",
                   help="write the RTD gzip-compressed as rtd.csv.gz (byte-reproducible)")
    s.set_defaults(handler=run_simulate)

    i = bsub.add_parser("ingest", help="RTD + control log -> bench_cube netCDF")
    i.add_argument("rtd", metavar="RTD", help="lidar real-time data CSV (.csv or gzip-compressed .csv.gz)")
    i.add_argument("control", metavar="CONTROL", help="SAFO-MV control log CSV (.csv or .csv.gz)")
    add_output_options(i, "CUBE.nc")
    i.add_argument("--settling-time", type=nonnegative("--settling-time"), default=5.0, metavar="S",
                   help="seconds after each bin start treated as transition (default 5)")
    i.add_argument("--outlier-rule", choices=("mad", "fixed", "none"), default="mad",
                   help="bad-estimate rule (default mad: |r - median| > k * 1.4826 MAD per bin)")
    i.add_argument("--outlier-k", type=positive("--outlier-k"), default=4.0,
                   help="MAD multiple of the mad rule (default 4)")
    i.add_argument("--outlier-threshold", type=positive("--outlier-threshold"), default=3.0, metavar="M_S",
                   help="limit on |measured - programmed| in m/s for the fixed rule (default 3)")
    i.set_defaults(handler=run_ingest)

    r = bsub.add_parser("repeatability", help="ISO 5725-4 between-run analysis of several cubes")
    r.add_argument("cubes", nargs="+", metavar="CUBE.nc")
    add_output_options(r, "REP.nc")
    r.add_argument("--exclude", action="append", default=[], metavar="RUN",
                   help="leave out a run by run_id or operator (run_id=X / operator=Y); repeatable")
    r.add_argument("--min-samples", type=nonnegative_int("--min-samples"), default=144,
                   help="use bins with more than this many samples in every run (default 144)")
    r.add_argument("--cnr-window", type=finite("--cnr-window"), nargs=2, default=(-18.0, -12.0),
                   metavar=("LO", "HI"),
                   help="CNR window in dB (default -18 -12)")
    r.add_argument("--velocity-window", type=finite("--velocity-window"), nargs=2, default=(-18.0, 18.0),
                   metavar=("LO", "HI"),
                   help="velocity window in m/s (default -18 18)")
    r.add_argument("--exclusive", action="store_true", help="exclude the window bounds (default: inclusive)")
    r.set_defaults(handler=run_repeatability)


def run_simulate(args: argparse.Namespace) -> int:
    """Simulate a run and write its two CSV files."""
    BenchRun.output_paths(args.output, overwrite=args.overwrite, compress=args.compress)  # before any work
    run = simulate_run(seed=args.seed, accumulation_time=f"{args.accumulation_time} s",
                       lidar_serial=args.serial, operator=args.operator, run_id=args.run_id,
                       bench_id=args.bench_id, start=args.start, bias_scale=args.bias_scale)
    rtd, control = run.write(args.output, overwrite=args.overwrite, compress=args.compress)
    print(f"wrote {rtd} ({len(run.rtd)} records) and {control} ({len(run.control)} bins)")
    return 0


def run_ingest(args: argparse.Namespace) -> int:
    """Ingest one run into a bench_cube."""
    check_writable(args.output, overwrite=args.overwrite)
    ds = ingest(args.rtd, args.control, settling_time=f"{args.settling_time} s",
                outlier_rule=args.outlier_rule, outlier_k=args.outlier_k,
                outlier_threshold=f"{args.outlier_threshold} m s-1", call=command_line(args))
    write_artefact(ds, args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}: {ds.attrs['ingest_records_used']} of {ds.attrs['ingest_records_total']} "
          f"records used, {ds.attrs['ingest_records_rejected_bad_estimate']} bad estimates rejected")
    return 0


def run_repeatability(args: argparse.Namespace) -> int:
    """Between-run analysis of several cubes."""
    check_writable(args.output, overwrite=args.overwrite)
    ds = repeatability(args.cubes, exclude=args.exclude, min_samples=args.min_samples,
                       cnr_window=tuple(args.cnr_window),
                       velocity_window=tuple(f"{v} m s-1" for v in args.velocity_window),
                       inclusive=not args.exclusive, call=command_line(args))
    write_artefact(ds, args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}: n_runs={int(ds.n_runs)}, bins={int(ds.n_bins_used)}, "
          f"s_delta={float(ds.mean_between_run_std_bias):.4f} m/s, "
          f"s_s={float(ds.mean_between_run_std_std):.4f} m/s")
    return 0
