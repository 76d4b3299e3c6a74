"""Fourier coefficients and time series drawn from a cross-spectral matrix (PyConTurb's scheme).

Synthesis (:func:`draw_coefficients`) follows PyConTurb: the matrix ``C`` (for the virtual
lidar, the 6 x 6 matrix of :func:`lidarcal.lidar.spectral.cross_spectral_matrix`) is normalised
to a coherence matrix ``Γ = D⁻¹ C D⁻¹`` (``D = sqrt(diag C)``), factorised ``Γ = L L^H`` (batched
Cholesky over frequencies), and ``c = D L ξ``.  The reference comes first in the
factorisation, so its u coefficients are ``m_u ξ_0``.  Which ``ξ`` have a fixed modulus is the
convention of ``LidarModel.reference_turbulence`` (``docs/validation.md``), declared here
(:data:`REFERENCE_TURBULENCE`) and passed to :func:`draw_coefficients` as it is:

* ``"pinned_u"`` (the model's default): ``ξ_0`` unit-modulus with uniform phase,
  every other ``ξ`` circular complex Gaussian.  The reference's realised 10-minute σ_u is the
  period's ``TI U`` exactly (the measured value, as for the first point of a ``gen_turb`` box),
  and nothing else is pinned: in PyConTurb only the *points'* amplitudes are fixed, and a LOS
  value integrates a continuum of points through the RWF, so its Fourier coefficients (given
  the reference's) are Gaussian; the reference's v (and the cup's ``σ_v²/2U``) scatters from
  period to period as in the atmosphere.
* ``"pinned_uvw"``: every ``ξ`` unit-modulus (the engine before
  ``reference_turbulence`` existed; kept bit for bit so that earlier results reproduce).  It
  pins the reference's σ_v too and gives the six signals fixed amplitudes, which removes
  15-25 % of the spread of lidar − reference.
* ``"free"``: every ``ξ`` circular complex Gaussian (a Gaussian process; the
  reference's realised σ_u scatters ~10 %).

* ``"inferred_level"``: the field's turbulence level is *unknown*, and
  the reference's realised σ_u is what was measured: all six signals are drawn as ``"free"``
  and then scaled by the one factor that makes the reference's realised σ_u equal ``TI U``.
  Given one 10-minute σ_u (and no prior on the level, the scale-invariant 1/σ), this is the
  posterior of the field: its level is ``TI U / sqrt(V)`` with ``V`` the realised variance
  of a unit-level reference, so it scatters about the measured value as a 10-minute σ_u
  scatters about the atmosphere's (±10 %).

``"pinned_u"`` and ``"inferred_level"`` draw the same numbers as ``"free"``.  Records written
before ``reference_turbulence`` existed say ``turbulence_amplitudes: "deterministic"`` or
``"rayleigh"`` (``"pinned_uvw"``, ``"free"``): :meth:`lidarcal.lidar.LidarModel.from_dict` maps
them when it reads one, and nothing else knows those words.
"""

from __future__ import annotations

import numpy as np

__all__ = ["REFERENCE_TURBULENCE", "draw_coefficients", "synthesise"]

#: Conventions of ``LidarModel.reference_turbulence``: which ``ξ`` :func:`draw_coefficients` pins.
REFERENCE_TURBULENCE = ("pinned_u", "pinned_uvw", "free", "inferred_level")


def draw_coefficients(C: np.ndarray, rng: np.random.Generator, reference_turbulence: str,
                      nt: int | None = None, jitter: float = 1e-10) -> np.ndarray:
    """Fourier coefficients ``(n_signals, n_f)`` with cross-spectra ``C`` (PyConTurb's scheme).

    ``C`` has shape ``(n_f, n, n)`` (positive frequencies).  ``c = D L ξ`` with ``D = sqrt(diag C)``,
    ``L L^H = D⁻¹ C D⁻¹ (+ jitter I)``; ``ξ`` unit-modulus with uniform phase (``"pinned_uvw"``),
    circular complex Gaussian, ``E|ξ|² = 1`` (``"free"``), or Gaussian but for the first
    signal's, normalised to unit modulus (``"pinned_u"``: the same draws as ``"free"``), or
    ``"free"`` rescaled so the first signal's realised variance is its expected one
    (``"inferred_level"``).
    With ``nt`` even the last (Nyquist) phasor is real as in ``gen_turb`` (``±1``, resp. real
    Gaussian of variance 1).
    """
    n_f, n, _ = C.shape
    d = np.sqrt(np.clip(np.real(np.einsum("fii->fi", C)), 0.0, None))
    inv = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
    gam = C * inv[:, :, None] * inv[:, None, :]
    idx = np.arange(n)
    gam[:, idx, idx] = np.where(d > 0, 1.0, 0.0) + jitter
    try:
        L = np.linalg.cholesky(gam)
    except np.linalg.LinAlgError:
        gam[:, idx, idx] -= jitter
        lam, vec = np.linalg.eigh(gam)
        L = vec * np.sqrt(np.clip(lam, 0.0, None))[:, None, :]
    if reference_turbulence == "pinned_uvw":
        phase = 2.0 * np.pi * rng.random((n_f, n))
        if nt is not None and nt % 2 == 0:
            phase[-1] = np.pi * (np.round(np.cos(phase[-1])) != 0.0)
        xi = np.exp(1j * phase)
    elif reference_turbulence in ("free", "pinned_u", "inferred_level"):
        xi = (rng.standard_normal((n_f, n)) + 1j * rng.standard_normal((n_f, n))) * np.sqrt(0.5)
        if nt is not None and nt % 2 == 0:
            xi[-1] = np.real(xi[-1]) * np.sqrt(2.0)
        if reference_turbulence == "pinned_u":
            # a circular Gaussian's phase is uniform: keep it, drop the modulus
            a = np.abs(xi[:, 0])
            xi[:, 0] = np.where(a > 0, xi[:, 0] / np.where(a > 0, a, 1.0), 1.0)
    else:
        raise ValueError(f"reference_turbulence must be one of {list(REFERENCE_TURBULENCE)}; "
                         f"got {reference_turbulence!r}")
    coef = (d * np.einsum("fij,fj->fi", L, xi)).T
    if reference_turbulence == "inferred_level":
        # all signals x the factor giving signal 0 its expected variance
        want, got = _realised_power(d[:, 0], nt), _realised_power(np.abs(coef[0]), nt)
        coef *= np.sqrt(want / got) if got > 0 else 1.0
    return coef


def _realised_power(m: np.ndarray, nt: int | None) -> float:
    """``2 Σ |m|² − |m_Nyquist|²`` (nt even): the realised variance of a series, up to ``nt/(nt-1)``."""
    return float(2.0 * np.sum(m**2) - (m[-1] ** 2 if nt is not None and nt % 2 == 0 else 0.0))


def synthesise(coef: np.ndarray, nt: int) -> np.ndarray:
    """Time series ``(n_signals, nt)`` from positive-frequency coefficients (DC = 0), as ``gen_turb``."""
    full = np.zeros(coef.shape[:-1] + (nt // 2 + 1,), dtype=complex)
    full[..., 1:coef.shape[-1] + 1] = coef
    return np.fft.irfft(full, n=nt, axis=-1) * nt
