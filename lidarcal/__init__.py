"""lidarcal — anemometer-free calibration of pulsed Doppler wind lidars.

The main entry points are available from the top level and imported on first use::

    import lidarcal

    result = lidarcal.calibrate("run1", lidarcal.CalibrationConfig(periods=144, min_periods=3))
    result.datasets["budget"].sel(height=120).relative_uncertainty
    lidarcal.verify(result.paths["certificate"]).ok

``lidarcal.diagnose_campaign`` is :func:`lidarcal.diagnose.diagnose`.  Importing lidarcal
imports none of them, nor xarray or pint, so that ``lidarcal --help`` and ``lidarcal verify``
start within a second of CPU (``benchmarks/bench_startup.py``).
:func:`lidarcal.units.register_units` makes cf-xarray's unit registry pint's application
registry, so that ``ds.pint.quantify()`` reads the units of every artefact;
lidarcal does it itself the first time it reads or converts a unit (docs/units.md).
"""

from importlib import import_module as _import_module
from importlib import metadata as _metadata

#: Public name -> (module, attribute); resolved by :func:`__getattr__` on first access.
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
    "verify": ("lidarcal.certificate.seal", "verify_certificate"),
    "open_certificate": ("lidarcal.certificate", "open_certificate"),
    "result_table": ("lidarcal.certificate", "result_table"),
    "diagnose_campaign": ("lidarcal.diagnose", "diagnose"),
}

__all__ = ["__version__", *_EXPORTS]  # and __init__.pyi, for type checkers (tests/test_frontdoor.py)


#: Submodules reachable as attributes of the package before anyone imported them.
_SUBMODULES = ("units",)


def __getattr__(name: str):
    """Import an entry point (or :data:`_SUBMODULES`) on first access (PEP 562)."""
    if name in _SUBMODULES:
        return _import_module(f"lidarcal.{name}")
    try:
        module, attr = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'lidarcal' has no attribute {name!r}") from None
    return getattr(_import_module(module), attr)


def __dir__() -> list[str]:
    """List the module's names and the entry points not yet imported (PEP 562)."""
    return sorted({*globals(), *_EXPORTS, *_SUBMODULES})


try:
    __version__ = _metadata.version("lidarcal")
except _metadata.PackageNotFoundError:  # running from a checkout without install
    __version__ = "0.0.0+unknown"
