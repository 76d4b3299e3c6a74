"""Find, name and fix model–field discrepancies (``lidarcal diagnose``, ``docs/diagnose.md``).

- :mod:`lidarcal.diagnose.effects` — the catalogue of effects (data).
- :mod:`lidarcal.diagnose.stats` — residuals, binning, significance tests, the gap metric.
- :mod:`lidarcal.diagnose.fit` — response smoothing, weighted least squares, BIC.
- :mod:`lidarcal.diagnose.core` — the workflow :func:`diagnose`.
- :mod:`lidarcal.diagnose.dataset` — the ``diagnosis`` artefact and the ``--json`` summary.
- :mod:`lidarcal.diagnose.generate` — hidden-effect field campaigns.
- :mod:`lidarcal.diagnose.report` — the offline HTML report.

Example
-------
>>> from lidarcal.diagnose import diagnose, summary, to_dataset   # doctest: +SKIP
>>> result = diagnose("field.nc")                                  # doctest: +SKIP
>>> summary(result)["effect"]                                      # doctest: +SKIP
'zero_distance_offset'
"""

import sys as _sys
import types as _types

from lidarcal.diagnose.core import DEFAULT_SEED, DiagnosisResult, diagnose
from lidarcal.diagnose.dataset import corrected_model, summary, to_dataset
from lidarcal.diagnose.effects import EFFECTS, Effect, Parameter, get_effect
from lidarcal.diagnose.generate import (
    GENERATOR_SEED,
    REALISTIC_STRENGTHS,
    generate_field_campaign,
    hidden_effect_conditions,
)


class _CallableModule(_types.ModuleType):
    """The package, callable as :func:`diagnose` (so ``lidarcal.diagnose(field)`` works)."""

    def __call__(self, *args, **kwargs) -> DiagnosisResult:
        return diagnose(*args, **kwargs)


_sys.modules[__name__].__class__ = _CallableModule

__all__ = [
    "EFFECTS", "Effect", "Parameter", "get_effect", "diagnose", "DiagnosisResult", "DEFAULT_SEED",
    "summary", "to_dataset", "corrected_model", "generate_field_campaign", "hidden_effect_conditions",
    "GENERATOR_SEED", "REALISTIC_STRENGTHS",
]
