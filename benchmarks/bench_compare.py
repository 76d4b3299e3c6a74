"""Benchmark: ``lidarcal compare`` on a 1,200-period, 4-height field campaign (target <= 60 s, 2 cores).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_compare.py [--effect none] [--periods 1200]
        [--heights 40 80 120 160] [--scheduler processes] [--workers 2] [--report]

Generates the campaign with ``lidarcal.diagnose.generate_field_campaign`` (not timed against the
target), then times :func:`lidarcal.compare.compare` (one campaign simulation, the sensitivities of
both pairs, the budgets), the artefact and, with ``--report``, the HTML report.  Prints the
times, the verdict and the cells that disagree.
"""

import argparse
import os
import tempfile
import time

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def main() -> None:
    import warnings

    from lidarcal.compare import compare, summary, to_dataset
    from lidarcal.compare.report import write_report
    from lidarcal.diagnose import generate_field_campaign, hidden_effect_conditions

    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--effect", default="none")
    p.add_argument("--periods", type=int, default=1200)
    p.add_argument("--heights", type=float, nargs="+", default=[40.0, 80.0, 120.0, 160.0])
    p.add_argument("--scheduler", default="processes")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--report", action="store_true", help="also time the HTML report")
    args = p.parse_args()
    warnings.simplefilter("ignore")
    opts = {"scheduler": args.scheduler, "workers": args.workers, "chunk": 50}

    t0 = time.perf_counter()
    cond = hidden_effect_conditions(args.periods, args.heights, seed=2024)
    field = generate_field_campaign(cond, args.effect, execution=opts)
    t1 = time.perf_counter()
    result = compare(field, execution=opts)
    t2 = time.perf_counter()
    ds = to_dataset(result)
    t3 = time.perf_counter()
    if args.report:
        with tempfile.TemporaryDirectory() as tmp:
            write_report(ds, os.path.join(tmp, "compare.html"))
    t4 = time.perf_counter()
    js = summary(ds)
    print(f"campaign: {args.periods} periods x {len(args.heights)} heights, hidden {args.effect}, "
          f"scheduler {args.scheduler} x {args.workers}")
    print(f"generate (1 simulation):          {t1 - t0:7.1f} s")
    print(f"compare (1 simulation + analysis): {t2 - t1:7.1f} s   <- target <= 60 s")
    print(f"artefact:                          {t3 - t2:7.1f} s")
    if args.report:
        print(f"report:                            {t4 - t3:7.1f} s")
    print(f"total compare + artefact:          {t3 - t1:7.1f} s")
    bad = [f"{c['variable']}@{c['height']:g} m (z {c['z']:+.1f})" for c in js["cells"] if not c["agree"]]
    print(f"verdict: {js['verdict']} ({len(bad)} of {len(js['cells'])} cells disagree"
          + (f": {', '.join(bad)}" if bad else "") + ")")


if __name__ == "__main__":
    main()
