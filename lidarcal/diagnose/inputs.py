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
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import open_artefact, source_name
from lidarcal.lidar import LidarModel
from lidarcal.lidar.geometry import check_reachable

__all__ = ["MEASURED", "check_field", "load_field", "min_periods", "nominal_model", "open_field"]

log = logging.getLogger("lidarcal.diagnose")

#: The measured pair a field campaign adds to the conditions.
MEASURED = ("lidar_wind_speed", "reference_wind_speed")


def min_periods(n_bins: int, min_bin_count: int) -> int:
    """Usable periods a height needs: enough to fill every bin of every variable."""
    return int(n_bins) * int(min_bin_count)


def open_field(field: str | os.PathLike | xr.Dataset) -> tuple[xr.Dataset, str]:
    """Open a field campaign (a path or a dataset) and require its measured pair; return (dataset, source)."""
    source = source_name(field, "<field campaign>")
    raw = field if isinstance(field, xr.Dataset) else open_artefact(field)
    missing = [n for n in MEASURED if n not in raw.variables]
    if missing:
        raise MissingVariableError(
            f"{source}: the measured pair is incomplete: variable(s) {missing} missing; a field_campaign "
            f"needs 'lidar_wind_speed' and 'reference_wind_speed' (m s-1) on (time, height); found "
            f"{sorted(map(str, raw.data_vars))}")
    return raw, source


def load_field(field: str | os.PathLike | xr.Dataset, *, n_bins: int, min_bin_count: int,
               min_wind_speed: float) -> tuple[xr.Dataset, np.ndarray, str]:
    """Open and check a field campaign; return (dataset, usable mask (time, height), source).

    A period is usable at a height when the measured pair and all six conditions are finite
    and the reference is at least ``min_wind_speed``.  Heights with fewer than
    :func:`min_periods` usable periods are dropped (with a log message); none left is an error.
    """
    raw, source = open_field(field)
    for name in MEASURED:
        if not np.isfinite(np.asarray(raw[name].values, dtype=float)).any():
            raise InputError(f"{source}: variable {name!r} is NaN everywhere; expected measured 10-minute "
                             f"wind speeds (m s-1) in at least {min_periods(n_bins, min_bin_count)} periods")
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
