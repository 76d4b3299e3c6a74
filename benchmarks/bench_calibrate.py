"""The default calibration with an adaptive Monte Carlo (JCGM 101 §7.9): time, replicas, memory.

Run (takes several minutes)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_calibrate.py [--periods 2016] [--workers 2]
        [--significant-digits N] [--repeat 3] [--keep DIR]

Runs :func:`lidarcal.pipeline.calibrate` on the embedded sample data (2,016 periods x 8 heights
by default) twice on one warmed-up ``distributed.LocalCluster`` of ``--workers`` single-threaded
processes (reached by its address, as a user's cluster would be):

1. with ``max_replicas=1`` — one replica, the Monte Carlo as it was before replicas;
2. with the defaults — replicas until every certified value has settled to
   ``--significant-digits`` (or the default ``max_replicas``), ``--repeat`` times (the median
   wall time is the figure to quote).

Prints each run's wall time, replicas, trials, the certified bins, the bins not settled (not
certified) and those certifying the Monte Carlo coverage interval,
the ratio of the two wall times, the peak RSS of the workers and of the client process after
each run (``ru_maxrss``, a running maximum: memory is flat in replicas when the second run does
not raise it much above the first's), and the SHA-256
of replica 0's simulated records in both runs (they must be equal: replicas never change
replica 0).

Target (docs/performance.md): the default calibration (1 significant digit) in <= 5 min on 2 cores.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ[_v] = "1"

import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from lidarcal.analysis.certification import DEFAULT_SIGNIFICANT_DIGITS  # noqa: E402
from lidarcal.campaign import local_cluster  # noqa: E402
from lidarcal.pipeline import CalibrationConfig, calibrate  # noqa: E402

#: Replica 0's per-period outputs whose values are digested.
RECORD_VARIABLES = ("lidar_wind_speed", "lidar_wind_speed_scalar", "lidar_wind_speed_vector",
                    "reference_wind_speed", "availability")


def records_digest(path: Path) -> str:
    """SHA-256 of replica 0's simulated records (time, height) as little-endian float64, in order."""
    h = hashlib.sha256()
    with xr.open_dataset(path) as ds:
        for name in RECORD_VARIABLES:
            h.update(np.ascontiguousarray(ds[name].transpose("time", "height").values, dtype="<f8").tobytes())
    return h.hexdigest()


def _worker_peak_mb(client) -> float:
    peaks = client.run(lambda: resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    return max(peaks.values())


def run(outdir: Path, address: str, client, periods: int, **options) -> dict:
    cfg = CalibrationConfig(periods=periods, scheduler=address, **options)
    t0 = time.perf_counter()
    result = calibrate(outdir, cfg)
    wall = time.perf_counter() - t0
    bud = result.datasets["budget"]
    return {"wall": wall, "replicas": int(bud.attrs["monte_carlo_replicas"]),
            "trials": int(bud.attrs["monte_carlo_trials"]),
            "certified": int((bud["bin_flag"] == 0).sum()),
            "not_settled": int((bud["numerical_flag"] == 1).sum()),
            "intervals": int(bud.attrs.get("certified_coverage_intervals", 0)),
            "client_peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "worker_peak_mb": _worker_peak_mb(client),
            "digest": records_digest(result.paths["simulated"])}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--periods", type=int, default=2016)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--significant-digits", type=int, default=DEFAULT_SIGNIFICANT_DIGITS)
    p.add_argument("--repeat", type=int, default=1, help="adaptive runs (the median wall time is printed)")
    p.add_argument("--keep", metavar="DIR",
                   help="keep both runs' outputs here (default: a temporary directory)")
    args = p.parse_args(argv)
    from distributed import Client

    base = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_calibrate_"))
    with local_cluster(args.workers, dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        address = cluster.scheduler_address
        one = run(base / "one-replica", address, client, args.periods, max_replicas=1,
                  significant_digits=args.significant_digits)
        fulls = [run(base / f"adaptive-{i}", address, client, args.periods,
                     significant_digits=args.significant_digits) for i in range(max(args.repeat, 1))]
    full = sorted(fulls, key=lambda r: r["wall"])[len(fulls) // 2]  # the median run
    named = [("one replica", one)] + [(f"to {args.significant_digits} significant digits", r) for r in fulls]
    for name, r in named:
        print(f"{name:>28}: {r['wall']:7.1f} s, {r['replicas']:3d} replicas, {r['trials']:7d} trials, "
              f"{r['certified']} certified bins ({r['intervals']} certifying the coverage interval), "
              f"{r['not_settled']} not settled; worker peak RSS "
              f"{r['worker_peak_mb']:.0f} MB, client peak RSS {r['client_peak_mb']:.0f} MB")
        print(f"{'':>28}  replica-0 records sha256 {r['digest']}")
    print(f"median of {len(fulls)} adaptive run(s): {full['wall']:.1f} s")
    print(f"ratio to one replica: {full['wall'] / one['wall']:.2f}x wall time, "
          f"{full['trials'] / one['trials']:.2f}x trials ({args.periods} periods x 8 heights, "
          f"{args.workers} workers); replica 0 identical: {one['digest'] == full['digest']}")
    print(f"outputs: {base}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
