"""What a raw reading of a lidar ``.sta`` file or a met-mast CSV may be: one rule for both readers.

- A cell is a number, or **missing**: empty, or one of :data:`MISSING_MARKERS` in any case
  (``NaN``, ``NA``, ``N/A``, ``null``, ``none``, ``-``), what WindCube firmware and common
  loggers and spreadsheets write for "no value".  Anything else (``n/a?``, ``12,5``, ``inf``)
  is refused with the file, line and column (:func:`read_numbers`).
- A number that is a logger's missing-data code (:data:`SENTINELS`: 9999, -999 ...) is refused,
  never read as a measurement nor silently dropped: the file must say NaN where it means it.
- A raw reading outside the physical range of the conditions contract (:data:`RAW_RANGES`) is
  refused with the reason (:func:`value_problem`: a sentinel, a negative speed, a direction in a
  speed column); a *derived* value (TI, shear exponent, CNR gradient) outside the contract's
  range is set missing and counted (:func:`set_missing_out_of_range`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

from lidarcal.errors import raise_first_bad
from lidarcal.schema import declared_variables

__all__ = ["PERIOD", "MISSING_MARKERS", "SENTINELS", "RAW_RANGES", "DERIVED_LIMITS", "read_numbers",
           "value_problem", "set_missing_out_of_range"]

#: Length of a 10-minute statistics interval.
PERIOD = np.timedelta64(600, "s")

#: Cell texts (lower case, stripped) that mean "no value"; an empty cell does too.
MISSING_MARKERS = ("nan", "na", "n/a", "null", "none", "-")

#: Values that loggers write for "no data": reported as such, never read as a measurement.
SENTINELS = (9999.0, -999.0, -9999.0, 999.0, 99999.0, -99999.0, 999999.0)


def _range(name: str) -> tuple[float, float]:
    lo, hi = declared_variables("conditions")[name]["range"]
    return lo, hi


#: Physical range of each raw column read and its unit (the conditions contract's ranges,
#: ``schemas/conditions.yaml``).
RAW_RANGES = {
    "speed": (_range("wind_speed"), "m/s"),
    "dispersion": (_range("wind_speed"), "m/s"),
    "direction": (_range("wind_from_direction"), "degree"),
    "cnr": (_range("cnr"), "dB"),
    "availability": ((0.0, 100.0), "%"),
}

#: Contract ranges of the derived variables: beyond them a value is an artefact of a tiny speed
#: (TI, shear) or a noisy CNR and is left missing, not clipped.
DERIVED_LIMITS = {name: _range(name)
                  for name in ("turbulence_intensity", "wind_shear_exponent", "cnr_gradient")}


def read_numbers(cells: pd.Series, where: Callable[[int], str]) -> np.ndarray:
    """Return the numbers of a column of text cells, NaN where a cell is missing (module docstring).

    ``where(r)`` names row ``r`` for the message (``"file: line 12, column 3 ('Spd80')"``).

    >>> read_numbers(pd.Series(["8.5", "", "NaN", "N/A", "-", " 7 "]), str).tolist()
    [8.5, nan, nan, nan, nan, 7.0]
    """
    text = cells.fillna("").astype(str).str.strip()
    missing = (text == "") | text.str.lower().isin(MISSING_MARKERS)
    values = pd.to_numeric(text.where(~missing, "NaN"), errors="coerce").to_numpy(dtype=float)
    raise_first_bad(~np.isfinite(values) & ~missing.to_numpy(), lambda r, n: (
        f"{where(r)}: expected a number; found {text.iloc[r]!r} ({n} such cell(s)); a "
        f"missing value is an empty cell or one of NaN, NA, N/A, null, none, -"))
    return values


def value_problem(value: float, role: str, lo: float, hi: float, unit: str) -> str:
    """Why ``value`` (outside [lo, hi]) cannot be a ``role`` reading: sentinel, negative, swapped column."""
    if value in SENTINELS:
        return (f"{value:g} is a missing-data code (sentinel), not a measurement; expected {unit} in "
                f"[{lo:g}, {hi:g}] or NaN")
    if role in ("speed", "dispersion") and value < 0:
        return f"negative wind speed {value:g} {unit}; expected {unit} in [{lo:g}, {hi:g}] or NaN"
    hint = ""
    if role in ("speed", "dispersion") and hi < value <= 360:
        hint = " (it looks like a wind direction: are the column names swapped?)"
    return f"expected {unit} in [{lo:g}, {hi:g}] or NaN; found {value:g}{hint}"


def set_missing_out_of_range(values: dict[str, np.ndarray],
                             limits: dict[str, tuple[float, float]]) -> dict[str, int]:
    """Set values outside ``limits`` to NaN in place; return how many per variable (those with any)."""
    counts = {}
    for name, (lo, hi) in limits.items():
        v = values[name]
        bad = np.isfinite(v) & ((v < lo) | (v > hi))
        if bad.any():
            v[bad] = np.nan
            counts[name] = int(bad.sum())
    return counts
