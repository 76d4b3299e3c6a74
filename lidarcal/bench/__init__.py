"""Fiber-optic bench (SAFO-MV) stage: simulated runs, ingest to the ℓcv-bin cube, repeatability.

- :mod:`lidarcal.bench.grid` — the Table 1 sweep grid and beam geometry.
- :mod:`lidarcal.bench.formats` — the RTD and control-log CSV formats (read/write, checks).
- :mod:`lidarcal.bench.response` — the simulated lidar's true LOS response.
- :mod:`lidarcal.bench.simulator` — simulated bench runs.
- :mod:`lidarcal.bench.kernels` — numpy kernels (matching, rejection, binning, between-run stats).
- :mod:`lidarcal.bench.ingest` — RTD + control log → ``bench_cube`` artefact.
- :mod:`lidarcal.bench.repeatability` — ISO 5725-4 within-laboratory analysis (§2.4).
"""

from lidarcal.bench.formats import read_control_log, read_rtd
from lidarcal.bench.ingest import build_cube, ingest
from lidarcal.bench.repeatability import repeatability
from lidarcal.bench.response import TrueResponse
from lidarcal.bench.simulator import BenchRun, simulate_run

__all__ = ["TrueResponse", "BenchRun", "simulate_run", "read_rtd", "read_control_log", "ingest",
           "build_cube", "repeatability"]
