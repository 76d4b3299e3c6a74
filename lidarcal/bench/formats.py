"""Plain-text formats of a bench run: the lidar's RTD and the SAFO-MV control log (CSV).

Both files are UTF-8 CSV with one header row.  Lines starting with ``#`` before the header
are comments; in the control log they carry ``# key: value`` metadata.  A column's unit is
the suffix of its name (``radial_wind_speed_m_s`` is in m s-1, ``_km_h`` in km h-1,
``_knot`` in knots): ``<a>_<b>`` reads "a per b", a single token is the unit itself.

RTD file (one row per lidar LOS estimate, 1.25 Hz; the lidar keeps scanning DBS, so only
the rows of the beam the bench's optical switch feeds carry the bench signal):

=============================  ==========================================================
``timestamp_utc``              ISO 8601, UTC (``2023-02-17T16:07:00.800Z``; an explicit
                               offset is converted to UTC; no designator means UTC)
``los``                        beam id: ``0``, ``90``, ``180``, ``270`` (azimuth, degree) or ``V``
``radial_wind_speed_<unit>``   measured radial velocity; any unit convertible to m s-1
``cnr_dB``                     measured carrier-to-noise ratio, dB (no other unit accepted)
``lidar_serial``               lidar serial number (must match the control log)
=============================  ==========================================================

Control log (one row per programmed ℓcv-bin, in time order, bins may not overlap)::

    # SAFO-MV control log
    # bench_id: SAFO-MV-01
    # operator: A
    # run_id: 1
    # lidar_serial: WLS866-0195
    # rf_driver_calibration_reference: ASERTI certificate ...
    # rf_driver_relative_uncertainty_percent: 5.95622e-08
    bin_index,start_utc,end_utc,los,programmed_velocity_m_s,programmed_cnr_dB
    0,2023-02-17T16:07:00.000Z,2023-02-17T16:17:50.000Z,0,-18.000,-28.00

Either file may be gzip-compressed (``rtd.csv.gz``): readers detect gzip by its magic bytes
(a ``.gz`` name that is not gzip is refused), and the writers compress when the path ends
in ``.gz``, byte-reproducibly (gzip header with mtime 0 and the name without ``.gz``).

Readers check everything a later step relies on and raise :mod:`lidarcal.errors`
exceptions naming the file, the column, what was expected and what was found.
"""

from __future__ import annotations

import contextlib
import gzip
import io
import os
import re
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from lidarcal.bench.grid import LOS_LABELS, los_index
from lidarcal.cf import iso_utc
from lidarcal.errors import InputError, MissingVariableError, UnitError, raise_first_bad
from lidarcal.io import atomic_path
from lidarcal.units import convert_values

__all__ = [
    "RtdTable", "ControlLog", "read_rtd", "read_control_log", "write_rtd", "write_control_log",
    "CONTROL_METADATA", "column_unit",
]

#: Required ``# key: value`` metadata of a control log.
CONTROL_METADATA = (
    "bench_id", "operator", "run_id", "lidar_serial",
    "rf_driver_calibration_reference", "rf_driver_relative_uncertainty_percent",
)
_CONTROL_COLUMNS = ("start_utc", "end_utc", "los")
_GZIP_MAGIC = b"\x1f\x8b"
#: What a damaged gzip stream raises: bad header or CRC, truncated stream, corrupt deflate data.
_GZIP_ERRORS = (gzip.BadGzipFile, EOFError, zlib.error)


@dataclass
class RtdTable:
    """RTD as numpy arrays: time (int64 ns since epoch, UTC), LOS index, velocity (m s-1), CNR (dB)."""

    time_ns: np.ndarray
    los: np.ndarray
    velocity: np.ndarray
    cnr: np.ndarray
    lidar_serial: str
    source: str = "<rtd>"

    def __len__(self) -> int:
        return len(self.time_ns)


@dataclass
class ControlLog:
    """Programmed bins: start/end (int64 ns, UTC), LOS index, velocity (m s-1), CNR (dB), metadata."""

    start_ns: np.ndarray
    end_ns: np.ndarray
    los: np.ndarray
    velocity: np.ndarray
    cnr: np.ndarray
    metadata: dict = field(default_factory=dict)
    source: str = "<control>"
    columns: dict = field(default_factory=dict)  #: actual column names of "velocity" and "cnr"

    def __len__(self) -> int:
        return len(self.start_ns)


def column_unit(suffix: str) -> str:
    """UDUNITS unit string of a column-name unit suffix (``m_s`` → ``m s-1``, ``dB`` → ``dB``)."""
    parts = suffix.split("_")
    if len(parts) == 1:
        return parts[0]
    if len(parts) == 2 and all(parts):
        return f"{parts[0]} {parts[1]}-1"
    return suffix.replace("_", " ")


def _compression(path: Path, what: str) -> str | None:
    """``"gzip"`` if the file starts with the gzip magic bytes, else None (a ``.gz`` name must be gzip)."""
    with open(path, "rb") as fh:
        head = fh.read(2)
    if head == _GZIP_MAGIC:
        return "gzip"
    if path.suffix.lower() == ".gz":
        raise InputError(f"{path}: {what} file is named '.gz' but is not gzip-compressed; expected the "
                         f"gzip magic bytes {_GZIP_MAGIC!r}, found {head!r}")
    return None


def _read_table(path: str | os.PathLike, what: str) -> tuple[pd.DataFrame, dict]:
    """CSV body and the ``# key: value`` metadata of the comment lines before the header.

    Plain or gzip-compressed (detected by the magic bytes) UTF-8 text.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: {what} file not found")
    if path.is_dir():
        raise InputError(f"{path}: {what} path is a directory; expected a CSV file")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: {what} file is empty")
    compression = _compression(path, what)
    meta: dict[str, str] = {}
    try:
        opener = gzip.open if compression == "gzip" else open
        with opener(path, "rt", encoding="utf-8") as fh:
            for line in fh:
                if not line.startswith("#"):
                    break
                m = re.match(r"#\s*([A-Za-z0-9_]+)\s*:\s*(.*?)\s*$", line)
                if m:
                    meta[m.group(1)] = m.group(2)
        df = pd.read_csv(path, comment="#", dtype=str, skip_blank_lines=True, compression=compression)
    except _GZIP_ERRORS as exc:
        raise InputError(f"{path}: {what} file is not a valid gzip file (corrupt or truncated); "
                         f"expected a complete gzip-compressed CSV; {type(exc).__name__}: {exc}") from None
    except pd.errors.EmptyDataError:
        raise InputError(f"{path}: {what} file has no header row and no data") from None
    except UnicodeDecodeError as exc:
        damaged = " (or its gzip data is corrupt)" if compression else ""
        raise InputError(f"{path}: {what} file is not UTF-8 text{damaged}: {exc}") from None
    except pd.errors.ParserError as exc:
        raise InputError(f"{path}: {what} file is not a readable CSV table: {exc}") from None
    df.columns = [str(c).strip() for c in df.columns]
    if len(df) == 0:
        raise InputError(f"{path}: {what} file has a header but no data rows")
    return df, meta


def _require(df: pd.DataFrame, name: str, path, what: str) -> pd.Series:
    if name not in df.columns:
        raise MissingVariableError(
            f"{path}: {what} column {name!r} is missing; found columns {list(df.columns)}")
    return df[name]


def _unit_column(df: pd.DataFrame, prefix: str, expected: str, path, what: str) -> tuple[np.ndarray, str]:
    """Find the one column ``<prefix>_<unit>`` and return its values converted to ``expected``."""
    names = [c for c in df.columns if c.startswith(prefix + "_")]
    if len(names) != 1:
        found = "none" if not names else ", ".join(names)
        raise MissingVariableError(
            f"{path}: {what} needs exactly one column named '{prefix}_<unit>' (e.g. '{prefix}_"
            f"{expected.replace(' ', '_').replace('-1', '')}'); found {found} among {list(df.columns)}")
    name = names[0]
    unit = column_unit(name[len(prefix) + 1:])
    values = _numeric(df[name], name, path, what)
    try:
        return convert_values(values, unit, expected, where=f"{path}: column {name!r}"), name
    except UnitError as exc:
        raise UnitError(f"{exc} (unit taken from the column name suffix)") from None


def _numeric(col: pd.Series, name: str, path, what: str) -> np.ndarray:
    values = pd.to_numeric(col.str.strip(), errors="coerce").to_numpy(dtype=float)
    raise_first_bad(~np.isfinite(values), lambda i, n: (
        f"{path}: {what} column {name!r} has {n} missing, NaN or non-numeric value(s); "
        f"expected finite numbers; first at data row {i + 1}: found {col.iloc[i]!r}"))
    return values


#: Plausible RTD values: a pulsed lidar's radial velocities stay far inside +-100 m s-1 (the
#: bench programs +-18 m s-1 and a bench_cube holds biases within +-60 m s-1); its CNR inside the
#: bench_cube's measured-CNR range.  A value outside is a corrupt record, refused by name here
#: rather than reported later as a problem of the output cube.
RTD_VELOCITY_RANGE = (-100.0, 100.0)
RTD_CNR_RANGE = (-60.0, 20.0)


def _check_range(values: np.ndarray, name: str, bounds: tuple[float, float], unit: str, path,
                 what: str) -> None:
    raise_first_bad((values < bounds[0]) | (values > bounds[1]), lambda i, n: (
        f"{path}: {what} column {name!r} data row {i + 1} is {values[i]:g} {unit} (after unit "
        f"conversion); expected values within [{bounds[0]:g}, {bounds[1]:g}] {unit}; "
        f"{n} row(s) outside"))


def _times(col: pd.Series, name: str, path, what: str) -> np.ndarray:
    text = col.str.strip()
    raise_first_bad(text.isna().to_numpy() | (text == "").to_numpy(), lambda i, n: (
        f"{path}: {what} column {name!r} has {n} empty timestamp(s); first at data row {i + 1}"))
    try:
        parsed = pd.to_datetime(text, format="ISO8601", utc=True)
    except (ValueError, TypeError) as exc:
        raise InputError(f"{path}: {what} column {name!r}: expected ISO 8601 UTC timestamps "
                         f"(e.g. 2023-02-17T16:07:00.800Z); {exc}") from None
    return parsed.dt.tz_convert(None).to_numpy().astype("datetime64[ns]").astype(np.int64)


def _check_increasing(t: np.ndarray, name: str, path, what: str) -> None:
    step = np.diff(t)
    raise_first_bad(step <= 0, lambda i, n: (  # row i + 1 repeats or precedes row i
        f"{path}: {what} column {name!r}: timestamps must be strictly increasing; "
        f"{n} are duplicated or out of order, first at data row {i + 2} "
        f"({iso_utc(t[i + 1], 'ms')} is {'duplicated' if step[i] == 0 else 'out of order'} after "
        f"{iso_utc(t[i], 'ms')})"))


def _los(col: pd.Series, path, what: str) -> np.ndarray:
    labels = col.fillna("").str.strip().to_numpy(dtype=str)
    idx = los_index(labels)
    raise_first_bad(idx < 0, lambda i, n: (
        f"{path}: {what} column 'los' has {n} row(s) with unknown LOS id(s) "
        f"{sorted(set(labels[idx < 0].tolist()))[:10]}; expected one of {list(LOS_LABELS)} (first at "
        f"data row {i + 1})"))
    return idx


def read_rtd(path: str | os.PathLike) -> RtdTable:
    """Read and check an RTD CSV file (see the module docstring for its columns)."""
    what = "RTD"
    df, _ = _read_table(path, what)
    for name in ("timestamp_utc", "los", "lidar_serial"):
        _require(df, name, path, what)
    velocity, vname = _unit_column(df, "radial_wind_speed", "m s-1", path, what)
    cnr, cname = _unit_column(df, "cnr", "dB", path, what)
    _check_range(velocity, vname, RTD_VELOCITY_RANGE, "m s-1", path, what)
    _check_range(cnr, cname, RTD_CNR_RANGE, "dB", path, what)
    t = _times(df["timestamp_utc"], "timestamp_utc", path, what)
    _check_increasing(t, "timestamp_utc", path, what)
    los = _los(df["los"], path, what)
    serials = df["lidar_serial"].fillna("").str.strip().unique().tolist()
    if len(serials) != 1 or not serials[0]:
        raise InputError(f"{path}: RTD column 'lidar_serial' must hold one lidar serial; found {serials[:5]}")
    return RtdTable(t, los, velocity, cnr, serials[0], str(path))


#: Largest difference between a bin's end - start and the declared ``accumulation_time_s``, s:
#: timestamps have millisecond resolution and a bench switches its state in well under a second.
DURATION_TOLERANCE_S = 1.0


def _check_durations(start: np.ndarray, end: np.ndarray, meta: dict, path) -> None:
    """Bins must last the declared ``accumulation_time_s`` (optional metadata) within 1 s."""
    declared = meta.get("accumulation_time_s")
    if declared is None:
        return
    try:
        seconds = float(declared)
    except ValueError:
        seconds = float("nan")
    if not (np.isfinite(seconds) and seconds > 0):
        raise InputError(f"{path}: control log metadata 'accumulation_time_s' must be a positive number of "
                         f"seconds; found {declared!r}")
    duration = (end - start) / 1e9
    raise_first_bad(np.abs(duration - seconds) > DURATION_TOLERANCE_S, lambda i, n: (
        f"{path}: control log row {i + 1} ({iso_utc(start[i], 'ms')} to {iso_utc(end[i], 'ms')}) lasts "
        f"{duration[i]:g} s; expected the declared accumulation_time_s {seconds:g} s "
        f"(+-{DURATION_TOLERANCE_S:g} s); {n} of {len(start)} bins differ"))


def read_control_log(path: str | os.PathLike) -> ControlLog:
    """Read and check a SAFO-MV control log (see the module docstring)."""
    what = "control log"
    df, meta = _read_table(path, what)
    missing = [k for k in CONTROL_METADATA if not meta.get(k)]
    if missing:
        raise MissingVariableError(f"{path}: control log header lacks metadata {missing} "
                                   f"(lines '# key: value' before the column header); found {sorted(meta)}")
    try:
        meta["rf_driver_relative_uncertainty_percent"] = float(meta["rf_driver_relative_uncertainty_percent"])
    except ValueError:
        found = meta["rf_driver_relative_uncertainty_percent"]
        raise InputError(f"{path}: control log metadata 'rf_driver_relative_uncertainty_percent' must be a "
                         f"number (percent); found {found!r}") from None
    for name in _CONTROL_COLUMNS:
        _require(df, name, path, what)
    start = _times(df["start_utc"], "start_utc", path, what)
    end = _times(df["end_utc"], "end_utc", path, what)
    _check_increasing(start, "start_utc", path, what)
    raise_first_bad(end <= start, lambda i, n: (
        f"{path}: control log row {i + 1}: end_utc {iso_utc(end[i], 'ms')} is not after "
        f"start_utc {iso_utc(start[i], 'ms')}"))
    raise_first_bad(end[:-1] > start[1:], lambda i, n: (  # row i + 1 starts before row i ends
        f"{path}: control log row {i + 2} starts at {iso_utc(start[i + 1], 'ms')}, before the previous "
        f"bin ends ({iso_utc(end[i], 'ms')}); programmed bins must not overlap"))
    _check_durations(start, end, meta, path)
    velocity, vname = _unit_column(df, "programmed_velocity", "m s-1", path, what)
    cnr, cname = _unit_column(df, "programmed_cnr", "dB", path, what)
    los = _los(df["los"], path, what)
    return ControlLog(start, end, los, velocity, cnr, meta, str(path), {"velocity": vname, "cnr": cname})


@contextlib.contextmanager
def _text_output(path: str | os.PathLike, overwrite: bool) -> Iterator[io.TextIOBase]:
    """Atomic UTF-8 text output, LF line ends; gzip (mtime 0, level 9) if ``path`` ends in ``.gz``."""
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp, open(tmp, "wb") as raw:
        if path.suffix.lower() == ".gz":
            # the header records mtime 0 and the final name (not the temporary one): reproducible bytes
            with gzip.GzipFile(filename=path.stem, mode="wb", fileobj=raw, mtime=0) as gz, \
                    io.TextIOWrapper(gz, encoding="utf-8", newline="\n") as fh:
                yield fh
        else:
            with io.TextIOWrapper(raw, encoding="utf-8", newline="\n") as fh:
                yield fh


def write_rtd(rtd: RtdTable, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write an RTD CSV atomically (m s-1 and dB, three decimals, millisecond timestamps).

    A path ending in ``.gz`` is written gzip-compressed, byte-reproducibly (header mtime 0).
    """
    df = pd.DataFrame({
        "timestamp_utc": iso_utc(rtd.time_ns, "ms"),
        "los": np.asarray(LOS_LABELS)[rtd.los],
        "radial_wind_speed_m_s": np.round(rtd.velocity, 3),
        "cnr_dB": np.round(rtd.cnr, 2),
        "lidar_serial": rtd.lidar_serial,
    })
    with _text_output(path, overwrite) as fh:
        df.to_csv(fh, index=False, float_format="%.3f", lineterminator="\n")
    return Path(path)


def write_control_log(log: ControlLog, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write a control log atomically, metadata as ``# key: value`` lines before the header.

    A path ending in ``.gz`` is written gzip-compressed, like :func:`write_rtd`.
    """
    df = pd.DataFrame({
        "bin_index": np.arange(len(log)),
        "start_utc": iso_utc(log.start_ns, "ms"),
        "end_utc": iso_utc(log.end_ns, "ms"),
        "los": np.asarray(LOS_LABELS)[log.los],
        "programmed_velocity_m_s": log.velocity,
        "programmed_cnr_dB": log.cnr,
    })
    with _text_output(path, overwrite) as fh:
        fh.write("# SAFO-MV control log\n")
        for key, value in log.metadata.items():
            fh.write(f"# {key}: {value}\n")
        df.to_csv(fh, index=False, float_format="%.3f", lineterminator="\n")
    return Path(path)
