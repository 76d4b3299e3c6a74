"""``lidarcal conditions``: check a conditions input, or generate synthetic conditions.

Examples::

    lidarcal conditions check field.nc --kind field_campaign
    lidarcal conditions synthetic -n 13700 --heights 40 60 80 100 120 140 160 200 --seed 1 -o c.nc
    lidarcal conditions synthetic --from-sample --heights 40 80 120 160 200 -o sample200.nc
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.field import add_conditions_from_sta
from lidarcal.cli.options import add_output_options, nonnegative_int, number, positive, positive_int
from lidarcal.conditions import load_conditions, sample_conditions_path, synthetic_conditions
from lidarcal.diagnose.inputs import check_field
from lidarcal.errors import InputError
from lidarcal.io import check_writable, open_artefact, write_artefact
from lidarcal.lidar import LidarModel, check_reachable
from lidarcal.readback import read_attr


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``conditions`` subcommand and its actions."""
    p = sub.add_parser(
        "conditions",
        help=COMMANDS["conditions"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    acts = p.add_subparsers(dest="action", metavar="ACTION")
    chk = acts.add_parser("check", help="load a conditions/field_campaign file and summarise it",
                          description="Run the checks of the command that reads the file (simulate for "
                          "conditions, diagnose with its default settings for field_campaign) and "
                          "summarise it; exit 2 with the first problem.")
    chk.add_argument("file", metavar="FILE")
    chk.add_argument("--kind", choices=("conditions", "field_campaign"), default="conditions")
    chk.set_defaults(handler=run_check)
    syn = acts.add_parser(
        "synthetic", help="seeded synthetic conditions (or the sample extrapolated in height)"
    )
    syn.add_argument(
        "-n",
        "--periods",
        type=positive_int("--periods"),
        default=None,
        metavar="N",
        help="number of 10-minute periods (default 1008 = one week; all with --from-sample)",
    )
    syn.add_argument(
        "--heights",
        type=positive("--heights"),
        nargs="+",
        default=[40, 60, 80, 100, 120, 140, 160, 200],
        metavar="M",
        help="heights in m (default 40 60 80 100 120 140 160 200)",
    )
    syn.add_argument("--seed", type=nonnegative_int("--seed"), default=0, help="random seed (default 0)")
    src = syn.add_mutually_exclusive_group()
    src.add_argument(
        "--from-sample",
        action="store_true",
        help="extrapolate the embedded real sample with each period's shear exponent",
    )
    src.add_argument("--base", metavar="C.nc", help="extrapolate this conditions file instead")
    syn.add_argument(
        "--median-speed",
        type=positive("--median-speed"),
        default=8.0,
        metavar="M/S",
        help="stochastic mode: median speed at the reference height (default 8)",
    )
    syn.add_argument(
        "--ref-height",
        type=positive("--ref-height"),
        default=80.0,
        metavar="M",
        help="stochastic mode: reference height (default 80)",
    )
    syn.add_argument(
        "--turbulence-reference",
        type=number("--turbulence-reference", lo=0, hi=1),
        default=0.10,
        metavar="I_REF",
        help="stochastic mode: IEC reference turbulence intensity (default 0.10)",
    )
    add_output_options(syn, "C.nc")
    syn.set_defaults(handler=run_synthetic)
    add_conditions_from_sta(acts)
    p.set_defaults(handler=lambda args: p.print_help() or 1)


def run_check(args: argparse.Namespace) -> int:
    """Print the shape, ranges and skipped periods of a conditions input."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = load_conditions(args.file, kind=args.kind)
    # the checks of the command that consumes the file, so what passes here passes there: diagnose's
    # for a field campaign, simulate's lidar (lidar_* attributes, reachable heights) for conditions
    if args.kind == "field_campaign":
        check_field(args.file)
    else:
        problems = check_reachable(LidarModel.from_attrs(ds, source=args.file), ds.height.values)
        if problems:
            raise InputError(f"{args.file}: variable 'height': heights the lidar of its lidar_* attributes "
                             "cannot measure: " + "; ".join(problems))
    print(f"{args.file}: {args.kind} ok, {ds.sizes['time']} periods, heights {ds.height.values.tolist()} m")
    for name in ds.data_vars:
        if name == "input_complete":
            continue
        v = ds[name].values
        if not np.isfinite(v).any():
            print(f"  {name:22s} [{ds[name].attrs['units']}]  all missing (NaN)")
            continue
        print(
            f"  {name:22s} [{ds[name].attrs['units']}]  min {np.nanmin(v):9.4g}"
            f"  median {np.nanmedian(v):9.4g}  max {np.nanmax(v):9.4g}"
        )
    print(f"  skipped (period, height) pairs: {read_attr(ds, 'lidarcal_skipped_count', kind='conditions')}")
    for w in caught:
        print(f"  note: {w.message}")
    return 0


def run_synthetic(args: argparse.Namespace) -> int:
    """Generate synthetic conditions and write them with provenance."""
    check_writable(args.output, overwrite=args.overwrite)
    base_path = args.base or (sample_conditions_path() if args.from_sample else None)
    base = open_artefact(base_path) if base_path else None
    n = args.periods or (base.sizes["time"] if base is not None else 1008)
    ds = synthetic_conditions(
        n,
        args.heights,
        args.seed,
        base=base,
        ref_height=args.ref_height,
        median_speed=args.median_speed,
        turbulence_reference=args.turbulence_reference,
        call=command_line(args),
    )
    write_artefact(ds, args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}: {n} periods at heights {args.heights} m")
    return 0
