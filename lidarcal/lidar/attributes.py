"""The ``lidar_*`` global attributes of a ``conditions`` / ``field_campaign`` file: the lidar it describes.

They are declared once, under ``read_back`` in ``schemas/conditions.yaml`` (meaning, unit,
range, default; ``field_campaign`` includes them), and read through
:func:`lidarcal.readback.read_attr`.  The declared defaults are :class:`~lidarcal.lidar.LidarModel`'s
field defaults (:data:`LIDAR_DEFAULTS`), so the nominal lidar and a file without the attributes agree
by construction.
"""

from __future__ import annotations

import xarray as xr

from lidarcal.readback import declared_read_back, read_attr

__all__ = ["LIDAR_DEFAULTS", "LIDAR_ATTRIBUTES", "lidar_attributes", "lidar_cnr_threshold"]

_DECLARED = declared_read_back("conditions")
#: The nominal lidar's configuration, as the schema declares it (LidarModel's field defaults).
LIDAR_DEFAULTS: dict[str, float] = {
    name: float(_DECLARED[name]["default"])
    for name in ("lidar_cone_angle", "lidar_hybrid_weight", "lidar_rwf_fwhm", "lidar_los_noise_std",
                 "lidar_beam_period")}

#: Optional global attributes of a ``conditions`` / ``field_campaign`` file giving the lidar's
#: nominal configuration: ``name: (default, meaning, lower bound, upper bound, zero allowed)``.
LIDAR_ATTRIBUTES: dict[str, tuple[float, str, float, float, bool]] = {
    name: (default, _DECLARED[name]["description"], float(_DECLARED[name]["range"][0]),
           float(_DECLARED[name]["range"][1]), not _DECLARED[name].get("exclusive_min", False))
    for name, default in LIDAR_DEFAULTS.items()}


def lidar_attributes(ds: xr.Dataset, *, source: str | None = None) -> dict[str, float]:
    """Return the ``lidar_*`` configuration in ``ds``'s global attributes, defaults filled in.

    Raises :class:`~lidarcal.errors.InputError` naming the file and attribute when a value is
    not a number or outside its range.
    """
    return {name: read_attr(ds, name, kind="conditions", source=source) for name in LIDAR_DEFAULTS}


def lidar_cnr_threshold(ds: xr.Dataset, *, source: str | None = None) -> float | None:
    """Return the CNR filter (dB) ``ds``'s ``lidar_cnr_threshold`` attribute gives, or None.

    ``lidarcal conditions from-sta`` and ``field from-sta`` write the ``.sta`` header's
    ``CNRThreshold`` there (``"not given"`` when the header has none, which counts as absent).
    A value that is neither a finite number in [-60, 20] dB nor ``"not given"`` is an
    :class:`~lidarcal.errors.InputError` naming the file.
    """
    return read_attr(ds, "lidar_cnr_threshold", kind="conditions", source=source)
