"""Certificate: bundling, provenance, consistency checks, sealing and `lidarcal verify`."""

import json

import netCDF4
import numpy as np
import pytest
import xarray as xr
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.analysis.terms import PAPER_INPUTS, TABLE4_WIND_SPEEDS, uncertainty_terms
from lidarcal.bench import build_cube, simulate_run
from lidarcal.certificate import (
    components,
    extract_component,
    make_certificate,
    open_certificate,
    provenance_chain,
    result_table,
)
from lidarcal.certificate.seal import integrity_record, seal_root, verify_certificate, write_certificate
from lidarcal.cli import main
from lidarcal.errors import InputError, OutputExistsError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.provenance import jsonable, sha256, stamp
from lidarcal.schema import validate_dataset

SERIAL = "WLS7-TEST"


@pytest.fixture(scope="module")
def artefact_files(tmp_path_factory):
    """A small but complete set of input files, written as the CLI would find them."""
    d = tmp_path_factory.mktemp("inputs")
    rec_path = d / "records.nc"
    make_records(n=400, lidar_serial=SERIAL).to_netcdf(rec_path)
    records = open_artefact(rec_path)
    paths = {"records": rec_path}
    paths["budget"] = write_artefact(budget(records), d / "budget.nc")
    paths["sens_shear"] = write_artefact(sensitivity(records, "wind_shear_exponent"), d / "sens_shear.nc")
    paths["sens_ti"] = write_artefact(sensitivity(records, "turbulence_intensity"), d / "sens_ti.nc")
    paths["terms"] = write_artefact(uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS), d / "terms.nc")
    run = simulate_run(seed=3, accumulation_time="20 s", lidar_serial=SERIAL)
    cube, _ = build_cube(run.rtd, run.control)
    cube = stamp(cube, "bench_cube", title="cube", summary="test cube", call="test")
    paths["cube"] = write_artefact(cube, d / "cube.nc")
    return paths


def _open(paths):
    return {
        "budget": open_artefact(paths["budget"]),
        "sensitivities": [open_artefact(paths["sens_shear"]), open_artefact(paths["sens_ti"])],
        "cube": open_artefact(paths["cube"]),
        "terms": open_artefact(paths["terms"]),
        "records": open_artefact(paths["records"]),
    }


def test_certificate_bundles_components_and_provenance(artefact_files):
    inputs = _open(artefact_files)
    cert = make_certificate(**inputs, config={"purpose": "test"})
    assert cert.attrs["lidar_serial"] == SERIAL
    assert cert.attrs["certificate_components"].split() == [
        "budget",
        "cube",
        "terms",
        "sensitivity_wind_shear_exponent",
        "sensitivity_turbulence_intensity",
    ]
    # flat prefixed names readable by any netCDF tool
    for name in (
        "budget_uncertainty",
        "cube_los_bias",
        "terms_total",
        "sensitivity_wind_shear_exponent_slope",
    ):
        assert name in cert.data_vars
    np.testing.assert_array_equal(cert.budget_uncertainty.values, inputs["budget"].uncertainty.values)
    assert cert.budget_wind_speed.attrs["bounds"] == "budget_wind_speed_bounds"
    # round trip of one component
    back = extract_component(cert, "sensitivity_wind_shear_exponent")
    xr.testing.assert_identical(back.slope, inputs["sensitivities"][0].slope)
    assert back.attrs["environmental_variable"] == "wind_shear_exponent"
    # provenance chain: every input with its file name and SHA-256, and their own inputs
    chain = {c["role"]: c for c in provenance_chain(cert)}
    # each input's own provenance is on its provenance_<role> variable, one attribute per line
    assert cert["provenance_budget"].attrs["lidarcal_source_file"] == artefact_files["budget"].name
    assert json.loads(cert["provenance_budget"].attrs["lidarcal_inputs"]) == chain["budget"]["inputs"]
    original = inputs["sensitivities"][0].attrs  # every global attribute comes back, Conventions included
    assert back.attrs == jsonable({k: v for k, v in original.items() if not k.startswith("lidarcal_source_")},
                                  strict=True) and back.attrs["Conventions"] == original["Conventions"]
    assert "global_Conventions" in cert["provenance_budget"].attrs  # CF reserves Conventions for files
    for role, key in (
        ("budget", "budget"),
        ("cube", "cube"),
        ("records", "records"),
        ("terms", "terms"),
        ("sensitivity_wind_shear_exponent", "sens_shear"),
    ):
        assert chain[role]["sha256"] == sha256(artefact_files[key])
        assert chain[role]["file"] == artefact_files[key].name
    assert [r["role"] for r in chain["budget"]["inputs"]] == ["records"]
    assert chain["budget"]["inputs"][0]["sha256"] == sha256(artefact_files["records"])
    recorded = {r["role"]: r["sha256"] for r in json.loads(cert.attrs["lidarcal_inputs"])}
    assert recorded["cube"] == sha256(artefact_files["cube"])
    assert json.loads(cert.attrs["lidarcal_config"]) == {"purpose": "test"}
    assert json.loads(cert.attrs["lidarcal_records_summary"])["periods"] == 400


def test_write_seal_verify_and_tamper(artefact_files, tmp_path):
    cert = make_certificate(**_open(artefact_files))
    path = write_certificate(cert, tmp_path / "cert.nc")
    report = verify_certificate(path)
    assert report.ok, report.problems
    with netCDF4.Dataset(path) as nc:  # never leave a handle open before writing (HDF5)
        assert report.variables_checked == len(nc.variables)
        stored = json.loads(nc.getncattr("lidarcal_integrity"))
    with pytest.raises(OutputExistsError):
        write_certificate(cert, path)
    # the record is defined on the stored bytes: recomputing gives the stored root, and each
    # variable carries its own digests (the seal reads as text in ncdump -h)
    record = integrity_record(path)
    assert stored["format"] == 2 and stored["root"] == seal_root(record)
    assert stored["variables"] == len(record["variables"]) == report.variables_checked
    with netCDF4.Dataset(path) as nc:
        digests = nc["budget_uncertainty"].getncattr("lidarcal_sha256").split()
    assert digests[1::2] == [record["variables"]["budget_uncertainty"][k] for k in ("data", "attributes")]
    # alter one value of one variable with netCDF4 directly
    with netCDF4.Dataset(path, "a") as nc:
        v = nc["budget_uncertainty"]  # (budget_wind_speed, budget_height)
        v[3, 0] = v[3, 0] + 1e-9
    report = verify_certificate(path)
    assert report.problems == ["variable 'budget_uncertainty': values altered"]
    # ... and one attribute of another, and a global attribute
    with netCDF4.Dataset(path, "a") as nc:
        nc["cube_los_bias"].setncattr("units", "km h-1")
        nc.setncattr("lidar_serial", "OTHER")
    problems = verify_certificate(path).problems
    assert "variable 'cube_los_bias': attributes altered" in problems
    assert "global attribute 'lidar_serial' altered" in problems
    assert len(problems) == 3, problems  # the cube's units are not part of the certificate schema
    # a bounds variable (whose digests sit on its parent, CF 7.1) is named too
    with netCDF4.Dataset(path, "a") as nc:
        assert "lidarcal_sha256" not in nc["budget_wind_speed_bounds"].ncattrs()
        b = nc["budget_wind_speed_bounds"]
        b[0, 0] = b[0, 0] + 0.1
    assert "variable 'budget_wind_speed_bounds': values altered" in verify_certificate(path).problems


def test_verify_cli_exit_codes(artefact_files, tmp_path, capsys):
    p = artefact_files
    out = tmp_path / "cert.nc"
    args = [
        "certificate",
        "--budget",
        str(p["budget"]),
        "--sensitivity",
        str(p["sens_shear"]),
        "--sensitivity",
        str(p["sens_ti"]),
        "--cube",
        str(p["cube"]),
        "--terms",
        str(p["terms"]),
        "--records",
        str(p["records"]),
        "-o",
        str(out),
    ]
    assert main(args) == 0
    assert main(["verify", str(out)]) == 0
    assert ": OK (" in capsys.readouterr().out
    # never overwritten silently
    before = sha256(out)
    assert main(args) == 2 and sha256(out) == before
    assert "file exists" in capsys.readouterr().err
    # the whole configuration is recorded
    with netCDF4.Dataset(out) as nc:
        cfg = json.loads(nc.getncattr("lidarcal_config"))
    assert cfg["sensitivity"] == [str(p["sens_shear"]), str(p["sens_ti"])] and cfg["overwrite"] is False
    with netCDF4.Dataset(out, "a") as nc:
        nc["sensitivity_turbulence_intensity_slope"][1] = 42.0
    assert main(["verify", str(out)]) == 1
    text = capsys.readouterr().out
    assert "ALTERED" in text and "'sensitivity_turbulence_intensity_slope': values altered" in text
    # a non-certificate file: clear error, non-zero
    assert main(["verify", str(p["budget"])]) == 2
    err = capsys.readouterr().err
    assert "budget.nc: not a lidarcal certificate: it is a 'uncertainty_budget' artefact" in err
    junk = tmp_path / "junk.nc"
    junk.write_bytes(b"not netcdf")
    assert main(["verify", str(junk)]) == 2
    assert "junk.nc: not a readable netCDF" in capsys.readouterr().err


def test_provenance_variables_take_their_metadata_from_the_schema(artefact_files):
    # the only variables a certificate writes itself: schemas/certificate.yaml declares them
    # (name template provenance_{role}), and the validator checks every one
    cert = make_certificate(**_open(artefact_files))
    own = {k: cert["provenance_sensitivity_turbulence_intensity"].attrs[k]
           for k in ("long_name", "units", "coverage_content_type")}
    assert own == {
        "long_name": "global attributes of the certificate's sensitivity_turbulence_intensity input",
        "units": "1",
        "coverage_content_type": "auxiliaryInformation",
    }
    assert cert["provenance_records"].attrs["long_name"] == (
        "provenance (file, SHA-256, inputs, configuration, seeds, history) of the certificate's "
        "records input")
    assert validate_dataset(cert, "certificate") == []
    cert["provenance_cube"].attrs["units"] = "m"
    assert validate_dataset(cert, "certificate") == ["variable 'provenance_cube' has units 'm'; expected '1'"]


def test_written_certificate_passes_validate(artefact_files, tmp_path, capsys):
    # the compliance-checker's cost grows ~quadratically with the number of variables (15 s for
    # the full bundle), so the default run checks a lean certificate that still has every
    # flattening case (bounds, string coordinate, scalar coordinate); the full one is slow-marked
    inputs = _open(artefact_files)
    lean = make_certificate(budget=inputs["budget"], sensitivities=[], terms=inputs["terms"],
                            demonstration=True)
    path = write_certificate(lean, tmp_path / "c.nc")
    assert main(["validate", str(path)]) == 0, capsys.readouterr().out


@pytest.mark.slow
def test_full_certificate_passes_validate(artefact_files, tmp_path, capsys):
    path = write_certificate(make_certificate(**_open(artefact_files)), tmp_path / "c.nc")
    assert main(["validate", str(path)]) == 0, capsys.readouterr().out


def test_inputs_that_disagree_are_refused(artefact_files, tmp_path):
    inputs = _open(artefact_files)
    other = inputs["cube"].copy()
    other.attrs["lidar_serial"] = "WLS7-9982"
    with pytest.raises(
        InputError,
        match=r"inputs disagree on the lidar: .*cube \(cube.nc\) has lidar_serial "
        r"'WLS7-9982'.*records \(records.nc\) has lidar_serial 'WLS7-TEST'",
    ):
        make_certificate(**{**inputs, "cube": other})
    # a budget computed from other records than the ones given
    rec2_path = tmp_path / "records2.nc"
    make_records(n=300, seed=9, lidar_serial=SERIAL).to_netcdf(rec2_path)
    with pytest.raises(
        InputError,
        match=r"budget \(budget.nc\) was computed from records 'records.nc'.*"
        r"but the records given is 'records2.nc'",
    ):
        make_certificate(**{**inputs, "records": open_artefact(rec2_path)})
    # wrong kinds and duplicate variables
    with pytest.raises(InputError, match="expected 'uncertainty_budget'"):
        make_certificate(**{**inputs, "budget": inputs["terms"]})
    with pytest.raises(
        InputError, match="two sensitivity inputs for the same variable 'wind_shear_exponent'"
    ):
        make_certificate(**{**inputs, "sensitivities": [inputs["sensitivities"][0]] * 2})
    # CLI: nothing written
    out = tmp_path / "cert.nc"
    rc = main(
        [
            "certificate",
            "--budget",
            str(artefact_files["budget"]),
            "--records",
            str(rec2_path),
            "-o",
            str(out),
        ]
    )
    assert rc == 2 and not out.exists()


def _earlier_layout(cert: xr.Dataset) -> xr.Dataset:
    """The layout certificates had before the short attributes: everything in two JSON attributes."""
    old = cert.drop_vars([v for v in cert.variables if str(v).startswith("provenance_")])
    comps = [{k: v for k, v in c.items() if k != "variable"} for c in components(cert)]
    chain = provenance_chain(cert)
    old.attrs["lidarcal_components"] = json.dumps(jsonable(comps, strict=True), sort_keys=True)
    old.attrs["lidarcal_provenance_chain"] = json.dumps(jsonable(chain, strict=True), sort_keys=True)
    return old


def test_certificates_of_the_earlier_layout_still_open_and_verify(artefact_files, tmp_path):
    """A certificate written before the short attributes (components and chain as JSON) reads the same."""
    cert = make_certificate(**_open(artefact_files))
    new = write_certificate(cert, tmp_path / "new.nc")
    old = write_certificate(_earlier_layout(cert), tmp_path / "old.nc")
    assert verify_certificate(old).ok and verify_certificate(new).ok
    o, n = xr.load_dataset(old), xr.load_dataset(new)
    assert len(o.attrs["lidarcal_provenance_chain"]) > 4000  # the long line the new layout avoids
    assert max(len(str(v)) for v in n.attrs.values()) <= 4000
    assert provenance_chain(o) == provenance_chain(n)
    assert [{k: v for k, v in c.items() if k != "variable"} for c in components(n)] == components(o)
    for name in ("budget", "sensitivity_wind_shear_exponent", "cube"):
        xr.testing.assert_identical(extract_component(o, name), extract_component(n, name))
    assert result_table(o).equals(result_table(n))
    assert open_certificate(old)["budget"].attrs == open_certificate(new)["budget"].attrs
