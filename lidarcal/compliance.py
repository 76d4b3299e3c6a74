"""Run the IOOS compliance-checker (CF-1.11 and ACDD-1.3) offline on a netCDF file.

A file *passes* when no high-priority check fails, apart from the documented exceptions:

``dB``
    CNR is stored in ``dB`` (and its gradient in ``dB m-1``), the unit the wind-lidar field
    uses.  UDUNITS has no decibel, so CF §3.1 reports it.  The same holds for units per
    decibel such as a sensitivity slope in ``% dB-1``.
``standard_name``
    ACDD asks for a ``standard_name`` on every data variable, but most calibration
    quantities (a bench bias, a relative or expanded uncertainty, a regression slope) have
    none in the CF table.  lidarcal sets a CF standard name wherever one exists, with the CF
    modifiers where they apply (``wind_speed standard_error`` for a standard uncertainty in
    m s-1, ``wind_speed number_of_observations`` for a bin count), and a ``long_name``
    everywhere.
``time coverage``
    ACDD recommends ``time_coverage_*`` and the checker tests them against a time variable.
    An artefact without a time dimension (the bench cube, the RWF, the terms, a budget or a
    sensitivity: statistics over a whole campaign) has no time variable whose first and last
    values could match a campaign's start and end, and lidarcal does not invent one; the
    period of its source data is kept as ``source_time_coverage_start``/``_end``.  Only the
    "not present" findings of such a file fall under this exception.
``vertical coverage``
    Likewise ``geospatial_vertical_*`` for an artefact without a vertical coordinate: the
    bench cube (measured indoors on a bench) and the RWF (along the beam) have no height.

Every variable's dimensions are in the canonical order of CF §2.4 (other dims, then time, then
height; :func:`lidarcal.cf.canonical_order`), so the checker's dimension-order check passes.

Medium- and low-priority findings are returned as warnings; :func:`summary_lines` folds
repeated findings (one line per check and per documented exception) for ``lidarcal validate``.
What the stock checker still reports, and which options make the rest vanish, is in
docs/certificate.md.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import warnings
from dataclasses import dataclass, field

__all__ = ["ComplianceReport", "check_compliance", "summary_lines", "SUITES"]

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


_TIME_COVERAGE = re.compile(r"^acdd:\S+ \[Global Attributes\] time_coverage_(start|end|duration|resolution) "
                            r"not present$")
_VERTICAL_COVERAGE = re.compile(r"^acdd:\S+ \[Global Attributes\] geospatial_vertical_"
                                r"(min|max|units|resolution|positive) not present$")


def exception_kind(line: str, *, has_time: bool = True, has_z: bool = True) -> str | None:
    """Name the documented exception a finding line falls under (``dB``, ...), else None.

    ``has_time`` and ``has_z`` say whether the file has a time and a vertical coordinate:
    without one, the absent ``time_coverage_*`` or ``geospatial_vertical_*`` attributes are the
    documented ``time coverage`` or ``vertical coverage`` exception.
    """
    if _DB_UNITS.search(line) or _PER_DB_UNITS.search(line):
        return "dB"
    if line.startswith("acdd") and line.endswith("] standard_name"):
        return "standard_name"
    if not has_time and _TIME_COVERAGE.match(line):
        return "time coverage"
    if not has_z and _VERTICAL_COVERAGE.match(line):
        return "vertical coverage"
    return None


def summary_lines(report: ComplianceReport, *, verbose: bool = False) -> list[str]:
    """Return the report as lines for a person.

    Failures in full; each documented exception and each warning check folded into one line
    with its count and the variables it concerns (every line with ``verbose``).
    """
    out = [f"compliance: {line}" for line in report.failures]
    kinds: dict[str, list[str]] = {}
    for line in report.exceptions:
        kinds.setdefault(exception_kind(line, has_time=False, has_z=False) or "other", []).append(line)
    for kind, lines in kinds.items():
        what = sorted({m.group(1) for line in lines for pat in _SUBJECTS if (m := pat.search(line))})
        names = f": {', '.join(what[:6])}{' ...' if len(what) > 6 else ''}" if what else ""
        out.append(f"documented exception ({kind}, see lidarcal.compliance): {len(lines)} finding(s){names}")
        if verbose:
            out.extend(f"  {line}" for line in lines)
    checks: dict[str, list[str]] = {}
    for line in report.warnings:
        checks.setdefault(line[: line.index("]") + 1] if "]" in line else line, []).append(line)
    for check, lines in checks.items():
        absent = [line[len(check):].strip()[: -len(" not present")] for line in lines
                  if line.endswith(" not present")]
        if not verbose and len(absent) == len(lines) > 1:  # ACDD: the attributes it asks for, by name
            out.append(f"warning: {check} not present ({len(absent)}): {', '.join(absent)}")
        elif verbose or len(lines) == 1:
            out.extend(f"warning: {line}" for line in lines)
        else:
            first = lines[0][len(check):].strip()
            out.append(f"warning: {check} {first[:150]} (and {len(lines) - 1} more like it; -v lists them)")
    return out


_SUBJECTS = (re.compile(r"units for (\S+), "), re.compile(r'variable "([^"]+)"'),
             re.compile(r"\] ((?:time_coverage|geospatial_vertical)_\S+) not present"))


def check_compliance(path: str | os.PathLike) -> ComplianceReport:
    """Run CF-1.11 and ACDD-1.3 checks on ``path`` (no network needed)."""
    from compliance_checker.cf.util import get_time_variable, get_z_variable
    from compliance_checker.runner import CheckSuite

    report = ComplianceReport(str(path))
    suite = CheckSuite()
    suite.load_all_available_checkers()
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):  # its "Using ... table"
        warnings.simplefilter("ignore")
        ds = suite.load_dataset(str(path))
        has_time, has_z = get_time_variable(ds) is not None, get_z_variable(ds) is not None
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
                if exception_kind(line, has_time=has_time, has_z=has_z) is not None:
                    report.exceptions.append(line)
                elif result.weight >= 3:
                    report.failures.append(line)
                else:
                    report.warnings.append(line)
    return report
