r"""``lidarcal field from-sta`` and ``lidarcal conditions from-sta``: WindCube ``.sta`` files in.

Examples::

    lidarcal conditions from-sta day1.sta day2.sta -o conditions.nc --min-availability 80
    lidarcal field from-sta day1.sta day2.sta --reference mast.csv \
        --reference-columns 80=Spd80mN,60=Spd60mN --reference-std 80=Spd80mNStd,60=Spd60mNStd -o field.nc
"""

from __future__ import annotations

import argparse

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import add_contact_options, number
from lidarcal.conditions.mast import parse_height_columns, sta_field_campaign
from lidarcal.conditions.sta import sta_conditions
from lidarcal.io import check_writable, write_artefact


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="+", metavar="FILE.sta", help="WindCube 10-minute statistics files")
    p.add_argument("--min-availability", type=number("--min-availability", lo=0, hi=100), default=80.0,
                   metavar="PCT",
                   help="data availability (%%) a period needs at a height, else NaN there (default 80)")
    p.add_argument("--allow-gaps", action="store_true",
                   help="read rows cut short (truncated files) as missing periods, with a warning naming "
                        "them, instead of refusing the file")
    p.add_argument("--cone-angle", type=number("--cone-angle", lo=0, hi=90, lo_open=True, hi_open=True),
                   metavar="DEGREES",
                   help="the lidar's cone angle from vertical where a file's header says ScanAngle=NA "
                        "(WindCube firmware 2.x); a file stating another angle is refused (default: the "
                        "files' own; never guessed)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    add_contact_options(p)


def add_conditions_from_sta(acts: argparse._SubParsersAction) -> None:
    """Add ``conditions from-sta`` to the ``conditions`` actions."""
    p = acts.add_parser("from-sta", help="read WindCube .sta files into a conditions file",
                        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    _common(p)
    p.add_argument("-o", "--output", required=True, metavar="CONDITIONS.nc")
    p.set_defaults(handler=run_conditions)


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``field`` subcommand and its ``from-sta`` action."""
    p = sub.add_parser("field", help=COMMANDS["field"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    acts = p.add_subparsers(dest="action", metavar="ACTION")
    f = acts.add_parser("from-sta", help="lidar .sta files + mast CSV -> field_campaign",
                        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    _common(f)
    f.add_argument("--reference", required=True, metavar="MAST.csv", help="met-mast CSV record")
    f.add_argument("--reference-columns", required=True, metavar="H=COL,...",
                   help="mean-speed column per height in m, e.g. 80=Spd80mN,60=Spd60mN")
    f.add_argument("--reference-std", metavar="H=COL,...",
                   help="standard deviation column per height (TI from the mast; else from the lidar)")
    f.add_argument("--reference-timestamp", choices=("start", "end"), default="start",
                   help="the mast's stamps mark the interval start (default) or end")
    f.add_argument("--reference-units", metavar="UNIT",
                   help="unit of the mast's speed columns whose names declare none, e.g. km/h, knot "
                        "(default m/s); a name like 'Spd80 (km/h)', 'Spd80 [km/h]' or 'Spd80_kmh' "
                        "declares its own")
    f.add_argument("--skip-ratio-check", action="store_true",
                   help="accept a campaign whose median lidar / reference speed ratio is outside 0.8-1.25 "
                        "(by default refused as a unit or column mix-up)")
    f.add_argument("--reference-time-column", metavar="NAME", help="time column (default: the first)")
    f.add_argument("-o", "--output", required=True, metavar="FIELD.nc")
    f.set_defaults(handler=run_field)
    p.set_defaults(handler=lambda args: p.print_help() or 1)


def run_conditions(args: argparse.Namespace) -> int:
    """Read the ``.sta`` files and write a ``conditions`` artefact."""
    check_writable(args.output, overwrite=args.overwrite)
    ds = sta_conditions(args.files, args.min_availability, allow_gaps=args.allow_gaps,
                        cone_angle=args.cone_angle, call=command_line(args))
    write_artefact(ds, args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}: {ds.sizes['time']} periods at heights {ds.height.values.tolist()} m")
    return 0


def run_field(args: argparse.Namespace) -> int:
    """Read the ``.sta`` files and the mast CSV and write a ``field_campaign`` artefact."""
    check_writable(args.output, overwrite=args.overwrite)
    columns = parse_height_columns(args.reference_columns, "--reference-columns")
    std = parse_height_columns(args.reference_std, "--reference-std") if args.reference_std else None
    ds = sta_field_campaign(args.files, args.reference, columns, std, timestamp=args.reference_timestamp,
                            time_column=args.reference_time_column, min_availability=args.min_availability,
                            allow_gaps=args.allow_gaps, units=args.reference_units,
                            check_ratio=not args.skip_ratio_check, cone_angle=args.cone_angle,
                            call=command_line(args))
    write_artefact(ds, args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}: {ds.sizes['time']} periods at heights {ds.height.values.tolist()} m, "
          f"{ds.attrs['reference_matched_periods']} with a mast record")
    return 0
