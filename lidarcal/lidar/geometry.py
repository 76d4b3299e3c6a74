"""Geometry of the virtual DBS lidar: beam directions, range gates, sample points.

One place for where the lidar looks.  Lidar frame: x east, y north, z up; azimuth clockwise
from north.  Beam ``b`` points along ``(sin φ sin θ_b, sin φ cos θ_b, cos φ)`` with the *true*
cone ``φ = cone_angle + beam_angle_offset``; the gate for height ``h`` is placed with the
*nominal* cone (what the lidar believes) at ``h / cos(cone_angle)``.
"""

from __future__ import annotations

import numpy as np

from lidarcal.errors import InputError
from lidarcal.lidar.model import LidarModel

__all__ = ["beam_geometry", "gate_ranges", "height_points", "period_points", "wind_axes", "check_reachable"]


def beam_geometry(model: LidarModel) -> tuple[np.ndarray, float, float]:
    """Return the beams' unit vectors ``(4, 3)`` (true cone) and the true and nominal cone (radians)."""
    phi_true = np.radians(model.cone_angle + model.beam_angle_offset)
    theta = np.radians(np.asarray(model.azimuths))
    units = np.stack([np.sin(phi_true) * np.sin(theta), np.sin(phi_true) * np.cos(theta),
                      np.full(4, np.cos(phi_true))], axis=-1)
    return units, phi_true, np.radians(model.cone_angle)


def gate_ranges(model: LidarModel, height: float) -> np.ndarray:
    """Ranges (m) of the RWF quadrature nodes of a gate placed for ``height``.

    The gate's nominal centre is at ``height / cos(cone_angle)`` (nominal cone); it sits
    ``zero_distance_offset`` further out, and node ``k`` at ``rwf_offsets[k]`` beyond that.
    """
    _, _, phi_nom = beam_geometry(model)
    return height / np.cos(phi_nom) + model.zero_distance_offset + np.asarray(model.rwf_offsets, dtype=float)


def height_points(model: LidarModel, height: float) -> np.ndarray:
    """Lidar-frame positions ``(4, K, 3)`` (east, north, up; m) of the RWF nodes of every beam."""
    units, _, _ = beam_geometry(model)
    return gate_ranges(model, height)[None, :, None] * units[:, None, :]


def wind_axes(wind_from_direction: float) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal unit vectors (east, north) of the downwind direction and of the cross-wind (left)."""
    th = np.radians(wind_from_direction)
    down = np.array([-np.sin(th), -np.cos(th)])
    return down, np.array([-down[1], down[0]])


def period_points(model: LidarModel, height: float, wind_from_direction: float) -> dict[str, np.ndarray]:
    """Return the points one height needs: the 4 x K RWF nodes (beam-major) and the reference.

    Keys: ``label`` (``"beam<azimuth>_node<k>"``, ``"reference"``), ``lidar`` (n, 3; east,
    north, up in m) and ``wind`` (n, 3; along-wind, cross-wind to the left, up in m), in the
    order :func:`simulate_period` passes them to the turbulence generator.
    """
    pts = height_points(model, height)
    if np.any(pts[..., 2] <= 0):
        raise InputError(f"height {height:g} m: the RWF nodes reach below the ground "
                         f"(lowest node z = {pts[..., 2].min():.3g} m); the RWF is too wide for this height")
    down, cross = wind_axes(wind_from_direction)
    flat = np.concatenate([pts.reshape(-1, 3), [[0.0, 0.0, height]]])
    wind = np.stack([flat[:, :2] @ down, flat[:, :2] @ cross, flat[:, 2]], axis=-1)
    labels = [f"beam{a:g}_node{k}" for a in model.azimuths for k in range(pts.shape[1])] + ["reference"]
    return {"label": np.array(labels), "lidar": flat, "wind": wind}



def check_reachable(model: LidarModel, heights: np.ndarray) -> list[str]:
    """Problems with measuring at ``heights`` (m) with ``model``; empty when all are reachable.

    Each RWF quadrature node of each beam must sit at a positive range and height: the gate is
    placed at range ``h / cos(cone)`` (nominal cone), moved by ``zero_distance_offset`` and
    the node offset (:func:`gate_ranges`), and seen along the true cone
    ``cone + beam_angle_offset``.
    """
    problems = []
    _, phi_true, phi_nom = beam_geometry(model)
    offsets = np.asarray(model.rwf_offsets, dtype=float)
    for h in np.asarray(heights, dtype=float):
        if not np.isfinite(h) or h <= 0:
            problems.append(f"height {h:g} m is not > 0")
            continue
        ranges = gate_ranges(model, h)
        if ranges.min() <= 0 or (ranges * np.cos(phi_true)).min() <= 0:
            problems.append(
                f"height {h:g} m needs range {ranges.min():.4g} m for the nearest RWF node "
                f"(gate {h / np.cos(phi_nom):.4g} m, zero-distance offset {model.zero_distance_offset:g} m, "
                f"RWF reaching {offsets.min():.4g} m); the RWF would extend below the lidar"
            )
    return problems
