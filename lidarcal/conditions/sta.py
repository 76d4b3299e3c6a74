"""WindCube ``.sta`` files into a ``conditions`` input (the format: :mod:`lidarcal.conditions.stafile`).

Conventions of :func:`sta_conditions`: ``time`` is the interval start (the end-of-interval
stamp minus 10 minutes) with CF ``time_bounds``; TI = speed dispersion / speed; a period whose
data availability at a height is below ``min_availability`` (%) is missing (NaN) at that
height; ``cnr_gradient`` is the gradient *along the beam*, ``dCNR/ds = dCNR/dz · cos φ``
(φ the file's scan angle from vertical), from neighbouring heights, and the shear exponent
uses the same neighbours (:mod:`lidarcal.conditions.kernels`).  Derived values outside the
contract's range are set missing (:func:`lidarcal.conditions.readings.set_missing_out_of_range`).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import xarray as xr

from lidarcal.conditions.formats import read_lidar_files
from lidarcal.conditions.kernels import shear_exponent, vertical_gradient
from lidarcal.conditions.readings import DERIVED_LIMITS, PERIOD, set_missing_out_of_range
from lidarcal.conditions.stafile import ROLES, StaFile
from lidarcal.conditions.synthetic import conditions_dataset
from lidarcal.errors import InputError
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs

__all__ = ["STA_COMMENTS", "measured_conditions", "sta_attributes", "sta_conditions"]

#: How each conditions variable is obtained from ``.sta`` columns (its ``comment`` attribute).
STA_COMMENTS = {
    "wind_speed": "lidar 10-minute mean horizontal wind speed (.sta speed column)",
    "wind_from_direction": "lidar 10-minute mean wind direction (.sta direction column)",
    "turbulence_intensity": "speed dispersion / speed (.sta dispersion and speed columns)",
    "wind_shear_exponent": "ln(U_b/U_a)/ln(z_b/z_a) between the neighbouring heights (Eq. 10)",
    "cnr": "measured carrier-to-noise ratio (.sta mean CNR column)",
    "cnr_gradient": "along the beam: finite difference between neighbouring heights times cos(scan "
                    "angle), dCNR/ds = dCNR/dz cos(phi)",
}


def _joined(files: list[StaFile], min_availability: float):
    order_h = np.argsort(files[0].altitudes, kind="stable")
    z = files[0].altitudes[order_h]
    end = np.concatenate([f.end for f in files])
    order_t = np.argsort(end, kind="stable")
    vals = {r: np.concatenate([f.values[r] for f in files])[order_t][:, order_h] for r in ROLES}
    avail = vals["availability"]
    low = ~(avail >= float(min_availability))  # NaN availability counts as unavailable
    for role in ("speed", "dispersion", "direction", "cnr"):
        vals[role] = np.where(low, np.nan, vals[role])
    return z, end[order_t], vals, low


def sta_attributes(files: list[StaFile], min_availability: float) -> dict:
    """Global attributes describing the lidar and the source files (serial, site, GPS, SHA-256 ...)."""
    first = files[0]
    serial = first.serial
    cnr_thr = first.get("cnrthreshold")
    try:
        cnr_thr_value: float | str | None = float(cnr_thr) if cnr_thr is not None else None
    except ValueError:
        cnr_thr_value = cnr_thr
    attrs = {
        "lidar_cone_angle": float(first.scan_angle),
        "lidar_scan_angle": float(first.scan_angle),
        "lidar_cone_angle_source": first.scan_angle_source,
        "lidar_serial": serial or "not given",
        "lidar_site": first.get("location", "localisation") or "not given",
        "lidar_gps_location": first.get("gpslocation", "gpslocalisation") or "not given",
        "lidar_cnr_threshold": cnr_thr_value if cnr_thr_value is not None else "not given",
        "lidar_firmware_version": first.get("version") or "not given",
        "lidar_timezone": first.get("timezone") or "not given in the file header",
        "instrument": f"WindCube pulsed Doppler wind lidar, ID System {serial or 'not given'}",
        "sta_dialect": first.dialect,
        "sta_min_availability": float(min_availability),
        "sta_files": json.dumps([
            {"file": f.path.name, "sha256": f.sha256, "dialect": f.dialect, "rows": int(f.end.size),
             "first_interval_end": str(pd.Timestamp(f.end.min())),
             "last_interval_end": str(pd.Timestamp(f.end.max()))}
            for f in files
        ]),
        "sta_header": json.dumps(first.header, ensure_ascii=False),
    }
    diffs = {f.path.name: {k: v for k, v in f.header.items() if first.header.get(k) != v} for f in files[1:]}
    diffs = {k: v for k, v in diffs.items() if v}
    if diffs:
        attrs["sta_header_differences"] = json.dumps(diffs, ensure_ascii=False)
    return attrs


def _time_bounds(ds: xr.Dataset, end: np.ndarray) -> xr.Dataset:
    bounds = np.stack([end - PERIOD, end], axis=-1).astype("datetime64[ns]")
    ds = ds.assign_coords(time_bounds=(("time", "nv"), bounds, {"long_name": "10-minute interval bounds"}))
    ds["time"].attrs["bounds"] = "time_bounds"
    # one explicit encoding for time and its bounds (CF: bounds share the coordinate's units)
    ds["time"].encoding.update(units="minutes since 1970-01-01 00:00:00", calendar="proleptic_gregorian")
    tz = read_attr(ds, "lidar_timezone", kind="conditions").replace(" ", "").upper()
    if tz not in ("UTC", "UTC+0", "UTC+00", "UTC+00:00", "UTC-0", "GMT"):
        ds["time"].attrs["long_name"] = "start of 10-minute period (lidar clock time, see comment)"
    ds["time"].attrs["comment"] = (
        "interval start = the .sta file's end-of-interval timestamp minus 10 minutes, in the lidar "
        "clock's time zone (header 'timezone': "
        f"{read_attr(ds, 'lidar_timezone', kind='conditions', default='not given')})"
    )
    return ds


def measured_conditions(files: list[StaFile], min_availability: float = 80.0, *, warn: bool = True,
                        comments: dict[str, str] | None = None) -> xr.Dataset:
    """Return the conditions of parsed ``.sta`` files (:func:`~lidarcal.conditions.stafile.read_sta_files`).

    What :func:`sta_conditions` stamps and a field campaign builds on (not yet stamped);
    ``comments`` overrides entries of :data:`STA_COMMENTS`.
    """
    if not 0 <= float(min_availability) <= 100:
        raise InputError(f"--min-availability: expected a percentage in [0, 100]; found {min_availability}")
    z, end, vals, low = _joined(files, min_availability)
    speed = vals["speed"]
    cos_phi = np.cos(np.radians(files[0].scan_angle))
    with np.errstate(divide="ignore", invalid="ignore"):
        ti = np.where(speed > 0, vals["dispersion"] / speed, np.nan)
    out = {
        "wind_speed": speed,
        "wind_from_direction": vals["direction"],
        "turbulence_intensity": ti,
        "wind_shear_exponent": shear_exponent(speed, z),
        "cnr": vals["cnr"],
        "cnr_gradient": vertical_gradient(vals["cnr"], z) * cos_phi,
    }
    dropped = set_missing_out_of_range(out, DERIVED_LIMITS)
    if dropped and warn:
        warnings.warn(
            f"{files[0].path}{' ...' if len(files) > 1 else ''}: derived values outside the conditions "
            f"contract's range set missing: {dropped}",
            UserWarning,
            stacklevel=3,
        )
    attrs = sta_attributes(files, min_availability)
    attrs["sta_out_of_range_set_missing"] = json.dumps(dropped)
    attrs["sta_below_availability_count"] = int(low.sum())
    ds = conditions_dataset(end - PERIOD, z, out, attrs, content="physicalMeasurement",
                            comments={**STA_COMMENTS, **(comments or {})})
    ds["data_availability"] = (("time", "height"), vals["availability"], output_attrs(
        "conditions", "data_availability", min_availability=f"{float(min_availability):g}"))
    ds = _time_bounds(ds, end)
    ds.attrs["time_coverage_start"] = str(pd.Timestamp(end.min() - PERIOD).isoformat())
    ds.attrs["time_coverage_end"] = str(pd.Timestamp(end.max()).isoformat())
    return ds


def sta_conditions(paths, min_availability: float = 80.0, *, warn: bool = True,
                   allow_gaps: bool = False, cone_angle: float | None = None,
                   cone_angle_from: str = "--cone-angle", call: str | None = None) -> xr.Dataset:
    """Read ``.sta`` files (one lidar) into a stamped ``conditions`` artefact (``docs/contracts.md``).

    Parameters
    ----------
    paths : sequence of path
        One or more ``.sta`` files of either dialect; joined along time (sorted).
    min_availability : float
        Data availability (%) a period needs at a height; below it every variable is NaN there.
    warn : bool
        Warn when derived values outside the contract's range are set missing.
    allow_gaps : bool
        Read rows cut short as missing periods (with a warning naming them) instead of refusing.
    cone_angle : float, optional
        The lidar's cone angle (degree from vertical) where a file's header says ``NA``
        (firmware 2.x); a file stating another one is refused
        (:func:`~lidarcal.conditions.stafile.resolve_cone_angle`).  Where it came from
        (``cone_angle_from``, default the option ``--cone-angle``) is the attribute
        ``lidar_cone_angle_source``.
    call : str, optional
        What produced it, for the provenance (default: this function).

    Returns
    -------
    xarray.Dataset
        The six contract variables on (time, height) plus ``data_availability`` (%) and
        ``time_bounds``; global attributes from :func:`sta_attributes` and the provenance.
    """
    paths = list(paths)
    files = read_lidar_files(paths, allow_gaps=allow_gaps, cone_angle=cone_angle,
                             cone_angle_from=cone_angle_from)
    ds = measured_conditions(files, min_availability, warn=warn)
    ds.attrs["license"] = "not specified: the licence of the source .sta files applies"
    return stamp(
        ds, "conditions",
        title=("Measured 10-minute conditions from WindCube "
               f"{read_attr(ds, 'lidar_serial', kind='conditions')}"),
        summary=f"{ds.sizes['time']} ten-minute periods at {ds.sizes['height']} heights read from "
                f"{len(paths)} WindCube .sta file(s); CNR and CNR gradient measured; periods below "
                f"{float(min_availability):g} % availability missing.",
        call=call or "lidarcal.conditions.sta.sta_conditions(...)",
        inputs={f"sta_{k}": p for k, p in enumerate(paths, start=1)},
        config={"files": [str(p) for p in paths], "min_availability": float(min_availability),
                "allow_gaps": bool(allow_gaps), "cone_angle": cone_angle},
    )
