"""Building a certificate: bundle the calibration's artefacts into one flat Dataset.

:func:`make_certificate` checks that the inputs belong together (:mod:`lidarcal.certificate.inputs`),
flattens every component into one Dataset and records each input's global attributes on its
``provenance_<role>`` variable (:mod:`lidarcal.certificate.layout`), adds the headline, the Monte
Carlo's settings, a summary of the records and the provenance chain's seeds, stamps the result
as a ``certificate`` artefact and adds the calibration status and the administrative data
(:mod:`lidarcal.certificate.admin`).  The Dataset is not yet sealed:
:func:`lidarcal.certificate.seal.write_certificate` writes and seals it.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate.admin import (
    DEMONSTRATION,
    STATUS_ATTR,
    STATUS_REASON_ATTR,
    certificate_attributes,
    default_method_reference,
)
from lidarcal.certificate.inputs import check_consistent, check_kind, input_label
from lidarcal.certificate.layout import (
    PROVENANCE_PREFIX,
    components,
    prefixed,
    provenance_chain,
    provenance_container,
    provenance_record,
    scalar_coords,
)
from lidarcal.certificate.measurand import MEASURAND, model_form_summary
from lidarcal.certificate.results import headline_sentence, not_settled_items
from lidarcal.errors import InputError
from lidarcal.provenance import jsonable, read_json_attr, stamp
from lidarcal.readback import read_attr

__all__ = ["make_certificate"]

_ROLE_KINDS = {
    "budget": "uncertainty_budget",
    "cube": "bench_cube",
    "rwf": "rwf",
    "terms": "uncertainty_terms",
}
_RECORD_KINDS = ("simulated_rtd", "field_campaign")


def _provenance(role: str, ds: xr.Dataset) -> dict[str, Any]:
    return {"role": role, **provenance_record(ds.attrs)}


def _records_summary(records: xr.Dataset) -> dict[str, Any]:
    out: dict[str, Any] = {
        "kind": read_attr(records, "lidarcal_artefact"),
        "periods": int(records.sizes.get("time", 0)),
    }
    if "height" in records.coords:
        out["heights_m"] = [float(h) for h in np.atleast_1d(records["height"].values)]
    if "time" in records.coords and records.sizes.get("time", 0):
        t = records["time"].values
        out["time_coverage_start"] = str(np.min(t))
        out["time_coverage_end"] = str(np.max(t))
    if "cnr" in records and records["cnr"].attrs.get("units") == "dB":
        cnr = np.asarray(records["cnr"].values, dtype=float)
        if np.isfinite(cnr).any():  # the CNR range the virtual lidar drew the bench cube at
            out["cnr_min_db"], out["cnr_max_db"] = float(np.nanmin(cnr)), float(np.nanmax(cnr))
    for name in ("lidarcal_base_seed", "lidarcal_lidar_model"):
        if name in records.attrs:
            out[name] = read_json_attr(records, name)
    return out


def _chain_seeds(chain: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Every seed recorded anywhere in the provenance chain, keyed ``"role (file)"``."""
    out: dict[str, Any] = {}
    for rec in chain:
        if isinstance(rec.get("seeds"), dict) and rec["seeds"]:
            out.setdefault(f"{rec.get('role')} ({rec.get('file')})", rec["seeds"])
        if isinstance(rec.get("inputs"), list):
            for key, value in _chain_seeds(rec["inputs"]).items():
                out.setdefault(key, value)
    return out


def make_certificate(
    *,
    budget: xr.Dataset,
    sensitivities: Mapping[str, xr.Dataset] | Iterable[xr.Dataset],
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
    terms: xr.Dataset | None = None,
    records: xr.Dataset | None = None,
    config: Mapping[str, Any] | None = None,
    call: str = "lidarcal.certificate.make_certificate",
    admin: Mapping[str, str] | None = None,
    demonstration: bool = False,
) -> xr.Dataset:
    """Bundle a calibration into one flat ``certificate`` Dataset (not yet sealed).

    Parameters
    ----------
    budget : xarray.Dataset
        ``uncertainty_budget`` artefact.
    sensitivities : mapping or iterable of xarray.Dataset
        ``sensitivity`` artefacts, one per environmental variable.
    cube, rwf, terms : xarray.Dataset, optional
        ``bench_cube``, ``rwf`` and ``uncertainty_terms`` artefacts.
    records : xarray.Dataset, optional
        The ``simulated_rtd`` / ``field_campaign`` records the budget came from: summarised
        (not copied) and checked against the other inputs.
    config : mapping, optional
        The full configuration of the calibration run, recorded as JSON.
    admin : mapping, optional
        Administrative data (:func:`lidarcal.certificate.admin.load_admin`: item, laboratory, responsible
        persons, customer, place, dates, certificate id ...), stored as global attributes
        (docs/certificate.md); what the data state (lidar serial, bench id, run, operator,
        the RF driver's calibration reference, dates) is filled in.
    demonstration : bool
        Force ``calibration_status = "demonstration"``.  Without it the status is
        ``demonstration`` when an input is lidarcal's embedded sample data or a simulated bench
        run, else ``issued``, which needs an issuer (laboratory and responsible person).

    Raises
    ------
    InputError
        If inputs describe different lidars (``lidar_serial``), if an input was computed from
        a different file than the one given, or an input is of the wrong kind; if ``admin``
        contradicts the data; if the certificate would be issued without an issuer.
    """
    sens = list(sensitivities.values()) if isinstance(sensitivities, Mapping) else list(sensitivities)
    parts = _parts_by_role(budget, sens, cube=cube, rwf=rwf, terms=terms)
    everything = dict(parts)
    if records is not None:
        check_kind("records", records, _RECORD_KINDS)
        everything["records"] = records
    # derived artefacts record their records input under the role "records"
    serial = check_consistent(everything)
    cert, comps = _flattened(parts, records)
    chain = [_provenance(role, ds) for role, ds in everything.items()]
    seeds = _chain_seeds(chain)
    pointers = [{"role": rec["role"], "kind": rec["kind"], "file": rec["file"], "sha256": rec["sha256"],
                 "variable": f"{PROVENANCE_PREFIX}{rec['role']}"} for rec in chain]
    cert.attrs = {
        "certificate_components": " ".join(c["name"] for c in comps),
        "lidarcal_components": json.dumps(jsonable(comps, strict=True), sort_keys=True),
        "lidarcal_provenance_chain": json.dumps(jsonable(pointers, strict=True), sort_keys=True),
        **_summary_attributes(budget, serial=serial, cube=cube, rwf=rwf, records=records),
    }
    cert = stamp(
        cert,
        "certificate",
        title=f"Lidar calibration certificate{' for ' + serial if serial else ''}",
        summary=(
            "Anemometer-free calibration of a pulsed Doppler wind lidar (SAFO-MV bench + Monte Carlo "
            "virtual lidar): uncertainty budget, environmental sensitivities, bench cube, range-weighting "
            "function and zero distance, with the provenance of every input and an integrity record."
        ),
        call=call,
        seeds=seeds,
        input_datasets=everything,
        config=dict(config or {}),
        keywords="Doppler lidar, wind speed, calibration certificate, uncertainty, traceability",
    )
    # the certificate's direct inputs; each one's own chain is on its provenance_<role> variable
    direct = read_json_attr(cert, "lidarcal_inputs")
    if isinstance(direct, list):
        for rec in direct:
            if isinstance(rec, dict) and rec.pop("inputs", None) is not None:
                rec["inputs_on"] = f"{PROVENANCE_PREFIX}{rec.get('role')}"
        cert.attrs["lidarcal_inputs"] = json.dumps(jsonable(direct, strict=True), sort_keys=True)
    return _with_admin(cert, admin, demonstration, cube=cube, records=records, config=config)


def _parts_by_role(budget: xr.Dataset, sens: list[xr.Dataset], *, cube: xr.Dataset | None,
                   rwf: xr.Dataset | None, terms: xr.Dataset | None) -> dict[str, xr.Dataset]:
    """Return the components by role (``budget``, ``cube``, ``rwf``, ``terms``, ``sensitivity_<var>``)."""
    inputs: dict[str, xr.Dataset] = {"budget": budget}
    for role, ds in (("cube", cube), ("rwf", rwf), ("terms", terms)):
        if ds is not None:
            inputs[role] = ds
    for role, ds in inputs.items():
        check_kind(role, ds, [_ROLE_KINDS[role]])
    sens_roles: dict[str, xr.Dataset] = {}
    for ds in sens:
        check_kind("sensitivity", ds, ["sensitivity"])
        var = read_attr(ds, "environmental_variable", kind="sensitivity")
        if not var:
            raise InputError(f"{input_label('sensitivity', ds)}: attribute 'environmental_variable' "
                             "is missing")
        role = f"sensitivity_{var}"
        if role in sens_roles:
            raise InputError(
                f"two sensitivity inputs for the same variable {var!r}: "
                f"{input_label(role, sens_roles[role])} and {input_label(role, ds)}"
            )
        sens_roles[role] = ds
    return {**inputs, **sens_roles}


def _flattened(parts: Mapping[str, xr.Dataset], records: xr.Dataset | None
               ) -> tuple[xr.Dataset, list[dict[str, Any]]]:
    """Merge the prefixed components into one Dataset with a ``provenance_<role>`` variable per input.

    Each input's global attributes go on a variable of their own, one attribute a line in
    ``ncdump -h``; the global JSON attributes only list and point to them (the returned entries).
    """
    cert = xr.merge([prefixed(ds, f"{role}_") for role, ds in parts.items()],
                    compat="no_conflicts", join="exact", combine_attrs="drop_conflicts")
    comps = []
    for role, ds in parts.items():
        cert[f"{PROVENANCE_PREFIX}{role}"] = provenance_container(role, ds, component=True)
        comps.append(
            {
                "name": role,
                "prefix": f"{role}_",
                "kind": read_attr(ds, "lidarcal_artefact"),
                "file": read_attr(ds, "lidarcal_source_file"),
                "sha256": read_attr(ds, "lidarcal_source_sha256"),
                "scalar_coordinates": scalar_coords(ds),
                "variable": f"{PROVENANCE_PREFIX}{role}",
            }
        )
    if records is not None:
        cert[f"{PROVENANCE_PREFIX}records"] = provenance_container("records", records, component=False)
    return cert, comps


def _summary_attributes(budget: xr.Dataset, *, serial: str | None, cube: xr.Dataset | None,
                        rwf: xr.Dataset | None, records: xr.Dataset | None) -> dict[str, Any]:
    """Return the certificate's own global attributes (approach, headline, Monte Carlo, lidar, Zd ...)."""
    attrs: dict[str, Any] = {"budget_approach": read_attr(budget, "approach", kind="uncertainty_budget",
                                                       default="unknown"),
                             "measurand": MEASURAND}
    if (model_form := model_form_summary(budget)) is not None:
        attrs["model_form"] = model_form
    if (headline := headline_sentence(budget)) is not None:
        attrs["expanded_uncertainty_headline"] = headline
    for key in ("monte_carlo_replicas", "monte_carlo_trials", "monte_carlo_significant_digits"):
        if key in budget.attrs:
            attrs[key] = int(budget.attrs[key])
    if "numerical_flag" in budget:  # listed apart with the largest tolerance of their values
        attrs["monte_carlo_not_settled"] = "; ".join(not_settled_items(budget)) or "none"
    if "certified_statement" in budget:
        attrs["certified_statement_rule"] = (
            "per certified bin: the error of one 10-minute mean lies within +-U (k = "
            f"{read_attr(budget, 'coverage_factor', kind='uncertainty_budget'):g}) where that interval holds "
            "95 % to 97.5 % "
            "of the Monte Carlo distribution; elsewhere (the two differ materially) the Monte Carlo "
            f"{budget.attrs.get('coverage_interval', 'symmetric')} 95 % coverage interval (JCGM 101 7.7) "
            "is certified")
    if serial:
        attrs["lidar_serial"] = serial
    if records is not None:
        attrs["lidarcal_records_summary"] = json.dumps(jsonable(_records_summary(records), strict=True),
                                                       sort_keys=True)
    if rwf is not None and "zero_distance" in rwf:
        attrs["zero_distance_m"] = float(rwf["zero_distance"])
    for key in ("bench_id", "operator", "run_id", "time_coverage_start", "time_coverage_end"):
        if cube is not None and key in cube.attrs:
            attrs[f"bench_{key}" if not key.startswith("bench") else key] = str(cube.attrs[key])
    return attrs


def _with_admin(cert: xr.Dataset, admin: Mapping[str, str] | None, demonstration: bool, *,
                cube: xr.Dataset | None, records: xr.Dataset | None,
                config: Mapping[str, Any] | None) -> xr.Dataset:
    """Add ``calibration_status`` and the administrative attributes (lidarcal.certificate.admin)."""
    cube_attrs = cube.attrs if cube is not None else {}
    cubed = cube is not None  # a cube's run_id, operator and bench_id are required: read only with one
    derived = {
        "item_serial_number": read_attr(cert, "lidar_serial", kind="certificate"),
        "bench_id": read_attr(cube, "bench_id", kind="bench_cube") if cubed else None,
        "bench_run_id": read_attr(cube, "run_id", kind="bench_cube") if cubed else None,
        "bench_operator": read_attr(cube, "operator", kind="bench_cube") if cubed else None,
        "rf_driver_calibration_reference": (
            read_attr(cube, "rf_driver_calibration_reference", kind="bench_cube") if cubed else None),
        "bench_run_start": cube_attrs.get("time_coverage_start"),
        "bench_run_end": cube_attrs.get("time_coverage_end"),
        "simulation_date": records.attrs.get("date_created") if records is not None else None,
        "method_reference": default_method_reference(cert.attrs.get("budget_approach", "unknown"), config),
    }
    # the inputs' own provenance is on the provenance_<role> variables: searched there too
    extra = certificate_attributes(cert.attrs, admin, derived={k: str(v) for k, v in derived.items() if v},
                                   provenance=[*provenance_chain(cert), *components(cert)],
                                   demonstration=demonstration)
    cert.attrs.update(extra)
    if cert.attrs.get("institution") in (None, "unspecified") and extra.get("laboratory_name"):
        cert.attrs["institution"] = extra["laboratory_name"]  # ACDD institution carries the laboratory
    if cert.attrs.get("creator_name") in (None, "lidarcal") and extra.get("responsible_persons"):
        # ACDD creator: the first responsible person, without the role
        first = extra["responsible_persons"].split(";")[0].strip()
        cert.attrs["creator_name"] = first.rsplit(" (", 1)[0] if first.endswith(")") else first
        cert.attrs["creator_type"] = "person"
    if extra[STATUS_ATTR] == DEMONSTRATION:
        cert.attrs["title"] = f"{cert.attrs['title']} - DEMONSTRATION, not a calibration of a real instrument"
        cert.attrs["summary"] = (f"DEMONSTRATION certificate ({extra[STATUS_REASON_ATTR]}). "
                                 + str(cert.attrs.get("summary", "")))
    return cert

