"""Pure numpy kernels of the range-weighting function (paper §2.2, Eqs. 1–2).

Everything here works on plain SI floats on a uniform ``range_offset`` grid ``z`` (metres
along the beam from the nominal range-gate centre, positive away from the lidar).  Nothing
here knows about files, units or metadata; :mod:`lidarcal.rwf.dataset` wraps these functions.

Conventions
-----------
Pulse length
    The *pulse length* is the full width at half maximum (FWHM) of the pulse's intensity
    envelope expressed in range, i.e. ``c * tau_FWHM / 2`` for a pulse of duration
    ``tau_FWHM``.  The paper's WindCube has 25 m (Table 1).
Time to range
    Backscatter received at time ``t`` from range ``r`` was emitted at ``t - 2 r / c``.
    A pulse intensity sampled in time, ``P(t)`` with ``t = 0`` the instant the lidar's
    range gating takes as the pulse centre, therefore weights range offset ``z`` with
    ``P(-2 z / c)``: the part of the pulse emitted *later* samples ranges *nearer* the lidar.
Apodization
    A Gaussian window over the FFT length of ``fft_size`` samples at sampling frequency
    ``f_s``; one sample spans ``c / (2 f_s)`` metres (0.6 m at 250 MHz), so the window spans
    ``fft_size * c / (2 f_s)`` metres and is zero outside it.  Its standard deviation is
    ``std_fraction * fft_size`` samples (0.2 is MATLAB's ``gausswin`` default alpha = 2.5).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "SPEED_OF_LIGHT",
    "FWHM_PER_SIGMA",
    "range_sample_spacing",
    "range_grid",
    "two_sided_gaussian_pulse",
    "two_sided_sigmas",
    "sampled_pulse",
    "time_to_range_offset",
    "gaussian_window",
    "rwf_from_pulse",
    "cnr_weighted_rwf",
    "barycenter",
    "full_width_half_maximum",
]

#: Speed of light in vacuum (m s-1), exact by definition of the metre.
SPEED_OF_LIGHT = 299_792_458.0
#: FWHM of a Gaussian divided by its standard deviation, 2 sqrt(2 ln 2).
FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))


def range_sample_spacing(sampling_frequency: float) -> float:
    """Range spanned by one digitiser sample, ``c / (2 f_s)`` (m); 0.5996 m at 250 MHz."""
    return SPEED_OF_LIGHT / (2.0 * sampling_frequency)


def range_grid(half_width: float, resolution: float) -> np.ndarray:
    """Odd-length uniform grid ``[-half_width, half_width]`` with 0 exactly at its centre."""
    n = int(np.ceil(half_width / resolution))
    return np.arange(-n, n + 1, dtype=float) * resolution


def two_sided_sigmas(fwhm: float, asymmetry: float) -> tuple[float, float]:
    """Near- and far-side standard deviations of a two-sided Gaussian.

    ``asymmetry = (s_far - s_near) / (s_far + s_near)`` in (-1, 1); ``s_far + s_near`` is
    kept at ``2 fwhm / FWHM_PER_SIGMA`` so that the FWHM does not depend on the asymmetry.
    """
    mean_sigma = fwhm / FWHM_PER_SIGMA
    return mean_sigma * (1.0 - asymmetry), mean_sigma * (1.0 + asymmetry)


def two_sided_gaussian_pulse(z: np.ndarray, fwhm: float, asymmetry: float, offset: float = 0.0) -> np.ndarray:
    """Asymmetric pulse: a Gaussian with different widths nearer and farther than its peak.

    The peak (value 1) sits at ``offset``; ``asymmetry > 0`` gives the longer tail away from
    the lidar.  Its FWHM equals ``fwhm`` for any asymmetry and its mean lies
    ``sqrt(2/pi) (s_far - s_near)`` beyond the peak.
    """
    near, far = two_sided_sigmas(fwhm, asymmetry)
    d = np.asarray(z, dtype=float) - offset
    sigma = np.where(d < 0.0, near, far)
    return np.exp(-0.5 * (d / sigma) ** 2)


def time_to_range_offset(time: np.ndarray) -> np.ndarray:
    """Range offset weighted by the pulse sample emitted at ``time`` (s): ``-c t / 2``."""
    return -0.5 * SPEED_OF_LIGHT * np.asarray(time, dtype=float)


def sampled_pulse(z: np.ndarray, z_samples: np.ndarray, intensity: np.ndarray) -> np.ndarray:
    """Measured pulse interpolated linearly onto ``z`` (zero outside the samples), peak 1.

    ``z_samples`` need not be sorted (a time axis maps to decreasing range) but must be
    distinct; ``intensity`` must be non-negative with a positive maximum.
    """
    order = np.argsort(z_samples, kind="stable")
    zs = np.asarray(z_samples, dtype=float)[order]
    ys = np.asarray(intensity, dtype=float)[order]
    out = np.interp(z, zs, ys, left=0.0, right=0.0)
    return out / ys.max()


def remove_noise_floor(z_samples: np.ndarray, intensity: np.ndarray, n_sigma: float = 3.0,
                       edge_fraction: float = 0.1) -> np.ndarray:
    """Measured pulse with its detector noise floor removed (same order as the input).

    A recorded pulse sits on a noise floor; clipped at zero it becomes a faint pedestal over
    the whole recording that Eq. 1 would turn into RWF weight tens of metres from the gate.
    The floor is estimated from the first and last ``edge_fraction`` of the recording (which
    must extend beyond the pulse): its median is subtracted, and everything outside the
    contiguous lobe around the peak that stays above ``n_sigma`` robust standard deviations
    (1.4826 MAD) of that floor is set to zero.  A noise-free recording is returned unchanged.
    """
    order = np.argsort(z_samples, kind="stable")
    y = np.asarray(intensity, dtype=float)[order]
    n_edge = max(int(edge_fraction * y.size), 1)
    edges = np.concatenate([y[:n_edge], y[-n_edge:]])
    floor = float(np.median(edges))
    noise = 1.4826 * float(np.median(np.abs(edges - floor)))
    y = np.clip(y - floor, 0.0, None)
    above = y > n_sigma * noise
    peak = int(np.argmax(y))
    lo = peak - int(np.argmin(above[peak::-1])) if not above[: peak + 1].all() else 0
    hi = peak + int(np.argmin(above[peak:])) if not above[peak:].all() else y.size
    cleaned = np.zeros_like(y)
    cleaned[lo:hi] = y[lo:hi]
    out = np.empty_like(cleaned)
    out[order] = cleaned
    return out


def gaussian_window(z: np.ndarray, fft_size: int, sample_spacing: float, std_fraction: float) -> np.ndarray:
    """Gaussian apodization window (peak 1) over ``fft_size`` samples, zero outside it.

    The window is centred on the nominal gate centre and spans ``fft_size * sample_spacing``
    metres; its standard deviation is ``std_fraction * fft_size * sample_spacing`` metres.
    """
    sigma = std_fraction * fft_size * sample_spacing
    half = 0.5 * fft_size * sample_spacing
    z = np.asarray(z, dtype=float)
    return np.where(np.abs(z) <= half, np.exp(-0.5 * (z / sigma) ** 2), 0.0)


def _normalise(w: np.ndarray, dz: float, axis: int = 0) -> np.ndarray:
    return w / (np.sum(w, axis=axis, keepdims=True) * dz)


def rwf_from_pulse(pulse: np.ndarray, window: np.ndarray, dz: float) -> np.ndarray:
    """Eq. 1: ``pulse ⊗ window²`` on the common grid, normalised to unit integral (m-1).

    ``pulse`` and ``window`` are sampled on the same odd-length, zero-centred grid of spacing
    ``dz``; the grid must be wide enough to hold the whole result (the caller's job).
    """
    rwf = np.convolve(pulse, window**2, mode="same")
    return _normalise(np.clip(rwf, 0.0, None), dz)


#: Largest |exponent| (decades) of the Eq. 2 factor evaluated without a shift: 10^100 leaves
#: 200 decades of headroom for the RWF values and their sum before a float64 overflows.
_MAX_DECADES = 100.0


def cnr_weighted_rwf(rwf: np.ndarray, z: np.ndarray, cnr_gradient: np.ndarray, dz: float = 1.0,
                     scale: float = 1.0, axis: int = 0) -> np.ndarray:
    """Eq. 2: ``RWF(z) 10^(scale g z / 20)`` with ``CNR(z) = CNR_0 + g z``, renormalised.

    The one implementation of Eq. 2, used for the tabulated RWF (:mod:`lidarcal.rwf.dataset`,
    ``axis=0``: result ``(z, *g.shape)``, unit integral with grid spacing ``dz``) and for the
    virtual lidar's quadrature nodes (:mod:`lidarcal.lidar.quadrature`, ``axis=-1``: result
    ``(*g.shape, K)``, ``dz = 1`` so the weights sum to 1).  ``rwf`` and ``z`` are 1-D of equal
    length, ``g`` in dB m-1 has any shape; ``scale = 0`` returns the unweighted RWF.

    Overflow guard: where the largest exponent along ``axis`` exceeds ``_MAX_DECADES`` in
    magnitude it is subtracted before ``10**`` (the constant cancels in the renormalisation);
    elsewhere the factor is evaluated as written, so moderate gradients give the same bits
    with or without the guard.
    """
    w0 = np.asarray(rwf, dtype=float)
    s = np.asarray(z, dtype=float)
    g = np.asarray(cnr_gradient, dtype=float)
    if axis == 0:
        shape = (-1,) + (1,) * g.ndim
        w0, s, g = w0.reshape(shape), s.reshape(shape), g[None, ...]
    elif axis == -1:
        g = g[..., None]
    else:
        raise ValueError(f"axis must be 0 or -1; got {axis}")
    decades = scale * g * s / 20.0
    top = np.max(decades, axis=axis, keepdims=True)
    shift = np.abs(top) > _MAX_DECADES
    if np.any(shift):
        decades = decades - np.where(shift, top, 0.0)
    w = w0 * 10.0 ** decades
    return _normalise(w, dz, axis=axis)


def barycenter(weights: np.ndarray, z: np.ndarray) -> np.ndarray:
    """First moment of ``weights`` along axis 0 (the barycenter of the RWF), metres."""
    z = np.asarray(z, dtype=float)
    w = np.asarray(weights, dtype=float)
    zz = z.reshape((-1,) + (1,) * (w.ndim - 1))
    return np.sum(w * zz, axis=0) / np.sum(w, axis=0)


def full_width_half_maximum(weights: np.ndarray, z: np.ndarray) -> float:
    """FWHM of a single-peaked curve, crossings found by linear interpolation (m)."""
    w = np.asarray(weights, dtype=float)
    half = 0.5 * w.max()
    above = np.flatnonzero(w >= half)
    i, j = above[0], above[-1]
    if i == 0 or j == len(w) - 1:
        return float("nan")  # the half-maximum crossing lies outside the grid

    def cross(a: int, b: int) -> float:
        return z[a] + (half - w[a]) * (z[b] - z[a]) / (w[b] - w[a])

    return float(cross(j, j + 1) - cross(i - 1, i))
