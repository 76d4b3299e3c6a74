"""The ``turbulence_box`` artefact: turbulence at a lidar's points, for inspection.

:func:`turbulence_box` simulates the u, v, w fluctuations at given points (wind frame) with
the fast generator or PyConTurb's ``gen_turb`` and returns a CF/ACDD dataset with dims
``time`` and ``point``.  The lidar-specific box (the points and random stream of one simulated height) is
:func:`lidarcal.lidar.box.lidar_turbulence_box`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.errors import InputError
from lidarcal.provenance import stamp
from lidarcal.schema import output_attrs
from lidarcal.turbulence.kernels import L_C, cell_size, generate_points, sigma_components
from lidarcal.turbulence.pyconturb_backend import generate_points_pyconturb
from lidarcal.units import to_magnitude

__all__ = ["turbulence_box", "GENERATORS"]

GENERATORS = ("fast", "pyconturb")
_EPOCH = np.datetime64("2000-01-01T00:00:00", "ns")


def _generate(generator: str, wind: np.ndarray, U: float, sigma: np.ndarray,
              seed_seq: np.random.SeedSequence, duration: float, dt: float) -> np.ndarray:
    x, y, z = wind.T
    if generator == "fast":
        return generate_points(x, y, z, wind_speed=U, sigma=sigma, rng=np.random.default_rng(seed_seq),
                               duration=duration, dt=dt)
    if generator == "pyconturb":
        return generate_points_pyconturb(x, y, z, wind_speed=U, sigma=sigma, seed=seed_seq, duration=duration,
                                         dt=dt)
    raise InputError(f"generator must be one of {GENERATORS}; got {generator!r}")


def _coords(points: np.ndarray, labels: list[str], nt: int, dt: float) -> dict:
    """Coordinates of a turbulence box: time (from the nominal epoch), elapsed time, x, y, z, labels."""
    values = {
        "time": ("time", _EPOCH + np.round(np.arange(nt) * dt * 1e9).astype("timedelta64[ns]")),
        "elapsed_time": ("time", np.arange(nt) * dt),
        "x": ("point", points[:, 0]),
        "y": ("point", points[:, 1]),
        "z": ("point", points[:, 2]),
        "point_label": ("point", np.array(labels, dtype=object)),
    }
    return {name: (dim, data, output_attrs("turbulence_box", name)) for name, (dim, data) in values.items()}


def turbulence_box(
    points: np.ndarray,
    *,
    labels: Sequence[str] | None = None,
    wind_speed: Any,
    turbulence_intensity: float,
    seed: Sequence[int] | int,
    seed_sequence: np.random.SeedSequence | None = None,
    reference_height: Any | None = None,
    wind_shear_exponent: float = 0.0,
    wind_from_direction: Any | None = None,
    duration: Any = "600 s",
    time_step: Any = "1 s",
    generator: str = "fast",
    cone_angle: Any | None = None,
    sampling_period: Any | None = None,
    call: str = "lidarcal.turbulence.turbulence_box",
    extra_attrs: dict | None = None,
) -> xr.Dataset:
    """Simulate turbulence at ``points`` (n, 3; along-wind, cross-wind, up in m) as a dataset.

    Physical arguments are pint quantities or strings (``"8 m/s"``); ``turbulence_intensity``
    and ``wind_shear_exponent`` are dimensionless.  The random stream is
    ``seed_sequence`` if given, else ``SeedSequence(seed)``.  ``mean_wind_speed`` follows the
    power law ``U (z / reference_height)^alpha`` (``reference_height`` defaults to the highest
    point).  Given the ``cone_angle`` of the lidar the points belong to and the
    ``sampling_period`` of one beam (time between two LOS of the same beam), the box also
    records the largest cell sizes a grid box could have used at ``reference_height`` (§2.3,
    :func:`~lidarcal.turbulence.kernels.cell_size`).
    """
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or points.shape[0] < 1:
        raise InputError(f"turbulence_box: argument 'points' must have shape (n, 3); got {points.shape}")
    U = float(to_magnitude(wind_speed, "m s-1", name="wind_speed"))
    ti = float(to_magnitude(turbulence_intensity, "1", name="turbulence_intensity"))
    alpha = float(to_magnitude(wind_shear_exponent, "1", name="wind_shear_exponent"))
    T = float(to_magnitude(duration, "s", name="duration"))
    dt = float(to_magnitude(time_step, "s", name="time_step"))
    z_ref = float(points[:, 2].max()) if reference_height is None else float(
        to_magnitude(reference_height, "m", name="reference_height"))
    direction = None if wind_from_direction is None else float(
        to_magnitude(wind_from_direction, "degree", name="wind_from_direction"))
    if not U > 0:
        raise InputError(f"turbulence_box: argument 'wind_speed' must be > 0 m s-1; got {U}")
    if not ti >= 0:
        raise InputError(f"turbulence_box: argument 'turbulence_intensity' must be >= 0; got {ti}")
    if np.any(points[:, 2] <= 0):
        raise InputError(f"turbulence_box: every point needs z > 0 m; found {points[:, 2].min():.6g} m")
    seed = (int(seed),) if np.isscalar(seed) else tuple(int(s) for s in seed)
    seed_sequence = seed_sequence if seed_sequence is not None else np.random.SeedSequence(list(seed))
    sigma = sigma_components(ti, U)
    try:
        series = _generate(generator, points, U, sigma, seed_sequence, T, dt)  # (3, n, nt)
    except ValueError as exc:
        if isinstance(exc, InputError):
            raise
        raise InputError(f"turbulence_box: {exc}") from None
    nt = series.shape[-1]
    labels = [f"p{i}" for i in range(points.shape[0])] if labels is None else [str(s) for s in labels]
    sigmas = {f"sigma_{name}": float(sigma[k]) for k, name in enumerate("uvw")}
    data = {  # canonical order: other dims, then time (CF 2.4)
        name: (("point", "time"), series[k], output_attrs("turbulence_box", name, **sigmas))
        for k, name in enumerate("uvw")
    }
    data["mean_wind_speed"] = (("point",), U * (points[:, 2] / z_ref) ** alpha,
                               output_attrs("turbulence_box", "mean_wind_speed"))
    ds = xr.Dataset(data, coords=_coords(points, labels, nt, dt))
    attrs = {
        "wind_speed": U, "turbulence_intensity": ti, "wind_shear_exponent": alpha,
        "reference_height": z_ref, "generator": generator, "coherence_model": "iec3d",
        "coherence_length": L_C, "spectral_model": "Kaimal (PyConTurb kaimal_spectrum)",
        **sigmas,
    }
    if cone_angle is not None and sampling_period is not None:
        a, b, longitudinal = cell_size(z_ref, float(to_magnitude(cone_angle, "degree", name="cone_angle")), U,
                                       float(to_magnitude(sampling_period, "s", name="sampling_period")))
        attrs.update(cell_size_opposite_beams=a, cell_size_adjacent_beams=b,
                     cell_size_longitudinal_max=longitudinal)
    if direction is not None:
        attrs["wind_from_direction"] = direction
    attrs = {k: v for k, v in attrs.items() if v is not None}
    attrs.update(extra_attrs or {})
    ds.attrs.update({f"lidarcal_{k}" if not k.startswith("lidarcal_") else k: v for k, v in attrs.items()})
    seeds = {"seed": list(seed), "seed_sequence_entropy": str(seed_sequence.entropy),
             "seed_sequence_spawn_key": list(seed_sequence.spawn_key)}
    return stamp(ds, "turbulence_box", title="Turbulence at lidar sample points",
                 summary=(f"u, v, w turbulent fluctuations ({generator} generator: Kaimal spectra, iec3d "
                          f"coherence, sigma_v = 0.8 sigma_u, sigma_w = 0.5 sigma_u, frozen turbulence along "
                          f"the wind) at {points.shape[0]} points, U = {U:g} m/s, TI = {ti:g}."),
                 call=call,
                 config={"wind_speed": U, "turbulence_intensity": ti, "wind_shear_exponent": alpha,
                         "duration": T, "time_step": dt, "generator": generator,
                         "wind_from_direction": direction,
                         "reference_height": z_ref},
                 seeds=seeds)
