"""Wind field reconstruction (WFR) of a four-beam DBS lidar: paper Eqs. 3-5, pure numpy.

Sliding reconstruction
    The LOS stream arrives one beam at a time (vertical beam ignored).  At every LOS the
    latest value of each of the four oblique beams is used, so every beam contributes each of
    its samples (150 per 10 minutes at 1 s per LOS) to up to four reconstructions.  A
    reconstruction exists once every beam has delivered a valid sample; dropped samples
    (NaN, availability) leave the beam's previous value in use.

Components
    With the beams ordered by azimuth (0°, 90°, 180°, 270°, clockwise from the lidar's north
    mark) and radial velocities positive away from the lidar, ``S1 - S3 = 2 sin(phi) V_0``
    where ``V_0`` is the horizontal wind component *toward* azimuth 0°:
    ``u_i = (S1 - S3) / (2 sin phi)`` (toward 0°), ``v_i = (S2 - S4) / (2 sin phi)`` (toward 90°).
    ``phi`` is the *nominal* cone angle: a true cone of ``phi + dphi`` then over-reads by
    ``sin(phi + dphi) / sin(phi) - 1 ≈ cot(phi) dphi`` (positive for a wider cone).

Averages
    * scalar (Eq. 3, reconstruct-then-average): ``V_scalar = mean(sqrt(u_i^2 + v_i^2))``;
    * vector (Eq. 4, average-then-reconstruct): ``V_vector = sqrt(mean(u_i)^2 + mean(v_i)^2)``.
      Eq. 4 as printed puts the squares inside the sums, which is an RMS speed (it would
      exceed the scalar mean); the text describes average-then-reconstruct, implemented here.
    * hybrid (Eq. 5): ``V_hybrid = p V_scalar + (1 - p) V_vector``.  ``p`` multiplies the
      *scalar* average (the order of Eq. 5's "p and (1 - p)"), so p = 1 is pure scalar and
      p = 0 pure vector; WindCube v2.1 uses p = 2/3, WindCube XP p = 1/2.  The ``hybrid_weight``
      of :class:`~lidarcal.lidar.LidarModel` and the ``p`` of ``diagnose`` mean the same.
      The paper's "p and (1 - p)" does not say which average p belongs to; the other reading,
      ``convention="vector"``, is ``V_hybrid = p V_vector + (1 - p) V_scalar``.  The two differ
      by ``(2p - 1)(V_scalar - V_vector)``: for p = 2/3 a third of the scalar-vector gap,
      about 0.3 % of the speed at TI 0.2 (``docs/wfr.md``).
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["hold_latest", "sliding_components", "scalar_speed", "vector_speed", "hybrid_speed",
           "reconstruct"]


def hold_latest(los: np.ndarray, beam: np.ndarray, n_beams: int = 4) -> np.ndarray:
    """Latest valid value of every beam at every LOS time: ``(..., n_beams, n_times)``.

    ``los`` is ``(..., n_times)``, ``beam`` ``(n_times,)`` gives the beam of each LOS; NaN marks
    a dropped sample.  Entries before a beam's first valid sample are NaN.
    """
    los = np.asarray(los, dtype=float)
    beam = np.asarray(beam)
    n = los.shape[-1]
    steps = np.arange(n)
    out = np.empty(los.shape[:-1] + (n_beams, n))
    padded = np.concatenate([los, np.full(los.shape[:-1] + (1,), np.nan)], axis=-1)
    for b in range(n_beams):
        valid = (beam == b) & np.isfinite(los)
        last = np.maximum.accumulate(np.where(valid, steps, -1), axis=-1)
        idx = np.where(last >= 0, last, n)  # n -> the NaN pad
        out[..., b, :] = np.take_along_axis(padded, idx, axis=-1)
    return out


def sliding_components(los: np.ndarray, beam: np.ndarray, cone_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal components (u_i toward 0°, v_i toward 90°) at every LOS; NaN until all beams seen."""
    held = hold_latest(los, beam, 4)
    two_sin = 2.0 * np.sin(np.radians(cone_angle))
    return (held[..., 0, :] - held[..., 2, :]) / two_sin, (held[..., 1, :] - held[..., 3, :]) / two_sin


def scalar_speed(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Eq. 3: mean of the instantaneous horizontal speeds (NaN entries ignored)."""
    with np.errstate(invalid="ignore"):
        return np.nanmean(np.hypot(u, v), axis=-1)


def vector_speed(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Eq. 4 as the text means it: speed of the mean horizontal vector (NaN entries ignored)."""
    with np.errstate(invalid="ignore"):
        return np.hypot(np.nanmean(u, axis=-1), np.nanmean(v, axis=-1))


def hybrid_speed(scalar: np.ndarray, vector: np.ndarray, p: float, convention: str = "scalar") -> np.ndarray:
    """Eq. 5: ``p * scalar + (1 - p) * vector`` (``convention="scalar"``, the default).

    ``convention="vector"`` puts p on the vector average: ``p * vector + (1 - p) * scalar``.

    >>> [round(float(hybrid_speed(10.3, 10.0, 2 / 3, c)), 9) for c in ("scalar", "vector")]
    [10.2, 10.1]
    """
    if convention == "scalar":
        return p * np.asarray(scalar) + (1.0 - p) * np.asarray(vector)
    if convention == "vector":
        return p * np.asarray(vector) + (1.0 - p) * np.asarray(scalar)
    raise ValueError(f"hybrid convention must be 'scalar' or 'vector'; got {convention!r}")


def reconstruct(los: np.ndarray, beam: np.ndarray, cone_angle: float, p: float,
                convention: str = "scalar") -> dict[str, np.ndarray]:
    """Scalar, vector and hybrid 10-min speeds from a LOS stream ``(..., n_times)``.

    ``convention`` is the average ``p`` multiplies (:func:`hybrid_speed`).  Returns
    ``{"scalar", "vector", "hybrid", "n_reconstructions"}``; the speeds are NaN where no
    reconstruction was possible.
    """
    u, v = sliding_components(los, beam, cone_angle)
    ok = np.isfinite(u) & np.isfinite(v)
    count = ok.sum(axis=-1)
    u, v = np.where(ok, u, np.nan), np.where(ok, v, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices -> NaN, intended
        scalar, vector = scalar_speed(u, v), vector_speed(u, v)
    return {"scalar": scalar, "vector": vector, "hybrid": hybrid_speed(scalar, vector, p, convention),
            "n_reconstructions": count}
