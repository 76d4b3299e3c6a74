"""Time ``simulate_period`` for one 8-height period on one core (docs/performance.md).

    python benchmarks/bench_engine.py [--periods 60] [--profile]

Prints the median wall-clock and CPU milliseconds per period (and per (period, height)) and
periods per second.  The campaign target is >= 40 periods/s on 2 cores (aim 60), i.e. <= ~50 ms
per 8-height period per core.
Conditions vary per period (speed 4-16 m/s, any direction, TI 0.05-0.25, shear 0-0.3) so
that nothing is accidentally cached.  The machine may be shared: CPU time is the steadier
number.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import cProfile  # noqa: E402
import pstats  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lidarcal.lidar import LidarModel, simulate_period  # noqa: E402

HEIGHTS = np.array([40.0, 60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 200.0])


def conditions(n, seed=0):
    rng = np.random.default_rng(seed)
    for _ in range(n):
        n = HEIGHTS.size
        yield dict(wind_speed=rng.uniform(4, 16, n), wind_from_direction=rng.uniform(0, 360, n),
                   turbulence_intensity=rng.uniform(0.05, 0.25, n),
                   wind_shear_exponent=rng.uniform(0, 0.3, n),
                   cnr=rng.uniform(-25, -10, n), cnr_gradient=rng.uniform(-0.05, 0.05, n))


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--periods", type=int, default=60)
    parser.add_argument("--profile", action="store_true", help="print the cProfile top 15")
    args = parser.parse_args()
    model = LidarModel.ideal()
    simulate_period(model, heights=HEIGHTS, seed=(0, 0), **next(conditions(1)))  # warm-up
    wall, cpu = [], []
    for i, cond in enumerate(conditions(args.periods, seed=1)):
        t0, c0 = time.perf_counter(), time.process_time()
        simulate_period(model, heights=HEIGHTS, seed=(1, i), **cond)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    w, c = 1e3 * np.median(wall), 1e3 * np.median(cpu)
    print(f"simulate_period, {HEIGHTS.size} heights, {args.periods} periods, 1 BLAS thread")
    print(f"median wall {w:.1f} ms/period ({1e3 / w:.1f} periods/s); median CPU {c:.1f} ms/period "
          f"({1e3 / c:.1f} periods/s per core)")
    print(f"median CPU {c / HEIGHTS.size:.2f} ms per (period, height); mean CPU "
          f"{1e3 * np.mean(cpu) / HEIGHTS.size:.2f} ms")
    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        for i, cond in enumerate(conditions(20, seed=2)):
            simulate_period(model, heights=HEIGHTS, seed=(2, i), **cond)
        prof.disable()
        pstats.Stats(prof).sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()
