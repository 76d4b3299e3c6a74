"""Turbulence at the lidar's points: PyConTurb's Kaimal / ``iec3d`` models and a fast generator.

* :mod:`lidarcal.turbulence.kernels` — pure numpy: spectra, coherence, :func:`generate_points`,
  :func:`cell_size`;
* :mod:`lidarcal.turbulence.pyconturb_backend` — the same layout from PyConTurb's ``gen_turb``;
* :mod:`lidarcal.turbulence.box` — the ``turbulence_box`` artefact (dataset level).
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
