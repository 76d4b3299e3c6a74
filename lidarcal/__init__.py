"""lidarcal — anemometer-free calibration of pulsed Doppler wind lidars.

Stages (one module or sub-package each; imports flow from kernels to datasets to the CLI):

- :mod:`lidarcal.bench` — fiber-optic bench (SAFO-MV): simulated runs, ingest to the
  ℓcv-bin cube, repeatability (ISO 5725-4).
- :mod:`lidarcal.rwf` — range-weighting function and zero distance (Eqs. 1–2).
- :mod:`lidarcal.analysis.terms` — uncertainty terms not modelled by Monte Carlo (Eqs. 6–11, Table 4).
- :mod:`lidarcal.conditions` — the ``conditions`` / ``field_campaign`` input contract.
- :mod:`lidarcal.turbulence` — Kaimal/coherence turbulence at the points the lidar needs.
- :mod:`lidarcal.lidar` — virtual DBS lidar, wind-field reconstruction, virtual reference.
- :mod:`lidarcal.campaign` — Dask-parallel, resumable Monte Carlo over a campaign.
- :mod:`lidarcal.analysis` — sensitivities, uncertainty budgets, classification sweeps.
- :mod:`lidarcal.certificate`, :mod:`lidarcal.report` — archiving and presenting results.
- :mod:`lidarcal.diagnose` — find, name and fix model–field discrepancies.

Shared infrastructure: :mod:`lidarcal.units`, :mod:`lidarcal.schema`, :mod:`lidarcal.io`,
:mod:`lidarcal.provenance`, :mod:`lidarcal.compliance`, :mod:`lidarcal.errors`.
"""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("lidarcal")
except _metadata.PackageNotFoundError:  # running from a checkout without install
    __version__ = "0.0.0+unknown"
