"""The virtual DBS lidar: configuration, geometry, RWF quadrature, reconstruction, simulation.

Public API (see ``docs/contracts.md``, "The virtual lidar"):

* :class:`LidarModel` — frozen, JSON-serialisable configuration (``ideal``, ``from_artefacts``,
  ``from_attrs``, ``to_dict``, ``from_dict``); :data:`LIDAR_ATTRIBUTES` and
  :func:`lidar_attributes` (:mod:`lidarcal.lidar.attributes`) read a conditions file's ``lidar_*``
  attributes, declared in ``schemas/conditions.yaml``;
* :class:`NoiseTable` (:mod:`lidarcal.lidar.noise`) — the bench cube's LOS bias, std and measured
  residuals per (CNR, velocity) bin, as the simulation draws from them;
* :mod:`lidarcal.lidar.bad_estimates` — bad estimates as a property of CNR: the fitted rate
  p_bad(CNR), its covariance, the search band, the replicas' draws of the curve;
* :mod:`lidarcal.lidar.spectral` — the continuous-RWF LOS signals' cross-spectral matrix;
* :mod:`lidarcal.lidar.synthesis` — Fourier coefficients and time series drawn from that matrix;
* :mod:`lidarcal.lidar.geometry` — beams, range gates, sample points, reachability;
* :func:`simulate_period` — one 10-minute period at several heights, lidar (hybrid, scalar,
  vector) and reference speeds;
* :mod:`lidarcal.lidar.wfr` — the pure reconstruction functions (Eqs. 3-5);
* :func:`lidarcal.lidar.box.lidar_turbulence_box` — the turbulence one simulated height saw.
"""

from lidarcal.lidar.geometry import check_reachable
from lidarcal.lidar.model import (
    DEFAULT_CNR_THRESHOLD,
    DEFAULT_RWF_FWHM,
    LIDAR_ATTRIBUTES,
    LidarModel,
    lidar_attributes,
)
from lidarcal.lidar.noise import NoiseTable
from lidarcal.lidar.quadrature import cnr_weights, gauss_hermite_rwf, gauss_rwf_nodes
from lidarcal.lidar.simulate import simulate_period

__all__ = ["DEFAULT_CNR_THRESHOLD", "DEFAULT_RWF_FWHM", "LIDAR_ATTRIBUTES", "LidarModel", "NoiseTable",
           "check_reachable", "lidar_attributes", "simulate_period", "gauss_hermite_rwf", "gauss_rwf_nodes",
           "cnr_weights"]
