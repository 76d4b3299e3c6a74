"""The conditions variables and the measured wind-speed pair, read from their one declaration.

``schemas/conditions.yaml`` declares the six conditions variables and
``schemas/field_campaign.yaml`` the measured pair (``lidar_wind_speed``,
``reference_wind_speed``), each with its canonical unit, long name and CF standard name.
Every module that needs those names, units or attributes takes them from here (a writer takes
a variable's attributes from :func:`variable_attrs`); every schema that carries them copies the
specs with an ``include`` entry (:mod:`lidarcal.schema`).
"""

from __future__ import annotations

from typing import NamedTuple

from lidarcal.schema import declared_variables, output_attrs

__all__ = [
    "Variable",
    "CONDITIONS",
    "FIELD_PAIR",
    "CONDITION_NAMES",
    "FIELD_NAMES",
    "CANONICAL_UNITS",
    "STANDARD_NAMES",
    "variable_attrs",
]


class Variable(NamedTuple):
    """One declared variable: canonical unit, long name, CF standard name (or None)."""

    units: str
    long_name: str
    standard_name: str | None


def _registry(kind: str, exclude: tuple[str, ...] = ()) -> dict[str, Variable]:
    """Return the required variables ``kind`` declares itself (optional ones are not in the contract)."""
    return {
        name: Variable(str(spec["units"]), str(spec["long_name"]), spec.get("standard_name"))
        for name, spec in declared_variables(kind).items()
        if name not in exclude and spec.get("required", True)
    }


#: The six conditions variables of ``docs/contracts.md``, in their declared order.
CONDITIONS: dict[str, Variable] = _registry("conditions")
#: The measured pair a ``field_campaign`` adds.
FIELD_PAIR: dict[str, Variable] = _registry("field_campaign", exclude=tuple(CONDITIONS))
#: Names of the conditions variables (the only legal drivers of a model effect).
CONDITION_NAMES: tuple[str, ...] = tuple(CONDITIONS)
#: Names of the measured pair.
FIELD_NAMES: tuple[str, ...] = tuple(FIELD_PAIR)
#: Canonical unit of every declared variable.
CANONICAL_UNITS: dict[str, str] = {n: v.units for n, v in {**CONDITIONS, **FIELD_PAIR}.items()}
#: CF standard names of the declared variables that have one.
STANDARD_NAMES: dict[str, str] = {
    n: v.standard_name for n, v in {**CONDITIONS, **FIELD_PAIR}.items() if v.standard_name
}


def variable_attrs(name: str, *, content: str = "modelResult", comment: str = "") -> dict:
    """Attributes a writer puts on conditions variable or measured-pair variable ``name``.

    From the schema that declares it (:func:`lidarcal.schema.output_attrs`): ``content`` is the
    ``coverage_content_type`` of a conditions variable (the measured pair is always a
    ``physicalMeasurement``), ``comment`` says how the values were obtained ("" writes none).

    >>> variable_attrs("cnr")["long_name"]
    'carrier-to-noise ratio'
    """
    if name in FIELD_PAIR:
        return output_attrs("field_campaign", name, comment=comment)
    return output_attrs("conditions", name, content=content, comment=comment)
