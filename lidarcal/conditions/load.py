"""Loading and checking ``conditions`` / ``field_campaign`` inputs (``docs/contracts.md``).

:func:`load_conditions` returns the contract in canonical units with one extra variable,
``input_complete`` (time, height): 1 where every variable the simulation (or, for a field
campaign, the comparison) needs is present, 0 where the period is skipped at that height.
Skipped periods are reported with a :class:`SkippedPeriodsWarning`; they are not an error.
"""

from __future__ import annotations

import functools
import hashlib
import os
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

import dask
import dask.array
import numpy as np
import xarray as xr

from lidarcal.cf import height_coord
from lidarcal.conditions.variables import CANONICAL_UNITS, CONDITION_NAMES, FIELD_NAMES, variable_attrs
from lidarcal.errors import InputError, MissingVariableError, ValidationError, raise_first_bad
from lidarcal.io import open_artefact, source_name
from lidarcal.provenance import LEGACY_SERIAL, lidar_serial
from lidarcal.readback import read_attr
from lidarcal.schema import declared_variables, output_attrs, validate_dataset
from lidarcal.units import convert_values, convert_variable

__all__ = ["SkippedPeriodsWarning", "load_conditions", "conditions_checksum"]


class SkippedPeriodsWarning(UserWarning):
    """Some periods lack a needed value at some height and will be skipped there."""


def _where(i: int, shape: tuple[int, ...], ds: xr.Dataset) -> str:
    """Where the flat index ``i`` of a (time, height) array lies."""
    t, h = np.unravel_index(i, shape)
    return f"time={ds.time.values[t]!s} (index {t}), height={float(ds.height.values[h]):g} m"


def _check_time(raw: xr.Dataset, source: str) -> None:
    """Refuse an empty, missing, unsorted or repeated time axis, naming the first offender."""
    if raw.sizes["time"] == 0:
        raise InputError(f"{source}: dimension 'time' has length 0; expected at least one 10-minute period")
    if "time" not in raw.coords:
        raise MissingVariableError(f"{source}: coordinate 'time' is missing (UTC timestamps are required)")
    t = raw["time"].values
    if t.dtype.kind not in "Mmfiu":
        raise InputError(f"{source}: coordinate 'time' holds {t.dtype} values; expected timestamps "
                         "(CF units 'seconds since ...' or datetime64)")
    missing = np.isnat(t) if t.dtype.kind in "Mm" else ~np.isfinite(t)
    raise_first_bad(missing, lambda i, n: (
        f"{source}: coordinate 'time' has {n} missing value(s) "
        f"(NaT or NaN), first at index {i}; expected a timestamp for every period"))

    def out_of_order(k: int, n: int) -> str:
        i = k + 1
        kind = "repeats" if t[i] == t[i - 1] else "comes before"
        return (f"{source}: coordinate 'time' must be strictly increasing; {n} value(s) are duplicated "
                f"or out of order, first at index {i}: {t[i]!s} {kind} the previous time {t[i - 1]!s}")
    raise_first_bad(~(t[1:] > t[:-1]), out_of_order)


class _FirstBad:
    """The first offending value of a variable and how many there are, gathered block after block."""

    def __init__(self) -> None:
        self.count, self.first, self.value = 0, -1, np.nan

    def add(self, bad: np.ndarray, values: np.ndarray, offset: int) -> None:
        """Add one block's mask (``values`` its values, ``offset`` its first flat index in the whole)."""
        flat = np.asarray(bad, dtype=bool).ravel()
        n = int(flat.sum())
        if n and self.first < 0:
            i = int(np.argmax(flat))
            self.first, self.value = offset + i, float(np.asarray(values).flat[i])
        self.count += n


class _ValueCheck:
    """Refuse +-inf and values outside the declared physical range (NaN stays "missing").

    Runs on the values as converted to canonical units, before any folding (a direction of
    1000 degree is refused, not wrapped), naming the first offending value, time and height and
    how many there are; :meth:`add` takes the variable block by block, :meth:`done` raises.
    """

    def __init__(self, name: str, unit: str, spec: dict, ds_shape: xr.Dataset, source: str,
                 hint: str = "") -> None:
        self.name, self.unit, self.ds_shape, self.source, self.hint = name, unit, ds_shape, source, hint
        lo, hi = (None, None) if spec.get("range") is None else spec["range"]
        self.lo = -np.inf if lo is None else float(lo)
        self.hi = np.inf if hi is None else float(hi)
        self.inf, self.outside = _FirstBad(), _FirstBad()

    def add(self, values: np.ndarray, offset: int) -> None:
        """Check one block of the (time, height) values; ``offset`` its first flat index."""
        self.inf.add(np.isinf(values), values, offset)
        with np.errstate(invalid="ignore"):
            self.outside.add((values < self.lo) | (values > self.hi), values, offset)

    def done(self) -> None:
        """Raise for what the blocks held, infinite values first."""
        name, source = self.name, self.source
        shape = tuple(self.ds_shape.sizes[d] for d in ("time", "height"))
        if self.inf.count:
            raise InputError(
                f"{source}: variable {name!r} has {self.inf.count} infinite value(s), first "
                f"{self.inf.value:g} at {_where(self.inf.first, shape, self.ds_shape)}; expected finite "
                "values (NaN marks a missing value)")
        if self.outside.count:
            unit = self.unit
            u, conv = ("", "") if unit == "1" else (f" {unit}", f" (after conversion to {unit})")
            raise InputError(
                f"{source}: variable {name!r} has {self.outside.count} value(s) outside "
                f"[{self.lo:g}, {self.hi:g}]{u}{conv}, first {self.outside.value:.6g}{u} at "
                f"{_where(self.outside.first, shape, self.ds_shape)}{self.hint}")


def _check_height(ds: xr.Dataset, source: str) -> np.ndarray:
    if "height" not in ds.dims:
        raise MissingVariableError(
            f"{source}: dimension 'height' is missing; found dims {sorted(map(str, ds.dims))}"
        )
    if "height" not in ds.coords:
        raise MissingVariableError(f"{source}: coordinate 'height' is missing (heights in m are required)")
    h = ds["height"]
    values = convert_values(h.values, h.attrs.get("units"), "m", where=f"{source}: coordinate 'height'")
    std = h.attrs.get("standard_name", "height")
    if std != "height":
        raise InputError(f"{source}: coordinate 'height' has standard_name {std!r}; expected 'height'")
    if str(h.attrs.get("positive", "up")).lower() != "up":
        raise InputError(f"{source}: coordinate 'height' has positive={h.attrs['positive']!r}; expected 'up'")
    if not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise InputError(f"{source}: coordinate 'height' must be finite and > 0 m; found {values.tolist()}")
    if np.unique(values).size != values.size:
        raise InputError(f"{source}: coordinate 'height' has repeated values {values.tolist()}")
    return values


def conditions_checksum(ds: xr.Dataset, names: tuple[str, ...] | None = None) -> str:
    """SHA-256 of the canonical content (time, height and the condition variables).

    Identical for a file and for the same data passed as a Dataset, so it can key cached
    simulation chunks independently of file metadata.
    """
    digest = _checksum_start(ds["height"].values, ds["time"].values)
    for name in names or CONDITION_NAMES:
        digest.update(name.encode())
        digest.update(np.ascontiguousarray(ds[name].values, dtype=float).tobytes())
    return digest.hexdigest()


#: One read of a lazily loaded input at a time: dask's threads must not enter HDF5 together.
_READ_LOCK = threading.Lock()
#: The last blocks read from a file (:func:`_file_block`): a block's variables are asked for one
#: by one, and the file is opened once for them all.
_LAST_BLOCKS: dict[tuple, xr.Dataset] = {}


@dataclass(frozen=True)
class _File:
    """A lazily read input's file, with its size and modification time when it was first read."""

    path: str
    size: int
    mtime_ns: int

    @classmethod
    def of(cls, path: str) -> _File:
        stat = Path(path).stat()
        return cls(str(path), stat.st_size, stat.st_mtime_ns)


def _file_block(path: _File, periods: slice) -> xr.Dataset:
    """Return ``periods`` of the file ``path``: its (time, height) variables, loaded, as the file has them.

    Opened and closed here (call it under :data:`_READ_LOCK`); the last two blocks are kept.  A
    file changed since it was first read (and checked, and hashed) is refused: the numbers of a
    lazily read input are those of the bytes its provenance names.
    """
    stat = Path(path.path).stat()
    if (stat.st_size, stat.st_mtime_ns) != (path.size, path.mtime_ns):
        raise InputError(f"{path.path}: the file changed while it was being read (size or modification "
                         "time); expected it unchanged until the command ends")
    key = (path, periods.start, periods.stop)
    if key not in _LAST_BLOCKS:
        with xr.open_dataset(path.path, engine="netcdf4", cache=False, decode_times=False,
                             create_default_indexes=False) as f:  # a block's values only: no index
            part = f.isel(time=periods)
            names = [n for n in part.data_vars if set(part[n].dims) == {"time", "height"}]
            block = part[names].load()
        while len(_LAST_BLOCKS) >= 2:
            _LAST_BLOCKS.pop(next(iter(_LAST_BLOCKS)))
        _LAST_BLOCKS[key] = block
    return _LAST_BLOCKS[key]


def _with_block_stats(so_far: tuple[int, float, float] | None,
                      values: np.ndarray) -> tuple[int, float, float]:
    """Return (NaN count, least, greatest non-NaN value) of the blocks so far and ``values``."""
    nan = np.isnan(values)
    n, lo, hi = so_far or (0, np.inf, -np.inf)
    if (~nan).any():
        lo, hi = min(lo, float(values[~nan].min())), max(hi, float(values[~nan].max()))
    return n + int(nan.sum()), lo, hi


def _checksum_start(height: np.ndarray, time: np.ndarray):
    """Return the conditions' SHA-256 fed the heights and times (:func:`conditions_checksum`)."""
    digest = hashlib.sha256()
    digest.update(np.ascontiguousarray(height, dtype=float).tobytes())
    digest.update(np.ascontiguousarray(time).view(np.uint8).tobytes())
    return digest


def _canonical(raw: xr.Dataset | _File, name: str, periods: slice, order: np.ndarray, source: str,
               fold: bool = True) -> np.ndarray:
    """(time, height) values of ``periods`` of ``name`` in canonical units, heights ascending.

    ``raw`` is the input in memory, or the path of its file: then the block is read through a
    handle of its own, opened and closed here under one lock.  A lazily read input is read in
    dask's threads; no handle of its file outlives a read, for the garbage collector to close in
    one thread while another reads (HDF5 is not thread-safe: that crashes the process).
    With ``fold`` a direction is folded into [0, 360) degree; the loader's range check sees the
    values as given (a direction of 1000 degree is refused, not wrapped).
    """
    if isinstance(raw, _File):
        with _READ_LOCK:
            block = _file_block(raw, periods)
        return _canonical(block, name, slice(None), order, source, fold)
    da = convert_variable(raw.isel(time=periods), name, CANONICAL_UNITS[name], source=source)
    values = np.asarray(da.transpose("time", "height").values, dtype=float)[:, order]
    return np.mod(values, 360.0) if fold and name == "wind_from_direction" else values


def load_conditions(
    path_or_dataset: str | os.PathLike | xr.Dataset,
    kind: str = "conditions",
    *,
    warn: bool = True,
    block: int | None = None,
) -> xr.Dataset:
    """Open, convert and check a ``conditions`` or ``field_campaign`` input.

    Parameters
    ----------
    path_or_dataset : path or xarray.Dataset
        The netCDF file (or an already opened dataset) following ``docs/contracts.md``.
    kind : {"conditions", "field_campaign"}
        ``field_campaign`` additionally requires ``lidar_wind_speed`` and
        ``reference_wind_speed``.
    warn : bool
        Emit a :class:`SkippedPeriodsWarning` when periods have missing values.
    block : int, optional
        Read and check the input ``block`` periods at a time and return its variables lazily
        (dask arrays, one chunk per block, read and converted again when used): memory does not
        grow with the input's length (``lidarcal smc`` on a long campaign).  Default: load
        everything at once.

    Returns
    -------
    xarray.Dataset
        Dims ``(time, height)``, heights ascending, every variable in canonical units
        (``m s-1``, ``degree`` in [0, 360), ``1``, ``dB``, ``dB m-1``) with CF attributes,
        plus ``input_complete`` (time, height; 1 = usable, 0 = skipped) and the global
        attributes ``lidarcal_conditions_checksum``, ``lidarcal_skipped_count`` and the
        input's own attributes.

    Raises
    ------
    MissingVariableError, UnitError, InputError
        Missing variable or dimension, units not convertible (wind speed in kelvin),
        negative wind speed, turbulence intensity outside [0, 1], values outside the
        schema's physical range.  Messages name the file, the variable, what was expected
        and what was found (with counts and the first offending time and height).
    """
    if kind not in ("conditions", "field_campaign"):
        raise InputError(f"kind must be 'conditions' or 'field_campaign'; got {kind!r}")
    source = source_name(path_or_dataset)
    if isinstance(path_or_dataset, xr.Dataset):
        raw = path_or_dataset
    else:
        raw = open_artefact(Path(path_or_dataset), load=block is None)
    if "time" not in raw.dims:
        raise MissingVariableError(
            f"{source}: dimension 'time' is missing; found dims {sorted(map(str, raw.dims))}"
        )
    _check_time(raw, source)
    heights = _check_height(raw, source)
    needed = CONDITION_NAMES + (FIELD_NAMES if kind == "field_campaign" else ())
    missing = [n for n in needed if n not in raw.variables]
    if missing:
        raise MissingVariableError(
            f"{source}: required variable(s) {missing} missing for a {kind!r} input; "
            f"found {sorted(map(str, raw.data_vars))}"
        )
    order = np.argsort(heights, kind="stable")
    for name in needed:
        if set(raw[name].dims) != {"time", "height"}:
            raise InputError(
                f"{source}: variable {name!r} has dims {tuple(raw[name].dims)}; expected ('time', 'height')"
            )
    nt = raw.sizes["time"]
    slices = [slice(0, nt)] if block is None else [slice(a, min(a + int(block), nt))
                                                    for a in range(0, nt, max(1, int(block)))]
    ds_shape = xr.Dataset(coords={"time": raw["time"].values, "height": heights[order]})
    declared = {**declared_variables("conditions"), **declared_variables(kind)}  # ranges, as validated
    hints = {"turbulence_intensity": "; expected a fraction sigma_u / U (percent must carry units '%')"}
    complete = np.ones((nt, heights.size), dtype=bool)
    digest = _checksum_start(heights[order], raw["time"].values)
    data, stats = {}, {}
    # a lazily read file: every block through a handle of its own (_canonical); in memory: raw itself
    file = str(raw.encoding.get("source", "")) if block is not None else ""
    reader = _File.of(file) if file and Path(file).is_file() else raw
    for name in needed:  # each variable block by block: converted, checked, hashed (as folded)
        check = _ValueCheck(name, CANONICAL_UNITS[name], declared.get(name, {}), ds_shape, source,
                            hints.get(name, ""))
        digest.update(name.encode())
        for sl in slices:
            values = _canonical(reader, name, sl, order, source, fold=False)
            check.add(values, sl.start * heights.size)
            if name == "wind_from_direction":
                values = np.mod(values, 360.0)
            complete[sl] &= np.isfinite(values)
            digest.update(np.ascontiguousarray(values, dtype=float).tobytes())
            stats[name] = _with_block_stats(stats.get(name), values)
            if block is None:
                data[name] = values
        check.done()
        if block is not None:  # lazy: each block read and converted again when it is used
            read = dask.delayed(functools.partial(_canonical, reader, name, order=order, source=source),
                                pure=False)
            data[name] = dask.array.concatenate(
                [dask.array.from_delayed(read(sl), shape=(sl.stop - sl.start, heights.size), dtype=float)
                 for sl in slices], axis=0)

    dims = ("time", "height")
    out = xr.Dataset(coords={"time": raw["time"].copy(), "height": height_coord(heights[order])})
    for name in needed:
        out[name] = (dims, data[name], variable_attrs(name))
    out["input_complete"] = (dims, complete.astype(np.int8), output_attrs("conditions", "input_complete"))
    attrs = {k: v for k, v in raw.attrs.items() if not k.startswith("lidarcal_conditions_")}
    if LEGACY_SERIAL in attrs:  # a file written before the serial number had one name
        serial = lidar_serial(attrs)
        attrs = {("lidar_serial" if k == LEGACY_SERIAL else k): (serial if k == LEGACY_SERIAL else v)
                 for k, v in attrs.items() if k != "lidar_serial"}
    out.attrs = attrs
    out.attrs["lidarcal_conditions_checksum"] = digest.hexdigest()  # conditions_checksum(out, needed)
    n_skip = int((~complete).sum())
    out.attrs["lidarcal_skipped_count"] = n_skip
    # a field_campaign holds everything a conditions input needs, so it may stand in for one
    superset = kind == "conditions" and read_attr(out, "lidarcal_artefact") == "field_campaign"
    checked = out.assign_attrs(lidarcal_artefact="conditions") if superset else out
    # the values as stored were gone through above, block by block: not read again to validate
    problems = validate_dataset(checked, kind, source=source,
                                value_stats=stats if block is not None else None)
    problems = [p for p in problems if "lidarcal_artefact" not in p]
    if problems:
        raise ValidationError(problems, source)
    if n_skip and warn:
        rows = np.unique(np.argwhere(~complete)[:, 0])
        warnings.warn(
            f"{source}: {n_skip} (period, height) value(s) in {rows.size} period(s) lack a needed variable "
            f"(NaN) and will be skipped; first at {_where(int(np.argmax(~complete)), complete.shape, out)}",
            SkippedPeriodsWarning,
            stacklevel=2,
        )
    return out
