"""``lidarcal certificate`` seals one lidar and one records chain, with or without ``--records``.

Issue 9, item 3: without ``--records`` a cube from lidar OTHER-999 was sealed with a budget for
WLS866-0195.  Every refusal must exit 2, name both files and both serials (or both records
files), and write nothing.
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.cli import main
from lidarcal.io import open_artefact, write_artefact

SERIAL = "WLS866-0195"


def _derived(d, name, records):
    path = d / f"{name}.nc"
    records.to_netcdf(path)
    rec = open_artefact(path)
    return (path, write_artefact(budget(rec), d / f"budget_{name}.nc"),
            write_artefact(sensitivity(rec, "wind_shear_exponent"), d / f"sens_{name}.nc"))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cert-inputs")
    out = {}
    out["rec_a"], out["budget_a"], out["sens_a"] = _derived(d, "a", make_records(n=300, lidar_serial=SERIAL))
    out["rec_b"], out["budget_b"], out["sens_b"] = _derived(d, "b", make_records(n=300, seed=7,
                                                                                   lidar_serial=SERIAL))
    anonymous = make_records(n=300, seed=9)
    del anonymous.attrs["lidar_serial"]
    out["rec_anon"], out["budget_anon"], out["sens_anon"] = _derived(d, "anon", anonymous)
    # a bench cube of another lidar: only its kind and serial matter for the check
    for serial, name in ((SERIAL, "cube_same"), ("OTHER-999", "cube_other")):
        cube = xr.Dataset({"los_bias": ("los", np.zeros(4))}, coords={"los": np.arange(4.0)})
        cube.attrs.update(lidarcal_artefact="bench_cube", lidar_serial=serial)
        cube.to_netcdf(d / f"{name}.nc")
        out[name] = d / f"{name}.nc"
    return out


def _certificate(tmp_path, capsys, budget, sens, *extra):
    out = tmp_path / "cert.nc"
    capsys.readouterr()
    code = main(["certificate", "--budget", str(budget), "--sensitivity", str(sens), *map(str, extra),
                 "-o", str(out), "--demonstration"])
    err = capsys.readouterr().err
    if code != 0:
        assert not out.exists() and "Traceback" not in err
    return code, err


@pytest.mark.parametrize("with_records", [False, True])
def test_cube_of_another_lidar_is_refused(files, tmp_path, capsys, with_records):
    extra = ["--cube", files["cube_other"]] + (["--records", files["rec_a"]] if with_records else [])
    code, err = _certificate(tmp_path, capsys, files["budget_a"], files["sens_a"], *extra)
    assert code == 2, err
    assert "inputs disagree on the lidar" in err
    assert f"budget (budget_a.nc) has lidar_serial '{SERIAL}'" in err
    assert "cube (cube_other.nc) has lidar_serial 'OTHER-999'" in err


def test_budget_of_unknown_lidar_with_a_cube_is_refused(files, tmp_path, capsys):
    code, err = _certificate(tmp_path, capsys, files["budget_anon"], files["sens_anon"],
                             "--cube", files["cube_same"])
    assert code == 2, err
    unnamed = "budget (budget_anon.nc), sensitivity_wind_shear_exponent (sens_anon.nc)"
    assert f"{unnamed} name(s) no lidar serial" in err
    assert f"cube (cube_same.nc) describe(s) lidar '{SERIAL}'" in err


def test_budget_and_sensitivity_from_different_records_are_refused(files, tmp_path, capsys):
    code, err = _certificate(tmp_path, capsys, files["budget_a"], files["sens_b"])
    assert code == 2, err
    assert "inputs disagree on the records" in err
    assert "budget (budget_a.nc) was computed from records 'a.nc'" in err
    assert "sensitivity_wind_shear_exponent (sens_b.nc) was computed from records 'b.nc'" in err
    # with --records, the one that does not match it is named
    code, err = _certificate(tmp_path, capsys, files["budget_a"], files["sens_b"],
                             "--records", files["rec_a"])
    assert code == 2 and "sens_b.nc" in err and "'b.nc'" in err and "a.nc" in err, err


def test_one_lidar_one_records_chain_is_sealed(files, tmp_path, capsys):
    """Positive control: the checks above refuse mixtures, not consistent inputs."""
    for extra in ([], ["--records", files["rec_a"]]):
        (tmp_path / "cert.nc").unlink(missing_ok=True)
        code, err = _certificate(tmp_path, capsys, files["budget_a"], files["sens_a"], *extra)
        assert code == 0, err
        assert open_artefact(tmp_path / "cert.nc").attrs["lidar_serial"] == SERIAL
