"""An independent field-campaign simulator for testing ``lidarcal diagnose`` (a test helper).

It shares no code with lidarcal's engine (no ``lidarcal.lidar``, ``lidarcal.turbulence``,
``lidarcal.campaign`` or ``lidarcal.diagnose``): the same physics, written again, differently,
so that a diagnosis is tested on data it did not generate — as real field data.

Per ten-minute period (1 Hz, 600 s):

* **Atmosphere.** A true speed at 80 m, direction, power-law shear exponent and turbulence
  intensity profile are drawn from this module's own ``numpy.random.Generator``.
* **Turbulence.** ONE box per period for all heights (heights are coherent with each other,
  unlike the engine's one box per height), made with PyConTurb's own building blocks: its
  Kaimal spectra and magnitude scaling (``pyconturb.magnitudes.get_magnitudes``) and its IEC
  3-D coherence (``pyconturb.coherence.get_iec3d_cor_mat``, the ``coh_model="iec3d"`` of
  ``gen_turb``), with this module's own phases and one batched Cholesky per component —
  ``gen_turb``'s algorithm (``docs/performance.md``: about 4 s per call even for 20 points,
  because it loops over frequencies in Python) at about 0.15 s of CPU per period of 4 heights
  (measured: 200 periods in 35 s on a shared 2-core machine).  The box holds only
  the points needed: 3 points along each beam per height (−1.5 σ, 0, +1.5 σ of the RWF; the
  fine RWF quadrature below interpolates between them) and the cup at every height,
  de-duplicated in (y, z); the along-wind position becomes Taylor's frozen-turbulence delay.
* **Lidar.** Four beams (azimuths 0, 90, 180, 270°) at the true cone angle, one line of sight
  per second in turn; each LOS is a 41-node quadrature of a Gaussian RWF (±3 σ) of the radial
  velocity of the mean power-law profile plus the turbulence, optionally weighted by the CNR
  *profile itself* along the beam (Eq. 2, ``10^(CNR(z)/20)``, not a linear gradient), plus
  Gaussian noise.  Reconstruction: sliding DBS with the latest sample of each beam and the
  nominal cone, scalar and vector 10-minute averages, hybrid ``p·scalar + (1 − p)·vector``.
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
at low CNR; no catalogue effect acts through the CNR level}.
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
}

DURATION = 600.0  # s
NT = 600  # 1 Hz
AZIMUTHS = np.array([0.0, 90.0, 180.0, 270.0])
N_RWF = 41  # RWF quadrature nodes per LOS
N_TURB = 3  # turbulence points per beam and height (the quadrature interpolates between them)
L_C = 8.1 * 42.0  # IEC coherence length scale (m)
REF_HEIGHT = 80.0

_CACHE: dict[str, tuple[xr.Dataset, dict[str, np.ndarray]]] = {}


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


def _dbs(los: np.ndarray, beam: np.ndarray, cone: float, p: float) -> float:
    """Sliding DBS: at every step once all four beams exist, the latest LOS of each beam.

    ``beam`` cycles 0, 1, 2, 3 (azimuths 0, 90, 180, 270°), so at step k the latest sample of
    beam b is k − ((k − b) mod 4).  Horizontal components with the nominal cone; returns the
    hybrid ``p · scalar + (1 − p) · vector`` 10-minute average.
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
    return p * scalar + (1.0 - p) * vector


def _period(heights, U80, direction, alpha, ti80, level, lapse, eff, cone, p, fwhm, noise_std, rng):
    """One period: lidar speed and cup series statistics at every height."""
    heights = np.asarray(heights, dtype=float)
    nh = heights.size
    phi_nom = np.radians(cone)
    phi = np.radians(cone + eff.get("beam_angle_offset", {}).get("offset", 0.0))
    zd = eff.get("zero_distance_offset", {}).get("offset", 0.0)
    scale = eff.get("cnr_gradient_weighting", {}).get("scale", 0.0)
    p_true = eff.get("hybrid_weight", {}).get("p", p)
    sigma_r = fwhm / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    s_nodes = np.linspace(-3.0 * sigma_r, 3.0 * sigma_r, N_RWF)
    s_turb = np.linspace(-1.5 * sigma_r, 1.5 * sigma_r, N_TURB)
    # wind frame: downwind d, cross-wind c (to the left of d), both horizontal (east, north)
    to = np.radians(direction + 180.0)
    d = np.array([np.sin(to), np.cos(to)])
    c = np.array([-d[1], d[0]])
    az = np.radians(AZIMUTHS)
    nb = np.column_stack([np.sin(phi) * np.sin(az), np.sin(phi) * np.cos(az), np.full(4, np.cos(phi))])
    # turbulence points: (height, beam, N_TURB) along the beams, then the cups
    r_c = heights / np.cos(phi_nom) + zd  # gate centres along the beam (m)
    rt = r_c[:, None, None] + s_turb[None, None, :]
    pts = rt[..., None] * nb[None, :, None, :]  # (nh, 4, N_TURB, 3)
    pts = np.concatenate([pts.reshape(-1, 3), np.column_stack([np.zeros((nh, 2)), heights])])
    x = pts[:, :2] @ d
    y = pts[:, :2] @ c
    z = pts[:, 2]
    speed = U80 * (z / REF_HEIGHT) ** alpha
    ti = ti80 * (z / REF_HEIGHT) ** -0.15
    turb = _turbulence(y, z, x, ti * speed, U80, speed, rng)
    beam_turb = turb[:, :-nh].reshape(3, nh, 4, N_TURB, NT)
    cup_u, cup_v = turb[0, -nh:], turb[1, -nh:]
    # lidar
    k = np.arange(NT)
    beam_of = k % 4
    interp = np.array([np.interp(s_nodes, s_turb, np.eye(N_TURB)[i]) for i in range(N_TURB)]).T  # (41, 5)
    lidar = np.empty(nh)
    for i, h in enumerate(heights):
        r = r_c[i] + s_nodes
        zn = r * np.cos(phi)
        w0 = np.exp(-0.5 * (s_nodes / sigma_r) ** 2)
        if scale:
            excess = _cnr_profile(zn, level, lapse) - _cnr_profile(h, level, lapse)  # dB along the beam
            w0 = w0 * 10.0 ** (scale * excess / 20.0)
        w0 = w0 / w0.sum()
        mean_node = U80 * (zn / REF_HEIGHT) ** alpha  # (41,)
        los = np.empty(NT)
        for b in range(4):
            sel = beam_of == b
            u, v, w = (interp @ beam_turb[m, i, b][:, sel] for m in range(3))  # (41, n_b)
            along, across = nb[b, :2] @ d, nb[b, :2] @ c
            vr = (mean_node[:, None] + u) * along + v * across + w * nb[b, 2]
            los[sel] = w0 @ vr
        los += noise_std * rng.standard_normal(NT)
        lidar[i] = _dbs(los, beam_of, cone, p_true)
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
    return lidar, ref, ti_meas, vane, ti[-nh:]


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
    start: str = "2021-01-01",
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
                      start], sort_keys=True)
    if key not in _CACHE:
        _CACHE[key] = _make(eff, int(n_periods), heights, int(seed), float(cone_angle), float(hybrid_weight),
                            float(rwf_fwhm), float(los_noise_std), start)
    ds, truth = _CACHE[key]
    return ds.copy(deep=True), {k: v.copy() for k, v in truth.items()}


def make_field_campaign(effects: Mapping[str, Mapping[str, float]], *, n_periods: int,
                        heights: Sequence[float] = (40.0, 80.0, 120.0, 160.0), seed: int,
                        cone_angle: float = 28.0, hybrid_weight: float = 2.0 / 3.0, rwf_fwhm: float = 30.0,
                        los_noise_std: float = 0.1, start: str = "2021-01-01") -> xr.Dataset:
    """Return a ``field_campaign`` dataset (``docs/contracts.md``) with ``effects`` hidden.

    ``effects`` maps effect names (:data:`EFFECT_PARAMETERS`) to their parameters; ``{}`` is an
    effect-free campaign.  The ``lidar_*`` attributes give the nominal lidar (``cone_angle``,
    ``hybrid_weight``, ``rwf_fwhm``, ``los_noise_std``, 1 s per LOS); the effects appear only in
    the ``independent_hidden_effects`` attribute (JSON), which ``diagnose`` never reads.
    """
    return make_field_campaign_with_truth(
        effects, n_periods=n_periods, heights=heights, seed=seed, cone_angle=cone_angle,
        hybrid_weight=hybrid_weight, rwf_fwhm=rwf_fwhm, los_noise_std=los_noise_std, start=start)[0]


def _make(eff, n, heights, seed, cone, p, fwhm, noise_std, start):
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
        ti80 = 0.12 * (0.75 * U80 + 5.6) / U80 * rng.lognormal(0.0, 0.25) * 0.8
        level, lapse = rng.normal(-12.0, 2.0), rng.normal(0.01, 0.03)
        lidar, ref, ti, vane, ti_true = _period(heights, U80, direction, alpha, ti80, level, lapse, eff,
                                                cone, p, fwhm, noise_std, rng)
        out["lidar"][t], out["ref"][t], out["ti"][t], out["dir"][t] = lidar, ref, ti, vane
        out["ti_true"][t] = ti_true
        cnr[t] = _cnr_profile(heights, level, lapse) + rng.normal(0.0, 0.3, nh)
        if "lidar_low_cnr_bias" in eff:
            lc = eff["lidar_low_cnr_bias"]
            out["lidar"][t] *= np.where(cnr[t] < lc["threshold"], 1.0 + lc["error"], 1.0)
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
               "independent_hidden_effects": json.dumps(eff, sort_keys=True),
               "title": "Independent synthetic field campaign (tests/independent_campaign.py)"},
    )
    return ds, truth
