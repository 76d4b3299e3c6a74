"""The global attributes lidarcal reads back: declared in the schemas, read only through read_attr."""

import ast
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml

from lidarcal.errors import InputError, SchemaError
from lidarcal.lidar.attributes import LIDAR_DEFAULTS
from lidarcal.readback import UndeclaredAttribute, declared_read_back, read_attr, read_back_names
from lidarcal.schema import READ_BACK_TYPES, check_schema_keys, list_kinds

PACKAGE = Path(__file__).resolve().parents[1] / "lidarcal"

#: Bare reads of a declared name that are not read-backs of an artefact, each with its reason.
NOT_READ_BACK = {
    # schema.py is below readback (readback reads the schemas): the validator reads the kind itself
    ("schema.py", "lidarcal_artefact"),
    # source_name is the root of every message's file name (read_attr's errors use it)
    ("readback.py", "lidarcal_source_file"),
    # cli/table.py prints an in-memory pandas table (certificate.results builds it), not an artefact
    ("cli/table.py", "coverage_factor"),
    # provenance.stamp reads the attributes it is writing (the serial it has just been given)
    ("provenance.py", "lidar_serial"),
    # read_attr itself: the kind the artefact says it is selects the declaration
    ("readback.py", "lidarcal_artefact"),
}


def _calls():
    """Every ``read_attr(obj, "name", kind=...)`` call in the package: (file, line, name, kind)."""
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "read_attr":
                name = node.args[1]
                kind = next((k.value for k in node.keywords if k.arg == "kind"), None)
                rel = str(path.relative_to(PACKAGE))
                if not isinstance(name, ast.Constant):  # the lidar_* loop: LIDAR_DEFAULTS' names
                    assert rel == "lidar/attributes.py", f"{rel}:{node.lineno}: read_attr's name is a literal"
                    for key in LIDAR_DEFAULTS:
                        yield rel, node.lineno, key, "conditions"
                    continue
                yield rel, node.lineno, name.value, kind.value if isinstance(kind, ast.Constant) else None


def _bare_reads(names):
    """``x.attrs.get("name")``, ``x.attrs["name"]`` and ``attrs.get("name")`` reads of declared names."""
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = str(path.relative_to(PACKAGE))
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            target = key = None
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr == "get" and node.args and isinstance(node.args[0], ast.Constant)):
                target, key = node.func.value, node.args[0].value
            elif (isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load)
                  and isinstance(node.slice, ast.Constant)):
                target, key = node.value, node.slice.value
            is_attrs = (isinstance(target, ast.Attribute) and target.attr == "attrs") or (
                isinstance(target, ast.Name) and target.id == "attrs")
            if is_attrs and key in names and (rel, key) not in NOT_READ_BACK:
                yield f"{rel}:{node.lineno}: {key!r}"


def test_every_name_read_back_is_declared_by_the_kind_it_names():
    declared = read_back_names()
    calls = list(_calls())
    assert len(calls) > 60  # the read-backs of the whole package go through here
    problems = [f"{f}:{line}: {name!r} is not declared" for f, line, name, _ in calls
                if name not in declared]
    problems += [f"{f}:{line}: schemas/{kind}.yaml does not declare {name!r}"
                 for f, line, name, kind in calls
                 if kind is not None and name in declared and kind not in declared[name]]
    assert not problems, "\n".join(problems)
    # and every declared name is read somewhere (a declaration nobody reads is stale)
    assert sorted(set(declared) - {name for _, _, name, _ in calls}) == []


def test_no_declared_name_is_read_by_a_bare_string():
    found = list(_bare_reads(set(read_back_names())))
    assert not found, "read these through lidarcal.readback.read_attr:\n" + "\n".join(found)


def test_a_misspelt_or_foreign_name_is_refused():
    with pytest.raises(UndeclaredAttribute, match=r"no schema declares the read-back global attribute "
                                                 r"'coverage_fctor'"):
        read_attr({"coverage_fctor": 2.0}, "coverage_fctor")
    with pytest.raises(UndeclaredAttribute, match=r"schemas/rwf.yaml declares no read-back attribute "
                                                 r"'coverage_factor'"):
        read_attr({}, "coverage_factor", kind="rwf")
    # two kinds declare it with different defaults (a certificate older than the rule reads 2)
    with pytest.raises(UndeclaredAttribute, match="declared differently"):
        read_attr({}, "monte_carlo_significant_digits")


def test_a_misspelt_key_of_a_read_back_entry_fails_when_the_schema_loads():
    schema = {"read_back": {"coverage_factor": {"type": "float", "defualt": 2.0, "description": "k"}}}
    with pytest.raises(SchemaError, match=r"x.yaml, read_back 'coverage_factor': unknown key 'defualt' "
                                          r"\(did you mean 'default'\?\)"):
        check_schema_keys(schema, "x.yaml")
    schema = {"read_back": {"coverage_factor": {"type": "real", "description": "k"}}}
    with pytest.raises(SchemaError, match="needs a 'description' and a 'type'.*found type 'real'"):
        check_schema_keys(schema, "x.yaml")


def test_every_schema_file_and_fragment_is_in_the_closed_language():
    root = PACKAGE.parent / "schemas"
    for path in [*root.glob("*.yaml"), *root.glob("shared/*.yaml")]:
        check_schema_keys(yaml.safe_load(path.read_text()), path.name)  # raises on an unknown key
    for kind in list_kinds():
        for name, spec in declared_read_back(kind).items():
            assert spec["description"] and spec["type"] in READ_BACK_TYPES, (kind, name)


def test_required_read_backs_are_required_global_attributes_too():
    """The validator (``attributes:``) and read_attr agree on what an artefact must carry."""
    for kind in list_kinds():
        raw = yaml.safe_load((PACKAGE.parent / "schemas" / f"{kind}.yaml").read_text())
        required = {n for n, s in declared_read_back(kind).items() if s.get("required")}
        assert required <= set(raw.get("attributes") or []), kind


def test_missing_required_and_malformed_values_name_file_attribute_expected_and_found(tmp_path):
    path = tmp_path / "cube_without_run.nc"
    xr.Dataset(attrs={"lidarcal_artefact": "bench_cube", "operator": "A"}).to_netcdf(path)
    with xr.open_dataset(path) as ds:
        with pytest.raises(InputError, match=rf"{path}: global attribute 'run_id' \(identifier of the "
                                             r"bench run\) is missing; expected text \(a bench_cube"):
            read_attr(ds, "run_id", kind="bench_cube")
        assert read_attr(ds, "operator", kind="bench_cube") == "A"
    path = tmp_path / "site.nc"
    xr.Dataset(attrs={"lidar_hybrid_weight": "two thirds", "lidar_cone_angle": 0.0,
                      "lidarcal_skipped_count": 2.5}).to_netcdf(path)
    with xr.open_dataset(path) as ds:
        with pytest.raises(InputError, match=rf"{path}: global attribute 'lidar_hybrid_weight' \(hybrid "
                                             r"weight p\) is 'two thirds'; expected a value in \[0, 1\]"):
            read_attr(ds, "lidar_hybrid_weight", kind="conditions")
        # the cone angle's lower end is excluded: (0, 90]
        with pytest.raises(InputError, match=r"'lidar_cone_angle' .* is 0\.0; expected a value in "
                                             r"\(0, 90\]"):
            read_attr(ds, "lidar_cone_angle", kind="conditions")
        with pytest.raises(InputError, match=r"'lidarcal_skipped_count' .* is 2\.5; expected an integer"):
            read_attr(ds, "lidarcal_skipped_count", kind="conditions")


def test_values_are_converted_to_the_declared_type():
    attrs = {"coverage_factor": np.float32(2.5), "monte_carlo_replicas": np.int32(12),
             "certified_range_m_s": np.array([3.0, 17.0]), "approach": np.str_("monte_carlo")}
    k = read_attr(attrs, "coverage_factor", kind="uncertainty_budget")
    n = read_attr(attrs, "monte_carlo_replicas", kind="uncertainty_budget")
    assert (type(k), k) == (float, 2.5) and (type(n), n) == (int, 12)
    assert read_attr(attrs, "certified_range_m_s", kind="uncertainty_budget") == (3.0, 17.0)
    assert type(read_attr(attrs, "approach", kind="uncertainty_budget")) is str
    # the declared defaults: the ones the bare reads used (k = 2, 4-16 m/s)
    assert read_attr({}, "coverage_factor", kind="uncertainty_budget") == 2.0
    assert read_attr({}, "certified_range_m_s", kind="uncertainty_budget") == (4.0, 16.0)
    assert read_attr({}, "monte_carlo_significant_digits", kind="certificate") == 2
    assert read_attr({}, "monte_carlo_significant_digits", kind="uncertainty_budget") is None
    with pytest.raises(InputError, match=r"'certified_range_m_s' .* expected two numbers lo <= hi"):
        read_attr({"certified_range_m_s": [16.0, 4.0]}, "certified_range_m_s", kind="uncertainty_budget")


def test_declared_certified_range_default_is_the_rules():
    from lidarcal.analysis.certification import DEFAULT_CERTIFIED_RANGE

    assert read_attr({}, "certified_range_m_s", kind="uncertainty_budget") == DEFAULT_CERTIFIED_RANGE


def test_legacy_and_absent_values_are_mapped_at_the_edge():
    legacy = {"lidar_serial_number": "WLS7-164"}
    assert read_attr(legacy, "lidar_serial", kind="uncertainty_budget") == "WLS7-164"
    assert read_attr({"lidar_serial": "", "lidar_serial_number": "A"}, "lidar_serial") == "A"
    assert read_attr({"lidar_serial": ""}, "lidar_serial") is None
    assert read_attr({"lidar_cnr_threshold": "Not Given"}, "lidar_cnr_threshold") is None
    assert read_attr({"lidar_cnr_threshold": np.float64(-22.0)}, "lidar_cnr_threshold") == -22.0


def test_an_include_copies_the_declaration_it_names():
    """lidar_serial is declared once (bench_cube) and included, legacy name and all, where it is read."""
    source = declared_read_back("bench_cube")["lidar_serial"]
    for kind in read_back_names()["lidar_serial"]:
        assert declared_read_back(kind)["lidar_serial"] == source, kind
    for kind in list_kinds():  # the provenance fragment belongs to every kind
        assert {"lidarcal_artefact", "lidarcal_source_file", "lidarcal_source_sha256"} <= set(
            declared_read_back(kind)), kind
