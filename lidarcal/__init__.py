"""lidarcal — anemometer-free calibration of pulsed Doppler wind lidars.

Stages (one module or sub-package each; imports flow from kernels to datasets to the CLI):

- :mod:`lidarcal.bench` — fiber-optic bench (SAFO-MV): simulated runs, ingest to the
  ℓcv-bin cube, repeatability (ISO 5725-4).
- :mod:`lidarcal.rwf` — range-weighting function and zero distance (Eqs. 1–2).
- :mod:`lidarcal.analysis.terms` — uncertainty terms not modelled by Monte Carlo (Eqs. 6–11, Table 4).
- :mod:`lidarcal.conditions` — the ``conditions`` / ``field_campaign`` input contract.
- :mod:`lidarcal.turbulence` — Kaimal/coherence turbulence at the points the lidar needs.
- :mod:`lidarcal.lidar` — virtual DBS lidar, wind-field reconstruction, virtual reference.
- :mod:`lidarcal.campaign` — Dask-parallel, resumable Monte Carlo over a campaign.
- :mod:`lidarcal.analysis` — sensitivities, uncertainty budgets, classification sweeps.
- :mod:`lidarcal.certificate`, :mod:`lidarcal.report` — archiving and presenting results.
- :mod:`lidarcal.diagnose` — find, name and fix model–field discrepancies.
- :mod:`lidarcal.compare` — a field campaign's slopes and budget beside the virtual lidar's.

Shared infrastructure: :mod:`lidarcal.units`, :mod:`lidarcal.schema`, :mod:`lidarcal.io`,
:mod:`lidarcal.provenance`, :mod:`lidarcal.compliance`, :mod:`lidarcal.errors`.

The main entry points are available from the top level, imported on first use so that
``import lidarcal`` stays fast::

    import lidarcal

    result = lidarcal.calibrate("run1", lidarcal.CalibrationConfig(periods=144, min_periods=3))
    result.datasets["budget"].sel(height=120).relative_uncertainty
    lidarcal.verify(result.paths["certificate"]).ok

``lidarcal.diagnose`` is the :mod:`lidarcal.diagnose` package; calling it runs
:func:`lidarcal.diagnose.diagnose`.
"""

import sys as _sys
from importlib import import_module as _import_module
from importlib import metadata as _metadata

#: Public name -> (module, attribute); resolved lazily by :func:`__getattr__`.
_EXPORTS = {
    "calibrate": ("lidarcal.pipeline", "calibrate"),
    "CalibrationConfig": ("lidarcal.pipeline", "CalibrationConfig"),
    "CalibrationResult": ("lidarcal.pipeline", "CalibrationResult"),
    "open_artefact": ("lidarcal.io", "open_artefact"),
    "LidarModel": ("lidarcal.lidar", "LidarModel"),
    "simulate_campaign": ("lidarcal.campaign", "simulate_campaign"),
    "sensitivity": ("lidarcal.analysis.sensitivity", "sensitivity"),
    "budget": ("lidarcal.analysis.budget", "budget"),
    "make_certificate": ("lidarcal.certificate", "make_certificate"),
    "verify": ("lidarcal.seal", "verify_certificate"),
    "open_certificate": ("lidarcal.certificate", "open_certificate"),
    "result_table": ("lidarcal.certificate", "result_table"),
    # the subpackage itself, callable as its diagnose() function (a submodule import would
    # rebind the attribute to the package anyway)
    "diagnose": ("lidarcal.diagnose", None),
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str):
    """Import an entry point on first access (PEP 562)."""
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'lidarcal' has no attribute {name!r}") from None
    value = _import_module(module)
    if attr is not None:
        value = getattr(value, attr)
    globals()[name] = value  # later accesses skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})



class _UnitsOnPintImport:
    """Import hook: when ``pint_xarray`` is first imported, register cf-xarray's unit registry.

    pint-xarray's ``ds.pint.quantify()`` parses units with pint's application registry, which
    does not understand CF spellings (``m s-1``, ``1``, ``dB``) until ``cf_xarray.units`` is
    imported.  Importing it costs most of a second, so ``import lidarcal`` does it only once
    pint-xarray is in use (now, if it already is).
    """

    def find_spec(self, name, path=None, target=None):
        if name != "pint_xarray":
            return None
        _sys.meta_path.remove(self)
        from importlib.util import find_spec

        spec = find_spec(name)
        if spec is not None and spec.loader is not None and hasattr(spec.loader, "exec_module"):
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                _register_units()

            spec.loader.exec_module = exec_module
        return spec


def _register_units() -> None:
    _import_module("lidarcal.units").register_units()


if "pint_xarray" in _sys.modules:
    _register_units()
elif not any(isinstance(f, _UnitsOnPintImport) for f in _sys.meta_path):
    _sys.meta_path.insert(0, _UnitsOnPintImport())

try:
    __version__ = _metadata.version("lidarcal")
except _metadata.PackageNotFoundError:  # running from a checkout without install
    __version__ = "0.0.0+unknown"
