"""Certificate status (demonstration / issued), its issuer and the administrative data (issue 18 §1-2)."""

import hashlib
import shutil

import netCDF4
import pytest
import yaml
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.bench import build_cube, simulate_run
from lidarcal.bench.formats import read_control_log, write_control_log, write_rtd
from lidarcal.bench.simulator import SIMULATED_ORIGIN
from lidarcal.certificate import make_certificate
from lidarcal.certificate.admin import ADMIN_FILE_KEYS, demonstration_reasons, load_admin
from lidarcal.cli import main
from lidarcal.conditions import synthetic_conditions
from lidarcal.data import sample_file
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.pipeline import CalibrationConfig, calibrate
from lidarcal.provenance import stamp

SERIAL = "WLS7-STATUS"

ADMIN = {
    "certificate_id": "LAB-2026-0042",
    "item": {"manufacturer": "Acme Lidars", "model": "PL-200", "serial_number": SERIAL, "firmware": "2.1.8"},
    "laboratory": {"name": "Example Wind Lab", "address": "1 Bench Street, 75000 Paris",
                   "country_code": "FR"},
    "responsible_persons": [{"name": "A. Engineer", "role": "calibration engineer"}, "B. Head (head of lab)"],
    "customer": {"name": "Wind Farm Operator Ltd", "address": "2 Turbine Road, Lyon"},
    "calibration_location": "Example Wind Lab, bench hall 2",
    "bench": {"run_start": "2026-03-14T09:30:00Z", "run_end": "2026-03-16", "operator": "C. Operator"},
    "simulation_date": "2026-03-20",
    "method_reference": "Black et al., anemometer-free calibration; lidarcal defaults",
}


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Budget and sensitivity of records that are neither sample data nor a simulated bench run."""
    d = tmp_path_factory.mktemp("status")
    rec_path = d / "records.nc"
    make_records(n=400, lidar_serial=SERIAL).to_netcdf(rec_path)
    records = open_artefact(rec_path)
    return {
        "records": rec_path,
        "budget": write_artefact(budget(records), d / "budget.nc"),
        "sens": write_artefact(sensitivity(records, "wind_shear_exponent"), d / "sens.nc"),
    }


def _cert_args(files, out, *extra):
    return ["certificate", "--budget", str(files["budget"]), "--sensitivity", str(files["sens"]),
            "--records", str(files["records"]), "-o", str(out), *map(str, extra)]


def _attrs(path):
    with netCDF4.Dataset(path) as nc:
        return {k: nc.getncattr(k) for k in nc.ncattrs()}


def test_simulated_bench_run_is_recorded_and_makes_a_demonstration(tmp_path):
    run = simulate_run(seed=5, accumulation_time="20 s", lidar_serial=SERIAL)
    path = write_control_log(run.control, tmp_path / "control_log.csv")
    assert f"# data_origin: {SIMULATED_ORIGIN}" in path.read_text().splitlines()[:12]
    assert read_control_log(path).metadata["data_origin"] == SIMULATED_ORIGIN
    cube, _ = build_cube(run.rtd, run.control)
    assert cube.attrs["data_origin"] == SIMULATED_ORIGIN
    cube = stamp(cube, "bench_cube", title="cube", summary="simulated", call="test")
    records = make_records(n=300, lidar_serial=SERIAL)
    cert = make_certificate(budget=budget(records), sensitivities=[], cube=cube)
    assert cert.attrs["calibration_status"] == "demonstration"
    assert "simulated by lidarcal bench simulate" in cert.attrs["calibration_status_reason"]
    assert "DEMONSTRATION" in cert.attrs["title"] and cert.attrs["summary"].startswith("DEMONSTRATION")
    # the bench traceability comes from the control log's metadata, through the cube
    assert cert.attrs["bench_id"] == "SAFO-MV-01" and cert.attrs["bench_run_id"] == "1"
    rf_reference = run.control.metadata["rf_driver_calibration_reference"]
    assert cert.attrs["rf_driver_calibration_reference"] == rf_reference
    assert cert.attrs["item_serial_number"] == SERIAL and cert.attrs["certificate_id"].startswith("lidarcal-")


def test_sample_files_are_recognised_by_their_sha256_wherever_copied(tmp_path):
    copy = tmp_path / "my_pulse.csv"
    shutil.copyfile(sample_file("rwf/pulse_example.csv"), copy)
    digest = hashlib.sha256(copy.read_bytes()).hexdigest()  # independent of lidarcal's sha256
    nested = {"lidarcal_provenance_chain": '[{"role": "rwf", "inputs": [{"file": "my_pulse.csv", '
                                           f'"sha256": "{digest}"}}]}}]'}
    reasons = demonstration_reasons(nested)
    assert reasons == ["input my_pulse.csv is lidarcal's embedded sample file "
                       "sample_data/rwf/pulse_example.csv"]
    copy.write_text(copy.read_text() + "# one more comment line\n")  # another file: not the sample
    changed = hashlib.sha256(copy.read_bytes()).hexdigest()
    assert demonstration_reasons({}, [{"file": "my_pulse.csv", "sha256": changed}]) == []


def test_issued_certificate_needs_an_issuer(files, tmp_path, capsys):
    out = tmp_path / "cert.nc"
    assert main(_cert_args(files, out)) == 2
    err = capsys.readouterr().err
    assert "needs an issuer" in err and "--creator" in err and "--institution" in err and "--admin" in err
    assert "--demonstration" in err and not out.exists()
    # only one of the two is not enough
    assert main(_cert_args(files, out, "--creator", "A. Engineer")) == 2
    assert "the laboratory" in capsys.readouterr().err and not out.exists()
    assert main(_cert_args(files, out, "--creator", "A. Engineer", "--institution", "Example Wind Lab")) == 0
    attrs = _attrs(out)
    assert attrs["calibration_status"] == "issued"
    assert attrs["laboratory_name"] == "Example Wind Lab" and attrs["responsible_persons"] == "A. Engineer"
    capsys.readouterr()
    assert main(["verify", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"{out}: ISSUED certificate lidarcal-") and "A. Engineer" in lines[0]
    assert ": OK (" in lines[1]
    assert main(["table", str(out), "--format", "md"]) == 0
    md = capsys.readouterr().out.splitlines()
    assert md[2].startswith("**ISSUED certificate")
    # --demonstration forces the status, and needs no issuer
    demo = tmp_path / "demo.nc"
    assert main(_cert_args(files, demo, "--demonstration")) == 0
    assert _attrs(demo)["calibration_status"] == "demonstration"
    capsys.readouterr()
    assert main(["verify", str(demo)]) == 0
    assert capsys.readouterr().out.splitlines()[0].startswith(f"{demo}: DEMONSTRATION certificate")


def test_admin_file_is_stored_validated_and_sealed(files, tmp_path, capsys):
    admin = tmp_path / "admin.yaml"
    admin.write_text(yaml.safe_dump(ADMIN, sort_keys=False))
    out = tmp_path / "cert.nc"
    assert main(_cert_args(files, out, "--admin", admin)) == 0  # the file names the issuer
    attrs = _attrs(out)
    expected = {
        "calibration_status": "issued", "certificate_id": "LAB-2026-0042", "item_manufacturer": "Acme Lidars",
        "item_model": "PL-200", "item_serial_number": SERIAL, "item_firmware": "2.1.8",
        "laboratory_name": "Example Wind Lab", "laboratory_address": "1 Bench Street, 75000 Paris",
        "laboratory_country_code": "FR",
        "responsible_persons": "A. Engineer (calibration engineer); B. Head (head of lab)",
        "customer_name": "Wind Farm Operator Ltd", "customer_address": "2 Turbine Road, Lyon",
        "calibration_location": "Example Wind Lab, bench hall 2", "bench_run_start": "2026-03-14T09:30:00Z",
        "bench_run_end": "2026-03-16", "bench_operator": "C. Operator", "simulation_date": "2026-03-20",
        "method_reference": "Black et al., anemometer-free calibration; lidarcal defaults",
        "institution": "Example Wind Lab",  # ACDD institution carries the laboratory
        "creator_name": "A. Engineer", "creator_type": "person",  # and creator the first person
    }
    assert {k: attrs.get(k) for k in expected} == expected
    acdd = {"calibration_status", "institution", "creator_name", "creator_type"}
    assert set(expected) - acdd <= set(ADMIN_FILE_KEYS.values())
    # sealed with the rest
    with netCDF4.Dataset(out, "a") as nc:
        nc.setncattr("customer_name", "Someone Else")
    capsys.readouterr()
    assert main(["verify", str(out)]) == 1
    assert "global attribute 'customer_name' altered" in capsys.readouterr().out
    # an option wins over the file
    out2 = tmp_path / "cert2.nc"
    assert main(_cert_args(files, out2, "--admin", admin, "--certificate-id", "LAB-2026-0043")) == 0
    assert _attrs(out2)["certificate_id"] == "LAB-2026-0043"


@pytest.mark.parametrize("content, expected", [
    ({"item": {"colour": "red"}}, "unknown key 'item.colour'; 'item' has keys"),
    ({"custmer": {"name": "X"}}, "unknown key 'custmer'"),
    ({"simulation_date": "14/03/2026"}, "key 'simulation_date': expected an ISO 8601 date"),
    ({"bench": {"run_start": "yesterday"}}, "key 'bench.run_start': expected an ISO 8601 date"),
    ({"laboratory": {"country_code": "France"}}, "key 'laboratory.country_code': expected an ISO 3166-1"),
    ({"responsible_persons": [{"role": "engineer"}]}, "responsible_persons'[0]: expected a mapping"),
    (["not", "a", "mapping"], "expected a mapping of administrative data"),
])
def test_bad_admin_file_is_refused_naming_file_and_key(files, tmp_path, capsys, content, expected):
    admin = tmp_path / "admin.yaml"
    admin.write_text(yaml.safe_dump(content))
    with pytest.raises(InputError, match="admin.yaml") as info:
        load_admin(admin)
    assert expected in str(info.value)
    out = tmp_path / "cert.nc"
    assert main(_cert_args(files, out, "--admin", admin, "--demonstration")) == 2
    err = capsys.readouterr().err
    assert expected in err and str(admin) in err and not out.exists()


def test_admin_contradicting_the_data_is_refused(files, tmp_path, capsys):
    admin = tmp_path / "admin.yaml"
    admin.write_text(yaml.safe_dump({"item": {"serial_number": "OTHER-1"}}))
    assert main(_cert_args(files, tmp_path / "c.nc", "--admin", admin, "--demonstration")) == 2
    assert f"item_serial_number 'OTHER-1' contradicts the certificate's data, which state '{SERIAL}'" \
        in capsys.readouterr().err


def test_calibrate_refuses_an_issued_run_without_issuer_before_any_work(tmp_path):
    run = simulate_run(seed=7, accumulation_time="20 s", lidar_serial=SERIAL)
    del run.control.metadata["data_origin"]  # as a real bench's control log: no simulation mark
    inputs = tmp_path / "inputs"
    inputs.mkdir()
    write_rtd(run.rtd, inputs / "rtd.csv")
    write_control_log(run.control, inputs / "control_log.csv")
    pulse = inputs / "pulse.csv"
    pulse.write_text(sample_file("rwf/pulse_example.csv").read_text() + "# measured on our bench\n")
    synthetic_conditions(12, (40.0, 80.0), seed=3).to_netcdf(inputs / "conditions.nc")
    cfg = CalibrationConfig(bench_rtd=str(inputs / "rtd.csv"), bench_control=str(inputs / "control_log.csv"),
                            pulse_file=str(pulse), conditions=str(inputs / "conditions.nc"), heights=(80.0,),
                            periods=12)
    out = tmp_path / "run"
    with pytest.raises(InputError, match="needs an issuer"):
        calibrate(out, cfg)
    assert not any(out.iterdir())  # refused before the first artefact
    # the same inputs with the simulation mark are a demonstration: no issuer needed (not run here)
    cfg_sample = CalibrationConfig(conditions=str(inputs / "conditions.nc"))
    from lidarcal.pipeline import _check_issuer  # the pre-check alone: a full run is too long for a unit test

    _check_issuer(cfg_sample, {}, False)  # sample bench data: demonstration, no issuer needed
    write_control_log(simulate_run(seed=7, accumulation_time="20 s").control, inputs / "sim_log.csv")
    _check_issuer(CalibrationConfig(bench_rtd=cfg.bench_rtd, bench_control=str(inputs / "sim_log.csv"),
                                    pulse_file=cfg.pulse_file, conditions=cfg.conditions), {}, False)
