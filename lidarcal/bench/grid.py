"""The ℓcv-bin grid of the SAFO-MV sweep (paper Table 1) and the DBS beam geometry.

Five lines of sight (four oblique beams at 62° elevation, i.e. 28° from vertical, at
azimuths 0°, 90°, 180°, 270°, and the vertical beam "V"), CNR −28…−6 dB in 2 dB steps and
programmed radial velocity −18…18 m/s in 1 m/s steps.  Bin edges lie half a step either
side of each node, so a programmed value is assigned to the bin whose node it is nearest.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "LOS_LABELS", "LOS_AZIMUTH", "LOS_ELEVATION", "CNR_NODES", "CNR_EDGES",
    "VELOCITY_NODES", "VELOCITY_EDGES", "los_index", "grid_index",
]

#: LOS labels in cube order (the ``los`` coordinate of a ``bench_cube``).
LOS_LABELS = ("0", "90", "180", "270", "V")
#: Beam azimuth per LOS, degree (the vertical beam is given 0).
LOS_AZIMUTH = np.array([0.0, 90.0, 180.0, 270.0, 0.0])
#: Beam elevation per LOS, degree (62° oblique = 28° from vertical; 90° vertical).
LOS_ELEVATION = np.array([62.0, 62.0, 62.0, 62.0, 90.0])

#: Programmed CNR nodes, dB (Table 1: −28 … −6 dB in 2 dB steps; 12 values).
CNR_NODES = np.arange(-28.0, -6.0 + 1e-9, 2.0)
CNR_EDGES = np.append(CNR_NODES - 1.0, CNR_NODES[-1] + 1.0)
#: Programmed radial velocity nodes, m s-1 (Table 1: −18 … 18 m/s in 1 m/s steps; 37 values).
VELOCITY_NODES = np.arange(-18.0, 18.0 + 1e-9, 1.0)
VELOCITY_EDGES = np.append(VELOCITY_NODES - 0.5, VELOCITY_NODES[-1] + 0.5)


def los_index(labels: np.ndarray) -> np.ndarray:
    """Cube index (0–4) of each LOS label; −1 for a label that is not one of :data:`LOS_LABELS`."""
    labels = np.asarray(labels, dtype=str)
    known = np.asarray(LOS_LABELS)
    order = np.argsort(known)
    pos = np.searchsorted(known[order], labels)
    pos = np.clip(pos, 0, len(known) - 1)
    hit = known[order][pos] == labels
    return np.where(hit, order[pos], -1)


def grid_index(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin index of each value for contiguous bins ``edges``; −1 outside ``[edges[0], edges[-1])``."""
    values = np.asarray(values, dtype=float)
    idx = np.searchsorted(edges, values, side="right") - 1
    return np.where((idx >= 0) & (idx < len(edges) - 1), idx, -1)
