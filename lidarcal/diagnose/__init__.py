"""Find, name and fix model–field discrepancies (``lidarcal diagnose``, ``docs/diagnose.md``).

- :mod:`lidarcal.diagnose.effects` — the catalogue of effects (data).
- :mod:`lidarcal.diagnose.inputs` — the field campaign checked and the nominal model it implies.
- :mod:`lidarcal.diagnose.stats` — residuals, binning, significance tests, the gap metric.
- :mod:`lidarcal.diagnose.fit` — response smoothing, weighted least squares, BIC.
- :mod:`lidarcal.diagnose.problem` — the residual to explain and the simulator (common random numbers).
- :mod:`lidarcal.diagnose.candidates` — the catalogue's effects fitted: responses, joint fit, bootstrap.
- :mod:`lidarcal.diagnose.selection` — forward selection, refinement and the answer.
- :mod:`lidarcal.diagnose.core` — the workflow :func:`diagnose`.
- :mod:`lidarcal.diagnose.dataset` — the ``diagnosis`` artefact and the ``--json`` summary.
- :mod:`lidarcal.diagnose.generate` — hidden-effect field campaigns.
- :mod:`lidarcal.diagnose.report` — the offline HTML report.

Example: a synthetic campaign whose lidar has a hidden 4 m zero-distance error, diagnosed among
three candidates (small and in one process; ``docs/diagnose.md`` explains the answer)

>>> from lidarcal.diagnose import diagnose, generate_field_campaign, hidden_effect_conditions, summary
>>> one_process = {"scheduler": "synchronous"}
>>> field = generate_field_campaign(hidden_effect_conditions(240, (40.0, 120.0)), "zero_distance_offset",
...                                 execution=one_process)
>>> result = diagnose(field, candidates=["zero_distance_offset", "reference_gain", "hybrid_weight"],
...                   n_bootstrap=50, execution=one_process)
>>> js = summary(result)
>>> js["effect"], 2.0 < js["parameters"]["offset"] < 6.0, js["gap_after"] < js["gap_before"]
('zero_distance_offset', True, True)
"""

from lidarcal.diagnose.core import DEFAULT_SEED, DiagnosisResult, diagnose
from lidarcal.diagnose.dataset import corrected_model, summary, to_dataset
from lidarcal.diagnose.effects import EFFECTS, Effect, Parameter, get_effect
from lidarcal.diagnose.generate import (
    GENERATOR_SEED,
    REALISTIC_STRENGTHS,
    generate_field_campaign,
    hidden_effect_conditions,
)

__all__ = [
    "EFFECTS", "Effect", "Parameter", "get_effect", "diagnose", "DiagnosisResult", "DEFAULT_SEED",
    "summary", "to_dataset", "corrected_model", "generate_field_campaign", "hidden_effect_conditions",
    "GENERATOR_SEED", "REALISTIC_STRENGTHS",
]
