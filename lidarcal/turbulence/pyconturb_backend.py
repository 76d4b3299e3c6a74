"""PyConTurb's ``gen_turb`` behind the same interface as :func:`~lidarcal.turbulence.kernels.generate_points`.

Used by the statistical-equivalence tests and by ``lidarcal turbulence --generator pyconturb``.
It works around the traps of PyConTurb 2.7.4 (``docs/performance.md``):

* ``gen_turb`` seeds the *global* NumPy RNG.  Calls are serialised by a lock and the global
  RNG state is saved and restored around them, so lidarcal's own code (which never uses the
  global RNG) is unaffected and results are reproducible within one process;
  ``in_subprocess=True`` runs it in a fresh spawned process instead.
* ``u_ref`` is always given, ``coh_model='iec3d'`` (coherence on u, v and w), ``nf_chunk=1``
  (intermediate values are buggy), every z must be > 0.
* Coherence depends only on (y, z): points sharing (y, z) but differing in x would make the
  matrix singular.  The points are de-duplicated in (y, z), generated at x = 0, and each
  point then gets Taylor's frozen-turbulence delay ``x / U`` as a Fourier phase, exactly as
  the fast generator does.
"""

from __future__ import annotations

import threading

import numpy as np

from lidarcal.turbulence.kernels import frequencies, unique_planar_points

__all__ = ["generate_points_pyconturb", "seed_from_sequence"]

_LOCK = threading.Lock()


def seed_from_sequence(seed_sequence: np.random.SeedSequence) -> int:
    """Return a 32-bit integer seed for ``gen_turb`` derived from a :class:`~numpy.random.SeedSequence`."""
    return int(seed_sequence.generate_state(1, dtype=np.uint32)[0])


def _gen_turb_planar(yz: np.ndarray, wind_speed: float, sigma: tuple[float, float, float], duration: float,
                     nt: int, seed: int, l_c: float) -> np.ndarray:
    """Run ``gen_turb`` at planar points ``yz`` (x = 0); returns ``(3, n_u, nt)`` fluctuations."""
    import pandas as pd
    from pyconturb import gen_turb
    from pyconturb.sig_models import constant_sig
    from pyconturb.spectral_models import kaimal_spectrum

    n = yz.shape[0]
    cols, rows = [], []
    for k in range(3):
        for p in range(n):
            cols.append(f"{'uvw'[k]}_p{p}")
            rows.append([k, 0.0, yz[p, 0], yz[p, 1]])
    spat_df = pd.DataFrame(np.array(rows).T, index=["k", "x", "y", "z"], columns=cols)

    def zero_profile(spat_df, **kwargs):
        return np.zeros(spat_df.shape[1])

    state = np.random.get_state()
    try:
        turb = gen_turb(spat_df, T=duration, nt=nt, coh_model="iec3d", nf_chunk=1, seed=seed,
                        u_ref=wind_speed, l_c=l_c, wsp_func=zero_profile, sig_func=constant_sig,
                        sig_vals=list(sigma), comps=[0, 1, 2], spec_func=kaimal_spectrum)
    finally:
        np.random.set_state(state)
    return turb[cols].to_numpy().T.reshape(3, n, nt)


def generate_points_pyconturb(x, y, z, *, wind_speed: float, sigma, seed: int | np.random.SeedSequence,
                              duration: float = 600.0, dt: float = 1.0, l_c: float = 340.2,
                              in_subprocess: bool = False) -> np.ndarray:
    """Fluctuations ``(3, n_points, nt)`` from PyConTurb ``gen_turb`` (same layout as the fast path)."""
    x, y, z = (np.atleast_1d(np.asarray(a, dtype=float)) for a in (x, y, z))
    if np.any(z <= 0):
        raise ValueError(f"PyConTurb needs every z > 0 m; found min z = {z.min():.6g} m")
    if not wind_speed > 0:
        raise ValueError(f"PyConTurb needs u_ref > 0 m s-1; got {wind_speed}")
    if isinstance(seed, np.random.SeedSequence):
        seed = seed_from_sequence(seed)
    nt, f = frequencies(duration, dt)
    sigma = tuple(float(s) for s in sigma)
    yz, index = unique_planar_points(y, z)
    args = (yz, float(wind_speed), sigma, float(duration), nt, int(seed), float(l_c))
    if in_subprocess:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
            planar = pool.submit(_gen_turb_planar, *args).result()
    else:
        with _LOCK:
            planar = _gen_turb_planar(*args)
    if np.all(x == 0):
        return planar[:, index]
    coef = np.fft.rfft(planar[:, index], axis=-1)
    coef *= np.exp(-2j * np.pi * f * (x[:, None] / wind_speed))
    return np.fft.irfft(coef, n=nt, axis=-1)
