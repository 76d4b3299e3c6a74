"""One declaration per concept: the conditions variables, the effect catalogue, the lidar defaults.

The six conditions variables and the measured pair are declared once (``schemas/conditions.yaml``,
``schemas/field_campaign.yaml``); every other schema copies them with ``include`` and every module
takes its tables from :mod:`lidarcal.conditions.variables`.  These tests fail when a copy drifts.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest

import lidarcal
import lidarcal.diagnose  # noqa: F401  (registers the catalogue schemas/diagnosis.yaml expands over)
from lidarcal.conditions import variables
from lidarcal.errors import InputError
from lidarcal.schema import _included, _read_schema, declared_variables, list_kinds, load_schema

#: The contract as docs/contracts.md states it (written out here, independently of the YAML).
CONTRACT_UNITS = {
    "wind_speed": "m s-1",
    "wind_from_direction": "degree",
    "turbulence_intensity": "1",
    "wind_shear_exponent": "1",
    "cnr": "dB",
    "cnr_gradient": "dB m-1",
    "lidar_wind_speed": "m s-1",
    "reference_wind_speed": "m s-1",
}
#: Schemas whose own spec of a same-named variable is another quantity: the bench's CNR setting
#: (a bench-grid coordinate, -40 ... 10 dB), and the wind-speed axis of the Table 4 / budget
#: tables and of the comparison's budgets (column speeds up to 100 m s-1), not the conditions'
#: 10-minute mean.
OTHER_QUANTITY = {("bench_cube", "cnr"), ("repeatability", "cnr"), ("uncertainty_budget", "wind_speed"),
                  ("uncertainty_terms", "wind_speed"), ("comparison", "wind_speed")}
PACKAGE = Path(lidarcal.__file__).parent


def test_registry_is_the_contract():
    assert variables.CONDITION_NAMES == tuple(list(CONTRACT_UNITS)[:6])
    assert variables.FIELD_NAMES == ("lidar_wind_speed", "reference_wind_speed")
    assert variables.CANONICAL_UNITS == CONTRACT_UNITS
    assert variables.STANDARD_NAMES == {
        "wind_speed": "wind_speed", "wind_from_direction": "wind_from_direction",
        "lidar_wind_speed": "wind_speed", "reference_wind_speed": "wind_speed"}
    for v in {**variables.CONDITIONS, **variables.FIELD_PAIR}.values():
        assert v.long_name.strip()


def _registry_name(name: str) -> str | None:
    """The registry variable a schema entry is named after (``cnr_bin_mean`` -> ``cnr``), or None."""
    for n in sorted(CONTRACT_UNITS, key=len, reverse=True):
        if re.fullmatch(rf"(max_deviation_)?{n}(_bin_(lower|upper|mean))?", name):
            return n
    return None


@pytest.mark.parametrize("kind", list_kinds())
def test_every_schema_agrees_with_the_registry(kind):
    schema = load_schema(kind)
    for section in ("coordinates", "variables"):
        for name, spec in schema[section].items():
            base = _registry_name(name)
            if base is None or (kind, name) in OTHER_QUANTITY:
                continue
            assert spec.get("units") == CONTRACT_UNITS[base], (kind, name, spec)
            std = (spec.get("attributes") or {}).get("standard_name")
            assert std in (None, variables.STANDARD_NAMES.get(base)), (kind, name, std)


@pytest.mark.parametrize("kind", sorted(set(list_kinds()) - {"conditions", "field_campaign"}))
def test_no_schema_redeclares_a_registry_variable(kind):
    """Outside the two declaring schemas a registry variable's unit is written only via include."""
    raw = _read_schema(kind)
    for section in ("coordinates", "variables"):
        for name, spec in (raw.get(section) or {}).items():
            if _registry_name(name) and (kind, name) not in OTHER_QUANTITY:
                assert "units" not in (spec or {}), f"{kind}.yaml re-declares the units of {name!r}"


def test_schemas_that_carry_the_conditions_include_all_six():
    for kind in ("field_campaign", "simulated_rtd"):
        assert set(variables.CONDITION_NAMES) <= set(load_schema(kind)["variables"])
    diag = load_schema("diagnosis")["variables"]
    sweep = load_schema("sweep")
    for n in variables.CONDITION_NAMES:
        assert {f"{n}_bin_lower", f"{n}_bin_upper", f"{n}_bin_mean"} <= set(diag)
        assert sweep["coordinates"][n]["dims"] == [n]
        assert sweep["variables"][f"max_deviation_{n}"] == {"units": CONTRACT_UNITS[n], "dims": ["height"]}
    # an override written in the including schema wins over the copy, the rest is kept
    assert load_schema("simulated_rtd")["variables"]["wind_from_direction"] == {
        "dims": ["time", "height"], "units": "degree", "allow_nan": True, "range": [0, 360]}
    assert "convertible" not in load_schema("simulated_rtd")["variables"]["wind_speed"]
    assert load_schema("field_campaign")["variables"]["cnr"]["convertible"] is True


def test_module_tables_come_from_the_registry():
    from lidarcal.analysis.sweep import SWEEP_VARIABLES
    from lidarcal.campaign.chunks import INPUTS

    assert variables.CANONICAL_UNITS == CONTRACT_UNITS
    assert tuple(INPUTS) == variables.CONDITION_NAMES
    assert sorted(SWEEP_VARIABLES) == sorted(variables.CONDITION_NAMES)


def test_synthetic_conditions_carry_the_declared_attributes():
    import numpy as np

    from lidarcal.conditions import conditions_dataset

    ds = conditions_dataset(np.array(["2024-01-01T00:00"], "datetime64[ns]"), [40.0, 80.0],
                            {n: np.zeros((1, 2)) for n in variables.CONDITION_NAMES})
    for n, v in variables.CONDITIONS.items():
        assert ds[n].attrs["units"] == v.units
        assert ds[n].attrs["long_name"] == v.long_name
        assert ds[n].attrs.get("standard_name") == v.standard_name


def test_diagnosis_schema_fit_entries_match_the_effect_catalogue():
    from lidarcal.diagnose.effects import EFFECTS

    schema = load_schema("diagnosis")["variables"]
    in_schema = {name for name in schema if name.startswith("fit_")}
    expected = set()
    for eid, effect in EFFECTS.items():
        for p in effect.parameters:
            base = f"fit_{eid}_{p.name}"
            names = (base, f"{base}_stderr", f"{base}_nominal", f"{base}_lower", f"{base}_upper")
            expected |= set(names)
            for name in names:
                assert schema[name]["units"] == p.units, name
                assert schema[name].get("required") is False, name  # only the fitted candidates are written
            assert tuple(schema[base]["range"]) == p.bounds, base  # fits are clipped to the bounds
    # every schema entry names an effect and a parameter of the catalogue, and vice versa
    assert in_schema == expected
    # expanded from one template per variable, the entries are those written out by hand before
    # (schemas/diagnosis.yaml at d0ee482, copied here)
    assert schema["fit_beam_angle_offset_offset"] == {"required": False, "dims": [], "units": "degree",
                                                      "range": [-3.0, 3.0]}
    assert schema["fit_reference_gain_gain_stderr"] == {"required": False, "dims": [], "units": "1",
                                                        "allow_nan": True, "range": [0, None]}
    assert declared_variables("diagnosis")["fit_reference_flow_distortion_width_upper"]["long_name"] == (
        "upper limit of the 95 % block-bootstrap interval of fitted full width of the shadowed sector "
        "(reference_flow_distortion)")
    # a constant reference gain acts through no condition; every other effect names its drivers
    assert all((e.drivers or eid == "reference_gain") and set(e.drivers) <= set(variables.CONDITION_NAMES)
               for eid, e in EFFECTS.items() if eid != "none")


def test_include_errors_name_the_schema_and_what_is_wrong():
    with pytest.raises(InputError, match=r"x\.yaml.*names \['nope'\].*declares"):
        _included({"from": "conditions", "only": ["nope"]}, "x.yaml")
    with pytest.raises(InputError, match=r"x\.yaml.*needs 'from'"):
        _included({"only": ["cnr"]}, "x.yaml")
    with pytest.raises(InputError, match=r"x\.yaml.*'into' is 'attributes'"):
        _included({"from": "conditions", "into": "attributes"}, "x.yaml")
    with pytest.raises(InputError, match="unknown artefact kind 'nope'"):
        _included({"from": "nope"}, "x.yaml")
    into, specs = _included({"from": "conditions", "only": ["cnr"], "name": "x_{name}", "keep": ["units"],
                             "set": {"dims": ["{name}"]}}, "x.yaml")
    assert (into, specs) == ("variables", {"x_cnr": {"units": "dB", "dims": ["cnr"]}})
    assert "long_name" not in load_schema("conditions")["variables"]["cnr"]  # metadata, not a check
    assert declared_variables("conditions")["cnr"]["long_name"] == "carrier-to-noise ratio"


def test_prefix_renames_an_included_spec_and_its_dims():
    into, specs = _included({"from": "uncertainty_budget", "only": ["contribution"], "prefix": "budget_",
                             "keep": ["dims", "units"]}, "x.yaml")
    assert (into, specs) == ("variables", {"budget_contribution": {
        "dims": ["budget_wind_speed", "budget_contributor", "budget_height"], "units": "m s-1"}})
    into, specs = _included({"from": "uncertainty_budget", "into": "coordinates", "only": ["height"],
                             "prefix": "budget_"}, "x.yaml")
    assert specs["budget_height"]["dims"] == ["budget_height"] and specs["budget_height"]["units"] == "m"


def test_certificate_declares_no_budget_variable_by_hand():
    """The certificate bundles the budget as budget_<name> on budget_<dim>: it includes those specs."""
    own = set(_read_schema("certificate").get("coordinates") or {}) | set(declared_variables("certificate"))
    assert not [name for name in own if name.startswith("budget_")]
    certificate, budget = load_schema("certificate"), load_schema("uncertainty_budget")
    # written out here (not read from the YAML): the budget variables the certificate checks
    carried = ["uncertainty", "relative_uncertainty", "expanded_uncertainty", "contribution", "sample_count",
               "bin_flag", "period_count", "numerical_tolerance", "numerical_flag", "certified_statement",
               "model_form_standard_error", "model_form_sample_count", "model_form_shift"]
    for name in carried:
        spec, source = certificate["variables"][f"budget_{name}"], budget["variables"][name]
        assert spec["dims"] == [f"budget_{d}" for d in source["dims"]], name
        assert (spec.get("units"), spec.get("range")) == (source.get("units"), source.get("range")), name
    assert certificate["coordinates"]["budget_height"]["units"] == "m"


def _literals(value) -> list[tuple[str, int]]:
    """(file, line) of every numeric literal equal to ``value`` in the package's code (not docstrings)."""
    hits = []
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text())
        negated = {id(n.operand) for n in ast.walk(tree) if isinstance(n, ast.UnaryOp)
                   and isinstance(n.op, ast.USub)}  # -28.0 (a CNR) is not 28
        for node in ast.walk(tree):
            if (isinstance(node, ast.Constant) and type(node.value) in (int, float)
                    and node.value == value and id(node) not in negated):
                hits.append((str(path.relative_to(PACKAGE)), node.lineno))
    return hits


def test_lidar_defaults_and_seed_are_declared_once():
    from lidarcal.campaign import DEFAULT_BASE_SEED
    from lidarcal.diagnose import DEFAULT_SEED
    from lidarcal.lidar import DEFAULT_RWF_FWHM, LidarModel

    assert (LidarModel.cone_angle, LidarModel.hybrid_weight, DEFAULT_RWF_FWHM) == (28.0, 2.0 / 3.0, 30.0)
    assert DEFAULT_SEED == DEFAULT_BASE_SEED == 20240101  # docs/seeds.md
    assert [f for f, _ in _literals(20240101)] == ["campaign/run.py"]
    # the lidar defaults are declared in schemas/conditions.yaml (read_back) and nowhere in code:
    # 28° appears only as Table 4's printed input (a paper value, not a default), 2/3 nowhere
    from lidarcal.readback import declared_read_back

    declared = declared_read_back("conditions")
    assert declared["lidar_cone_angle"]["default"] == LidarModel.cone_angle
    assert declared["lidar_hybrid_weight"]["default"] == LidarModel.hybrid_weight == 2.0 / 3.0
    assert sorted(f for f, _ in _literals(28.0)) == ["analysis/terms.py"]
    assert _literals(2.0 / 3.0) == []


def test_output_attrs_fill_templates_from_the_writers_context(tmp_path, monkeypatch):
    """Output metadata comes from the schema: templates, raw values, name templates, checks."""
    import numpy as np
    import xarray as xr

    from lidarcal import schema

    (tmp_path / "toy.yaml").write_text(
        "kind: toy\ndescription: a toy\ndims: [height]\n"
        "coordinates:\n  height: {dims: [height], units: m}\n"
        "variables:\n"
        "  slope:\n    dims: [height]\n    long_name: 'slope to {xname}'\n    units: '{slope_units}'\n"
        "    comment: '{note}'\n    coverage_factor: '{k}'\n"
        "  flag: {dims: [height], units: '1', flag_values: [0, 1], attributes: {flag_meanings: no yes}}\n"
        "  'sensitivity_{variable}': {dims: [height], units: '%', long_name: 'sensitivity to {variable}'}\n"
        "attributes: []\nprovenance: false\n")
    monkeypatch.setattr(schema, "_schema_dir", lambda: tmp_path)
    for cached in (schema._read_schema, schema.load_schema):
        cached.cache_clear()
    monkeypatch.setattr(schema, "_read_schema", functools.cache(schema._read_schema.__wrapped__))
    monkeypatch.setattr(schema, "load_schema", functools.cache(schema.load_schema.__wrapped__))
    attrs = schema.output_attrs("toy", "slope", xname="wind speed", slope_units="% (m s-1)-1", note="", k=2.0)
    assert attrs == {"long_name": "slope to wind speed", "units": "% (m s-1)-1",
                     "coverage_content_type": "modelResult", "coverage_factor": 2.0}  # empty comment left out
    assert list(attrs)[:3] == ["long_name", "units", "coverage_content_type"]
    flag = schema.output_attrs("toy", "flag")
    assert flag["flag_values"].dtype == np.int8 and flag["flag_meanings"] == "no yes"
    assert schema.output_attrs("toy", "sensitivity_cnr")["long_name"] == "sensitivity to cnr"
    with pytest.raises(KeyError, match=r"needs \['xname'"):
        schema.output_attrs("toy", "slope", slope_units="1", note="", k=1)
    with pytest.raises(InputError, match="declares no variable 'nope'"):
        schema.output_attrs("toy", "nope")
    # the validator checks every variable a name template matches, and not a templated unit
    ds = xr.Dataset({"slope": ("height", [1.0], {"units": "anything"}),
                     "flag": ("height", np.array([1], np.int8), flag),
                     "sensitivity_cnr": ("height", [1.0], {"units": "m"})},
                    coords={"height": ("height", [40.0], {"units": "m"})})
    problems = schema.validate_dataset(ds, "toy")
    assert problems == ["variable 'sensitivity_cnr' has units 'm'; expected '%'"]
    filled = schema.with_output_attrs(ds.drop_vars("slope"), "toy")
    assert filled["sensitivity_cnr"].attrs["units"] == "%"
    assert filled["sensitivity_cnr"].attrs["long_name"] == "sensitivity to cnr"


def test_an_exact_spec_wins_over_a_name_template_in_the_validator():
    """diagnosis.yaml includes cnr_bin_mean (NaN allowed: an empty bin) and describes {name}_bin_mean.

    The template carries the words; the checks of the included exact entry apply, so a diagnosis of
    a short campaign with an empty bin is valid (it was refused as 'NaN is not allowed here').
    """
    import numpy as np
    import xarray as xr

    from lidarcal.schema import output_attrs, validate_dataset

    attrs = output_attrs("diagnosis", "cnr_bin_mean", label="carrier-to-noise ratio")
    ds = xr.Dataset({"cnr_bin_mean": (("bin", "height"), np.array([[1.0], [np.nan]]), attrs)},
                    coords={"height": ("height", [80.0], {"units": "m", "standard_name": "height",
                                                         "positive": "up"})})
    problems = validate_dataset(ds, "diagnosis")
    assert not [p for p in problems if "cnr_bin_mean" in p], problems
