"""The schema language is closed: a key of ``schemas/*.yaml`` is a check or a declared attribute.

A misspelt check (``allow_nans``, ``requried``) used to be written to the netCDF as an attribute
and its check lost; it is now a :class:`~lidarcal.errors.SchemaError` naming the file, the
variable and the key.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import xarray as xr
import yaml

import lidarcal.diagnose  # noqa: F401  (registers the catalogue schemas/diagnosis.yaml expands over)
from lidarcal import schema
from lidarcal.data import packaged_dir
from lidarcal.errors import InputError, SchemaError

SCHEMA_FILES = sorted(p for p in packaged_dir("schemas").iterdir() if p.name.endswith(".yaml"))


@pytest.mark.parametrize("path", SCHEMA_FILES, ids=lambda p: p.name)
def test_every_schema_file_uses_only_declared_keys(path):
    raw = yaml.safe_load(path.read_text())  # the file itself, not the loader's cached copy
    schema.check_schema_keys(raw, path.name)
    # and independently of check_schema_keys: each spec key is a check or a declared attribute
    for section in ("coordinates", "variables"):
        for name, spec in (raw.get(section) or {}).items():
            unknown = set(spec or {}) - schema._CHECK_KEYS - schema.WRITTEN_ATTRIBUTES
            assert not unknown, f"{path.name}: {section} {name!r} has unknown key(s) {sorted(unknown)}"
            unknown = set((spec or {}).get("attributes") or {}) - schema.WRITTEN_ATTRIBUTES
            assert not unknown, f"{path.name}: {section} {name!r} checks undeclared {sorted(unknown)}"
    assert schema.load_schema(raw["kind"])["kind"] == path.name[:-5]


def test_written_attributes_and_checks_overlap_only_in_units():
    assert schema.WRITTEN_ATTRIBUTES & schema._CHECK_KEYS == {"units"}


@pytest.fixture
def toy_schemas(tmp_path, monkeypatch):
    """A schema directory of our own (``toy.yaml`` written by the test), with fresh caches."""
    monkeypatch.setattr(schema, "_schema_dir", lambda: tmp_path)
    monkeypatch.setattr(schema, "_read_schema", functools.cache(schema._read_schema.__wrapped__))
    monkeypatch.setattr(schema, "load_schema", functools.cache(schema.load_schema.__wrapped__))
    (tmp_path / "conditions.yaml").write_text(
        (packaged_dir("schemas") / "conditions.yaml").read_text())

    def write(body: str, height: str = "{dims: [height], units: m}") -> None:
        (tmp_path / "toy.yaml").write_text(
            f"kind: toy\ndescription: a toy\ndims: [height]\ncoordinates:\n  height: {height}\n{body}")
        schema._read_schema.cache_clear()
        schema.load_schema.cache_clear()
    return write


@pytest.mark.parametrize("body, where, key, hint", [
    ("variables:\n  speed: {dims: [height], units: m s-1, allow_nans: true}\n",
     "variable 'speed'", "allow_nans", "allow_nan"),
    ("variables:\n  speed: {dims: [height], units: m s-1, requried: false}\n",
     "variable 'speed'", "requried", "required"),
    ("variables:\n  speed: {dims: [height], units: m s-1, longname: wind speed}\n",
     "variable 'speed'", "longname", "long_name"),
    ("variables:\n  speed: {dims: [height], units: m s-1, attributes: {standard_nam: wind_speed}}\n",
     "variable 'speed', attributes", "standard_nam", "standard_name"),
    ("variables: {}\n", "coordinate 'height'", "unit", "units"),
    ("variables: {}\ninclude:\n  - {from: conditions, only: [cnr], keep: [units, rnage]}\n",
     "include from 'conditions', keep", "rnage", "range"),
    ("variables: {}\ninclude:\n  - {from: conditions, only: [cnr], set: {allownan: true}}\n",
     "include from 'conditions', set", "allownan", "allow_nan"),
    ("variables: {}\nattribute: [lidar_serial]\n", "", "attribute", "attributes"),
])
def test_a_misspelt_key_names_the_file_the_variable_and_the_key(toy_schemas, body, where, key, hint):
    toy_schemas(body, "{dims: [height], unit: m}" if key == "unit" else "{dims: [height], units: m}")
    with pytest.raises(SchemaError) as info:
        schema.load_schema("toy")
    message = str(info.value)
    assert message.startswith(f"schema toy.yaml{', ' + where if where else ''}: unknown key {key!r}")
    assert f"did you mean {hint!r}" in message
    assert isinstance(info.value, InputError)  # callers catching InputError still see it


def test_a_misspelt_key_is_not_written_as_an_attribute(toy_schemas):
    """Writing through the schema raises; it never silently copies the typo onto the variable."""
    toy_schemas("variables:\n  speed: {dims: [height], units: m s-1, allow_nans: true, long_name: speed}\n")
    ds = xr.Dataset({"speed": ("height", np.array([1.0, np.nan]))}, coords={"height": [40.0, 80.0]})
    with pytest.raises(SchemaError, match="allow_nans"):
        schema.output_attrs("toy", "speed")
    with pytest.raises(SchemaError, match="allow_nans"):  # not taken for an undeclared variable
        schema.with_output_attrs(ds, "toy")
    toy_schemas("variables:\n  speed: {dims: [height], units: m s-1, allow_nan: true, long_name: speed}\n")
    assert schema.output_attrs("toy", "speed") == {"long_name": "speed", "units": "m s-1",
                                                   "coverage_content_type": "modelResult"}
    assert schema.load_schema("toy")["variables"]["speed"]["allow_nan"] is True


EXPAND = """variables: {}
expand:
  - over: toy_rows
    registered_by: a toy stage
    variables:
      "fit_{effect}_{name}": {dims: [height], units: "{units}", range: "{range}",
                              long_name: "fitted {parameter} ({effect})"}
"""


@pytest.fixture
def toy_catalogue(monkeypatch):
    """An empty catalogue registry of our own (the real one keeps the diagnose stage's rows)."""
    monkeypatch.setattr(schema, "_CATALOGUES", {})


def test_a_template_is_expanded_over_the_registered_rows(toy_schemas, toy_catalogue):
    toy_schemas(EXPAND)
    assert schema.catalogue_owners("toy") == ["a toy stage"]  # what `lidarcal validate` imports first
    with pytest.raises(SchemaError, match=r"toy\.yaml: expands over the catalogue 'toy_rows', which is not "
                                          r"registered \(a toy stage registers it on import\)"):
        schema.load_schema("toy")
    schema.register_catalogue("toy_rows", [
        {"effect": "gain", "name": "g", "parameter": "relative gain", "units": "1", "range": [-0.2, 0.2]},
        {"effect": "shift", "name": "dz", "parameter": "height shift", "units": "m", "range": [-3.0, 3.0]}])
    assert schema.catalogue_owners("toy") == []
    variables = schema.load_schema("toy")["variables"]
    assert variables == {"fit_gain_g": {"dims": ["height"], "units": "1", "range": [-0.2, 0.2]},
                         "fit_shift_dz": {"dims": ["height"], "units": "m", "range": [-3.0, 3.0]}}
    assert schema.output_attrs("toy", "fit_shift_dz") == {
        "long_name": "fitted height shift (shift)", "units": "m", "coverage_content_type": "modelResult"}
    # the expanded entries check like written ones: a fit outside its range is a problem
    ds = xr.Dataset({"fit_shift_dz": ("height", [4.0]), "fit_gain_g": ("height", [0.1])},
                    coords={"height": ("height", [40.0], {"units": "m"})})
    for name in ds.data_vars:
        ds[name].attrs = schema.output_attrs("toy", name)
    problems = [p for p in schema.validate_dataset(ds, "toy") if "global attribute" not in p]
    assert problems == ["variable 'fit_shift_dz' has maximum 4, above the physical range [-3.0, 3.0]"]


def test_an_expand_template_needs_every_placeholder_from_the_rows(toy_schemas, toy_catalogue):
    schema.register_catalogue("toy_rows", [{"effect": "gain", "name": "g", "units": "1", "range": [0, 1]}])
    toy_schemas(EXPAND)
    with pytest.raises(SchemaError, match=r"expand over 'toy_rows'.*needs \['parameter'\]"):
        schema.load_schema("toy")
    toy_schemas(EXPAND.replace("registered_by", "registerd_by"))
    with pytest.raises(SchemaError, match="unknown key 'registerd_by'.*did you mean 'registered_by'"):
        schema.load_schema("toy")
    toy_schemas(EXPAND.replace("long_name", "longname"))
    with pytest.raises(SchemaError, match="unknown key 'longname'"):
        schema.load_schema("toy")
    toy_schemas(EXPAND.replace("variables: {}", "variables:\n  fit_gain_g: {dims: [height]}"))
    schema.register_catalogue("toy_rows", [{"effect": "gain", "name": "g", "parameter": "gain",
                                            "units": "1", "range": [0, 1]}])
    with pytest.raises(SchemaError, match="'fit_gain_g' is declared and also expanded"):
        schema.load_schema("toy")


class _NoDuplicatesLoader(yaml.SafeLoader):
    """A YAML loader that refuses a key given twice in one mapping (PyYAML keeps the last)."""


def _no_duplicates(loader, node, deep=False):
    keys = [loader.construct_object(k, deep=deep) for k, _ in node.value]
    twice = sorted({k for k in keys if keys.count(k) > 1}, key=str)
    if twice:
        raise yaml.constructor.ConstructorError(None, None, f"key(s) {twice} given twice", node.start_mark)
    return yaml.SafeLoader.construct_mapping(loader, node, deep=deep)


_NoDuplicatesLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _no_duplicates)


@pytest.mark.parametrize("path", SCHEMA_FILES, ids=lambda p: p.name)
def test_no_schema_file_gives_a_key_twice(path):
    # PyYAML silently keeps the last of two equal keys: a second `include:` would drop the first's
    # entries without a word (it happened when two branches each added one to certificate.yaml).
    yaml.load(path.read_text(), Loader=_NoDuplicatesLoader)


def test_a_key_given_twice_is_caught():
    with pytest.raises(yaml.constructor.ConstructorError, match="given twice"):
        yaml.load("include: [a]\nvariables: {}\ninclude: [b]\n", Loader=_NoDuplicatesLoader)
