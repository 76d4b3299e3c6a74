"""Turbulent LOS signals filtered by the continuous RWF, drawn from their cross-spectral matrix.

The four LOS values of a DBS lidar are linear functionals of the turbulent field,
``LOS_b = ∫ F(s) (a_b · V)(P_b(s)) ds`` with ``F`` the (CNR-weighted, Eq. 2) range-weighting
function and ``a_b`` the beam's unit vector in the wind frame.  The virtual lidar only needs
these four signals and the reference point's ``u`` and ``v``, so they are drawn directly from
their 6 x 6 cross-spectral matrix per frequency instead of sampling turbulence at points.

Signals are ordered ``(ref_u, ref_v, LOS_0, ..., LOS_3)``.  With PyConTurb's Fourier
convention (a point's coefficient is ``m_c(f, z) (L ξ) exp(-2πi f x / U)``, ``m_c`` the
Kaimal magnitude scaled to carry exactly ``σ_c²``, see :mod:`lidarcal.turbulence.kernels`)
and no cross-component coherence, the matrix ``C_ij(f) = E[c_i c_j*]`` is ::

    C_ij = Σ_c a_ic a_jc ∬ F_i(s) F_j(s') m_c(f, z_i(s)) m_c(f, z_j(s'))
                          coh_c(f, r_ij(s, s')) exp(-2πi f (x_i(s) - x_j(s')) / U) ds ds'

with the ``iec3d`` coherence ``coh_c = exp(-β_c(f) r)``, ``β_c = 12 sqrt((f/U)² + (0.12/L_c)²)``,
``r`` the cross-wind/vertical separation and ``x`` the along-wind position (Taylor's frozen
turbulence gives the phase).  Three kinds of entries:

* **Same beam.**  Two points of one beam are ``Δ = s' - s`` apart along a line, so
  ``r = q_b |Δ|`` (``q_b`` the beam's y-z length per metre) and the phase is ``exp(2πi f a_x Δ / U)``:
  the kernel depends on ``Δ`` only and has a cusp at ``Δ = 0``.  The double integral is the 1-D
  integral ``2 Re ∫_0^∞ A_c(f, Δ) exp(κ Δ) dΔ``, ``κ = -β_c q_b + 2πi f a_x / U``, of the
  autocorrelation ``A_c(Δ) = ∫ G_c(s) G_c(s + Δ) ds`` of ``G_c = F m_c`` on a fine uniform grid,
  integrated *exactly* against the exponential for piecewise-linear ``A`` (product
  integration: the cusp costs nothing).  ``A`` is frequency-independent (times ``m_c(f)²``)
  when the whole gate is above 60 m, where the Kaimal spectrum stops depending on ``z``;
  below, ``m_c(f, z)`` is factorised at low rank (``Σ_k U_k(f) V_k(z)``, by an SVD weighted by
  the RWF) and ``A`` assembled from ``rank²`` frequency-independent correlations.
* **Beam – beam and beam – reference.**  Smooth unless the two y-z lines nearly coincide (a
  beam pair when the wind blows along their axis or at 45° to it; a beam and the reference when
  the wind blows along the beam).  When they pass within :data:`R_COLLINEAR` of each other at
  the gate, the cusp is integrated exactly in the difference coordinate (``r² = α D² + r0²``,
  product integration in ``D``, trapezoid in the mean coordinate, the spectra's z-dependence by
  a low-rank factorisation); within :data:`R_FINE`, product Gauss quadrature with
  :data:`N_FINE` nodes per beam; otherwise :data:`N_CROSS` nodes (:data:`N_FAR` beyond
  :data:`R_FAR`), and zero at frequencies where even the closest node pair's coherence is below
  :data:`COHERENCE_FLOOR`.  Against a brute-force double sum (``tests/test_lidar_spectral.py``) every
  element is within 1.2 % of ``sqrt(C_ii C_jj)``.
* **Reference – reference.**  ``m_u(f, h)²``, ``m_v(f, h)²`` and 0 (``u ⊥ v``).

**Frequencies.**  The matrix is computed at every frequency up to :data:`N_DENSE` and at every
:data:`KNOT_STEP`-th beyond (60 of the 300 frequencies of a 10-minute period at 1 s), and
interpolated in between: once the frozen-turbulence phase between the gate centres is taken out,
every coherence is a smooth function of f (a cubic spline reproduces the full computation within
1.2e-4 of ``sqrt(C_ii C_jj)``), and so is every spectrum in log f.  The reference's spectra are
exact at every frequency.

The signals are drawn from the matrix by :mod:`lidarcal.lidar.synthesis`.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from lidarcal.lidar.geometry import beam_geometry, wind_axes
from lidarcal.lidar.product_integration import cusp_integral, side_integral
from lidarcal.lidar.quadrature import gauss_hermite_rwf, gauss_rwf_nodes
from lidarcal.turbulence.kernels import (
    COHERENCE_DECAY,
    L_C,
    LAMBDA_1,
    LENGTH_SCALE_FACTORS,
    spectral_magnitudes,
)

__all__ = ["N_CROSS", "continuous_rwf", "cross_spectral_matrix", "knot_indices"]

#: Gauss nodes per beam for the beam-beam and beam-reference entries.
N_CROSS = 8
#: Fine-grid spacing of the same-beam autocorrelation, as a fraction of the RWF's standard deviation.
GRID_PER_SIGMA = 1.0 / 6.0
#: Above this height (m) PyConTurb's Kaimal length scale stops depending on z (Lambda_1 / 0.7).
_Z_KAIMAL = 60.0


def _z_kaimal(length_scale: float) -> float:
    """Height (m) above which the Kaimal length scale ``min(0.7 z, Lambda_1)`` is constant (60 m at 42 m)."""
    return _Z_KAIMAL if length_scale == LAMBDA_1 else round(float(length_scale) / 0.7, 9)
#: The continuous RWF is cut off below this height (m): at 40 m the part of a 30-m Gaussian RWF
#: below it is 0.08 % of the weight.
_Z_GROUND = 1.0
#: The continuous RWF is tabulated to where it falls below its value at this many standard deviations of a
#: Gaussian (3.7e-6 of the peak; the weight beyond is 6e-7).
_TAIL_SIGMAS = 5.0


@functools.lru_cache(maxsize=32)
def continuous_rwf(offsets: tuple[float, ...], weights: tuple[float, ...],
                   profile: tuple[tuple[float, ...], tuple[float, ...]] | None = None):
    """Return the continuous RWF on a fine uniform grid, and its Gauss nodes for the cross entries.

    ``profile`` is a tabulated RWF ``(offsets, values)`` (m, any normalisation) in the frame of
    the quadrature nodes; without it the RWF is the Gaussian with the nodes' mean and variance
    (exact for the ideal lidar, whose nodes are Gauss-Hermite).

    Returns ``(s, w, nodes, node_weights)``: grid (m, uniform, spacing ``GRID_PER_SIGMA σ``),
    RWF on it normalised to ``sum(w) * ds = 1``, and :data:`N_CROSS` Gauss nodes and weights.
    """
    x, wq = np.asarray(offsets, float), np.asarray(weights, float)
    mu = float(np.sum(wq * x))
    sigma = float(np.sqrt(np.sum(wq * (x - mu) ** 2)))
    h = GRID_PER_SIGMA * sigma
    if profile is None:
        half = int(np.ceil(_TAIL_SIGMAS / GRID_PER_SIGMA))
        s = mu + h * np.arange(-half, half + 1)
        w = np.exp(-0.5 * ((s - mu) / sigma) ** 2)
        nodes, node_w = gauss_hermite_rwf(sigma * 2.0 * np.sqrt(2.0 * np.log(2.0)), N_CROSS)
        nodes = nodes + mu
    else:
        ps, pv = (np.asarray(a, float) for a in profile)
        pv = np.clip(pv, 0.0, None)
        keep = np.flatnonzero(pv > np.exp(-0.5 * _TAIL_SIGMAS**2) * pv.max())
        lo, hi = ps[keep[0]], ps[keep[-1]]
        s = np.arange(np.floor(lo / h), np.ceil(hi / h) + 1) * h
        w = np.interp(s, ps, pv, left=0.0, right=0.0)
        nodes, node_w = gauss_rwf_nodes(ps, pv, N_CROSS)
    w = w / (w.sum() * h)
    for a in (s, w, nodes, node_w):
        a.setflags(write=False)
    return s, w, nodes, node_w


def _beta(f: np.ndarray, wind_speed: float, l_c: float = L_C, decay: float = COHERENCE_DECAY) -> np.ndarray:
    """``β_c(f)`` of the ``iec3d`` coherence ``exp(-β r)``, shape ``(3, n_f)``."""
    lc = l_c * LENGTH_SCALE_FACTORS / LENGTH_SCALE_FACTORS[0]
    return float(decay) * np.sqrt((f[None, :] / wind_speed) ** 2 + (0.12 / lc[:, None]) ** 2)


def _phases(x: np.ndarray, wind_speed: float, f: np.ndarray) -> np.ndarray:
    """``exp(-2πi f x / U)``: shape ``x.shape + f.shape``."""
    return np.exp(np.multiply.outer(np.asarray(x, float) * (-2j * np.pi / wind_speed), f))


class _Magnitudes:
    """Kaimal magnitudes ``m_c(f, z)`` (``f`` without DC) at any z.

    Exact above 60 m (``Lambda_1 / 0.7``; one column), linear interpolation on a 2-m grid below
    (smooth in z).
    """

    def __init__(self, z_lo: float, z_hi: float, f_all: np.ndarray, wind_speed: float, sigma, nt: int,
                 z_weight=None, sel: np.ndarray | None = None, length_scale: float = LAMBDA_1):
        z_top = _z_kaimal(length_scale)
        self.uniform = z_lo >= z_top
        top = min(z_hi, z_top)
        self.z = np.array([z_top]) if self.uniform else np.linspace(
            z_lo, top, max(2, int(np.ceil((top - z_lo) / 2.0)) + 1))
        self.m_all = spectral_magnitudes(f_all, self.z, wind_speed, sigma, nt, length_scale)[:, 1:, :]
        # only the frequencies ``sel`` are used (the normalisation above and the low-rank factorisation
        # below see all of them, so a subset gives the same values as the full computation)
        self._sel = slice(None) if sel is None else np.asarray(sel)
        self.m = np.ascontiguousarray(self.m_all[:, self._sel])
        self._z_weight = z_weight

    @functools.cached_property
    def _svd(self):
        # joint low-rank factorisation m_c(f, z) = Σ_k U[c, f, k] V[k, z] (smooth in f and z), in the norm
        # weighted by where the RWF puts its weight (z_weight(z), default uniform); only needed below 60 m
        n_f = self.m_all.shape[1]
        w = np.ones(self.z.size) if self._z_weight is None else np.sqrt(np.maximum(self._z_weight(self.z),
                                                                                   1e-6))
        u, sv, vt = np.linalg.svd(self.m_all.reshape(3 * n_f, -1) * w, full_matrices=False)
        return u.reshape(3, n_f, -1)[:, self._sel], sv, vt / w

    def factors(self, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """``U (3, nf, r)`` and ``V (r, nz)`` keeping singular values above ``tol`` times the largest."""
        u, sv, vt = self._svd
        r = int(np.count_nonzero(sv > tol * sv[0]))
        return u[..., :r] * sv[:r], vt[:r]

    def weights(self, z: np.ndarray) -> np.ndarray:
        """Interpolation matrix ``(nz, len(z))`` (clamped at both ends; above 60 m the last column)."""
        z = np.atleast_1d(np.asarray(z, float))
        out = np.zeros((self.z.size, z.size))
        if self.z.size == 1:
            out[0] = 1.0
            return out
        pos = np.interp(z, self.z, np.arange(self.z.size))
        i0 = np.minimum(np.floor(pos).astype(int), self.z.size - 2)
        t = pos - i0
        cols = np.arange(z.size)
        out[i0, cols] = 1.0 - t
        out[i0 + 1, cols] += t
        return out

    def __call__(self, z: np.ndarray) -> np.ndarray:
        """``m_c(f, z)``: shape ``(3, nf, len(z))``."""
        return self.m @ self.weights(z)


@functools.lru_cache(maxsize=256)
def _line_nodes(offsets, weights, profile, n_cut: int, n_nodes: int):
    """Gauss nodes and weights of the continuous RWF with its first ``n_cut`` grid points cut off."""
    s, w, nodes, node_w = continuous_rwf(offsets, weights, profile)
    if n_cut == 0 and n_nodes == nodes.size:
        return nodes, node_w
    if n_cut == 0 and profile is None:
        sd = np.sqrt(np.sum(w * s**2) / np.sum(w) - (np.sum(w * s) / np.sum(w)) ** 2)
        x, wx = gauss_hermite_rwf(sd * 2.0 * np.sqrt(2.0 * np.log(2.0)), n_nodes)
        return x + np.sum(w * s) / np.sum(w), wx
    return gauss_rwf_nodes(s[n_cut:], w[n_cut:], n_nodes)


def _autocorrelation(F: np.ndarray, h: float, mags: _Magnitudes, z_line: np.ndarray) -> np.ndarray:
    """Autocorrelation ``A_c(f, Δ_j) = ∫ G(s) G(s + Δ_j) ds`` of ``G = F m_c(f, z(s))``.

    Shape ``(N, 3, nf)`` (lag first), or ``(N, 1, 1)`` (times ``m_c(f)²``) when the spectrum does not
    depend on z.

    Below 60 m the low-rank factorisation ``m_c(f, z) = Σ_k U_ck(f) V_k(z)`` leaves only
    ``rank²`` frequency-independent correlations.
    """
    if mags.uniform:
        return (np.correlate(F, F, mode="full")[F.size - 1:] * h)[:, None, None]
    Uf, Vz = mags.factors(1e-6)
    G = F * (Vz @ mags.weights(z_line))  # (r, N)
    r = G.shape[0]
    corr = np.empty((r, r, F.size))
    for a in range(r):
        for b in range(r):
            corr[a, b] = np.correlate(G[b], G[a], mode="full")[F.size - 1:]  # Σ_i G_a(i) G_b(i + j)
    UU = (Uf[:, :, :, None] * Uf[:, :, None, :]).reshape(3 * Uf.shape[1], r * r)
    return (corr.reshape(r * r, -1).T @ UU.T).reshape(F.size, 3, Uf.shape[1]) * h


def _collinear_pair(F, s, h, R, up, qa, qb, pa, pb, eps, beta, k, mags: _Magnitudes, U, f, proj2):
    """Cross-spectrum of a beam pair whose y-z lines (nearly) coincide.

    ``r² = α D² + (ε ρ̄)²`` in ``D = ρ - ρ'``, ``ρ̄ = (ρ + ρ')/2`` (``ρ`` the distance along the y-z
    projection); the cusp in ``D`` is integrated exactly, ``ρ̄`` by the trapezoid rule, ``ε ρ̄``
    taken constant within slabs of ``ρ̄``.
    """
    alpha = 1.0 - eps**2 / 4.0
    hr = h * min(qa, qb)
    rho_lo, rho_hi = (R + s[0]) * min(qa, qb), (R + s[-1]) * max(qa, qb)
    # ρ̄ carries a smooth envelope times exp(-i k ρ̄ (pa - pb)): the trapezoid rule on twice the grid
    # spacing is spectrally accurate while k |pa - pb| 2 hr < π/2
    step = 2 if 2.0 * float(k.max()) * abs(pa - pb) * 2.0 * hr < np.pi / 2 else 1
    rb = rho_lo + step * hr * np.arange(int(np.ceil((rho_hi - rho_lo) / (step * hr))) + 1)
    j0 = int(np.ceil((rho_hi - rho_lo) / hr))
    D = (np.arange(2 * j0 + 1) - j0) * hr
    Fa = np.interp((rb[None, :] + D[:, None] / 2) / qa - R, s, F, left=0.0, right=0.0)
    Fb = np.interp((rb[None, :] - D[:, None] / 2) / qb - R, s, F, left=0.0, right=0.0)
    Phi = Fa * Fb * (step * hr / (qa * qb))
    big = Phi > 1e-7 * Phi.max()
    rows, cols = np.flatnonzero(big.any(axis=1)), np.flatnonzero(big.any(axis=0))
    jlo, jhi = min(rows[0], j0), max(rows[-1], j0)
    Phi, D, rb = Phi[jlo:jhi + 1, cols[0]:cols[-1] + 1], D[jlo:jhi + 1], rb[cols[0]:cols[-1] + 1]
    j0 -= jlo
    n_f = f.size
    E = _phases(rb * (pa - pb), U, f)  # (L, nf)
    E32 = np.concatenate([E.real, E.imag], axis=1).astype(np.float32)  # (L, 2 nf)
    beta32 = beta.astype(np.float32)
    if mags.uniform:
        Va = Vb = np.ones((1, D.size, rb.size))
    else:
        Uf, Vz = mags.factors(_COLLINEAR_RANK_TOL)
        za = np.clip((rb[None, :] + D[:, None] / 2) * up / qa, mags.z[0], mags.z[-1])
        zb = np.clip((rb[None, :] - D[:, None] / 2) * up / qb, mags.z[0], mags.z[-1])
        Va = np.stack([np.interp(za, mags.z, v) for v in Vz])  # (r, J, L)
        Vb = np.stack([np.interp(zb, mags.z, v) for v in Vz])
    rank = Va.shape[0]
    # slabs of equal weight in ρ̄: midpoint error of exp(-β r0) over a slab ~ (β ε width)² / 24 < 2 % (at the
    # vertex; < 1 % in the cross-spectra against the brute force),
    # counting only β where the coherence at the weighted centre, exp(-β ε ρ_centre), is not negligible
    mass = np.cumsum(Phi.sum(0))
    mass /= mass[-1]
    rho_c = float(np.interp(0.5, mass, rb))
    width = float(np.interp(0.995, mass, rb) - np.interp(0.005, mass, rb))
    beta_eff = min(float(beta.max()), 8.0 / max(eps * rho_c, 1e-12))
    n_slab = int(np.clip(np.ceil(beta_eff * eps * width / _SLAB_PRODUCT), 1, 16))
    edges = np.unique(np.concatenate([[0, rb.size], np.searchsorted(mass, np.arange(1, n_slab) / n_slab)]))
    P_sum = 0.0  # the cusp integral is linear in P and its kernel is the same for every slab
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if b <= a:
            continue
        Eab = E32[a:b]  # (L_slab, 2 nf): cos | sin
        VV = (Va[:, None, :, a:b] * Vb[None, :, :, a:b]).reshape(rank**2, D.size, b - a)
        weights = (Phi[None, :, a:b] * VV).astype(np.float32)
        # single precision (1e-7 relative on sums of positive weights times unit phasors)
        Y = np.matmul(weights, Eab).astype(np.float64)  # (r², J, 2 nf)
        P = np.empty((D.size, 3 if not mags.uniform else 1, n_f), dtype=complex)  # lag first
        if mags.uniform:
            P.real[:, 0] = Y[0, :, :n_f]
            P.imag[:, 0] = Y[0, :, n_f:]
        else:
            UU = (Uf[:, :, :, None] * Uf[:, :, None, :]).reshape(3, n_f, rank**2).transpose(1, 0, 2)
            Yt = Y.transpose(2, 0, 1)  # (2 nf, r², J)
            P.real = np.matmul(UU, Yt[:n_f]).transpose(2, 1, 0)  # (nf, 3, J) -> (J, 3, nf)
            P.imag = np.matmul(UU, Yt[n_f:]).transpose(2, 1, 0)
        if eps > 0:
            r0 = eps * float(np.sum(rb[a:b] * Phi[:, a:b].sum(0)) / max(Phi[:, a:b].sum(), 1e-300))
            excess = (np.sqrt(alpha * D**2 + r0**2) - np.sqrt(alpha) * np.abs(D)).astype(np.float32)
            damp = np.exp(-beta32[None] * excess[:, None, None]).astype(np.float64)  # (J, 3, nf)
            if P.shape[1] == 1:
                P = P * damp
            else:
                P *= damp
        P_sum = P_sum + P
    total = cusp_integral(P_sum, j0, hr, beta * np.sqrt(alpha), -k * (pa + pb) / 2.0)
    if mags.uniform:
        total = total * mags.m[:, :, 0] ** 2
    return np.einsum("c,cf->f", proj2, total)


#: Largest β ε Δρ̄ across one slab of the near-collinear pair integral.
_SLAB_PRODUCT = 0.7
#: Singular-value tolerance of the spectra's z-dependence in the near-collinear pairs (r² products per slab).
_COLLINEAR_RANK_TOL = 2e-3
#: Gauss nodes per beam for pairs closer than :data:`R_FINE`.
N_FINE = 16
#: Beam pairs whose y-z lines pass closer than this (m, at the gate) get the cusp-exact treatment.
R_COLLINEAR = 4.0
#: ... and closer than this twice the Gauss nodes.
R_FINE = 10.0
#: Pairs at least this far apart (m, at the gate) get :data:`N_FAR` nodes per beam: the coherence is smooth
#: over the gate there (against 16 nodes, 6 are within 2e-3 of sqrt(C_ii C_jj) beyond 25 m).
R_FAR = 25.0
N_FAR = 6


#: Every frequency index up to this one is computed; beyond it only every :data:`KNOT_STEP`-th (and the
#: Nyquist frequency), the rest interpolated (:func:`cross_spectral_matrix`).
N_DENSE = 24
KNOT_STEP = 8


def knot_indices(n_f: int) -> np.ndarray:
    """Positions (0-based, into the ``n_f`` positive frequencies) at which the matrix is computed."""
    if n_f <= N_DENSE + 2 * KNOT_STEP:
        return np.arange(n_f)
    return np.unique(np.r_[np.arange(N_DENSE), np.arange(N_DENSE, n_f, KNOT_STEP), n_f - 1])


@functools.lru_cache(maxsize=16)
def _interpolation_weights(n_f: int, knots: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Cubic-spline weights ``(n_f, n_knots)`` from the knots to every frequency: in f, and in log f."""
    n = np.arange(1.0, n_f + 1.0)
    nk = n[list(knots)]
    eye = np.eye(len(knots))
    return CubicSpline(nk, eye)(n), CubicSpline(np.log(nk), eye)(np.log(n))


def cross_spectral_matrix(model, height: float, wind_speed: float, wind_from_direction: float,
                          sigma: np.ndarray, cnr_gradient: float, duration: float,
                          n_cross: int = N_CROSS, interpolate: bool = True) -> np.ndarray:
    """Return the 6 x 6 cross-spectral matrix ``C (n_f, 6, 6)`` of ``(ref_u, ref_v, LOS_0..LOS_3)``.

    ``n_f = nt // 2`` positive frequencies ``n / duration`` (``nt = duration / beam_period``),
    in PyConTurb's units: ``C_ii`` is ``|m|²`` of a single signal, so ``2 Σ_f C_ii`` is its variance
    (minus half the Nyquist term).  ``sigma`` is ``(σ_u, σ_v, σ_w)`` (m s-1).

    With ``interpolate`` (the default) the matrix is computed at :func:`knot_indices` only (60 of
    300 frequencies for a 10-minute period at 1 s) and interpolated between them: the coherences
    ``C_ij / sqrt(C_ii C_jj)``, with the frozen-turbulence phase between the gate centres taken out,
    by a cubic spline in f, and the spectra ``sqrt(C_ii)`` by a cubic spline in log f.  Both are
    smooth there (measured over random conditions: within 1.2e-4 of ``sqrt(C_ii C_jj)`` of the
    full computation; ``tests/test_lidar_spectral.py`` checks the result against the brute force at
    interpolated frequencies).  The reference's own spectra are set exactly, so its realised
    variance stays the period's.
    """
    U = float(wind_speed)
    nt = int(round(duration / model.beam_period))
    n_f = nt // 2
    sel = knot_indices(n_f) if interpolate else np.arange(n_f)
    Ck, x_centre, m_ref = _matrix_at(model, height, U, wind_from_direction, sigma, cnr_gradient, duration,
                                     n_cross, sel)
    if sel.size == n_f:
        return Ck
    f = np.arange(1, n_f + 1) / duration
    w_lin, w_log = _interpolation_weights(n_f, tuple(sel.tolist()))
    d = np.sqrt(np.clip(np.real(np.einsum("fii->fi", Ck)), 0.0, None))  # (nk, 6)
    ph = _phases(x_centre, U, f[sel]).T  # (nk, 6): the gate centres' frozen-turbulence phases
    inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    G = Ck * (inv * np.conj(ph))[:, :, None] * (inv * ph)[:, None, :]
    G = (w_lin @ G.reshape(sel.size, 36)).reshape(n_f, 6, 6)
    d_full = np.exp(w_log @ np.log(np.where(d > 0, d, 1.0))) * (d > 0).all(axis=0)
    d_full[:, :2] = m_ref[:2].T  # the reference's spectra exactly
    a = d_full * _phases(x_centre, U, f).T
    return G * a[:, :, None] * np.conj(a)[:, None, :]


@dataclass
class _Gate:
    """One height's range gate, as every block of :func:`_matrix_at` sees it.

    The CNR-weighted RWF ``F`` on the fine grid ``s`` (spacing ``h``, cut off below the ground),
    the beams' unit vectors in the wind frame (``along``, ``across``, ``up``; ``proj`` the
    components ``a_bc``, ``q`` each beam's y-z length per metre), the coherence decay ``beta``
    and wavenumbers ``k`` at the frequencies ``f``, the Kaimal magnitudes ``mags`` and the
    reference's ``m_ref``.
    """

    height: float
    U: float
    f: np.ndarray
    s: np.ndarray
    h: float
    F: np.ndarray
    R: float
    up: float
    along: np.ndarray
    across: np.ndarray
    proj: np.ndarray
    q: np.ndarray
    beta: np.ndarray
    beta32: np.ndarray
    k: np.ndarray
    mags: _Magnitudes
    m_ref: np.ndarray
    rwf_key: tuple
    n_cut: int
    scale: float
    n_cross: int
    _nodes: dict = field(default_factory=dict)

    def nodes(self, n: int) -> tuple:
        """Return ``n`` Gauss nodes of the weighted RWF: y and z positions, weights x magnitudes x phases."""
        if n not in self._nodes:
            nodes, node_w = _line_nodes(*self.rwf_key, self.n_cut, n)
            wn = node_w * 10.0 ** (self.scale * nodes)
            wn /= wn.sum()
            rn = self.R + nodes
            ph = _phases(rn[None, :] * self.along[:, None], self.U, self.f)  # (4, n, nf)
            Ub = wn * self.mags(rn * self.up)[None] * np.swapaxes(ph, 1, 2)[:, None]  # (4, 3, nf, n)
            self._nodes[n] = (rn[None, :] * self.across[:, None], rn * self.up, Ub)
        return self._nodes[n]

    def rule(self, r0: float) -> int:
        """Gauss nodes per beam for two signals ``r0`` apart (m) at the gate."""
        return N_FINE if r0 < R_FINE else self.n_cross if r0 < R_FAR else min(self.n_cross, N_FAR)


def _coherence(model) -> tuple[float, float]:
    """Return ``(l_c, a)`` of the model's IEC coherence (PyConTurb's defaults without the fields)."""
    return (float(getattr(model, "coherence_length", L_C)),
            float(getattr(model, "coherence_decay", COHERENCE_DECAY)))


def _length_scale(model) -> float:
    """Return the model's Kaimal Lambda_1 (m)."""
    return float(getattr(model, "turbulence_length_scale", LAMBDA_1))


def _gate(model, height: float, U: float, wind_from_direction: float, sigma: np.ndarray, cnr_gradient: float,
          f_all: np.ndarray, nt: int, n_cross: int, sel: np.ndarray) -> _Gate:
    """Set up :class:`_Gate` at the positive frequencies ``sel`` (0-based) of ``f_all``."""
    f = f_all[1:][sel]
    key = (model.rwf_offsets, model.rwf_weights, getattr(model, "rwf_profile", None))
    s, w0, _, _ = continuous_rwf(*key)
    h = s[1] - s[0]
    units, _, phi_nom = beam_geometry(model)
    up = units[0, 2]
    R = height / np.cos(phi_nom) + model.zero_distance_offset
    n_cut = int(np.count_nonzero((R + s) * up < _Z_GROUND))  # a tail reaching below the ground is cut off
    s, w0 = s[n_cut:], w0[n_cut:]
    scale = model.cnr_weighting_scale * cnr_gradient / 20.0
    F = w0 * 10.0 ** (scale * s)
    F /= F.sum() * h

    down, cross = wind_axes(wind_from_direction)
    along, across = units[:, :2] @ down, units[:, :2] @ cross  # (4,)
    proj = np.stack([along, across, units[:, 2]], axis=-1)  # (4, 3): a_bc
    q = np.hypot(across, up)  # (4,) y-z length of the beam per metre
    beta = _beta(f, U, *_coherence(model))  # (3, nf)
    z_line = (R + s) * up
    # spectra vary with z below 60 m: tabulated where the RWF carries weight (> 1e-3 of its peak,
    # clamped beyond: the tails hold < 3e-4 of the weight)
    z_w = z_line[F > 1e-3 * F.max()]
    mags = _Magnitudes(float(min(z_w.min(), height)), float(max(z_w.max(), height)), f_all, U, sigma, nt,
                       z_weight=lambda z: np.interp(z, z_line, F) / F.max(), sel=sel,
                       length_scale=_length_scale(model))
    return _Gate(height=height, U=U, f=f, s=s, h=h, F=F, R=R, up=up, along=along, across=across, proj=proj,
                 q=q, beta=beta, beta32=beta.astype(np.float32), k=2.0 * np.pi * f / U, mags=mags,
                 m_ref=mags(np.array([height]))[..., 0], rwf_key=key, n_cut=n_cut, scale=scale,
                 n_cross=n_cross)


def _matrix_at(model, height: float, U: float, wind_from_direction: float, sigma: np.ndarray,
               cnr_gradient: float, duration: float, n_cross: int, sel: np.ndarray):
    """Compute the matrix at the positive frequencies ``sel`` (0-based).

    Also returns the signals' gate-centre along-wind positions (m) and the reference's magnitudes
    ``m_c(f, h)`` (3, n_f) at every frequency.
    """
    nt = int(round(duration / model.beam_period))
    df = 1.0 / duration
    n_f_all = nt // 2
    f_all = np.arange(n_f_all + 1) * df
    g = _gate(model, height, U, wind_from_direction, sigma, cnr_gradient, f_all, nt, n_cross, sel)
    C = np.zeros((g.f.size, 6, 6), dtype=complex)
    C[:, 0, 0] = g.m_ref[0] ** 2  # reference - reference (u ⊥ v)
    C[:, 1, 1] = g.m_ref[1] ** 2
    _same_beam(g, C)
    _beam_reference(g, C)
    _beam_beam(g, C)
    if g.mags.uniform:  # the tabulated column (60 m) is the spectrum at every height above 60 m
        m_ref_all = g.mags.m_all[:, :, 0]
    else:
        m_ref_all = spectral_magnitudes(f_all, np.array([float(height)]), U, sigma, nt,
                                        _length_scale(model))[:, 1:, 0]  # (3, n_f)
    return C, np.concatenate([[0.0, 0.0], g.R * g.along]), m_ref_all


def _same_beam(g: _Gate, C: np.ndarray) -> None:
    """Fill the same-beam entries: ``2 Re ∫_0^∞ A(Δ) exp(κΔ) dΔ``, ``A`` the autocorrelation of ``F m``."""
    F, h, q, along, beta, k, mags, m_ref = g.F, g.h, g.q, g.along, g.beta, g.k, g.mags, g.m_ref
    A = _autocorrelation(F, h, mags, (g.R + g.s) * g.up)
    peak = np.max(np.abs(A), axis=(1, 2))
    A = A[:int(np.flatnonzero(peak > 1e-10 * peak.max())[-1]) + 2]
    # A is real, so the real part depends on q and |along| only: opposite beams share one integral
    qs, als = q.tolist(), np.abs(along).tolist()
    first = [next(r for r in range(b + 1) if abs(qs[r] - qs[b]) <= 1e-12 * qs[b]
                  and abs(als[r] - als[b]) <= 1e-12) for b in range(4)]
    reps = sorted(set(first))
    kap = (-beta[None] * q[reps, None, None] + 1j * k[None, None, :] * along[reps, None, None]) * h
    same = 2.0 * np.real(side_integral(A, h, kap))  # (len(reps), 3, nf)
    if mags.uniform:
        same = same * (m_ref**2)[None]
    for b in range(4):
        C[:, 2 + b, 2 + b] = np.einsum("c,cf->f", g.proj[b] ** 2, same[reps.index(first[b])])


def _beam_reference(g: _Gate, C: np.ndarray) -> None:
    """Fill the beam - reference entries (and their conjugates).

    ``r² = q² (s - s0)² + d²``, ``d`` the reference's distance from the beam's y-z line: the cusp
    at ``s0`` is integrated exactly for beams within :data:`R_COLLINEAR`, the rest by Gauss quadrature.
    """
    F, s, h, R, up, q, along, across, proj = g.F, g.s, g.h, g.R, g.up, g.q, g.along, g.across, g.proj
    beta, beta32, k, mags, m_ref, height, n_f = g.beta, g.beta32, g.k, g.mags, g.m_ref, g.height, g.f.size
    s0 = height * up / q**2 - R  # (4,)
    d = height * np.abs(across) / q
    near = np.flatnonzero(d < R_COLLINEAR)
    if near.size:  # cusp at s0: exact in D = s - s0 on one grid D_j = (j - j0) h for these beams
        j0 = int(np.ceil(np.max(s0[near] - s[0]) / h))
        D = (np.arange(j0 + int(np.ceil(np.max(s[-1] - s0[near]) / h)) + 1) - j0) * h  # (J,)
        sd = s0[near, None] + D  # (B, J)
        Fd = np.interp(sd, s, F, left=0.0, right=0.0)
        md = (mags.m[:2] @ mags.weights(((R + sd) * up).ravel())).reshape(2, n_f, near.size, D.size)
        md = md.transpose(3, 2, 0, 1)  # (J, B, 2, nf): lag first
        excess = (np.hypot(q[near, None] * D, d[near, None]) - q[near, None] * np.abs(D)).T  # r - q|D| >= 0
        P = Fd.T[:, :, None, None] * md * np.exp(-beta32[None, None, :2]
                                                  * excess[:, :, None, None].astype(np.float32))
        val = cusp_integral(P, j0, h, beta[None, :2] * q[near, None, None],
                             (k[None, :] * along[near, None])[:, None])  # (B, 2, nf)
        val *= np.exp(1j * k[None, :] * (along[near] * (R + s0[near]))[:, None])[:, None]
        for i, b in enumerate(near):
            C[:, :2, 2 + b] = (val[i] * m_ref[:2] * proj[b, :2, None]).T
    for b in np.flatnonzero(d >= R_COLLINEAR):  # smooth kernel: Gauss quadrature
        yw, zw, Ub = g.nodes(g.rule(d[b]))
        r = np.hypot(yw[b], zw - height)
        m = _coherent_frequencies(beta, float(r.min()))
        E = np.exp(-beta32[:2, :m, None] * r.astype(np.float32))  # (2, m, n)
        C[:m, :2, 2 + b] = (np.sum(np.conj(Ub[b, :2, :m]) * E, axis=-1) * m_ref[:2, :m]
                            * proj[b, :2, None]).T
    C[:, 2:, :2] = np.conj(np.swapaxes(C[:, :2, 2:], 1, 2))


def _beam_beam(g: _Gate, C: np.ndarray) -> None:
    """Fill the beam - beam entries: near-collinear pairs cusp-exact, the others by Gauss quadrature."""
    q, across, up, proj, beta, beta32 = g.q, g.across, g.up, g.proj, g.beta, g.beta32
    rho_c = g.R * q  # y-z distance of each gate centre from the lidar
    groups: dict[int, list] = {}
    for b in range(4):
        for b2 in range(b + 1, 4):
            cos_g = np.clip((across[b] * across[b2] + up**2) / (q[b] * q[b2]), -1.0, 1.0)
            eps = 2.0 * np.sin(0.5 * np.arccos(cos_g))
            r0 = eps * 0.5 * (rho_c[b] + rho_c[b2])
            if r0 < R_COLLINEAR:
                total = _collinear_pair(g.F, g.s, g.h, g.R, up, q[b], q[b2], g.along[b] / q[b],
                                        g.along[b2] / q[b2], eps, beta, g.k, g.mags, g.U, g.f,
                                        proj[b] * proj[b2])
                C[:, 2 + b, 2 + b2] = total
                C[:, 2 + b2, 2 + b] = np.conj(total)
            else:
                groups.setdefault(g.rule(r0), []).append((b, b2))
    for n, pairs in groups.items():
        yw, zw, Ub = g.nodes(n)
        for ia, ib in pairs:
            r = np.hypot(yw[ia][:, None] - yw[ib][None, :], zw[:, None] - zw[None, :])  # (n, n)
            m = _coherent_frequencies(beta, float(r.min()))
            # coherence in single precision (1e-7 relative; the exponential is 10x faster in float32)
            E = np.exp(-beta32[:, :m, None, None] * r.astype(np.float32))  # (3, m, n, n)
            vb = np.conj(Ub[ib, :, :m])
            t = np.matmul(E, np.stack([vb.real, vb.imag], axis=-1).astype(np.float32)).astype(np.float64)
            t = t[..., 0] + 1j * t[..., 1]
            total = proj[ia] * proj[ib] @ np.sum(Ub[ia, :, :m] * t, axis=-1)  # (m,)
            C[:m, 2 + ia, 2 + ib] = total
            C[:m, 2 + ib, 2 + ia] = np.conj(total)


#: Coherence below which a cross-spectral entry is set to zero (far below the 2 % accuracy of the
#: matrix and the float32 resolution of the coherence itself, 1e-7).
COHERENCE_FLOOR = 1e-7


def _coherent_frequencies(beta: np.ndarray, r_min: float) -> int:
    """Count the leading frequencies at which ``exp(-β_c(f) r_min)`` exceeds :data:`COHERENCE_FLOOR`.

    ``β_c(f)`` grows with ``f`` for every component, so beyond that count every node pair of two
    signals at least ``r_min`` apart is incoherent and their cross-spectrum is zero to that floor.
    """
    live = np.exp(-beta.min(axis=0) * r_min) > COHERENCE_FLOOR  # (nf,), monotone: True then False
    return int(np.count_nonzero(live))
