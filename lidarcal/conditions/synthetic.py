"""Synthetic ``conditions`` for heights and ranges a met mast lacks.

Two modes, both seeded through :class:`numpy.random.SeedSequence` (never the global RNG):

* **stochastic** (``base=None``): a reference-height (``ref_height``) wind-speed series as an
  AR(1) process in log space (Weibull-like marginal, median ``median_speed``), a direction
  random walk, a diurnal shear exponent plus AR(1) noise, and turbulence intensity from the
  IEC 61400-1 normal turbulence model ``sigma_u = I_ref (0.75 U + 5.6)`` with a lognormal
  scatter; speeds at every height follow the period's power law (Eq. 10) and ``sigma_u`` is
  taken constant with height, so ``TI(z) = sigma_u / U(z)``.
* **extrapolated** (``base=<conditions Dataset>``): the first ``n_periods`` periods of a real
  record (e.g. the embedded brightwind sample at 40/60/80 m) are carried to ``heights``:
  below the top measured height values are interpolated in log-height; above it the top
  height's speed is extrapolated with that period's shear exponent (Eq. 10), direction and
  ``sigma_u`` are held, so ``TI(z) = sigma_u / U(z)``.  Periods with a missing value stay
  missing (NaN), they are never invented; extrapolations giving TI > 1 are set missing too.

In both modes the shear exponent written to the file is recomputed from the generated
speeds at neighbouring heights (:func:`~lidarcal.conditions.kernels.shear_exponent`), exactly
as for measured data, and CNR comes from :func:`~lidarcal.conditions.kernels.cnr_model`
with its gradient from neighbouring heights, converted to a gradient along the beam
(``dCNR/ds = dCNR/dz · cos φ``, :func:`~lidarcal.conditions.kernels.cnr_gradient_along_beam`).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.cf import height_coord, time_coord
from lidarcal.conditions.kernels import (
    ar1,
    cnr_gradient_along_beam,
    cnr_model,
    power_law,
    shear_exponent,
)
from lidarcal.conditions.load import load_conditions
from lidarcal.conditions.variables import CONDITION_NAMES, variable_attrs
from lidarcal.errors import InputError, raise_first_bad
from lidarcal.io import source_name
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import declared_variables

__all__ = ["synthetic_conditions", "conditions_dataset"]


def conditions_dataset(
    times, heights, values: dict[str, np.ndarray], attrs: dict | None = None, *,
    content: str = "modelResult", comments: dict[str, str] | None = None,
) -> xr.Dataset:
    """Assemble a contract-conforming ``conditions`` Dataset from arrays on (time, height), not stamped.

    Each variable gets the attributes its schema declares
    (:func:`~lidarcal.conditions.variables.variable_attrs`): ``content`` its
    ``coverage_content_type`` (``physicalMeasurement`` for measured values), ``comments`` the
    comment of some of them.
    """
    ds = xr.Dataset(coords={"time": time_coord(times), "height": height_coord(heights)})
    for name in CONDITION_NAMES:
        ds[name] = (
            ("time", "height"),
            np.asarray(values[name], dtype=float),
            variable_attrs(name, content=content, comment=(comments or {}).get(name, "")),
        )
    ds.attrs.update(attrs or {})
    return ds


def _check_heights(heights) -> np.ndarray:
    z = np.asarray(heights, dtype=float).ravel()
    if z.size < 2 or not np.all(np.isfinite(z)) or np.any(z <= 0) or np.any(np.diff(z) <= 0):
        raise InputError(
            f"synthetic_conditions: heights must be >= 2 strictly increasing values > 0 m; got {z.tolist()}"
        )
    return z


def _stochastic(
    n: int,
    z: np.ndarray,
    rng: np.random.Generator,
    ref_height: float,
    median_speed: float,
    turbulence_reference: float,
    hours: np.ndarray,
) -> dict[str, np.ndarray]:
    log_u = np.log(median_speed) + ar1(rng, n, 0.995, 0.45)
    u_ref = np.clip(np.exp(log_u), 0.5, 35.0)
    direction = np.mod(240.0 + np.cumsum(rng.normal(0.0, 4.0, n)) + ar1(rng, n, 0.9, 10.0), 360.0)
    # stable nights, mixed afternoons: mean shear 0.14 +- 0.08 diurnal, AR(1) scatter 0.07
    alpha = 0.14 + 0.08 * np.cos(2 * np.pi * (hours - 2.0) / 24) + ar1(rng, n, 0.97, 0.07)
    speed = power_law(u_ref, ref_height, alpha, z)
    sigma_u = turbulence_reference * (0.75 * u_ref + 5.6) * np.exp(ar1(rng, n, 0.9, 0.25) - 0.25**2 / 2)
    ti = np.clip(sigma_u[:, None] / speed, 0.01, 0.6)
    return {
        "wind_speed": speed,
        "wind_from_direction": np.repeat(direction[:, None], z.size, axis=1),
        "turbulence_intensity": ti,
    }


def _extrapolated(base: xr.Dataset, n: int, z: np.ndarray) -> dict[str, np.ndarray]:
    base = load_conditions(base, warn=False)
    if n > base.sizes["time"]:
        raise InputError(f"synthetic_conditions: base has {base.sizes['time']} periods; asked for {n}")
    zb = base.height.values
    top = zb.size - 1
    u = base.wind_speed.values[:n]
    sig = u * base.turbulence_intensity.values[:n]
    alpha_top = base.wind_shear_exponent.values[:n, top]
    # below the top measured height: log-height interpolation (power law between measured heights),
    # constant extrapolation of the lowest height's shear below it
    logz = np.log(zb)
    out_u = np.empty((n, z.size))
    out_sig = np.empty((n, z.size))
    for j, zj in enumerate(z):
        if zj >= zb[top]:
            out_u[:, j] = u[:, top] * (zj / zb[top]) ** alpha_top
            out_sig[:, j] = sig[:, top]
            continue
        k = int(np.clip(np.searchsorted(zb, zj) - 1, 0, top - 1))
        w = (np.log(zj) - logz[k]) / (logz[k + 1] - logz[k])
        with np.errstate(divide="ignore", invalid="ignore"):
            out_u[:, j] = np.exp((1 - w) * np.log(u[:, k]) + w * np.log(u[:, k + 1]))
        # sigma_u: linear between measured heights, held at the lowest one's below it (carried
        # linearly, it turned negative: TI < 0 at 40 m from a mast at 80 and 120 m)
        wc = min(max(w, 0.0), 1.0)
        out_sig[:, j] = (1 - wc) * sig[:, k] + wc * sig[:, k + 1]
    nearest = np.abs(z[:, None] - zb[None, :]).argmin(axis=1)
    direction = base.wind_from_direction.values[:n][:, nearest]
    with np.errstate(divide="ignore", invalid="ignore"):
        ti = out_sig / out_u
    # a strongly negative shear carried far above the mast can make U(z) tiny and TI > 1:
    # not physical, so such (period, height) values are left missing, not clipped
    unphysical = ti > 1.0
    out_u[unphysical] = np.nan
    ti[unphysical] = np.nan
    return {
        "wind_speed": out_u,
        "wind_from_direction": direction,
        "turbulence_intensity": ti,
        "_times": base.time.values[:n],
        "_attrs": dict(base.attrs),
    }


def _check_extrapolated(vals: dict[str, np.ndarray], times: np.ndarray, z: np.ndarray, source: str) -> None:
    """Refuse a base whose values, carried to ``z``, leave the contract's ranges.

    The problem lies in the base file (speeds that do not form a profile: a strongly negative
    shear carried down gives 100 m/s at 40 m), so it is named, not the output that would fail
    validation.
    """
    declared = declared_variables("conditions")
    for name in ("wind_speed", "turbulence_intensity", "wind_shear_exponent"):
        lo, hi = declared[name]["range"]
        values = vals[name]
        with np.errstate(invalid="ignore"):
            bad = (values < lo) | (values > hi)

        def message(i: int, n: int, name=name, values=values, lo=lo, hi=hi) -> str:
            t, h = np.unravel_index(i, values.shape)
            return (f"{source}: its wind speeds and turbulence carried to heights {z.tolist()} m give "
                    f"{n} {name} value(s) outside [{lo:g}, {hi:g}], first {values[t, h]:.4g} at "
                    f"time={times[t]!s} (index {t}), height={z[h]:g} m; expected values that form a "
                    "plausible profile (check the base file's wind_speed at neighbouring heights)")
        raise_first_bad(bad, message)


def synthetic_conditions(
    n_periods: int,
    heights=(40, 60, 80, 100, 120, 140, 160, 200),
    seed: int = 0,
    *,
    base: xr.Dataset | None = None,
    start: str = "2024-01-01T00:00",
    ref_height: float = 80.0,
    median_speed: float = 8.0,
    turbulence_reference: float = 0.10,
    cnr_params: dict | None = None,
    cone_angle: float | None = None,
    call: str | None = None,
) -> xr.Dataset:
    """Generate ``n_periods`` ten-minute periods of conditions at ``heights`` (m), a stamped artefact.

    Parameters
    ----------
    n_periods : int
        Number of 10-minute periods.
    heights : sequence of float
        Heights in m, strictly increasing, at least two.
    seed : int
        Entropy of the :class:`numpy.random.SeedSequence` driving every random draw.
    base : xarray.Dataset, optional
        A real ``conditions`` record to extrapolate to ``heights`` (see module docstring);
        without it the series is stochastic.
    start : str
        Start time of the first period (stochastic mode).
    ref_height, median_speed, turbulence_reference : float
        Stochastic mode: height (m) of the reference series, its median speed (m/s) and the
        IEC reference turbulence intensity ``I_ref``.
    cnr_params : dict, optional
        Overrides of :data:`~lidarcal.conditions.kernels.CNR_MODEL`.
    cone_angle : float, optional
        Cone angle (degree from vertical) of the lidar the CNR gradient is meant for: the
        ``cnr_gradient`` is along the beam, ``cos φ`` times the vertical derivative of the
        modelled CNR.  Default: the base record's ``lidar_cone_angle`` attribute, else
        the :class:`~lidarcal.lidar.LidarModel` default (28°).
    call : str, optional
        What produced it, for the provenance (default: this function).

    Returns
    -------
    xarray.Dataset
        A ``conditions`` artefact (``docs/contracts.md``) with the generator's settings in
        ``lidarcal_synthetic`` global attributes and lidarcal's provenance (the base record's
        history carried over).
    """
    n = int(n_periods)
    if n < 1:
        raise InputError(f"synthetic_conditions: n_periods must be >= 1; got {n_periods!r}")
    z = _check_heights(heights)
    ss = np.random.SeedSequence([int(seed), 0x5C0D])
    rng_wind, rng_cnr = (np.random.default_rng(s) for s in ss.spawn(2))
    if base is None:
        times = np.datetime64(start, "ns") + np.arange(n) * np.timedelta64(600, "s")
        hours = (times - times.astype("datetime64[D]")) / np.timedelta64(1, "h")
        vals = _stochastic(n, z, rng_wind, float(ref_height), float(median_speed),
                           float(turbulence_reference), hours.astype(float))
        attrs = {
            "lidarcal_synthetic": "stochastic",
            "lidarcal_synthetic_ref_height": float(ref_height),
            "lidarcal_synthetic_median_speed": float(median_speed),
            "lidarcal_synthetic_turbulence_reference": float(turbulence_reference),
        }
    else:
        vals = _extrapolated(base, n, z)
        times = vals.pop("_times")
        attrs = {
            k: v
            for k, v in vals.pop("_attrs").items()
            if not k.startswith(("lidarcal_source_", "lidarcal_conditions_", "lidarcal_skipped"))
        }
        attrs["lidarcal_synthetic"] = (
            "extrapolated from a measured record with each period's shear exponent "
            "(Eq. 10) above its top height, log-height interpolation below"
        )
        hours = (times - times.astype("datetime64[D]")) / np.timedelta64(1, "h")
    vals["wind_shear_exponent"] = shear_exponent(vals["wind_speed"], z)
    if base is not None:
        _check_extrapolated(vals, times, z, source_name(base))
    cnr = cnr_model(np.asarray(hours, dtype=float), z, rng_cnr, cnr_params)
    missing = ~np.isfinite(vals["wind_speed"])
    cnr[missing] = np.nan
    vals["cnr"] = cnr
    if cone_angle is None:
        cone_angle = read_attr(attrs, "lidar_cone_angle", kind="conditions")
    vals["cnr_gradient"] = cnr_gradient_along_beam(cnr, z, float(cone_angle))
    attrs.update({
        "lidarcal_synthetic_seed": int(seed),
        "lidarcal_synthetic_cone_angle": float(cone_angle),
        "title": "synthetic 10-minute conditions",
        "comment": "generated by lidarcal.conditions.synthetic_conditions; CNR from lidarcal's "
                   "documented CNR model (lidarcal.conditions.kernels.cnr_model)",
    })
    mode = "stochastic" if base is None else f"extrapolated from {source_name(base)}"
    config = {"n_periods": n, "heights": z.tolist(), "seed": int(seed), "start": start,
              "ref_height": float(ref_height), "median_speed": float(median_speed),
              "turbulence_reference": float(turbulence_reference), "cnr_params": dict(cnr_params or {}),
              "cone_angle": float(cone_angle), "base": None if base is None else source_name(base)}
    return stamp(
        conditions_dataset(times, z, vals, attrs), "conditions",
        title=f"Synthetic 10-minute conditions ({mode})",
        summary=f"{n} ten-minute periods at {z.size} heights generated by "
                f"lidarcal.conditions.synthetic_conditions ({mode}).",
        call=call or "lidarcal.conditions.synthetic_conditions(...)",
        input_datasets={"base": base} if base is not None else None,
        config=config, seeds={"seed": int(seed)},
    )
