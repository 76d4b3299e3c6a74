"""The RWF as the virtual lidar carries it: quadrature nodes and the continuous profile, by value or digest.

:func:`rwf_nodes` reduces an ``rwf`` artefact to what :class:`~lidarcal.lidar.model.LidarModel`
holds (``rwf_offsets``, ``rwf_weights``, ``rwf_profile``); :class:`RwfProfileDigest` is a
profile an artefact's attribute form records only by its SHA-256 (:func:`rwf_profile_digest`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import source_name
from lidarcal.lidar.quadrature import gauss_rwf_nodes, trapezoid_weights
from lidarcal.rwf.kernels import barycenter
from lidarcal.units import convert_variable

__all__ = ["RwfProfileDigest", "rwf_profile_digest", "rwf_nodes"]


@dataclasses.dataclass(frozen=True)
class RwfProfileDigest:
    """An RWF profile known only by digest (:attr:`LidarModel.rwf_profile` of an attribute-form record).

    ``sha256`` is :func:`rwf_profile_digest` of the profile, ``count`` its number of points;
    :meth:`LidarModel.with_rwf` restores the values from the RWF artefact the model was built from.
    """

    sha256: str
    count: int
    #: What error messages call the record holding it; not part of the record.
    origin: str = dataclasses.field(default="lidar model", compare=False, repr=False)

    def to_dict(self) -> dict[str, Any]:
        """Return the attribute form: ``{"sha256": ..., "count": ...}``."""
        return {"sha256": self.sha256, "count": self.count}


def rwf_profile_digest(profile: Any) -> str:
    """SHA-256 of an RWF profile: its offsets then its values, little-endian float64."""
    import hashlib

    values = np.ascontiguousarray(np.asarray(profile, dtype=float), dtype="<f8")
    return hashlib.sha256(values.tobytes()).hexdigest()


def rwf_nodes(rwf: xr.Dataset, n_nodes: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Return an ``rwf`` artefact's ``n_nodes`` Gauss nodes (m), weights and continuous profile.

    The ``cnr_gradient = 0`` column, re-centred on the recorded zero distance (the barycentre
    when none is recorded); the profile ``(offsets (m), values)`` on a 0.5-m grid where the RWF
    exceeds 1e-6 of its peak, normalised to its peak.
    """
    src = source_name(rwf)
    if "rwf" not in rwf.variables:
        raise MissingVariableError(f"{src}: rwf artefact has no variable 'rwf'; "
                                   f"found {sorted(map(str, rwf.variables))}")
    values = convert_variable(rwf, "rwf", "m-1", source=src)
    offsets = convert_variable(rwf, "range_offset", "m", source=src)
    if "cnr_gradient" in values.dims:
        grad = convert_variable(rwf, "cnr_gradient", "dB m-1", source=src).values
        values = values.isel(cnr_gradient=int(np.argmin(np.abs(grad))))
        if abs(grad).min() > 1e-9:
            raise InputError(f"{src}: variable 'cnr_gradient' has no 0 dB m-1 column; found {grad.tolist()}")
    values = values.transpose("range_offset")
    order = np.argsort(offsets.values)
    s, g = offsets.values[order], values.values[order]
    # The lidar applies its calibrated zero distance (the barycentre of the full RWF, paper
    # §3.2): its gates are centred on that barycentre, so the nodes are re-centred on it.
    if "zero_distance" in rwf.variables:
        zd = float(convert_variable(rwf, "zero_distance", "m", source=src).values)
    else:
        zd = float(barycenter(g * trapezoid_weights(s), s))  # trapezoid rule on a non-uniform table
    try:
        nodes, weights = gauss_rwf_nodes(s, g, n_nodes)
    except ValueError as exc:
        raise InputError(f"{src}: variable 'rwf' cannot be reduced to {n_nodes} nodes: {exc}") from None
    # the continuous RWF for the turbulence filter, on a 0.5-m grid where it exceeds 1e-6 of its peak
    keep = np.flatnonzero(g > 1e-6 * g.max())
    grid = np.arange(np.ceil(s[keep[0]] / 0.5), np.floor(s[keep[-1]] / 0.5) + 1) * 0.5
    profile = (tuple(np.round(grid - zd, 6).tolist()),
               tuple(float(v) for v in np.interp(grid, s, g / g.max()).round(9)))
    return nodes - zd, weights, profile
