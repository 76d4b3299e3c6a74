"""``lidarcal sweep [--cube C.nc] [--rwf R.nc] [--wind-speed 4:16:4 ...] -o SWEEP.nc``.

Classification-style sweep (paper Discussion a-b): simulate the virtual lidar on a full
grid of conditions and report the maximum |deviation| from the virtual reference and the
sensitivity slopes over the whole parameter space.  Grid values: ``START:STOP:STEP``
(inclusive) or a comma list, in the canonical units (m s-1, 1, 1, dB, dB m-1, degree).
"""

from __future__ import annotations

import argparse

import numpy as np

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import (
    add_heights_option,
    add_lidar_options,
    add_los_noise_option,
    add_output_options,
    add_parallel_options,
    add_progress_option,
    add_reference_turbulence_option,
    add_seed_option,
    execution_of,
    positive_int,
)
from lidarcal.conditions.grid import DEFAULT_GRID, SWEEP_VARIABLES
from lidarcal.conditions.variables import CANONICAL_UNITS
from lidarcal.errors import InputError
from lidarcal.io import check_writable, open_artefact, write_artefact
from lidarcal.lidar import LidarModel
from lidarcal.pipeline import sweep
from lidarcal.readback import read_attr
from lidarcal.units import Q_


def parse_values(text: str, name: str) -> list[float]:
    """``"4:16:4"`` → [4, 8, 12, 16]; ``"0.05,0.1"`` → [0.05, 0.1]."""
    try:
        if ":" in text:
            start, stop, step = (float(x) for x in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            n = int(np.floor((stop - start) / step + 1e-9)) + 1
            return [round(start + i * step, 12) for i in range(n)]
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError(
            f"--{name.replace('_', '-')} {text!r}: expected START:STOP:STEP (STEP > 0) or a "
            "comma-separated list of numbers"
        ) from None


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``sweep`` subcommand."""
    p = sub.add_parser(
        "sweep",
        help=COMMANDS["sweep"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    for name in SWEEP_VARIABLES:
        default = ",".join(f"{v:g}" for v in DEFAULT_GRID[name])
        p.add_argument(
            f"--{name.replace('_', '-')}",
            metavar="VALUES",
            help=f"grid of {name} in {CANONICAL_UNITS[name]} (default {default})",
        )
    add_heights_option(p, default=(100.0,), help="heights, m (default 100)")
    p.add_argument("--repeats", type=positive_int("--repeats"), default=1, metavar="N",
                   help="Monte Carlo replicates per grid point (default 1)")
    lidar = add_lidar_options(p, default="the ideal Gaussian lidar")
    add_los_noise_option(lidar)
    add_reference_turbulence_option(lidar)
    add_seed_option(p)
    add_parallel_options(p)
    add_progress_option(p)
    p.add_argument("--records-output", metavar="SIM.nc", help="also write the simulated records")
    add_output_options(p, "SWEEP.nc")
    p.set_defaults(handler=run, resume=lambda args: (args.workdir, None))


def run(args: argparse.Namespace) -> int:
    """Build the grid, simulate, analyse, write."""
    check_writable(args.output, overwrite=args.overwrite)
    if args.records_output:
        check_writable(args.records_output, overwrite=args.overwrite)
    grid = {}
    for name in SWEEP_VARIABLES:
        text = getattr(args, name)
        if text is not None:
            vals = parse_values(text, name)
            unit = CANONICAL_UNITS[name]
            grid[name] = vals if unit in ("1", "dB", "dB m-1") else Q_(np.asarray(vals), unit)
    cube = open_artefact(args.cube, "bench_cube") if args.cube else None
    rwf = open_artefact(args.rwf, "rwf") if args.rwf else None
    model = LidarModel.from_artefacts(cube=cube, rwf=rwf, los_noise_model=args.los_noise)
    if args.reference_turbulence:
        model = model.replace(reference_turbulence=args.reference_turbulence)
    inputs = {k: v for k, v in (("cube", args.cube), ("rwf", args.rwf)) if v}
    call = command_line(args)
    ds, records = sweep(
        model,
        grid=grid,
        heights=args.heights,
        repeats=args.repeats,
        base_seed=args.seed,
        execution=execution_of(args),
        call=call,
        inputs=inputs,
    )
    write_artefact(ds, args.output, overwrite=args.overwrite)
    if args.records_output:
        write_artefact(records, args.records_output, overwrite=args.overwrite)
    print(f"{args.output}: {read_attr(ds, 'sweep_points', kind='sweep')} grid points x "
          f"{read_attr(ds, 'sweep_repeats', kind='sweep')} replicate(s)")
    for i, h in enumerate(ds.height.values):
        where = ", ".join(f"{n}={float(ds[f'max_deviation_{n}'][i]):g}" for n in SWEEP_VARIABLES)
        print(f"  {h:g} m: max |deviation| {float(ds.max_abs_deviation[i]):.3f} % at {where}")
        if "variable" in ds.coords:
            for v in ds.variable.values:
                st = float(ds.slope_times_std.sel(variable=v)[i])
                sig = "significant" if int(ds.significant.sel(variable=v)[i]) else "not significant"
                print(f"      {v}: m*std = {st:+.3f} % ({sig})")
    return 0
