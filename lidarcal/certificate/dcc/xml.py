"""The DCC's XML vocabulary and its administrative data (lidarcal.certificate.dcc.export builds the results).

Namespaces and schema versions, the small element builders every part of the document uses,
and ``administrativeData``: software, core data, the calibrated item, laboratory, persons,
customer, statements and the method text.
"""

from __future__ import annotations

import datetime as _dt
import re
from collections.abc import Iterable, Mapping
from typing import Any

from lxml import etree

from lidarcal import __version__
from lidarcal.certificate.admin import (
    STATUS_ATTR,
    status_line,
)
from lidarcal.certificate.measurand import MEASURAND
from lidarcal.certificate.results import HEADLINE_LABEL
from lidarcal.readback import read_attr

DCC_NS = "https://ptb.de/dcc"
SI_NS = "https://ptb.de/si"
DCC_SCHEMA_VERSION = "3.1.2"
#: Where ``dcc.xsd`` 3.1.2 imports the D-SI schema from (resolved to a local file by :func:`validate_dcc`).
SI_SCHEMA_URL = "https://ptb.de/si/v2.1.0/SI_Format.xsd"
_XSI = "http://www.w3.org/2001/XMLSchema-instance"
#: Coverage probability stated with the k = 2 expanded uncertainty (normal distribution).
COVERAGE_PROBABILITY = 0.95
_NOT_STATED = "not stated"

# ------------------------------------------------------------------ XML helpers


def _d(tag: str) -> str:
    return f"{{{DCC_NS}}}{tag}"


def _s(tag: str) -> str:
    return f"{{{SI_NS}}}{tag}"


def _sub(parent: etree._Element, tag: str, text: str | None = None, **attrib: str) -> etree._Element:
    el = etree.SubElement(parent, tag, {k: v for k, v in attrib.items() if v is not None})
    if text is not None:
        el.text = str(text)
    return el


def _text(parent: etree._Element, tag: str, *contents: str, ref_type: str | None = None) -> etree._Element:
    """Add a ``dcc:textType`` / ``dcc:richContentType`` element with English content(s)."""
    el = _sub(parent, _d(tag), refType=ref_type)
    for content in contents:
        _sub(el, _d("content"), content, lang="en")
    return el


def _numbers(values: Iterable[float]) -> str:
    return " ".join(repr(float(v)) for v in values)


def _location(parent: etree._Element, address: str | None, country: str | None) -> None:
    loc = _sub(parent, _d("location"))
    if country:
        _sub(loc, _d("countryCode"), country)
    further = _sub(loc, _d("further"))
    _sub(further, _d("content"), address or _NOT_STATED, lang="en")


def _contact(parent: etree._Element, tag: str, name: str | None, *, email: str | None, address: str | None,
             country: str | None = None) -> etree._Element:
    """Add a ``dcc:contactType`` (name, eMail and location are required by the schema)."""
    el = _sub(parent, _d(tag))
    _text(el, "name", name or _NOT_STATED)
    _sub(el, _d("eMail"), email or _NOT_STATED)
    _location(el, address, country)
    return el


def _release(version: str) -> str:
    """Software release as PTB's rules spell it: a letter, then the version (``v0.1.0``)."""
    return f"v{version}" if version[:1].isdigit() else version


def _date(text: str | None) -> _dt.date | None:
    if not text:
        return None
    try:
        return _dt.datetime.fromisoformat(str(text).replace("Z", "+00:00")).date()
    except ValueError:
        try:
            return _dt.date.fromisoformat(str(text)[:10])
        except ValueError:
            return None


def _persons(text: str | None) -> list[tuple[str, str | None]]:
    out = []
    for part in str(text or "").split(";"):
        part = part.strip()
        if not part:
            continue
        m = re.fullmatch(r"(.*?)\s*\(([^()]*)\)", part)
        out.append((m.group(1), m.group(2)) if m and m.group(1) else (part, None))
    return out


# ------------------------------------------------------------------ the document


def _administrative(root: etree._Element, attrs: Mapping[str, Any], digest: str, file_name: str) -> None:
    """Write ``administrativeData``: software, core data, item, laboratory, persons, customer, statements."""
    admin = _sub(root, _d("administrativeData"))
    software = _sub(_sub(admin, _d("dccSoftware")), _d("software"))
    _text(software, "name", "lidarcal")
    _sub(software, _d("release"), _release(__version__))
    _sub(software, _d("type"), "application")
    _text(software, "description", "Anemometer-free calibration of pulsed Doppler wind lidars: fiber-optic "
          "bench and Monte Carlo virtual lidar; wrote this DCC from the netCDF certificate")

    _core_data(admin, attrs, digest, file_name)
    _item(admin, attrs)
    lab = _sub(admin, _d("calibrationLaboratory"))
    _contact(lab, "contact", attrs.get("laboratory_name") or (
        attrs.get("institution") if attrs.get("institution") != "unspecified" else None),
        email=attrs.get("creator_email"), address=attrs.get("laboratory_address"),
        country=attrs.get("laboratory_country_code"))

    persons = _sub(admin, _d("respPersons"))
    listed = _persons(attrs.get("responsible_persons")) or [(f"{_NOT_STATED} (demonstration certificate)"
                                                             if attrs.get(STATUS_ATTR) != "issued"
                                                             else _NOT_STATED, None)]
    for i, (name, role) in enumerate(listed):
        person = _sub(persons, _d("respPerson"))
        _text(_sub(person, _d("person")), "name", name)
        if role:
            _sub(person, _d("role"), role)
        if i == 0:
            _sub(person, _d("mainSigner"), "true" if attrs.get(STATUS_ATTR) == "issued" else "false")

    _contact(admin, "customer", attrs.get("customer_name"), email=None, address=attrs.get("customer_address"))

    _statements(admin, attrs, digest, file_name)


def _core_data(admin: etree._Element, attrs: Mapping[str, Any], digest: str, file_name: str) -> None:
    """Write ``coreData``: country, languages, identifier (the netCDF's SHA-256), performance dates."""
    core = _sub(admin, _d("coreData"))
    country = attrs.get("laboratory_country_code")
    _sub(core, _d("countryCodeISO3166_1"), country or "ZZ")  # ZZ: ISO 3166 user-assigned, "not stated"
    _sub(core, _d("usedLangCodeISO639_1"), "en")
    _sub(core, _d("mandatoryLangCodeISO639_1"), "en")
    _sub(core, _d("uniqueIdentifier"), attrs.get("certificate_id") or f"sha256:{digest}")
    idents = _sub(core, _d("identifications"))
    ident = _sub(idents, _d("identification"), refType="lidarcal_netcdfCertificateSha256")
    _sub(ident, _d("issuer"), "calibrationLaboratory")
    _sub(ident, _d("value"), f"sha256:{digest}")
    _text(ident, "name", f"SHA-256 of the sealed netCDF certificate {file_name}, the original record of "
          "these results")
    keys = ("bench_run_start", "bench_run_end", "bench_time_coverage_start", "bench_time_coverage_end",
            "simulation_date")
    dates = [d for d in (_date(attrs.get(k)) for k in keys) if d is not None]
    created = _date(attrs.get("date_created")) or _dt.date.today()
    _sub(core, _d("beginPerformanceDate"), min(dates, default=created).isoformat())
    _sub(core, _d("endPerformanceDate"), max(dates, default=created).isoformat())
    _sub(core, _d("performanceLocation"), "laboratory")


def _item(admin: etree._Element, attrs: Mapping[str, Any]) -> None:
    """Write ``items``: the lidar, its firmware, manufacturer, model and serial number."""
    items = _sub(admin, _d("items"))
    item = _sub(items, _d("item"))
    _text(item, "name", "Pulsed Doppler wind lidar")
    _text(item, "description", "Lidar whose 10-minute mean horizontal wind speed this certificate states "
          "the uncertainty of (bench-calibrated line-of-sight response, Monte Carlo virtual lidar)")
    if attrs.get("item_firmware"):
        fw = _sub(_sub(item, _d("installedSoftwares")), _d("software"))
        _text(fw, "name", "lidar firmware")
        _sub(fw, _d("release"), _release(str(attrs["item_firmware"])))
        _sub(fw, _d("type"), "firmware")
    manufacturer = _sub(item, _d("manufacturer"))
    _text(manufacturer, "name", attrs.get("item_manufacturer") or _NOT_STATED)
    if attrs.get("item_model"):
        _sub(item, _d("model"), attrs["item_model"])
    ids = _sub(item, _d("identifications"))
    ident = _sub(ids, _d("identification"), refType="basic_serialNumber")
    _sub(ident, _d("issuer"), "manufacturer")
    _sub(ident, _d("value"), (read_attr(attrs, "item_serial_number", kind="certificate")
                                   or read_attr(attrs, "lidar_serial", kind="certificate") or _NOT_STATED))
    _text(ident, "name", "Serial number")


def _statements(admin: etree._Element, attrs: Mapping[str, Any], digest: str, file_name: str) -> None:
    """Write ``statements``: calibration status, the netCDF original, place and headline."""
    statements = _sub(admin, _d("statements"))
    status = _sub(statements, _d("statement"), refType="lidarcal_calibrationStatus")
    _sub(status, _d("convention"), f"lidarcal {STATUS_ATTR}: {attrs.get(STATUS_ATTR) or _NOT_STATED}")
    _text(status, "declaration", status_line(attrs))
    _sub(status, _d("valid"), "true" if attrs.get(STATUS_ATTR) == "issued" else "false")
    record = _sub(statements, _d("statement"), refType="lidarcal_netcdfCertificate")
    _sub(record, _d("reference"), f"{file_name} sha256:{digest}")
    _text(record, "declaration", f"The sealed netCDF certificate {file_name} (SHA-256 {digest}) is the "
          "original record of these results; check it with: lidarcal verify " + file_name)
    if attrs.get("calibration_location"):
        place = _sub(statements, _d("statement"), refType="lidarcal_calibrationLocation")
        _text(place, "declaration", f"Place of the bench run: {attrs['calibration_location']}")
    if attrs.get("expanded_uncertainty_headline"):
        head = _sub(statements, _d("statement"), refType="lidarcal_headline")
        _text(head, "declaration", f"{HEADLINE_LABEL}: {attrs['expanded_uncertainty_headline']}")
    measurand = _sub(statements, _d("statement"), refType="lidarcal_measurand")  # docs/certificate.md
    _text(measurand, "declaration", str(read_attr(attrs, "measurand", kind="certificate") or MEASURAND))


def _methods(parent: etree._Element, attrs: Mapping[str, Any]) -> None:
    methods = _sub(parent, _d("usedMethods"))
    method = _sub(methods, _d("usedMethod"), refType="lidarcal_anemometerFreeCalibration")
    _text(method, "name", "Anemometer-free calibration of a pulsed Doppler wind lidar: fiber-optic bench "
          "and Monte Carlo virtual lidar in synthetic turbulence")
    _text(method, "description", "The lidar's line-of-sight response is measured on a fiber-optic bench "
          "(programmed Doppler shift, SI-traceable through the RF driver's calibration); a virtual lidar "
          "configured by it is simulated against a virtual point reference in synthetic turbulence driven "
          "by measured 10-minute conditions; the budget combines the simulated differences with the terms "
          "not simulated (GUM, coverage factor 2). Budget approach: "
          f"{attrs.get('budget_approach', 'unknown')}.")
    _sub(method, _d("reference"), attrs.get("method_reference") or str(attrs.get("references", _NOT_STATED)))
    software = _sub(_sub(parent, _d("usedSoftware")), _d("software"))
    _text(software, "name", "lidarcal")
    _sub(software, _d("release"), _release(str(attrs.get("product_version", __version__))))
    _sub(software, _d("type"), "application")

    equipment = _sub(_sub(parent, _d("measuringEquipments")), _d("measuringEquipment"),
                     refType="lidarcal_fiberOpticBench")
    bench = read_attr(attrs, "bench_id", kind="certificate")
    _text(equipment, "name", f"Fiber-optic lidar calibration bench {bench or ''}".strip())
    lines = [f"bench run {attrs.get('bench_run_id') or _NOT_STATED}",
             f"operator {attrs.get('bench_operator') or _NOT_STATED}",
             f"from {attrs.get('bench_run_start') or attrs.get('bench_time_coverage_start') or _NOT_STATED} "
             f"to {attrs.get('bench_run_end') or attrs.get('bench_time_coverage_end') or _NOT_STATED}",
             "RF driver calibration: "
             + str(read_attr(attrs, "rf_driver_calibration_reference", kind="certificate") or _NOT_STATED)]
    _text(equipment, "description", *lines)
    ids = _sub(equipment, _d("identifications"))
    for ref, value, name in (("lidarcal_benchId", bench, "Bench id"),
                             ("lidarcal_benchRunId", attrs.get("bench_run_id"), "Bench run")):
        ident = _sub(ids, _d("identification"), refType=ref)
        _sub(ident, _d("issuer"), "calibrationLaboratory")
        _sub(ident, _d("value"), value or _NOT_STATED)
        _text(ident, "name", name)

    conditions = _sub(_sub(parent, _d("influenceConditions")), _d("influenceCondition"),
                      refType="lidarcal_simulatedConditions")
    _text(conditions, "name", "Atmospheric conditions of the Monte Carlo simulation")
    _text(conditions, "description", "The virtual lidar and the virtual reference were simulated in "
          "synthetic turbulence driven by a record of measured 10-minute conditions (wind speed, turbulence "
          "intensity, shear, CNR); the certificate holds their provenance.")
    summary = _records_text(attrs)
    _text(_sub(conditions, _d("data")), "text", summary)

def _records_text(attrs: Mapping[str, Any]) -> str:
    try:
        records = read_attr(attrs, "lidarcal_records_summary", kind="certificate")  # InputError: a ValueError
    except ValueError:
        records = None
    if not isinstance(records, dict):
        return "Simulated periods: not stated in the certificate."
    heights = ", ".join(f"{float(z):g}" for z in records.get("heights_m", []))
    return (f"{records.get('periods', _NOT_STATED)} simulated 10-minute periods"
            + (f" at heights {heights} m" if heights else "")
            + (f", conditions from {records['time_coverage_start']} to {records['time_coverage_end']}"
               if records.get("time_coverage_start") else "") + ".")
