"""The bench noise table of a virtual lidar: bias, std and measured residuals per bin.

A :class:`NoiseTable` is the bench cube reduced to what the simulation draws from: for each
beam a (CNR, radial velocity) table of the LOS bias and standard deviation (empty bins filled
from the nearest populated one) and, optionally, every measured residual (measured −
programmed, bad estimates included) as a ragged array, from which it draws a bin's residuals
(``los_noise_model = "residuals"``) or only its good ones (``"mixture"``, with
:mod:`lidarcal.lidar.bad_estimates`).  :func:`noise_table_from_cube` builds it from a
``bench_cube`` artefact; :class:`lidarcal.lidar.model.LidarModel` carries it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.errors import InputError
from lidarcal.io import source_name
from lidarcal.lidar.bad_estimates import BadEstimates, good_pools
from lidarcal.units import convert_variable

__all__ = ["NoiseTable", "LOS_NOISE_MODELS", "noise_table_from_cube", "cube_residuals", "cube_residual_array",
           "residuals_digest", "table_digest", "tuplify", "listify", "fit_bad_estimates"]

log = logging.getLogger(__name__)

#: LOS noise models of a bench-calibrated lidar (:attr:`LidarModel.los_noise_model`): ``"mixture"``
#: good residuals resampled and bad estimates at the CNR's fitted rate; ``"residuals"`` every
#: residual of the bin resampled (runs before the mixture existed); ``"gaussian"`` N(bias, std).
LOS_NOISE_MODELS = ("mixture", "residuals", "gaussian")


def tuplify(value: Any) -> Any:
    """Nested lists/arrays as nested tuples of Python numbers (hashable dataclass fields)."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, list | tuple):
        return tuple(tuplify(v) for v in value)
    return float(value) if isinstance(value, np.floating | np.integer) else value


def listify(value: Any) -> Any:
    """Nested tuples as nested lists (JSON)."""
    if isinstance(value, tuple | list):
        return [listify(v) for v in value]
    return value

@dataclasses.dataclass(frozen=True)
class NoiseTable:
    """Per-beam LOS error table from the bench cube: bias and std on (beam, CNR, velocity).

    ``cnr`` (dB) and ``velocity`` (m s-1, radial, positive away from the lidar) are the bin
    centres; ``bias`` and ``std`` (m s-1) have shape ``(n_beams, n_cnr, n_velocity)`` with the
    beams in the order of :attr:`LidarModel.azimuths`.  Empty bins have already been filled from
    the nearest populated bin (see :meth:`LidarModel.from_artefacts`).

    Lookup (:meth:`lookup`) is bilinear in (CNR, velocity) between bin centres and clamped to
    the edge bins outside the table.

    Optionally the table carries each bin's measured residuals (measured − programmed, bad
    estimates included) as a contiguous ragged array: ``residual_count`` (same shape as
    ``bias``, every bin >= 1 after filling) and ``residuals``, the bins' values concatenated in
    C order of ``(beam, cnr, velocity)``.  :meth:`draw_residuals` resamples them.

    ``residuals_sha256`` and ``residuals_total`` identify them (:func:`residuals_digest`): the
    SHA-256 of ``residual_count`` as little-endian int64 in C order followed by ``residuals``
    as little-endian float64, and the number of values.  They are filled in from the values;
    given with the values they must match.  A table recorded in an artefact's attributes holds
    only the digest (``residual_count`` and ``residuals`` ``None``, :attr:`needs_residuals`):
    :meth:`LidarModel.with_residuals` restores the values from the bench cube the model was
    built from, and until then :meth:`draw_residuals` refuses to draw.

    ``table_sha256`` identifies ``bias`` and ``std`` the same way (:func:`table_digest`); it is
    filled in from the values.  The attribute form of a table (:meth:`attribute_form`, what an
    artefact records) keeps the bin centres and the digests only: the bias and std are the bench
    cube's own ``los_bias``/``los_std`` (the cube is an input recorded by its SHA-256), so
    recording them again would only repeat tens of kB of numbers.  Such a table
    (:attr:`needs_table`) refuses :meth:`lookup` until
    :meth:`LidarModel.with_residuals <lidarcal.lidar.LidarModel.with_residuals>` restores it from the cube.
    """

    cnr: tuple[float, ...]
    velocity: tuple[float, ...]
    bias: tuple[tuple[tuple[float, ...], ...], ...] | None = None
    std: tuple[tuple[tuple[float, ...], ...], ...] | None = None
    residual_count: tuple[tuple[tuple[int, ...], ...], ...] | None = None
    residuals: tuple[float, ...] | None = None
    residuals_sha256: str | None = None
    residuals_total: int | None = None
    table_sha256: str | None = None
    #: What error messages call the table (the record it was read from); not part of the record.
    origin: str = dataclasses.field(default="noise table", compare=False, repr=False)

    def __post_init__(self) -> None:
        for name in ("cnr", "velocity", "bias", "std", "residual_count"):
            object.__setattr__(self, name, tuplify(getattr(self, name)))
        if self.residuals is not None:  # tens of thousands of values: one conversion, not per element
            values = np.atleast_1d(np.asarray(self.residuals, dtype=float))
            object.__setattr__(self, "residuals", tuple(values.tolist()))
        for name in ("cnr", "velocity"):
            axis = np.asarray(getattr(self, name))
            if axis.size > 1 and np.any(np.diff(axis) <= 0):
                raise InputError(f"noise table: {name} bin centres must be strictly increasing")
        shape = None
        if self.bias is None and self.std is None:
            if not _is_digest(self.table_sha256):
                raise InputError(f"noise table: without bias and std values, table_sha256 must be 64 "
                                 f"hexadecimal digits (the digest of the bench cube's table); found "
                                 f"{self.table_sha256!r}")
            object.__setattr__(self, "_arrays", None)
        else:
            bias, std = np.asarray(self.bias, float), np.asarray(self.std, float)
            shape = (bias.shape[0], len(self.cnr), len(self.velocity)) if bias.ndim == 3 else None
            if shape is None or bias.shape != shape or std.shape != shape:
                raise InputError(f"noise table: bias and std must have shape (beam, {len(self.cnr)} CNR, "
                                 f"{len(self.velocity)} velocity); found {bias.shape} and {std.shape}")
            if not (np.all(np.isfinite(bias)) and np.all(np.isfinite(std)) and np.all(std >= 0)):
                raise InputError("noise table: bias and std must be finite and std >= 0 in every bin")
            digest = table_digest(bias, std)
            if self.table_sha256 is not None and self.table_sha256 != digest:
                raise InputError(f"noise table: bias and std do not match table_sha256: expected sha256 "
                                 f"{self.table_sha256}, found sha256 {digest}")
            object.__setattr__(self, "table_sha256", digest)
            object.__setattr__(self, "_arrays", (np.asarray(self.cnr), np.asarray(self.velocity), bias, std))
        if (self.residual_count is None) != (self.residuals is None):
            raise InputError("noise table: residual_count and residuals go together; one of them is missing")
        if self.residuals is not None:
            count = np.asarray(self.residual_count)
            values = np.asarray(self.residuals, dtype=float)
            if shape is None:
                raise InputError("noise table: residuals need the bias and std values too")
            if count.shape != shape or count.dtype.kind not in "iu" or np.any(count < 1):
                raise InputError(f"noise table: residual_count must hold whole numbers >= 1 with shape "
                                 f"{shape}; found shape {count.shape}")
            if values.ndim != 1 or values.size != int(count.sum()) or not np.all(np.isfinite(values)):
                raise InputError(f"noise table: residuals must be {int(count.sum())} finite values (the sum "
                                 f"of residual_count); found {values.size}")
            flat = count.ravel()
            start = np.concatenate([[0], np.cumsum(flat)[:-1]])
            object.__setattr__(self, "_ragged", (flat, start, values))
            digest = residuals_digest(count, values)
            if self.residuals_sha256 is not None and self.residuals_sha256 != digest:
                raise InputError(f"noise table: the residuals do not match residuals_sha256: expected "
                                 f"sha256 {self.residuals_sha256}, found sha256 {digest}")
            if self.residuals_total is not None and int(self.residuals_total) != values.size:
                raise InputError(f"noise table: residuals_total is {self.residuals_total}; found "
                                 f"{values.size} residuals")
            object.__setattr__(self, "residuals_sha256", digest)
            object.__setattr__(self, "residuals_total", int(values.size))
        elif self.residuals_sha256 is not None:
            if (not isinstance(self.residuals_sha256, str) or len(self.residuals_sha256) != 64
                    or self.residuals_total is None or int(self.residuals_total) < 1):
                raise InputError(f"noise table: residuals_sha256 must be 64 hexadecimal digits with "
                                 f"residuals_total >= 1; found {self.residuals_sha256!r} and "
                                 f"{self.residuals_total!r}")
            object.__setattr__(self, "residuals_total", int(self.residuals_total))
        elif self.residuals_total is not None:
            raise InputError("noise table: residuals_total without residuals_sha256")

    @property
    def needs_table(self) -> bool:
        """True when the table knows its bias and std only by digest (an attribute-form record)."""
        return self.bias is None

    @property
    def needs_values(self) -> bool:
        """True when anything is known only by digest (:attr:`needs_table` or :attr:`needs_residuals`)."""
        return self.needs_table or self.needs_residuals

    def attribute_form(self) -> NoiseTable:
        """Return what an artefact records: the bin centres and the digests, no bench values."""
        return dataclasses.replace(self.without_residuals(), bias=None, std=None)

    @property
    def has_residuals(self) -> bool:
        """True when the table carries measured residuals to resample."""
        return self.residuals is not None

    @property
    def needs_residuals(self) -> bool:
        """True when the table knows its residuals only by digest (an attribute-form record)."""
        return self.residuals is None and self.residuals_sha256 is not None

    def without_residuals(self) -> NoiseTable:
        """Return the attribute form: the same table with the residuals replaced by their digest."""
        if self.residuals is None:
            return self
        return dataclasses.replace(self, residual_count=None, residuals=None)

    def missing_residuals_message(self) -> str:
        """Why a digest-only table cannot draw, and how to restore it."""
        if not self.needs_residuals:
            return self.missing_table_message()
        return (f"{self.origin} records the bench residuals only by digest: no bench cube given; pass the "
                f"cube the model was built from (--cube), its residuals have sha256 {self.residuals_sha256} "
                f"({self.residuals_total} values); or use los_noise_model 'gaussian'")

    def missing_table_message(self) -> str:
        """Why a table known by digest cannot look up its bias and std, and how to restore it."""
        return (f"{self.origin} records the bench noise table (los_bias, los_std) only by digest: no bench "
                f"cube given; pass the cube the model was built from (--cube), its table has sha256 "
                f"{self.table_sha256}")

    def draw_residuals(self, beam: np.ndarray, cnr: float, velocity: np.ndarray,
                       uniforms: np.ndarray) -> np.ndarray:
        """Draw one measured residual (m s-1) per sample from the neighbouring bins.

        ``beam`` (index into the beams) and ``velocity`` (m s-1) give each sample, ``cnr`` (dB)
        the period; ``uniforms`` is ``(3, n)`` uniform numbers in [0, 1).  The bin is chosen at
        random among the neighbours :meth:`lookup` interpolates between, each with its bilinear
        weight (row 0 picks the CNR neighbour, row 1 the velocity neighbour; clamped outside
        the table), so the draw's distribution is the bilinear mixture of the bins'
        distributions and its mean the bilinear interpolation of the bins' mean residuals; row 2
        picks one of that bin's residuals with equal probability.
        """
        self._require_residuals()
        count, start, values = self._ragged
        return _pick(count, start, values, self._cells(beam, cnr, velocity, uniforms), uniforms[2])

    def draw_good_residuals(self, beam: np.ndarray, cnr: float, velocity: np.ndarray, uniforms: np.ndarray,
                            bad: BadEstimates) -> np.ndarray:
        """Draw one *good* residual (m s-1) per sample: :meth:`draw_residuals` on the good pools.

        The pools are :func:`lidarcal.lidar.bad_estimates.good_pools` of the table's residuals
        with the classification of ``bad`` (its per-CNR thresholds and ``min_good``): each bin's
        good residuals, with its CNR neighbours' when it has fewer than ``min_good``.  They are
        built once per table and classification.
        """
        self._require_residuals()
        if tuple(bad.cnr) != tuple(self.cnr):
            raise InputError(f"{self.origin}: the bad-estimate model's CNR bins {list(bad.cnr)} dB are not "
                             "the "
                             f"noise table's {list(self.cnr)} dB")
        count, start, values = self.good_pools(bad.threshold, bad.min_good)
        return _pick(count, start, values, self._cells(beam, cnr, velocity, uniforms), uniforms[2])

    def good_pools(self, threshold: tuple[float, ...], min_good: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the good-residual pools as a flat ragged array ``(count, start, values)`` (cached)."""
        self._require_residuals()
        key = (tuple(threshold), int(min_good))
        cache = self.__dict__.setdefault("_good_cache", {})
        if key not in cache:
            counts, values, _ = good_pools(np.asarray(self.residual_count), self._ragged[2],
                                           np.asarray(threshold, dtype=float), int(min_good))
            flat = counts.ravel()
            cache[key] = (flat, np.concatenate([[0], np.cumsum(flat)[:-1]]), values)
        return cache[key]

    def _require_residuals(self) -> None:
        if self.needs_residuals:
            raise InputError(self.missing_residuals_message())
        if self.residuals is None:
            raise InputError("noise table: no measured residuals to resample (a cube without "
                             "'los_residual'); use los_noise_model='gaussian'")

    def _cells(self, beam: np.ndarray, cnr: float, velocity: np.ndarray, uniforms: np.ndarray) -> np.ndarray:
        """Flat bin index per sample: the CNR and velocity neighbour picked with their bilinear weights."""
        cnr_axis, vel_axis, _, _ = self._arrays
        n_c, n_v = cnr_axis.size, vel_axis.size
        velocity = np.asarray(velocity, dtype=float)
        ci = np.zeros(velocity.shape, dtype=np.intp)
        if n_c > 1:
            pos = float(np.interp(cnr, cnr_axis, np.arange(n_c)))
            i0 = int(np.floor(pos))
            ci = np.where(uniforms[0] < pos - i0, min(i0 + 1, n_c - 1), i0)
        vi = np.zeros(velocity.shape, dtype=np.intp)
        if n_v > 1:
            pos_v = np.interp(velocity, vel_axis, np.arange(n_v))
            j0 = np.floor(pos_v).astype(np.intp)
            vi = np.where(uniforms[1] < pos_v - j0, np.minimum(j0 + 1, n_v - 1), j0)
        return (np.asarray(beam, dtype=np.intp) * n_c + ci) * n_v + vi

    def lookup(self, beam: int, cnr: float, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bias and std (m s-1) for one beam at one CNR (dB) and many radial velocities."""
        if self.needs_table:
            raise InputError(self.missing_table_message())
        cnr_axis, vel_axis, bias, std = self._arrays
        if cnr_axis.size == 1:
            i0 = i1 = 0
            t = 0.0
        else:
            pos = np.interp(cnr, cnr_axis, np.arange(cnr_axis.size))  # clamped fractional index
            i0 = int(np.floor(pos))
            i1 = min(i0 + 1, cnr_axis.size - 1)
            t = pos - i0
        rows_b = (1.0 - t) * bias[beam, i0] + t * bias[beam, i1]
        rows_s = (1.0 - t) * std[beam, i0] + t * std[beam, i1]
        if vel_axis.size == 1:
            return np.full_like(velocity, rows_b[0]), np.full_like(velocity, rows_s[0])
        return np.interp(velocity, vel_axis, rows_b), np.interp(velocity, vel_axis, rows_s)


def _pick(count: np.ndarray, start: np.ndarray, values: np.ndarray, cell: np.ndarray,
          uniforms: np.ndarray) -> np.ndarray:
    """One value of each sample's bin ``cell`` of a ragged array, each with equal probability."""
    k = np.minimum((uniforms * count[cell]).astype(np.intp), count[cell] - 1)
    return values[start[cell] + k]


def _fill_nearest(values: np.ndarray) -> np.ndarray:
    """Fill NaN bins of a 2-D (cnr, velocity) table from the nearest populated bin (index space)."""
    from scipy.ndimage import distance_transform_edt

    missing = ~np.isfinite(values)
    if not missing.any():
        return values
    _, (ii, jj) = distance_transform_edt(missing, return_indices=True)
    return values[ii, jj]


def _fill_index(valid: np.ndarray) -> np.ndarray:
    """Flat index of the nearest valid bin of a 2-D table for every bin (index space)."""
    from scipy.ndimage import distance_transform_edt

    _, (ii, jj) = distance_transform_edt(~valid, return_indices=True)
    return np.ravel_multi_index((ii, jj), valid.shape)


def _ragged_residuals(cube: xr.Dataset, rows: list[int], ci: np.ndarray,
                      vi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the cube's residuals as counts (beam, cnr, velocity) and concatenated values.

    Each beam's empty bins take the residuals of the nearest bin that has some (as the bias and
    std of :func:`_fill_nearest`).
    """
    src = source_name(cube)
    var = convert_variable(cube, "los_residual", "m s-1", source=src)
    extra = [d for d in var.dims if d not in ("los", "cnr", "velocity")]
    if len(extra) != 1:
        raise InputError(f"{src}: variable 'los_residual' must have dims (los, cnr, velocity, sample); "
                         f"found {tuple(var.dims)}")
    res = var.transpose("los", "cnr", "velocity", extra[0]).values
    counts, values = [], []
    for row in rows:
        r = res[row][np.ix_(ci, vi)]                        # (cnr, velocity, sample)
        n = np.isfinite(r).sum(axis=-1)
        if not (n > 0).any():
            raise InputError(f"{src}: variable 'los_residual' is empty (all NaN) for the beam of "
                             f"los_azimuth {float(cube.los_azimuth.values[row]):g}")
        src_bin = _fill_index(n > 0)
        flat = r.reshape(-1, r.shape[-1])[src_bin]         # (cnr * velocity, sample)
        counts.append(n.ravel()[src_bin].reshape(n.shape))
        values.append(flat[np.isfinite(flat)])               # C order: bin by bin, time order within
    return np.array(counts, dtype=np.int64), np.concatenate(values)


def residuals_digest(count: Any, values: Any) -> str:
    """SHA-256 identifying a noise table's residuals (:class:`NoiseTable`).

    The hash of ``count`` as little-endian int64 in C order of ``(beam, cnr, velocity)``
    followed by ``values`` as little-endian float64 (the concatenated bins, in that order).
    """
    h = hashlib.sha256(np.ascontiguousarray(count, dtype="<i8").tobytes())
    h.update(np.ascontiguousarray(values, dtype="<f8").tobytes())
    return h.hexdigest()


def table_digest(bias: Any, std: Any) -> str:
    """SHA-256 identifying a noise table's bias and std (:class:`NoiseTable`).

    The hash of ``bias`` followed by ``std``, each as little-endian float64 in C order of
    ``(beam, cnr, velocity)``.
    """
    h = hashlib.sha256(np.ascontiguousarray(bias, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(std, dtype="<f8").tobytes())
    return h.hexdigest()


def _is_digest(value: Any) -> bool:
    return isinstance(value, str) and len(value) == 64 and all(c in "0123456789abcdef" for c in value)


def _cube_layout(cube: xr.Dataset, azimuths: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray, list[int],
                                                                          np.ndarray, np.ndarray]:
    """Return the cube's bin centres, each beam azimuth's row and the sort orders of both axes."""
    src = source_name(cube)
    cnr = convert_variable(cube, "cnr", "dB", source=src).values
    vel = convert_variable(cube, "velocity", "m s-1", source=src).values
    az = convert_variable(cube, "los_azimuth", "degree", source=src).values
    el = convert_variable(cube, "los_elevation", "degree", source=src).values
    rows = []
    for a in azimuths:
        diff = np.abs((az - a + 180.0) % 360.0 - 180.0)
        cand = np.flatnonzero((diff < 0.5) & (el < 89.0))
        if cand.size != 1:
            raise InputError(f"{src}: coordinate 'los_azimuth' should hold exactly one oblique beam at "
                             f"{a}°; found azimuths {az.tolist()} with elevations {el.tolist()}")
        rows.append(int(cand[0]))
    return cnr, vel, rows, np.argsort(cnr), np.argsort(vel)


def cube_residual_array(cube: xr.Dataset, azimuths: tuple[float, ...]) -> np.ndarray:
    """Return the cube's residuals of these beams as ``(beam, cnr, velocity, sample)``, NaN-padded.

    The bins in the order of a table built from ``cube`` (axes increasing); empty bins stay
    empty (NaN), not filled, as
    :meth:`BadEstimates.from_residuals <lidarcal.lidar.bad_estimates.BadEstimates.from_residuals>`
    needs them: a filled bin would count its neighbour's residuals twice.
    """
    _, _, rows, ci, vi = _cube_layout(cube, azimuths)
    src = source_name(cube)
    var = convert_variable(cube, "los_residual", "m s-1", source=src)
    extra = [d for d in var.dims if d not in ("los", "cnr", "velocity")]
    if len(extra) != 1:
        raise InputError(f"{src}: variable 'los_residual' must have dims (los, cnr, velocity, sample); "
                         f"found {tuple(var.dims)}")
    res = var.transpose("los", "cnr", "velocity", extra[0]).values
    return np.stack([res[row][np.ix_(ci, vi)] for row in rows])


def cube_residuals(cube: xr.Dataset, azimuths: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Return the residuals a table built from ``cube`` for these beams carries: (counts, values)."""
    _, _, rows, ci, vi = _cube_layout(cube, azimuths)
    return _ragged_residuals(cube, rows, ci, vi)


def noise_table_from_cube(cube: xr.Dataset, azimuths: tuple[float, ...], *,
                          residuals: bool = False) -> NoiseTable:
    """Build the table of the beams at ``azimuths`` from a ``bench_cube`` (residuals too if asked)."""
    src = source_name(cube)
    bias = convert_variable(cube, "los_bias", "m s-1", source=src)
    std = convert_variable(cube, "los_std", "m s-1", source=src)
    cnr, vel, rows, ci, vi = _cube_layout(cube, azimuths)
    bias = bias.transpose("los", "cnr", "velocity").values
    std = std.transpose("los", "cnr", "velocity").values
    out_b, out_s = [], []
    for a, row in zip(azimuths, rows, strict=True):
        b, s = bias[row][np.ix_(ci, vi)], std[row][np.ix_(ci, vi)]
        ok = np.isfinite(b) & np.isfinite(s)
        if not ok.any():
            raise InputError(f"{src}: variables 'los_bias'/'los_std' are empty (all NaN) "
                             f"for the beam at {a}°")
        b, s = np.where(ok, b, np.nan), np.where(ok, s, np.nan)
        out_b.append(_fill_nearest(b))
        out_s.append(_fill_nearest(s))
    extra = {}
    if residuals:
        count, values = _ragged_residuals(cube, rows, ci, vi)
        extra = {"residual_count": count, "residuals": values}
    return NoiseTable(cnr=cnr[ci], velocity=vel[vi], bias=np.array(out_b), std=np.array(out_s), **extra)


def fit_bad_estimates(cube: xr.Dataset, azimuths: tuple[float, ...],
                      cnr_threshold: float | None) -> BadEstimates:
    """Classify the bench cube's residuals of these beams and fit p_bad(CNR) (``docs/method.md``).

    ``cnr_threshold`` (dB or None): the lidar's CNR filter, which sets the CNR bins the rate is
    fitted over.  Raises :class:`~lidarcal.errors.InputError` naming the cube when its residuals
    hold too few bad estimates to estimate the search band, or the fit fails.
    """
    src = source_name(cube)
    res = cube_residual_array(cube, azimuths)
    cnr = convert_variable(cube, "cnr", "dB", source=src).values
    vel = convert_variable(cube, "velocity", "m s-1", source=src).values
    try:
        bad = BadEstimates.from_residuals(res, np.sort(cnr), np.sort(vel), cnr_threshold=cnr_threshold)
    except ValueError as exc:
        raise InputError(f"{src}: variable 'los_residual' cannot give the bad-estimate rate: {exc}") from None
    if bad.fit_pvalue < 1e-3:
        log.warning("%s: the logistic p_bad(CNR) does not describe the bench's bad-estimate counts "
                    "(Pearson chi-square %.1f on %d degrees of freedom, p = %.1e)", src, bad.fit_chi2,
                    bad.fit_dof, bad.fit_pvalue)
    if bad.band_uniformity_p < 1e-3:
        log.warning("%s: the bench's bad estimates are not uniform over the search band %.2f to %.2f m s-1 "
                    "(Kolmogorov-Smirnov p = %.1e); the virtual lidar draws them uniform", src, *bad.band,
                    bad.band_uniformity_p)
    return bad
