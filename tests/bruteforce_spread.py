"""Brute-force reference for the spread of lidar − reference, made with PyConTurb's own ``gen_turb``.

A test helper (and, run as a script, the generator of ``tests/data/bruteforce_spread.json``).
It shares no code with lidarcal's engine: no ``lidarcal`` import at all.

One ten-minute period (1 Hz, 600 s) of an ideal DBS lidar (cone 28°, beams at azimuths
0/90/180/270°, one LOS per second in turn, sliding reconstruction, hybrid ``p = 2/3`` on the
scalar average, Gaussian LOS noise 0.1 m/s) and a cup at ``(0, 0, h)`` in uniform wind
``U = 8 m/s`` (no shear):

* **Turbulence** by ``pyconturb.gen_turb`` itself (Kaimal spectra, ``coh_model="iec3d"``,
  σ_u = TI·U, σ_v = 0.8 σ_u, σ_w = 0.5 σ_u), one call per component so that the reference's
  place in the Cholesky order can differ between components:

  - **u**: the cup point FIRST, then the beam points: its Fourier coefficients are
    ``m_u ξ_0`` with ``|ξ_0| = 1`` (gen_turb's fixed amplitudes), so its realised 10-minute
    σ_u is exactly TI·U — the measured value of a conditions file;
  - **v** and **w**: the cup point is one more point of the field, after the beam points
    (it does not influence them; its own v keeps gen_turb's point-level convention).

  gen_turb's Cholesky factors are computed once per case by PyConTurb's own
  ``generate_coherence_file`` and loaded by ``gen_turb(coh_file=...)`` (its documented cache).
* **Beams**: :data:`N_NODES` points per beam along ±3 σ of the Gaussian RWF (FWHM 30 m), the
  continuous RWF discretised with its own Gaussian weights; points sharing (y, z) — opposite
  beams when the wind blows along them, beam pairs at 45° — share one gen_turb point, and each
  point's along-wind position ``x`` becomes Taylor's frozen-turbulence delay ``x / U``
  (``gen_turb``'s ``iec3d`` coherence sees y and z only).
* **Cup**: 10-minute mean of ``sqrt((U + u)² + v²)`` at 1 Hz.

``python tests/bruteforce_spread.py [n_periods [case,case...]]`` extends the stored file (about 0.3 s per
period and case on a quiet core); ``tests/test_reference_turbulence.py`` checks a live subset
of it bit for bit and compares lidarcal's engine with its statistics.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pyconturb
from pyconturb import gen_turb
from pyconturb.coherence import generate_coherence_file

DATA = Path(__file__).parent / "data" / "bruteforce_spread.json"
U = 8.0
CONE = 28.0
P_HYBRID = 2.0 / 3.0
FWHM = 30.0
NOISE = 0.1
T, NT = 600.0, 600
N_NODES = 41
L_C = 340.2
SIGMA_RATIOS = (1.0, 0.8, 0.5)
CASES = [(ti, h, d) for ti in (0.1, 0.2) for h in (40.0, 120.0) for d in (0.0, 45.0)]


def case_name(ti: float, height: float, direction: float) -> str:
    return f"ti{ti:g}_h{height:g}_d{direction:g}"


class Case:
    """Geometry, gen_turb point lists and cached Cholesky factors of one (TI, height, direction)."""

    def __init__(self, ti: float, height: float, direction: float, workdir: Path):
        self.ti, self.height, self.direction = ti, height, direction
        phi = np.radians(CONE)
        az = np.radians([0.0, 90.0, 180.0, 270.0])
        nb = np.column_stack([np.sin(phi) * np.sin(az), np.sin(phi) * np.cos(az), np.full(4, np.cos(phi))])
        to = np.radians(direction + 180.0)  # the wind blows toward
        d = np.array([np.sin(to), np.cos(to)])  # downwind (east, north)
        c = np.array([-d[1], d[0]])  # cross-wind, to the left
        sig_r = FWHM / (2.0 * np.sqrt(2.0 * np.log(2.0)))
        s = np.linspace(-3.0 * sig_r, 3.0 * sig_r, N_NODES)
        w = np.exp(-0.5 * (s / sig_r) ** 2)
        self.w = w / w.sum()
        r = height / np.cos(phi) + s  # (N,)
        pts = r[None, :, None] * nb[:, None, :]  # (4, N, 3)
        self.x = pts[..., :2] @ d  # (4, N) along-wind
        y = pts[..., :2] @ c
        z = pts[..., 2]
        self.proj = np.column_stack([nb[:, :2] @ d, nb[:, :2] @ c, nb[:, 2]])  # (4, 3): a_b in (u, v, w)
        yz = np.round(np.column_stack([y.ravel(), z.ravel()]), 6)
        ref = np.array([[0.0, round(height, 6)]])
        uniq, inverse = np.unique(yz, axis=0, return_inverse=True)
        self.n_beam_points = uniq.shape[0]
        # u: the cup first (a beam point with the cup's (y, z) is the cup itself)
        is_ref = np.all(uniq == ref, axis=1)
        u_pts = np.concatenate([ref, uniq[~is_ref]])
        u_index = np.empty(uniq.shape[0], int)
        u_index[~is_ref] = 1 + np.arange(np.count_nonzero(~is_ref))
        u_index[is_ref] = 0
        # v: beam points, then the cup unless it is one of them; w: beam points
        v_pts = uniq if is_ref.any() else np.concatenate([uniq, ref])
        v_ref = int(np.flatnonzero(is_ref)[0]) if is_ref.any() else uniq.shape[0]
        self.points = [u_pts, v_pts, uniq]
        self.node_index = [u_index[inverse.ravel()].reshape(4, N_NODES)] + [
            inverse.ravel().reshape(4, N_NODES)] * 2
        self.ref_index = (0, v_ref)
        self.freq = np.arange(NT // 2 + 1) / T
        self.files = []
        for k in range(3):
            f = workdir / f"{case_name(ti, height, direction)}_{'uvw'[k]}.h5"
            generate_coherence_file(self._spat(k), f, freq=self.freq, coh_model="iec3d", u_ref=U, l_c=L_C)
            self.files.append(f)

    def _spat(self, k: int) -> pd.DataFrame:
        p = self.points[k]
        n = p.shape[0]
        return pd.DataFrame(np.vstack([np.full(n, k), np.zeros(n), p[:, 0], p[:, 1]]),
                            index=["k", "x", "y", "z"], columns=[f"{'uvw'[k]}_p{i}" for i in range(n)])

    def turbulence(self, seed_key) -> list[np.ndarray]:
        """gen_turb's (nt, n_points) series of u, v, w (zero mean)."""
        out = []
        for k in range(3):
            spat = self._spat(k)
            n = spat.shape[1]
            sig = SIGMA_RATIOS[k] * self.ti * U
            seed = int(np.random.SeedSequence([*seed_key, k]).generate_state(1)[0])
            df = gen_turb(spat, T=T, nt=NT, coh_model="iec3d", coh_file=self.files[k], nf_chunk=NT // 2 + 1,
                          seed=seed, u_ref=U, l_c=L_C,
                          wsp_func=lambda spat_df, **kw: np.zeros(spat_df.shape[1]),
                          sig_func=lambda spat_df, sig=sig, n=n, **kw: np.full(n, sig))
            out.append(df.to_numpy())
        return out

    def period(self, period: int, case_id: int) -> tuple[float, float]:
        """``(lidar hybrid speed, cup mean speed)`` of one period."""
        turb = self.turbulence((case_id, period))
        spec = [np.fft.rfft(t, axis=0) for t in turb]  # (nf, n) per component
        delay = np.exp(-2j * np.pi * self.freq[:, None, None] * (self.x / U)[None])  # (nf, 4, N)
        los_f = np.zeros((self.freq.size, 4), complex)
        for k in range(3):
            nodes = spec[k][:, self.node_index[k]]  # (nf, 4, N)
            los_f += self.proj[None, :, k] * np.sum(nodes * delay * self.w, axis=-1)
        los_b = np.fft.irfft(los_f, n=NT, axis=0) + U * self.proj[:, 0]  # (NT, 4)
        k = np.arange(NT)
        beam = k % 4
        rng = np.random.default_rng([case_id, period, 99])
        los = los_b[k, beam] + NOISE * rng.standard_normal(NT)
        cup = np.mean(np.hypot(U + turb[0][:, self.ref_index[0]], turb[1][:, self.ref_index[1]]))
        return dbs(los, CONE, P_HYBRID), float(cup)


def dbs(los: np.ndarray, cone: float, p: float) -> float:
    """Sliding DBS: from step 3 on, the latest LOS of each beam (beams cycle 0..3); hybrid speed."""
    k = np.arange(3, los.size)[:, None]
    b = np.arange(4)[None, :]
    latest = los[k - ((k - b) % 4)]
    s2 = 2.0 * np.sin(np.radians(cone))
    north, east = (latest[:, 0] - latest[:, 2]) / s2, (latest[:, 1] - latest[:, 3]) / s2
    return p * float(np.mean(np.hypot(east, north))) + (1.0 - p) * float(np.hypot(east.mean(), north.mean()))


def run_case(case_id: int, periods, workdir: Path) -> np.ndarray:
    """Per-period (L − R)/R of case ``CASES[case_id]`` for the given period numbers."""
    case = Case(*CASES[case_id], workdir)
    out = []
    for p in periods:
        lid, cup = case.period(int(p), case_id)
        out.append((lid - cup) / cup)
    return np.array(out)


def main(n_periods: int, cases=None) -> None:
    """Write ``n_periods`` periods of each case in ``cases`` (default all); stored periods are kept.

    A period depends only on its case and index, so extending a stored case gives the numbers a
    single longer run would.
    """
    result = json.loads(DATA.read_text()) if DATA.exists() else {"cases": {}}
    result.update({"pyconturb": pyconturb.__version__, "settings": {
        "wind_speed": U, "cone_angle": CONE, "hybrid_weight": P_HYBRID, "rwf_fwhm": FWHM,
        "los_noise_std": NOISE, "duration": T, "nt": NT, "nodes_per_beam": N_NODES,
        "reference": "first in the u factorisation, after the beam points in v"}})
    for cid, case in enumerate(CASES):
        if cases is not None and cid not in cases:
            continue
        old = result["cases"].get(case_name(*case), {"ratio": [], "cpu_s": 0.0})
        t0 = time.process_time()
        with tempfile.TemporaryDirectory() as tmp:
            new = run_case(cid, range(len(old["ratio"]), n_periods), Path(tmp))
        cpu = time.process_time() - t0
        ratio = np.concatenate([old["ratio"], new])
        result["cases"][case_name(*case)] = {"ratio": [round(float(r), 12) for r in ratio],
                                             "cpu_s": round(old["cpu_s"] + cpu, 1)}
        print(f"{case_name(*case)}: mean {100 * ratio.mean():+.4f} %  std {100 * ratio.std(ddof=1):.4f} %  "
              f"({ratio.size} periods, {cpu:.0f} s CPU)", flush=True)
        DATA.parent.mkdir(exist_ok=True)
        DATA.write_text(json.dumps(result, indent=0))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 600,
         [int(c) for c in sys.argv[2].split(",")] if len(sys.argv) > 2 else None)
