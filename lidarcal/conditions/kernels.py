"""Pure numpy kernels for atmospheric conditions (no files, no metadata; SI floats, CNR in dB).

Vertical derivatives follow the paper's §3.3: at every height the quantity is computed from
the **two nearest neighbouring heights** (the one below and the one above), and from the
single neighbour at the lowest and highest heights.  For the shear exponent this applies the
power law of Eq. 10, ``U = U0 (z / z0) ** alpha``, between the two heights used:
``alpha = ln(U_b / U_a) / ln(z_b / z_a)``.

The CNR gradient of the ``conditions`` contract is a rate **along the beam** (dB per metre of
range, the variable of the paper's Eq. 2 and Figure 3, and what the virtual lidar applies
to its range-weighting nodes).  Heights are vertical: an oblique beam at cone angle φ from
the vertical climbs ``cos φ`` metres per metre of range, so

    dCNR/ds = dCNR/dz · cos φ,   dCNR/dz = (CNR_b - CNR_a) / (z_b - z_a)

between the same two heights (:func:`cnr_gradient_along_beam`).  With φ = 28° a height-based
gradient is 1/cos 28° = 1.13 times the along-beam one.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "neighbour_pairs",
    "shear_exponent",
    "vertical_gradient",
    "cnr_gradient_along_beam",
    "power_law",
    "cnr_model",
    "ar1",
]


def neighbour_pairs(heights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the indices ``(lower, upper)`` of the two heights used at each height (paper §3.3).

    Interior heights use their neighbours below and above; the lowest height uses itself and
    the next one up, the highest height the one below and itself.  ``heights`` must be
    strictly increasing with at least two entries.
    """
    heights = np.asarray(heights, dtype=float)
    n = heights.size
    if n < 2:
        raise ValueError(f"need at least two heights for a vertical derivative; got {n}")
    if np.any(np.diff(heights) <= 0):
        raise ValueError(f"heights must be strictly increasing; got {heights.tolist()}")
    idx = np.arange(n)
    return np.clip(idx - 1, 0, n - 1), np.clip(idx + 1, 0, n - 1)


def shear_exponent(speed: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """Power-law shear exponent (Eq. 10) at each height from neighbouring heights.

    Parameters
    ----------
    speed : ndarray (..., height)
        Mean horizontal wind speed in m/s; NaN or non-positive values give NaN.
    heights : ndarray (height,)
        Strictly increasing heights in m.

    Returns
    -------
    ndarray (..., height)
        ``ln(U[upper] / U[lower]) / ln(z[upper] / z[lower])``.

    Examples
    --------
    >>> z = np.array([40.0, 60.0, 80.0])
    >>> np.round(shear_exponent(8.0 * (z / 80.0) ** 0.2, z), 12)
    array([0.2, 0.2, 0.2])
    """
    speed = np.asarray(speed, dtype=float)
    z = np.asarray(heights, dtype=float)
    lo, hi = neighbour_pairs(z)
    with np.errstate(divide="ignore", invalid="ignore"):
        logu = np.where(speed > 0, np.log(np.where(speed > 0, speed, 1.0)), np.nan)
    return (logu[..., hi] - logu[..., lo]) / np.log(z[hi] / z[lo])


def vertical_gradient(values: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """Finite-difference **vertical** gradient d/dz at each height from neighbouring heights (§3.3).

    Per metre of height.  For the ``cnr_gradient`` of a ``conditions`` file use
    :func:`cnr_gradient_along_beam`, which is per metre of range along the beam.
    """
    values = np.asarray(values, dtype=float)
    z = np.asarray(heights, dtype=float)
    lo, hi = neighbour_pairs(z)
    return (values[..., hi] - values[..., lo]) / (z[hi] - z[lo])


def cnr_gradient_along_beam(cnr: np.ndarray, heights: np.ndarray, cone_angle: float) -> np.ndarray:
    """CNR gradient along the beam (dB per metre of range) from CNR at neighbouring heights.

    ``dCNR/ds = dCNR/dz · cos φ`` with ``dCNR/dz`` from :func:`vertical_gradient` and φ the
    cone angle in degrees from the vertical (28° for a WindCube).

    Examples
    --------
    A CNR falling 0.1 dB per metre of height falls 0.1 cos 28° = 0.0883 dB per metre of range:

    >>> z = np.array([40.0, 80.0, 120.0])
    >>> np.round(cnr_gradient_along_beam(-10.0 - 0.1 * (z - 40.0), z, 28.0), 6)
    array([-0.088295, -0.088295, -0.088295])
    """
    phi = float(cone_angle)
    if not 0.0 <= phi < 90.0:
        raise ValueError(f"cone_angle must be in [0, 90) degree from vertical; got {phi}")
    return vertical_gradient(cnr, heights) * np.cos(np.radians(phi))


def power_law(speed_ref: np.ndarray, z_ref: np.ndarray, alpha: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """Eq. 10: speeds at ``heights`` (last axis) from ``speed_ref`` at ``z_ref`` with exponent ``alpha``.

    ``speed_ref``, ``z_ref`` and ``alpha`` broadcast against each other (one value per
    period, say); the result has a trailing ``height`` axis.
    """
    speed_ref = np.asarray(speed_ref, dtype=float)[..., None]
    z_ref = np.asarray(z_ref, dtype=float)[..., None]
    alpha = np.asarray(alpha, dtype=float)[..., None]
    return speed_ref * (np.asarray(heights, dtype=float) / z_ref) ** alpha


def ar1(rng: np.random.Generator, n: int, phi: float, sigma: float) -> np.ndarray:
    """Stationary AR(1) series of length ``n``: lag-1 correlation ``phi``, marginal std ``sigma``."""
    eps = rng.standard_normal(n) * sigma * np.sqrt(1.0 - phi**2)
    out = np.empty(n)
    prev = rng.standard_normal() * sigma
    for i in range(n):  # n ~ 1e4: a plain loop is fast enough and obviously correct
        prev = phi * prev + eps[i]
        out[i] = prev
    return out


#: Parameters of :func:`cnr_model` (dB, dB/m of height, m, hours); documented in the sample README.
#: The focus bump outweighs the aerosol lapse below the focus, so the mean CNR gradient is
#: positive below ~106 m and negative above (+0.05 dB/m at 60-80 m, -0.07 dB/m at 140-160 m
#: along the beam), the shape of the paper's Figure 3 (right: zero crossing at 110 m, the focal
#: distance; extremes within ±0.1 dB/m).
CNR_MODEL = {
    "cnr_at_40m": -13.0,  # dB, daily mean CNR at 40 m
    "diurnal_amplitude": 3.0,  # dB, convective mixing lifts aerosol in the afternoon
    "diurnal_peak_hour": 14.0,  # local solar hour of the CNR maximum
    "lapse": -0.01,  # dB/m of height, mean decrease of CNR with height (aerosol decay)
    "lapse_std": 0.015,  # dB/m of height, period-to-period variability of the lapse
    "focus_gain": 5.0,  # dB, telescope focus bump: the mean gradient crosses zero at 106 m
    "focus_height": 110.0,  # m, focal distance (Figure 3 right: zero crossing at 110 m)
    "focus_width": 60.0,  # m, e-folding half-width of the focus bump
    "noise_std": 2.0,  # dB, slow synoptic variability (AR(1), 10-min lag corr 0.98)
    "noise_phi": 0.98,
    "floor": -35.0,  # dB, CNR clipped to [floor, ceiling]
    "ceiling": 0.0,
}


def cnr_model(
    hours: np.ndarray,
    heights: np.ndarray,
    rng: np.random.Generator,
    params: dict | None = None,
) -> np.ndarray:
    """Modelled CNR (dB) on (period, height): diurnal cycle, decay with height, focus bump.

    ``CNR(t, z) = c40 + A cos(2π (h - h_peak) / 24) + n(t) + s(t) (z - 40) + G exp(-((z - z_f)/w)²)``
    with ``n`` an AR(1) process (std ``noise_std``) and ``s`` the lapse rate, ``lapse +
    lapse_std * AR(1)``; clipped to ``[floor, ceiling]``.  It stands in for the lidar CNR a
    met mast does not record; the CNR gradient then follows from neighbouring heights
    (:func:`cnr_gradient_along_beam`), as for measured CNR.

    The profile's parameters are **per metre of height** (``lapse`` in dB m-1 vertically);
    the along-beam gradient is ``cos φ`` times its vertical derivative.
    """
    p = {**CNR_MODEL, **(params or {})}
    hours = np.asarray(hours, dtype=float)
    z = np.asarray(heights, dtype=float)
    n = hours.size
    base = (
        p["cnr_at_40m"]
        + p["diurnal_amplitude"] * np.cos(2 * np.pi * (hours - p["diurnal_peak_hour"]) / 24)
        + ar1(rng, n, p["noise_phi"], p["noise_std"])
    )
    lapse = p["lapse"] + ar1(rng, n, p["noise_phi"], p["lapse_std"])
    focus = p["focus_gain"] * np.exp(-(((z - p["focus_height"]) / p["focus_width"]) ** 2))
    cnr = base[:, None] + lapse[:, None] * (z - 40.0) + focus[None, :]
    return np.clip(cnr, p["floor"], p["ceiling"])
