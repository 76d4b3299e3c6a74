"""The field campaign beside the virtual lidar in its conditions (``lidarcal compare``, ``docs/compare.md``).

- :mod:`lidarcal.compare.core` — :func:`compare`: simulate the campaign's conditions, the
  sensitivity slopes of both pairs with the slope test, the two budgets.
- :mod:`lidarcal.compare.dataset` — the ``comparison`` artefact and the ``--json`` object.
- :mod:`lidarcal.compare.report` — the offline HTML report (the paper's Figures 8 and 9).

Example
-------
>>> from lidarcal.compare import compare, summary, to_dataset   # doctest: +SKIP
>>> ds = to_dataset(compare("field.nc"))                        # doctest: +SKIP
>>> summary(ds)["verdict"]                                      # doctest: +SKIP
'agree'
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
