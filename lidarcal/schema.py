"""Declarative artefact schemas and the validator that reports every problem at once.

Each artefact kind has one YAML file in ``schemas/`` (shipped inside the package as
``lidarcal/schemas``) listing its dimensions, coordinates and variables (dims, units,
whether NaN is allowed, physical range) and its required global attributes.  The validator
never stops at the first problem: it collects them all, each naming the source, the
variable, what was expected and what was found.

A variable is declared once.  A schema that carries variables declared in another one
(the six conditions variables, the measured wind-speed pair) copies their specs with an
``include`` entry instead of repeating them::

    include:
      - from: conditions          # schema kind whose own variables are copied
        into: coordinates         # or variables (the default); coordinates copies the source's
                                  # coordinates (or, by name, its variables)
        only: [wind_speed, cnr]   # a subset (default: all its required ones, in their order)
        name: "{name}_bin_lower"  # name template (default "{name}")
        keep: [units, range]      # spec keys copied (default: all)
        set: {dims: ["{name}"]}   # keys set on every copy; "{name}" is replaced in strings
        prefix: budget_           # prefix the copied names and their dims (a bundled component)

A spec holds checks (``dims``, ``units``, ``convertible``, ``allow_nan``, ``range``,
``required``, ``attributes``) and the output metadata lidarcal writes on the variable: every
other key (``long_name``, ``standard_name``, ``comment``, ``coverage_content_type``,
``flag_values``, ``ancillary_variables`` ...) is an attribute to write, not a check, and so are
``units`` and the checked ``attributes``.  The language is closed: a written key must be one of
:data:`WRITTEN_ATTRIBUTES` (CF, ACDD and a few lidarcal settings), so a misspelt check
(``allow_nans``) is refused with a :class:`~lidarcal.errors.SchemaError` naming the file, the
variable and the key instead of being written as an attribute with its check lost.
:func:`output_attrs` turns a spec into the attributes
of a variable being written; it is the only place an artefact's variables get their long names,
units and comments, so a new output variable is one YAML entry.  Strings may be templates
filled from the writer's context (``"sensitivity slope m of the difference to {xname}"``); a
value that is one placeholder alone (``"{coverage_factor}"``) takes the context value as it is.
A variable name may be a template too (``"sensitivity_{variable}"``): it stands for every
variable whose name matches, the matched parts join the context, and the validator checks each
match that has no exact spec of its own (none is required).  A template in ``units`` or in a
checked attribute is not checked.

Keeping ``standard_name`` in an include turns it into a required ``standard_name`` attribute;
other metadata is not copied by an include.  A spec the including schema writes itself under the
same name is merged over the copy (its keys win).  ``prefix`` renames a copy and its dimensions
the way a bundle renames a component (the certificate carries the uncertainty budget's variables
as ``budget_<name>`` on ``budget_<dim>``), so the bundle declares them by including them.

A ``read_back`` section declares the global attributes lidarcal reads back from an artefact of
the kind (``type``, ``description``, and optionally ``units``, ``default``, ``required``,
``range``, ``exclusive_min``, ``absent`` values that count as missing, ``legacy`` names): the
keys are a closed set (:data:`READ_BACK_KEYS`); :mod:`lidarcal.readback` reads them.  An
``include`` entry ``into: read_back`` copies another kind's (or ``shared/<name>``'s) entries.

A schema whose variables follow a catalogue that lives in code (one ``fit_*`` set per parameter
of every diagnose effect) declares them once, as templates expanded over the catalogue's rows::

    expand:
      - over: diagnose_effect_parameters   # rows registered by the stage that owns the catalogue
        registered_by: lidarcal.diagnose   # named in the error when it is not registered
        variables:
          "fit_{effect}_{name}": {dims: [], units: "{units}", range: "{range}",
                                  long_name: "fitted {parameter} ({effect})"}

Each row (a mapping) fills every ``{placeholder}`` of the names and specs (a value that is one
placeholder alone takes the row's value as it is: a list stays a list), giving one exact entry
per row and template.  The fixed metadata stays here; the rows come from
:func:`register_catalogue`, which the owning stage calls on import (infrastructure never imports
a stage), so a new catalogue entry needs no schema edit.
"""

from __future__ import annotations

import difflib
import functools
import re
import string
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr
import yaml

from lidarcal.data import packaged_dir
from lidarcal.errors import InputError, SchemaError, ValidationError
from lidarcal.units import LOG_UNITS, parse_unit

__all__ = ["load_schema", "declared_variables", "declared_spec", "list_kinds", "validate_dataset",
           "output_attrs", "with_output_attrs", "check_schema_keys", "schema_file", "register_catalogue",
           "catalogue_owners",
           "COMMON_ATTRIBUTES", "WRITTEN_ATTRIBUTES", "READ_BACK_KEYS", "READ_BACK_TYPES"]

#: Global attributes every artefact written by lidarcal must carry.
COMMON_ATTRIBUTES = (
    "Conventions", "title", "summary", "history", "date_created", "id", "license",
    "lidarcal_artefact", "lidarcal_version", "lidarcal_software", "lidarcal_inputs",
    "lidarcal_config", "lidarcal_seeds",
)


def _schema_dir():
    """``schemas/`` as installed in the wheel, else the checkout's top-level folder."""
    return packaged_dir("schemas")


def list_kinds() -> list[str]:
    """Names of all artefact kinds that have a schema."""
    return sorted(p.name[:-5] for p in _schema_dir().iterdir() if p.name.endswith(".yaml"))


#: Keys an ``include`` entry may have.
_INCLUDE_KEYS = {"from", "into", "only", "name", "keep", "set", "prefix"}
#: Top-level keys of a schema file.
_TOP_KEYS = frozenset({"kind", "description", "provenance", "dims", "stackable_dims",
                       "units_on_every_variable", "include", "expand", "coordinates", "variables",
                       "attributes", "read_back"})
#: Keys of a ``read_back`` entry (a global attribute lidarcal reads back; :mod:`lidarcal.readback`).
READ_BACK_KEYS = frozenset({"type", "description", "units", "default", "required", "range",
                            "exclusive_min", "absent", "legacy"})
#: The types a read-back attribute may have (``range``: two numbers lo <= hi; ``json``: JSON text).
READ_BACK_TYPES = frozenset({"float", "int", "str", "range", "json"})
#: Keys an ``expand`` entry may have.
_EXPAND_KEYS = frozenset({"over", "registered_by", "variables"})
#: Catalogue name -> its rows, as registered by the stage that owns the catalogue.
_CATALOGUES: dict[str, tuple[dict[str, Any], ...]] = {}
#: Spec keys that are checks (``units`` and ``attributes`` are also written).
_CHECK_KEYS = frozenset({"dims", "units", "convertible", "allow_nan", "range", "required", "attributes"})
#: Variable attributes a spec may write (directly or under ``attributes``): CF-1.11 Appendix A's
#: attributes of data and coordinate variables, ACDD-1.3's ``coverage_content_type``, and the few
#: lidarcal attributes that record a writer's setting on the variable it shaped.  The schema language
#: is closed: a key that is neither a check nor one of these (a misspelt ``allow_nans``) is refused,
#: never written as an attribute with its check lost.  A new written attribute is one name here.
WRITTEN_ATTRIBUTES = frozenset({
    # CF-1.11 Appendix A (variable and coordinate attributes)
    "ancillary_variables", "axis", "bounds", "calendar", "cell_measures", "cell_methods", "comment",
    "flag_masks", "flag_meanings", "flag_values", "long_name", "positive", "references", "source",
    "standard_name", "units", "valid_max", "valid_min", "valid_range",
    # ACDD-1.3
    "coverage_content_type",
    # lidarcal: the setting that shaped the variable (rwf, turbulence_box, uncertainty_budget)
    "coverage_factor", "coverage_probability", "description", "fft_size", "pulse_shape", "sigma_target",
    "window_length_m", "window_std_fraction",
})
#: Attributes :func:`output_attrs` writes first, in this order (the rest follow as declared).
_LEADING_ATTRS = ("long_name", "units", "coverage_content_type", "standard_name")


def schema_file(kind: str, required: tuple[str, ...] = ("kind", "description", "dims")) -> dict[str, Any]:
    """Read ``schemas/<kind>.yaml`` as written: nothing expanded or included, every key checked.

    Its ``required`` top-level keys must be present and the kind it declares must be ``kind``
    (:func:`check_schema_keys` checks the rest); a ``shared/<name>`` fragment needs only ``kind``.
    """
    path = _schema_dir() / f"{kind}.yaml"
    if not path.is_file():
        raise InputError(f"unknown artefact kind {kind!r}; known kinds: {', '.join(list_kinds())}")
    schema = yaml.safe_load(path.read_text()) or {}
    for key in required:
        if key not in schema:
            raise SchemaError(f"schema {path.name}: missing top-level key {key!r}")
    if schema["kind"] != kind:
        raise SchemaError(f"schema {path.name}: declares kind {schema['kind']!r}")
    check_schema_keys(schema, path.name)
    return schema


@functools.cache
def _read_schema(kind: str) -> dict[str, Any]:
    """Read the YAML of ``kind`` (``expand`` entries expanded, includes not resolved) and check it."""
    path = _schema_dir() / f"{kind}.yaml"
    schema = schema_file(kind)
    if schema.get("expand"):
        variables = dict(schema.get("variables") or {})
        for entry in schema["expand"]:
            for name, spec in _expanded(entry, path.name).items():
                if name in variables:
                    raise SchemaError(f"schema {path.name}: variable {name!r} is declared and also "
                                      f"expanded over the catalogue {entry['over']!r}")
                variables[name] = spec
        schema["variables"] = variables
    return schema


def register_catalogue(name: str, rows: Iterable[Mapping[str, Any]]) -> None:
    """Give the catalogue ``name`` the ``rows`` a schema's ``expand`` entries range over.

    Called on import by the stage that owns the catalogue (``lidarcal.diagnose.effects``
    registers ``diagnose_effect_parameters``); registering again replaces the rows.
    """
    _CATALOGUES[name] = tuple(dict(row) for row in rows)
    _read_schema.cache_clear()
    load_schema.cache_clear()


def catalogue_owners(kind: str) -> list[str]:
    """Modules that register a catalogue ``kind``'s ``expand`` entries need and that is not registered.

    Their ``registered_by``: a caller that validates any kind (``lidarcal validate``), being above
    every stage, imports them; infrastructure never does.
    """
    path = _schema_dir() / f"{kind}.yaml"
    raw = yaml.safe_load(path.read_text()) if path.is_file() else None
    entries = [e for e in (raw or {}).get("expand") or [] if isinstance(e, dict)]
    return [str(e["registered_by"]) for e in entries
            if e.get("over") not in _CATALOGUES and e.get("registered_by")]


def _expand_value(value: Any, row: Mapping[str, Any], where: str) -> Any:
    """``value`` with every ``{placeholder}`` filled from ``row`` (one alone: the row's value as is)."""
    if isinstance(value, list):
        return [_expand_value(v, row, where) for v in value]
    if isinstance(value, dict):
        return {k: _expand_value(v, row, where) for k, v in value.items()}
    if not _is_template(value):
        return value
    fields = [f for _, f, _, _ in string.Formatter().parse(value) if f]
    missing = sorted(set(fields) - set(row))
    if missing:
        raise SchemaError(f"{where}: the template {value!r} needs {missing}; the catalogue's rows "
                          f"have {sorted(row)}")
    if len(fields) == 1 and value == "{" + fields[0] + "}":
        return row[fields[0]]
    return value.format_map(row)


def _expanded(entry: dict[str, Any], filename: str) -> dict[str, dict[str, Any]]:
    """Return the exact variable specs of one ``expand`` entry: every template, for every row."""
    over = entry.get("over")
    if over not in _CATALOGUES:
        owner = f" ({entry['registered_by']} registers it on import)" if entry.get("registered_by") else ""
        raise SchemaError(f"schema {filename}: expands over the catalogue {over!r}, which is not "
                          f"registered{owner}; registered: {sorted(_CATALOGUES)}")
    out: dict[str, dict[str, Any]] = {}
    for row in _CATALOGUES[over]:
        for template, spec in (entry.get("variables") or {}).items():
            where = f"schema {filename}, expand over {over!r}, variable {template!r}"
            out[_expand_value(template, row, where)] = _expand_value(dict(spec or {}), row, where)
    return out


def _unknown(key: str, allowed: frozenset[str] | set[str], where: str) -> SchemaError:
    close = difflib.get_close_matches(key, sorted(allowed), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return SchemaError(f"{where}: unknown key {key!r}{hint}; expected one of {sorted(allowed)}")


def check_schema_keys(schema: dict[str, Any], filename: str) -> None:
    """Refuse a key the schema language does not know, naming the file, the variable and the key.

    Top-level keys, the keys of every coordinate and variable spec (:data:`_CHECK_KEYS` and
    :data:`WRITTEN_ATTRIBUTES`), the names under a spec's checked ``attributes`` and an
    ``include`` entry's ``keep`` and ``set`` (checks only: an include copies checks), an
    ``expand`` entry's keys and its template specs are all closed sets.  A misspelt check would
    otherwise be written as an attribute and never checked.
    """
    for key in schema:
        if key not in _TOP_KEYS:
            raise _unknown(str(key), _TOP_KEYS, f"schema {filename}")
    spec_keys = _CHECK_KEYS | WRITTEN_ATTRIBUTES
    specs = [("coordinate", name, spec) for name, spec in (schema.get("coordinates") or {}).items()]
    specs += [("variable", name, spec) for name, spec in (schema.get("variables") or {}).items()]
    for entry in schema.get("expand") or []:
        if not isinstance(entry, dict):
            raise SchemaError(f"schema {filename}: an expand entry is a mapping; found {entry!r}")
        for key in entry:
            if key not in _EXPAND_KEYS:
                where = f"schema {filename}, expand over {entry.get('over')!r}"
                raise _unknown(str(key), _EXPAND_KEYS, where)
        specs += [("variable", name, spec) for name, spec in (entry.get("variables") or {}).items()]
    for role, name, spec in specs:
        where = f"schema {filename}, {role} {name!r}"
        if not isinstance(spec or {}, dict):
            raise SchemaError(f"{where}: expected a mapping of keys; found {spec!r}")
        for key in spec or {}:
            if key not in spec_keys:
                raise _unknown(str(key), spec_keys, where)
        checked = (spec or {}).get("attributes") or {}
        if not isinstance(checked, dict):
            raise SchemaError(f"{where}: 'attributes' must map attribute names to values; "
                              f"found {checked!r}")
        for key in checked:
            if key not in WRITTEN_ATTRIBUTES:
                raise _unknown(str(key), WRITTEN_ATTRIBUTES, f"{where}, attributes")
    for name, spec in (schema.get("read_back") or {}).items():
        where = f"schema {filename}, read_back {name!r}"
        if not isinstance(spec, dict):
            raise SchemaError(f"{where}: expected a mapping of keys; found {spec!r}")
        for key in spec:
            if key not in READ_BACK_KEYS:
                raise _unknown(str(key), READ_BACK_KEYS, where)
        if spec.get("type") not in READ_BACK_TYPES or not spec.get("description"):
            raise SchemaError(f"{where}: needs a 'description' and a 'type' in {sorted(READ_BACK_TYPES)}; "
                              f"found type {spec.get('type')!r}")
    keep_keys = _CHECK_KEYS | {"standard_name"}
    for entry in schema.get("include") or []:
        if not isinstance(entry, dict):
            raise SchemaError(f"schema {filename}: an include entry is a mapping; found {entry!r}")
        where = f"schema {filename}, include from {entry.get('from')!r}"
        for key in entry.get("keep") or []:
            if key not in keep_keys:
                raise _unknown(str(key), keep_keys, f"{where}, keep")
        for key in entry.get("set") or {}:
            if key not in _CHECK_KEYS:
                raise _unknown(str(key), _CHECK_KEYS, f"{where}, set")


def declared_variables(kind: str) -> dict[str, dict[str, Any]]:
    """Return the variable specs schema ``kind`` writes itself (not those it includes), in order."""
    return {name: dict(spec or {}) for name, spec in (_read_schema(kind).get("variables") or {}).items()}


def _substitute(value: Any, name: str) -> Any:
    if isinstance(value, str):
        return value.replace("{name}", name)
    if isinstance(value, list):
        return [_substitute(v, name) for v in value]
    if isinstance(value, dict):
        return {k: _substitute(v, name) for k, v in value.items()}
    return value


def _included(entry: dict[str, Any], where: str) -> tuple[str, dict[str, dict[str, Any]]]:
    """Resolve one ``include`` entry to (section, {name: spec})."""
    unknown = set(entry) - _INCLUDE_KEYS
    if "from" not in entry or unknown:
        raise SchemaError(f"schema {where}: include entry {entry!r} needs 'from' and may only have "
                         f"{sorted(_INCLUDE_KEYS)}; found {sorted(entry)}")
    into = entry.get("into", "variables")
    if into not in ("variables", "coordinates", "read_back"):
        raise SchemaError(f"schema {where}: include 'into' is {into!r}; "
                          "expected 'variables', 'coordinates' or 'read_back'")
    if into == "read_back":  # resolved by lidarcal.readback.declared_read_back
        return into, {}
    source = declared_variables(entry["from"])
    if into == "coordinates":  # the source's own coordinates first, then its variables
        coordinates = _read_schema(entry["from"]).get("coordinates") or {}
        source = {**source, **{name: dict(spec or {}) for name, spec in coordinates.items()}}
    only = entry.get("only", [n for n, spec in source.items() if spec.get("required", True)])
    missing = [n for n in only if n not in source]
    if missing:
        raise SchemaError(f"schema {where}: include from {entry['from']!r} names {missing}, which "
                         f"{entry['from']}.yaml does not declare; it declares {list(source)}")
    keep, out = entry.get("keep"), {}
    for name in only:
        spec = {k: v for k, v in source[name].items() if keep is None or k in keep}
        std = spec.pop("standard_name", None) if keep is not None else None
        spec = {k: v for k, v in spec.items() if k in _CHECK_KEYS}
        if std is not None:
            spec["attributes"] = {**spec.get("attributes", {}), "standard_name": std}
        prefix = entry.get("prefix", "")
        if prefix and "dims" in spec:
            spec["dims"] = [prefix + dim for dim in spec["dims"]]
        spec.update(_substitute(entry.get("set") or {}, name))
        out[prefix + entry.get("name", "{name}").replace("{name}", name)] = spec
    return into, out


@functools.cache
def load_schema(kind: str) -> dict[str, Any]:
    """Load the schema of artefact ``kind`` with its ``include`` entries resolved.

    Specs carry only checks: the metadata keys are in :func:`declared_variables` and written by
    :func:`output_attrs`.
    """
    raw = _read_schema(kind)
    schema = {k: v for k, v in raw.items() if k not in ("include", "expand", "read_back")}
    sections: dict[str, dict[str, Any]] = {"coordinates": {}, "variables": {}}
    for entry in raw.get("include") or []:
        into, specs = _included(entry, f"{kind}.yaml")
        sections.get(into, {}).update(specs)
    for section in sections:
        for name, spec in (raw.get(section) or {}).items():
            own = {k: v for k, v in (spec or {}).items() if k in _CHECK_KEYS}
            sections[section][name] = {**sections[section].get(name, {}), **own}
        if section not in raw and not sections[section]:
            raise SchemaError(f"schema {kind}.yaml: missing top-level key {section!r}")
        schema[section] = sections[section]
    return schema


def _is_template(value: Any) -> bool:
    """Tell whether ``value`` is a string with a ``{placeholder}`` (filled from context, not checked)."""
    return isinstance(value, str) and any(field for _, field, _, _ in string.Formatter().parse(value))


@functools.cache
def _name_pattern(template: str) -> re.Pattern:
    """Regex for a templated variable name: ``{x}`` becomes the named group ``x``."""
    parts = []
    for literal, field, _, _ in string.Formatter().parse(template):
        parts.append(re.escape(literal))
        if field:
            parts.append(f"(?P<{field}>.+)")
    return re.compile("".join(parts))


def declared_spec(kind: str, name: str) -> tuple[dict[str, Any], dict[str, str]]:
    """Return the spec ``kind`` writes itself for ``name`` and the parts a name template matched.

    An exact entry wins over a name template.  When ``name`` is also included from another
    schema, the ``units`` and checked ``attributes`` the include copied are written too, unless
    the own entry says them (so the grid coordinates of a sweep declare only their long name).
    """
    raw = _read_schema(kind)
    sections = [raw.get("coordinates") or {}, raw.get("variables") or {}]
    included = {**load_schema(kind)["coordinates"], **load_schema(kind)["variables"]}.get(name, {})
    inherited = {k: v for k, v in included.items() if k in ("units", "attributes")}
    for section in sections:
        if name in section:
            return {**inherited, **(section[name] or {})}, {}
    for section in sections:
        for key, spec in section.items():
            if _is_template(key) and (match := _name_pattern(key).fullmatch(name)):
                return {**inherited, **(spec or {})}, match.groupdict()
    raise InputError(f"schema {kind}.yaml declares no variable {name!r} (nor a name template matching "
                     f"it); declare it there with its long_name and units")


def _fill(value: Any, context: dict[str, Any], where: str) -> Any:
    if isinstance(value, str) and _is_template(value):
        fields = [f for _, f, _, _ in string.Formatter().parse(value) if f]
        missing = [f for f in fields if f not in context]
        if missing:
            raise KeyError(f"{where}: the template {value!r} needs {missing}; the writer gave "
                           f"{sorted(context)}")
        if value == "{" + fields[0] + "}" and len(fields) == 1:
            return context[fields[0]]  # the context value as it is (a number stays a number)
        return value.format_map(context)
    if isinstance(value, list):
        return [_fill(v, context, where) for v in value]
    return value


def output_attrs(kind: str, name: str, **context: Any) -> dict[str, Any]:
    """Return the attributes of output variable ``name`` of artefact ``kind``, from its schema.

    Every key of the variable's spec that is not a check, plus ``units`` and the checked
    ``attributes``, with templates filled from ``context`` (and from the parts of a templated
    name).  ``coverage_content_type`` defaults to ``modelResult``; ``flag_values`` become an
    ``int8`` array.  Order: long_name, units, coverage_content_type, standard_name, then the rest
    as declared.  A template that fills to ``""`` (no standard name, no comment) is left out, and so
    is a key declared ``null`` (``coverage_content_type: null``: a label coordinate that has none).
    """
    spec, parts = declared_spec(kind, name)
    context = {**parts, **context}
    declared = {k: v for k, v in spec.items() if k not in _CHECK_KEYS or k == "units"}
    declared.update(spec.get("attributes") or {})
    declared.setdefault("coverage_content_type", "modelResult")
    where = f"schema {kind}.yaml, variable {name!r}"
    filled = {key: _fill(value, context, where) for key, value in declared.items()}
    if "flag_values" in filled:
        filled["flag_values"] = np.asarray(filled["flag_values"], dtype=np.int8)
    for key in [k for k, v in declared.items()
                if (_is_template(v) and isinstance(filled[k], str) and filled[k] == "") or v is None]:
        del filled[key]  # a template that fills to nothing, or a key declared null, is left out
    return {**{k: filled.pop(k) for k in _LEADING_ATTRS if k in filled}, **filled}


def with_output_attrs(ds: xr.Dataset, kind: str, **context: Any) -> xr.Dataset:
    """``ds`` with the schema's attributes (:func:`output_attrs`) on every variable ``kind`` declares.

    Attributes already on a variable and not declared are kept; declared ones are set.  Variables
    the schema does not declare (included ones, bounds) are left as they are.
    """
    out = ds.copy(deep=False)
    for name in list(out.variables):
        try:
            attrs = output_attrs(kind, str(name), **context)
        except SchemaError:
            raise  # a malformed schema is the code's error, not an undeclared variable
        except InputError:
            continue
        out.variables[name].attrs = {**out.variables[name].attrs, **attrs}
    return out


def _unit_ok(found: str | None, spec: dict) -> str | None:
    """Return a problem description, or None when ``found`` satisfies ``spec``."""
    expected = spec.get("units")
    if expected is None or _is_template(expected):
        return None
    if found is None:
        return f"has no 'units' attribute; expected {expected!r}"
    if spec.get("convertible", False):
        if expected in LOG_UNITS:
            return None if found in LOG_UNITS[expected] else f"has units {found!r}; expected {expected!r}"
        try:
            ok = parse_unit(found, where="").dimensionality == parse_unit(expected, where="").dimensionality
        except InputError:
            ok = False
        return None if ok else f"has units {found!r}; expected units convertible to {expected!r}"
    return None if found == expected else f"has units {found!r}; expected {expected!r}"


def _dims_match(found, expected, stackable) -> bool:
    """Exact match, or ``expected`` followed only by the schema's ``stackable_dims``.

    Stacked dims (the heights of terms evaluated at several heights) are spatio-temporal, so in
    the canonical order (:func:`lidarcal.cf.canonical_dims`) they come last.
    """
    found, expected = list(found), list(expected)
    extra = len(found) - len(expected)
    if extra == 0:
        return found == expected
    return extra > 0 and found[:len(expected)] == expected and set(found[len(expected):]) <= set(stackable)


def _lazy_value_stats(ds: xr.Dataset) -> dict[str, tuple[int, float, float]]:
    """(NaN count, least and greatest non-NaN value) of every numeric variable of several dask chunks.

    All in one computation on this process, so a lazily computed artefact (``smc``: one chunk per
    block of periods) is computed once for its checks, a block at a time, whatever its length.  A
    variable of one chunk (a lazily opened file's) is read whole by the caller, as it is cheaper.
    """
    lazy = {str(n): v for n, v in ds.variables.items()
            if v.chunks is not None and v.dtype.kind in "fiu" and any(len(c) > 1 for c in v.chunks)}
    if not lazy:
        return {}
    import dask  # deferred: only for lazy datasets
    import dask.array as da

    exprs = {}
    for name, var in lazy.items():
        x = var.data.astype(float)
        nan = da.isnan(x)
        exprs[name] = (nan.sum(), da.where(nan, np.inf, x).min(), da.where(nan, -np.inf, x).max())
    (stats,) = dask.compute(exprs, scheduler="synchronous")
    return {n: (int(k), float(lo), float(hi)) for n, (k, lo, hi) in stats.items()}


def _check_variable(ds: xr.Dataset, name: str, spec: dict, role: str, problems: list[str],
                    stackable: tuple[str, ...] = (),
                    stats: Mapping[str, tuple[int, float, float]] | None = None) -> None:
    if name not in ds.variables:
        if spec.get("required", True):
            problems.append(f"{role} {name!r} is missing")
        return
    var = ds[name] if name in ds.data_vars or name in ds.coords else ds.variables[name]
    dims = spec.get("dims")
    if dims is not None and not _dims_match(var.dims, dims, stackable):
        problems.append(f"{role} {name!r} has dims {tuple(var.dims)}; expected {tuple(dims)}")
    msg = _unit_ok(var.attrs.get("units"), spec)
    if msg:
        problems.append(f"{role} {name!r} {msg}")
    for attr, value in spec.get("attributes", {}).items():
        found = var.attrs.get(attr)
        if _is_template(value) or (isinstance(found, np.ndarray) and np.array_equal(found, value)):
            continue
        if found != value:
            problems.append(f"{role} {name!r} attribute {attr!r} is {found!r}; expected {value!r}")
    kind = var.dtype.kind
    if kind not in "fiu":
        return
    if stats and name in stats:
        n_nan, least, greatest = stats[name]
    else:
        values = np.asarray(var.values, dtype=float)
        nan = np.isnan(values)
        n_nan = int(nan.sum())
        least, greatest = (float(values[~nan].min()), float(values[~nan].max())) if n_nan < values.size else (
            np.inf, -np.inf)
    if not spec.get("allow_nan", False) and n_nan:
        problems.append(f"{role} {name!r} has {n_nan} NaN value(s); NaN is not allowed here")
    rng = spec.get("range")
    if rng is not None and n_nan < var.size:
        lo, hi = (float(r) if r is not None else None for r in rng)
        if lo is not None and least < lo:
            problems.append(f"{role} {name!r} has minimum {least:.6g}, "
                            f"below the physical range [{lo}, {hi}]")
        if hi is not None and greatest > hi:
            problems.append(f"{role} {name!r} has maximum {greatest:.6g}, "
                            f"above the physical range [{lo}, {hi}]")


def validate_dataset(
    ds: xr.Dataset,
    kind: str | None = None,
    *,
    source: str = "<dataset>",
    raise_on_error: bool = False,
    value_stats: Mapping[str, tuple[int, float, float]] | None = None,
) -> list[str]:
    """Check ``ds`` against the schema of ``kind`` (default: its ``lidarcal_artefact``).

    Returns the list of problems (empty when valid); with ``raise_on_error`` a non-empty
    list raises :class:`~lidarcal.errors.ValidationError` carrying all of them.
    ``value_stats``: variables whose values the caller has already gone through, by name: (NaN
    count, least and greatest non-NaN value) of the values ``ds`` holds (a lazily read input,
    checked block by block as it was read: not read again here).
    """
    found_kind = ds.attrs.get("lidarcal_artefact")
    kind = kind or found_kind
    problems: list[str] = []
    if kind is None:
        problems.append("global attribute 'lidarcal_artefact' is missing; cannot tell which schema applies")
    else:
        schema = load_schema(kind)
        stackable = tuple(schema.get("stackable_dims") or ())
        if found_kind is not None and found_kind != kind:
            problems.append(f"is a {found_kind!r} artefact; expected {kind!r}")
        for dim in schema["dims"]:
            if dim not in ds.dims:
                problems.append(f"dimension {dim!r} is missing; found {sorted(map(str, ds.dims))}")
        exact = {n for section in ("coordinates", "variables") for n in schema.get(section) or {}
                 if not _is_template(n)}
        known = dict(value_stats or {})
        stats = {**_lazy_value_stats(ds.drop_vars(list(known), errors="ignore")), **known}
        for section, role in (("coordinates", "coordinate"), ("variables", "variable")):
            for name, spec in (schema.get(section) or {}).items():
                if not _is_template(name):
                    _check_variable(ds, name, spec or {}, role, problems, stackable, stats)
                    continue
                for found in sorted(map(str, ds.variables)):  # a name template checks every match
                    if found not in exact and _name_pattern(name).fullmatch(found):  # exact specs win
                        _check_variable(ds, found, spec or {}, role, problems, stackable, stats)
        attrs = list(schema.get("attributes") or [])
        if schema.get("provenance", True):
            attrs = [*COMMON_ATTRIBUTES, *attrs]
        for attr in attrs:
            if attr not in ds.attrs:
                problems.append(f"global attribute {attr!r} is missing")
        if schema.get("units_on_every_variable", True):
            for name, var in ds.data_vars.items():
                if var.dtype.kind in "fiu" and "units" not in var.attrs and "flag_values" not in var.attrs:
                    problems.append(f"variable {name!r} has no 'units' attribute")
    if problems and raise_on_error:
        raise ValidationError(problems, source)
    return problems
