"""``lidarcal calibrate [-o OUTDIR]``: the whole calibration, bench to certificate.

With no options it runs on the embedded sample data (a simulated SAFO-MV bench run, an
example pulse, and two weeks of a real met-mast record carried to 40–200 m; --periods 0 takes
all three months of it), writing every artefact into OUTDIR and printing where each went.  Any
input can be replaced by your own file; every input is read and checked before anything is
written.

Examples::

    lidarcal calibrate                              # sample data -> ./lidarcal-output
    lidarcal calibrate -o run1 --periods 500        # quicker
    lidarcal calibrate --rtd rtd.csv --control control_log.csv --conditions site.nc -o run2

Without a terminal (under tee, nohup, a batch job) it prints a progress line every 30 s
(--progress-interval): periods done, chunks, time left.  A run that is interrupted (Ctrl-C) or
killed during the simulation keeps its finished chunks in OUTDIR/.simulation-chunks; Ctrl-C
prints how many and the command that resumes (the same with --overwrite), and the resumed run
says how many it reused.

The Monte Carlo states its own accuracy (JCGM 101 7.9): replicas of the periods of the certified
bins that have not settled are simulated with independent seeds until every certified value is
stable to --significant-digits (default 1), or --max-replicas is reached; the certificate then
says which values did not settle.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lidarcal.campaign.model_form import DEFAULT_PER_BIN
from lidarcal.certificate.admin import status_line
from lidarcal.cli import COMMANDS
from lidarcal.cli.options import (
    add_admin_options,
    add_certification_options,
    add_contact_options,
    add_heights_option,
    add_los_noise_option,
    add_monte_carlo_options,
    add_overwrite_option,
    add_parallel_options,
    add_progress_option,
    add_reference_turbulence_option,
    add_seed_option,
    admin_from_args,
    progress_of,
)
from lidarcal.pipeline import CHUNK_DIR, DEFAULT_HEIGHTS, CalibrationConfig, calibrate


def _periods(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"--periods expects a whole number >= 0; got {text!r}")
    return value


def _model_form_periods(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0 or value == 1:
        raise argparse.ArgumentTypeError(f"--model-form-periods expects 0 (none) or a whole number >= 2 "
                                         f"(a standard deviation needs two periods); got {text!r}")
    return value


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``calibrate`` subcommand."""
    p = sub.add_parser("calibrate", help=COMMANDS["calibrate"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-o", "--outdir", default="lidarcal-output", help="output directory (default %(default)s)")
    p.add_argument("--rtd", metavar="RTD.csv", help="bench real-time data (default: sample run)")
    p.add_argument("--control", metavar="CONTROL.csv", help="bench control log (default: sample run)")
    p.add_argument("--cube", metavar="CUBE.nc", help="use an existing bench_cube instead of ingesting")
    p.add_argument("--rwf", metavar="RWF.nc", help="use an existing rwf artefact")
    p.add_argument("--pulse-file", metavar="PULSE.csv", help="measured pulse (default: sample pulse)")
    p.add_argument("--fft-size", type=int, choices=(64, 128), default=64, help="apodization FFT size")
    p.add_argument("--conditions", metavar="C.nc", help="conditions file (default: real sample, 40-200 m)")
    add_heights_option(p, default=DEFAULT_HEIGHTS, help="heights for the sample conditions, m "
                       f"(default {' '.join(f'{h:g}' for h in DEFAULT_HEIGHTS)})")
    p.add_argument("--periods", type=_periods, default=2016, metavar="N",
                   help="10-minute periods from the start of the record (default %(default)s = 2 weeks; "
                   "0 = all)")
    p.add_argument("--noise-terms", choices=("printed", "derived"), default="printed",
                   help="Eqs. 6-7 as printed (reproduces Table 4, default) or as propagated through the "
                   "10-minute average (docs/noise_terms.md)")
    p.add_argument("--table4", choices=("corrected", "printed"), default="corrected",
                   help="Table 4 terms: corrected (default: dv_SAFO / 2, Eq. 11 with dz cos(phi)) or as the "
                   "paper prints them (lidarcal terms --table4)")
    p.add_argument("--model-form-periods", type=_model_form_periods, default=DEFAULT_PER_BIN, metavar="N",
                   help="most periods per (height, wind-speed bin) each model-form alternative re-simulates "
                   "with the nominal seeds (default %(default)s; 0 = no model_form contributor; "
                   "docs/method.md)")
    add_los_noise_option(p)
    add_reference_turbulence_option(p)
    add_certification_options(p)  # --min-periods also sets the sensitivities' bins (one rule)
    add_monte_carlo_options(p)
    add_seed_option(p)
    add_parallel_options(p, workdir=False)  # chunks are cached in OUTDIR/.simulation-chunks
    add_overwrite_option(p)
    add_contact_options(p)
    add_admin_options(p)
    add_progress_option(p)
    p.add_argument("--sign", metavar="KEY",
                   help="sign the certificate's seal with this Ed25519 private key (lidarcal keygen); "
                   "without it the certificate is sealed for integrity only")
    p.set_defaults(handler=run, resume=lambda args: (Path(args.outdir) / CHUNK_DIR, "--overwrite"))


def run(args: argparse.Namespace) -> int:
    """Build the configuration from the options and run the chain."""
    cfg = CalibrationConfig(
        bench_rtd=args.rtd, bench_control=args.control, cube=args.cube, rwf=args.rwf,
        pulse_file=args.pulse_file, conditions=args.conditions, heights=tuple(args.heights),
        periods=None if args.periods == 0 else args.periods, base_seed=args.seed,
        workers=args.workers, scheduler=args.scheduler, fft_size=args.fft_size, chunk=args.chunk,
        min_periods=args.min_periods, certified_range=tuple(args.certified_range),
        significant_digits=args.significant_digits, max_replicas=args.max_replicas,
        coverage_interval=args.coverage_interval,
        model_form_periods=args.model_form_periods,
        los_noise_model=args.los_noise,
        reference_turbulence=args.reference_turbulence,
        terms={**({} if args.noise_terms == "printed" else {"noise_terms": args.noise_terms}),
               **({"paper_table4": True} if args.table4 == "printed" else {})},
    )
    result = calibrate(args.outdir, cfg, overwrite=args.overwrite, progress=progress_of(args),
                       signing_key=args.sign, admin=admin_from_args(args), demonstration=args.demonstration)
    print(f"done: {status_line(result.datasets['certificate'].attrs)}")
    print(f"done: certificate {result.paths['certificate']}, report {result.paths['report']}, "
          f"certificate document {result.paths['report_pdf']}")
    return 0
