"""Tests of the shared data-model core: units, schema validation, provenance, atomic IO."""

import json

import numpy as np
import pint_xarray  # noqa: F401  (registers the .pint accessor)
import pytest
import xarray as xr
from analysis_factories import var_attrs

from lidarcal.cf import height_coord, time_coord
from lidarcal.compliance import check_compliance
from lidarcal.diagnose import EFFECTS  # registers the catalogue schemas/diagnosis.yaml expands over
from lidarcal.errors import InputError, OutputExistsError, UnitError, ValidationError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.provenance import sha256, stamp
from lidarcal.schema import list_kinds, load_schema, validate_dataset
from lidarcal.units import Q_, cf_units, convert_values, to_magnitude, ureg


def make_conditions(n=4, heights=(40.0, 80.0), seed=0):
    rng = np.random.default_rng(seed)
    shape = (n, len(heights))
    ds = xr.Dataset(
        {
            "wind_speed": (("time", "height"), rng.uniform(4, 12, shape),
                           var_attrs("wind speed", "m s-1", "wind_speed")),
            "wind_from_direction": (("time", "height"), rng.uniform(0, 360, shape),
                                    var_attrs("wind direction", "degree", "wind_from_direction")),
            "turbulence_intensity": (("time", "height"), rng.uniform(0.05, 0.2, shape), var_attrs("TI", "1")),
            "wind_shear_exponent": (("time", "height"), rng.uniform(0, 0.3, shape), var_attrs("shear", "1")),
            "cnr": (("time", "height"), rng.uniform(-25, -10, shape), var_attrs("CNR", "dB")),
            "cnr_gradient": (("time", "height"), rng.uniform(-0.05, 0.05, shape),
                             var_attrs("CNR gradient", "dB m-1")),
        },
        coords={"time": time_coord(np.arange(n) * np.timedelta64(600, "s") + np.datetime64("2024-01-01")),
                "height": height_coord(heights)},
    )
    return ds


def test_unit_conversion_knots_and_refusal():
    # 1 knot = 1852 m / 3600 s exactly
    np.testing.assert_allclose(convert_values([10.0], "knot", "m s-1", where="f"), [10 * 1852 / 3600])
    with pytest.raises(UnitError, match=r"conditions.nc: variable 'wind_speed' has units 'K'.*m s-1"):
        convert_values([1.0], "K", "m s-1", where="conditions.nc: variable 'wind_speed'")
    with pytest.raises(UnitError, match="no 'units' attribute"):
        convert_values([1.0], None, "m s-1", where="x")
    with pytest.raises(UnitError, match="expected 'dB'"):
        convert_values([1.0], "W", "dB", where="x")
    assert convert_values([-20.0], "dB", "dB", where="x")[0] == -20.0


def test_to_magnitude_refuses_bare_numbers():
    assert to_magnitude(Q_(0.45, "m"), "m", name="dz") == pytest.approx(0.45)
    assert to_magnitude("1 km", "m", name="z") == pytest.approx(1000.0)
    assert to_magnitude(0.2, "1", name="alpha") == 0.2
    with pytest.raises(UnitError, match="argument 'z'"):
        to_magnitude(100.0, "m", name="z")


def test_registry_reads_and_writes_udunits_spellings():
    # pint-xarray with lidarcal's registry parses the artefacts' UDUNITS strings, and cf_units
    # spells the parsed units back exactly as the schemas declare them
    q = make_conditions().pint.quantify(unit_registry=ureg)
    assert q.wind_speed.data.units == ureg.Unit("m/s")
    assert float(q.wind_speed[0, 0].data.to("km/h").magnitude) == pytest.approx(
        3.6 * float(q.wind_speed[0, 0].data.magnitude)
    )
    names = ("wind_from_direction", "cnr_gradient", "wind_speed")
    spelled = {name: cf_units(q[name].data.units) for name in names}
    assert spelled == {"wind_from_direction": "degree", "cnr_gradient": "dB m-1", "wind_speed": "m s-1"}


def test_validator_reports_every_problem_at_once():
    ds = make_conditions()
    ds = ds.drop_vars("cnr")
    ds["wind_speed"].attrs["units"] = "K"
    ds["turbulence_intensity"][0, 0] = 1.5
    ds["wind_shear_exponent"] = ds.wind_shear_exponent.transpose()
    problems = validate_dataset(ds, "conditions", source="c.nc")
    text = "\n".join(problems)
    assert len(problems) == 4, text
    assert "'cnr' is missing" in text
    assert "'wind_speed' has units 'K'" in text
    assert "maximum 1.5" in text
    assert "dims ('height', 'time')" in text
    with pytest.raises(ValidationError) as err:
        validate_dataset(ds, "conditions", source="c.nc", raise_on_error=True)
    assert err.value.problems == problems and "c.nc" in str(err.value)


def test_every_schema_is_complete():
    assert EFFECTS  # its catalogue registered, the diagnosis schema loads
    for kind in list_kinds():
        schema = load_schema(kind)
        assert schema["kind"] == kind
        for section in ("coordinates", "variables"):
            for name, spec in (schema[section] or {}).items():
                # a name template may leave dims to the exact or included names it also matches
                # (sweep's slope_{variable} matches slope_times_std, which has dims of its own)
                assert "dims" in spec or "{" in name, f"{kind}.{name} lacks dims"


def test_write_is_atomic_validated_and_refuses_overwrite(tmp_path):
    ds = stamp(make_conditions(), "conditions", title="t", summary="s", call="test")
    path = tmp_path / "c.nc"
    write_artefact(ds, path)
    with pytest.raises(OutputExistsError):
        write_artefact(ds, path)
    write_artefact(ds, path, overwrite=True)
    bad = ds.drop_vars("cnr")
    with pytest.raises(ValidationError):
        write_artefact(bad, tmp_path / "bad.nc")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.nc"]  # no partial or temp file left
    back = open_artefact(path, "conditions")
    assert back.attrs["lidarcal_source_sha256"] == sha256(path)
    xr.testing.assert_identical(back.wind_speed, ds.wind_speed)
    import netCDF4

    with netCDF4.Dataset(path) as nc:  # CF: coordinates carry no fill value; data variables do
        assert "_FillValue" not in nc["height"].ncattrs()
        assert "_FillValue" in nc["wind_speed"].ncattrs()


def test_provenance_records_inputs_and_history(tmp_path):
    src = tmp_path / "in.txt"
    src.write_text("hello")
    parent = make_conditions()
    parent.attrs["history"] = "[2020-01-01T00:00:00Z] made by hand"
    ds = stamp(make_conditions(), "conditions", title="t", summary="s", call="lidarcal x",
               inputs={"raw": src}, input_datasets={"parent": parent}, config={"a": 1}, seeds={"base": 7})
    inputs = json.loads(ds.attrs["lidarcal_inputs"])
    # SHA-256 of b"hello"
    assert inputs == [{"role": "raw", "file": "in.txt",
                       "sha256": "2cf24dba5fb0a30e26e83b2ac5b9e29e1b161e5c1fa7425e73043362938b9824"}]
    assert ds.attrs["history"].splitlines()[0] == "[2020-01-01T00:00:00Z] made by hand"
    assert "lidarcal x" in ds.attrs["history"].splitlines()[1]
    assert json.loads(ds.attrs["lidarcal_seeds"]) == {"base": 7}
    assert ds.attrs["Conventions"] == "CF-1.11, ACDD-1.3"


@pytest.mark.parametrize("content", [b"", b"CDF\x01garbage", b"\x89HDF\r\n\x1a\n" + b"\0" * 50])
def test_open_refuses_empty_and_truncated(tmp_path, content):
    path = tmp_path / "broken.nc"
    path.write_bytes(content)
    with pytest.raises(InputError, match="broken.nc"):
        open_artefact(path)


def test_truncated_real_file(tmp_path):
    ds = stamp(make_conditions(200), "conditions", title="t", summary="s", call="test")
    path = write_artefact(ds, tmp_path / "c.nc")
    data = path.read_bytes()
    cut = tmp_path / "cut.nc"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="cut.nc: not a readable netCDF"):
        open_artefact(cut)


def test_compliance_checker_real_run(tmp_path):
    ds = stamp(make_conditions(), "conditions", title="t", summary="s", call="test")
    path = write_artefact(ds, tmp_path / "c.nc")
    report = check_compliance(path)
    assert report.passed, report.failures
    # dB and dB m-1 are the documented CF exceptions
    assert sum("UDUNITS" in e for e in report.exceptions) == 2
    ds.wind_speed.attrs.pop("long_name")
    ds.wind_speed.attrs["units"] = "furlongs"
    path2 = write_artefact(ds, tmp_path / "bad.nc", validate=False)
    assert not check_compliance(path2).passed


def test_to_magnitude_log_units_are_checked_not_evaluated():
    # pint would read "0.1 dB m-1" logarithmically (1.023); lidarcal keeps the number
    assert to_magnitude("0.1 dB m-1", "dB m-1", name="g") == pytest.approx(0.1)
    assert to_magnitude("-20 dB", "dB", name="cnr") == pytest.approx(-20.0)
    with pytest.raises(UnitError, match="argument 'g' has units 'm s-1'; expected 'dB m-1'"):
        to_magnitude(Q_(0.1, "m/s"), "dB m-1", name="g")


def test_written_files_get_ordinary_permissions(tmp_path):
    import os
    import stat

    ds = stamp(make_conditions(), "conditions", title="t", summary="s", call="test")
    path = write_artefact(ds, tmp_path / "c.nc")
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


def test_schema_stackable_dims_accept_a_trailing_height_only():
    from lidarcal.schema import validate_dataset

    def dims_problems(**variables):
        ds = xr.Dataset({name: (dims, np.ones([2] * len(dims)), {"units": "m s-1"})
                         for name, dims in variables.items()},
                        attrs={"lidarcal_artefact": "uncertainty_terms"})
        return [p for p in validate_dataset(ds) if "has dims" in p]

    # uncertainty_terms declares stackable_dims [height]: stacked heights come last, as in the
    # canonical dimension order (CF 2.4), and no other dimension may be added
    assert dims_problems(total=("wind_speed",), mean_between_run_std_std=()) == []
    assert dims_problems(total=("wind_speed", "height"), mean_between_run_std_std=("height",)) == []
    assert dims_problems(total=("height", "wind_speed")) == [
        "variable 'total' has dims ('height', 'wind_speed'); expected ('wind_speed',)"]
    assert len(dims_problems(total=("wind_speed", "time"))) == 1


def test_history_records_the_command_as_typed(tmp_path, capsys):
    from lidarcal.cli import main

    out = tmp_path / "t.nc"
    assert main(["terms", "--height", "120", "-o", str(out)]) == 0
    history = open_artefact(out).attrs["history"]
    # the call given to main(), not the test runner's sys.argv
    assert f"lidarcal terms --height 120 -o {out}" in history
    assert "-m pytest" not in history and "-q" not in history.split()


def test_copying_an_opened_artefact_does_not_persist_its_source_notes(tmp_path):
    ds = stamp(make_conditions(), "conditions", title="t", summary="s", call="test")
    first = write_artefact(ds, tmp_path / "a.nc")
    opened = open_artefact(first)
    assert opened.attrs["lidarcal_source_file"] == "a.nc"
    copy = write_artefact(opened, tmp_path / "b.nc")
    import netCDF4

    with netCDF4.Dataset(copy) as nc:
        assert not [a for a in nc.ncattrs() if a.startswith("lidarcal_source_")]
    assert open_artefact(copy).attrs["lidarcal_source_file"] == "b.nc"
    assert opened.attrs["lidarcal_source_file"] == "a.nc"  # the caller's dataset is untouched
