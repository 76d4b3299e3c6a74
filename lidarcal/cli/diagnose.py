"""``lidarcal diagnose``: find, name and add the effect that explains a field–model gap.

``lidarcal diagnose FIELD.nc [--cube CUBE.nc] [--rwf RWF.nc] -o DIAGNOSIS.nc [--json] [--report R.html]``
(``docs/diagnose.md``).  With ``--json`` only the JSON object goes to stdout; progress goes to stderr.

``lidarcal diagnose-generate --effect ID [--param NAME=VALUE] -o FIELD.nc`` writes a synthetic
``field_campaign`` with one hidden catalogue effect (for tests, demos and benchmarks).
"""

from __future__ import annotations

import argparse
import json
import sys

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import (
    add_heights_option,
    add_lidar_options,
    add_output_options,
    add_parallel_options,
    add_progress_option,
    add_seed_option,
    execution_of,
    nonnegative,
    nonnegative_int,
    number,
    positive_int,
    probability,
)
from lidarcal.conditions import load_conditions
from lidarcal.diagnose.core import diagnose
from lidarcal.diagnose.dataset import summary, to_dataset
from lidarcal.diagnose.effects import EFFECTS
from lidarcal.diagnose.generate import GENERATOR_SEED, generate_field_campaign, hidden_effect_conditions
from lidarcal.diagnose.problem import DEFAULT_BOOTSTRAP, DEFAULT_MODEL_UNCERTAINTY
from lidarcal.diagnose.report import write_report
from lidarcal.diagnose.selection import DEFAULT_TOLERANCE
from lidarcal.errors import InputError
from lidarcal.io import check_writable, open_artefact, write_artefact


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``diagnose`` and ``diagnose-generate`` subcommands."""
    p = sub.add_parser("diagnose", help=COMMANDS["diagnose"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("field", metavar="FIELD.nc", help="field_campaign netCDF (docs/contracts.md)")
    add_lidar_options(p, default="the field file's lidar_* attributes")
    add_output_options(p, "DIAGNOSIS.nc", help="diagnosis artefact to write")
    p.add_argument("--json", action="store_true", help="print only the JSON summary on stdout")
    p.add_argument("--report", metavar="REPORT.html", help="also write an offline HTML report")
    p.add_argument("--candidates", nargs="+", choices=[e for e in EFFECTS if e != "none"], metavar="EFFECT",
                   help="catalogue effects to try (default: all)")
    add_seed_option(p, help="base seed of the simulations")
    p.add_argument("--bins", type=number("--bins", lo=2, integer=True), default=6,
                   help="quantile bins per environmental variable")
    p.add_argument("--min-bin-count", type=positive_int("--min-bin-count"), default=10,
                   help="periods a bin needs to count")
    p.add_argument("--alpha", type=probability("--alpha"), default=0.01, help="family-wise false-alarm rate")
    p.add_argument("--bic-threshold", type=nonnegative("--bic-threshold"), default=6.0,
                   help="ΔBIC an effect must beat")
    p.add_argument("--tolerance", type=nonnegative("--tolerance"), default=DEFAULT_TOLERANCE,
                   help="practical tolerance, %% of wind speed: an effect must change (L-R)/R by more, and a "
                        "smaller gap is 'none' (default %(default)g %%: a tenth of the ~1 %% calibration "
                        "uncertainty)")
    p.add_argument("--bootstrap", type=positive_int("--bootstrap"), default=DEFAULT_BOOTSTRAP,
                   help="day-block bootstrap resamples for the uncertainties and 95 %% intervals")
    p.add_argument("--model-uncertainty", type=nonnegative("--model-uncertainty"),
                   default=DEFAULT_MODEL_UNCERTAINTY,
                   help="model-form standard uncertainty of a fitted parameter, as a share of its fitted "
                        "change (added to the bootstrap; an effect whose derived or fitted share is larger "
                        "uses that, docs/diagnose.md)")
    p.add_argument("--min-wind-speed", type=nonnegative("--min-wind-speed"), default=3.0,
                   help="minimum reference speed, m s-1")
    _sim_args(p)
    p.set_defaults(handler=run)

    g = sub.add_parser("diagnose-generate", help=COMMANDS["diagnose-generate"].help,
                       description=_generate.__doc__)
    g.add_argument("--effect", default="none", choices=list(EFFECTS), help="hidden catalogue effect")
    g.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                   help="effect parameter (default: a realistic strength)")
    g.add_argument("--conditions", metavar="C.nc", help="conditions to simulate (default: synthetic)")
    g.add_argument("--periods", type=positive_int("--periods"), default=300,
                   help="synthetic periods (without --conditions)")
    add_heights_option(g, default=(40.0, 80.0, 120.0, 160.0),
                       help="synthetic heights, m (without --conditions)")
    g.add_argument("--conditions-seed", type=nonnegative_int("--conditions-seed"), default=11,
                   help="seed of the synthetic conditions")
    # not the diagnosis' seed: the hidden effect must be found through independent noise
    add_seed_option(g, default=GENERATOR_SEED, help="base seed of the measurement simulation")
    add_output_options(g, "FIELD.nc")
    _sim_args(g)
    g.set_defaults(handler=_generate)


def _sim_args(p: argparse.ArgumentParser) -> None:
    add_parallel_options(p, workdir=False)
    add_progress_option(p)


def run(args: argparse.Namespace) -> int:
    """Run the diagnosis, write the artefact (and report), print the summary."""
    check_writable(args.output, overwrite=args.overwrite)
    if args.report:
        check_writable(args.report, overwrite=args.overwrite)
    cube = open_artefact(args.cube, "bench_cube") if args.cube else None
    rwf = open_artefact(args.rwf, "rwf") if args.rwf else None
    result = diagnose(
        args.field, cube=cube, rwf=rwf, candidates=args.candidates, base_seed=args.seed, n_bins=args.bins,
        min_bin_count=args.min_bin_count, alpha=args.alpha, bic_threshold=args.bic_threshold,
        tolerance=args.tolerance, n_bootstrap=args.bootstrap, model_uncertainty=args.model_uncertainty,
        min_wind_speed=args.min_wind_speed,
        execution=execution_of(args))
    inputs = {"field": args.field, **({"cube": args.cube} if args.cube else {}),
              **({"rwf": args.rwf} if args.rwf else {})}
    call = command_line(args)
    ds = to_dataset(result, call=call, inputs=inputs)
    write_artefact(ds, args.output, overwrite=args.overwrite)
    if args.report:
        write_report(ds, args.report, overwrite=args.overwrite)
    js = summary(result)
    if args.json:
        print(json.dumps(js))
    else:
        named = " + ".join(e["effect"] for e in js["effects"]) or js["effect"]
        print(f"{args.field}: effect {named} {js['parameters']} (± {js['uncertainties']}); "
              f"gap {js['gap_before']:.3f} % -> {js['gap_after']:.3f} % "
              f"(noise floor {js['gap_noise_floor']:.3f} %)\n  {js['note']}\n  wrote {args.output}")
    return 0


def _parse_params(items: list[str]) -> dict[str, float] | None:
    if not items:
        return None
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise InputError(f"--param {item!r}: expected NAME=NUMBER, e.g. offset=4") from None
    return out


def _generate(args: argparse.Namespace) -> int:
    """Simulate a field campaign with a hidden catalogue effect and write it (field_campaign)."""
    check_writable(args.output, overwrite=args.overwrite)
    if args.conditions:
        cond = load_conditions(args.conditions)
    else:
        cond = hidden_effect_conditions(args.periods, args.heights, args.conditions_seed)
    ds = generate_field_campaign(cond, args.effect, _parse_params(args.param), base_seed=args.seed,
                                 execution=execution_of(args),
                                 call=command_line(args))
    write_artefact(ds, args.output, overwrite=args.overwrite)
    print(f"wrote {args.output}: {ds.sizes['time']} periods x {ds.sizes['height']} heights, hidden effect "
          f"{ds.attrs['lidarcal_hidden_effect']}", file=sys.stderr)
    return 0
