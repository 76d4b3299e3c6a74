"""``lidarcal simulate``: Monte Carlo over a campaign of 10-minute periods (Dask, resumable).

Examples::

    lidarcal simulate -o sim.nc                                   # embedded sample conditions
    lidarcal simulate --conditions c.nc --cube cube.nc --rwf rwf.nc --heights 40 80 -o sim.nc
    lidarcal simulate --conditions c.nc --workdir run1/ -o sim.nc  # resumable: rerun after a crash
    lidarcal simulate --conditions c.nc --scheduler tcp://10.0.0.5:8786 -o sim.nc

Without ``--cube``/``--rwf`` the ideal lidar of ``docs/contracts.md`` is used, configured by the
conditions file's ``lidar_*`` global attributes when present.

With ``--max-replicas M`` (> 1) the periods of the certified bins whose values (estimate,
standard uncertainty, coverage interval, U) have not settled to ``--significant-digits`` are
simulated again with independent seeds (JCGM 101 7.9; docs/certificate.md), judged with the
Table 4 terms ``lidarcal budget`` uses without ``--terms``; the trials are stored beside
replica 0 (``trial_*`` variables) and ``lidarcal budget`` uses them all.  Without replicas (the
default here) no value can settle, so ``lidarcal budget`` then certifies no bin.
"""

from __future__ import annotations

import argparse
import os

from lidarcal.analysis.certification import digits_text
from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.settings import CONNECT_TIMEOUT, WORKER_TIMEOUT
from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import (
    add_certification_options,
    add_heights_option,
    add_lidar_options,
    add_los_noise_option,
    add_monte_carlo_options,
    add_output_options,
    add_parallel_options,
    add_progress_option,
    add_reference_turbulence_option,
    add_seed_option,
    execution_of,
    nonnegative_int,
    positive,
    rule_of,
)
from lidarcal.conditions import load_conditions, sample_conditions_path
from lidarcal.diagnose import corrected_model
from lidarcal.io import check_writable, open_artefact, write_artefact
from lidarcal.lidar import LidarModel
from lidarcal.readback import read_attr


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``simulate`` subcommand."""
    p = sub.add_parser(
        "simulate",
        help=COMMANDS["simulate"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--conditions",
        metavar="C.nc",
        help="conditions or field_campaign input (default: the embedded brightwind sample)",
    )
    lidar = add_lidar_options(p, default="the ideal lidar, or the conditions' lidar_* attributes")
    add_los_noise_option(lidar)
    add_reference_turbulence_option(lidar)
    p.add_argument("--model", metavar="FILE.nc", help="use the LidarModel in FILE's lidarcal_lidar_model "
                   "attribute, e.g. a diagnosis with its fitted effect added; the attribute records bench "
                   "data by digest: --cube and --rwf then give the cube and RWF the model was built from)")
    add_heights_option(p, help="heights to simulate, m (default: all heights of the conditions)")
    add_seed_option(p, help="base seed; the period at time t uses SeedSequence([seed, t in whole "
                    "seconds since 1970, height_mm])")
    add_parallel_options(p)
    p.add_argument(
        "--los-periods",
        type=nonnegative_int("--los-periods"),
        nargs="+",
        default=(),
        metavar="I",
        help="period indices whose LOS time series are stored",
    )
    p.add_argument(
        "--duration", type=positive("--duration"), default=600.0, metavar="S",
        help="period length, s (default 600)",
    )
    p.add_argument(
        "--timeout",
        type=positive("--timeout"),
        default=CONNECT_TIMEOUT,
        metavar="S",
        help="seconds to wait for a remote scheduler (default %(default)g)",
    )
    p.add_argument(
        "--worker-timeout",
        type=positive("--worker-timeout"),
        default=WORKER_TIMEOUT,
        metavar="S",
        help="dask.distributed: seconds to wait while no worker is connected (none joined, or all "
        "lost) before stopping with exit status 2 (default %(default)g)",
    )
    add_certification_options(p)
    add_monte_carlo_options(p, max_replicas=1)
    add_progress_option(p)
    add_output_options(p, "SIM.nc")
    p.set_defaults(handler=run, resume=lambda args: (args.workdir, None))


def run(args: argparse.Namespace) -> int:
    """Load inputs, build the lidar model, run the campaign and write the ``simulated_rtd`` file."""
    check_writable(args.output, overwrite=args.overwrite)
    conditions = args.conditions or sample_conditions_path()
    cond = load_conditions(conditions, warn=False)  # simulate_campaign reports skipped periods
    inputs = {}
    if args.model:
        cube = open_artefact(args.cube, "bench_cube") if args.cube else None
        rwf = open_artefact(args.rwf, "rwf") if args.rwf else None
        model = corrected_model(args.model, cube=cube, rwf=rwf)
        if args.los_noise:
            model = model.with_los_noise(args.los_noise, cube)
        inputs.update({k: v for k, v in (("model", args.model), ("cube", args.cube), ("rwf", args.rwf)) if v})
    elif args.cube or args.rwf:
        cube = open_artefact(args.cube, "bench_cube") if args.cube else None
        rwf = open_artefact(args.rwf, "rwf") if args.rwf else None
        model = LidarModel.from_artefacts(cube=cube, rwf=rwf, los_noise_model=args.los_noise)
        inputs.update({k: v for k, v in (("cube", args.cube), ("rwf", args.rwf)) if v})
    else:
        model = LidarModel.from_attrs(cond, los_noise_model=args.los_noise)
    if args.reference_turbulence:
        model = model.replace(reference_turbulence=args.reference_turbulence)
    base_seed = args.seed
    execution = execution_of(args)  # one Progress for replica 0 and the replicas: the dashboard said once
    ds = simulate_campaign(
        conditions,
        model,
        heights=args.heights,
        base_seed=base_seed,
        los_periods=args.los_periods,
        duration=args.duration,
        execution=execution.labelled("replica 0" if args.max_replicas > 1 else "simulation"),
        inputs=inputs,
        call=command_line(args),
    )
    if args.max_replicas > 1:
        from lidarcal.campaign.adaptive import adaptive_replicas  # deferred: only with replicas

        ds, bud = adaptive_replicas(ds, conditions, model, rule=rule_of(args), max_replicas=args.max_replicas,
                                    base_seed=base_seed, duration=args.duration, execution=execution)
        from lidarcal.certificate import not_settled_sentence  # deferred: only with replicas

        missed = (not_settled_sentence(bud)
                  or f"every certified bin settled to {digits_text(args.significant_digits)}")
        replicas = read_attr(bud, "monte_carlo_replicas", kind="uncertainty_budget")
        print(f"Monte Carlo: {replicas} replica(s), {ds.sizes.get('trial', 0)} further trials; {missed}")
    if not args.model and args.cube and (serial := read_attr(cube, "lidar_serial", kind="bench_cube")):
        ds.attrs["lidar_serial"] = serial  # records of the cube's lidar
    write_artefact(ds, args.output, overwrite=args.overwrite)
    skipped = read_attr(ds, "lidarcal_skipped_count", kind="simulated_rtd")
    print(
        f"wrote {os.fspath(args.output)}: {ds.sizes['time']} periods x {ds.sizes['height']} heights, "
        f"{skipped} (period, height) skipped for missing input, base seed {base_seed}"
    )
    return 0
