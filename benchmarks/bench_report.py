"""Benchmark: CPU seconds of the report (HTML + the certificate document PDF) of a calibration.

Usage::

    python benchmarks/bench_report.py RUN [--repeat 3] [--png]

``RUN`` is the output directory of a default ``lidarcal calibrate -o RUN``.  Each repeat runs
in a fresh Python process (so the plotting libraries' imports count, as they do in a
``calibrate`` run), builds the certificate from RUN's artefacts as ``calibrate`` does, and
times ``lidarcal.certificate.report.write_report`` on it (as ``calibrate`` calls it: before the
certificate is sealed) with ``time.process_time`` (CPU of this process, all threads); then
the PDF alone again.  Prints every repeat and the medians.  The target is at most 5 s of CPU.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

_CHILD = """
import json, sys, time
from pathlib import Path
from lidarcal.certificate import make_certificate
from lidarcal.io import open_artefact
run, out, png = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3] == "1"
sens = [open_artefact(p, "sensitivity") for p in sorted(run.glob("sensitivity_*.nc"))]
cert = make_certificate(budget=open_artefact(run / "budget.nc", "uncertainty_budget"), sensitivities=sens,
                        cube=open_artefact(run / "cube.nc", "bench_cube"),
                        rwf=open_artefact(run / "rwf.nc", "rwf"),
                        terms=open_artefact(run / "terms.nc", "uncertainty_terms"),
                        records=open_artefact(run / "simulated.nc"), config={}, call="bench_report",
                        demonstration=True)
t0 = time.process_time()
import lidarcal.certificate.report as report
written = report.write_report(out / "report.html", certificate=cert, png=png)
t1 = time.process_time()
from lidarcal.certificate.document import write_document
t2 = time.process_time()
write_document(out / "again.pdf", cert)
t3 = time.process_time()
print(json.dumps({"report": t1 - t0, "pdf": t3 - t2, "pages": written["pages"], "png": len(written["png"])}))
"""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run", help="output directory of lidarcal calibrate")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--png", action="store_true", help="also write the PNGs (not done by default)")
    args = p.parse_args()
    runs = []
    for i in range(args.repeat):
        with tempfile.TemporaryDirectory() as tmp:
            done = subprocess.run(
                [sys.executable, "-c", _CHILD, args.run, tmp, "1" if args.png else "0"],
                check=True,
                capture_output=True,
                text=True,
            )
        run = json.loads(done.stdout.strip().splitlines()[-1])
        runs.append(run)
        print(
            f"run {i + 1}: report (HTML + PDF{' + PNGs' if args.png else ''}) {run['report']:.2f} s CPU; "
            f"PDF alone (libraries loaded) {run['pdf']:.2f} s CPU; {run['pages']} pages, {run['png']} PNGs"
        )
    print(
        f"median: report {statistics.median(r['report'] for r in runs):.2f} s CPU, "
        f"PDF {statistics.median(r['pdf'] for r in runs):.2f} s CPU (target: report <= 5 s)"
    )


if __name__ == "__main__":
    main()
