"""``lidarcal rwf``: range-weighting function, CNR weighting and zero distance (Eqs. 1–2).

Examples::

    lidarcal rwf --pulse-length 25 --fft-size 64 -o rwf.nc
    lidarcal rwf --pulse-length 25 --asymmetry 0.2 -o rwf_asym.nc
    lidarcal rwf --pulse-file sample_data/rwf/pulse_example.csv --fft-size 128 -o rwf_xp.nc
"""

from __future__ import annotations

import argparse

import numpy as np

from lidarcal.cli import COMMANDS, command_line
from lidarcal.cli.options import add_output_options, finite, positive
from lidarcal.io import check_writable, write_artefact
from lidarcal.readback import read_attr
from lidarcal.rwf import range_weighting_function
from lidarcal.units import Q_


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``rwf`` subcommand."""
    p = sub.add_parser("rwf", help=COMMANDS["rwf"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    pulse = p.add_argument_group("pulse")
    pulse.add_argument("--pulse-length", type=positive("--pulse-length"), default=25.0, metavar="M",
                       help="pulse FWHM in range, c*tau/2, metres (default 25, the paper's WindCube)")
    pulse.add_argument("--asymmetry", type=finite("--asymmetry"), default=0.0,
                       help="two-sided Gaussian asymmetry (s_far - s_near)/(s_far + s_near) in (-1, 1); "
                            "positive = longer tail away from the lidar (default 0 = Gaussian)")
    pulse.add_argument("--pulse-offset", type=finite("--pulse-offset"), default=0.0, metavar="M",
                       help="pulse peak beyond the nominal gate centre, metres (a Zd error; default 0)")
    pulse.add_argument("--pulse-file", metavar="CSV",
                       help="measured pulse: CSV with 'time_<unit>' or 'range_offset_<unit>' and 'intensity' "
                            "columns (see lidarcal.rwf); overrides the synthetic shape")
    apod = p.add_argument_group("apodization")
    apod.add_argument("--fft-size", type=int, choices=(64, 128), default=64,
                      help="FFT length in samples (64: WindCube v2.1, 128: WindCube XP; default 64)")
    apod.add_argument("--sampling-frequency", type=positive("--sampling-frequency"), default=250.0,
                      metavar="MHZ",
                      help="digitiser sampling frequency in MHz (default 250, i.e. 0.6 m per sample)")
    apod.add_argument("--window-std", type=positive("--window-std"), default=0.2, metavar="FRACTION",
                      help="Gaussian window std as a fraction of the FFT length (default 0.2)")
    grid = p.add_argument_group("grid")
    grid.add_argument("--cnr-gradient", type=finite("--cnr-gradient"), nargs="+", metavar="DB_PER_M",
                      help="CNR gradients in dB m-1 (default -0.1 ... 0.1 in 0.01 steps; 0 always added)")
    grid.add_argument("--resolution", type=positive("--resolution"), default=0.1, metavar="M",
                      help="range_offset grid spacing in metres (default 0.1)")
    grid.add_argument("--half-width", type=positive("--half-width"), metavar="M",
                      help="range_offset grid half extent in metres (default: just wide enough)")
    add_output_options(p, "RWF.nc")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Compute the RWF artefact, write it and print its zero distance and width."""
    check_writable(args.output, overwrite=args.overwrite)
    ds = range_weighting_function(
        pulse_length=Q_(args.pulse_length, "m"),
        asymmetry=args.asymmetry,
        pulse_offset=Q_(args.pulse_offset, "m"),
        pulse_file=args.pulse_file,
        fft_size=args.fft_size,
        sampling_frequency=Q_(args.sampling_frequency, "MHz"),
        window_std_fraction=args.window_std,
        cnr_gradient=None if args.cnr_gradient is None else Q_(np.asarray(args.cnr_gradient), "dB m-1"),
        resolution=Q_(args.resolution, "m"),
        half_width=None if args.half_width is None else Q_(args.half_width, "m"),
        call=command_line(args),
    )
    path = write_artefact(ds, args.output, overwrite=args.overwrite)
    g = ds.cnr_gradient.values
    print(f"{path}: {read_attr(ds, 'pulse_shape', kind='rwf')} pulse, FFT {args.fft_size} points")
    print(f"  zero distance Zd      {float(ds.zero_distance):+.4f} m")
    print(f"  RWF FWHM              {float(ds.rwf_fwhm):.3f} m")
    print(f"  barycenter at {g.min():+g} / {g.max():+g} dB m-1: "
          f"{float(ds.barycenter[0]):+.3f} / {float(ds.barycenter[-1]):+.3f} m")
    return 0

