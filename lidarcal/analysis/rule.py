"""The certification rule as one value: what a budget certifies and how its values are stated.

The fewest periods of a certified bin, the certified wind-speed range, the significant digits
every certified value settles to, the coverage factor k and the Monte Carlo coverage interval
travel together from the command line (:func:`lidarcal.cli.options.rule_of`) or a
:class:`~lidarcal.pipeline.CalibrationConfig` to :func:`lidarcal.analysis.budget.budget`, the
adaptive replicas (:func:`lidarcal.campaign.adaptive.adaptive_replicas`) and the campaign
uncertainty.  :class:`CertificationRule` checks them once, when it is made; the budget records
them (:meth:`CertificationRule.record`) and applies them with
:mod:`lidarcal.analysis.certification`'s kernels.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

from lidarcal.analysis.certification import (
    DEFAULT_CERTIFIED_RANGE,
    DEFAULT_MIN_PERIODS,
    DEFAULT_SIGNIFICANT_DIGITS,
)
from lidarcal.errors import InputError
from lidarcal.units import to_magnitude

__all__ = ["CertificationRule", "COVERAGE_INTERVALS"]

#: The Monte Carlo coverage intervals (JCGM 101 §7.7).
COVERAGE_INTERVALS = ("symmetric", "shortest")


@dataclasses.dataclass(frozen=True)
class CertificationRule:
    """What a budget certifies, and how its values are stated.

    Parameters
    ----------
    min_periods : int
        Fewest distinct 10-minute periods a certified bin holds (>= 2;
        :func:`~lidarcal.analysis.certification.certified_bins`).
    certified_range : (float, float)
        Bin centres (m s-1, inclusive; bare numbers or speed quantities) a certified bin may have.
    significant_digits : int
        Significant digits of each bin's expanded uncertainty U that the Monte Carlo must settle
        the bin's values to (>= 1; JCGM 101 §7.9).
    coverage_factor : float
        k of the expanded uncertainty.
    coverage_interval : {"symmetric", "shortest"}
        The Monte Carlo coverage interval (JCGM 101 §7.7).

    >>> rule = CertificationRule(min_periods=3, certified_range=("4 m/s", 16))
    >>> rule.certified_range, CertificationRule.of({"min_periods": 3}) == CertificationRule(min_periods=3)
    ((4.0, 16.0), True)
    """

    min_periods: int = DEFAULT_MIN_PERIODS
    certified_range: tuple[float, float] = DEFAULT_CERTIFIED_RANGE
    significant_digits: int = DEFAULT_SIGNIFICANT_DIGITS
    coverage_factor: float = 2.0
    coverage_interval: str = "symmetric"

    def __post_init__(self) -> None:
        if int(self.min_periods) < 2:
            raise InputError(f"min_periods must be >= 2 (a standard deviation needs two periods); "
                             f"got {self.min_periods}")
        object.__setattr__(self, "min_periods", int(self.min_periods))
        object.__setattr__(self, "certified_range", _certified_range(self.certified_range))
        if int(self.significant_digits) < 1:
            raise InputError(f"significant_digits must be >= 1; got {self.significant_digits}")
        object.__setattr__(self, "significant_digits", int(self.significant_digits))
        object.__setattr__(self, "coverage_factor", float(self.coverage_factor))
        if self.coverage_interval not in COVERAGE_INTERVALS:
            raise InputError(f"coverage_interval must be one of {list(COVERAGE_INTERVALS)}; "
                             f"got {self.coverage_interval!r}")

    @classmethod
    def of(cls, rule: CertificationRule | Mapping[str, Any] | None) -> CertificationRule:
        """Return ``rule`` as a :class:`CertificationRule` (None: the defaults; a mapping: its fields)."""
        if isinstance(rule, CertificationRule):
            return rule
        if rule is None:
            return cls()
        if isinstance(rule, Mapping):
            names = {f.name for f in dataclasses.fields(cls)}
            unknown = sorted(set(rule) - names)
            if unknown:
                raise InputError(f"certification rule settings {unknown} unknown; expected some of "
                                 f"{sorted(names)}")
            return cls(**rule)
        raise InputError(f"rule must be a CertificationRule, a mapping of its fields or None; got "
                         f"{type(rule).__name__}")

    def replace(self, **changes: Any) -> CertificationRule:
        """Return this rule with ``changes`` (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)

    def record(self, *, monte_carlo: bool = True) -> dict[str, Any]:
        """Return what a budget's provenance records of the rule (in ``lidarcal_config``).

        The coverage interval is a Monte Carlo setting: an IEC budget (``monte_carlo=False``)
        does not record it.
        """
        out = {"min_periods": self.min_periods, "certified_range_m_s-1": list(self.certified_range),
               "significant_digits": self.significant_digits, "coverage_factor": self.coverage_factor}
        if monte_carlo:
            out["coverage_interval"] = self.coverage_interval
        return out


def _certified_range(value: Any) -> tuple[float, float]:
    def speed(v: Any) -> float:  # bare numbers are m s-1 here (the range is documented in m s-1)
        return float(v) if isinstance(v, int | float | np.number) else float(
            to_magnitude(v, "m s-1", name="certified_range"))

    try:
        lo, hi = (speed(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"certified_range must be two wind speeds (m s-1), low and high; "
                         f"got {value!r}") from None
    if not 0 <= lo <= hi:
        raise InputError(f"certified_range must satisfy 0 <= low <= high; got {lo:g} to {hi:g} m s-1")
    return lo, hi
