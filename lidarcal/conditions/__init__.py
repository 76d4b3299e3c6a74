"""The ``conditions`` / ``field_campaign`` input contract (``docs/contracts.md``) and its generators.

- :func:`load_conditions` — open, convert to canonical units, check, flag missing periods.
- :func:`synthetic_conditions` — seeded synthetic conditions, or a real record extrapolated
  to more heights with each period's shear (Eq. 10).
- :mod:`lidarcal.conditions.variables` — the variable names, units and attributes, read from
  ``schemas/conditions.yaml`` and ``schemas/field_campaign.yaml``.
- :mod:`lidarcal.conditions.sta` / :mod:`~lidarcal.conditions.stafile` /
  :mod:`~lidarcal.conditions.mast` — WindCube ``.sta`` files and met-mast CSV records in, with
  the value rules of :mod:`lidarcal.conditions.readings`; every lidar file is read through the
  registry of formats of :mod:`lidarcal.conditions.formats`.
- :mod:`lidarcal.conditions.kernels` — shear exponent and CNR gradient from neighbouring
  heights (paper §3.3), the CNR model used where no lidar CNR was measured.
"""

from lidarcal.conditions.kernels import cnr_gradient_along_beam, cnr_model, shear_exponent, vertical_gradient
from lidarcal.conditions.load import SkippedPeriodsWarning, conditions_checksum, load_conditions
from lidarcal.conditions.synthetic import conditions_dataset, synthetic_conditions
from lidarcal.data import sample_file

__all__ = [
    "SkippedPeriodsWarning",
    "conditions_checksum",
    "conditions_dataset",
    "cnr_model",
    "load_conditions",
    "sample_conditions_path",
    "shear_exponent",
    "synthetic_conditions",
    "vertical_gradient",
    "cnr_gradient_along_beam",
]


def sample_conditions_path():
    """Path of the embedded real sample (brightwind demo mast, 3 months, 40/60/80 m)."""
    return sample_file("conditions/conditions.nc")
