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
import copy
import functools
import io
import os
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field

from lidarcal.provenance import ACDD_SPELLINGS, CONTACT_ENV, USER_ATTRIBUTES

__all__ = ["ComplianceReport", "check_compliance", "summary_lines", "missing_attributes", "missing_lines",
           "SUITES"]

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


def missing_attributes(report: ComplianceReport) -> list[str]:
    """Return the ACDD attributes found absent (``acknowledgment/acknowledgement``: either spelling)."""
    return [m.group(1) for line in report.warnings if (m := _ACDD_ABSENT.match(line))]


def missing_lines(missing: list[str], where: str = "") -> list[str]:
    """Say which ACDD attributes are ``missing`` (``where``: in which files), and the option giving each."""
    if not missing:
        return []
    out = [f"warning: {len(missing)} ACDD attribute(s) not present{where}; give them with:"]
    by_option: dict[str, list[str]] = {}
    for name in missing:
        option = supplied_by(name)
        if option.startswith("--attribute"):  # the name to give ("a/b": the ACDD-1.3 spelling)
            option, name = "--attribute NAME=VALUE", option.split()[1].partition("=")[0]
        by_option.setdefault(option, []).append(name)
    out.extend(f"  {option}: {', '.join(names)}" for option, names in by_option.items())
    return out


def summary_lines(report: ComplianceReport, *, verbose: bool = False, missing: bool = True) -> list[str]:
    """Return the report as lines for a person.

    Failures in full; each documented exception and each warning check folded into one line
    with its count and the variables it concerns (every line with ``verbose``).  The absent
    ACDD attributes are one block (:func:`missing_lines`), left out with ``missing=False``
    (``lidarcal validate`` of several files says the block they share once).
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
        if _ACDD_ABSENT.match(line) and not verbose:
            continue
        checks.setdefault(line[: line.index("]") + 1] if "]" in line else line, []).append(line)
    absent = [] if verbose else missing_attributes(report)
    site_missing = any(name in _SITE_ATTRIBUTES for name in absent)
    if missing:  # ACDD: each attribute it asks for once, grouped by what supplies it
        out.extend(missing_lines(absent))
    for check, lines in checks.items():
        if site_missing and _EXTENTS.search(check) and not verbose:
            continue  # "geospatial_lat_min/max attribute not found": the site, listed above
        if verbose or len(lines) == 1:
            out.extend(f"warning: {line}" for line in lines)
        else:
            first = lines[0][len(check):].strip()
            out.append(f"warning: {check} {first[:150]} (and {len(lines) - 1} more like it; -v lists them)")
    return out


_ACDD_ABSENT = re.compile(r"^acdd:\S+ \[Global Attributes\] (\S+) not present$")
_EXTENTS = re.compile(r"\[geospatial_(lat|lon)_extents_match\]")

#: ACDD attributes lidarcal writes only when the user gives them, and the option of every
#: writing command (or its environment variable) that does (``lidarcal validate`` says which).
_CONTACT_OPTIONS = {
    "creator_name": "--creator", "institution": "--institution", "creator_institution": "--institution",
    "creator_email": "--creator-email", "creator_url": "--creator-url", "publisher_name": "--publisher",
    "publisher_type": "--publisher", "publisher_institution": "--publisher",
    "publisher_email": "--publisher-email", "publisher_url": "--publisher-url",
}
_SITE_ATTRIBUTES = ("geospatial_lat_min", "geospatial_lat_max", "geospatial_lon_min", "geospatial_lon_max",
                    "geospatial_lat_units", "geospatial_lon_units", "geospatial_lat_resolution",
                    "geospatial_lon_resolution", "geospatial_bounds", "geospatial_bounds_crs")


def supplied_by(attribute: str) -> str:
    """Name the option of lidarcal's writing commands that supplies a missing ACDD ``attribute``.

    >>> supplied_by("creator_email")
    '--creator-email TEXT (or $LIDARCAL_CREATOR_EMAIL)'
    >>> supplied_by("geospatial_lat_min")
    '--site-latitude DEGREES --site-longitude DEGREES (or $LIDARCAL_SITE_LATITUDE/_LONGITUDE)'
    >>> supplied_by("program")
    '--attribute program=VALUE'
    >>> supplied_by("acknowledgment/acknowledgement")
    '--attribute acknowledgement=VALUE'
    """
    if attribute in _CONTACT_OPTIONS:
        env = CONTACT_ENV.get(attribute) or CONTACT_ENV.get(
            {"creator_institution": "institution"}.get(attribute, "publisher_name"))
        return f"{_CONTACT_OPTIONS[attribute]} TEXT (or ${env})"
    if attribute in _SITE_ATTRIBUTES:
        return "--site-latitude DEGREES --site-longitude DEGREES (or $LIDARCAL_SITE_LATITUDE/_LONGITUDE)"
    # the checker names an attribute it accepts in two spellings as "a/b"
    # ("acknowledgment/acknowledgement"): lidarcal writes the ACDD-1.3 one
    names = [ACDD_SPELLINGS.get(a, a) for a in attribute.split("/")]
    user = next((a for a in names if a in USER_ATTRIBUTES), None)
    if user is not None:
        return f"--attribute {user}=VALUE"
    return "not settable by an option (lidarcal writes it; report a missing one as a bug)"


_SUBJECTS = (re.compile(r"units for (\S+), "), re.compile(r'variable "([^"]+)"'),
             re.compile(r"\] ((?:time_coverage|geospatial_vertical)_\S+) not present"))


#: Functions of ``compliance_checker.cf.util`` that only read the dataset (and a variable name):
#: the checker calls them again and again for every variable (6,700 times for a certificate of 88
#: variables, each scanning every variable's attributes), so one run answers each question once.
_PURE_QUERIES = (
    "get_coordinate_variables", "get_auxiliary_coordinate_variables", "get_geophysical_variables",
    "get_z_variable", "get_z_variables", "get_lat_variable", "get_latitude_variables",
    "get_true_latitude_variables", "get_lon_variable", "get_longitude_variables",
    "get_true_longitude_variables", "get_platform_variables", "get_instrument_variables",
    "get_time_variable", "get_time_variables", "get_axis_variables", "get_climatology_variable",
    "get_flag_variables", "get_grid_mapping_variables", "get_axis_map", "is_coordinate_variable",
    "coordinate_dimension_matrix", "is_geophysical", "guess_feature_type", "get_cell_boundary_map",
    "get_cell_boundary_variables", "get_bounds_variables", "get_forecast_metadata_variables",
)


def _fresh(value):
    """Copy ``value``'s containers (lists, tuples, sets, dicts), sharing the netCDF objects in them."""
    if isinstance(value, dict):
        out = copy.copy(value)  # keeps a defaultdict's factory
        out.update((k, _fresh(v)) for k, v in value.items())
        return out
    if isinstance(value, list | set | tuple):
        return type(value)(_fresh(v) for v in value)
    return value


@contextlib.contextmanager
def _answers_once() -> Iterator[None]:
    """Within the block, each read-only query of the checker's ``cf.util`` is computed once per argument.

    The file is opened read-only and never changes during a run, so the findings are the same
    as without the cache (``tests/test_artefact_metadata.py`` checks that on a file with failures);
    callers get a copy of each answer, so none can alter another's.
    """
    from compliance_checker.cf import util

    saved = {name: getattr(util, name) for name in _PURE_QUERIES if hasattr(util, name)}

    def once(func):
        answers: dict = {}

        @functools.wraps(func)
        def query(nc, *args):
            key = (id(nc), *args)
            try:
                hit = key in answers
            except TypeError:  # an unhashable argument: ask the checker itself
                return func(nc, *args)
            if not hit:
                answers[key] = func(nc, *args)
            return _fresh(answers[key])
        return query

    try:
        for name, func in saved.items():
            setattr(util, name, once(func))
        yield
    finally:
        for name, func in saved.items():
            setattr(util, name, func)


def check_compliance(path: str | os.PathLike, *, cache: bool = True) -> ComplianceReport:
    """Run CF-1.11 and ACDD-1.3 checks on ``path`` (no network needed).

    ``cache=False`` runs the stock checker without :func:`_answers_once` (same findings, slower).
    """
    from compliance_checker.cf.util import get_time_variable, get_z_variable
    from compliance_checker.runner import CheckSuite

    report = ComplianceReport(str(path))
    suite = CheckSuite()
    suite.load_all_available_checkers()
    # its "Using packaged standard name table" (on stderr) and other chatter (stdout): not findings
    quiet = contextlib.ExitStack()
    quiet.enter_context(contextlib.redirect_stdout(io.StringIO()))
    quiet.enter_context(contextlib.redirect_stderr(io.StringIO()))
    with warnings.catch_warnings(), quiet, (_answers_once() if cache else contextlib.nullcontext()):
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
