"""``lidarcal sensitivity RECORDS.nc --variable VAR [--variable ...] -o OUT.nc``.

IEC 61400-50-2 style sensitivity of the lidar-reference difference to environmental
variables (paper §3.3, Eqs. 12-13).  One ``sensitivity`` artefact per variable: with several
``--variable``, ``-o`` must contain ``{variable}`` (e.g. ``-o sens_{variable}.nc``).
"""

from __future__ import annotations

import argparse

import numpy as np

from lidarcal.analysis.budget import DEFAULT_MIN_PERIODS
from lidarcal.analysis.sensitivity import sensitivity
from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import add_output_options, nonnegative, positive, positive_int, positive_quantity
from lidarcal.conditions.variables import CANONICAL_UNITS
from lidarcal.errors import InputError
from lidarcal.io import check_writable, open_artefact, write_artefact


def _bin_width(text: str) -> str:
    """Argparse ``type`` of ``--bin-width [VAR=]WIDTH``: the width must be a quantity > 0."""
    _name, sep, value = text.partition("=")
    positive_quantity("--bin-width")(value if sep else text)
    return text


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``sensitivity`` subcommand."""
    p = sub.add_parser(
        "sensitivity",
        help=COMMANDS["sensitivity"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("records", metavar="RECORDS.nc", help="simulated_rtd or field_campaign file")
    p.add_argument(
        "--variable",
        action="append",
        required=True,
        metavar="VAR",
        help="environmental variable to bin by (repeatable), e.g. wind_shear_exponent",
    )
    add_output_options(p, "OUT.nc", help="output file; with several variables it must contain {variable}")
    p.add_argument(
        "--bin-width",
        action="append",
        type=_bin_width,
        default=[],
        metavar="[VAR=]WIDTH",
        help="bin width, e.g. 0.05 or 'wind_speed=0.5 m s-1' (bare numbers: the variable's "
        "canonical units); default per variable",
    )
    p.add_argument(
        "--min-periods",
        type=positive_int("--min-periods"),
        default=DEFAULT_MIN_PERIODS,
        help=f"minimum periods per bin used in the regression (default {DEFAULT_MIN_PERIODS})",
    )
    p.add_argument(
        "--regression",
        choices=("weighted", "unweighted"),
        default="weighted",
        help="weighted: least squares of bin means with weights n/s2 (default); unweighted: ordinary "
        "least squares on bin centres, as the paper describes the IEC 61400-50-2 procedure",
    )
    p.add_argument(
        "--absolute", action="store_true", help="difference in m s-1 instead of %% of the reference"
    )
    p.add_argument(
        "--height", type=positive("--height"), action="append", metavar="M",
        help="height to analyse (repeatable)",
    )
    p.add_argument(
        "--reference-range",
        nargs=2,
        type=nonnegative("--reference-range"),
        default=[4.0, 16.0],
        metavar=("LO", "HI"),
        help="reference wind speed range in m s-1 (default 4 16)",
    )
    p.add_argument("--all-wind-speeds", action="store_true", help="use every period (no reference range)")
    p.set_defaults(handler=run)


def _widths(specs: list[str], variables: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for spec in specs:
        name, sep, value = spec.partition("=")
        targets = [name] if sep else variables
        value = value if sep else spec
        if sep and name not in variables:
            raise InputError(
                f"--bin-width {spec!r}: {name!r} is not one of the --variable values {variables}"
            )
        for v in targets:
            try:
                float(value)
                out[v] = f"{value} {CANONICAL_UNITS.get(v, '')}".strip()
            except ValueError:
                out[v] = value
    return out


def run(args: argparse.Namespace) -> int:
    """Compute and write one sensitivity artefact per variable; print the slopes."""
    variables = list(dict.fromkeys(args.variable))
    if len(variables) > 1 and "{variable}" not in args.output:
        raise InputError(
            f"-o {args.output!r}: with several --variable the output name must contain "
            "'{variable}', e.g. sens_{variable}.nc"
        )
    outputs = {v: args.output.replace("{variable}", v) for v in variables}
    for path in outputs.values():
        check_writable(path, overwrite=args.overwrite)
    widths = _widths(args.bin_width, variables)
    records = open_artefact(args.records)
    call = command_line(args)
    results = {}
    for v in variables:  # compute everything first: nothing is written if one variable fails
        results[v] = sensitivity(
            records,
            v,
            bin_width=widths.get(v),
            min_periods=args.min_periods,
            regression=args.regression,
            relative=not args.absolute,
            heights=args.height,
            reference_range=None if args.all_wind_speeds else tuple(args.reference_range),
            source=args.records,
            call=call,
        )
    for v, ds in results.items():
        write_artefact(ds, outputs[v], overwrite=args.overwrite)
        print(f"{outputs[v]}: sensitivity to {v} [slope in {ds.slope.attrs['units']}]")
        print(
            f"  {'height':>8} {'slope':>10} {'SE':>8} {'R':>7} {'std':>9} {'m*std':>8} {'m*std*R':>8} "
            f"{'Eq12':>5} {'Eq13':>5}"
        )
        for i, h in enumerate(ds.height.values):
            row = [
                ds[n].values[i]
                for n in (
                    "slope",
                    "slope_standard_error",
                    "correlation",
                    "variable_std",
                    "slope_times_std",
                    "slope_times_std_times_r",
                )
            ]
            f12, f13 = (int(ds[n].values[i]) for n in ("significant_eq12", "significant_eq13"))
            txt = " ".join(
                f"{x:>{w}.4g}" if np.isfinite(x) else f"{'nan':>{w}}"
                for x, w in zip(row, (10, 8, 7, 9, 8, 8), strict=True)
            )
            print(f"  {h:>8g} {txt} {'yes' if f12 else 'no':>5} {'yes' if f13 else 'no':>5}")
    return 0
