"""The virtual DBS lidar and the virtual reference inside simulated turbulence (paper §2.3).

:func:`simulate_period` simulates one 10-minute period at several heights.  Each height is an
independent problem with its own random streams, ``SeedSequence([*seed, round(height*1000)])``
spawned into (turbulence, LOS noise, availability), so a height's result never depends on
which other heights are simulated.

Per height ``h`` (all angles in the lidar frame: x east, y north, z up; azimuth clockwise
from north):

* **Geometry.** Beam ``b`` points along ``n_b = (sin φ sin θ_b, sin φ cos θ_b, cos φ)`` with the
  *true* cone ``φ = cone_angle + beam_angle_offset``.  The range gate's nominal centre is at
  ``r = h / cos(cone_angle)``; it actually sits ``zero_distance_offset`` further out, and the
  RWF quadrature nodes are at ``r + zero_distance_offset + s_k``.
* **Wind.** The mean wind blows *toward* ``θ_w + 180°`` (``θ_w`` = meteorological
  ``wind_from_direction``) with speed ``U_h (z / h)^α`` at height ``z``; the vertical mean is
  zero.  Turbulence (u along-wind, v cross-wind to the left, w up; Kaimal spectra and ``iec3d``
  coherence as PyConTurb, Taylor's frozen turbulence along the wind) enters only through the
  six signals the period needs: the four LOS values filtered by the *continuous* RWF and the
  reference's u and v, drawn from their exact 6 x 6 cross-spectral matrix per frequency
  (:mod:`lidarcal.lidar.spectral`).  By default (``LidarModel.reference_turbulence = "pinned_u"``)
  the reference comes first and its u has fixed amplitudes (its realised σ_u is the period's
  measured TI·U), and everything else has Gaussian Fourier coefficients given it (PyConTurb's
  point-level convention seen through the continuous RWF).  One independent draw per height
  (cross-height coherence is not modelled; every per-height statistic is exact).
* **Sampling.** LOS ``k`` (time ``k · beam_period``) belongs to beam ``k mod 4``: 150 samples
  per beam per 10 minutes at 1 s per LOS; the vertical beam is ignored.
* **Radial velocity** ``v_r = V · n_b``, positive away from the lidar.  The LOS value is the
  mean part ``Σ_k w_k U(z_k) a_b`` over the K CNR-weighted quadrature nodes of Eq. 2
  (``w_k ∝ w_k^0 10^(scale · g · s_k / 20)``, ``scale = cnr_weighting_scale``, ``g`` the period's
  CNR gradient) plus the turbulent LOS signal (the same Eq. 2 weighting of the continuous RWF),
  plus an error drawn for this beam, the period's CNR and this sample's noise-free radial
  velocity: by default (``los_noise_model = "mixture"``, a cube with measured residuals) the
  estimate is a bad one with probability p_bad(CNR) at the period's CNR, its value uniform over
  the lidar's search band whatever the true velocity (:mod:`lidarcal.lidar.bad_estimates`), and
  otherwise the noise-free value plus one of the bench bin's *good* residuals, the bin picked
  among the neighbours with its bilinear weight
  (:meth:`~lidarcal.lidar.noise.NoiseTable.draw_good_residuals`); with ``"residuals"`` one of
  the bin's residuals, bad estimates included (:meth:`~lidarcal.lidar.noise.NoiseTable.draw_residuals`);
  with ``"gaussian"`` ``N(μ, σ)``, ``μ, σ`` the table's MAD-trimmed bias and std (bilinear,
  clamped); ``μ = 0, σ = los_noise_std`` for the ideal lidar.  Samples are kept with
  probability ``availability``.
* **Reconstruction** (:mod:`lidarcal.lidar.wfr`): sliding, nominal cone angle, scalar / vector /
  hybrid with ``p = hybrid_weight`` multiplying the scalar average.
* **Virtual reference**: the point (0, 0, h) at every simulation time step (1 Hz for a 1-s beam
  period), 10-min mean of ``sqrt((U_h + u)^2 + v^2)`` (a cup's scalar mean), times
  ``LidarModel.reference_scale(direction, TI)``: ``(1 + reference_overspeeding · TI)``, the
  gain ``1 + reference_gain`` and the mast shadow ``1 − deficit`` for a period whose mean
  direction lies in the ``reference_flow_distortion_*`` sector (edge smoothed by the spread of
  the instantaneous direction, 0.8 · TI rad).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lidarcal.errors import InputError
from lidarcal.lidar.geometry import beam_geometry, period_points, wind_axes
from lidarcal.lidar.model import LidarModel, RwfProfileDigest
from lidarcal.lidar.quadrature import cnr_weights
from lidarcal.lidar.spectral import cross_spectral_matrix
from lidarcal.lidar.synthesis import REFERENCE_AMPLITUDES, draw_coefficients, synthesise
from lidarcal.lidar.wfr import reconstruct
from lidarcal.turbulence.kernels import sigma_components

__all__ = ["simulate_period", "height_seed"]

OUTPUTS = ("lidar_wind_speed", "lidar_wind_speed_scalar", "lidar_wind_speed_vector",
           "reference_wind_speed", "availability")


def height_seed(seed: Sequence[int] | int, height: float) -> np.random.SeedSequence:
    """Return the seed sequence of one height: ``SeedSequence([*seed, round(height * 1000)])``."""
    seed = (seed,) if np.isscalar(seed) else tuple(seed)
    return np.random.SeedSequence([*(int(s) for s in seed), int(round(float(height) * 1000))])


def _simulate_height(model: LidarModel, height: float, U: float, direction: float, ti: float,
                     alpha: float, cnr: float, gradient: float, seed: Sequence[int], duration: float,
                     n_times: int) -> dict[str, np.ndarray | float]:
    turb_ss, noise_ss, avail_ss = height_seed(seed, height).spawn(3)
    units, phi_true, phi_nom = beam_geometry(model)
    pts = period_points(model, height, direction)["lidar"][:-1].reshape(4, -1, 3)  # RWF nodes (refuses < 0 m)
    down, cross = wind_axes(direction)
    beam_of_time = np.arange(n_times) % 4
    mean_speed = U * (pts[..., 2] / height) ** alpha  # (4, K)
    along = units[:, :2] @ down  # (4,) horizontal projections of the beams on the wind axes
    weights = cnr_weights(model.rwf_offsets, model.rwf_weights, gradient, model.cnr_weighting_scale)
    los_mean = (mean_speed @ weights) * along  # (4,) RWF-weighted mean radial velocity
    sigma = sigma_components(ti, U)
    if np.any(sigma > 0):  # turbulence: (ref_u, ref_v, LOS_0..3) from their cross-spectral matrix
        C = cross_spectral_matrix(model, height, U, direction, sigma, gradient, duration)
        coef = draw_coefficients(C, np.random.default_rng(turb_ss),
                                 REFERENCE_AMPLITUDES[model.reference_turbulence], n_times)
        turb = synthesise(coef, n_times)  # (6, n_times)
    else:
        turb = np.zeros((6, n_times))
    los_true = los_mean[beam_of_time] + turb[2 + beam_of_time, np.arange(n_times)]
    noise_rng = np.random.default_rng(noise_ss)
    if model.noise_table is not None and model.los_noise_model == "mixture":
        # five uniforms per LOS: bad or not, the bad value, CNR neighbour, velocity neighbour, good residual
        u = noise_rng.random((5, n_times))
        good = los_true + model.noise_table.draw_good_residuals(beam_of_time, cnr, los_true, u[2:],
                                                                model.bad_estimates)
        los = model.bad_estimates.apply(good, cnr, u[:2])
    elif model.noise_table is not None and model.los_noise_model == "residuals":
        # three uniforms per LOS: CNR neighbour, velocity neighbour, residual within the bin
        u = noise_rng.random((3, n_times))
        los = los_true + model.noise_table.draw_residuals(beam_of_time, cnr, los_true, u)
    elif model.noise_table is None:
        los = los_true + model.los_noise_std * noise_rng.standard_normal(n_times)
    else:
        noise = noise_rng.standard_normal(n_times)
        los = np.empty(n_times)
        for b in range(4):
            sel = beam_of_time == b
            bias, std = model.noise_table.lookup(b, cnr, los_true[sel])
            los[sel] = los_true[sel] + bias + std * noise[sel]
    keep = np.random.default_rng(avail_ss).random(n_times) < model.availability
    los = np.where(keep, los, np.nan)
    ref_u, ref_v = turb[0], turb[1]
    # reference effects (over-speeding, gain, mast shadow): LidarModel.reference_scale
    reference = np.mean(np.hypot(U + ref_u, ref_v)) * model.reference_scale(direction, ti)
    return {"reference_wind_speed": reference, "availability": keep.mean(), "los": los}


def _checked_arguments(model: LidarModel, heights, duration: float, **given
                       ) -> tuple[np.ndarray, dict[str, np.ndarray], int]:
    """Check :func:`simulate_period`'s arguments; return the heights, the conditions per height and the steps.

    ``given`` holds the six conditions in their order (wind speed, direction, turbulence
    intensity, shear exponent, CNR, CNR gradient), each broadcast to one value per height.
    """
    if not isinstance(model, LidarModel):
        raise InputError(f"simulate_period: model must be a LidarModel; got {type(model).__name__}")
    if isinstance(model.rwf_profile, RwfProfileDigest):  # an attribute-form record: never a silent default
        raise InputError(model.missing_rwf_message())
    heights = np.atleast_1d(np.asarray(heights, dtype=float))
    if heights.ndim != 1 or np.any(~np.isfinite(heights)) or np.any(heights <= 0):
        raise InputError(f"simulate_period: argument 'heights' must be a 1-D array of finite heights > 0 m; "
                         f"got {heights.tolist()}")
    conditions = {}
    for name, value in given.items():
        try:
            conditions[name] = np.broadcast_to(np.asarray(value, dtype=float), heights.shape)
        except ValueError:
            raise InputError(f"simulate_period: argument {name!r} has shape {np.shape(value)}; expected a "
                             f"scalar or one value per height {heights.shape}") from None
    bad = conditions["wind_speed"] <= 0
    if bad.any():
        raise InputError(f"simulate_period: argument 'wind_speed' must be > 0 m s-1 (or NaN); found "
                         f"{conditions['wind_speed'][bad].tolist()} at heights {heights[bad].tolist()} m")
    bad = conditions["turbulence_intensity"] < 0
    if bad.any():
        raise InputError(f"simulate_period: argument 'turbulence_intensity' must be >= 0; found "
                         f"{conditions['turbulence_intensity'][bad].tolist()}")
    n_times = int(round(duration / model.beam_period))
    if n_times < 4 or abs(n_times * model.beam_period - duration) > 1e-9 * duration:
        raise InputError(f"simulate_period: duration {duration} s must be a whole number (>= 4) of beam "
                         f"periods ({model.beam_period} s)")
    return heights, conditions, n_times


def simulate_period(
    model: LidarModel,
    *,
    heights,
    wind_speed,
    wind_from_direction,
    turbulence_intensity,
    wind_shear_exponent,
    cnr,
    cnr_gradient,
    seed: Sequence[int] | int,
    duration: float = 600.0,
    return_los: bool = False,
) -> dict[str, np.ndarray]:
    """Simulate one period: the virtual lidar's and the virtual reference's 10-min speeds.

    Parameters
    ----------
    model : LidarModel
        The virtual lidar.
    heights : array_like
        Measurement heights (m, > 0).
    wind_speed, wind_from_direction, turbulence_intensity, wind_shear_exponent, cnr, cnr_gradient : array_like
        The period's conditions over ``heights`` (m s-1, degree, 1, 1, dB, dB m-1), SI floats;
        scalars broadcast.  A height with any NaN condition gets NaN outputs.
    seed : tuple of int
        ``(base_seed, period_key)`` from the campaign (the key: the period's time in whole
        seconds since 1970, :func:`lidarcal.campaign.chunks.period_keys`); each height draws from
        ``SeedSequence([*seed, round(height * 1000)])``.
    duration : float
        Period length (s); a whole number of ``model.beam_period`` steps.
    return_los : bool
        Also return ``los`` (heights, n_times; m s-1, NaN = dropped), ``los_beam`` (n_times;
        index into ``model.azimuths``) and ``los_time`` (n_times; s).

    Returns
    -------
    dict of str to ndarray
        ``lidar_wind_speed`` (hybrid), ``lidar_wind_speed_scalar``, ``lidar_wind_speed_vector``,
        ``reference_wind_speed`` (m s-1) and ``availability`` (fraction of LOS samples kept),
        each of shape ``(len(heights),)``.
    """
    heights, conditions, n_times = _checked_arguments(
        model, heights, duration, wind_speed=wind_speed, wind_from_direction=wind_from_direction,
        turbulence_intensity=turbulence_intensity, wind_shear_exponent=wind_shear_exponent, cnr=cnr,
        cnr_gradient=cnr_gradient)
    out = {name: np.full(heights.shape, np.nan) for name in OUTPUTS}
    los = np.full((heights.size, n_times), np.nan)
    done = []
    for i, h in enumerate(heights):
        values = [float(conditions[n][i]) for n in conditions]
        if not np.all(np.isfinite(values)):
            continue
        if model.cnr_threshold is not None and conditions["cnr"][i] < model.cnr_threshold:
            out["availability"][i] = 0.0  # the lidar's CNR filter drops every LOS of the period
            continue
        res = _simulate_height(model, float(h), *values, seed=seed, duration=duration, n_times=n_times)
        for name in ("reference_wind_speed", "availability"):
            out[name][i] = res[name]
        los[i] = res["los"]
        done.append(i)
    if done:  # the wind-field reconstruction of every simulated height at once (row by row identical)
        wfr = reconstruct(los[done], np.arange(n_times) % 4, model.cone_angle, model.hybrid_weight,
                          model.hybrid_convention)
        for name, key in (("lidar_wind_speed", "hybrid"), ("lidar_wind_speed_scalar", "scalar"),
                          ("lidar_wind_speed_vector", "vector")):
            out[name][done] = wfr[key]
    if return_los:
        out["los"] = los
        out["los_beam"] = np.arange(n_times) % 4
        out["los_time"] = np.arange(n_times) * model.beam_period
    return out
