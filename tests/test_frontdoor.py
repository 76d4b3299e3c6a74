"""The front door for Python users: lazy top-level entry points and the README's Python chain."""

import ast
import importlib
import json
import re
import subprocess
import sys
import types
from pathlib import Path

import pytest

import lidarcal
from lidarcal.errors import InputError

README = Path(__file__).resolve().parents[1] / "README.md"


def test_every_exported_name_resolves_to_its_entry_point():
    from lidarcal.certificate.seal import verify_certificate
    from lidarcal.diagnose import diagnose
    from lidarcal.pipeline import calibrate

    assert len(lidarcal.__all__) >= 11
    for name in lidarcal.__all__:
        assert getattr(lidarcal, name) is not None, name
    assert lidarcal.calibrate is calibrate
    assert lidarcal.verify is verify_certificate
    assert lidarcal.diagnose_campaign is diagnose
    with pytest.raises(AttributeError, match="no attribute 'calibrat'"):
        lidarcal.calibrat  # noqa: B018


def _stub() -> tuple[list[str], dict[str, tuple[str, str]]]:
    """``__all__`` and the imports (name -> (module, attribute)) of lidarcal/__init__.pyi."""
    tree = ast.parse(Path(lidarcal.__file__).with_suffix(".pyi").read_text())
    names = next(ast.literal_eval(node.value) for node in tree.body
                 if isinstance(node, ast.Assign) and node.targets[0].id == "__all__")
    imports = {alias.asname or alias.name: (node.module, alias.name)
               for node in tree.body if isinstance(node, ast.ImportFrom) for alias in node.names}
    return names, imports


def test_dir_all_and_the_type_checkers_view_agree():
    names, imports = _stub()
    assert names == lidarcal.__all__
    assert set(names) - {"__version__"} <= set(imports)
    for name, (module, attr) in imports.items():  # what the checker sees is what lidarcal holds
        assert getattr(lidarcal, name) is getattr(importlib.import_module(module), attr), name
    # dir() lists every export, before its first use too, and otherwise only submodules
    public = {name for name in dir(lidarcal) if not name.startswith("_")}
    assert set(names) - {"__version__"} <= public
    others = public - set(names)
    assert "units" in others and all(isinstance(getattr(lidarcal, name), types.ModuleType) for name in others)


def test_diagnose_campaign_runs_the_diagnosis(tmp_path):
    import lidarcal.diagnose as package

    # the top-level name does not collide with the package: after importing it, both are there
    assert lidarcal.diagnose is package and "diagnose" not in lidarcal.__all__
    # a missing field file is diagnose()'s input error
    with pytest.raises(InputError, match="missing.nc"):
        lidarcal.diagnose_campaign(tmp_path / "missing.nc")


#: What a command that runs no simulation and draws nothing never needs: seconds of CPU to import.
ENGINE = ("cf_xarray", "scipy.stats", "scipy.interpolate", "matplotlib", "bokeh", "distributed", "pyconturb",
          "pint_xarray", "lidarcal.pipeline", "lidarcal.campaign", "lidarcal.analysis",
          "lidarcal.certificate.report", "lidarcal.certificate.document", "lidarcal.diagnose",
          "lidarcal.lidar")
#: ... and what ``lidarcal --help`` needs none of either.
LIBRARIES = ("numpy", "xarray", "pandas", "pint", "dask", "netCDF4", "yaml")


def _loaded(code: str) -> list[str]:
    """Run ``code`` in a fresh interpreter; return which of ENGINE and LIBRARIES it imported."""
    probe = (f"{code}\nimport json, sys\nprint(json.dumps(sorted(m for m in {(*ENGINE, *LIBRARIES)!r} "
             "if m in sys.modules)))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.splitlines()[-1])


def test_import_lidarcal_and_help_import_no_library():
    """``import lidarcal``, ``lidarcal --help`` and ``--version`` import neither xarray nor pint."""
    code = ("import sys, lidarcal\n"
            "assert not [f for f in sys.meta_path if type(f).__module__.startswith('lidarcal')]")  # no hook
    assert _loaded(code) == []
    for argv in (["--help"], ["--version"], []):
        code = ("import contextlib, io\nfrom lidarcal.cli import main\n"
                f"with contextlib.redirect_stdout(io.StringIO()), contextlib.suppress(SystemExit):\n"
                f"    main({argv!r})")
        assert _loaded(code) == [], argv
    # the help still lists every command, with its line, without importing a command module
    code = ("import sys\nfrom lidarcal.cli import build_parser\nprint(build_parser([]).format_help())\n"
            "assert not [m for m in sys.modules if m.startswith('lidarcal.cli.')]")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    from lidarcal.cli import COMMANDS

    text = " ".join(done.stdout.split())
    assert all(f"{name} {' '.join(c.help.split())}" in text for name, c in COMMANDS.items())


def test_units_registry_is_built_and_registered_on_first_use():
    assert _loaded("import lidarcal.units") == ["numpy"]
    code = ("import json, pint, lidarcal\n"
            "first = lidarcal.units.to_magnitude('36 km/h', 'm s-1', name='u')\n"
            "print(json.dumps([first, pint.get_application_registry().get() is lidarcal.units.ureg]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert json.loads(out) == [10.0, True]  # 36 km/h = 10 m/s, and pint-xarray would use this registry
    # the entry points are imported on first use
    code = "import sys, lidarcal; lidarcal.calibrate; print('lidarcal.pipeline' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "True"


def test_verify_imports_only_what_reading_a_certificate_needs(tmp_path):
    """``lidarcal verify`` reads a netCDF file and hashes it: no unit registry, no engine, no plots.

    (xarray itself imports pint, to recognise pint arrays, and the seal check reads the file
    through dask.)
    """
    from analysis_factories import make_records

    from lidarcal.analysis import budget
    from lidarcal.cli import main
    from lidarcal.io import open_artefact, write_artefact

    make_records(n=200).to_netcdf(tmp_path / "records.nc")
    bud = write_artefact(budget(open_artefact(tmp_path / "records.nc")), tmp_path / "budget.nc")
    cert = tmp_path / "cert.nc"
    assert main(["certificate", "--budget", str(bud), "-o", str(cert), "--demonstration"]) == 0
    code = ("import contextlib, io\nfrom lidarcal.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
            f"    assert main(['verify', {str(cert)!r}]) == 0\n"
            "assert ': OK (' in out.getvalue()")
    assert set(_loaded(code)) - set(LIBRARIES) == set()


def test_readme_python_chain_runs_as_a_script_without_a_main_guard(tmp_path):
    """The README's "In Python" block pasted into a script, run with ``python script.py``.

    No ``if __name__ == "__main__":`` guard: the worker processes (two here) must not run the
    script again.  One day is cut to 24 periods, at most 2 Monte Carlo replicas (the second
    round of simulations goes to the workers again) and no model-form runs, to keep it quick:
    the script, its workers and its printed result are what is checked here, the model-form and
    replica stages on a real run in tests/test_pipeline.py.
    """
    section = README.read_text().split("## In Python", 1)[1]
    block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    assert "periods=144" in block and "__main__" not in block
    script = tmp_path / "chain.py"
    short = "periods=24, workers=2, max_replicas=2, model_form_periods=0"
    script.write_text(block.replace("periods=144", short))
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    # the printed number is a relative uncertainty in percent
    number, unit = done.stdout.split()
    assert float(number) > 0 and unit == "%"
    budget = lidarcal.open_artefact(tmp_path / "lidarcal-python" / "budget.nc")
    assert budget.attrs["lidarcal_artefact"] == "uncertainty_budget"
    assert list(budget.height.values) == [80.0, 120.0]
    assert budget.relative_uncertainty.attrs["units"] == "%"
    assert (tmp_path / "lidarcal-python" / "certificate.nc").exists()
