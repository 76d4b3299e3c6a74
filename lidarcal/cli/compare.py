"""``lidarcal compare``: the field campaign beside the virtual lidar in its own conditions.

``lidarcal compare FIELD.nc [--cube CUBE.nc --rwf RWF.nc | --model DIAGNOSIS.nc] -o COMPARE.nc
[--json] [--report compare.html] [--reference-uncertainty 0.1] [--alpha 0.05]`` (``docs/compare.md``):
sensitivity slopes of the measured and the simulated pair per height and environmental variable
with a Holm-corrected test, and the IEC and Monte Carlo budgets side by side.  With ``--json``
only the JSON object goes to stdout; progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import (
    add_lidar_options,
    add_los_noise_option,
    add_output_options,
    add_parallel_options,
    add_progress_option,
    add_seed_option,
    execution_of,
    nonnegative,
    positive_int,
    probability,
)
from lidarcal.compare import (
    DEFAULT_ALPHA,
    DEFAULT_REFERENCE_UNCERTAINTY,
    DEFAULT_VARIABLES,
    VARIABLES,
    compare,
)
from lidarcal.compare.dataset import summary, to_dataset
from lidarcal.compare.report import write_report
from lidarcal.errors import InputError
from lidarcal.io import check_writable, open_artefact, write_artefact


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``compare`` subcommand."""
    p = sub.add_parser(
        "compare",
        help=COMMANDS["compare"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("field", metavar="FIELD.nc", help="field_campaign netCDF (docs/contracts.md)")
    g = add_lidar_options(p, default="the field file's lidar_* attributes")
    g.add_argument(
        "--model",
        metavar="DIAGNOSIS.nc",
        help="simulate the corrected model of a diagnosis (its lidarcal_lidar_model attribute) "
        "instead of --rwf; --cube restores the bench data it records by digest, and --rwf its RWF "
        "profile when it records one",
    )
    add_los_noise_option(g)
    add_output_options(p, "COMPARE.nc", help="comparison artefact to write")
    p.add_argument("--json", action="store_true", help="print only the JSON object on stdout")
    p.add_argument("--report", metavar="REPORT.html", help="also write an offline HTML report")
    p.add_argument(
        "--reference-uncertainty",
        type=nonnegative("--reference-uncertainty"),
        default=DEFAULT_REFERENCE_UNCERTAINTY,
        metavar="M_S",
        help="standard uncertainty of the reference anemometer in the IEC budget, m s-1 "
        "(default %(default)g)",
    )
    p.add_argument(
        "--alpha",
        type=probability("--alpha"),
        default=DEFAULT_ALPHA,
        help="family-wise false-alarm rate of the slope comparison, Holm over the cells "
        "(default %(default)g)",
    )
    p.add_argument(
        "--variables",
        nargs="+",
        choices=VARIABLES,
        default=list(DEFAULT_VARIABLES),
        metavar="VARIABLE",
        help=f"environmental variables to compare (default: "
        f"{' '.join(DEFAULT_VARIABLES)}; any of {', '.join(VARIABLES)})",
    )
    p.add_argument(
        "--min-periods",
        type=positive_int("--min-periods"),
        default=10,
        help="periods a sensitivity bin needs (both sides; default %(default)s)",
    )
    add_seed_option(p, help="base seed of the simulation")
    add_parallel_options(p, workdir=False)
    add_progress_option(p)
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Simulate, compare, write the artefact (and report), print the verdict or the JSON object."""
    if args.model and args.rwf:
        raise InputError(
            "--model (a diagnosis's corrected model) and --rwf both configure the range weighting; give one"
        )
    check_writable(args.output, overwrite=args.overwrite)
    if args.report:
        check_writable(args.report, overwrite=args.overwrite)
    cube = open_artefact(args.cube, "bench_cube") if args.cube else None
    rwf = open_artefact(args.rwf, "rwf") if args.rwf else None
    diagnosis = open_artefact(args.model, load=False, chunks={}) if args.model else None
    inputs = {
        "field": args.field,
        **{k: getattr(args, k) for k in ("cube", "rwf") if getattr(args, k)},
        **({"model": args.model} if args.model else {}),
    }
    result = compare(
        args.field,
        cube=cube,
        rwf=rwf,
        diagnosis=diagnosis,
        variables=args.variables,
        alpha=args.alpha,
        reference_uncertainty=args.reference_uncertainty,
        base_seed=args.seed,
        min_periods=args.min_periods,
        los_noise_model=args.los_noise,
        execution=execution_of(args),
        inputs=inputs,
    )
    ds = to_dataset(result, call=command_line(args), inputs=inputs)
    write_artefact(ds, args.output, overwrite=args.overwrite)
    if args.report:
        write_report(ds, args.report, overwrite=args.overwrite)
    js = summary(ds)
    if args.json:
        print(json.dumps(js))
    else:
        bad = [c for c in js["cells"] if not c["agree"]]
        print(
            f"{args.field}: {js['verdict']} ({len(bad)} of {len(js['cells'])} cells disagree at alpha "
            f"{js['alpha']:g}, Holm-corrected)"
        )
        for c in bad:
            print(
                f"  {c['variable']} at {c['height']:g} m: measured {c['measured_slope']:.3g} ± "
                f"{c['measured_se']:.2g}, simulated {c['simulated_slope']:.3g} ± {c['simulated_se']:.2g} "
                f"{c['units']} (z {c['z']:+.1f})"
            )
        if js["next"]:
            print(f"  next: {js['next']}")
        print(f"  wrote {args.output}")
    return 0
