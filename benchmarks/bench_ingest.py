"""Benchmark: ingest a simulated 57-hour SAFO-MV run (≈256,000 RTD records) into a bench_cube.

The paper's WLS866-0195 calibration lasted 57 h.  The Table 1 sweep has 2220 programmed bins, so
the accumulation time is chosen as (57 h − 60 s of lidar lead/tail) / 2220 ≈ 92.4 s per bin; at
1.25 Hz that is 256,500 RTD records.  The script writes the two CSV files once, then times
``lidarcal.bench.ingest.ingest`` (read both files, check them, match, reject, bin, stamp
provenance incl. SHA-256 of the inputs) and, separately, writing the netCDF artefact.

    python benchmarks/bench_ingest.py [--repeats 5] [--hours 57]
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from lidarcal.bench.ingest import ingest  # noqa: E402
from lidarcal.bench.simulator import simulate_run  # noqa: E402
from lidarcal.io import write_artefact  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--hours", type=float, default=57.0)
    args = parser.parse_args()
    accumulation = (args.hours * 3600 - 60) / 2220
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        run = simulate_run(seed=57, accumulation_time=f"{accumulation} s")
        t_sim = time.perf_counter() - t0
        t0 = time.perf_counter()
        rtd, control = run.write(tmp)
        t_csv = time.perf_counter() - t0
        n = len(run.rtd)
        print(f"simulated {args.hours:g} h run: {n} RTD records, {len(run.control)} bins, "
              f"accumulation {accumulation:.1f} s/bin; simulate {t_sim:.2f} s, write CSV {t_csv:.2f} s "
              f"({rtd.stat().st_size / 1e6:.1f} MB)")
        times, writes = [], []
        for i in range(args.repeats):
            t0 = time.perf_counter()
            ds = ingest(rtd, control)
            times.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            write_artefact(ds, tmp / f"cube{i}.nc")
            writes.append(time.perf_counter() - t0)
        med = statistics.median(times)
        print(f"ingest: records={n} seconds={med:.3f} (median of {args.repeats}; min {min(times):.3f}, "
              f"max {max(times):.3f}) records_per_s={n / med:,.0f}")
        print(f"write_artefact (validate + netCDF): median {statistics.median(writes):.3f} s")
        a = ds.attrs
        print(f"records used {a['ingest_records_used']}, transition {a['ingest_records_transition']}, "
              f"LOS mismatch {a['ingest_records_los_mismatch']}, "
              f"bad estimates rejected {a['ingest_records_rejected_bad_estimate']}")


if __name__ == "__main__":
    main()
