"""The virtual DBS lidar: configuration, RWF quadrature, wind field reconstruction, simulation.

Public API (the contract of CONTRIBUTING.md, "The virtual lidar"):

* :class:`LidarModel` — frozen, JSON-serialisable configuration (``ideal``, ``from_artefacts``,
  ``to_dict``, ``from_dict``);
* :func:`simulate_period` — one 10-minute period at several heights, lidar (hybrid, scalar,
  vector) and reference speeds;
* :mod:`lidarcal.lidar.wfr` — the pure reconstruction functions (Eqs. 3-5).
"""

from lidarcal.lidar.model import DEFAULT_CNR_THRESHOLD, LidarModel, NoiseTable
from lidarcal.lidar.quadrature import cnr_weights, gauss_hermite_rwf, gauss_rwf_nodes
from lidarcal.lidar.simulate import simulate_period

__all__ = ["DEFAULT_CNR_THRESHOLD", "LidarModel", "NoiseTable", "simulate_period", "gauss_hermite_rwf",
           "gauss_rwf_nodes", "cnr_weights"]
