"""The turbulence a virtual lidar samples at one height, as a ``turbulence_box`` artefact.

:func:`lidar_turbulence_box` simulates turbulence at the RWF quadrature nodes and the reference
point of one height, with the height's turbulence stream: the statistics the virtual lidar
samples (its LOS signals are drawn directly, see :mod:`lidarcal.lidar.spectral`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.lidar.geometry import period_points
from lidarcal.lidar.model import LidarModel
from lidarcal.lidar.simulate import height_seed
from lidarcal.turbulence.box import turbulence_box
from lidarcal.units import to_magnitude

__all__ = ["lidar_turbulence_box"]


def lidar_turbulence_box(model: LidarModel, *, height: Any, wind_speed: Any, turbulence_intensity: float,
                         wind_from_direction: Any, seed: Sequence[int] | int,
                         wind_shear_exponent: float = 0.0, duration: Any = "600 s", generator: str = "fast",
                         call: str = "lidarcal.lidar.box.lidar_turbulence_box") -> xr.Dataset:
    """Simulate the turbulence at the points ``simulate_period(model, ..., seed=seed)`` samples at one height.

    The points are the virtual lidar's RWF quadrature nodes and the reference, with the height's
    ``SeedSequence([*seed, round(height * 1000)])`` turbulence stream; the simulator itself draws
    the continuous-RWF LOS signals from their cross-spectra (:mod:`lidarcal.lidar.spectral`), so
    these point series show the turbulence statistics it sampled, not its exact LOS values.
    """
    h = float(to_magnitude(height, "m", name="height"))
    direction = float(to_magnitude(wind_from_direction, "degree", name="wind_from_direction"))
    seed = (int(seed),) if np.isscalar(seed) else tuple(int(s) for s in seed)
    pts = period_points(model, h, direction)
    return turbulence_box(pts["wind"], labels=pts["label"], wind_speed=wind_speed,
                          turbulence_intensity=turbulence_intensity, seed=seed,
                          seed_sequence=height_seed(seed, h).spawn(3)[0], reference_height=f"{h} m",
                          wind_shear_exponent=wind_shear_exponent, wind_from_direction=f"{direction} degree",
                          duration=duration, time_step=f"{model.beam_period} s", generator=generator,
                          cone_angle=f"{model.cone_angle} degree",
                          sampling_period=f"{len(model.azimuths) * model.beam_period} s",
                          call=call, extra_attrs={"lidar_model": model.to_json(), "height": h})
