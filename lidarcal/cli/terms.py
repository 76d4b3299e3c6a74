"""``lidarcal terms``: uncertainty terms not modelled by Monte Carlo (Eqs. 6–11, Table 4).

Defaults are the paper's inputs.  s-bar_s, s-bar_delta and the run count can come from a
``repeatability`` artefact (``--repeatability``); an explicit option overrides the file.
Prints the table on stdout.  Examples::

    lidarcal terms -o terms.nc                                  # Eq. 9 as a formula (0.00286 U)
    lidarcal terms --table4 printed --beam-angle-coefficient 0.00248 -o t4.nc   # Table 4 as printed
    lidarcal terms --repeatability rep.nc --height 120 --shear 0.14 -o terms.nc
    lidarcal terms --noise-terms derived -o terms_derived.nc    # Eqs. 6-7 propagated
"""

from __future__ import annotations

import argparse

import numpy as np

from lidarcal.analysis.terms import PAPER_INPUTS, format_table, repeatability_inputs, uncertainty_terms
from lidarcal.cli import command_line
from lidarcal.cli.options import (
    add_output_options,
    finite,
    nonnegative,
    number,
    positive,
    positive_int,
    probability,
)
from lidarcal.io import check_writable, write_artefact
from lidarcal.lidar import LidarModel
from lidarcal.units import Q_


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``terms`` subcommand."""
    p = sub.add_parser("terms", help="non-simulated uncertainty terms (Eqs. 6-11, Table 4)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--repeatability", metavar="REP.nc",
                   help="repeatability artefact giving s-bar_s, s-bar_delta and n_runs")
    p.add_argument("--wind-speed", type=positive("--wind-speed"), nargs="+",
                   default=[4, 6, 8, 10, 12, 14, 16],
                   metavar="M_S", help="wind speeds in m/s (default: Table 4's 4 6 ... 16)")
    p.add_argument("--height", type=positive("--height"), default=100.0, metavar="M",
                   help="measurement height z, m (100)")
    p.add_argument("--shear", type=number("--shear", lo=-2, hi=2), default=0.2, metavar="ALPHA",
                   help="power-law shear exponent (0.2)")
    p.add_argument("--cone-angle", type=number("--cone-angle", lo=0, hi=90, lo_open=True, hi_open=True),
                   default=LidarModel.cone_angle, metavar="DEG",
                   help="beam angle from vertical, degree (%(default)g; Table 1's polar 62 is the elevation)")
    p.add_argument("--std-repeatability", type=nonnegative("--std-repeatability"), metavar="M_S",
                   help="s-bar_s, m/s (default: from --repeatability, else 0.027)")
    p.add_argument("--bias-repeatability", type=nonnegative("--bias-repeatability"), metavar="M_S",
                   help="s-bar_delta, m/s (default: from --repeatability, else 0.021)")
    p.add_argument("--n-runs", type=positive_int("--n-runs"),
                   help="bench runs (default: from --repeatability, else 4)")
    p.add_argument("--n-los-samples", type=positive_int("--n-los-samples"), default=150,
                   help="radial velocities per LOS per 10 min (150)")
    p.add_argument("--eq7-n", choices=("los_samples", "runs"), default="los_samples",
                   help="N of Eq. 7: los_samples reproduces Table 4's 0.0026, runs follows the text "
                        "(default los_samples)")
    p.add_argument("--noise-terms", choices=("printed", "derived"), default="printed",
                   help="Eqs. 6-7 as printed (reproduces Table 4, default) or as propagated through the "
                        "10-minute average: sqrt(N) on Eq. 6, none on Eq. 7 (docs/noise_terms.md)")
    p.add_argument("--los-noise-std", type=nonnegative("--los-noise-std"), metavar="M_S",
                   help="LOS noise std in the derived Eq. 6's noise-bias part, m/s (0.1)")
    p.add_argument("--hybrid-weight", type=probability("--hybrid-weight"), metavar="P",
                   help="hybrid weight p in the derived Eq. 6's noise-bias part (2/3)")
    p.add_argument("--bench-uncertainty", type=nonnegative("--bench-uncertainty"), default=0.0145,
                   metavar="M_S",
                   help="dv_SAFO as stated, m/s (0.0145)")
    p.add_argument("--bench-coverage-factor", type=positive("--bench-coverage-factor"), metavar="K",
                   help="k dividing dv_SAFO (default 2: it is stated at k = 2; 1 with --table4 printed)")
    p.add_argument("--table4", choices=("corrected", "printed"), default="corrected",
                   help="corrected (default): dv_SAFO / 2 and Eq. 11 with the height error dz cos(phi); "
                        "printed: both as Table 4 uses them (with --beam-angle-coefficient 0.00248 the "
                        "table is reproduced to its printed digits)")
    p.add_argument("--beam-angle-uncertainty", type=nonnegative("--beam-angle-uncertainty"), default=0.087,
                   metavar="DEG",
                   help="beam angle standard uncertainty, degree (0.087)")
    p.add_argument("--beam-angle-coefficient", type=finite("--beam-angle-coefficient"), metavar="C",
                   help="use C*U for Eq. 9 (Table 4 prints 0.00248; the formula gives 0.00286)")
    p.add_argument("--zero-distance-uncertainty", type=nonnegative("--zero-distance-uncertainty"),
                   default=0.45, metavar="M",
                   help="Zd standard uncertainty, m (0.45)")
    add_output_options(p, "TERMS.nc")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Compute the terms, write the artefact and print the table."""
    check_writable(args.output, overwrite=args.overwrite)
    rep = None
    source = {k: PAPER_INPUTS[k] for k in ("mean_between_run_std_std", "mean_between_run_std_bias", "n_runs")}
    if args.repeatability:
        found, rep = repeatability_inputs(args.repeatability)
        source.update(found)
    if args.std_repeatability is not None:
        source["mean_between_run_std_std"] = Q_(args.std_repeatability, "m/s")
    if args.bias_repeatability is not None:
        source["mean_between_run_std_bias"] = Q_(args.bias_repeatability, "m/s")
    if args.n_runs is not None:
        source["n_runs"] = args.n_runs
    ds = uncertainty_terms(
        Q_(np.asarray(args.wind_speed, dtype=float), "m/s"),
        **source,
        n_los_samples=args.n_los_samples,
        bench_uncertainty=Q_(args.bench_uncertainty, "m/s"),
        beam_angle_uncertainty=Q_(args.beam_angle_uncertainty, "degree"),
        zero_distance_uncertainty=Q_(args.zero_distance_uncertainty, "m"),
        shear_exponent=args.shear,
        height=Q_(args.height, "m"),
        cone_angle=Q_(args.cone_angle, "degree"),
        beam_angle_coefficient=args.beam_angle_coefficient,
        bias_repeatability_n=args.eq7_n,
        bench_coverage_factor=args.bench_coverage_factor,
        paper_table4=args.table4 == "printed",
        noise_terms=args.noise_terms,
        los_noise_std=None if args.los_noise_std is None else Q_(args.los_noise_std, "m/s"),
        hybrid_weight=args.hybrid_weight,
        repeatability=rep,
        call=command_line(args),
    )
    path = write_artefact(ds, args.output, overwrite=args.overwrite)
    print(format_table(ds))
    print(f"written: {path}")
    return 0

