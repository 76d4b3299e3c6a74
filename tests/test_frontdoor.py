"""The front door for Python users: lazy top-level entry points and the README's Python chain."""

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import lidarcal
from lidarcal.errors import InputError

README = Path(__file__).resolve().parents[1] / "README.md"


def test_every_exported_name_resolves_to_its_entry_point():
    from lidarcal.pipeline import calibrate
    from lidarcal.seal import verify_certificate

    assert len(lidarcal.__all__) >= 11
    for name in lidarcal.__all__:
        assert getattr(lidarcal, name) is not None, name
        assert name in dir(lidarcal), name
    assert lidarcal.calibrate is calibrate
    assert lidarcal.verify is verify_certificate
    with pytest.raises(AttributeError, match="no attribute 'calibrat'"):
        lidarcal.calibrat  # noqa: B018


def test_diagnose_is_the_package_and_runs_the_diagnosis(tmp_path):
    import lidarcal.diagnose as package

    assert lidarcal.diagnose is package and "effects" in dir(package)
    # calling the package runs diagnose(): a missing field file is its input error
    with pytest.raises(InputError, match="missing.nc"):
        lidarcal.diagnose(tmp_path / "missing.nc")


def test_import_lidarcal_stays_light():
    code = ("import sys, json, lidarcal; "
            "print(json.dumps(sorted(m for m in ('numpy', 'xarray', 'dask', 'pint', 'netCDF4') "
            "if m in sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out) == []
    # first use imports what it needs
    code = "import sys, lidarcal; lidarcal.open_artefact; print('xarray' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "True"


def test_readme_python_chain_runs(tmp_path, monkeypatch):
    """Execute the README's "In Python" block, with one day cut to 24 periods to keep it quick."""
    section = README.read_text().split("## In Python", 1)[1]
    block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert "periods=144" in block
    block = block.replace("periods=144", "periods=24")
    monkeypatch.chdir(tmp_path)
    namespace = {}
    exec(compile(block, str(README), "exec"), namespace)  # noqa: S102 - our own README
    budget = namespace["budget"]
    assert budget.attrs["lidarcal_artefact"] == "uncertainty_budget"
    assert list(budget.height.values) == [80.0, 120.0]
    # the printed number is a relative uncertainty in percent
    assert budget.relative_uncertainty.attrs["units"] == "%"
    assert (tmp_path / "lidarcal-python" / "certificate.nc").exists()
