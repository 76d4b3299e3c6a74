"""What a steward reads in ten years: provenance to the raw record, contacts, CF/ACDD, pint units."""

import json
import re
import subprocess
import sys

import netCDF4
import numpy as np
import pytest
import xarray as xr

from lidarcal.certificate import provenance_chain
from lidarcal.cli import main
from lidarcal.compliance import ComplianceReport, check_compliance, exception_kind, summary_lines
from lidarcal.data import sample_file
from lidarcal.errors import InputError
from lidarcal.io import write_artefact
from lidarcal.provenance import contact, merge_history, stamp
from lidarcal.schema import declared_spec, load_schema

#: the findings the stock checker may still report, each documented in lidarcal.compliance
DOCUMENTED = {"dB", "standard_name", "time coverage", "vertical coverage"}


@pytest.fixture(scope="module")
def run_dir(short_calibration):
    """A real 48-period calibration given the contact, site and user options (tests/conftest.py)."""
    return short_calibration[0]


def _walk(records):
    for rec in records or []:
        yield rec
        yield from _walk(rec.get("inputs"))


def test_every_artefact_names_its_makers(run_dir):
    for path in sorted(run_dir.glob("*.nc")):
        with netCDF4.Dataset(path) as nc:
            attrs = {k: nc.getncattr(k) for k in nc.ncattrs()}
        assert attrs["creator_name"] == "A. Steward", path.name
        assert attrs["creator_email"] == "steward@example.org" and attrs["institution"] == "Test Lab"
        assert attrs["publisher_name"] == "Test Archive"
        assert attrs["date_issued"] == attrs["date_created"]
        assert "instrument" in attrs and "platform" in attrs
        software = json.loads(attrs["lidarcal_software"])
        assert {"python", "pandas", "distributed"} <= set(software)
        assert "coordinates" not in attrs  # CF defines no global coordinates attribute
        lines = attrs["history"].splitlines()
        assert len(lines) == len(set(lines)), path.name
        stamps = [re.match(r"\[([^\]]+)\]", line).group(1) for line in lines]
        assert stamps == sorted(stamps), path.name


def test_every_artefact_carries_the_global_attributes_lidarcal_reads_back(run_dir):
    """Each written artefact has every read-back attribute its schema declares, readable as declared.

    The exception is the conditions input: its lidar_* configuration and load stamps are optional
    (absent: the nominal lidar's defaults), so a conditions file need only read without error.
    """
    from lidarcal.io import open_artefact
    from lidarcal.readback import declared_read_back, read_attr

    kinds = set()
    for path in sorted(run_dir.glob("*.nc")):
        with open_artefact(path, load=False) as ds:
            kind = ds.attrs["lidarcal_artefact"]
            kinds.add(kind)
            declared = declared_read_back(kind)
            if kind != "conditions":
                assert sorted(set(declared) - set(ds.attrs)) == [], path.name
            for name in declared:
                read_attr(ds, name, kind=kind)  # raises InputError on a malformed value
            assert read_attr(ds, "lidarcal_source_file") == path.name
    assert {"bench_cube", "rwf", "simulated_rtd", "sensitivity", "uncertainty_terms", "uncertainty_budget",
            "certificate", "conditions"} <= kinds


def test_certificate_chain_reaches_the_raw_mast_record(run_dir):
    cert = xr.open_dataset(run_dir / "certificate.nc")
    chain = provenance_chain(cert)  # each input's own chain is on its provenance_<role> variable
    # independent reference: the packaged conditions file's own record of its source
    with netCDF4.Dataset(sample_file("conditions/conditions.nc")) as nc:
        raw_sha, raw_file = nc.getncattr("source_file_sha256"), nc.getncattr("source_file")
    found = [r for r in _walk(chain) if r.get("sha256") == raw_sha]
    assert found and found[0]["file"] == raw_file.rsplit("/", 1)[-1]
    # the record that used it names its licence and source
    holders = [r for r in _walk(chain) if any(i.get("sha256") == raw_sha for i in r.get("inputs", []))]
    assert holders and holders[0]["source_license"] == "MIT"
    # every seed of the chain at the top: the Monte Carlo base seed and the CNR model's
    seeds = json.loads(cert.attrs["lidarcal_seeds"])
    values = json.dumps(seeds)
    assert '"base_seed": 20240101' in values and '"cnr_model": 20160601' in values


#: ``ncdump -h`` prints every attribute on one line (newlines as ``\\n``): none may be longer (issue 18)
ATTRIBUTE_LIMIT = 4000


def test_every_attribute_of_a_run_reads_as_one_short_line(run_dir):
    """No global or variable attribute of any artefact of a run is over 4000 characters."""
    found = {}
    for path in sorted(run_dir.glob("*.nc")):
        with netCDF4.Dataset(path) as nc:
            items = [("", k, nc.getncattr(k)) for k in nc.ncattrs()]
            for var in nc.variables.values():
                items += [(var.name, k, var.getncattr(k)) for k in var.ncattrs()]
        for var, key, value in items:
            text = value if isinstance(value, str) else ", ".join(map(str, np.atleast_1d(value)))
            found[f"{path.name}: {var}:{key}" if var else f"{path.name}: :{key}"] = len(text)
    assert len({k.split(":")[0] for k in found}) == len(list(run_dir.glob("*.nc"))) >= 9
    long = {k: n for k, n in found.items() if n > ATTRIBUTE_LIMIT}
    assert not long, long
    # nothing is lost: the lidar model restores from the run's cube and RWF by its digests, and the
    # certificate's chain still reaches the simulation's configuration
    from lidarcal.io import open_artefact
    from lidarcal.lidar import LidarModel

    with netCDF4.Dataset(run_dir / "simulated.nc") as nc:
        record = nc.getncattr("lidarcal_lidar_model")
    model = LidarModel.from_dict(record, cube=open_artefact(run_dir / "cube.nc"),
                                 rwf=open_artefact(run_dir / "rwf.nc"))
    assert not model.noise_table.needs_values and len(model.rwf_profile[0]) == json.loads(record)[
        "rwf_profile"]["count"]
    # `simulate --model` with the run's cube and RWF re-simulates its records bit for bit
    cond, sim = run_dir.parent / "cond3.nc", run_dir.parent / "again.nc"
    xr.load_dataset(run_dir / "conditions.nc").isel(time=slice(0, 3)).to_netcdf(cond)
    assert main(["simulate", "--conditions", str(cond), "--model", str(run_dir / "simulated.nc"), "--cube",
                 str(run_dir / "cube.nc"), "--rwf", str(run_dir / "rwf.nc"), "--workers", "1",
                 "--no-progress", "-o", str(sim)]) == 0
    again, first = xr.load_dataset(sim), xr.load_dataset(run_dir / "simulated.nc").isel(time=slice(0, 3))
    np.testing.assert_array_equal(again.lidar_wind_speed.values,
                                  first.lidar_wind_speed.sel(height=again.height).values)
    chain = {r["role"]: r for r in provenance_chain(xr.load_dataset(run_dir / "certificate.nc"))}
    assert chain["records"]["config"]["model"] == json.loads(record)
    assert chain["budget"]["inputs"][0]["role"] == "records"


def test_terms_describe_every_height(run_dir):
    terms = xr.open_dataset(run_dir / "terms.nc")
    assert "60, 120 m" in terms.attrs["summary"] and "terms at 60 m)" not in terms.attrs["history"]
    config = json.loads(terms.attrs["lidarcal_config"])
    assert config["height"] == [60.0, 120.0]
    np.testing.assert_array_equal(config["shear_exponent"], terms.shear_exponent.values)
    assert (terms.attrs["geospatial_vertical_min"], terms.attrs["geospatial_vertical_max"]) == (60, 120)


def test_cf_details_of_the_written_files(run_dir):
    with netCDF4.Dataset(run_dir / "simulated.nc") as nc:
        assert nc["time"].getncattr("units_metadata") == "leap_seconds: none"
        assert nc.getncattr("time_coverage_resolution") == "PT600S"
        assert (nc.getncattr("geospatial_vertical_min"), nc.getncattr("geospatial_vertical_max")) == (60, 120)
    with netCDF4.Dataset(run_dir / "certificate.nc") as nc:
        assert nc["cube_los_bias"].getncattr("cell_methods") == "cube_los: cube_cnr: cube_velocity: mean"
        assert "time_coverage_start" not in nc.ncattrs()  # no time variable in a certificate
    with netCDF4.Dataset(run_dir / "cube.nc") as nc:
        assert "time_coverage_start" not in nc.ncattrs() and "source_time_coverage_start" in nc.ncattrs()


def _only_documented(report, name):
    """No failure, no warning; every exception documented, and CF's only the decibel."""
    assert report.failures == [], (name, report.failures)
    assert report.warnings == [], (name, report.warnings)
    kinds = {exception_kind(line, has_time=False, has_z=False) for line in report.exceptions}
    assert kinds <= DOCUMENTED, (name, kinds)
    cf = {exception_kind(line) for line in report.exceptions if line.startswith("cf")}
    assert cf <= {"dB"}, (name, cf)
    return kinds


def test_stock_checker_finds_only_documented_exceptions(run_dir):
    # the checker takes seconds per file (the certificate most: test below, slow); the cube (no
    # time, no height, dB, bench time), the records (time x height) and the budget (statistics
    # over the campaign, its dims reordered to (wind_speed, height)) cover every fix
    kinds = {name: _only_documented(check_compliance(run_dir / name), name)
             for name in ("cube.nc", "simulated.nc", "budget.nc")}
    assert kinds["cube.nc"] == DOCUMENTED  # no time, no height
    assert "time coverage" in kinds["budget.nc"] and "vertical coverage" not in kinds["budget.nc"]
    assert not kinds["simulated.nc"] & {"time coverage", "vertical coverage"}


@pytest.mark.slow
def test_stock_checker_on_every_artefact_of_a_run(run_dir):
    # every file calibrate writes; the sweep, diagnosis,
    # turbulence box and repeatability kinds are checked in their own modules' tests
    files = sorted(run_dir.glob("*.nc"))
    kinds = {xr.open_dataset(f).attrs["lidarcal_artefact"] for f in files}
    assert kinds == {"bench_cube", "rwf", "conditions", "simulated_rtd", "uncertainty_terms", "sensitivity",
                     "uncertainty_budget", "certificate"}
    for path in files:
        _only_documented(check_compliance(path), path.name)


def test_without_user_details_the_checker_asks_for_them(tmp_path):
    # the same kind of file without contact, site or further attributes: ACDD asks for exactly
    # what the options give (none of it is invented)
    ds = xr.open_dataset(sample_file("conditions/conditions.nc"))
    with contact():
        out = stamp(ds.isel(time=slice(0, 6)), "conditions", title="t", summary="s", call="test")
    write_artefact(out, tmp_path / "c.nc")
    acdd = " ".join(check_compliance(tmp_path / "c.nc").warnings)
    for attr in ("creator_email", "publisher_name", "geospatial_lat_min", "contributor_name", "program",
                 "metadata_link", "geospatial_bounds_vertical_crs"):
        assert f"{attr} not present" in acdd, attr
    assert "latitude" not in out.coords


def test_site_options_describe_one_point(run_dir, capsys):
    with netCDF4.Dataset(run_dir / "budget.nc") as nc:
        attrs = {k: nc.getncattr(k) for k in nc.ncattrs()}
        assert float(nc["latitude"][...]) == 55.6869 and nc["latitude"].getncattr("units") == "degrees_north"
        assert float(nc["longitude"][...]) == 12.0976
        assert "latitude longitude" in nc["uncertainty"].getncattr("coordinates")
        assert nc["uncertainty"].dimensions == ("wind_speed", "height")  # CF 2.4: other dims, then Z
    assert (attrs["geospatial_lat_min"], attrs["geospatial_lon_max"]) == (55.6869, 12.0976)
    assert attrs["geospatial_bounds"] == "POINT (55.6869 12.0976)"
    assert attrs["geospatial_bounds_crs"] == "EPSG:4326"
    assert attrs["program"] == "Test programme" and attrs["creator_institution"] == "Test Lab"
    assert attrs["publisher_institution"] == "Test Archive" and "Black" in attrs["references"]
    # the campaign's period, kept beside a budget that has no time variable
    with netCDF4.Dataset(run_dir / "simulated.nc") as nc:
        start = nc.getncattr("time_coverage_start")
    assert attrs["source_time_coverage_start"] == start and "time_coverage_start" not in attrs
    # bad values are refused before any work, naming the option
    for bad in (["--site-latitude", "91", "--site-longitude", "0"], ["--site-latitude", "north"],
                ["--attribute", "history=mine"], ["--attribute", "program"]):
        with pytest.raises(SystemExit) as exc:
            main(["terms", "-o", str(run_dir / "never.nc"), *bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert bad[0] in err, err
    assert not (run_dir / "never.nc").exists()


def test_validate_folds_repeated_findings():
    report = ComplianceReport("x.nc", exceptions=[
        f'cf:1.11 [§3.1 Units] units for v{i}, "dB" are not recognized by UDUNITS' for i in range(40)
    ], warnings=["acdd:1.3 [Global Attributes] comment not present",
                 "acdd:1.3 [Global Attributes] creator_url not present"])
    lines = summary_lines(report)
    assert len(lines) == 4
    assert lines[0].startswith("documented exception (dB") and "40 finding(s)" in lines[0]
    # each missing ACDD attribute once, under what supplies it
    assert lines[1] == "warning: 2 ACDD attribute(s) not present; give them with:"
    assert sorted(lines[2:]) == [
        "  --creator-url TEXT (or $LIDARCAL_CREATOR_URL): creator_url",
        "  not settable by an option (lidarcal writes it; report a missing one as a bug): comment"]
    assert len(summary_lines(report, verbose=True)) == 1 + 40 + 2


def test_every_missing_acdd_attribute_names_an_option_that_exists(tmp_path, capsys):
    # a file written without any user details: validate names, for each attribute the checker
    # asks for, an option that the writing commands really accept
    from lidarcal.cli import build_parser
    from lidarcal.compliance import supplied_by

    ds = xr.open_dataset(sample_file("conditions/conditions.nc"))
    with contact():
        out = stamp(ds.isel(time=slice(0, 6)), "conditions", title="t", summary="s", call="test")
    write_artefact(out, tmp_path / "c.nc")
    report = check_compliance(tmp_path / "c.nc")
    absent = [w.split("] ")[1].removesuffix(" not present") for w in report.warnings
              if w.startswith("acdd") and w.endswith(" not present")]
    assert len(absent) >= 10
    calibrate = build_parser()._subparsers._group_actions[0].choices["calibrate"]
    for attr in absent:
        option = supplied_by(attr)
        assert not option.startswith("not settable"), attr
        for word in option.split():
            if word.startswith("--"):
                assert word in calibrate._option_string_actions, (attr, word)
    lines = summary_lines(report)
    assert sum(attr in line for line in lines for attr in absent) >= len(absent)
    assert not any("extents_match" in line for line in lines)  # the site, said once


def test_compliance_cache_gives_the_stock_checker_findings(tmp_path):
    # the per-run cache of the checker's read-only queries must not change a single finding:
    # compared on a file with failures (bad units, a variable without long_name) and findings of
    # every kind
    ds = xr.open_dataset(sample_file("conditions/conditions.nc")).isel(time=slice(0, 6))
    with contact():
        out = stamp(ds, "conditions", title="t", summary="s", call="test")
    out["wind_speed"].attrs["units"] = "furlongs"
    out["extra"] = out["wind_speed"] * 2
    out["extra"].attrs = {"units": "m s-1", "coordinates": "nowhere"}
    out.to_netcdf(tmp_path / "bad.nc")
    cached, stock = check_compliance(tmp_path / "bad.nc"), check_compliance(tmp_path / "bad.nc", cache=False)
    assert cached.failures and cached.warnings
    assert (cached.failures, cached.exceptions, cached.warnings) == (stock.failures, stock.exceptions,
                                                                     stock.warnings)


def test_merge_history_dedupes_and_orders():
    a = "[2024-01-02T00:00:00Z] b\n[2024-01-01T00:00:00Z] a"
    b = "[2024-01-01T00:00:00Z] a\nfree text\n[2024-01-03T00:00:00Z] c"
    # "a" once; the untimed line stays after the line it followed ("a"), before "b"
    assert merge_history(a, b).splitlines() == [
        "[2024-01-01T00:00:00Z] a", "free text", "[2024-01-02T00:00:00Z] b", "[2024-01-03T00:00:00Z] c",
    ]


def test_pint_quantifies_every_artefact_after_register_units(run_dir):
    # lidarcal.units.register_units() makes cf-xarray's registry pint's (import lidarcal alone
    # does not: it imports no unit library, docs/units.md)
    code = (
        "import glob, lidarcal.units\n"
        "lidarcal.units.register_units()\n"
        "import pint_xarray, xarray as xr\n"
        f"files = sorted(glob.glob({str(run_dir)!r} + '/*.nc'))\n"
        "kinds = set()\n"
        "for f in files:\n"
        "    ds = xr.open_dataset(f)\n"
        "    q = ds.pint.quantify()\n"
        "    kinds.add(ds.attrs['lidarcal_artefact'])\n"
        "b = xr.open_dataset([f for f in files if f.endswith('budget.nc')][0]).pint.quantify()\n"
        "print(sorted(kinds), b.uncertainty.pint.to('km/h').pint.units)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    kinds, unit = done.stdout.rsplit("]", 1)
    for kind in ("bench_cube", "rwf", "conditions", "simulated_rtd", "uncertainty_terms", "sensitivity",
                 "uncertainty_budget", "certificate"):
        assert repr(kind) in kinds
    assert unit.strip() == "kilometer / hour"


def test_every_variable_of_a_run_is_described_by_its_schema(run_dir):
    """Output metadata is declared once: each variable a run writes is in its kind's schema, with its words.

    A variable lidarcal writes but no schema declares (or one whose long name was written by hand
    and drifted from the schema's) fails here; the certificate is made of its components' variables.
    """
    checked = 0
    for path in sorted(run_dir.glob("*.nc")):
        with netCDF4.Dataset(path) as nc:
            kind = nc.getncattr("lidarcal_artefact")
            if kind == "certificate":
                continue
            bounds = {str(v.getncattr("bounds")) for v in nc.variables.values() if "bounds" in v.ncattrs()}
            resolved = load_schema(kind)
            for name, var in nc.variables.items():
                # bounds, and the site point stamp() adds to any kind
                if name in bounds or name in ("latitude", "longitude"):
                    continue
                try:
                    spec, _ = declared_spec(kind, name)
                except InputError:  # copied from another schema by an include
                    assert name in {**resolved["coordinates"], **resolved["variables"]}, (path.name, name)
                    continue
                declared = spec.get("long_name")
                if isinstance(declared, str) and "{" not in declared:
                    assert var.getncattr("long_name") == declared, (path.name, name)
                    checked += 1
    assert checked > 50
