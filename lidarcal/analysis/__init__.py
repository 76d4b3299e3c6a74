"""Analysis of lidar/reference records: sensitivities (§3.3), uncertainty budgets (§3.4).

- :func:`sensitivity` — IEC 61400-50-2 style binned regression and the Eqs. 12–13 tests.
- :func:`budget` — per height and 0.5 m s-1 bin uncertainty budget (Monte Carlo or IEC approach).

Pure numpy kernels live in :mod:`lidarcal.analysis.kernels`.
"""

from lidarcal.analysis.budget import budget
from lidarcal.analysis.sensitivity import compare_slopes, sensitivities, sensitivity

__all__ = ["sensitivity", "sensitivities", "compare_slopes", "budget"]
