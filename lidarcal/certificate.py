"""The calibration certificate: one flat, self-verifying netCDF file (paper Figure 1).

:func:`make_certificate` bundles the uncertainty budget, the sensitivities, the bench cube,
the RWF (with Zd), the Table 4 terms and a summary of the records into **one flat Dataset**:
every component's variables, coordinates and dimensions are renamed with a prefix
(``budget_uncertainty``, ``cube_los_bias``, ``rwf_zero_distance``,
``sensitivity_wind_shear_exponent_slope`` ...), so that plain netCDF tools (ncdump, netCDF4,
any language) read it without groups.  :func:`extract_component` gives a component back as
the Dataset it was.  The full configuration is a global attribute; each input's global
attributes (file name, SHA-256, its own inputs, configuration, seeds and history) are the
attributes of a scalar variable ``provenance_<role>``, one short attribute each, so that
``ncdump -h`` reads as text; :func:`components` and :func:`provenance_chain` read them (and the
earlier layout, where they were JSON inside the global attributes ``lidarcal_components`` and
``lidarcal_provenance_chain``).

:func:`write_certificate` writes atomically, refuses to replace an existing file unless asked,
and **seals** it: a global attribute ``lidarcal_integrity`` records the SHA-256 of every
variable's stored values, of every variable's attributes and of every global attribute.  The
canonical byte forms are defined on the file as stored (no xarray decoding), so the record
can be re-checked years later with any netCDF library (:func:`integrity_record` documents
them); :func:`verify_certificate` (``lidarcal verify``) recomputes them.  The record detects
alteration, not forgery: whoever can rewrite the file can also rewrite the checksums.  Against
forgery the seal can be **signed** (``signing_key``, :mod:`lidarcal.signing`): an Ed25519
signature of the seal's exact text in ``lidarcal_signature``, next to the signer's public key
and fingerprint (``lidarcal_signature_public_key``, ``lidarcal_signature_key``, which the seal
covers).  Checked against the public key the user trusts (``verify_certificate(public_key=)``),
a re-sealed file fails.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.admin import (
    DEMONSTRATION,
    STATUS_ATTR,
    STATUS_REASON_ATTR,
    certificate_attributes,
    default_method_reference,
)
from lidarcal.analysis.budget import DEFAULT_CERTIFIED_RANGE
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, source_name
from lidarcal.provenance import jsonable, read_json_attr, stamp

# the seal lives in lidarcal.seal; re-exported here, where users have always found it
from lidarcal.seal import (
    CANONICAL_FORM,
    INTEGRITY_ATTR,
    SIGNATURE_ALGORITHM_ATTR,
    SIGNATURE_ATTR,
    SIGNATURE_KEY_ATTR,
    SIGNATURE_PUBLIC_KEY_ATTR,
    VerificationReport,
    integrity_record,
    invalid_seal_banner,
    require_valid_seal,
    verify_certificate,
    write_certificate,
)
from lidarcal.units import register_units

__all__ = [
    "make_certificate",
    "write_certificate",
    "verify_certificate",
    "integrity_record",
    "require_valid_seal",
    "invalid_seal_banner",
    "extract_component",
    "components",
    "provenance_chain",
    "records_summary",
    "container_attributes",
    "PROVENANCE_PREFIX",
    "open_certificate",
    "result_table",
    "headline_range",
    "headline_sentence",
    "certified_rule",
    "not_settled",
    "HEADLINE_WIND_SPEEDS",
    "VerificationReport",
    "INTEGRITY_ATTR",
    "SIGNATURE_ATTR",
    "SIGNATURE_KEY_ATTR",
    "SIGNATURE_PUBLIC_KEY_ATTR",
    "SIGNATURE_ALGORITHM_ATTR",
    "CANONICAL_FORM",
]

_ROLE_KINDS = {
    "budget": "uncertainty_budget",
    "cube": "bench_cube",
    "rwf": "rwf",
    "terms": "uncertainty_terms",
}
_RECORD_KINDS = ("simulated_rtd", "field_campaign")


# ------------------------------------------------------------------ flattening


def _prefixed(ds: xr.Dataset, prefix: str) -> xr.Dataset:
    """Rename every variable, coordinate and dimension of ``ds`` to ``prefix + name``."""
    names = {str(n): f"{prefix}{n}" for n in ds.variables}
    dims = {str(d): f"{prefix}{d}" for d in ds.dims if d not in ds.variables}
    out = ds.rename({**names, **dims})
    for var in out.variables.values():
        for key in ("bounds", "ancillary_variables"):
            if key in var.attrs:
                var.attrs[key] = " ".join(names.get(t, t) for t in str(var.attrs[key]).split())
        if "cell_methods" in var.attrs:
            var.attrs["cell_methods"] = _renamed_cell_methods(var.attrs["cell_methods"], {**names, **dims})
        var.encoding = {}
    out.attrs = {}
    # a scalar coordinate would be attached (``coordinates``) to every variable of the flat
    # file, e.g. giving all heights a second Z axis; store it as a data variable instead
    return out.reset_coords(_scalar_coords(out))


def _renamed_cell_methods(text: str, rename: Mapping[str, str]) -> str:
    """``cell_methods`` with the dimension names (``los: cnr: velocity: mean``) renamed (CF §7.3)."""
    return " ".join(f"{rename.get(t[:-1], t[:-1])}:" if t.endswith(":") else t for t in str(text).split())


def _scalar_coords(ds: xr.Dataset) -> list[str]:
    return [str(n) for n, c in ds.coords.items() if c.ndim == 0]


def extract_component(cert: xr.Dataset, name: str) -> xr.Dataset:
    """Return component ``name`` (``"budget"``, ``"cube"``, ``"sensitivity_cnr"`` ...) as it was.

    Names, dimensions and the component's global attributes are restored.
    """
    info = {c["name"]: c for c in components(cert)}
    if name not in info:
        raise InputError(f"certificate has no component {name!r}; it has {sorted(info)}")
    prefix = info[name]["prefix"]
    keep = [v for v in cert.variables if str(v).startswith(prefix)]
    sub = cert[[v for v in keep if v in cert.data_vars]]
    sub = sub.assign_coords({v: cert[v] for v in keep if v in cert.coords and v not in sub.coords})
    sub = sub.drop_vars([v for v in sub.variables if not str(v).startswith(prefix)])
    rename = {str(v): str(v)[len(prefix) :] for v in sub.variables}
    rename.update({str(d): str(d)[len(prefix) :] for d in sub.dims if d not in sub.variables})
    out = sub.rename(rename)
    for var in out.variables.values():
        for key in ("bounds", "ancillary_variables"):
            if key in var.attrs:
                var.attrs[key] = " ".join(
                    t[len(prefix) :] if t.startswith(prefix) else t for t in str(var.attrs[key]).split()
                )
        if "cell_methods" in var.attrs:
            var.attrs["cell_methods"] = _renamed_cell_methods(var.attrs["cell_methods"], rename)
    out.attrs = dict(info[name].get("attributes", {}))
    out = out.drop_vars([v for v in out.variables if str(v).startswith(PROVENANCE_PREFIX)], errors="ignore")
    scalars = [n for n in info[name].get("scalar_coordinates", []) if n in out.variables]
    return out.set_coords(scalars)


def components(cert: xr.Dataset) -> list[dict[str, Any]]:
    """List the components of a certificate (name, prefix, kind, file, sha256, attributes).

    Reads both layouts: a component's global ``attributes`` are the attributes of its
    ``provenance_<name>`` variable (certificates written since the attributes were made short),
    or a key of the ``lidarcal_components`` JSON (certificates written before).
    """
    comps = read_json_attr(cert, "lidarcal_components")
    if not isinstance(comps, list):
        raise InputError("not a lidarcal certificate: global attribute 'lidarcal_components' is missing")
    out = []
    for comp in comps:
        comp = dict(comp)
        if "attributes" not in comp and comp.get("variable") in cert.variables:
            attrs = container_attributes(cert[comp["variable"]])
            comp["attributes"] = {k: v for k, v in attrs.items() if not k.startswith("lidarcal_source_")}
        out.append(comp)
    return out


def container_attributes(var: xr.DataArray) -> dict[str, Any]:
    """Return the global attributes of an input recorded on its ``provenance_<role>`` variable.

    Names CF reserves for variables were stored as ``global_<name>`` and are restored; the
    variable's own ``long_name``, ``coverage_content_type``, ``units`` and seal digest are left out.
    """
    out = {}
    for key, value in var.attrs.items():
        if key in _CONTAINER_OWN:
            continue
        out[key[len("global_"):] if key.startswith("global_") else key] = jsonable(value, strict=True)
    return out


def provenance_chain(cert: xr.Dataset) -> list[dict[str, Any]]:
    """Return the provenance chain of a certificate's inputs, one record per role, in either layout.

    Each record holds ``role``, ``kind``, ``file``, ``sha256``, ``id``, ``lidarcal_version``,
    ``inputs`` (the input's own chain, to any depth), ``config``, ``seeds`` and ``history``: read
    from the input's ``provenance_<role>`` variable, or from the ``lidarcal_provenance_chain``
    JSON of a certificate written before the attributes were made short.
    """
    chain = read_json_attr(cert, "lidarcal_provenance_chain")
    if not isinstance(chain, list):
        return []
    out = []
    for rec in chain:
        if isinstance(rec, Mapping) and rec.get("variable") in cert.variables:
            attrs = container_attributes(cert[rec["variable"]])
            rec = {**_provenance_record(attrs), "role": rec.get("role"), "kind": rec.get("kind"),
                   "file": rec.get("file"), "sha256": rec.get("sha256")}
        out.append(rec)
    return out


def records_summary(cert: xr.Dataset) -> dict[str, Any] | None:
    """Return the summary of the records a certificate's budget came from (``lidarcal_records_summary``)."""
    out = read_json_attr(cert, "lidarcal_records_summary")
    return out if isinstance(out, dict) else None


def open_certificate(path: str | os.PathLike, *, chunks: dict | None = None,
                     allow_invalid: bool = False) -> xr.DataTree:
    """Open a certificate as an :class:`xarray.DataTree`, one group per component.

    Every group (``budget``, ``cube``, ``rwf``, ``terms``, ``sensitivity_<variable>``) holds
    the component under its original variable and dimension names, as
    :func:`extract_component` restores it, so ``tree["budget"].sel(height=120, wind_speed=8,
    method="nearest")`` and the ``cf`` accessor work.  The root holds the certificate's global
    attributes (provenance, integrity record).  Values are loaded into memory (a certificate
    is small), so ``....item()`` and ``float(...)`` work at once; give ``chunks`` (e.g. ``{}``)
    to read lazily with dask instead.  Opening also registers
    cf-xarray's unit registry with pint, so ``tree["budget"].dataset.pint.quantify()``
    understands the stored units.

    The seal is checked first (:func:`require_valid_seal`); with ``allow_invalid`` an altered
    certificate is opened anyway, its problems listed in the root attribute
    ``lidarcal_seal_problems``.

    Raises
    ------
    InputError
        If ``path`` is missing, unreadable or not a lidarcal certificate.
    SealError
        If its seal does not match its contents (unless ``allow_invalid``).
    """
    register_units()
    # read without closing: xarray shares one cached handle per file, and closing it under
    # another open Dataset of the same file made netCDF4's next open of it crash (HDF5)
    ds = open_artefact(path, load=False, chunks=chunks)
    if ds.attrs.get("lidarcal_artefact") != "certificate":
        found = ds.attrs.get("lidarcal_artefact")
        raise InputError(f"{path}: not a lidarcal certificate: it is "
                         f"{repr(found) + ' artefact' if found else 'not a lidarcal artefact'}")
    seal = require_valid_seal(path, allow_invalid=allow_invalid)
    if chunks is None:
        ds = ds.load()  # a certificate is small: values an analyst can .item()
    nodes: dict[str, xr.Dataset] = {"/": xr.Dataset(attrs=dict(ds.attrs))}
    if seal is not None and not seal.ok:
        nodes["/"].attrs["lidarcal_seal_problems"] = invalid_seal_banner(seal)
    for comp in components(ds):
        nodes[f"/{comp['name']}"] = extract_component(ds, comp["name"])
    return xr.DataTree.from_dict(nodes)


# ------------------------------------------------------------------ result table

#: Wind speeds (bin centres, m/s) certified by default (the range of the paper's Table 4, from the
#: 4 m/s cut-in that wind sensors are calibrated from); the rule itself is
#: :func:`lidarcal.analysis.budget.certified_bins`, recorded in the budget's ``bin_flag``.
HEADLINE_WIND_SPEEDS = DEFAULT_CERTIFIED_RANGE


def _budget_of(obj: xr.Dataset) -> xr.Dataset:
    if obj.attrs.get("lidarcal_artefact") == "certificate" or "lidarcal_components" in obj.attrs:
        return extract_component(obj, "budget")
    if "relative_expanded_uncertainty" not in obj:
        kind = obj.attrs.get("lidarcal_artefact")
        what = f"a {kind!r} artefact" if kind else "a file with no lidarcal_artefact attribute"
        raise InputError(f"{source_name(obj)}: expected a certificate or an uncertainty_budget; found {what} "
                         f"and no variable 'relative_expanded_uncertainty' (variables "
                         f"{sorted(map(str, obj.data_vars))})")
    return obj


def _certified_value(budget: xr.Dataset) -> int:
    """Return the ``bin_flag`` value meaning ``certified`` (the budget declares its own meanings)."""
    names = {m: v for v, m in _flag_names(budget["bin_flag"]).items()}
    if "certified" not in names:
        raise InputError(f"{source_name(budget)}: the budget's bin_flag has no meaning 'certified' (found "
                         f"{budget['bin_flag'].attrs.get('flag_meanings')!r}); it predates the certification "
                         "rule: recompute it with lidarcal budget")
    return names["certified"]


def _headline_mask(budget: xr.Dataset) -> xr.DataArray:
    certified = budget["bin_flag"] == _certified_value(budget)
    return certified & np.isfinite(budget["relative_expanded_uncertainty"])


def certified_rule(obj: xr.Dataset) -> str:
    """Return the budget's certification rule in words, e.g. ``centres 4 to 16 m/s, >= 10 periods``."""
    budget = _budget_of(obj)
    lo, hi = np.asarray(budget.attrs.get("certified_range_m_s", DEFAULT_CERTIFIED_RANGE), dtype=float)
    return f"centres {lo:g} to {hi:g} m/s, >= {int(budget.attrs.get('min_periods', 0))} periods"


def not_settled(obj: xr.Dataset) -> list[tuple[float, float]]:
    """(height m, bin centre m/s) of the certified values the Monte Carlo did not settle."""
    budget = _budget_of(obj)
    if "numerical_flag" not in budget:
        return []
    flag = budget["numerical_flag"].transpose("height", "wind_speed").values
    return [(float(budget["height"].values[i]), float(budget["wind_speed"].values[j]))
            for i, j in zip(*np.nonzero(flag == 1), strict=True)]


def headline_range(obj: xr.Dataset, *, wind_speeds: tuple[float, float] | None = None
                   ) -> tuple[float, float] | None:
    """Smallest and largest k = 2 relative expanded uncertainty (%) quoted on the certificate.

    Only certified bins count (``bin_flag`` ``certified``: centre in the certified range and
    enough distinct periods; :func:`lidarcal.analysis.budget.certified_bins`); ``wind_speeds``
    (m/s, inclusive) may narrow them further.  ``obj`` is a certificate or an
    ``uncertainty_budget``; None when no bin qualifies.
    """
    budget = _budget_of(obj)
    mask = _headline_mask(budget)
    if wind_speeds is not None:
        mask = mask & (budget["wind_speed"] >= wind_speeds[0]) & (budget["wind_speed"] <= wind_speeds[1])
    rel = budget["relative_expanded_uncertainty"].where(mask)
    if not bool(np.isfinite(rel).any()):
        return None
    return float(rel.min()), float(rel.max())


def headline_sentence(obj: xr.Dataset) -> str | None:
    """Return the certificate's headline: the certified range and any values that did not settle."""
    budget = _budget_of(obj)
    rng = headline_range(budget)
    if rng is None:
        return None
    text = (f"{rng[0]:.2f} % to {rng[1]:.2f} % (k = {float(budget.attrs.get('coverage_factor', 2)):g}; "
            f"certified bins: {certified_rule(budget)}; lidarcal table lists every bin)")
    missed = not_settled(budget)
    if missed:
        text += (f"; {len(missed)} certified value(s) did not settle to "
                 f"{int(budget.attrs['monte_carlo_significant_digits'])} significant digits within "
                 f"{int(budget.attrs['monte_carlo_replicas'])} Monte Carlo replicas "
                 "(monte_carlo_not_settled)")
    return text


def _flag_names(var: xr.DataArray) -> dict[int, str]:
    values = np.atleast_1d(var.attrs.get("flag_values", []))
    meanings = str(var.attrs.get("flag_meanings", "")).split()
    return {int(v): m for v, m in zip(values, meanings, strict=False)}


def _significant_sensitivities(cert: xr.Dataset) -> dict[float, str]:
    """Per height, the sensitivities significant by Eq. 12 or 13, as readable text."""
    out: dict[float, list[str]] = {}
    for comp in components(cert):
        if not comp["name"].startswith("sensitivity_"):
            continue
        sens = extract_component(cert, comp["name"])
        var = sens.attrs.get("environmental_variable", comp["name"][len("sensitivity_"):])
        for z in np.atleast_1d(sens["height"].values):
            one = sens.sel(height=z)
            if not int(one["significant"]):
                continue
            eqs = [eq for eq, name in (("Eq. 12", "significant_eq12"), ("Eq. 13", "significant_eq13"))
                   if int(one[name])]
            out.setdefault(float(z), []).append(
                f"{var}: m*std = {float(one['slope_times_std']):.2f} %, "
                f"m*std*R = {float(one['slope_times_std_times_r']):.2f} % ({', '.join(eqs)})"
            )
    return {z: "; ".join(v) for z, v in out.items()}


def _reason(flag: str, periods: int, budget: xr.Dataset) -> str:
    """Why a bin is not certified, in words ("" when it is)."""
    lo, hi = np.asarray(budget.attrs.get("certified_range_m_s", DEFAULT_CERTIFIED_RANGE), dtype=float)
    return {"certified": "",
            "too_few_periods": f"{periods} periods (fewer than {int(budget.attrs.get('min_periods', 0))})",
            "empty": "no period",
            "outside_certified_range": f"centre outside {lo:g} to {hi:g} m/s"}.get(flag, flag)


def result_table(cert: xr.Dataset, *, contributors: int = 3, allow_invalid: bool = False):
    """IEC-style result table of a certificate: one row per height and wind-speed bin.

    Columns: ``height_m``, ``wind_speed_m_s`` (bin centre) and its bounds, ``sample_count``
    (Monte Carlo trials), ``period_count`` (distinct 10-minute periods), ``bin_flag`` (the
    budget's flag meaning: ``certified``, ``too_few_periods``, ``empty``,
    ``outside_certified_range``), ``certified`` (counted in :func:`headline_range`),
    ``not_certified_reason``, the k = 2 expanded uncertainty in m/s and in % of the bin's mean
    reference wind speed, ``numerical_tolerance_pct`` (the Monte Carlo's tolerance on that %,
    JCGM 101 7.9) and ``numerically_settled``, ``main_contributors`` (the largest
    ``contributors`` standard-uncertainty contributions, in %) and ``significant_sensitivities``
    (per height, Eqs. 12-13).  Numbers are the certificate's own values, not rounded.

    A certificate read from a file has its seal checked first (:func:`require_valid_seal`):
    an altered one raises :class:`~lidarcal.errors.SealError` unless ``allow_invalid`` (the
    caller then shows :func:`invalid_seal_banner` with the table).

    Returns
    -------
    pandas.DataFrame
    """
    import pandas as pd

    if not allow_invalid and "lidarcal_components" in cert.attrs:
        require_valid_seal(cert)

    budget = _budget_of(cert).load()
    k = float(budget.attrs.get("coverage_factor", 2.0))
    flags = _flag_names(budget["bin_flag"])
    # rows run over (height, wind speed): index by those names, whatever the stored order
    headline = _headline_mask(budget).transpose("height", "wind_speed")
    budget = budget.transpose("height", "wind_speed", ...)
    sens = _significant_sensitivities(cert) if "lidarcal_components" in cert.attrs else {}
    names = [str(c) for c in budget["contributor"].values]
    bounds = budget["wind_speed_bounds"].values if "wind_speed_bounds" in budget else None
    rows = []
    for i, z in enumerate(budget["height"].values):
        for j, u in enumerate(budget["wind_speed"].values):
            rel_c = budget["relative_contribution"].values[i, j]
            order = [n for n in np.argsort(-np.nan_to_num(rel_c, nan=-np.inf)) if np.isfinite(rel_c[n])]
            main = "; ".join(f"{names[n]} {rel_c[n]:.2f} %" for n in order[:contributors])
            flag = int(budget["bin_flag"].values[i, j])
            periods = int(budget["period_count"].values[i, j]) if "period_count" in budget else -1
            tol = (float(budget["numerical_tolerance"].values[i, j]) if "numerical_tolerance" in budget
                   else np.nan)
            nflag = int(budget["numerical_flag"].values[i, j]) if "numerical_flag" in budget else 2
            rows.append({
                "height_m": float(z),
                "wind_speed_m_s": float(u),
                "wind_speed_min_m_s": float(bounds[j, 0]) if bounds is not None else np.nan,
                "wind_speed_max_m_s": float(bounds[j, 1]) if bounds is not None else np.nan,
                "sample_count": int(budget["sample_count"].values[i, j]),
                "period_count": periods,
                "bin_flag": flags.get(flag, str(flag)),
                "certified": bool(headline.values[i, j]),
                "not_certified_reason": _reason(flags.get(flag, str(flag)), periods, budget),
                f"expanded_uncertainty_k{k:g}_m_s": float(budget["expanded_uncertainty"].values[i, j]),
                f"expanded_uncertainty_k{k:g}_pct": float(
                    budget["relative_expanded_uncertainty"].values[i, j]),
                "numerical_tolerance_pct": tol,
                "numerically_settled": {0: "yes", 1: "no"}.get(nflag, ""),
                "main_contributors": main,
                "significant_sensitivities": sens.get(float(z), ""),
            })
    table = pd.DataFrame(rows)
    table.attrs["coverage_factor"] = k
    table.attrs["certified_rule"] = certified_rule(budget)
    table.attrs["headline_range_pct"] = headline_range(budget)
    table.attrs["not_settled"] = not_settled(budget)
    table.attrs["significant_digits"] = budget.attrs.get("monte_carlo_significant_digits")
    return table


# ------------------------------------------------------------------ consistency


def _label(role: str, ds: xr.Dataset) -> str:
    src = ds.attrs.get("lidarcal_source_file")
    return f"{role} ({src})" if src else role


def _find_key(obj: Any, key: str) -> Any:
    if isinstance(obj, Mapping):
        if key in obj:
            return obj[key]
        for v in obj.values():
            found = _find_key(v, key)
            if found is not None:
                return found
    elif isinstance(obj, list):
        for v in obj:
            found = _find_key(v, key)
            if found is not None:
                return found
    return None


def _serial(ds: xr.Dataset) -> str | None:
    for name in ("lidar_serial", "lidar_serial_number"):  # the latter: field campaigns from .sta files
        if ds.attrs.get(name):
            return str(ds.attrs[name])
    model = read_json_attr(ds, "lidarcal_lidar_model")
    found = _find_key(model, "lidar_serial") if model is not None else None
    return str(found) if found else None


def _records_of(ds: xr.Dataset) -> tuple[str | None, str] | None:
    """``(file, sha256)`` of the records ``ds`` was computed from, if it recorded them."""
    recorded = read_json_attr(ds, "lidarcal_inputs")
    for rec in recorded if isinstance(recorded, list) else []:
        if isinstance(rec, Mapping) and rec.get("role") == "records" and rec.get("sha256"):
            return rec.get("file"), str(rec["sha256"])
    return None


def _check_consistent(inputs: Mapping[str, xr.Dataset]) -> str | None:
    """Refuse inputs that describe different lidars or were derived from other files.

    With or without the records themselves: every input naming a lidar must name the same
    one, and once any input names one, the budget and every sensitivity must name it too (a
    budget of unknown lidar cannot be vouched for with another lidar's cube); the budget and
    every sensitivity must have been computed from the same records file (by checksum).
    """
    serials = {role: s for role, ds in inputs.items() if (s := _serial(ds))}
    distinct = sorted(set(serials.values()))
    if len(distinct) > 1:
        pairs = [f"{_label(r, inputs[r])} has lidar_serial {s!r}" for r, s in serials.items()]
        raise InputError("inputs disagree on the lidar: " + "; ".join(pairs))
    unnamed = [r for r in inputs if r not in serials and (r == "budget" or r.startswith("sensitivity_"))]
    if distinct and unnamed:
        named = ", ".join(f"{_label(r, inputs[r])}" for r in serials)
        raise InputError(
            f"inputs may describe different lidars: {', '.join(_label(r, inputs[r]) for r in unnamed)} "
            f"name(s) no lidar serial (their records did not record one), but {named} describe(s) "
            f"lidar {distinct[0]!r}; simulate the records with that lidar's cube (lidarcal simulate "
            "--cube) so that the budget and sensitivities carry its lidar_serial"
        )
    chains = {r: found for r, ds in inputs.items() if r != "records" and (found := _records_of(ds))}
    if len({sha for _, sha in chains.values()}) > 1:
        parts = [f"{_label(r, inputs[r])} was computed from records {f!r} (sha256 {sha[:12]}...)"
                 for r, (f, sha) in chains.items()]
        raise InputError("inputs disagree on the records: " + "; ".join(parts))
    _check_chains(inputs)
    return distinct[0] if distinct else None


def _chain(recorded: Any, via: tuple[Mapping[str, Any], ...] = ()
           ) -> Iterable[tuple[tuple[Mapping[str, Any], ...], Mapping[str, Any]]]:
    """Every record of a provenance chain (``lidarcal_inputs``), with the records leading to it."""
    for rec in recorded if isinstance(recorded, list) else []:
        if isinstance(rec, Mapping):
            yield via, rec
            yield from _chain(rec.get("inputs"), (*via, rec))


def _check_chains(inputs: Mapping[str, xr.Dataset]) -> None:
    """Refuse an input whose provenance chain names another file in a role that was given.

    The chain is followed to any depth, so a budget computed from records simulated with
    another bench cube or RWF is refused without the records themselves (``--records``).
    """
    known = {role: str(sha) for role, ds in inputs.items() if (sha := ds.attrs.get("lidarcal_source_sha256"))}
    for role, ds in inputs.items():
        for via, rec in _chain(read_json_attr(ds, "lidarcal_inputs")):
            other, sha = rec.get("role"), rec.get("sha256")
            if other not in known or other == role or not sha or str(sha) == known[other]:
                continue
            steps = "".join(f"{hop.get('role')} {hop.get('file')!r} (sha256 {hop.get('sha256')}), which was "
                            "computed from " for hop in via)
            raise InputError(
                f"inputs disagree: {_label(role, ds)} was computed from {steps}{other} {rec.get('file')!r} "
                f"(sha256 {sha}), but the {other} given is "
                f"{inputs[other].attrs.get('lidarcal_source_file')!r} (sha256 {known[other]}); give the "
                f"{other} it was computed from, or recompute it from this one"
            )


def _check_kind(role: str, ds: xr.Dataset, kinds: Iterable[str]) -> None:
    kinds = tuple(kinds)
    found = ds.attrs.get("lidarcal_artefact")
    if found is not None and found not in kinds:
        raise InputError(
            f"{_label(role, ds)}: is a {found!r} artefact; expected {' or '.join(map(repr, kinds))}"
        )


# ------------------------------------------------------------------ building


def _provenance(role: str, ds: xr.Dataset) -> dict[str, Any]:
    return {"role": role, **_provenance_record(ds.attrs)}


def _provenance_record(attrs: Mapping[str, Any]) -> dict[str, Any]:
    def json_attr(name):
        value = attrs.get(name)
        if isinstance(value, str):
            try:
                return json.loads(value)
            except ValueError:
                return value
        return value

    return {
        "kind": attrs.get("lidarcal_artefact"),
        "file": attrs.get("lidarcal_source_file"),
        "sha256": attrs.get("lidarcal_source_sha256"),
        "id": attrs.get("id"),
        "lidarcal_version": attrs.get("lidarcal_version"),
        "inputs": json_attr("lidarcal_inputs"),
        "config": json_attr("lidarcal_config"),
        "seeds": json_attr("lidarcal_seeds"),
        "history": attrs.get("history"),
    }


#: Prefix of the variables holding each certificate input's global attributes.
PROVENANCE_PREFIX = "provenance_"
#: The container variable's own attributes (not the input's).
_CONTAINER_OWN = ("long_name", "coverage_content_type", "units", "lidarcal_sha256")
#: Attribute names CF or xarray give a meaning on a variable: an input's global attribute of
#: that name is stored on its container as ``global_<name>``.
_VARIABLE_RESERVED = frozenset({
    "Conventions", "featureType", "external_variables", "_FillValue", "missing_value", "units", "calendar",
    "coordinates", "scale_factor", "add_offset", "dtype", "bounds", "grid_mapping", "cell_methods",
    "cell_measures", "ancillary_variables", "standard_name", "long_name", "valid_min", "valid_max",
    "valid_range", "flag_values", "flag_masks", "flag_meanings", "compress", "formula_terms", "positive",
    "axis", "climatology", "coverage_content_type", "lidarcal_sha256", "_Unsigned", "_Encoding",
})
#: The attributes of a non-component input (the records) kept on its container: its chain entry.
_CHAIN_ATTRS = ("lidarcal_artefact", "lidarcal_source_file", "lidarcal_source_sha256", "id",
                "lidarcal_version",
                "lidarcal_inputs", "lidarcal_config", "lidarcal_seeds", "history")


def _netcdf_attr(value: Any) -> Any:
    """Return ``value`` if netCDF stores it as it is (text, numbers, 1-D numbers), else its JSON."""
    if isinstance(value, str | np.str_):
        return str(value)
    if isinstance(value, bool | np.bool_):
        return int(value)
    if isinstance(value, int | float | np.integer | np.floating):
        return value
    arr = np.asarray(value) if isinstance(value, list | tuple | np.ndarray) else None
    if arr is not None and arr.ndim == 1 and arr.size and arr.dtype.kind in "iuf":
        return arr
    return json.dumps(jsonable(value, strict=True), sort_keys=True)


def _container(role: str, ds: xr.Dataset, *, component: bool) -> xr.DataArray:
    """Return a scalar container variable whose attributes are the input's global attributes.

    Each attribute stays a line of its own in ``ncdump -h`` (no JSON of JSON); a component keeps
    every global attribute (restored by :func:`extract_component`), the records only their
    chain entry.
    """
    keep = ds.attrs if component else {k: ds.attrs[k] for k in _CHAIN_ATTRS if k in ds.attrs}
    attrs = {(f"global_{k}" if k in _VARIABLE_RESERVED or k.startswith("global_") else k): _netcdf_attr(v)
             for k, v in keep.items() if v is not None}
    what = ("global attributes" if component
            else "provenance (file, SHA-256, inputs, configuration, seeds, history)")
    attrs["long_name"] = f"{what} of the certificate's {role} input"
    attrs["coverage_content_type"] = "auxiliaryInformation"
    attrs["units"] = "1"  # every variable has units; this one's value (0) carries no meaning
    # numeric, not a text scalar: netCDF-C/HDF5 can crash reopening a file after a scalar
    # variable-length string was read from it while another handle was open
    return xr.DataArray(np.int8(0), attrs=attrs)


def _records_summary(records: xr.Dataset) -> dict[str, Any]:
    out: dict[str, Any] = {
        "kind": records.attrs.get("lidarcal_artefact"),
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
        Administrative data (:func:`lidarcal.admin.load_admin`: item, laboratory, responsible
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
    inputs: dict[str, xr.Dataset] = {"budget": budget}
    for role, ds in (("cube", cube), ("rwf", rwf), ("terms", terms)):
        if ds is not None:
            inputs[role] = ds
    for role, ds in inputs.items():
        _check_kind(role, ds, [_ROLE_KINDS[role]])
    sens_roles: dict[str, xr.Dataset] = {}
    for ds in sens:
        _check_kind("sensitivity", ds, ["sensitivity"])
        var = ds.attrs.get("environmental_variable")
        if not var:
            raise InputError(f"{_label('sensitivity', ds)}: attribute 'environmental_variable' is missing")
        role = f"sensitivity_{var}"
        if role in sens_roles:
            raise InputError(
                f"two sensitivity inputs for the same variable {var!r}: "
                f"{_label(role, sens_roles[role])} and {_label(role, ds)}"
            )
        sens_roles[role] = ds
    everything = {**inputs, **sens_roles}
    if records is not None:
        _check_kind("records", records, _RECORD_KINDS)
        everything["records"] = records
    # derived artefacts record their records input under the role "records"
    serial = _check_consistent(everything)

    parts = [_prefixed(ds, f"{role}_") for role, ds in {**inputs, **sens_roles}.items()]
    cert = xr.merge(parts, compat="no_conflicts", join="exact", combine_attrs="drop_conflicts")
    # Each input's global attributes go on a variable of their own (provenance_<role>), one
    # attribute a line in ncdump -h; the global JSON attributes only list and point to them.
    comps = []
    for role, ds in {**inputs, **sens_roles}.items():
        cert[f"{PROVENANCE_PREFIX}{role}"] = _container(role, ds, component=True)
        comps.append(
            {
                "name": role,
                "prefix": f"{role}_",
                "kind": ds.attrs.get("lidarcal_artefact"),
                "file": ds.attrs.get("lidarcal_source_file"),
                "sha256": ds.attrs.get("lidarcal_source_sha256"),
                "scalar_coordinates": _scalar_coords(ds),
                "variable": f"{PROVENANCE_PREFIX}{role}",
            }
        )
    if records is not None:
        cert[f"{PROVENANCE_PREFIX}records"] = _container("records", records, component=False)
    chain = [_provenance(role, ds) for role, ds in everything.items()]
    seeds = _chain_seeds(chain)
    pointers = [{"role": rec["role"], "kind": rec["kind"], "file": rec["file"], "sha256": rec["sha256"],
                 "variable": f"{PROVENANCE_PREFIX}{rec['role']}"} for rec in chain]
    cert.attrs = {
        "certificate_components": " ".join(c["name"] for c in comps),
        "lidarcal_components": json.dumps(jsonable(comps, strict=True), sort_keys=True),
        "lidarcal_provenance_chain": json.dumps(jsonable(pointers, strict=True), sort_keys=True),
        "budget_approach": str(budget.attrs.get("approach", "unknown")),
    }
    if (headline := headline_sentence(budget)) is not None:
        cert.attrs["expanded_uncertainty_headline"] = headline
    for key in ("monte_carlo_replicas", "monte_carlo_trials", "monte_carlo_significant_digits"):
        if key in budget.attrs:
            cert.attrs[key] = int(budget.attrs[key])
    if "numerical_flag" in budget:
        missed = not_settled(budget)
        cert.attrs["monte_carlo_not_settled"] = "; ".join(f"{z:g} m {u:g} m/s" for z, u in missed) or "none"
    if serial:
        cert.attrs["lidar_serial"] = serial
    if records is not None:
        cert.attrs["lidarcal_records_summary"] = json.dumps(jsonable(_records_summary(records), strict=True),
                                                            sort_keys=True)
    if rwf is not None and "zero_distance" in rwf:
        cert.attrs["zero_distance_m"] = float(rwf["zero_distance"])
    for key in ("bench_id", "operator", "run_id", "time_coverage_start", "time_coverage_end"):
        if cube is not None and key in cube.attrs:
            cert.attrs[f"bench_{key}" if not key.startswith("bench") else key] = str(cube.attrs[key])
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


def _with_admin(cert: xr.Dataset, admin: Mapping[str, str] | None, demonstration: bool, *,
                cube: xr.Dataset | None, records: xr.Dataset | None,
                config: Mapping[str, Any] | None) -> xr.Dataset:
    """Add ``calibration_status`` and the administrative attributes (lidarcal.admin)."""
    cube_attrs = cube.attrs if cube is not None else {}
    derived = {
        "item_serial_number": cert.attrs.get("lidar_serial"),
        "bench_id": cube_attrs.get("bench_id"),
        "bench_run_id": cube_attrs.get("run_id"),
        "bench_operator": cube_attrs.get("operator"),
        "rf_driver_calibration_reference": cube_attrs.get("rf_driver_calibration_reference"),
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
