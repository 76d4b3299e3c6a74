"""The user's own uncertainty terms of a campaign (mounting, flow inhomogeneity from a CFD study …).

A small YAML file lists them; each becomes a contributor of ``lidarcal smc`` under its name::

    terms:
      - name: flow_inhomogeneity
        value: 0.5
        unit: "%"                  # "%" of the wind speed, or a speed ("m s-1", "m/s")
        distribution: normal       # normal: value is the standard uncertainty;
                                   # rectangular / triangular: value is the half-width a
        source: "CFD study of the site, report XYZ-2024, table 5"
      - name: mounting
        value: 0.02
        unit: m s-1
        distribution: rectangular
        source: "tripod levelled to 0.5 degree (installation report)"

The standard uncertainty is ``value`` (normal), ``a/√3`` (rectangular) or ``a/√6``
(triangular) (GUM 4.3.7 and 4.3.9); a term in % scales with each period's wind speed.  Every
key is required; a file with anything else (an unknown key, a name used twice or taken by a
built-in contributor, a unit that is neither a percentage nor a speed, a negative value) is
refused naming the file, the term and the key.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from lidarcal.errors import InputError
from lidarcal.io import check_input_file
from lidarcal.units import ureg

__all__ = ["UserTerm", "load_user_terms", "DISTRIBUTIONS", "BUILT_IN"]

#: Distribution -> divisor turning ``value`` into a standard uncertainty (GUM 4.3.7, 4.3.9).
DISTRIBUTIONS = {"normal": 1.0, "rectangular": math.sqrt(3.0), "triangular": math.sqrt(6.0)}
#: Contributor names lidarcal computes itself: a user term may not take them.
BUILT_IN = ("calibration", "environmental_iec", "environmental_monte_carlo")
_KEYS = ("name", "value", "unit", "distribution", "source")
_NAME = re.compile(r"^[a-z][a-z0-9_]{0,63}$")


@dataclass(frozen=True)
class UserTerm:
    """One user term: its standard uncertainty is relative (a fraction of U) or absolute (m s-1)."""

    name: str
    value: float
    unit: str
    distribution: str
    source: str
    relative: bool  #: True: ``standard`` is a fraction of the wind speed; False: m s-1

    @property
    def standard(self) -> float:
        """The standard uncertainty: a fraction of the wind speed (relative) or m s-1."""
        scale = 0.01 if self.relative else 1.0
        factor = float(ureg.Quantity(1.0, self.unit).to("percent" if self.relative else "m/s").magnitude)
        return self.value * factor * scale / DISTRIBUTIONS[self.distribution]

    def at(self, speed: np.ndarray) -> np.ndarray:
        """Return the term's standard uncertainty (m s-1) at wind speeds ``speed`` (m s-1)."""
        speed = np.asarray(speed, dtype=float)
        return self.standard * speed if self.relative else np.where(np.isfinite(speed), self.standard, np.nan)

    def describe(self) -> dict:
        """Return the term as recorded in the artefact."""
        return {
            "name": self.name,
            "value": self.value,
            "unit": self.unit,
            "distribution": self.distribution,
            "source": self.source,
        }


def _unit(text: str, where: str) -> bool:
    """Return True for a percentage, False for a speed; refuse anything else."""
    try:
        q = ureg.Quantity(1.0, text)
    except Exception:  # pint raises many types for unparsable text
        raise InputError(
            f"{where}: key 'unit': expected '%' or a speed such as 'm s-1'; found {text!r}"
        ) from None
    if q.check("[length]/[time]"):
        return False
    if q.dimensionless and text.strip() in ("%", "percent"):
        return True
    raise InputError(
        f"{where}: key 'unit': expected '%' (of the wind speed) or a speed such as 'm s-1'; found {text!r}"
    )


def load_user_terms(path: str | os.PathLike) -> list[UserTerm]:
    """Read the user terms YAML file (module docstring); raise :class:`InputError` naming what is wrong."""
    path = check_input_file(path, "user terms YAML file")
    try:
        doc = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable YAML file: {exc}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("terms"), list):
        raise InputError(
            f"{path}: expected a mapping with a list 'terms' (each: {', '.join(_KEYS)}); found "
            f"{type(doc).__name__ if not isinstance(doc, dict) else sorted(doc)}"
        )
    extra = sorted(set(doc) - {"terms"})
    if extra:
        raise InputError(f"{path}: unknown top-level key(s) {extra}; expected only 'terms'")
    out: list[UserTerm] = []
    for k, item in enumerate(doc["terms"], start=1):
        where = f"{path}: term {k}"
        if not isinstance(item, dict):
            raise InputError(f"{where}: expected a mapping with keys {list(_KEYS)}; found {item!r}")
        where = f"{path}: term {k} ({item.get('name', 'unnamed')!r})"
        missing = [key for key in _KEYS if key not in item]
        unknown = sorted(set(item) - set(_KEYS))
        if missing or unknown:
            raise InputError(f"{where}: expected keys {list(_KEYS)}; missing {missing}, unknown {unknown}")
        name = str(item["name"])
        if not _NAME.match(name) or name in BUILT_IN or name in {t.name for t in out}:
            why = (
                "taken by a built-in contributor"
                if name in BUILT_IN
                else "used twice"
                if name in {t.name for t in out}
                else "not lower-case letters, digits and _"
            )
            raise InputError(
                f"{where}: key 'name': {name!r} is {why}; expected a new name such as 'flow_inhomogeneity'"
            )
        try:
            value = float(item["value"])
        except (TypeError, ValueError):
            value = float("nan")
        if not (math.isfinite(value) and value >= 0):
            raise InputError(f"{where}: key 'value': expected a finite number >= 0; found {item['value']!r}")
        dist = str(item["distribution"])
        if dist not in DISTRIBUTIONS:
            raise InputError(
                f"{where}: key 'distribution': expected one of {list(DISTRIBUTIONS)}; found {dist!r}"
            )
        source = str(item["source"]).strip()
        if not source:
            raise InputError(
                f"{where}: key 'source': expected where the value comes from; found an empty text"
            )
        relative = _unit(str(item["unit"]), where)
        out.append(
            UserTerm(
                name=name,
                value=value,
                unit=str(item["unit"]),
                distribution=dist,
                source=source,
                relative=relative,
            )
        )
    return out
