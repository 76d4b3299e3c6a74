"""``lidarcal budget RECORDS.nc [--terms TERMS.nc] [--approach iec] -o BUDGET.nc``.

Calibration uncertainty budget per height and 0.5 m s-1 reference wind-speed bin (paper
§3.4, Figure 9), Monte Carlo approach (virtual reference from Table 4 terms, mean and std of
the difference, sigma/sqrt(N)) or IEC field approach (reference anemometer, mean difference,
sigma/sqrt(N), mounting, separation, flow inhomogeneity).
"""

from __future__ import annotations

import argparse

import numpy as np

from lidarcal.analysis.budget import budget
from lidarcal.analysis.certification import digits_text
from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import (
    add_certification_options,
    add_monte_carlo_options,
    add_output_options,
    positive,
    positive_quantity,
    rule_of,
)
from lidarcal.io import check_writable, open_artefact, write_artefact
from lidarcal.readback import read_attr


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``budget`` subcommand."""
    p = sub.add_parser(
        "budget",
        help=COMMANDS["budget"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("records", metavar="RECORDS.nc", help="simulated_rtd or field_campaign file")
    add_output_options(p, "BUDGET.nc")
    p.add_argument("--approach", choices=("monte_carlo", "iec"), default="monte_carlo")
    p.add_argument("--terms", metavar="TERMS.nc", help="uncertainty_terms artefact (Monte Carlo approach)")
    p.add_argument("--noise-terms", choices=("printed", "derived"), default="printed",
                   help="Eqs. 6-7 of the terms computed when no --terms is given: as printed (default) "
                   "or as propagated through the 10-minute average (docs/noise_terms.md)")
    p.add_argument("--bin-width", type=positive_quantity("--bin-width", "m s-1"), default="0.5 m s-1",
                   help="wind speed bin width (default '0.5 m s-1')")
    add_certification_options(p)
    add_monte_carlo_options(p, replicas=False)
    p.add_argument(
        "--height", type=positive("--height"), action="append", metavar="M",
        help="height to include (repeatable)",
    )
    p.add_argument(
        "--coverage-factor", type=positive("--coverage-factor"), default=2.0,
        help="k of the expanded uncertainty (default 2)",
    )
    p.add_argument(
        "--reference-uncertainty",
        metavar="'0.1 m s-1'",
        help="IEC: standard uncertainty of the reference anemometer (absolute part)",
    )
    p.add_argument(
        "--reference-relative-uncertainty",
        default="0 %",
        metavar="'0.5 %'",
        help="IEC: relative part of the reference uncertainty (added in quadrature)",
    )
    for name in ("mounting", "separation", "flow-inhomogeneity"):
        p.add_argument(
            f"--{name}",
            default="0 %",
            metavar="'0 %'",
            help=f"IEC: relative standard uncertainty due to {name.replace('-', ' ')} (default 0)",
        )
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Compute, write and summarise the budget."""
    check_writable(args.output, overwrite=args.overwrite)
    records = open_artefact(args.records)
    terms = open_artefact(args.terms, "uncertainty_terms") if args.terms else None
    call = command_line(args)
    extra = {}
    if args.approach == "iec":
        extra = dict(
            reference_uncertainty=args.reference_uncertainty,
            reference_relative_uncertainty=args.reference_relative_uncertainty,
            mounting=args.mounting,
            separation=args.separation,
            flow_inhomogeneity=args.flow_inhomogeneity,
        )
    ds = budget(
        records,
        terms=terms,
        approach=args.approach,
        bin_width=args.bin_width,
        rule=rule_of(args),
        heights=args.height,
        noise_terms=args.noise_terms,
        source=args.records,
        call=call,
        **extra,
    )
    write_artefact(ds, args.output, overwrite=args.overwrite)
    print(
        f"{args.output}: {args.approach} budget, {ds.sizes['height']} height(s) x "
        f"{ds.sizes['wind_speed']} wind speed bins"
    )
    lo, hi = read_attr(ds, "certified_range_m_s", kind="uncertainty_budget")
    for h in ds.height.values:
        sub = ds.sel(height=h)
        rel = sub.relative_uncertainty.values
        ok = np.isfinite(rel) & (sub.bin_flag.values == 0)
        if ok.any():
            print(
                f"  {h:g} m: relative standard uncertainty "
                f"{np.nanmin(rel[ok]):.2f}-{np.nanmax(rel[ok]):.2f} % "
                f"over {int(ok.sum())} certified bins (centres {lo:g}-{hi:g} m/s, "
                f">= {read_attr(ds, 'min_periods', kind='uncertainty_budget')} periods)"
            )
        else:
            print(f"  {h:g} m: no certified bin (centres {lo:g}-{hi:g} m/s, "
                  f">= {read_attr(ds, 'min_periods', kind='uncertainty_budget')} periods)")
    if "numerical_flag" in ds:
        from lidarcal.certificate import not_settled_sentence  # deferred: only with a Monte Carlo

        digits = read_attr(ds, "monte_carlo_significant_digits", kind="uncertainty_budget")
        missed = not_settled_sentence(ds) or f"every certified bin settled to {digits_text(digits)}"
        replicas = read_attr(ds, "monte_carlo_replicas", kind="uncertainty_budget")
        trials = read_attr(ds, "monte_carlo_trials", kind="uncertainty_budget")
        print(f"  Monte Carlo: {replicas} replica(s), {trials} trials; {missed}")
    return 0
