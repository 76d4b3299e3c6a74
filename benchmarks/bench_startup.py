"""Benchmark: CPU seconds a ``lidarcal`` command costs before it does any work (issue 27).

Usage::

    python benchmarks/bench_startup.py [CERT.nc] [--repeat 5] [--importtime]

Each measurement is a new Python process, as a user runs the command; the CPU (user + system)
of that process is read with ``getrusage(RUSAGE_CHILDREN)``.  Printed, as medians:

* ``import lidarcal`` and ``lidarcal --help`` / ``--version`` (whole commands);
* for every command, its **start**: the process that builds that command's parser and imports
  its module, as ``lidarcal COMMAND ...`` does before its handler runs (nothing is read or
  written);
* with ``CERT.nc`` (a certificate, e.g. ``lidarcal-output/certificate.nc``; without one, a small
  certificate is made in a temporary directory), the whole ``lidarcal verify CERT.nc``.

The targets: ``lidarcal --help`` and the start of ``lidarcal verify`` at most 1 s of CPU.
``--importtime`` also lists the ten slowest imports of ``lidarcal verify`` (``python -X
importtime``, wall-clock microseconds including everything each import pulls in).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

#: Builds the command's parser as ``lidarcal.cli.main`` does, i.e. imports its module.
_START = "import sys\nfrom lidarcal.cli import build_parser\nbuild_parser([sys.argv[1]])\n"


def cpu(cmd: list[str], repeat: int) -> float:
    """Median CPU seconds (user + system) of ``cmd`` run ``repeat`` times, each in a new process."""
    out = []
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        out.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return statistics.median(out)


def _small_certificate(directory: Path) -> Path:
    """The certificate of a short calibration (48 periods, 2 heights; about a minute)."""
    subprocess.run([sys.executable, "-m", "lidarcal", "calibrate", "-o", str(directory), "--periods", "48",
                    "--heights", "80", "120", "--min-periods", "3", "--max-replicas", "2", "--no-progress"],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return directory / "certificate.nc"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("certificate", nargs="?", type=Path, help="certificate to verify (default: a short run's)")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--importtime", action="store_true", help="the slowest imports of lidarcal verify")
    args = p.parse_args()
    from lidarcal.cli import COMMANDS

    py = sys.executable
    print(f"import lidarcal:       {cpu([py, '-c', 'import lidarcal'], args.repeat):.2f} s CPU")
    helped = cpu([py, "-m", "lidarcal", "--help"], args.repeat)
    print(f"lidarcal --help:       {helped:.2f} s CPU (target <= 1 s)")
    print(f"lidarcal --version:    {cpu([py, '-m', 'lidarcal', '--version'], args.repeat):.2f} s CPU")
    print("start of each command (parser built, its module imported; nothing run):")
    for name in COMMANDS:
        target = " (target <= 1 s)" if name == "verify" else ""
        print(f"  {name:18s} {cpu([py, '-c', _START, name], args.repeat):.2f} s CPU{target}")
    with tempfile.TemporaryDirectory() as tmp:
        cert = args.certificate or _small_certificate(Path(tmp))
        whole = cpu([py, "-m", "lidarcal", "verify", str(cert)], args.repeat)
        print(f"lidarcal verify {cert.name} (whole command): {whole:.2f} s CPU")
        if args.importtime:
            done = subprocess.run([py, "-X", "importtime", "-m", "lidarcal", "verify", str(cert)],
                                  capture_output=True, text=True)
            rows = [line.split("|") for line in done.stderr.splitlines()
                    if line.startswith("import time:")][1:]
            top = sorted(((int(r[1]), r[2].rstrip()) for r in rows), reverse=True)[:10]
            print("slowest imports of lidarcal verify (us, cumulative):")
            for us, name in top:
                print(f"  {us:9d} {name}")


if __name__ == "__main__":
    main()
