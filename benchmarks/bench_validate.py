"""Benchmark: ``lidarcal validate`` on the default run's certificate (issue target: <= 5 s).

Times the whole command as a user runs it (a new process: start-up, schema check, the
CF-1.11/ACDD-1.3 compliance checker) and, in this process, the compliance checker alone with
and without lidarcal's per-run cache of the checker's read-only queries (same findings; the
ratio is what the cache saves).  Without ``--certificate`` it first runs the default
``lidarcal calibrate`` into a temporary directory (about 1-3 minutes).

    python benchmarks/bench_validate.py [--certificate CERT.nc] [--repeats 5]
"""

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lidarcal.compliance import check_compliance


def _cpu_of_child(cmd):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--certificate", type=Path)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cert = args.certificate
        if cert is None:
            subprocess.run([sys.executable, "-m", "lidarcal", "calibrate", "-o", tmp, "--no-progress"],
                           check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})
            cert = Path(tmp) / "certificate.nc"
        runs = [_cpu_of_child([sys.executable, "-m", "lidarcal", "validate", str(cert)])
                for _ in range(args.repeats)]
        wall, cpu = statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs)
        print(f"lidarcal validate {cert.name}: wall {wall:.2f} s, CPU {cpu:.2f} s "
              f"(median of {args.repeats}; target <= 5 s)")
        cached, stock = [], []
        for _ in range(args.repeats):
            t0 = time.process_time()
            check_compliance(cert)
            cached.append(time.process_time() - t0)
        t0 = time.process_time()
        check_compliance(cert, cache=False)
        stock.append(time.process_time() - t0)
        print(f"compliance checker alone: {statistics.median(cached):.2f} s CPU with the cache, "
              f"{stock[0]:.2f} s without (ratio {stock[0] / statistics.median(cached):.1f}x)")


if __name__ == "__main__":
    main()
