"""The certificate's flat layout, both ways: components and provenance in one netCDF file.

A certificate holds each component (budget, bench cube, RWF, Table 4 terms, one sensitivity per
variable) with every variable, coordinate and dimension renamed with a prefix
(``budget_uncertainty``, ``cube_los_bias``, ``sensitivity_cnr_slope`` ...), so that plain netCDF
tools read it without groups: :func:`prefixed` flattens a component, :func:`extract_component`
gives it back as the Dataset it was.  Each input's global attributes are the attributes of a
scalar variable ``provenance_<role>`` (:func:`provenance_container`), one short attribute each, so
that ``ncdump -h`` reads as text; :func:`components`, :func:`container_attributes` and
:func:`provenance_chain` read them back (and the earlier layout, where they were JSON inside the
global attributes ``lidarcal_components`` and ``lidarcal_provenance_chain``).
:func:`open_certificate` checks the seal and opens the file as a DataTree, one group per component.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate.seal import invalid_seal_banner, require_valid_seal
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, read_image
from lidarcal.provenance import jsonable, read_json_attr
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs
from lidarcal.units import register_units

__all__ = [
    "PROVENANCE_PREFIX",
    "prefixed",
    "scalar_coords",
    "extract_component",
    "components",
    "container_attributes",
    "provenance_chain",
    "provenance_record",
    "provenance_container",
    "records_summary",
    "open_certificate",
]

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



def prefixed(ds: xr.Dataset, prefix: str) -> xr.Dataset:
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
    return out.reset_coords(scalar_coords(out))


def _renamed_cell_methods(text: str, rename: Mapping[str, str]) -> str:
    """``cell_methods`` with the dimension names (``los: cnr: velocity: mean``) renamed (CF §7.3)."""
    return " ".join(f"{rename.get(t[:-1], t[:-1])}:" if t.endswith(":") else t for t in str(text).split())


def scalar_coords(ds: xr.Dataset) -> list[str]:
    """Names of the scalar coordinates of ``ds`` (stored as data variables in the flat file)."""
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
            rec = {**provenance_record(attrs), "role": rec.get("role"), "kind": rec.get("kind"),
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

    The seal is checked first (:func:`lidarcal.certificate.seal.require_valid_seal`); with
    ``allow_invalid`` an altered certificate is opened anyway, its problems listed in the root attribute
    ``lidarcal_seal_problems``.

    Raises
    ------
    InputError
        If ``path`` is missing, unreadable or not a lidarcal certificate.
    SealError
        If its seal does not match its contents (unless ``allow_invalid``).
    """
    register_units()
    # the seal first, from the file's bytes (lidarcal.io.open_image): no handle of this file is
    # open yet, and one a caller holds elsewhere is never touched; InputError for a file that
    # is not a certificate
    seal = require_valid_seal(path, allow_invalid=allow_invalid)
    # read from memory too: a lazy (chunks) tree keeps its handle, which must not share the
    # file with one the caller holds; a certificate is small: loaded, values an analyst can .item()
    ds = open_artefact(path, load=chunks is None, chunks=chunks, image=read_image(path, "certificate file"))
    nodes: dict[str, xr.Dataset] = {"/": xr.Dataset(attrs=dict(ds.attrs))}
    nodes["/"].encoding["source"] = str(path)  # the file whose seal readers (result_table) check
    if seal is not None and not seal.ok:
        nodes["/"].attrs["lidarcal_seal_problems"] = invalid_seal_banner(seal)
    for comp in components(ds):
        nodes[f"/{comp['name']}"] = extract_component(ds, comp["name"])
    return xr.DataTree.from_dict(nodes)


def provenance_record(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """Return an input's provenance (kind, file, SHA-256, id, version, inputs, config, seeds, history)."""
    def json_attr(name):
        value = attrs.get(name)
        if isinstance(value, str):
            try:
                return json.loads(value)
            except ValueError:
                return value
        return value

    return {
        "kind": read_attr(attrs, "lidarcal_artefact"),
        "file": read_attr(attrs, "lidarcal_source_file"),
        "sha256": read_attr(attrs, "lidarcal_source_sha256"),
        "id": attrs.get("id"),
        "lidarcal_version": attrs.get("lidarcal_version"),
        "inputs": json_attr("lidarcal_inputs"),
        "config": json_attr("lidarcal_config"),
        "seeds": json_attr("lidarcal_seeds"),
        "history": attrs.get("history"),
    }



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


def provenance_container(role: str, ds: xr.Dataset, *, component: bool) -> xr.DataArray:
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
    attrs.update(output_attrs("certificate", f"{PROVENANCE_PREFIX}{role}", what=what))
    # numeric, not a text scalar: netCDF-C/HDF5 can crash reopening a file after a scalar
    # variable-length string was read from it while another handle was open
    return xr.DataArray(np.int8(0), attrs=attrs)

