"""Dask-parallel, resumable Monte Carlo over a campaign of 10-minute periods.

:func:`simulate_campaign` turns a ``conditions`` input and a
:class:`lidarcal.lidar.LidarModel` into a ``simulated_rtd`` artefact; see
:mod:`lidarcal.campaign.run` for scheduling, seeding and resuming.
"""

from lidarcal.campaign.run import DEFAULT_BASE_SEED, simulate_campaign
from lidarcal.campaign.scheduler import WORKER_CONFIG, local_cluster
from lidarcal.campaign.workers import BLAS_ENV

__all__ = ["simulate_campaign", "local_cluster", "DEFAULT_BASE_SEED", "BLAS_ENV", "WORKER_CONFIG"]
