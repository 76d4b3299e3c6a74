"""A ``field_campaign`` from WindCube ``.sta`` files and a met-mast CSV record.

The lidar's own 10-minute speed becomes ``lidar_wind_speed``; the mast's 10-minute mean at
the same height becomes ``reference_wind_speed``, matched on the interval **start** (mast
stamps marking the interval end are shifted back 10 minutes with ``timestamp="end"``).
The conditions to simulate are the mast's speed (``wind_speed``), the lidar's direction,
turbulence intensity from the mast's standard deviation where a std column is given for
that height (else from the lidar's dispersion), and shear exponent and CNR gradient from the
lidar's neighbouring altitudes (all of them, before keeping the mast heights).
"""

from __future__ import annotations

import io
import json
import os
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from lidarcal.conditions.formats import read_lidar_files
from lidarcal.conditions.readings import (
    DERIVED_LIMITS,
    PERIOD,
    RAW_RANGES,
    SENTINELS,
    read_numbers,
    set_missing_out_of_range,
    value_problem,
)
from lidarcal.conditions.sta import STA_COMMENTS, measured_conditions
from lidarcal.conditions.variables import variable_attrs
from lidarcal.errors import InputError, LidarcalError, MissingVariableError, raise_first_bad
from lidarcal.io import check_input_file
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.units import convert_values

__all__ = ["parse_height_columns", "read_reference_csv", "sta_field_campaign", "column_unit", "RATIO_LIMITS"]

#: Plausible range of the campaign's median lidar / reference speed ratio; outside it the mast
#: columns are almost certainly in another unit (km/h: 0.28) or the wrong columns.
RATIO_LIMITS = (0.8, 1.25)

#: Unit suffixes loggers append to column names (``Spd80mN_kmh``), lower case -> pint unit.
_SUFFIX_UNITS = {"kmh": "km/h", "kph": "km/h", "ms": "m/s", "mps": "m/s", "kn": "knot", "kt": "knot",
                 "kts": "knot", "knots": "knot", "mph": "mph"}


#: A timestamp's trailing UTC offset (``+01:00``, ``-0500``, ``Z``).
_OFFSET = r"((?:[+-]\d{2}:?\d{2}|Z|UTC|GMT)\s*)$"


def _parser_message(exc: BaseException) -> str:
    """Return pandas' tokenizer message with its line numbers (1-based file lines, the header is line 1)."""
    return str(exc).replace("C error: ", "").strip()


def column_unit(name: str) -> str | None:
    """Return the unit a column name declares (``Spd80 (km/h)``, ``Spd80 [m/s]``, ``Spd80_kmh``), or None."""
    m = re.search(r"[\(\[]\s*([^()\[\]]+?)\s*[\)\]]\s*$", name)
    if m:
        return m.group(1)
    m = re.search(r"_([A-Za-z]+)$", name)
    if m and m.group(1).lower() in _SUFFIX_UNITS:
        return _SUFFIX_UNITS[m.group(1).lower()]
    return None


def parse_height_columns(text: str, option: str = "--reference-columns") -> dict[float, str]:
    """``"80=Spd80mN,60=Spd60mN"`` -> ``{80.0: "Spd80mN", 60.0: "Spd60mN"}`` (height in m)."""
    out: dict[float, str] = {}
    for item in (t.strip() for t in str(text).split(",")):
        if not item:
            continue
        height, sep, column = item.partition("=")
        try:
            h = float(height)
        except ValueError:
            h = float("nan")
        if not sep or not column.strip() or not np.isfinite(h) or h <= 0:
            raise InputError(f"{option}: expected HEIGHT=COLUMN pairs like '80=Spd80mN'; found {item!r}")
        if h in out:
            raise InputError(f"{option}: height {h:g} m given twice")
        out[h] = column.strip()
    if not out:
        raise InputError(f"{option}: expected at least one HEIGHT=COLUMN pair; found {text!r}")
    return out


def _start_times(path: Path, cells: pd.Series, column: int, timestamp: str) -> np.ndarray:
    """Return the interval starts of a mast's time column (one UTC offset, parsable, no repeats)."""
    tcol = cells.name
    text = cells.astype(str).str.strip()
    offsets = text.str.extract(_OFFSET, expand=False).fillna("none")
    raise_first_bad((offsets != offsets.iloc[0]).to_numpy(), lambda r, n: (
        f"{path}: line {r + 2}, column {column} ({tcol!r}): timestamp {text.iloc[r]!r} "
        f"has UTC offset {offsets.iloc[r]!r} but line 2 has {offsets.iloc[0]!r}; expected one offset "
        f"throughout (a daylight-saving switch? convert the record to one clock, e.g. UTC, first)"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # format inference notices; unparsable cells are reported below
        try:
            times = pd.to_datetime(text, errors="coerce")
        except (ValueError, TypeError) as exc:  # mixtures pandas refuses even with errors="coerce"
            raise InputError(f"{path}: column {column} ({tcol!r}): timestamps cannot be "
                             f"read together: {exc}") from None
    raise_first_bad(times.isna().to_numpy(), lambda r, n: (
        f"{path}: line {r + 2}, column {column} ({tcol!r}): expected a timestamp; found {text.iloc[r]!r}"))
    start = times.to_numpy(dtype="datetime64[ns]") - (PERIOD if timestamp == "end" else np.timedelta64(0))
    _, first, counts = np.unique(start, return_index=True, return_counts=True)
    if (counts > 1).any():
        a = int(first[np.flatnonzero(counts > 1)[0]])
        b = int(np.flatnonzero(start == start[a])[1])
        raise InputError(
            f"{path}: line {b + 2}, column {column} ({tcol!r}): duplicated timestamp "
            f"{text.iloc[b]!r} (also line {a + 2})"
        )
    return start


def read_reference_csv(
    path: str | os.PathLike,
    columns: dict[float, str],
    std: dict[float, str] | None = None,
    *,
    timestamp: str = "start",
    time_column: str | None = None,
    units: str | None = None,
) -> tuple[np.ndarray, dict[float, np.ndarray], dict[float, np.ndarray], dict[str, str]]:
    """Read a mast CSV: interval-start times and the mean (and std) speed columns per height, in m s-1.

    A column's unit is the one its name declares (:func:`column_unit`), else ``units``
    (``--reference-units``), else m s-1; a name and ``units`` that disagree are refused.
    Missing values, sentinels (9999, -999), negative speeds and speeds beyond the physical
    range follow :mod:`lidarcal.conditions.readings`; refusals name the file, line and column.

    Returns
    -------
    (start times datetime64[ns], {height: mean speed}, {height: std}, {column: unit read})
    """
    path = Path(path)
    if timestamp not in ("start", "end"):
        raise InputError(f"--reference-timestamp: expected 'start' or 'end'; found {timestamp!r}")
    check_input_file(path, "mast CSV file")
    raw = path.read_bytes()
    try:
        content = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        content = raw.decode("latin-1")  # every byte is a Latin-1 character: cannot fail
    try:
        df = pd.read_csv(io.StringIO(content), dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        raise InputError(f"{path}: not a readable CSV table: {_parser_message(exc)}") from None
    names = list(df.columns)
    tcol = time_column or (names[0] if names else None)
    wanted = [tcol, *columns.values(), *(std or {}).values()]
    missing = [c for c in wanted if c not in names]
    if missing:
        raise MissingVariableError(f"{path}: column(s) {missing} not found; the file has {names}")
    start = _start_times(path, df[tcol], names.index(tcol) + 1, timestamp)

    used: dict[str, str] = {}

    def numbers(col: str, role: str) -> np.ndarray:
        number = names.index(col) + 1
        where = f"{path}: column {number} ({col!r})"
        values = read_numbers(df[col], lambda r: f"{path}: line {r + 2}, column {number} ({col!r})")
        sentinel = np.isin(values, SENTINELS)
        declared = column_unit(col)
        if declared and units and not _same_unit(declared, units):
            raise InputError(f"{where}: the column name declares {declared!r} but --reference-units is "
                             f"{units!r}")
        unit = declared or units or "m/s"
        used[col] = unit
        try:
            converted = convert_values(np.where(sentinel, np.nan, values), unit, "m s-1", where=where)
        except LidarcalError as exc:
            raise InputError(f"{exc} (--reference-units or the unit in the column name)") from None
        (lo, hi), _ = RAW_RANGES[role]
        bad = sentinel | (np.isfinite(converted) & ((converted < lo) | (converted > hi)))

        def message(r: int, n: int) -> str:
            v = float(values[r])
            if sentinel[r] or v < 0:
                problem = value_problem(v, role, lo, hi, unit)
            else:
                problem = (f"{v:g} {unit} = {converted[r]:.4g} m/s is outside the physical range "
                           f"[{lo:g}, {hi:g}] m/s")
                if unit == "m/s" and v <= 360 and role == "speed":
                    problem += " (a wind direction? are the column names swapped?)"
            return f"{path}: line {r + 2}, column {number} ({col!r}): {problem}"
        raise_first_bad(bad, message)
        return converted

    means = {h: numbers(c, "speed") for h, c in columns.items()}
    stds = {h: numbers(c, "dispersion") for h, c in (std or {}).items()}
    return start, means, stds, used


def _same_unit(a: str, b: str) -> bool:
    try:
        return bool(np.isclose(convert_values([1.0], a, "m s-1", where="unit"),
                               convert_values([1.0], b, "m s-1", where="unit")).all())
    except LidarcalError:
        return False


def _match_heights(heights: list[float], altitudes: np.ndarray, option: str, source: str) -> list[int]:
    idx, absent = [], []
    for h in heights:
        hit = np.flatnonzero(np.isclose(altitudes, h, rtol=0, atol=1e-6))
        if hit.size:
            idx.append(int(hit[0]))
        else:
            absent.append(h)
    if absent:
        raise InputError(
            f"{option}: mast height(s) {[f'{h:g}' for h in absent]} m are not among the lidar's altitudes "
            f"{[f'{a:g}' for a in altitudes]} m ({source})"
        )
    return idx


def _median_ratio(lidar_speed: np.ndarray, ref: np.ndarray, check: bool, used: dict[str, str],
                  columns: dict[float, str], reference, source: str) -> float:
    """Median lidar / reference speed ratio; refuse an implausible one (a unit or column mix-up)."""
    both = np.isfinite(lidar_speed) & np.isfinite(ref) & (ref > 0)
    ratio = float(np.median(lidar_speed[both] / ref[both])) if both.any() else float("nan")
    lo, hi = RATIO_LIMITS
    if check and np.isfinite(ratio) and not lo <= ratio <= hi:
        read = ", ".join(f"{c!r} in {u}" for c, u in used.items() if c in columns.values())
        raise InputError(
            f"{reference}: the median lidar / reference wind speed ratio is {ratio:.3f} over "
            f"{int(both.sum())} matched period-heights (lidar {source}), outside the plausible "
            f"[{lo:g}, {hi:g}]; mast columns read as {read}. Is the mast in another unit (give "
            f"--reference-units, e.g. km/h) or are these the wrong columns? --skip-ratio-check accepts "
            f"the campaign as it is"
        )
    return ratio


def _matcher(times: np.ndarray, start: np.ndarray, reference, timestamp: str):
    """Return a function putting a mast series on the lidar's ``times`` (NaN where the mast has none)."""
    pos = pd.Index(start).get_indexer(pd.Index(times))
    found = pos >= 0
    if not found.any():
        raise InputError(
            f"{reference}: no mast interval start matches a lidar interval start (lidar "
            f"{pd.Timestamp(times.min())} .. {pd.Timestamp(times.max())}, mast "
            f"{pd.Timestamp(start.min())} .. {pd.Timestamp(start.max())}, --reference-timestamp {timestamp})"
        )
    return lambda series: np.where(found, series[np.clip(pos, 0, None)], np.nan)


def _comments(altitudes: np.ndarray, columns: dict[float, str], std: dict[float, str]) -> dict[str, str]:
    """Return the comments of a field campaign's conditions variables (the mast's part in them)."""
    ti_source = {f"{h:g}": f"mast {std[h]} / {columns[h]}" if h in std
                 else "lidar speed dispersion / lidar speed" for h in sorted(columns)}
    return {
        "wind_speed": "mast 10-minute mean (the reference): the conditions to simulate",
        "turbulence_intensity": "per height: " + json.dumps(ti_source),
        "wind_shear_exponent": STA_COMMENTS["wind_shear_exponent"] + " of the lidar's altitudes "
                               + str([float(a) for a in np.sort(altitudes)]),
        "cnr_gradient": STA_COMMENTS["cnr_gradient"] + "; neighbours among the lidar's altitudes",
    }


def sta_field_campaign(
    sta_paths,
    reference: str | os.PathLike,
    columns: dict[float, str],
    std: dict[float, str] | None = None,
    *,
    timestamp: str = "start",
    time_column: str | None = None,
    min_availability: float = 80.0,
    allow_gaps: bool = False,
    units: str | None = None,
    check_ratio: bool = True,
    cone_angle: float | None = None,
    call: str | None = None,
) -> xr.Dataset:
    """Build a stamped ``field_campaign`` artefact (``docs/contracts.md``) from ``.sta`` files and a mast CSV.

    Parameters
    ----------
    sta_paths : sequence of path
        The lidar's ``.sta`` files (see :func:`~lidarcal.conditions.sta.sta_conditions`).
    reference : path
        Mast CSV with a time column and one mean-speed column per height (m s-1).
    columns, std : dict of height (m) -> column name
        Mean speed columns and, optionally, their standard deviations (for TI).
    timestamp : {"start", "end"}
        Whether the mast's stamps mark the interval start or end.
    time_column : str, optional
        The mast's time column (default: the first column).
    min_availability : float
        Lidar data availability (%) a period needs at a height.
    allow_gaps : bool
        Read ``.sta`` rows cut short as missing periods (warning) instead of refusing.
    units : str, optional
        Unit of the mast's speed columns (``"km/h"``, ``"knot"``, any pint unit of speed) where
        the column name declares none; default m s-1.
    check_ratio : bool
        Refuse a campaign whose median lidar / reference speed ratio is outside
        :data:`RATIO_LIMITS` (a unit or column mix-up); False records the ratio only.
    cone_angle : float, optional
        The lidar's cone angle (degree from vertical) where a file's header says ``NA``
        (``--cone-angle``; :func:`~lidarcal.conditions.stafile.resolve_cone_angle`).
    call : str, optional
        What produced it, for the provenance (default: this function).

    Returns
    -------
    xarray.Dataset
        On (time, height) at the mast heights (ascending), lidar times, with lidarcal's provenance.
    """
    sta_paths, std = list(sta_paths), dict(std or {})
    extra = [h for h in std if h not in columns]
    if extra:
        raise InputError(
            f"--reference-std: height(s) {[f'{h:g}' for h in extra]} m have no mean column in "
            f"--reference-columns ({[f'{h:g}' for h in columns]} m)"
        )
    files = read_lidar_files(sta_paths, allow_gaps=allow_gaps, cone_angle=cone_angle)
    cond = measured_conditions(files, min_availability, warn=False,
                               comments=_comments(files[0].altitudes, columns, std))
    source = ", ".join(Path(p).name for p in sta_paths)
    heights = sorted(columns)
    idx = _match_heights(heights, cond.height.values, "--reference-columns", source)
    start, means, stds, used = read_reference_csv(reference, columns, std, timestamp=timestamp,
                                                  time_column=time_column, units=units)
    on_lidar_times = _matcher(cond.time.values, start, reference, timestamp)
    ref = np.column_stack([on_lidar_times(means[h]) for h in heights])
    out = cond.isel(height=idx)
    lidar_speed = out["wind_speed"].values
    ratio = _median_ratio(lidar_speed, ref, check_ratio, used, columns, reference, source)
    ti = out["turbulence_intensity"].values.copy()
    for k, h in enumerate(heights):
        if h in stds:
            with np.errstate(divide="ignore", invalid="ignore"):
                ti[:, k] = np.where(ref[:, k] > 0, on_lidar_times(stds[h]) / ref[:, k], np.nan)
    vals = {"turbulence_intensity": ti}
    dropped = set_missing_out_of_range(vals, {"turbulence_intensity": DERIVED_LIMITS["turbulence_intensity"]})
    dims = ("time", "height")
    out["wind_speed"] = (dims, ref, dict(out["wind_speed"].attrs))
    out["turbulence_intensity"] = (dims, vals["turbulence_intensity"],
                                   dict(out["turbulence_intensity"].attrs))
    out["lidar_wind_speed"] = (dims, lidar_speed, variable_attrs(
        "lidar_wind_speed", comment="the .sta file's speed column; missing below the availability threshold"))
    out["reference_wind_speed"] = (dims, ref, variable_attrs(
        "reference_wind_speed",
        comment=f"mast CSV {Path(reference).name}, columns "
                f"{json.dumps({f'{h:g}': columns[h] for h in heights})} (read in "
                f"{json.dumps({columns[h]: used[columns[h]] for h in heights})}, converted to m s-1), "
                f"matched on interval start"))
    lo, hi = RATIO_LIMITS
    out.attrs.update({
        "reference_file": Path(reference).name,
        "reference_columns": json.dumps({f"{h:g}": columns[h] for h in heights}),
        "reference_std_columns": json.dumps({f"{h:g}": std[h] for h in sorted(std)}),
        "reference_timestamp": timestamp,
        "reference_units_read": json.dumps(used),
        "lidar_reference_median_ratio": ratio,
        "lidar_reference_ratio_checked": f"{'yes' if check_ratio else 'no (--skip-ratio-check)'}: plausible "
                                         f"range [{lo:g}, {hi:g}]",
        "reference_matched_periods": int(np.isfinite(ref).any(axis=1).sum()),
        "sta_out_of_range_set_missing": json.dumps(
            {**json.loads(cond.attrs["sta_out_of_range_set_missing"]), **{f"mast {k}": v for k, v in
                                                                         dropped.items()}}),
        "license": "not specified: the licences of the source .sta files and mast record apply",
    })
    config = {"files": [str(p) for p in sta_paths], "reference": str(reference),
              "columns": {f"{h:g}": c for h, c in columns.items()},
              "std": {f"{h:g}": c for h, c in std.items()},
              "timestamp": timestamp, "time_column": time_column, "min_availability": float(min_availability),
              "allow_gaps": bool(allow_gaps), "units": units, "check_ratio": bool(check_ratio),
              "cone_angle": cone_angle}
    return stamp(
        out, "field_campaign",
        title=(f"Field campaign: WindCube {read_attr(out, 'lidar_serial', kind='field_campaign')} "
               "against a met mast"),
        summary=f"{out.sizes['time']} ten-minute periods at {out.sizes['height']} mast heights: lidar speed "
                f"from {len(sta_paths)} .sta file(s), reference speed from {out.attrs['reference_file']}.",
        call=call or "lidarcal.conditions.mast.sta_field_campaign(...)",
        inputs={**{f"sta_{k}": p for k, p in enumerate(sta_paths, start=1)}, "reference": reference},
        config=config,
    )
