"""Digital Calibration Certificate (DCC): a certificate as PTB DCC XML, schema 3.1.2 with D-SI 2.1.0.

:func:`dcc_tree` turns a sealed netCDF certificate into the XML of PTB's Digital Calibration
Certificate (``https://ptb.de/dcc``, ``dcc.xsd`` 3.1.2, importing the D-SI ``SI_Format.xsd``
2.1.0, ``https://ptb.de/si``):

* ``administrativeData``: ``dccSoftware`` (lidarcal and its version); ``coreData`` with the
  certificate id as ``uniqueIdentifier``, the SHA-256 of the netCDF certificate as an
  identification, the performance dates (bench run to simulation) and location; the calibrated
  lidar (``items``); the laboratory; the responsible persons; the customer; statements giving
  the ``calibration_status`` (first), the place of the bench run and the netCDF's SHA-256.
* ``measurementResults``: one result per height with the wind-speed bin centres as a D-SI
  ``realListXMLList`` whose ``expandedUncXMLList`` holds the expanded uncertainty (k = 2,
  coverage probability 0.95) and whose ``dcc:relativeUncertainty`` the relative expanded
  uncertainty (%), the relative expanded uncertainty as its own list, the numerical tolerance
  when the budget has one, the number of Monte Carlo trials and of distinct periods per bin, and,
  when the budget has the Monte Carlo distribution, its estimate, standard uncertainty and 95 %
  coverage interval per bin (%) with each bin's certified statement in the labels of a list of
  its own; bins whose Monte Carlo values did not settle are left out of these lists and given
  apart, with their tolerances; the method, lidarcal as the software, the bench as the
  measuring equipment; and a second result with the environmental sensitivity slopes
  significant by Eq. 12 or 13.

The XML refers to the netCDF certificate by SHA-256, so the two stay one record: the netCDF is
the sealed (optionally signed) original, the XML its exchange form.  :func:`validate_dcc`
checks a document against the XSDs (not shipped with lidarcal: they are PTB's, LGPL).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from lxml import etree

from lidarcal.certificate.admin import (
    ADMIN_FILE_KEYS,
    STATUS_ATTR,
    STATUS_REASON_ATTR,
    certificate_attributes,
    status_line,
)
from lidarcal.certificate.dcc.xml import (
    _XSI,
    COVERAGE_PROBABILITY,
    DCC_NS,
    DCC_SCHEMA_VERSION,
    SI_NS,
    SI_SCHEMA_URL,
    _administrative,
    _d,
    _methods,
    _numbers,
    _s,
    _sub,
    _text,
)
from lidarcal.certificate.layout import components, extract_component
from lidarcal.certificate.measurand import model_form_summary, model_form_values
from lidarcal.certificate.results import certified_mask, not_settled_rows
from lidarcal.certificate.seal import require_valid_seal, seal_problems
from lidarcal.errors import InputError, SealError, ValidationError
from lidarcal.io import atomic_path, check_writable, open_artefact, read_image
from lidarcal.provenance import check_text
from lidarcal.readback import read_attr
from lidarcal.units import si_unit

__all__ = ["DCC_NS", "SI_NS", "DCC_SCHEMA_VERSION", "SI_SCHEMA_URL", "dcc_tree",
           "write_dcc", "validate_dcc", "dcc_attributes", "COVERAGE_PROBABILITY"]


def _flags(budget: xr.Dataset) -> dict[int, str]:
    return _flags_of(budget, "bin_flag")


def _flags_of(budget: xr.Dataset, name: str) -> dict[int, str]:
    if name not in budget:
        return {}
    var = budget[name]
    values = np.atleast_1d(var.attrs.get("flag_values", []))
    meanings = str(var.attrs.get("flag_meanings", "")).split()
    return {int(v): m for v, m in zip(values, meanings, strict=False)}


def _real_list(parent: etree._Element, name: str, values: np.ndarray, unit: str, *,
               labels: list[str] | None = None, ref_type: str | None = None,
               expanded: np.ndarray | None = None, k: float = 2.0,
               relative: np.ndarray | None = None, description: str | None = None) -> etree._Element:
    quantity = _sub(parent, _d("quantity"), refType=ref_type)
    _text(quantity, "name", name)
    if description:
        _text(quantity, "description", description)
    rl = _sub(quantity, _s("realListXMLList"))
    if labels is not None:
        _sub(rl, _s("labelXMLList"), " ".join(labels))
    _sub(rl, _s("valueXMLList"), _numbers(values))
    _sub(rl, _s("unitXMLList"), unit)
    if expanded is not None:
        unc = _sub(rl, _s("expandedUncXMLList"))
        _sub(unc, _s("uncertaintyXMLList"), _numbers(expanded))
        _sub(unc, _s("coverageFactorXMLList"), f"{k:g}")
        _sub(unc, _s("coverageProbabilityXMLList"), f"{COVERAGE_PROBABILITY:g}")
        _sub(unc, _s("distributionXMLList"), "normal")
    if relative is not None:
        rel = _sub(_sub(quantity, _d("relativeUncertainty")), _d("relativeUncertaintyXmlList"))
        _sub(rel, _s("valueXMLList"), _numbers(relative))
        _sub(rel, _s("unitXMLList"), r"\percent")
    return quantity


#: The Monte Carlo distribution's lists per height (JCGM 101): budget variable, name, refType.
_MONTE_CARLO_LISTS = (
    ("relative_mean_difference", "Estimate of the error of one 10-minute mean (mean lidar minus reference)",
     "lidarcal_errorEstimate"),
    ("relative_error_standard_uncertainty", "Standard uncertainty of the error of one 10-minute mean",
     "lidarcal_errorStandardUncertainty"),
    ("relative_coverage_interval_lower", "Lower end of the 95 % coverage interval of the error (Monte Carlo)",
     "lidarcal_coverageIntervalLower"),
    ("relative_coverage_interval_upper", "Upper end of the 95 % coverage interval of the error (Monte Carlo)",
     "lidarcal_coverageIntervalUpper"),
)


def _budget_results(root: etree._Element, cert: xr.Dataset, attrs: Mapping[str, Any], digest: str,
                    file_name: str) -> None:
    budget = extract_component(cert, "budget").load()
    k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
    flags = _flags(budget)
    result_el = _sub(root, _d("measurementResult"), refType="lidarcal_windSpeedUncertainty")
    _text(result_el, "name", "Expanded uncertainty of the lidar's 10-minute mean horizontal wind speed")
    _text(result_el, "description",
          "Per height and 0.5 m/s bin of the reference wind speed: expanded uncertainty (coverage factor "
          f"{k:g}, coverage probability {COVERAGE_PROBABILITY:g}) in m/s and in % of the bin's mean "
          "reference wind speed. Each value's label is the bin's flag (" + ", ".join(flags.values())
          + "); bins without a value (no period) are left out, and so are bins whose Monte Carlo values did "
          "not settle, which are given apart with their numerical tolerances. Where the budget has the Monte "
          "Carlo distribution of the error of one 10-minute mean (JCGM 101), its estimate, standard "
          "uncertainty and 95 % coverage interval follow, labelled with what each certified bin certifies "
          "(expanded_uncertainty: the error lies within +-U; coverage_interval: it lies in the interval, "
          "where the two differ materially). " + status_line(attrs))
    _methods(result_el, attrs)
    results = _sub(result_el, _d("results"))
    certified = certified_mask(budget).transpose("height", "wind_speed").values
    statements = _flags_of(budget, "certified_statement")
    model_form = model_form_values(budget)  # (wind_speed, height), or None
    budget = budget.transpose("height", "wind_speed", ...)
    missed = {(r["height_m"], r["wind_speed_m_s"]) for r in not_settled_rows(budget)}
    tolerance = budget.get("numerical_tolerance")
    for i, z in enumerate(np.atleast_1d(budget["height"].values)):
        rel = budget["relative_expanded_uncertainty"].values[i]
        absolute = budget["expanded_uncertainty"].values[i]
        apart = np.array([(float(z), float(u)) in missed for u in budget["wind_speed"].values])
        keep = np.isfinite(rel) & np.isfinite(absolute) & (absolute >= 0) & (rel >= 0) & ~apart
        result = _sub(results, _d("result"), refType="lidarcal_heightResult")
        _text(result, "name", f"Height {float(z):g} m")
        data = _sub(result, _d("data"))
        if not keep.any():
            _text(data, "text", f"No wind-speed bin at {float(z):g} m has a value.")
            continue
        speeds = budget["wind_speed"].values[keep]
        labels = [flags.get(int(f), str(int(f))) for f in budget["bin_flag"].values[i][keep]]
        lst = _sub(data, _d("list"), refType="lidarcal_windSpeedBins")
        _text(lst, "name", f"Wind-speed bins at {float(z):g} m")
        _real_list(lst, "Reference wind speed, bin centre, with the expanded uncertainty of the lidar's "
                   "10-minute mean horizontal wind speed", speeds, r"\metre\second\tothe{-1}", labels=labels,
                   ref_type="lidarcal_windSpeedBinCentre", expanded=absolute[keep], k=k, relative=rel[keep])
        _real_list(lst, f"Relative expanded uncertainty (k = {k:g})", rel[keep], r"\percent", labels=labels,
                   ref_type="lidarcal_relativeExpandedUncertainty",
                   description=f"coverage factor {k:g}, coverage probability {COVERAGE_PROBABILITY:g}")
        if tolerance is not None:
            tol = tolerance.transpose("height", "wind_speed").values[i][keep]
            if np.isfinite(tol).all():
                _real_list(lst, "Numerical tolerance of the relative expanded uncertainty (Monte Carlo)", tol,
                           si_unit(str(tolerance.attrs.get("units", "%"))), labels=labels,
                           ref_type="lidarcal_numericalTolerance")
        if model_form is not None:  # the simulation's model-form contributor (docs/method.md)
            _real_list(lst, "Model-form standard uncertainty (k = 1), relative to the bin's mean reference "
                       "wind speed", model_form["value"][:, i][keep], r"\percent", labels=labels,
                       ref_type="lidarcal_modelFormUncertainty", description=model_form_summary(budget))
        _real_list(lst, "Monte Carlo trials in the bin", budget["sample_count"].values[i][keep].astype(float),
                   r"\one", labels=labels, ref_type="lidarcal_sampleCount")
        if "period_count" in budget:
            _real_list(lst, "Distinct 10-minute periods in the bin",
                       budget["period_count"].values[i][keep].astype(float), r"\one", labels=labels,
                       ref_type="lidarcal_periodCount")
        mc = keep & np.all([np.isfinite(budget[name].values[i]) for name, _, _ in _MONTE_CARLO_LISTS
                            if name in budget] or [np.zeros(keep.shape, dtype=bool)], axis=0)
        if "certified_statement" in budget and mc.any():
            said = [statements.get(int(f), str(int(f))) if certified[i][j]
                    else flags.get(int(fl), str(int(fl)))
                    for j, (f, fl) in enumerate(zip(budget["certified_statement"].values[i],
                                                    budget["bin_flag"].values[i], strict=True)) if mc[j]]
            for name, title, ref in _MONTE_CARLO_LISTS:
                _real_list(lst, title, budget[name].values[i][mc], r"\percent", labels=said, ref_type=ref,
                           description="% of the bin's mean reference wind speed; label: the statement a "
                                       "certified bin certifies, else the bin's flag")
    if missed:  # listed apart: never among the certified results (JCGM 101 7.9)
        _not_settled_result(results, budget, sorted(missed))
    meta = _sub(result_el, _d("measurementMetaData"))
    known = {**attrs, **budget.attrs}  # the budget's, or the certificate's own
    names = ("monte_carlo_replicas", "monte_carlo_trials", "monte_carlo_significant_digits")
    monte_carlo = [f"{name.replace('monte_carlo_', '').replace('_', ' ')} {known[name]}"
                   for name in names if name in known]
    if monte_carlo:
        mc = _sub(meta, _d("metaData"), refType="lidarcal_monteCarlo")
        _text(mc, "declaration", "Monte Carlo: " + ", ".join(monte_carlo))
    record = _sub(meta, _d("metaData"), refType="lidarcal_netcdfCertificate")
    _sub(record, _d("reference"), f"{file_name} sha256:{digest}")
    _text(record, "declaration", f"Values copied unrounded from the sealed netCDF certificate {file_name} "
          f"(SHA-256 {digest}).")


def _not_settled_result(results: etree._Element, budget: xr.Dataset,
                        cells: list[tuple[float, float]]) -> None:
    """Write the bins left out because their Monte Carlo values did not settle, with their tolerances."""
    result = _sub(results, _d("result"), refType="lidarcal_notSettled")
    _text(result, "name", "Not certified: Monte Carlo values not settled")
    _text(result, "description", "Bins certified but for the Monte Carlo, whose values did not settle "
          "within the replicas run (JCGM 101 7.9): not certified, given with their relative expanded "
          "uncertainty and the largest numerical tolerance of their values.")
    rows = {(r["height_m"], r["wind_speed_m_s"]): r for r in not_settled_rows(budget)}
    labels = [f"{z:g}m_{u:g}m/s" for z, u in cells]
    lst = _sub(_sub(result, _d("data")), _d("list"))
    _real_list(lst, "Height", np.array([z for z, _ in cells]), r"\metre", labels=labels,
               ref_type="lidarcal_height")
    _real_list(lst, "Reference wind speed, bin centre", np.array([u for _, u in cells]),
               r"\metre\second\tothe{-1}", labels=labels, ref_type="lidarcal_windSpeedBinCentre")
    _real_list(lst, "Relative expanded uncertainty (not certified)",
               np.array([rows[c]["expanded_uncertainty_pct"] for c in cells]), r"\percent", labels=labels,
               ref_type="lidarcal_relativeExpandedUncertainty")
    tol = np.array([max((v for key, v in rows[c].items() if key.startswith("tolerance_") and np.isfinite(v)),
                        default=np.nan) for c in cells])
    if np.isfinite(tol).all():
        _real_list(lst, "Largest numerical tolerance of the bin's values (Monte Carlo)", tol, r"\percent",
                   labels=labels, ref_type="lidarcal_numericalTolerance")


def _sensitivity_results(root: etree._Element, cert: xr.Dataset) -> None:
    result_el = _sub(root, _d("measurementResult"), refType="lidarcal_sensitivities")
    _text(result_el, "name", "Environmental sensitivities significant by Eq. 12 or Eq. 13")
    _text(result_el, "description", "Slope m of the lidar-minus-reference wind-speed difference against an "
          "environmental variable, per height where m * std (Eq. 12) or m * std * R (Eq. 13) is significant.")
    _methods(result_el, cert.attrs)
    results = _sub(result_el, _d("results"))
    found = 0
    for comp in components(cert):
        if not comp["name"].startswith("sensitivity_"):
            continue
        sens = extract_component(cert, comp["name"]).load()
        var = read_attr(sens, "environmental_variable", kind="sensitivity",
                        default=comp["name"][len("sensitivity_"):])
        sig = np.atleast_1d(sens["significant"].values).astype(bool) & np.isfinite(np.atleast_1d(
            sens["slope"].values))
        if not sig.any():
            continue
        found += 1
        heights = np.atleast_1d(sens["height"].values)[sig]
        labels = [f"{float(z):g}m" for z in heights]
        result = _sub(results, _d("result"), refType="lidarcal_sensitivity")
        _text(result, "name", f"Sensitivity to {var.replace('_', ' ')}")
        lst = _sub(_sub(result, _d("data")), _d("list"))
        _real_list(lst, "Height", heights, r"\metre", labels=labels, ref_type="lidarcal_height")
        _real_list(lst, f"Slope m against {var.replace('_', ' ')}", np.atleast_1d(sens["slope"].values)[sig],
                   si_unit(str(sens["slope"].attrs.get("units", "1"))), labels=labels,
                   ref_type="lidarcal_sensitivitySlope")
        for name, title in (("slope_times_std", "Eq. 12 statistic m * std"),
                            ("slope_times_std_times_r", "Eq. 13 statistic m * std * R")):
            if name in sens:
                _real_list(lst, title, np.atleast_1d(sens[name].values)[sig],
                           si_unit(str(sens[name].attrs.get("units", "1"))), labels=labels,
                           ref_type=f"lidarcal_{name}")
    if not found:
        result = _sub(results, _d("result"))
        _text(result, "name", "No significant sensitivity")
        _text(_sub(result, _d("data")), "text", "No environmental sensitivity in the certificate is "
              "significant by Eq. 12 or Eq. 13 at any height.")


def dcc_attributes(cert: xr.Dataset, *, admin: Mapping[str, str] | None = None,
                   certificate_file: str = "certificate.nc") -> dict[str, Any]:
    """Return the certificate's global attributes with ``admin`` added, as the DCC states them.

    A certificate written before ``calibration_status`` existed is judged now by the same rule
    (:func:`lidarcal.certificate.admin.certificate_attributes`); one that could not be issued (no issuer)
    says "not stated".  An issued DCC needs ``laboratory_country_code``; a demonstration without
    one states ``ZZ`` (ISO 3166 user-assigned: unknown).

    Raises
    ------
    InputError
        Not a certificate, ``admin`` contradicting it, or an issued one without a country.
    """
    if read_attr(cert, "lidarcal_artefact") != "certificate":
        raise InputError(f"{certificate_file}: not a lidarcal certificate (lidarcal_artefact "
                         f"{read_attr(cert, 'lidarcal_artefact')!r})")
    attrs = dict(cert.attrs)
    for key, value in attrs.items():  # a certificate sealed before control characters were refused
        if isinstance(value, str):
            check_text(value, f"{certificate_file}: global attribute {key!r} (XML 1.0 cannot hold it)")
    for key, value in (admin or {}).items():
        check_text(value, f"--admin: {key}")
        if attrs.get(key) not in (None, "", value):
            raise InputError(f"--admin: {key} {value!r} contradicts the certificate {certificate_file}, "
                             f"which states {attrs[key]!r} (sealed); a DCC only adds what the certificate "
                             "does not say")
        attrs[key] = value
    if STATUS_ATTR not in cert.attrs:
        # a certificate written before calibration_status existed: judge it now, never issue it
        try:
            given = {k: v for k, v in attrs.items() if k in ADMIN_FILE_KEYS.values()}
            judged = certificate_attributes(attrs, given)
        except InputError:
            judged = {STATUS_ATTR: "not stated"}
        attrs.setdefault(STATUS_ATTR, judged.get(STATUS_ATTR, "not stated"))
        if judged.get(STATUS_REASON_ATTR):
            attrs.setdefault(STATUS_REASON_ATTR, judged[STATUS_REASON_ATTR])
    if attrs.get(STATUS_ATTR) == "issued" and not attrs.get("laboratory_country_code"):
        raise InputError(f"{certificate_file}: an issued DCC needs the laboratory's country (coreData "
                         "countryCodeISO3166_1): give laboratory.country_code in --admin ADMIN.yaml "
                         "(docs/certificate.md)")
    return attrs


def dcc_tree(cert: xr.Dataset, *, certificate_sha256: str, certificate_file: str = "certificate.nc",
             admin: Mapping[str, str] | None = None) -> etree._ElementTree:
    """Build the DCC XML of certificate ``cert`` (an opened netCDF certificate).

    Parameters
    ----------
    cert : xarray.Dataset
        The certificate as read from its file.
    certificate_sha256 : str
        SHA-256 of that file: the XML names it, so XML and netCDF stay one record.
    certificate_file : str
        The netCDF file's name, as the XML refers to it.
    admin : mapping, optional
        Administrative data (:func:`lidarcal.certificate.admin.load_admin`) the certificate does not state
        itself; a value that contradicts the certificate's own is refused.

    Raises
    ------
    InputError
        If ``cert`` is not a certificate or ``admin`` contradicts it.
    SealError
        If ``cert`` was read from a file whose seal does not match its contents (or is missing).
    """
    require_valid_seal(cert)  # a certificate read from a file: its seal first (None: built here, unsealed)
    return _tree(cert, certificate_sha256, certificate_file, admin)


def _tree(cert: xr.Dataset, certificate_sha256: str, certificate_file: str, admin) -> etree._ElementTree:
    attrs = dcc_attributes(cert, admin=admin, certificate_file=certificate_file)
    etree.register_namespace("dcc", DCC_NS)
    etree.register_namespace("si", SI_NS)
    root = etree.Element(_d("digitalCalibrationCertificate"), nsmap={"dcc": DCC_NS, "si": SI_NS, "xsi": _XSI})
    root.set("schemaVersion", DCC_SCHEMA_VERSION)
    root.set(f"{{{_XSI}}}schemaLocation", f"{DCC_NS} https://ptb.de/dcc/v{DCC_SCHEMA_VERSION}/dcc.xsd")
    # XML comments may not hold "--": the option names are written with non-breaking hyphens
    root.append(etree.Comment(f" {status_line(attrs)} ".replace("--", "\u2011\u2011")))
    _administrative(root, attrs, certificate_sha256, certificate_file)
    results = _sub(root, _d("measurementResults"))
    _budget_results(results, cert, attrs, certificate_sha256, certificate_file)
    _sensitivity_results(results, cert)
    return etree.ElementTree(root)


def write_dcc(certificate: str | os.PathLike, output: str | os.PathLike, *,
              admin: Mapping[str, str] | None = None, overwrite: bool = False,
              xsd: str | os.PathLike | None = None, signer: Any = None) -> Path:
    """Write the DCC XML of the netCDF certificate file ``certificate`` to ``output`` (atomically).

    The certificate's seal is checked first (:func:`lidarcal.certificate.seal.require_valid_seal`; an altered
    or unsealed one raises :class:`~lidarcal.errors.SealError`).  With ``xsd`` (PTB's ``dcc.xsd``,
    ``SI_Format.xsd`` beside it) the document is validated first and nothing is written when it
    is invalid.  With ``signer`` (:func:`lidarcal.certificate.dcc.sign.load_signer`) it is signed with the
    laboratory's X.509 key and chain (enveloped XAdES-BES).

    Raises
    ------
    InputError
        Bad certificate or administrative data, or the document does not validate.
    """
    check_writable(output, overwrite=overwrite)
    image = read_image(certificate, "certificate file")  # the bytes checked, read and named by SHA-256
    report = require_valid_seal(certificate, image=image, allow_invalid=True)
    if report is not None and not report.ok:
        raise SealError(f"{certificate}: refusing to export this certificate as a DCC: "
                        f"{seal_problems(report)}. A DCC is written only from a certificate whose seal "
                        "holds: it names the netCDF as the sealed original of its numbers")
    cert = open_artefact(certificate, "certificate", image=image)
    tree = _tree(cert, hashlib.sha256(image).hexdigest(), Path(certificate).name, admin)  # checked above
    if xsd is not None:
        problems = validate_dcc(tree, xsd)
        if problems:
            raise ValidationError(problems, source=f"{output} (against {xsd})")
    data = etree.tostring(tree, xml_declaration=True, encoding="UTF-8", pretty_print=True)
    if signer is not None:  # the laid-out text is what is signed: never re-indented after
        signed = signer.sign(etree.fromstring(data, etree.XMLParser(resolve_entities=False)))
        data = etree.tostring(signed, xml_declaration=True, encoding="UTF-8")
    with atomic_path(output, overwrite=overwrite) as tmp:
        tmp.write_bytes(data)  # an OSError (ENOSPC) atomic_path reports as a full disk; lxml's own
        # writer raised SerialisationError IO_ENOSPC instead
    return Path(output)


class _LocalSchemas(etree.Resolver):
    def __init__(self, mapping: Mapping[str, str]):
        super().__init__()
        self.mapping = dict(mapping)

    def resolve(self, url, pubid, context):
        if url in self.mapping:
            return self.resolve_filename(self.mapping[url], context)
        return None


def validate_dcc(document: str | os.PathLike | etree._ElementTree, xsd: str | os.PathLike,
                 si_xsd: str | os.PathLike | None = None) -> list[str]:
    """Validate a DCC against ``dcc.xsd``; return the schema's error messages (empty: valid).

    ``dcc.xsd`` imports the D-SI schema from :data:`SI_SCHEMA_URL`; it is read from ``si_xsd``
    (default: ``SI_Format.xsd`` next to ``xsd``), never from the network.

    Raises
    ------
    InputError
        If a schema file is missing or not a schema.
    """
    xsd = Path(xsd)
    si_path = Path(si_xsd) if si_xsd is not None else xsd.with_name("SI_Format.xsd")
    for path, what in ((xsd, "DCC schema dcc.xsd"), (si_path, "D-SI schema SI_Format.xsd")):
        if not path.is_file():
            raise InputError(f"{path}: {what} not found")
    parser = etree.XMLParser(no_network=True)
    parser.resolvers.add(_LocalSchemas({SI_SCHEMA_URL: str(si_path)}))
    try:
        schema = etree.XMLSchema(etree.parse(str(xsd), parser))
    except (etree.XMLSchemaParseError, etree.XMLSyntaxError) as exc:
        raise InputError(f"{xsd}: not a usable XML schema (with {si_path}): {exc}") from None
    tree = document if isinstance(document, etree._ElementTree) else etree.parse(str(document))
    if schema.validate(tree):
        return []
    return [f"line {e.line}: {e.message}" for e in schema.error_log]
