"""The WindCube ``.sta`` 10-minute statistics file format: parse one file, join several.

Two dialects exist, both Latin-1 text with LF or CRLF line ends and tab-separated columns:

* the **newer** one: first line ``HeaderSize=N``, first column ``Timestamp (end of interval)``
  (``YYYY/MM/DD HH:MM``), a few station columns, then one group per height whose column
  names carry the height (``40m Wind Speed (m/s)``, ``40m Wind Speed Dispersion (m/s)``,
  ``40m Wind Direction (°)``, ``40m CNR (dB)``, ``40m Data Availability (%)`` ...), each
  group followed by an empty column;
* the **older** one: first line ``HeaderLength=N``, first column ``Date``
  (``DD/MM/YYYY HH:MM:SS``, end of interval), ``WiperCount``, ``Tm``, then per height index
  ``i`` (1 ... number of altitudes, in header order) ``Vhm<i>``, ``dVh<i>``, ``VhMax<i>``,
  ``VhMin<i>``, ``Azim<i>``, ``um<i>`` ... ``dw<i>``, the **un-indexed** ``CNRm``, ``dCNR``,
  ``CNRmax``, ``CNRmin`` (the same names in every group: they are mapped by their position
  inside the group that ``Vhm<i>`` opens), ``spectral_broadening``, ``dspectral_broadening``,
  ``Avail.<i>`` and an empty column.

Line 1 is ``HeaderSize=N`` / ``HeaderLength=N``; lines 2 ... N + 1 are the header (``key=value``
lines, ``****`` separators, section titles); line N + 2 names the columns; data follow.
Firmware 2.x writes ``NA`` for internal header parameters (``ScanAngle (°)=NA``,
``Pulses / Line of Sight=NA`` ...): only the cone angle is needed, and a file whose header does
not state it gets it from the caller (:func:`resolve_cone_angle`: ``--cone-angle``, or the
certificate of ``lidarcal smc``), never a guess.  The
dialect is recognised from the first column name.  A missing value is ``NaN`` (as the firmware
writes it) or any missing-value marker of :mod:`lidarcal.conditions.readings`, the rule the mast
CSV reader shares.

:func:`read_sta_files` returns the parsed files; :mod:`lidarcal.conditions.sta` turns them into
``conditions`` (time is the interval start there).
"""

from __future__ import annotations

import csv
import hashlib
import io
import os
import re
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from lidarcal.conditions.readings import MISSING_MARKERS, PERIOD, RAW_RANGES, read_numbers, value_problem
from lidarcal.errors import InputError, raise_first_bad
from lidarcal.io import check_input_file

__all__ = ["StaFile", "read_sta", "read_sta_files", "resolve_cone_angle", "check_spacing", "DIALECTS",
           "ROLES",
           "CONE_ANGLE_TOLERANCE"]

#: First column name -> (dialect name, timestamp format, description of the format).
DIALECTS = {
    "Timestamp (end of interval)": ("newer", "%Y/%m/%d %H:%M", "YYYY/MM/DD HH:MM"),
    "Date": ("older", "%d/%m/%Y %H:%M:%S", "DD/MM/YYYY HH:MM:SS"),
}

#: The five per-height quantities read; the others of each group are ignored.
ROLES = ("speed", "dispersion", "direction", "cnr", "availability")

#: Newer dialect: quantity (lower case, without units) -> (role, accepted unit spellings).
_NEWER = {
    "wind speed": ("speed", ("m/s",)),
    "wind speed dispersion": ("dispersion", ("m/s",)),
    "wind direction": ("direction", ("°", "deg", "degree", "degrees")),
    "cnr": ("cnr", ("dB",)),
    "data availability": ("availability", ("%",)),
}
_NEWER_NAME = re.compile(r"^(\d+(?:\.\d+)?)\s*m\s+(.*?)\s*(?:\(([^()]*)\))?\s*$")
_OLDER_INDEXED = re.compile(
    r"^(Vhm|dVh|VhMax|VhMin|Azim|um|du|vm|dv|wm|dw|Avail\.)(\d+)$"
)
_OLDER_ROLE = {"Vhm": "speed", "dVh": "dispersion", "Azim": "direction", "Avail.": "availability"}
_FIRST_LINE = re.compile(r"^\s*(HeaderSize|HeaderLength)\s*=\s*(\d+)\s*$")
#: Normalised header keys (:func:`_norm`) that may declare the statistics averaging period.
_PERIOD_KEYS = ("averagingperiod", "averagingtime", "averageperiod", "averagetime", "statisticsperiod",
                "statisticaverage", "averaging")
@dataclass
class StaFile:
    """One parsed ``.sta`` file; arrays on (row, altitude) in the header's altitude order."""

    path: Path
    dialect: str
    header_size: int
    header: dict[str, str]
    header_lines: dict[str, tuple[int, str]]  # normalised key -> (line number, key as written)
    altitudes: np.ndarray
    scan_angle: float | None  # None: the header says NA (firmware 2.x); see resolve_cone_angle
    end: np.ndarray  # datetime64[ns], end-of-interval stamps as written
    lines: np.ndarray  # file line number of each row
    values: dict[str, np.ndarray]  # role -> (row, altitude)
    columns: dict[str, list[int]]  # role -> 1-based column of each altitude
    sha256: str = ""
    #: where ``scan_angle`` came from: the file header, or what resolved an ``NA`` header value
    scan_angle_source: str = "file header"

    def get(self, *keys: str) -> str | None:
        """Header value of the first normalised key present (see :func:`_norm`)."""
        for key in keys:
            if key in self.header_lines:
                return self.header[self.header_lines[key][1]]
        return None

    def line_of(self, *keys: str) -> int | None:
        """Line number of the first normalised key present."""
        for key in keys:
            if key in self.header_lines:
                return self.header_lines[key][0]
        return None

    @property
    def serial(self) -> str | None:
        """``ID System``: the lidar's serial."""
        return self.get("idsystem")


def _norm(key: str) -> str:
    """Header key without units, spaces or case: ``ScanAngle (°)`` -> ``scanangle``."""
    return re.sub(r"\([^)]*\)", "", key).replace(" ", "").replace("\t", "").lower()


def _declared_period(path: Path, header: dict, where: dict) -> None:
    """Refuse a file whose header declares an averaging period other than 10 minutes."""
    for key in _PERIOD_KEYS:
        if key not in where:
            continue
        line, name = where[key]
        text = header[name]
        m = re.match(r"^\s*([0-9.]+)\s*([a-zA-Z]*)\s*$", text)
        in_name = re.search(r"\(([^)]*)\)", name)
        unit = (in_name.group(1).strip().lower() if in_name else "") or (m.group(2).lower() if m else "")
        scale = {"s": 1, "sec": 1, "second": 1, "seconds": 1, "": 1, "min": 60, "mn": 60, "minute": 60,
                 "minutes": 60, "m": 60, "h": 3600}.get(unit or "")
        if not m or scale is None:
            raise InputError(f"{path}: line {line} ({name!r}): expected an averaging period such as 600 s; "
                             f"found {text!r}")
        seconds = float(m.group(1)) * scale
        if seconds != PERIOD / np.timedelta64(1, "s"):
            raise InputError(
                f"{path}: line {line} ({name}={text}): the file declares {seconds:g} s statistics; lidarcal "
                f"reads 10-minute (600 s) statistics only"
            )
        return


def check_spacing(path_of, end: np.ndarray, lines: np.ndarray) -> None:
    """Refuse interval ends that are not whole 10-minute periods apart (overlapping or shifted periods).

    ``end`` sorted or not; gaps of whole periods (missing statistics) are allowed.  ``path_of(k)``
    names the file of row ``k``.
    """
    if end.size < 2:
        return
    order = np.argsort(end, kind="stable")
    step = np.diff(end[order])
    bad = (step % PERIOD != np.timedelta64(0, "ns")) | (step <= np.timedelta64(0, "ns"))

    def message(k: int, n: int) -> str:
        a, b = int(order[k]), int(order[k + 1])
        return (
            f"{path_of(b)}: line {lines[b]}, column 1: interval ending {pd.Timestamp(end[b])} is "
            f"{step[k] / np.timedelta64(1, 's'):g} s after the one ending {pd.Timestamp(end[a])} "
            f"({path_of(a)}, line {lines[a]}); 10-minute statistics must be whole multiples of 600 s apart "
            f"(overlapping or shifted periods are refused)"
        )
    raise_first_bad(bad, message)


def _float(text: str, where: str, what: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise InputError(f"{where}: {what}: expected a number; found {text!r}") from None


def _parse_header(path: Path, lines: list[str]) -> tuple[int, dict, dict]:
    m = _FIRST_LINE.match(lines[0]) if lines else None
    if not m:
        found = lines[0][:60] if lines else "an empty file"
        raise InputError(
            f"{path}: line 1, column 1: unknown STA dialect: expected 'HeaderSize=N' (newer WindCube "
            f"firmware) or 'HeaderLength=N' (older); found {found!r}"
        )
    n = int(m.group(2))
    n_lines = len(lines)
    if n + 2 > n_lines:
        raise InputError(
            f"{path}: line 1, column 1: {m.group(1)}={n} points past the data: the column-name line "
            f"would be line {n + 2} but the file has {n_lines} line(s)"
        )
    header: dict[str, str] = {}
    where: dict[str, tuple[int, str]] = {}
    for k in range(1, n + 1):
        text = lines[k]
        if "=" not in text:
            continue  # '****' separators and section titles
        key, value = text.split("=", 1)
        key = key.strip()
        if not key:
            continue
        name = key if key not in header else f"{key} (line {k + 1})"
        header[name] = value.strip().replace("\t", " ")
        where.setdefault(_norm(key), (k + 1, name))
    return n, header, where


def _header_numbers(path: Path, n: int, header: dict, where: dict) -> tuple[np.ndarray, float]:
    span = f"{path}: header (lines 2-{n + 1})"
    if "altitudes" not in where:
        raise InputError(f"{span}: key 'Altitudes (m)' missing; expected the measurement heights in m")
    line, key = where["altitudes"]
    raw = header[key].split()
    alts = np.array([_float(t, f"{path}: line {line}", f"{key!r} value {t!r}") for t in raw])
    if alts.size < 2 or np.any(~np.isfinite(alts)) or np.any(alts <= 0):
        raise InputError(
            f"{path}: line {line}: {key!r}: expected at least two heights > 0 m (shear and CNR gradient "
            f"need neighbours); found {raw}"
        )
    if np.unique(alts).size != alts.size:
        raise InputError(f"{path}: line {line}: {key!r}: repeated height in {raw}")
    if "scanangle" not in where:
        raise InputError(f"{span}: key 'ScanAngle (°)' missing; expected the cone angle in degrees")
    line, key = where["scanangle"]
    if header[key].strip().lower() in MISSING_MARKERS:
        return alts, None  # firmware 2.x writes NA for internal parameters: resolved by the caller
    phi = _float(header[key], f"{path}: line {line}", f"{key!r}")
    if not 0 < phi < 90:
        raise InputError(
            f"{path}: line {line}: {key!r}: expected a cone angle in (0, 90) degree; found {phi}"
        )
    return alts, phi


def _missing_group(path: Path, line: int, h: float, i: int, alts: np.ndarray, where: str,
                   expected: str, after: int) -> InputError:
    return InputError(
        f"{path}: line {line}, column {after}: height group missing: no column {expected!r} for altitude "
        f"{h:g} m (number {i} of {alts.size} in the header's Altitudes, {where}); expected the group "
        f"from column {after} on"
    )


def _columns_newer(path: Path, line: int, names: list[str], alts: np.ndarray, alt_line: int) -> dict:
    found: dict[float, dict[str, int]] = {}
    last_col: dict[float, int] = {}
    for j, name in enumerate(names):
        m = _NEWER_NAME.match(name)
        if not m:
            continue
        h = float(m.group(1))
        if not np.any(np.isclose(alts, h, rtol=0, atol=1e-6)):
            raise InputError(
                f"{path}: line {line}, column {j + 1}: {name!r} is for height {h:g} m, which is not among "
                f"the header's Altitudes {alts.tolist()} (line {alt_line})"
            )
        last_col[h] = j + 1
        spec = _NEWER.get(re.sub(r"\s+", " ", m.group(2)).lower())
        if spec is None:
            continue
        role, units = spec
        unit = (m.group(3) or "").strip()
        if unit not in units:
            hint = " (is the file Latin-1 encoded?)" if "Â" in unit else ""
            raise InputError(
                f"{path}: line {line}, column {j + 1}: {name!r}: expected units {units[0]!r}; found "
                f"{unit!r}{hint}"
            )
        group = found.setdefault(h, {})
        if role in group:
            raise InputError(
                f"{path}: line {line}, column {j + 1}: {name!r} repeats column {group[role] + 1} "
                f"({names[group[role]]!r})"
            )
        group[role] = j
    out = {role: [] for role in ROLES}
    labels = {"speed": "Wind Speed (m/s)", "dispersion": "Wind Speed Dispersion (m/s)",
              "direction": "Wind Direction (°)", "cnr": "CNR (dB)", "availability": "Data Availability (%)"}
    after = 2
    for i, h in enumerate(alts, start=1):
        key = next((k for k in found if abs(k - h) <= 1e-6), None)
        group = found.get(key, {}) if key is not None else {}
        for role in ROLES:
            if role not in group:
                raise _missing_group(path, line, h, i, alts, f"line {alt_line}", f"{h:g}m {labels[role]}",
                                     after if not group else min(group.values()) + 1)
            out[role].append(group[role])
        after = last_col[key] + 2  # past the group's empty column
    return out


def _columns_older(path: Path, line: int, names: list[str], alts: np.ndarray, alt_line: int) -> dict:
    starts: dict[int, int] = {}
    for j, name in enumerate(names):
        m = _OLDER_INDEXED.match(name)
        if m and m.group(1) == "Vhm":
            i = int(m.group(2))
            if not 1 <= i <= alts.size:
                raise InputError(
                    f"{path}: line {line}, column {j + 1}: {name!r}: height index {i} outside 1..{alts.size} "
                    f"(the header's Altitudes, line {alt_line}, list {alts.size} heights)"
                )
            if i in starts:
                raise InputError(
                    f"{path}: line {line}, column {j + 1}: {name!r} repeats column {starts[i] + 1}"
                )
            starts[i] = j
    bounds = sorted(starts.values()) + [len(names)]
    out = {role: [] for role in ROLES}
    after = 4  # Date, WiperCount, Tm
    for i, h in enumerate(alts, start=1):
        if i not in starts:
            raise _missing_group(path, line, h, i, alts, f"line {alt_line}", f"Vhm{i}", after)
        j0 = starts[i]
        j1 = bounds[bounds.index(j0) + 1]
        group: dict[str, int] = {}
        for j in range(j0, j1):
            name = names[j]
            m = _OLDER_INDEXED.match(name)
            if m:
                if int(m.group(2)) != i:
                    raise InputError(
                        f"{path}: line {line}, column {j + 1}: {name!r} inside the group of height index {i} "
                        f"({h:g} m, opened by 'Vhm{i}' at column {j0 + 1}); expected index {i}"
                    )
                role = _OLDER_ROLE.get(m.group(1))
            else:
                role = "cnr" if name == "CNRm" else None  # un-indexed: by position in this group
            if role is None:
                continue
            if role in group:
                raise InputError(
                    f"{path}: line {line}, column {j + 1}: {name!r} appears twice in the group of height "
                    f"index {i} (also column {group[role] + 1})"
                )
            group[role] = j
        expected = {"speed": f"Vhm{i}", "dispersion": f"dVh{i}", "direction": f"Azim{i}", "cnr": "CNRm",
                    "availability": f"Avail.{i}"}
        for role in ROLES:
            if role not in group:
                raise InputError(
                    f"{path}: line {line}, columns {j0 + 1}-{j1}: the group of height index {i} ({h:g} m) "
                    f"has no column {expected[role]!r}"
                )
            out[role].append(group[role])
        after = j1 + 1
    return out


def _truncated_rows(path: Path, lines: list[str], n: int, names: list[str], allow_gaps: bool) -> list[int]:
    """Return the file lines of rows cut short (refused unless ``allow_gaps``); refuse rows too long."""
    col_line = n + 2
    needed = max(j for j, name in enumerate(names) if name.strip()) + 1  # a trailing empty column may go
    truncated = []
    for k in range(n + 2, len(lines)):
        count = lines[k].count("\t") + 1
        if count > len(names):
            raise InputError(
                f"{path}: line {k + 1}, column {len(names) + 1}: {count} tab-separated fields; the "
                f"column-name line (line {col_line}) names {len(names)}"
            )
        if count < needed:
            truncated.append((k + 1, count))
    if truncated:
        listed = ", ".join(f"line {ln} ({c} of {needed} fields)" for ln, c in truncated[:10])
        more = f" and {len(truncated) - 10} more" if len(truncated) > 10 else ""
        text = (f"{path}: {len(truncated)} truncated row(s), cut short before column {needed} "
                f"({names[needed - 1]!r}): {listed}{more}")
        if not allow_gaps:
            raise InputError(f"{text}; repair or remove them, or pass --allow-gaps to read them as "
                             "missing periods")
        warnings.warn(f"{text}; read as missing periods (--allow-gaps)", UserWarning, stacklevel=3)
    return [ln for ln, _ in truncated]


def read_sta(path: str | os.PathLike, *, allow_gaps: bool = False) -> StaFile:
    """Parse one WindCube ``.sta`` file (either dialect; see the module docstring).

    ``allow_gaps``: rows cut short (fewer fields than the column names) become missing periods
    with a warning naming them, instead of an error.

    Raises
    ------
    InputError
        Unknown dialect, header length pointing past the data, a height group missing,
        unparsable numbers or timestamps, duplicated timestamps, statistics not 10 minutes
        apart, truncated rows, sentinel values (9999, -999), negative speeds or values outside
        the physical range (e.g. swapped columns); the message names the file, the line and
        the column.
    """
    path = check_input_file(path, ".sta file")
    raw = path.read_bytes()
    text = raw.decode("latin-1")  # every byte is a Latin-1 character: decoding cannot fail
    lines = text.split("\n")
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in lines]
    while lines and not lines[-1].strip():
        lines.pop()
    n, header, where = _parse_header(path, lines)
    alts, phi = _header_numbers(path, n, header, where)
    _declared_period(path, header, where)
    col_line = n + 2
    names = lines[n + 1].split("\t")
    first = names[0].strip()
    if first not in DIALECTS:
        looks = " (it looks like a data row: does the header length point past the column names?)" \
            if re.match(r"^\d", first) else ""
        raise InputError(
            f"{path}: line {col_line}, column 1: unknown STA dialect: the column-name line (line N + 2 for "
            f"{lines[0].strip()}) must start with 'Timestamp (end of interval)' (newer) or 'Date' (older); "
            f"found {first[:60]!r}{looks}"
        )
    dialect, fmt, fmt_text = DIALECTS[first]
    alt_line = where["altitudes"][0]
    finder = _columns_newer if dialect == "newer" else _columns_older
    cols = finder(path, col_line, names, alts, alt_line)

    n_rows = len(lines) - (n + 2)
    if n_rows < 1:
        raise InputError(f"{path}: line {col_line}: no data rows after the column-name line")
    truncated = _truncated_rows(path, lines, n, names, allow_gaps)
    # the table is parsed from the lines split above (decoded as Latin-1, CR stripped) so that
    # row r is exactly file line n + 3 + r, whatever stray carriage returns a line holds
    try:
        df = pd.read_csv(
            io.StringIO("\n".join(lines[n + 2:]) + "\n"), sep="\t", header=None,
            names=list(range(len(names))), dtype=str, keep_default_na=False, skip_blank_lines=False,
            quoting=csv.QUOTE_NONE, index_col=False, lineterminator="\n",
        )
    except (pd.errors.ParserError, ValueError) as exc:
        raise InputError(f"{path}: lines {n + 3}-{len(lines)}: not a tab-separated table: {exc}") from None
    first_line = n + 3
    stamps = df[0].fillna("").astype(str).str.strip()
    end = pd.to_datetime(stamps, format=fmt, errors="coerce")
    raise_first_bad(end.isna().to_numpy(), lambda r, n: (
        f"{path}: line {first_line + r}, column 1 ({first!r}): expected a timestamp {fmt_text}; found "
        f"{stamps.iloc[r]!r}"))
    end = end.to_numpy(dtype="datetime64[ns]")
    row_lines = first_line + np.arange(n_rows)
    _, inverse, counts = np.unique(end, return_inverse=True, return_counts=True)
    if (counts > 1).any():
        dup = np.flatnonzero(counts[inverse] > 1)
        a, b = dup[0], dup[1:][end[dup[1:]] == end[dup[0]]][0]
        raise InputError(
            f"{path}: line {row_lines[b]}, column 1: duplicated timestamp {stamps.iloc[b]!r} (also line "
            f"{row_lines[a]})"
        )
    check_spacing(lambda k: path, end, row_lines)
    cut = np.isin(row_lines, truncated)
    values = {}
    for role in ROLES:
        values[role] = np.column_stack([
            read_numbers(df[j], lambda r, j=j: f"{path}: line {first_line + r}, column {j + 1} "
                                               f"({names[j]!r})")
            for j in cols[role]])
        values[role][cut] = np.nan  # a row cut short: its last field may be cut mid-number
        (lo, hi), unit = RAW_RANGES[role]
        v = values[role]
        bad = np.isfinite(v) & ((v < lo) | (v > hi))

        def message(i: int, n: int, v=v, role=role, lo=lo, hi=hi, unit=unit) -> str:
            r, c = np.unravel_index(i, v.shape)
            j = cols[role][c]
            more = f" ({n} such cell(s) in the file)" if n > 1 else ""
            return (f"{path}: line {first_line + r}, column {j + 1} ({names[j]!r}): "
                    f"{value_problem(float(v[r, c]), role, lo, hi, unit)}{more}")
        raise_first_bad(bad, message)
    return StaFile(
        path=path, dialect=dialect, header_size=n, header=header, header_lines=where, altitudes=alts,
        scan_angle=phi, end=end, lines=row_lines, values=values,
        columns={role: [j + 1 for j in js] for role, js in cols.items()},
        sha256=hashlib.sha256(raw).hexdigest(),
    )


def _same(files: list[StaFile], what: str, key: str, get) -> None:
    ref = files[0]
    for other in files[1:]:
        a, b = get(ref), get(other)
        if a != b:
            line_a, line_b = ref.line_of(key), other.line_of(key)
            written = f"{other.header_lines[key][1]}={other.get(key)}" if line_b else "key missing"
            raise InputError(
                f"{other.path}: line {line_b or f'2-{other.header_size + 1}'} ({written!r}): {what} {b!r} "
                f"differs from {a!r} in {ref.path} (line {line_a}); files joined along time must come "
                f"from one lidar with one configuration"
            )


#: Two cone angles closer than this (degree) are the same configuration (files write 2-3 decimals).
CONE_ANGLE_TOLERANCE = 0.01


def resolve_cone_angle(files: list[StaFile], cone_angle: float | None = None, *,
                       given_by: str = "--cone-angle") -> list[StaFile]:
    """Return ``files`` with every cone angle known: a header ``NA`` takes ``cone_angle``.

    WindCube firmware 2.x writes ``NA`` for internal header parameters (``ScanAngle (°)=NA``):
    such a file's cone angle is ``cone_angle`` (degree from vertical), and its
    ``scan_angle_source`` says ``given_by`` (the command-line option, or the certificate that
    supplied it); without one the file is refused with a message naming ``given_by``.  A file
    whose header states a number must agree with ``cone_angle`` when one is given (within
    :data:`CONE_ANGLE_TOLERANCE`): a file of another configuration is refused.  Never guessed.
    """
    out = []
    for f in files:
        line, key = f.header_lines["scanangle"]
        written = f"{key}={f.header[key]}"
        if f.scan_angle is None:
            if cone_angle is None:
                raise InputError(
                    f"{f.path}: line {line} ({written!r}): the file does not state the lidar's cone angle "
                    f"(WindCube firmware 2.x writes NA for internal parameters) and none was given; "
                    f"expected the configured cone angle from vertical in degrees: pass {given_by} DEGREES "
                    "(lidarcal never guesses it)")
            out.append(replace(f, scan_angle=float(cone_angle),
                               scan_angle_source=f"{given_by} (the file header says {f.header[key]!r})"))
            continue
        if cone_angle is not None and abs(f.scan_angle - float(cone_angle)) > CONE_ANGLE_TOLERANCE:
            raise InputError(
                f"{f.path}: line {line} ({written!r}): cone angle {f.scan_angle:g} degree differs from "
                f"{float(cone_angle):g} degree given by {given_by}; expected {float(cone_angle):g} degree "
                "(a file of another lidar configuration is refused)")
        out.append(f)
    return out


def read_sta_files(paths, *, allow_gaps: bool = False, cone_angle: float | None = None,
                   cone_angle_from: str = "--cone-angle") -> list[StaFile]:
    """Read several ``.sta`` files and check they can be joined along time (one lidar, one setup).

    ``cone_angle`` (degree) stands for a header's ``ScanAngle=NA`` and must match a stated one;
    ``cone_angle_from`` names where it came from in messages and attributes
    (:func:`resolve_cone_angle`).
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise InputError("no .sta file given")
    files = resolve_cone_angle([read_sta(p, allow_gaps=allow_gaps) for p in paths], cone_angle,
                               given_by=cone_angle_from)
    _same(files, "ID System (serial)", "idsystem", lambda f: f.serial)
    _same(files, "Altitudes", "altitudes", lambda f: f.altitudes.tolist())
    _same(files, "ScanAngle", "scanangle", lambda f: round(f.scan_angle, 2))
    seen: dict[np.datetime64, tuple[StaFile, int]] = {}
    for f in files:
        for t, line in zip(f.end, f.lines, strict=True):
            if t in seen:
                g, line0 = seen[t]
                raise InputError(
                    f"{f.path}: line {line}, column 1: duplicated timestamp (interval ending "
                    f"{pd.Timestamp(t)}) also in {g.path}, line {line0}"
                )
            seen[t] = (f, int(line))
    if len(files) > 1:
        owner = np.concatenate([np.full(f.end.size, k) for k, f in enumerate(files)])
        check_spacing(lambda k: files[owner[k]].path, np.concatenate([f.end for f in files]),
                      np.concatenate([f.lines for f in files]))
    return files
