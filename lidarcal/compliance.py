"""Run the IOOS compliance-checker (CF-1.11 and ACDD-1.3) offline on a netCDF file.

A file *passes* when no high-priority check fails, apart from the documented exceptions:

``dB``
    CNR is stored in ``dB`` (and its gradient in ``dB m-1``), the unit the wind-lidar field
    uses.  UDUNITS has no decibel, so CF §3.1 reports it.  The same holds for units per
    decibel such as a sensitivity slope in ``% dB-1``.
``standard_name``
    ACDD asks for a ``standard_name`` on every data variable, but most calibration
    quantities (a bench bias, an uncertainty contribution) have none in the CF table.
    lidarcal sets a CF standard name wherever one exists and a ``long_name`` everywhere.

Medium- and low-priority findings are returned as warnings.
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field

__all__ = ["ComplianceReport", "check_compliance", "SUITES"]

SUITES = ("cf:1.11", "acdd:1.3")
_DB_UNITS = re.compile(r'units for \S+, "dB( m-1)?" are not recognized by UDUNITS')
_PER_DB_UNITS = re.compile(
    r'units for \S+, "[^"]*(?<![A-Za-z])dB-1(?![A-Za-z0-9])[^"]*" are not recognized by UDUNITS')


@dataclass
class ComplianceReport:
    """Outcome of the compliance-checker on one file."""

    path: str
    failures: list[str] = field(default_factory=list)
    exceptions: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when no high-priority check failed beyond the documented exceptions."""
        return not self.failures


def _failed(result) -> bool:
    value = result.value
    if isinstance(value, tuple):
        return value[0] < value[1]
    return not bool(value)


def _is_exception(suite: str, result, msg: str) -> bool:
    if suite.startswith("cf") and (_DB_UNITS.search(msg) or _PER_DB_UNITS.search(msg)):
        return True
    return suite.startswith("acdd") and msg == "standard_name"


def check_compliance(path: str | os.PathLike) -> ComplianceReport:
    """Run CF-1.11 and ACDD-1.3 checks on ``path`` (no network needed)."""
    from compliance_checker.runner import CheckSuite

    report = ComplianceReport(str(path))
    suite = CheckSuite()
    suite.load_all_available_checkers()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = suite.load_dataset(str(path))
        try:
            groups = suite.run_all(ds, list(SUITES), [], [])
        finally:
            if hasattr(ds, "close"):
                ds.close()
    for name, (results, errors) in groups.items():
        for check, err in (errors or {}).items():
            report.failures.append(f"{name}: check {check} crashed: {err}")
        for result in results:
            if not _failed(result):
                continue
            msgs = [str(m) for m in (result.msgs or [])] or [str(result.name)]
            for msg in msgs:
                line = f"{name} [{result.name}] {msg}"
                if result.weight >= 3:
                    (report.exceptions if _is_exception(name, result, msg) else report.failures).append(line)
                else:
                    report.warnings.append(line)
    return report
