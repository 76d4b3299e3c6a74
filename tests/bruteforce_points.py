"""Point-level brute force of the spread of lidar − reference, with fixed or Gaussian amplitudes (numpy only).

A test helper (and, run as a script, the generator of ``tests/data/bruteforce_points.json``).  No
``lidarcal`` import.  It follows ``tests/bruteforce_spread.py`` (PyConTurb's ``gen_turb`` scheme:
Kaimal spectra scaled to carry σ², ``iec3d`` coherence on y-z separations, one Cholesky factor per
frequency and component, Taylor's frozen-turbulence delay along the wind, 41 points per beam over
±3 σ of a 30-m Gaussian RWF, the cup first in the u factorisation and after the beam points in v,
an ideal DBS lidar, sliding reconstruction, hybrid p = 2/3, 0.1 m/s LOS noise, U = 8 m/s, no shear)
but draws the unit coefficients itself, so that the amplitude convention can be chosen:

* ``fixed`` — every point's coefficient has unit modulus and a uniform phase (``gen_turb``);
* ``gaussian`` — circular complex Gaussian coefficients, but the cup's u keeps unit modulus (its
  realised σ_u is TI·U): the point-level form of lidarcal's ``pinned_u``.

Both come from the same normal draws (``fixed`` keeps their phases): common random numbers, so the
ratio of the two spreads is measured far more precisely than either spread.

``python tests/bruteforce_points.py [n_periods]`` writes the stored file (about 0.15 s per period
and case on a quiet core).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data" / "bruteforce_points.json"
U, CONE, P_HYBRID, FWHM, NOISE, T, NT = 8.0, 28.0, 2.0 / 3.0, 30.0, 0.1, 600.0, 600
N_NODES = 41
L_C = 340.2 * np.array([1.0, 2.7 / 8.1, 0.66 / 8.1])
SIGMA_RATIOS = np.array([1.0, 0.8, 0.5])
#: (TI, height, direction) of the stored cases: where gen_turb's spread depends on the direction
CASES = [(0.2, 120.0, 0.0), (0.2, 120.0, 45.0)]


def case_name(ti: float, height: float, direction: float) -> str:
    return f"ti{ti:g}_h{height:g}_d{direction:g}"


class Case:
    """Points, Cholesky factors and Kaimal magnitudes of one (TI, height, direction)."""

    def __init__(self, ti: float, height: float, direction: float):
        phi = np.radians(CONE)
        az = np.radians([0.0, 90.0, 180.0, 270.0])
        nb = np.column_stack([np.sin(phi) * np.sin(az), np.sin(phi) * np.cos(az), np.full(4, np.cos(phi))])
        to = np.radians(direction + 180.0)
        down = np.array([np.sin(to), np.cos(to)])
        left = np.array([-down[1], down[0]])
        sr = FWHM / (2.0 * np.sqrt(2.0 * np.log(2.0)))
        s = np.linspace(-3.0 * sr, 3.0 * sr, N_NODES)
        w = np.exp(-0.5 * (s / sr) ** 2)
        self.w = w / w.sum()
        pts = (height / np.cos(phi) + s)[None, :, None] * nb[:, None, :]
        self.x = pts[..., :2] @ down
        self.proj = np.column_stack([nb[:, :2] @ down, nb[:, :2] @ left, nb[:, 2]])
        yz = np.round(np.column_stack([(pts[..., :2] @ left).ravel(), pts[..., 2].ravel()]), 6)
        uniq, inverse = np.unique(yz, axis=0, return_inverse=True)
        ref = np.array([0.0, round(height, 6)])
        is_ref = np.all(uniq == ref, axis=1)
        others = uniq[~is_ref]
        self.points, self.index, self.ref = [], [], []
        for k in range(3):  # u: the cup first; v and w: the beam points, then the cup
            first = k == 0
            p = np.concatenate([ref[None], others]) if first else np.concatenate([others, ref[None]])
            where = np.empty(uniq.shape[0], dtype=int)
            where[~is_ref] = np.arange(others.shape[0]) + (1 if first else 0)
            where[is_ref] = 0 if first else others.shape[0]
            self.points.append(p)
            self.index.append(where[inverse.ravel()].reshape(4, N_NODES))
            self.ref.append(0 if first else others.shape[0])
        self.f = np.arange(NT // 2 + 1) / T
        self.chol, self.mag = [], []
        for k in range(3):
            p = self.points[k]
            r = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
            a = 12.0 * np.sqrt((self.f[1:, None, None] / U) ** 2 + (0.12 / L_C[k]) ** 2)
            coh = np.exp(-a * r[None])
            coh[:, np.arange(len(p)), np.arange(len(p))] += 1e-10
            self.chol.append(np.linalg.cholesky(coh))
            tau = 42.0 * (8.1, 2.7, 0.66)[k] / U
            m = np.sqrt(4.0 * tau / (1.0 + 6.0 * tau * self.f) ** (5.0 / 3.0) / T / 2.0)
            m[0] = 0.0
            power = 2.0 * np.sum(m**2) - m[-1] ** 2
            self.mag.append(m * SIGMA_RATIOS[k] * ti * U / np.sqrt(NT / (NT - 1) * power))

    def periods(self, seed: tuple[int, ...]) -> dict[str, float]:
        """(L − R)/R of one period for each amplitude convention, from the same draws."""
        rng = np.random.default_rng(list(seed))
        draws = []
        for k in range(3):
            xi = (rng.standard_normal((NT // 2, len(self.points[k])))
                  + 1j * rng.standard_normal((NT // 2, len(self.points[k])))) * np.sqrt(0.5)
            xi[-1] = np.real(xi[-1]) * np.sqrt(2.0)  # the Nyquist coefficient of an even series is real
            draws.append(xi)
        noise = NOISE * rng.standard_normal(NT)
        out = {}
        for amplitude in ("gaussian", "fixed"):
            turb = []
            for k in range(3):
                xi = draws[k].copy()
                if amplitude == "fixed":  # gen_turb: every point's coefficient of unit modulus
                    xi /= np.abs(xi)
                elif k == 0:  # pinned_u: the cup's u alone of unit modulus (its phase kept)
                    xi[:, self.ref[0]] /= np.abs(xi[:, self.ref[0]])
                full = np.zeros((NT // 2 + 1, len(self.points[k])), dtype=complex)
                full[1:] = np.einsum("fij,fj->fi", self.chol[k], xi) * self.mag[k][1:, None]
                turb.append(full)
            delay = np.exp(-2j * np.pi * self.f[:, None, None] * (self.x / U)[None])
            los_f = sum(self.proj[None, :, k] * np.sum(turb[k][:, self.index[k]] * delay * self.w, axis=-1)
                        for k in range(3))
            los_b = np.fft.irfft(los_f, n=NT, axis=0) * NT + U * self.proj[:, 0]
            step = np.arange(NT)
            lidar = _dbs(los_b[step, step % 4] + noise)
            u = np.fft.irfft(turb[0][:, self.ref[0]], n=NT) * NT
            v = np.fft.irfft(turb[1][:, self.ref[1]], n=NT) * NT
            cup = float(np.mean(np.hypot(U + u, v)))
            out[amplitude] = (lidar - cup) / cup
        return out


def _dbs(los: np.ndarray) -> float:
    """Sliding DBS from step 3 on (the latest LOS of each beam), hybrid speed with p on the scalar average."""
    k = np.arange(3, los.size)[:, None]
    latest = los[k - ((k - np.arange(4)[None, :]) % 4)]
    s2 = 2.0 * np.sin(np.radians(CONE))
    north, east = (latest[:, 0] - latest[:, 2]) / s2, (latest[:, 1] - latest[:, 3]) / s2
    return P_HYBRID * float(np.mean(np.hypot(east, north))) + (1.0 - P_HYBRID) * float(
        np.hypot(east.mean(), north.mean()))


def run_case(case_id: int, periods) -> dict[str, np.ndarray]:
    """Per-period (L − R)/R of ``CASES[case_id]`` for both conventions (seed ``(case_id, period)``)."""
    case = Case(*CASES[case_id])
    rows = [case.periods((case_id, int(p), 7)) for p in periods]
    return {a: np.array([r[a] for r in rows]) for a in ("gaussian", "fixed")}


def main(n_periods: int) -> None:
    """Write ``n_periods`` periods of every case (a period depends only on its case and index: kept)."""
    result = json.loads(DATA.read_text()) if DATA.exists() else {"cases": {}}
    result["settings"] = {"wind_speed": U, "cone_angle": CONE, "hybrid_weight": P_HYBRID, "rwf_fwhm": FWHM,
                          "los_noise_std": NOISE, "duration": T, "nt": NT, "nodes_per_beam": N_NODES,
                          "reference": "first in the u factorisation, after the beam points in v"}
    for cid, case in enumerate(CASES):
        old = result["cases"].get(case_name(*case), {"gaussian": [], "fixed": [], "cpu_s": 0.0})
        t0 = time.process_time()
        new = run_case(cid, range(len(old["gaussian"]), n_periods))
        stored = {a: [round(float(r), 12) for r in np.concatenate([old[a], new[a]])]
                  for a in ("gaussian", "fixed")}
        cpu = round(old["cpu_s"] + time.process_time() - t0, 1)
        result["cases"][case_name(*case)] = {**stored, "cpu_s": cpu}
        for a in ("gaussian", "fixed"):
            r = np.array(stored[a])
            print(f"{case_name(*case)} {a}: std {100 * r.std(ddof=1):.4f} %  mean {100 * r.mean():+.4f} %  "
                  f"({r.size} periods)", flush=True)
        DATA.parent.mkdir(exist_ok=True)
        DATA.write_text(json.dumps(result, indent=0))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3000)
