"""Turbulence at the lidar's points: PyConTurb's Kaimal / ``iec3d`` models and a fast generator.

* :mod:`lidarcal.turbulence.kernels` — pure numpy: spectra, coherence, :func:`generate_points`,
  :func:`cell_size`;
* :mod:`lidarcal.turbulence.pyconturb_backend` — the same layout from PyConTurb's ``gen_turb``;
* :mod:`lidarcal.turbulence.box` — the ``turbulence_box`` artefact (dataset level).

Design choices (measured; see ``benchmarks/bench_engine.py``)
-------------------------------------------------------------
* **One small independent box per (period, height).**  The virtual lidar needs, per height,
  4 beams x K RWF nodes + 1 reference point (21 points for K = 5).  Generating exactly those
  points is exact for every per-height statistic (spectra, variances, coherence between the
  beams and nodes of that height) and keeps each factorisation at 21 x 21 per component and
  frequency.  Coherence *between heights* is not modelled: the outputs of different heights
  of one period are independent draws, which matters only for statistics that combine
  heights (e.g. a shear exponent estimated from two simulated heights), not for the
  per-height lidar-minus-reference comparisons the calibration uses.
* **No cache of factorisations.**  With per-height boxes the build + Cholesky is ~2 ms per
  height; a cache keyed by (rounded U, direction mod 90°, height, geometry) would hold
  3 x 300 x 21 x 21 floats (3.2 MB) per key and, at any binning fine enough not to bias the
  results, hit rarely (a 95-day campaign has ~13,700 distinct periods over ~90 x 150
  (direction, speed) bins per height).  It does not pay, so there is none and no binning.
* **Frozen turbulence for along-wind separation**, as a Fourier phase on every point, instead
  of coherence in x (which ``iec3d`` ignores); points sharing (y, z) are de-duplicated.
"""

from lidarcal.turbulence.kernels import (
    CellSize,
    cell_size,
    generate_points,
    iec3d_coherence,
    kaimal_psd,
    sigma_components,
    spectral_magnitudes,
)

__all__ = ["CellSize", "cell_size", "generate_points", "iec3d_coherence", "kaimal_psd",
           "sigma_components", "spectral_magnitudes"]
