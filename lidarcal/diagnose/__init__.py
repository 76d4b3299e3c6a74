"""Find, name and fix model–field discrepancies (``lidarcal diagnose``, DESIGN.md 3.2).

- :mod:`lidarcal.diagnose.effects` — the catalogue of effects (data).
- :mod:`lidarcal.diagnose.stats` — residuals, binning, significance tests, the gap metric.
- :mod:`lidarcal.diagnose.fit` — response smoothing, weighted least squares, BIC.
"""

from lidarcal.diagnose.effects import EFFECTS, Effect, Parameter, get_effect

__all__ = ["EFFECTS", "Effect", "Parameter", "get_effect"]
