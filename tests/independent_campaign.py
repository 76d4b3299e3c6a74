"""An independent field-campaign simulator for testing ``lidarcal diagnose`` (a test helper).

It shares no code with lidarcal's engine (no ``lidarcal.lidar``, ``lidarcal.turbulence``,
``lidarcal.campaign`` or ``lidarcal.diagnose``): the same physics, written again, differently,
so that a diagnosis is tested on data it did not generate — as real field data.

Per ten-minute period (1 Hz, 600 s):

* **Atmosphere.** A true speed at 80 m, direction, power-law shear exponent and turbulence
  intensity profile are drawn from this module's own ``numpy.random.Generator``.
* **Turbulence** (``rwf="continuous"``, the default). The four LOS signals of every height and
  the cups' u and v at every height are drawn TOGETHER (heights are coherent with each other,
  unlike the engine's one box per height) from their cross-spectral matrix, built from
  PyConTurb's own building blocks: its Kaimal spectra and magnitude scaling
  (``pyconturb.magnitudes.get_magnitudes``; σ_v = 0.8 σ_u, σ_w = 0.5 σ_u, each gate at its
  centre height) and the IEC 3-D coherence of its ``iec3d`` model (``get_iec3d_cor_mat``; the
  formula is written here for distances, :func:`_coherence`, and tested against it).  Each LOS
  is the continuous-RWF integral of the radial turbulence along its beam: pairs on one beam are
  double integrals over the beam integrated exactly over cells of σ_r/8, pairs on different
  beams use nodes σ_r/2 apart (:func:`_los_covariance`); a point's along-wind position x
  becomes Taylor's frozen-turbulence delay x / U.  Gaussian Fourier coefficients, one Cholesky
  factor per frequency.  About 0.1 s of CPU per period of 4 heights (the turbulence of a
  period is memoised, so paired campaigns share it).  It converges: halving both grid steps
  moves the matrix by < 0.2 % of its diagonal and the hybrid response by 0.2 %, and at 100 m,
  8 m/s, TI 0.2 its hybrid response (V_scalar − V_vector)/R is within 2 % of lidarcal's engine
  (``tests/test_independent_campaign.py``).
* **Turbulence** (``rwf="three_point"``, a deliberately mis-specified simulator, kept for the
  tests that want one). PyConTurb's spectra and coherence at 3 points along each beam per
  height (−1.5 σ, 0, +1.5 σ of the RWF), linearly interpolated under the RWF, fixed-amplitude
  random phases and a batched Cholesky per component (``gen_turb``'s algorithm). Its hybrid
  response is 20 % too large at TI 0.2 (0.90 % against 0.75 %) and its TI² slope of the mean
  (L − R)/R 8-10 % flatter (``docs/validation.md``): a model-form difference of the kind real data have.
* **Lidar.** Four beams (azimuths 0, 90, 180, 270°) at the true cone angle, one line of sight
  per second in turn; each LOS is the mean power-law profile's radial velocity under a
  Gaussian RWF (±3 σ, a 41-node quadrature) plus the turbulence above, the RWF optionally
  weighted by the CNR *profile itself* along the beam (Eq. 2, ``10^(CNR(z)/20)``, not a linear
  gradient), plus Gaussian noise.  Reconstruction: sliding DBS with the latest sample of each
  beam and the nominal cone, scalar and vector 10-minute averages, hybrid
  ``p·scalar + (1 − p)·vector``.
* **Mast.** A cup and vane at (0, 0, h): the cup's 1 Hz horizontal speed; the reported
  ``wind_speed`` / ``reference_wind_speed`` is its 10-minute mean, ``turbulence_intensity``
  its own σ / mean, ``wind_from_direction`` the vector-mean direction of the vane, and
  ``wind_shear_exponent`` the log-log slope of the cup means at the neighbouring heights (one
  neighbour at the ends).  The conditions are these *measured* values, as a real mast reports.
* **CNR.** A smooth profile per period: level, a lapse rate that varies between periods and a
  bump at the telescope focus (110 m); ``cnr_gradient`` is its derivative along the beam.

Effects (``effects={"name": {parameter: value}}``): the catalogue effects of
``docs/diagnose.md`` — ``zero_distance_offset`` {offset m}, ``beam_angle_offset`` {offset
degree}, ``cnr_gradient_weighting`` {scale}, ``hybrid_weight`` {p}, ``reference_overspeeding``
{coefficient}, ``reference_flow_distortion`` {centre, width, deficit: applied to every 1 Hz
cup sample whose *instantaneous* direction lies in the sector, so the edge is smoothed by the
direction's fluctuations}, ``reference_gain`` {gain} — and one outside the catalogue,
``lidar_sector_error`` {centre, width, error: the lidar's 10-minute speed is (1 + error) × its
value when the vane's mean direction lies in the sector} — on lidar/reference ratios this is
indistinguishable from the reference's mast shadow (``reference_flow_distortion`` with deficit
error/(1 + error)), so it is *not* outside the catalogue any more — and one that is,
``lidar_low_cnr_bias`` {threshold dB, error: the lidar's 10-minute speed is (1 + error) × its
value at a (period, height) whose reported CNR is below threshold: a Doppler estimator biased
at low CNR; no catalogue effect acts through the CNR level, but its non-zero mean looks like a
reference gain} and ``lidar_cnr_slope`` {slope per dB, pivot dB: the lidar's speed is
(1 + slope · (CNR − pivot)) × its value; with the pivot at the campaign's median CNR
(about −10.3 dB) its mean is near zero, so no constant effect can absorb it}.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
import xarray as xr
from pyconturb.coherence import get_iec3d_cor_mat
from pyconturb.magnitudes import get_magnitudes
from pyconturb.spectral_models import kaimal_spectrum

__all__ = ["EFFECT_PARAMETERS", "make_field_campaign", "make_field_campaign_with_truth"]

#: Every supported effect and its parameter names.
EFFECT_PARAMETERS: dict[str, tuple[str, ...]] = {
    "zero_distance_offset": ("offset",),
    "beam_angle_offset": ("offset",),
    "cnr_gradient_weighting": ("scale",),
    "hybrid_weight": ("p",),
    "reference_overspeeding": ("coefficient",),
    "reference_flow_distortion": ("centre", "width", "deficit"),
    "reference_gain": ("gain",),
    "lidar_sector_error": ("centre", "width", "error"),
    "lidar_low_cnr_bias": ("threshold", "error"),
    "lidar_cnr_slope": ("slope", "pivot"),
}

DURATION = 600.0  # s
NT = 600  # 1 Hz
AZIMUTHS = np.array([0.0, 90.0, 180.0, 270.0])
N_RWF = 41  # RWF quadrature nodes per LOS
FINE_STEP, COARSE_STEP = 1.0 / 8.0, 0.5  # continuous RWF: grid steps along the beam, in σ_r
L_C = 8.1 * 42.0  # IEC coherence length scale (m)
REF_HEIGHT = 80.0

_CACHE: dict[str, tuple[xr.Dataset, dict[str, np.ndarray]]] = {}
#: Continuous-RWF turbulence of recent periods (oldest dropped first beyond the byte budget).
_TURBULENCE: dict[str, np.ndarray] = {}
TURBULENCE_CACHE_BYTES = 200 * 2**20


def _sector(direction, centre: float, width: float) -> np.ndarray:
    return np.abs((np.asarray(direction) - centre + 180.0) % 360.0 - 180.0) <= 0.5 * width


def _cnr_profile(z, level: float, lapse: float):
    """CNR (dB) at heights z: level − lapse·(z − 100) + a 3 dB bump at the 110 m focus."""
    z = np.asarray(z, dtype=float)
    return level - lapse * (z - 100.0) + 3.0 * np.exp(-0.5 * ((z - 110.0) / 35.0) ** 2)


def _cnr_slope(z, lapse: float):
    """dCNR/dz (dB m-1) of :func:`_cnr_profile`."""
    z = np.asarray(z, dtype=float)
    return -lapse - 3.0 * (z - 110.0) / 35.0**2 * np.exp(-0.5 * ((z - 110.0) / 35.0) ** 2)


def _turbulence(y, z, x, sigma_u, u_ref, mean_speed, rng):
    """Fluctuations (3, n_points, NT) at points (x along-wind, y cross-wind, z up) of one period.

    PyConTurb's Kaimal magnitudes (scaled to σ_u, 0.8 σ_u, 0.5 σ_u per point) and its iec3d
    coherence, this module's phases, a batched Cholesky per component; points sharing (y, z)
    share a series, and each point is delayed by x / (its mean speed) (frozen turbulence).
    """
    yz = np.round(np.column_stack([y, z]), 6)
    uniq, first, inverse = np.unique(yz, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    n = uniq.shape[0]
    nf = NT // 2 + 1
    freq = np.arange(nf) / DURATION
    out = np.empty((3, n, NT))
    for k, factor in enumerate((1.0, 0.8, 0.5)):
        spat = pd.DataFrame(np.vstack([np.full(n, k), np.zeros(n), uniq[:, 0], uniq[:, 1]]),
                            index=["k", "x", "y", "z"], columns=[f"{'uvw'[k]}_p{i}" for i in range(n)])
        sig = factor * np.asarray(sigma_u)[first]
        mags = get_magnitudes(spat, kaimal_spectrum, lambda spat_df, sig=sig, **kw: sig, T=DURATION,
                              nt=NT, u_ref=u_ref)  # (nf, n)
        coh = get_iec3d_cor_mat(freq[1:], spat, u_ref=u_ref, l_c=L_C)  # (nf-1, n, n)
        chol = np.linalg.cholesky(coh + 1e-12 * np.eye(n))
        phase = np.exp(2j * np.pi * rng.random((nf, n)))
        phase[-1] = np.sign(np.cos(np.angle(phase[-1]))) + 0j  # Nyquist term real (even NT)
        coef = np.zeros((nf, n), complex)
        coef[1:] = (chol @ (mags[1:] * phase[1:])[:, :, None])[:, :, 0]
        out[k] = np.fft.irfft(coef, n=NT, axis=0).T * NT
    series = out[:, inverse]
    delay = np.asarray(x) / np.asarray(mean_speed)
    spec = np.fft.rfft(series, axis=-1) * np.exp(-2j * np.pi * freq * delay[:, None])
    return np.fft.irfft(spec, n=NT, axis=-1)


def _coherence(r, freq, k: int, u_ref: float):
    """IEC coherence of component ``k`` (0 u, 1 v, 2 w) at y-z distance ``r`` (m) and ``freq`` (Hz).

    The formula of PyConTurb's ``iec3d`` model (length scale ``L_C`` for u, 2.7/8.1 and 0.66/8.1
    of it for v and w), written here for distances rather than point lists;
    ``tests/test_independent_campaign.py`` checks it against ``get_iec3d_cor_mat``.
    """
    return np.exp(-_decay(freq, k, u_ref) * np.abs(r))


def _magnitudes(z, sigma, k: int, u_ref: float) -> np.ndarray:
    """PyConTurb's Kaimal Fourier magnitudes (nf, n) of component ``k`` at heights ``z``, std ``sigma``."""
    n = len(z)
    spat = pd.DataFrame(np.vstack([np.full(n, k), np.zeros(n), np.zeros(n), np.asarray(z, float)]),
                        index=["k", "x", "y", "z"], columns=[f"{'uvw'[k]}_p{i}" for i in range(n)])
    sig = np.asarray(sigma, dtype=float)
    return get_magnitudes(spat, kaimal_spectrum, lambda spat_df, sig=sig, **kw: sig, T=DURATION, nt=NT,
                          u_ref=u_ref)


def _gate_weights(s, r_c, sigma_r, weight):
    """RWF weights (n_gates, len(s)) of every gate at beam distances ``s``, each row summing to 1.

    The Gaussian RWF over ±3 σ_r about each gate centre times ``weight(i, s)`` (the Eq. 2 CNR
    factor, or 1).
    """
    rel = np.asarray(s)[None, :] - np.asarray(r_c)[:, None]
    w = np.where(np.abs(rel) <= 3.0 * sigma_r + 1e-9, np.exp(-0.5 * (rel / sigma_r) ** 2), 0.0)
    w = w * np.array([weight(i, s) for i in range(len(r_c))])
    return w / w.sum(axis=1, keepdims=True)


def _decay(freq, k: int, u_ref: float) -> np.ndarray:
    """Decay rate a (m-1) of :func:`_coherence`: coherence = exp(−a r)."""
    lc = L_C * (1.0, 2.7 / 8.1, 0.66 / 8.1)[k]
    return 12.0 * np.sqrt((np.asarray(freq) / u_ref) ** 2 + (0.12 / lc) ** 2)


def _spectral(freq, k: int, u_ref: float, r, dtau) -> np.ndarray:
    """:func:`_coherence` at distances ``r`` times the frozen-turbulence phase e^{−2πi f Δτ}, (nf, ...).

    ``freq`` are the multiples n/T of the first frequency: the phase at the n-th is the n-th
    power of the first one's (a running product instead of a complex exponential per entry).
    """
    r, dtau = np.asarray(r, dtype=float), np.asarray(dtau, dtype=float)
    step = np.exp(-2j * np.pi * dtau / DURATION)
    phase = np.cumprod(np.broadcast_to(step, (len(freq),) + step.shape), axis=0)
    return np.exp(-_decay(freq, k, u_ref).reshape((-1,) + (1,) * r.ndim) * r) * phase


def _cell_kernel(zeta, n_lags: int):
    """Mean of exp(-a|x| - i q x) over pairs of unit cells ℓ cells apart, ℓ = −(n−1) … n−1.

    ``zeta`` = (a + i q)·Δ, one per frequency; returns (len(zeta), 2 n − 1).  The exact double
    integral of the coherence (times the frozen-turbulence phase) over two cells of the fine
    grid: e^{−ζ ℓ} (2 sinh(ζ/2)/ζ)² for ℓ > 0, its conjugate for −ℓ, and g(ζ) + g(ζ̄),
    g(ζ) = (ζ − 1 + e^{−ζ})/ζ², for ℓ = 0.  Unlike point values it stays right when the
    coherence decays within a cell (high frequencies).
    """
    zeta = np.asarray(zeta)[:, None]
    powers = np.cumprod(np.broadcast_to(np.exp(-zeta), (zeta.shape[0], n_lags - 1)), axis=1)  # e^{-ζℓ}
    pos = powers * (2.0 * np.sinh(zeta / 2.0) / zeta) ** 2
    zero = (zeta + np.expm1(-zeta)) / zeta**2
    return np.concatenate([np.conj(pos[:, ::-1]), zero + np.conj(zero), pos], axis=1)


def _los_covariance(r_c, z_gate, sigma_gate, heights, sigma_cup, nb, d, c, u_ref, sigma_r, weight,
                    fine=None, coarse=None):
    """Cross-spectral matrix (nf − 1, 6 nh, 6 nh) of the continuous-RWF LOS turbulence and the cups.

    Signals: the RWF-weighted radial turbulence of every (gate i, beam b) at index 4 i + b, then
    the cups' u (4 nh + j) and v (5 nh + j).  Each component (u, v, w; σ 1, 0.8, 0.5 × σ_u) has
    PyConTurb's Kaimal spectrum at the gate's centre height (at the cup's height for the cups)
    and the iec3d coherence in (y, z); a point at along-wind position x lags by x / u_ref
    (frozen turbulence).  The RWF is continuous:

    * pairs on the same beam (any two gates) are double integrals over the beam that depend on
      the separation only: the gates' weights on a ``fine`` grid (σ_r / 8) are cross-correlated
      once and summed against the coherence integrated exactly over each pair of cells
      (:func:`_cell_kernel`) at every lag;
    * pairs on different beams, and beam-cup pairs, are smooth in the positions (their
      coherence is small wherever it varies fast): the weights on a ``coarse`` grid (σ_r / 2)
      shared by the gates of a beam.

    ``tests/test_independent_campaign.py`` checks both against a brute-force double sum over
    explicit points and PyConTurb's own ``get_iec3d_cor_mat``.
    """
    fine, coarse = fine or FINE_STEP, coarse or COARSE_STEP
    nh = len(r_c)
    freq = np.arange(1, NT // 2 + 1) / DURATION
    lo, hi = np.min(r_c) - 3.0 * sigma_r, np.max(r_c) + 3.0 * sigma_r
    step_f, step_c = sigma_r * fine, sigma_r * coarse
    s_f = lo + step_f * np.arange(int(np.ceil((hi - lo) / step_f)) + 1)
    s_c = lo + step_c * np.arange(int(np.ceil((hi - lo) / step_c)) + 1)
    w_f, w_c = _gate_weights(s_f, r_c, sigma_r, weight), _gate_weights(s_c, r_c, sigma_r, weight)
    # cross-correlations of the fine weights: corr[i, j, l] = sum_q w_i[q + l] w_j[q]
    corr = np.array([[np.correlate(w_f[i], w_f[j], "full") for j in range(nh)] for i in range(nh)])
    corr = corr.reshape(nh * nh, -1).T
    # coarse nodes of every beam: y (cross-wind), z and the frozen-turbulence delay x / u_ref
    pos = s_c[None, :, None] * nb[:, None, :]  # (4, n_c, 3)
    y, z, tau = pos[..., :2] @ c, pos[..., 2], (pos[..., :2] @ d) / u_ref
    cup_y, cup_z = np.zeros(nh), np.asarray(heights, dtype=float)
    proj = np.array([nb[:, :2] @ d, nb[:, :2] @ c, nb[:, 2]])  # (component, beam): radial share
    cov = np.zeros((freq.size, 6 * nh, 6 * nh), complex)
    los = 4 * np.arange(nh)

    def add(rows, cols, block):  # a block and, off the diagonal, its Hermitian mirror
        cov[:, rows[:, None], cols[None, :]] += block
        if rows is not cols:
            cov[:, cols[:, None], rows[None, :]] += np.conj(block).transpose(0, 2, 1)

    for k, share in enumerate((1.0, 0.8, 0.5)):
        m_g = _magnitudes(z_gate, share * np.asarray(sigma_gate), k, u_ref)[1:]  # (nf-1, nh)
        m_c = _magnitudes(heights, share * np.asarray(sigma_cup), k, u_ref)[1:]
        mm = m_g[:, :, None] * m_g[:, None, :]
        cup = (4 + k) * nh + np.arange(nh)
        for b in range(4):
            # same beam: the coherence along the beam (y-z distance rho per metre) and the delay,
            # integrated exactly over pairs of fine cells
            rho = np.hypot(nb[b, :2] @ c, nb[b, 2])
            zeta = (_decay(freq, k, u_ref) * rho + 2j * np.pi * freq * (nb[b, :2] @ d) / u_ref) * step_f
            same = (_cell_kernel(zeta, s_f.size) @ corr).reshape(-1, nh, nh)
            beam = los + b
            add(beam, beam, proj[k, b] ** 2 * mm * same)
            for bb in range(b + 1, 4):  # another beam: point values on the coarse nodes
                g = _spectral(freq, k, u_ref, np.hypot(y[b][:, None] - y[bb], z[b][:, None] - z[bb]),
                              tau[b][:, None] - tau[bb])  # (nf-1, n_c, n_c)
                add(beam, los + bb, proj[k, b] * proj[k, bb] * mm * (w_c @ g @ w_c.T))
            if k < 2:  # the cups' u and v
                g = _spectral(freq, k, u_ref, np.hypot(y[b][:, None] - cup_y, z[b][:, None] - cup_z),
                              tau[b][:, None] - np.zeros(nh))  # (nf-1, n_c, nh)
                add(beam, cup, proj[k, b] * m_g[:, :, None] * m_c[:, None, :] * (w_c @ g))
        if k < 2:
            g = _spectral(freq, k, u_ref, np.abs(cup_z[:, None] - cup_z), np.zeros((nh, nh)))
            add(cup, cup, m_c[:, :, None] * m_c[:, None, :] * g)
    return cov


def _draw(cov, rng) -> np.ndarray:
    """Gaussian Fourier coefficients with cross-spectral matrix ``cov``; the series (n, NT).

    One Cholesky factor per frequency (continuous in the matrix, so campaigns that share a seed
    and differ by an effect stay paired).  The Nyquist term is real (even NT): drawn from the
    real part of its matrix.
    """
    nf1, n, _ = cov.shape
    xi = (rng.standard_normal((nf1 - 1, n)) + 1j * rng.standard_normal((nf1 - 1, n))) / np.sqrt(2.0)
    coef = np.zeros((nf1 + 1, n), complex)
    coef[1:-1] = (np.linalg.cholesky(cov[:-1]) @ xi[:, :, None])[:, :, 0]
    coef[-1] = np.linalg.cholesky(cov[-1].real) @ rng.standard_normal(n)
    return np.fft.irfft(coef, n=NT, axis=0).T * NT


def _dbs(los: np.ndarray, beam: np.ndarray, cone: float) -> tuple[float, float]:
    """Sliding DBS: at every step once all four beams exist, the latest LOS of each beam.

    ``beam`` cycles 0, 1, 2, 3 (azimuths 0, 90, 180, 270°), so at step k the latest sample of
    beam b is k − ((k − b) mod 4).  Horizontal components with the nominal cone; returns the
    scalar and the vector 10-minute averages (the hybrid is ``p · scalar + (1 − p) · vector``).
    """
    k = np.arange(3, los.size)[:, None]
    b = np.arange(4)[None, :]
    if not np.array_equal(beam, np.arange(los.size) % 4):
        raise ValueError("beams must cycle 0, 1, 2, 3")
    latest = los[k - ((k - b) % 4)]  # (steps, 4)
    s = np.sin(np.radians(cone))
    north = (latest[:, 0] - latest[:, 2]) / (2.0 * s)
    east = (latest[:, 1] - latest[:, 3]) / (2.0 * s)
    scalar = float(np.mean(np.hypot(east, north)))
    vector = float(np.hypot(east.mean(), north.mean()))
    return scalar, vector


def _period(heights, U80, direction, alpha, ti80, level, lapse, eff, cone, p, fwhm, noise_std, rng,
            rwf="continuous", turb_seed=()):
    """One period: lidar speed (hybrid, scalar, vector) and cup series statistics at every height.

    ``rwf``: ``"continuous"`` (the default: the LOS turbulence is the continuous-RWF integral,
    :func:`_los_covariance`) or ``"three_point"`` (turbulence at 3 points per beam, interpolated
    under the RWF: a deliberately mis-specified simulator); ``("points", n, span)`` puts n points
    over ±span σ_r (convergence studies).  The continuous turbulence has its own stream,
    ``default_rng(turb_seed)``, and is memoised on everything it depends on (effects that act on
    the reference or on the lidar's speed leave it as it was; paired campaigns share it).
    """
    heights = np.asarray(heights, dtype=float)
    nh = heights.size
    phi_nom = np.radians(cone)
    phi = np.radians(cone + eff.get("beam_angle_offset", {}).get("offset", 0.0))
    zd = eff.get("zero_distance_offset", {}).get("offset", 0.0)
    scale = eff.get("cnr_gradient_weighting", {}).get("scale", 0.0)
    p_true = eff.get("hybrid_weight", {}).get("p", p)
    sigma_r = fwhm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    s_nodes = np.linspace(-3.0 * sigma_r, 3.0 * sigma_r, N_RWF)
    # wind frame: downwind d, cross-wind c (to the left of d), both horizontal (east, north)
    to = np.radians(direction + 180.0)
    d = np.array([np.sin(to), np.cos(to)])
    c = np.array([-d[1], d[0]])
    az = np.radians(AZIMUTHS)
    nb = np.column_stack([np.sin(phi) * np.sin(az), np.sin(phi) * np.cos(az), np.full(4, np.cos(phi))])
    r_c = heights / np.cos(phi_nom) + zd  # gate centres along the beam (m)

    def excess(i, s):  # Eq. 2 CNR weighting along the beam (dB above the gate's height), or none
        if not scale:
            return np.ones(np.shape(s))
        return 10.0 ** (scale * (_cnr_profile(np.asarray(s) * np.cos(phi), level, lapse)
                                 - _cnr_profile(heights[i], level, lapse)) / 20.0)

    ti_cup = ti80 * (heights / REF_HEIGHT) ** -0.15
    if rwf == "continuous":
        z_gate = r_c * np.cos(phi)
        sigma_gate = ti80 * (z_gate / REF_HEIGHT) ** -0.15 * U80 * (z_gate / REF_HEIGHT) ** alpha
        key = json.dumps([list(turb_seed), U80, direction, alpha, ti80, [level, lapse, scale] if scale else 0,
                          heights.tolist(), float(phi), float(zd), fwhm])
        if key not in _TURBULENCE:
            sigma_cup = ti_cup * U80 * (heights / REF_HEIGHT) ** alpha
            cov = _los_covariance(r_c, z_gate, sigma_gate, heights, sigma_cup, nb, d, c, U80, sigma_r, excess)
            _TURBULENCE[key] = _draw(cov, np.random.default_rng(list(turb_seed)))
            while len(_TURBULENCE) * _TURBULENCE[key].nbytes > TURBULENCE_CACHE_BYTES:
                _TURBULENCE.pop(next(iter(_TURBULENCE)))
        series = _TURBULENCE[key]
        los_turb = series[:4 * nh].reshape(nh, 4, NT)
        cup_u, cup_v = series[4 * nh:5 * nh], series[5 * nh:]
    else:
        n_pts, span = (3, 1.5) if rwf == "three_point" else rwf[1:]
        s_turb = np.linspace(-span * sigma_r, span * sigma_r, n_pts)
        # turbulence points: (height, beam, n_pts) along the beams, then the cups
        rt = r_c[:, None, None] + s_turb[None, None, :]
        pts = rt[..., None] * nb[None, :, None, :]  # (nh, 4, n_pts, 3)
        pts = np.concatenate([pts.reshape(-1, 3), np.column_stack([np.zeros((nh, 2)), heights])])
        x = pts[:, :2] @ d
        y = pts[:, :2] @ c
        z = pts[:, 2]
        speed = U80 * (z / REF_HEIGHT) ** alpha
        ti = ti80 * (z / REF_HEIGHT) ** -0.15
        turb = _turbulence(y, z, x, ti * speed, U80, speed, rng)
        beam_turb = turb[:, :-nh].reshape(3, nh, 4, n_pts, NT)
        cup_u, cup_v = turb[0, -nh:], turb[1, -nh:]
        # linear interpolation between the turbulence points (outside them: the end point's value)
        interp = np.array([np.interp(s_nodes, s_turb, row) for row in np.eye(n_pts)]).T  # (N_RWF, n_pts)
        los_turb = np.empty((nh, 4, NT))
        for i in range(nh):
            w0 = _gate_weights(r_c[i] + s_nodes, r_c[i:i + 1], sigma_r, lambda _, s, i=i: excess(i, s))[0]
            for b in range(4):
                u, v, w = (w0 @ interp @ beam_turb[m, i, b] for m in range(3))
                los_turb[i, b] = u * (nb[b, :2] @ d) + v * (nb[b, :2] @ c) + w * nb[b, 2]
    # lidar: the mean (shear) part by the N_RWF-node quadrature, the turbulence, the noise
    beam_of = np.arange(NT) % 4
    scalar, vector = np.empty(nh), np.empty(nh)
    for i in range(nh):
        r = r_c[i] + s_nodes
        w0 = _gate_weights(r, r_c[i:i + 1], sigma_r, lambda _, s, i=i: excess(i, s))[0]
        mean_node = U80 * (r * np.cos(phi) / REF_HEIGHT) ** alpha  # (N_RWF,)
        mean_los = (w0 @ mean_node) * (nb[:, :2] @ d)  # (4,)
        los = mean_los[beam_of] + los_turb[i, beam_of, np.arange(NT)]
        los += noise_std * rng.standard_normal(NT)
        scalar[i], vector[i] = _dbs(los, beam_of, cone)
    lidar = p_true * scalar + (1.0 - p_true) * vector
    # mast: cup speed and vane direction at 1 Hz
    U_h = U80 * (heights / REF_HEIGHT) ** alpha
    east = (U_h[:, None] + cup_u) * d[0] + cup_v * c[0]
    north = (U_h[:, None] + cup_u) * d[1] + cup_v * c[1]
    cup = np.hypot(east, north)
    inst_dir = np.degrees(np.arctan2(-east, -north)) % 360.0
    if "reference_flow_distortion" in eff:
        fd = eff["reference_flow_distortion"]
        cup = cup * np.where(_sector(inst_dir, fd["centre"], fd["width"]), 1.0 - fd["deficit"], 1.0)
    cup = cup * (1.0 + eff.get("reference_gain", {}).get("gain", 0.0))
    mean = cup.mean(axis=1)
    ti_meas = cup.std(axis=1, ddof=1) / mean
    vane = np.degrees(np.arctan2(-east.mean(axis=1), -north.mean(axis=1))) % 360.0
    ref = mean * (1.0 + eff.get("reference_overspeeding", {}).get("coefficient", 0.0) * ti_meas)
    if "lidar_sector_error" in eff:
        se = eff["lidar_sector_error"]
        lidar = lidar * np.where(_sector(vane, se["centre"], se["width"]), 1.0 + se["error"], 1.0)
    return lidar, ref, ti_meas, vane, ti_cup, scalar, vector


def _shear(heights, speeds):
    """Log-log slope of the means at the neighbouring heights (one neighbour at the ends)."""
    h = np.asarray(heights, dtype=float)
    out = np.empty(speeds.shape)
    for i in range(h.size):
        lo, hi = max(i - 1, 0), min(i + 1, h.size - 1)
        out[:, i] = np.log(speeds[:, hi] / speeds[:, lo]) / np.log(h[hi] / h[lo])
    return out


def _check_effects(effects: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
    out = {}
    for name, params in effects.items():
        if name not in EFFECT_PARAMETERS:
            raise ValueError(f"unknown effect {name!r}; supported: {sorted(EFFECT_PARAMETERS)}")
        if set(params) != set(EFFECT_PARAMETERS[name]):
            raise ValueError(f"effect {name!r} needs parameters {EFFECT_PARAMETERS[name]}; "
                             f"got {sorted(params)}")
        out[name] = {k: float(v) for k, v in params.items()}
    return out


def make_field_campaign_with_truth(
    effects: Mapping[str, Mapping[str, float]], *, n_periods: int,
    heights: Sequence[float] = (40.0, 80.0, 120.0, 160.0), seed: int, cone_angle: float = 28.0,
    hybrid_weight: float = 2.0 / 3.0, rwf_fwhm: float = 30.0, los_noise_std: float = 0.1,
    start: str = "2021-01-01", rwf: str = "continuous", turbulence_scale: float = 1.0,
) -> tuple[xr.Dataset, dict[str, np.ndarray]]:
    """:func:`make_field_campaign` plus the hidden truth (true speed, shear, TI per period).

    Results are memoised per argument set for the session (copies are returned).  The
    atmosphere drawn for a period depends only on ``seed`` and the period's index, not on the
    effects, and so do the turbulence phases and the lidar noise: two campaigns with the same
    seed differ only by their effects (paired comparisons in the tests).
    """
    eff = _check_effects(effects)
    heights = tuple(float(h) for h in heights)
    key = json.dumps([eff, n_periods, heights, seed, cone_angle, hybrid_weight, rwf_fwhm, los_noise_std,
                      start, rwf, turbulence_scale], sort_keys=True)
    if key not in _CACHE:
        _CACHE[key] = _make(eff, int(n_periods), heights, int(seed), float(cone_angle), float(hybrid_weight),
                            float(rwf_fwhm), float(los_noise_std), start, rwf, float(turbulence_scale))
    ds, truth = _CACHE[key]
    return ds.copy(deep=True), {k: v.copy() for k, v in truth.items()}


def make_field_campaign(effects: Mapping[str, Mapping[str, float]], *, n_periods: int,
                        heights: Sequence[float] = (40.0, 80.0, 120.0, 160.0), seed: int,
                        cone_angle: float = 28.0, hybrid_weight: float = 2.0 / 3.0, rwf_fwhm: float = 30.0,
                        los_noise_std: float = 0.1, start: str = "2021-01-01",
                        rwf: str = "continuous", turbulence_scale: float = 1.0) -> xr.Dataset:
    """Return a ``field_campaign`` dataset (``docs/contracts.md``) with ``effects`` hidden.

    ``effects`` maps effect names (:data:`EFFECT_PARAMETERS`) to their parameters; ``{}`` is an
    effect-free campaign.  The ``lidar_*`` attributes give the nominal lidar (``cone_angle``,
    ``hybrid_weight``, ``rwf_fwhm``, ``los_noise_std``, 1 s per LOS); the effects appear only in
    the ``independent_hidden_effects`` attribute (JSON), which ``diagnose`` never reads.
    ``rwf`` is the turbulence along the beam (``"continuous"``, or the deliberately mis-specified
    ``"three_point"``, module docstring); ``turbulence_scale`` multiplies every period's
    turbulence intensity (another TI distribution).
    """
    return make_field_campaign_with_truth(
        effects, n_periods=n_periods, heights=heights, seed=seed, cone_angle=cone_angle,
        hybrid_weight=hybrid_weight, rwf_fwhm=rwf_fwhm, los_noise_std=los_noise_std, start=start, rwf=rwf,
        turbulence_scale=turbulence_scale)[0]


def _make(eff, n, heights, seed, cone, p, fwhm, noise_std, start, rwf, turbulence_scale):
    nh = len(heights)
    shape = (n, nh)
    out = {name: np.empty(shape) for name in ("lidar", "ref", "ti", "dir", "ti_true")}
    truth = {"speed_80": np.empty(n), "alpha": np.empty(n), "direction": np.empty(n), "ti_80": np.empty(n)}
    cnr = np.empty(shape)
    grad = np.empty(shape)
    for t in range(n):
        rng = np.random.default_rng([seed, t, 0x1D])
        U80 = rng.uniform(4.5, 15.0)
        direction = rng.uniform(0.0, 360.0)
        alpha = float(np.clip(rng.normal(0.14, 0.09), -0.1, 0.45))
        ti80 = 0.12 * (0.75 * U80 + 5.6) / U80 * rng.lognormal(0.0, 0.25) * 0.8 * turbulence_scale
        level, lapse = rng.normal(-12.0, 2.0), rng.normal(0.01, 0.03)
        lidar, ref, ti, vane, ti_true, _, _ = _period(heights, U80, direction, alpha, ti80, level, lapse, eff,
                                                      cone, p, fwhm, noise_std, rng, rwf=rwf,
                                                      turb_seed=(seed, t, 0x7B))
        out["lidar"][t], out["ref"][t], out["ti"][t], out["dir"][t] = lidar, ref, ti, vane
        out["ti_true"][t] = ti_true
        cnr[t] = _cnr_profile(heights, level, lapse) + rng.normal(0.0, 0.3, nh)
        if "lidar_low_cnr_bias" in eff:
            lc = eff["lidar_low_cnr_bias"]
            out["lidar"][t] *= np.where(cnr[t] < lc["threshold"], 1.0 + lc["error"], 1.0)
        if "lidar_cnr_slope" in eff:
            cs = eff["lidar_cnr_slope"]
            out["lidar"][t] *= 1.0 + cs["slope"] * (cnr[t] - cs["pivot"])
        grad[t] = _cnr_slope(heights, lapse) * np.cos(np.radians(cone))
        truth["speed_80"][t], truth["alpha"][t], truth["direction"][t], truth["ti_80"][t] = (U80, alpha,
                                                                                            direction, ti80)
    truth["turbulence_intensity_requested"] = out["ti_true"]
    time = pd.date_range(start, periods=n, freq="10min").values
    dims = ("time", "height")

    def var(values, units, long_name, standard_name=None):
        attrs = {"units": units, "long_name": long_name}
        if standard_name:
            attrs["standard_name"] = standard_name
        return (dims, values, attrs)

    ds = xr.Dataset(
        {
            "wind_speed": var(out["ref"], "m s-1", "mast cup 10-minute mean wind speed", "wind_speed"),
            "wind_from_direction": var(out["dir"], "degree", "mast vane vector-mean direction",
                                       "wind_from_direction"),
            "turbulence_intensity": var(out["ti"], "1", "cup standard deviation over mean"),
            "wind_shear_exponent": var(_shear(heights, out["ref"]), "1",
                                       "power-law exponent from the cup means at neighbouring heights"),
            "cnr": var(cnr, "dB", "lidar carrier-to-noise ratio"),
            "cnr_gradient": var(grad, "dB m-1", "CNR gradient along the beam"),
            "lidar_wind_speed": var(out["lidar"], "m s-1", "lidar 10-minute hybrid speed", "wind_speed"),
            "reference_wind_speed": var(out["ref"], "m s-1", "mast cup 10-minute mean speed", "wind_speed"),
        },
        coords={"time": ("time", time),
                "height": ("height", np.asarray(heights), {"units": "m", "standard_name": "height",
                                                           "positive": "up"})},
        attrs={"lidarcal_artefact": "field_campaign", "lidar_cone_angle": cone, "lidar_hybrid_weight": p,
               "lidar_rwf_fwhm": fwhm, "lidar_los_noise_std": noise_std, "lidar_beam_period": 1.0,
               "independent_hidden_effects": json.dumps(eff, sort_keys=True), "independent_rwf": str(rwf),
               "title": "Independent synthetic field campaign (tests/independent_campaign.py)"},
    )
    return ds, truth


def fixed_conditions(n_periods: int, *, height: float = 100.0, speed: float = 8.0, ti: float = 0.2,
                     direction: float = 0.0, seed: int = 0, cone_angle: float = 28.0, rwf_fwhm: float = 30.0,
                     los_noise_std: float = 0.1, rwf="continuous") -> dict[str, np.ndarray]:
    """Per-period records of one height in fixed conditions (no shear, no effect).

    ``speed`` and ``ti`` are the mean speed and the requested TI at ``height`` (the module's TI
    profile is scaled to give it there).  Returns ``scalar``, ``vector`` (the lidar's two
    10-minute averages), ``reference`` (the cup's mean) and ``ti`` (the cup's own TI), each of
    ``n_periods``: the statistics the diagnosis' responses rest on, e.g. the hybrid response
    (scalar − vector) / reference.
    """
    ti80 = ti * (height / REF_HEIGHT) ** 0.15
    out = {k: np.empty(n_periods) for k in ("scalar", "vector", "reference", "ti")}
    for t in range(n_periods):
        rng = np.random.default_rng([seed, t, 0x5F])
        _, ref, ti_meas, _, _, scalar, vector = _period(
            [height], speed, direction, 0.0, ti80, -12.0, 0.0, {}, cone_angle, 2.0 / 3.0, rwf_fwhm,
            los_noise_std, rng, rwf=rwf, turb_seed=(seed, t, 0x7C))
        for name, value in zip(("scalar", "vector", "reference", "ti"), (scalar, vector, ref, ti_meas),
                               strict=True):
            out[name][t] = value[0]
    return out
