"""The "true" LOS response of a simulated lidar on the bench: bias, noise and bad estimates.

Pure numpy: everything is in SI floats (velocities in m s-1, CNR in dB, probabilities in 1).

Default (WindCube-like) model, per LOS index ``l``::

    std(l, c, v)  = std_scale * g_l * (sigma_floor + sigma_low * exp(-k * (c - c_ref))) * (1 + a_v * |v|)
    bias(l, c, v) = bias_scale * (b_l + beta_v * v + beta_c * (c - c_mid)) + bias_offset
    p_bad(c)      = p_max / (1 + exp((c - c_bad) / w_bad))

With the defaults, std is 0.050 m/s at −10 dB and 0.300 m/s at −26 dB (v = 0, LOS gain 1),
the bias is a few cm/s and drifts mildly with velocity and CNR, and the probability of a
bad estimate (a uniform random velocity in the lidar's ±30 m/s range) is about 3 % at
−22 dB, 10 % at −24 dB, 25 % at −26 dB and 40 % at −28 dB, but below 0.3 % above −18 dB.

``bias_offset`` and ``std_scale`` model run-to-run (operator) variation: each can be a
scalar or an array of shape (5, 12, 37) on the ℓcv grid (:mod:`lidarcal.bench.grid`),
looked up at the nearest grid node.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from lidarcal.bench.grid import CNR_EDGES, CNR_NODES, VELOCITY_EDGES, VELOCITY_NODES

__all__ = ["TrueResponse"]

_GRID_SHAPE = (5, len(CNR_NODES), len(VELOCITY_NODES))


def _nearest(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    idx = np.searchsorted(edges, values, side="right") - 1
    return np.clip(idx, 0, len(edges) - 2)


@dataclass(frozen=True)
class TrueResponse:
    """Smooth model of a lidar's LOS bias and noise as functions of LOS, CNR and velocity.

    All parameters are SI floats (m s-1, dB, 1).  ``to_dict`` gives a JSON-serialisable
    record for provenance (array-valued ``bias_offset``/``std_scale`` are summarised).
    """

    sigma_floor: float = 0.04          #: m s-1, high-CNR noise floor
    sigma_low: float = 0.26            #: m s-1, extra noise at c_ref
    sigma_cnr_ref: float = -26.0       #: dB
    sigma_decay: float = 0.2036        #: 1/dB, so that std(-10 dB) = 0.05 m/s
    sigma_velocity_slope: float = 0.002  #: relative std increase per m/s of |v|
    los_std_gain: tuple[float, ...] = (1.0, 1.03, 0.98, 1.01, 0.95)
    los_bias: tuple[float, ...] = (0.02, -0.01, 0.015, -0.02, 0.01)  #: m s-1 per LOS
    bias_velocity_slope: float = 0.0008  #: (m s-1) per (m s-1)
    bias_cnr_slope: float = -0.001       #: m s-1 per dB
    bias_cnr_mid: float = -17.0          #: dB
    bias_scale: float = 1.0              #: multiplies the systematic bias model
    bias_offset: Any = 0.0               #: m s-1, scalar or (5, 12, 37) grid array (run effect)
    std_scale: Any = 1.0                 #: 1, scalar or (5, 12, 37) grid array (run effect)
    bad_probability_max: float = 0.5
    bad_cnr_midpoint: float = -26.0      #: dB
    bad_cnr_width: float = 1.5           #: dB
    velocity_range: float = 30.0         #: m s-1, a bad estimate is uniform in ±velocity_range
    cnr_noise_std: float = 0.2           #: dB, noise of the lidar's own CNR estimate
    noise_floor_cnr: float = -33.0       #: dB, CNR reported on a beam the bench does not feed

    def __post_init__(self):
        for name in ("bias_offset", "std_scale"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.ndim and value.shape != _GRID_SHAPE:
                raise ValueError(f"TrueResponse.{name} must be a scalar or have shape {_GRID_SHAPE}; "
                                 f"found shape {value.shape}")
        if len(self.los_std_gain) != 5 or len(self.los_bias) != 5:
            raise ValueError("TrueResponse.los_std_gain and los_bias need one value per LOS (5)")

    def _grid_term(self, name: str, los: np.ndarray, cnr: np.ndarray, v: np.ndarray) -> np.ndarray:
        value = np.asarray(getattr(self, name), dtype=float)
        if value.ndim == 0:
            return np.broadcast_to(value, np.broadcast(los, cnr, v).shape)
        return value[los, _nearest(cnr, CNR_EDGES), _nearest(v, VELOCITY_EDGES)]

    def std(self, los: np.ndarray, cnr: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Noise standard deviation, m s-1, for LOS index ``los`` at CNR ``cnr`` (dB), velocity ``v``."""
        los, cnr, v = np.asarray(los), np.asarray(cnr, float), np.asarray(v, float)
        base = self.sigma_floor + self.sigma_low * np.exp(-self.sigma_decay * (cnr - self.sigma_cnr_ref))
        gain = np.asarray(self.los_std_gain)[los]
        speed = 1 + self.sigma_velocity_slope * np.abs(v)
        return self._grid_term("std_scale", los, cnr, v) * gain * base * speed

    def bias(self, los: np.ndarray, cnr: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Systematic bias (mean measured − true), m s-1."""
        los, cnr, v = np.asarray(los), np.asarray(cnr, float), np.asarray(v, float)
        model = (np.asarray(self.los_bias)[los] + self.bias_velocity_slope * v
                 + self.bias_cnr_slope * (cnr - self.bias_cnr_mid))
        return self.bias_scale * model + self._grid_term("bias_offset", los, cnr, v)

    def bad_probability(self, cnr: np.ndarray) -> np.ndarray:
        """Probability that an estimate is a uniform random velocity (a "bad estimate")."""
        z = (np.asarray(cnr, float) - self.bad_cnr_midpoint) / self.bad_cnr_width
        return self.bad_probability_max / (1.0 + np.exp(np.clip(z, -50, 50)))

    def expected_cube(self) -> tuple[np.ndarray, np.ndarray]:
        """Bias and std at the grid nodes, arrays of shape (5, 12, 37) (no bad estimates)."""
        los, cnr, v = np.meshgrid(np.arange(5), CNR_NODES, VELOCITY_NODES, indexing="ij")
        return self.bias(los, cnr, v), self.std(los, cnr, v)

    def to_dict(self) -> dict:
        """JSON-serialisable parameters; grid arrays are summarised by mean and std."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            arr = np.asarray(value, dtype=float) if f.name in ("bias_offset", "std_scale") else None
            if arr is not None and arr.ndim:
                out[f.name] = {"grid_mean": float(arr.mean()), "grid_std": float(arr.std())}
            elif arr is not None:
                out[f.name] = float(arr)
            elif isinstance(value, tuple):
                out[f.name] = list(value)
            else:
                out[f.name] = value
        return out
