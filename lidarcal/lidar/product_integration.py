"""Product integration: exact integrals of piecewise-linear functions against exponentials.

The cross-spectral matrix (:mod:`lidarcal.lidar.spectral`) integrates correlations that are
tabulated on a uniform grid against ``exp(z t)`` kernels with a cusp (``exp(-mu |D|)``).  Taking
the tabulated function as piecewise linear and the exponential exactly, interval by interval,
costs nothing at the cusp and stays exact however fast the kernel decays or oscillates across an
interval: :func:`side_integral` over ``[0, ∞)``, :func:`cusp_integral` over the whole line.
Pure numpy.
"""

from __future__ import annotations

import numpy as np

__all__ = ["side_integral", "cusp_integral"]


def _phi(z: np.ndarray, ez: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``∫_0^1 (1 - t) e^(zt) dt`` and ``∫_0^1 t e^(zt) dt`` for complex ``z``, given ``ez = e^z``.

    The closed forms lose ``~1e-16 / |z|²`` to cancellation, so ``|z| < 1e-3`` takes the series.
    """
    z2 = z * z
    with np.errstate(divide="ignore", invalid="ignore"):
        phi0 = (ez - 1.0 - z) / z2
        phi1 = (z * ez - ez + 1.0) / z2
    small = np.abs(z) < 1e-3
    if small.any():
        zs = z[small]
        phi0[small] = 0.5 + zs / 6.0 + zs * zs / 24.0
        phi1[small] = 0.5 + zs / 3.0 + zs * zs / 8.0
    return phi0, phi1


def side_integral(P: np.ndarray, h: float, z: np.ndarray) -> np.ndarray:
    """``∫_0^∞ P(t) e^(z t / h) dt``, ``P`` piecewise linear on ``t_j = j h`` (FIRST axis); exact kernel.

    ``z`` (complex, ``Re z <= 0``) broadcasts against ``P[0]``.  Interval ``j`` contributes
    ``h e^(j z) (P_j φ0(z) + P_(j+1) φ1(z))``: a polynomial in ``e^z``, evaluated by Horner's rule
    (the lag axis first, so that every step reads one contiguous slice).
    """
    z = np.asarray(z, dtype=complex)
    rho = np.exp(z)
    phi0, phi1 = _phi(z, rho)
    Pt = np.asarray(P)
    n = Pt.shape[0]
    # Σ_j ρ^j (P_j φ0 + P_(j+1) φ1) = φ0 Σ_j ρ^j P_j + φ1 Σ_j ρ^j P_(j+1), j = 0 .. n-2
    tail = np.zeros(np.broadcast_shapes(rho.shape, Pt.shape[1:]), dtype=complex)
    scalar = Pt.ndim == 1 or all(d == 1 for d in Pt.shape[1:])
    coef = Pt.reshape(n).tolist() if scalar else Pt  # per-lag scalars: Python numbers add fastest
    for j in range(n - 1, 0, -1):  # tail = Σ_(j>=1) ρ^(j-1) P_j
        tail *= rho
        tail += coef[j]
    head = Pt[0] + rho * (tail - Pt[n - 1] * rho ** (n - 2)) if n > 1 else Pt[0]  # Σ_(j<=n-2) ρ^j P_j
    return h * (phi0 * head + phi1 * tail)


def cusp_integral(P: np.ndarray, j0: int, h: float, mu: np.ndarray, kap: np.ndarray) -> np.ndarray:
    """``∫ P(D) exp(-mu |D| + i kap D) dD``, ``P`` piecewise linear on ``D_j = (j - j0) h`` (first axis)."""
    pos = side_integral(P[j0:], h, (-mu + 1j * kap) * h)
    neg = side_integral(P[j0::-1], h, (-mu - 1j * kap) * h)
    return pos + neg
