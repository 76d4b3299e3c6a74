"""What ``lidarcal diagnose`` accepts: a field campaign and the nominal lidar it describes.

:func:`open_field` opens a ``field_campaign`` and requires its measured pair (``compare`` uses it
too); :func:`load_field` checks it and keeps the heights and periods a
diagnosis can use; :func:`check_field` is the same check for ``lidarcal conditions check``;
:func:`nominal_model` is the lidar the file's ``lidar_*`` attributes (and an optional bench cube
or RWF) describe.
"""

from __future__ import annotations

import logging
import os
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.conditions import load_conditions
from lidarcal.conditions.mast import RATIO_LIMITS
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import open_artefact, source_name
from lidarcal.lidar import LidarModel
from lidarcal.lidar.geometry import check_reachable
from lidarcal.readback import read_attr
from lidarcal.units import convert_variable

__all__ = ["MEASURED", "check_field", "load_field", "min_periods", "nominal_model", "open_field"]

log = logging.getLogger("lidarcal.diagnose")

#: The measured pair a field campaign adds to the conditions.
MEASURED = ("lidar_wind_speed", "reference_wind_speed")


def min_periods(n_bins: int, min_bin_count: int) -> int:
    """Usable periods a height needs: enough to fill every bin of every variable."""
    return int(n_bins) * int(min_bin_count)


def open_field(field: str | os.PathLike | xr.Dataset) -> tuple[xr.Dataset, str]:
    """Open a field campaign (a path or a dataset) and check its measured pair; return (dataset, source).

    The pair must be there, each with a finite value somewhere, and the median lidar /
    reference ratio over the periods and heights where both are finite must lie in
    :data:`lidarcal.conditions.mast.RATIO_LIMITS` (the check ``field from-sta`` makes: a reference
    in km/h labelled m/s gives 0.28), unless the file records that the check was skipped on
    purpose (its ``lidar_reference_ratio_checked`` attribute starts with ``no``).

    Raises
    ------
    InputError
        Naming the file and the variable: one of the pair missing or NaN everywhere, or the ratio
        implausible.
    """
    source = source_name(field, "<field campaign>")
    raw = field if isinstance(field, xr.Dataset) else open_artefact(field)
    missing = [n for n in MEASURED if n not in raw.variables]
    if missing:
        raise MissingVariableError(
            f"{source}: the measured pair is incomplete: variable(s) {missing} missing; a field_campaign "
            f"needs 'lidar_wind_speed' and 'reference_wind_speed' (m s-1) on (time, height); found "
            f"{sorted(map(str, raw.data_vars))}")
    for name in MEASURED:
        if not np.isfinite(np.asarray(raw[name].values, dtype=float)).any():
            raise InputError(f"{source}: variable {name!r} is NaN everywhere; expected measured 10-minute "
                             "wind speeds (m s-1)")
    _check_ratio(raw, source)
    return raw, source


def _check_ratio(raw: xr.Dataset, source: str) -> None:
    """Refuse a lidar / reference pair whose median ratio is implausible (a unit or column mix-up)."""
    lidar, ref = (convert_variable(raw, name, "m s-1", source=source) for name in MEASURED)
    lidar, ref = xr.broadcast(lidar, ref)
    a, b = np.asarray(lidar.values, dtype=float), np.asarray(ref.values, dtype=float)
    both = np.isfinite(a) & np.isfinite(b) & (b > 0)
    if not both.any():
        raise InputError(f"{source}: variables 'lidar_wind_speed' and 'reference_wind_speed' are never "
                         "both finite (with a reference above 0) in the same period and height: nothing to "
                         "compare")
    ratio = float(np.median(a[both] / b[both]))
    lo, hi = RATIO_LIMITS
    if lo <= ratio <= hi:
        return
    checked = read_attr(raw, "lidar_reference_ratio_checked", kind="field_campaign")
    skipped = checked.strip().lower().startswith("no")
    if skipped:  # accepted knowingly when the campaign was made (field from-sta --skip-ratio-check)
        log.warning("%s: median lidar_wind_speed / reference_wind_speed ratio %.3f is outside [%g, %g]; "
                    "accepted: the file says the ratio check was skipped (%s)", source, ratio, lo, hi,
                    checked)
        return
    units = {name: raw[name].attrs.get("units", "no units") for name in MEASURED}
    raise InputError(
        f"{source}: the median ratio of variable 'lidar_wind_speed' ({units['lidar_wind_speed']}) to "
        f"variable 'reference_wind_speed' ({units['reference_wind_speed']}) is {ratio:.3f} over "
        f"{int(both.sum())} period-heights, outside the plausible [{lo:g}, {hi:g}] (a reference in km/h "
        f"labelled m s-1 gives {1 / 3.6:.2f}): is one of them in another unit than its units attribute "
        "says, or the wrong column? If the pair really differs this much, set the global attribute "
        "lidar_reference_ratio_checked to 'no: <why>' (field from-sta --skip-ratio-check does)")


def load_field(field: str | os.PathLike | xr.Dataset, *, n_bins: int, min_bin_count: int,
               min_wind_speed: float) -> tuple[xr.Dataset, np.ndarray, str]:
    """Open and check a field campaign; return (dataset, usable mask (time, height), source).

    A period is usable at a height when the measured pair and all six conditions are finite
    and the reference is at least ``min_wind_speed``.  Heights with fewer than
    :func:`min_periods` usable periods are dropped (with a log message); none left is an error.
    """
    raw, source = open_field(field)  # the pair present, finite somewhere, in a plausible ratio
    ds = load_conditions(raw, kind="field_campaign", warn=False)
    ref = ds["reference_wind_speed"].values
    usable = np.asarray(ds["input_complete"].values, dtype=bool) & (ref >= min_wind_speed)
    need = min_periods(n_bins, min_bin_count)
    counts = usable.sum(axis=0)
    keep = counts >= need
    if not keep.any():
        raise InputError(
            f"{source}: too few usable periods: at most {int(counts.max())} per height have the measured "
            f"pair, "
            f"all six conditions and reference_wind_speed >= {min_wind_speed:g} m s-1; diagnose needs at "
            f"least {need} per height ({n_bins} bins x {min_bin_count} periods)")
    if not keep.all():
        log.warning("%s: dropping height(s) %s m: fewer than %d usable periods (%s)", source,
                    ds.height.values[~keep].tolist(), need, counts[~keep].tolist())
    ds = ds.isel(height=np.flatnonzero(keep))
    usable = usable[:, keep]
    rows = usable.any(axis=1)
    return ds.isel(time=np.flatnonzero(rows)), usable[rows], source


def nominal_model(ds: xr.Dataset, *, cube: xr.Dataset | None = None, rwf: xr.Dataset | None = None):
    """Return the nominal lidar: the file's ``lidar_*`` attributes, configured from cube/RWF if given."""
    return LidarModel.from_attrs(ds, cube=cube, rwf=rwf)


def check_field(field: str | os.PathLike | xr.Dataset, *, cube: xr.Dataset | None = None,
                rwf: xr.Dataset | None = None, model: Any = None, n_bins: int = 6, min_bin_count: int = 10,
                min_wind_speed: float = 3.0) -> tuple[xr.Dataset, np.ndarray, str, Any]:
    """Every check :func:`diagnose` makes of its inputs before simulating: the one field_campaign check.

    :func:`load_field` (contract, measured pair, enough usable periods per height), the nominal
    model from the ``lidar_*`` attributes (or ``cube``/``rwf``, or ``model``) and the heights
    the lidar can reach.  ``lidarcal conditions check --kind field_campaign`` runs it with
    diagnose's defaults.  Returns (dataset, usable mask, source, nominal model).
    """
    ds, usable, source = load_field(field, n_bins=n_bins, min_bin_count=min_bin_count,
                                    min_wind_speed=min_wind_speed)
    if model is None:
        model = nominal_model(ds, cube=cube, rwf=rwf)
    _check_reachable(model, ds.height.values, source)
    return ds, usable, source, model


def _check_reachable(model, heights: np.ndarray, source: str) -> None:
    """Refuse heights whose range gate (with the RWF's extent) would reach below the lidar."""
    problems = check_reachable(model, heights)
    if problems:
        raise InputError(f"{source}: variable 'height': heights the lidar cannot measure with this RWF and "
                         f"geometry: " + "; ".join(problems))
