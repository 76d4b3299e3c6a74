"""Range-weighting function, CNR weighting and zero distance (paper §2.2, Eqs. 1–2).

- :func:`range_weighting_function` — the ``rwf`` artefact from a synthetic or measured pulse.
- :func:`read_pulse_csv` — a bench pulse recording.
- :mod:`lidarcal.rwf.kernels` — pure numpy: pulse shapes, apodization, Eq. 1, Eq. 2 weights,
  barycentre.
"""

from lidarcal.rwf.dataset import (
    DEFAULT_CNR_GRADIENTS,
    PulseSamples,
    RwfConfig,
    compute_rwf,
    range_weighting_function,
    read_pulse_csv,
)

__all__ = [
    "PulseSamples",
    "RwfConfig",
    "read_pulse_csv",
    "compute_rwf",
    "range_weighting_function",
    "DEFAULT_CNR_GRADIENTS",
]
