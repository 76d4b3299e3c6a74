r"""``lidarcal turbulence``: turbulence at the points a virtual lidar samples at one height.

Writes a ``turbulence_box`` artefact (dims ``point``, ``time``; u, v, w fluctuations in the wind
frame; point coordinates x, y, z in m) for inspection.  With the default fast generator the
series are exactly those ``simulate_period`` uses for that height and ``--seed``.  Examples::

    lidarcal turbulence --wind-speed 8 --ti 0.1 --height 100 --direction 0 --seed 1 -o box.nc
    lidarcal turbulence --wind-speed 8 --ti 0.1 --height 100 --direction 30 --seed 1 2 \\
        --generator pyconturb -o box_pct.nc
"""

from __future__ import annotations

import argparse

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import add_output_options, nonnegative_int, number, positive, positive_int
from lidarcal.io import check_writable, write_artefact
from lidarcal.lidar import DEFAULT_RWF_FWHM, LidarModel
from lidarcal.lidar.box import lidar_turbulence_box
from lidarcal.turbulence.box import GENERATORS
from lidarcal.units import Q_


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``turbulence`` subcommand."""
    p = sub.add_parser("turbulence", help=COMMANDS["turbulence"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--wind-speed", type=positive("--wind-speed"), required=True, metavar="M_S",
                   help="mean wind speed, m/s")
    p.add_argument("--ti", type=number("--ti", lo=0, hi=1), required=True,
                   help="turbulence intensity sigma_u / U (e.g. 0.1)")
    p.add_argument("--height", type=positive("--height"), required=True, metavar="M",
                   help="measurement height, m")
    p.add_argument("--direction", type=number("--direction", lo=-360, hi=720), default=0.0, metavar="DEG",
                   help="wind-from direction relative to the lidar's north mark, degree (0)")
    p.add_argument("--shear", type=number("--shear", lo=-2, hi=2), default=0.0, metavar="ALPHA",
                   help="power-law shear exponent (0)")
    p.add_argument("--seed", type=nonnegative_int("--seed"), nargs="+", default=[0], metavar="INT",
                   help="seed tuple as simulate_period takes it, e.g. BASE_SEED PERIOD_KEY (a "
                   "simulated_rtd's period_key) (0)")
    p.add_argument("--duration", type=positive("--duration"), default=600.0, metavar="S",
                   help="period length, s (600)")
    p.add_argument("--cone-angle", type=number("--cone-angle", lo=0, hi=90, lo_open=True, hi_open=True),
                   default=LidarModel.cone_angle, metavar="DEG",
                   help="cone angle from vertical (%(default)g)")
    p.add_argument("--rwf-fwhm", type=positive("--rwf-fwhm"), default=DEFAULT_RWF_FWHM, metavar="M",
                   help="Gaussian RWF FWHM, m (%(default)g)")
    p.add_argument("--nodes", type=positive_int("--nodes"), default=5,
                   help="RWF quadrature nodes per beam (5)")
    p.add_argument("--beam-period", type=positive("--beam-period"), default=1.0, metavar="S",
                   help="seconds per LOS (1)")
    p.add_argument("--generator", choices=GENERATORS, default="fast",
                   help="fast (lidarcal's) or pyconturb (gen_turb; slower) (fast)")
    add_output_options(p, "BOX.nc")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Simulate the box and write it."""
    check_writable(args.output, overwrite=args.overwrite)
    model = LidarModel.ideal(cone_angle=args.cone_angle, rwf_fwhm=args.rwf_fwhm,
                             beam_period=args.beam_period, n_nodes=args.nodes)
    ds = lidar_turbulence_box(
        model, height=Q_(args.height, "m"), wind_speed=Q_(args.wind_speed, "m/s"),
        turbulence_intensity=args.ti, wind_from_direction=Q_(args.direction, "degree"), seed=tuple(args.seed),
        wind_shear_exponent=args.shear, duration=Q_(args.duration, "s"), generator=args.generator,
        call=command_line(args))
    write_artefact(ds, args.output, overwrite=args.overwrite)
    std = ds[["u", "v", "w"]].std("time")
    print(f"{args.output}: {ds.sizes['point']} points x {ds.sizes['time']} steps; mean std over points "
          f"u {float(std.u.mean()):.3f}, v {float(std.v.mean()):.3f}, w {float(std.w.mean()):.3f} m/s "
          f"(target {ds.attrs['lidarcal_sigma_u']:.3f}, {ds.attrs['lidarcal_sigma_v']:.3f}, "
          f"{ds.attrs['lidarcal_sigma_w']:.3f})")
    return 0
