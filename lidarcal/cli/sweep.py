"""``lidarcal sweep [--cube C.nc] [--rwf R.nc] [--wind-speed 4:16:4 ...] -o SWEEP.nc``.

Classification-style sweep (paper Discussion a-b): simulate the virtual lidar on a full
grid of conditions and report the maximum |deviation| from the virtual reference and the
sensitivity slopes over the whole parameter space.  Grid values: ``START:STOP:STEP``
(inclusive) or a comma list, in the canonical units (m s-1, 1, 1, dB, dB m-1, degree).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from lidarcal.analysis._records import CANONICAL_UNITS
from lidarcal.analysis.sweep import DEFAULT_GRID, SWEEP_VARIABLES, sweep
from lidarcal.cli import command_line
from lidarcal.errors import InputError
from lidarcal.io import check_writable, open_artefact, write_artefact
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
        help="maximum deviation and slopes over a full grid of conditions",
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
    p.add_argument(
        "--height", type=float, action="append", metavar="M", help="height (repeatable; default 100)"
    )
    p.add_argument("--repeats", type=int, default=1, help="Monte Carlo replicates per grid point (default 1)")
    p.add_argument("--cube", metavar="CUBE.nc", help="bench_cube artefact (default: ideal Gaussian noise)")
    p.add_argument("--rwf", metavar="RWF.nc", help="rwf artefact (default: ideal Gaussian RWF)")
    p.add_argument("--seed", type=int, help="base seed")
    p.add_argument("--scheduler", help="dask scheduler (default: local processes)")
    p.add_argument("--workers", type=int, metavar="N")
    p.add_argument("--chunk", type=int, default=64, metavar="N", help="periods per task (default 64)")
    p.add_argument("--workdir", metavar="DIR", help="resumable chunk cache")
    p.add_argument("--records-output", metavar="SIM.nc", help="also write the simulated records")
    p.add_argument("-o", "--output", required=True, metavar="SWEEP.nc")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Build the grid, simulate, analyse, write."""
    from lidarcal.lidar import LidarModel

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
    model = LidarModel.from_artefacts(cube=cube, rwf=rwf)
    inputs = {k: v for k, v in (("cube", args.cube), ("rwf", args.rwf)) if v}
    call = command_line(args)
    ds, records = sweep(
        model,
        grid=grid,
        heights=args.height or (100.0,),
        repeats=args.repeats,
        base_seed=args.seed,
        scheduler=args.scheduler,
        workers=args.workers,
        chunk=args.chunk,
        workdir=args.workdir,
        progress=sys.stderr.isatty(),
        call=call,
        inputs=inputs,
    )
    write_artefact(ds, args.output, overwrite=args.overwrite)
    if args.records_output:
        write_artefact(records, args.records_output, overwrite=args.overwrite)
    print(f"{args.output}: {ds.attrs['sweep_points']} grid points x {ds.attrs['sweep_repeats']} replicate(s)")
    for i, h in enumerate(ds.height.values):
        where = ", ".join(f"{n}={float(ds[f'max_deviation_{n}'][i]):g}" for n in SWEEP_VARIABLES)
        print(f"  {h:g} m: max |deviation| {float(ds.max_abs_deviation[i]):.3f} % at {where}")
        if "variable" in ds.coords:
            for v in ds.variable.values:
                st = float(ds.slope_times_std.sel(variable=v)[i])
                sig = "significant" if int(ds.significant.sel(variable=v)[i]) else "not significant"
                print(f"      {v}: m*std = {st:+.3f} % ({sig})")
    return 0
