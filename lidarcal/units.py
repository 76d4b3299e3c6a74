"""The single pint registry and the unit checks used at every public boundary.

The registry is cf-xarray's, so UDUNITS/CF strings such as ``m s-1`` parse.  Pint treats
``dB`` as a logarithmic (offset) unit, so CNR quantities are checked by their unit string
and then handled as plain floats.  :func:`si_unit` writes a UDUNITS string in the D-SI form
of a Digital Calibration Certificate (:mod:`lidarcal.certificate.dcc.export`).

The registry is built the first time lidarcal needs it (``ureg`` or ``Q_`` is used, a unit is
parsed or converted, or :func:`register_units` is called), not when this module is imported:
building it (importing pint and ``cf_xarray.units``) costs about a second of CPU, which a
command that never touches a unit (``lidarcal --help``, ``lidarcal verify``) should not pay.
Once built, it is pint's application registry, the one pint-xarray uses (docs/units.md).
"""

from __future__ import annotations

import numbers
import re
from typing import TYPE_CHECKING, Any

import numpy as np

from lidarcal.errors import MissingVariableError, UnitError

if TYPE_CHECKING:
    import pint
    import xarray as xr

__all__ = [
    "ureg",  # noqa: F822  (built on first access: __getattr__)
    "Q_",  # noqa: F822
    "LOG_UNITS",
    "cf_units",
    "convert_values",
    "convert_variable",
    "to_magnitude",
    "parse_unit",
    "register_units",
    "si_unit",
]

#: Units pint cannot do arithmetic with; accepted only as these exact strings.
LOG_UNITS = {"dB": {"dB", "decibel"}, "dB m-1": {"dB m-1", "dB/m", "decibel m-1"}}

_CANONICAL = {
    "degree": "degree",
    "decibel": "dB",
    "delta_decibel / meter": "dB m-1",
    "dimensionless": "1",
    "percent": "%",
}


def _registry() -> pint.UnitRegistry:
    """Return cf-xarray's registry, importing it (which makes it pint's application registry) on first use."""
    registry = globals().get("ureg")
    if registry is None:
        from cf_xarray.units import units as registry  # importing it makes it pint's application registry

        globals().update(ureg=registry, Q_=registry.Quantity)
    return registry


def __getattr__(name: str) -> Any:
    """``ureg`` and ``Q_`` (the registry and its Quantity), built on first access (PEP 562)."""
    if name in ("ureg", "Q_"):
        _registry()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register_units() -> None:
    """Make this registry (cf-xarray's) pint's application registry, the one pint-xarray uses.

    lidarcal builds the registry the first time it parses or converts a unit, and building it
    registers it; call this before ``ds.pint.quantify()`` on a dataset lidarcal has not yet
    read units from (``ds.pint.quantify()`` then understands ``m s-1``, ``%``, ``dB``, ``1``),
    or again if other code replaced the application registry since.
    """
    import pint

    registry = _registry()
    if pint.get_application_registry().get() is not registry:
        pint.set_application_registry(registry)


def cf_units(unit: pint.Unit | str) -> str:
    """Return the UDUNITS/CF spelling of ``unit`` (``degree`` rather than ``deg``)."""
    unit = _registry().Unit(unit) if isinstance(unit, str) else unit
    name = str(unit)
    if name in _CANONICAL:
        return _CANONICAL[name]
    return f"{unit:cf}" or "1"


def parse_unit(text: str, *, where: str) -> pint.Unit:
    """Return ``text`` as a unit of the registry or raise a :class:`UnitError` naming ``where``."""
    try:
        return _registry().Unit(text)
    except Exception as exc:  # pint raises several unrelated types here
        raise UnitError(f"{where}: units {text!r} cannot be parsed ({exc})") from None


def convert_values(values: Any, found: str | None, expected: str, *, where: str) -> np.ndarray:
    """Convert ``values`` from unit ``found`` to ``expected`` or raise a :class:`UnitError`.

    ``where`` names the file and variable in the message, e.g. ``"conditions.nc: variable
    'wind_speed'"``.
    """
    values = np.asarray(values, dtype=float)
    if found is None or str(found).strip() == "":
        raise UnitError(f"{where} has no 'units' attribute; expected units convertible to {expected!r}")
    found = str(found).strip()
    if expected in LOG_UNITS:
        if found in LOG_UNITS[expected]:
            return values
        raise UnitError(f"{where} has units {found!r}; expected {expected!r}")
    if found in {alias for a in LOG_UNITS.values() for alias in a}:
        raise UnitError(f"{where} has units {found!r}; expected units convertible to {expected!r}")
    src, dst = parse_unit(found, where=where), parse_unit(expected, where="expected unit")
    if src.dimensionality != dst.dimensionality:
        raise UnitError(
            f"{where} has units {found!r} ({src.dimensionality}); expected units convertible "
            f"to {expected!r} ({dst.dimensionality})"
        )
    if src == dst:
        return values
    return _registry().Quantity(values, src).to(dst).magnitude


def convert_variable(ds: xr.Dataset, name: str, expected: str, *, source: str = "<dataset>") -> xr.DataArray:
    """Return ``ds[name]`` converted to ``expected`` units, attributes kept, ``units`` updated."""
    if name not in ds.variables:
        raise MissingVariableError(
            f"{source}: required variable {name!r} is missing; found {sorted(map(str, ds.variables))}"
        )
    da = ds[name]
    where = f"{source}: variable {name!r}"
    values = convert_values(da.values, da.attrs.get("units"), expected, where=where)
    out = da.copy(data=values)
    out.attrs = {**da.attrs, "units": expected}
    return out


def to_magnitude(value: Any, expected: str, *, name: str) -> float | np.ndarray:
    """Convert a physical argument to a bare magnitude in ``expected`` units.

    Accepts a pint quantity or a string such as ``"100 m"``.  Bare numbers are refused for
    dimensional quantities (their unit would be a guess) but accepted for dimensionless ones.
    """
    where = f"argument {name!r}"
    if isinstance(value, str):
        number, _, unit = value.strip().partition(" ")
        if unit.strip() in {alias for a in LOG_UNITS.values() for alias in a}:
            # pint would evaluate "0.1 dB m-1" logarithmically; split the number off instead
            try:
                return convert_values(float(number), unit.strip(), expected, where=where).item()
            except ValueError as exc:
                if isinstance(exc, UnitError):
                    raise
                raise UnitError(f"{where}: cannot parse {value!r} as a quantity") from None
        try:
            value = _registry().Quantity(value)
        except Exception as exc:
            raise UnitError(f"{where}: cannot parse {value!r} as a quantity ({exc})") from None
    import pint  # deferred: imported with the registry, which was built above or here

    _registry()
    if isinstance(value, pint.Quantity):
        found = cf_units(value.units)
        out = convert_values(value.magnitude, found, expected, where=where)
        return out.item() if out.ndim == 0 else out
    dimensionless = expected not in LOG_UNITS and parse_unit(expected, where="expected unit").dimensionless
    if isinstance(value, numbers.Number | np.ndarray | list | tuple) and dimensionless:
        return np.asarray(value, dtype=float) if not isinstance(value, numbers.Number) else float(value)
    raise UnitError(
        f"argument {name!r}: got the bare number {value!r}; give a quantity with units "
        f"convertible to {expected!r}, e.g. ureg.Quantity({value!r}, {expected!r})"
    )


#: UDUNITS symbol -> D-SI (BIPM SI brochure) unit macro.
_SI_UNITS = {"m": r"\metre", "s": r"\second", "%": r"\percent", "1": r"\one", "dB": r"\decibel",
             "K": r"\kelvin", "kg": r"\kilogram", "rad": r"\radian", "degree": r"\degree", "Hz": r"\hertz",
             "W": r"\watt", "Pa": r"\pascal", "hPa": r"\hecto\pascal", "km": r"\kilo\metre", "h": r"\hour",
             "min": r"\minute", "degC": r"\degreecelsius"}


def si_unit(units: str) -> str:
    """D-SI unit text of a UDUNITS unit string such as ``"m s-1"``, ``"%"`` or ``"% dB-1 m"``.

    Raises
    ------
    UnitError
        For a unit symbol lidarcal does not know how to write in D-SI.
    """
    text = str(units).strip()
    if text in ("", "1"):
        return r"\one"
    out = []
    for token in text.split():
        m = re.fullmatch(r"([A-Za-z%]+)(\^?[-+]?\d+)?", token)
        if not m or m.group(1) not in _SI_UNITS:
            raise UnitError(f"unit {units!r}: no D-SI form known for {token!r}; known symbols "
                             f"{sorted(_SI_UNITS)}")
        power = int(m.group(2).lstrip("^")) if m.group(2) else 1
        out.append(_SI_UNITS[m.group(1)] + (rf"\tothe{{{power}}}" if power != 1 else ""))
    return "".join(out)
