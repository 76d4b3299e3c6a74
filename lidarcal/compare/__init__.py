"""The field campaign beside the virtual lidar in its conditions (``lidarcal compare``, ``docs/compare.md``).

- :mod:`lidarcal.compare.core` — :func:`compare`: simulate the campaign's conditions, the
  sensitivity slopes of both pairs with the slope test, the two budgets.
- :mod:`lidarcal.compare.dataset` — the ``comparison`` artefact and the ``--json`` object.
- :mod:`lidarcal.compare.report` — the offline HTML report (the paper's Figures 8 and 9).

Example: a synthetic campaign whose lidar has a hidden 4 m zero-distance error, compared with the
nominal lidar (small and in one process; ``docs/compare.md`` has the worked example)

>>> from lidarcal.compare import compare, summary, to_dataset
>>> from lidarcal.diagnose import generate_field_campaign, hidden_effect_conditions
>>> one_process = {"scheduler": "synchronous"}
>>> field = generate_field_campaign(hidden_effect_conditions(150, (40.0, 120.0)), "zero_distance_offset",
...                                 execution=one_process)
>>> js = summary(to_dataset(compare(field, execution=one_process)))
>>> js["verdict"], sorted({c["variable"] for c in js["cells"] if not c["agree"]})
('disagree', ['wind_shear_exponent'])
"""

from lidarcal.compare.core import (
    CORRECTION,
    DEFAULT_ALPHA,
    DEFAULT_REFERENCE_UNCERTAINTY,
    DEFAULT_VARIABLES,
    VARIABLES,
    Comparison,
    compare,
)
from lidarcal.compare.dataset import summary, to_dataset

__all__ = [
    "compare",
    "Comparison",
    "to_dataset",
    "summary",
    "DEFAULT_VARIABLES",
    "VARIABLES",
    "DEFAULT_ALPHA",
    "DEFAULT_REFERENCE_UNCERTAINTY",
    "CORRECTION",
]
