"""Ingest a bench run (lidar RTD + SAFO-MV control log) into the ℓcv-bin ``bench_cube``.

Steps (paper §2.1, §3.1), all vectorised:

1. every RTD record is matched to the programmed bin whose ``[start, end)`` contains its
   timestamp (``np.searchsorted``); records outside every bin are dropped;
2. transition records are removed: those within ``settling_time`` (default 5 s) of their
   bin's start — the lidar still reports the previous or a mixed state for about
   latency + one record (≈ 3 s on a WindCube) — and those whose LOS is not the one the
   bench feeds in that bin (the lidar keeps scanning DBS; the other beams see no signal);
3. bad estimates are rejected per ℓcv-bin by a documented rule: by default
   ``|r − median(r)| > k · max(1.4826 · MAD(r), min_scale)`` with ``r`` = measured −
   programmed, ``k = 4``, ``min_scale = 0.005 m/s``.  The median and MAD stay robust while
   fewer than half the samples are bad; a good Gaussian sample is lost with probability
   6e-5 and the std is lowered by 0.05 %.  Bad estimates that happen to fall inside the
   window stay: with the default simulated lidar they inflate s by ~1 % at −22 dB, ~7 % at
   −26 dB and ~70 % at −28 dB (where 40 % of estimates are bad) — real bench cubes show the
   same rise.  Alternatives: a fixed threshold ``|r| > outlier_threshold`` or no rejection.
   Rejections are counted per bin (``outlier_count``) and in total;
4. per (LOS, CNR, velocity) bin: δ = mean(r) (``los_bias``), s = std(r, ddof=1)
   (``los_std``; with one programmed value per bin, the std of the measured velocity) and N
   (``sample_count``);
5. every candidate residual ``r`` of the bin, *before* step 3 (bad estimates included), in
   time order along a ``sample`` dimension padded with NaN (``los_residual``): the virtual
   lidar resamples them so that bad estimates enter the simulation with their measured
   frequency (``docs/contracts.md``, bench cube).  Steps 3-4 do not see this variable, so
   ``los_bias`` and ``los_std`` are what they were without it.

Programmed values are assigned to the Table 1 grid node they are nearest (bins of ±1 dB,
±0.5 m/s); several control rows in the same bin are pooled.

Before binning, the two files must describe the same run (:func:`check_agreement`): every
programmed bin's settled window holds RTD records (at least half as many as the RTD's record
rate implies) including some of the fed LOS if it spans two scan cycles, and per bin the median of measured −
programmed velocity is within ``max(0.5 m/s, 4 · 1.4826 · MAD, 5 · 1.2533 · σ / √n)``, σ the
robust spread pooled over the bins of the same LOS and CNR.  0.5 m/s is half the
Table 1 velocity step: a median further off lies nearer a neighbouring programmed velocity,
which is what a control log shifted or with another bin length against the RTD produces; a
lidar that biased would sort its records into the wrong velocity bins anyway.  The ``4 ·
robust σ`` term (the multiple of the outlier rule) lets through bins dominated by bad
estimates (40 % at −28 dB), whose median means little; the last term is 5 standard errors of
a median of n records (a good bin is refused with probability 6e-7, 1e-3 for a 2220-bin run),
which matters for short bins.  Bins give no verdict when they have fewer than 5 records or
when the noise of their LOS and CNR (robust σ of successive records) exceeds 0.25 m/s, a quarter
velocity step: such bins cannot tell neighbouring programmed velocities apart, and at low CNR
(40 % bad estimates at −28 dB) two or three bad estimates that happen to fall close together
would outvote the good ones (simulated 20-s runs, 3 or 4 records a bin, were refused for
that in 9 of 12 seeds before this rule; none of 16 seeds of 20-s and 60-s runs is refused
now).  On the sample run 1665 of 2220 bins are judged (CNR >= -22 dB) and the largest
|median| / tolerance is 0.33; a 30-s control log against the sample's 60-s RTD fails in 251 of
its 259 judged bins, from the first LOS-0 bins on.
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.bench import kernels
from lidarcal.bench.formats import ControlLog, RtdTable, read_control_log, read_rtd
from lidarcal.bench.grid import (
    CNR_EDGES,
    CNR_NODES,
    LOS_AZIMUTH,
    LOS_ELEVATION,
    LOS_LABELS,
    VELOCITY_EDGES,
    VELOCITY_NODES,
    grid_index,
)
from lidarcal.binning import group_statistics
from lidarcal.cf import iso_utc, with_bounds
from lidarcal.errors import InputError, raise_first_bad
from lidarcal.provenance import stamp
from lidarcal.schema import output_attrs
from lidarcal.units import to_magnitude

__all__ = ["ingest", "build_cube", "cube_template", "check_agreement", "OUTLIER_RULES"]

OUTLIER_RULES = ("mad", "fixed", "none")
_SHAPE = (len(LOS_LABELS), len(CNR_NODES), len(VELOCITY_NODES))
#: Agreement of the RTD with the control log (module docstring): floor of the tolerance on the
#: per-bin median of measured - programmed (half the Table 1 velocity step, m s-1), multiple of
#: the robust spread, fewest records for a verdict, least fraction of the expected RTD records.
AGREEMENT_FLOOR = 0.5 * float(np.min(np.diff(VELOCITY_NODES)))
AGREEMENT_K = 4.0
AGREEMENT_Z = 5.0
AGREEMENT_MIN_RECORDS = 5
AGREEMENT_MAX_NOISE = 0.5 * AGREEMENT_FLOOR
COVERAGE_MIN_FRACTION = 0.5


def cube_template() -> xr.Dataset:
    """Empty ℓcv grid with the ``bench_cube`` coordinates (los, cnr, velocity) and bounds."""
    values = {"los": ("los", np.asarray(LOS_LABELS, dtype=object)), "los_azimuth": ("los", LOS_AZIMUTH),
              "los_elevation": ("los", LOS_ELEVATION), "cnr": ("cnr", CNR_NODES),
              "velocity": ("velocity", VELOCITY_NODES)}
    ds = xr.Dataset(coords={name: (dim, data, output_attrs("bench_cube", name))
                            for name, (dim, data) in values.items()})
    ds = with_bounds(ds, "cnr", CNR_EDGES)
    ds = with_bounds(ds, "velocity", VELOCITY_EDGES)
    return ds


def _cells(control: ControlLog) -> np.ndarray:
    ci, vi = grid_index(control.cnr, CNR_EDGES), grid_index(control.velocity, VELOCITY_EDGES)
    names = {"cnr": "programmed_cnr_dB", "velocity": "programmed_velocity_m_s", **control.columns}
    checks = ((names["cnr"], ci, control.cnr, CNR_EDGES, "dB"),
              (names["velocity"], vi, control.velocity, VELOCITY_EDGES, "m s-1"))
    for name, idx, values, edges, unit in checks:
        raise_first_bad(idx < 0, functools.partial(_off_grid, control.source, name, values, edges, unit))
    return np.ravel_multi_index((control.los, ci, vi), _SHAPE)


def _off_grid(source: str, name: str, values: np.ndarray, edges: np.ndarray, unit: str, i: int,
              n: int) -> str:
    """Say that row ``i``, the first of ``n``, is outside the Table 1 grid."""
    return (f"{source}: control log column {name!r} row {i + 1} is {values[i]:g} {unit} "
            f"(after unit conversion); "
            f"expected values within the Table 1 grid [{edges[0]:g}, {edges[-1]:g}) {unit}")


def _bin_name(control: ControlLog, i: int) -> str:
    return (f"row {i + 1} ({iso_utc(control.start_ns[i], 'ms')} to {iso_utc(control.end_ns[i], 'ms')}, "
            f"LOS {LOS_LABELS[control.los[i]]}, programmed CNR {control.cnr[i]:g} dB, "
            f"programmed velocity {control.velocity[i]:g} m s-1)")


def check_agreement(rtd: RtdTable, control: ControlLog, bin_idx: np.ndarray, status: np.ndarray,
                    settling_ns: int, row_of_bin: np.ndarray | None = None) -> None:
    """Refuse an RTD and a control log that do not describe the same run (module docstring).

    ``bin_idx`` and ``status`` are :func:`lidarcal.bench.kernels.match_to_bins`'s answer;
    ``row_of_bin`` groups the bins whose noise is alike (same LOS and programmed CNR; default:
    each bin alone) for the pooled spread of the median's sampling term.  The message names
    both files, the first disagreeing bin (row, time, LOS, CNR, velocity), what was expected
    and what was found, and how many bins disagree.
    """
    n_bins = len(control)
    both = f"{rtd.source} (RTD) and {control.source} (control log)"
    # coverage: records of any beam in each bin's settled window, against the RTD's record rate
    t = rtd.time_ns
    lo = np.searchsorted(t, np.minimum(control.start_ns + settling_ns, control.end_ns), side="left")
    n_in = np.searchsorted(t, control.end_ns, side="left") - lo
    dt = float(np.median(np.diff(t))) if len(t) > 1 else np.inf
    expected = (control.end_ns - control.start_ns - settling_ns) / dt
    uncovered = n_in < np.floor(COVERAGE_MIN_FRACTION * expected)  # under 2 records expected: no verdict
    raise_first_bad(uncovered, lambda i, n: (
        f"{both} do not describe the same run: the RTD does not cover the programmed bin "
        f"{_bin_name(control, i)}; expected about {max(expected[i], 0):.0f} RTD records (one per "
        f"{dt / 1e9:.3g} s) after the {settling_ns / 1e9:g} s settling time, found {int(n_in[i])}; "
        f"{n} of {n_bins} bins are not covered (RTD from {iso_utc(t[0], 'ms')} to "
        f"{iso_utc(t[-1], 'ms')})"))
    cand = np.flatnonzero(status == kernels.USED)
    group = bin_idx[cand]
    residual = rtd.velocity[cand] - control.velocity[group]
    count, median, scale = kernels.robust_location(residual, group, n_bins)
    rows = np.arange(n_bins) if row_of_bin is None else np.asarray(row_of_bin)
    n_rows = int(rows.max()) + 1
    # spread of alike bins from successive records of a bin: unbiased even with 2 or 3 records a bin
    # (deviations from a 3-record median are not), robust to bad estimates through the median
    same = group[1:] == group[:-1]
    step = np.abs(np.diff(residual))[same]
    pooled = 1.4826 / np.sqrt(2) * kernels.group_median(step, rows[group[1:][same]], n_rows)[rows]
    with np.errstate(divide="ignore", invalid="ignore"):
        sampling = AGREEMENT_Z * 1.2533 * np.nan_to_num(pooled) / np.sqrt(count)  # SE of a median
    tolerance = np.maximum.reduce([np.full(n_bins, AGREEMENT_FLOOR), AGREEMENT_K * np.nan_to_num(scale),
                                   np.nan_to_num(sampling)])
    # a verdict only where the lidar resolves the velocity grid (noise of alike bins <= a quarter step)
    # and enough records can outvote bad estimates
    judged = (count >= AGREEMENT_MIN_RECORDS) & (np.nan_to_num(pooled, nan=np.inf) <= AGREEMENT_MAX_NOISE)
    off = judged & (np.abs(median) > tolerance)
    # a scanning lidar visits each of its beams once per cycle: two full cycles without the fed
    # beam cannot be a matter of phase
    n_beams = len(np.unique(rtd.los))
    no_los = (count == 0) & (n_in >= 2 * n_beams)

    def message(i: int, n: int) -> str:
        if no_los[i]:
            found = (f"none of its {int(n_in[i])} RTD records is of LOS {LOS_LABELS[control.los[i]]} "
                     "(the beam the bench feeds)")
            expected_txt = "records of the fed LOS"
        else:
            found = (f"median measured velocity {control.velocity[i] + median[i]:.3f} m s-1 over "
                     f"{int(count[i])} records (measured - programmed {median[i]:+.3f} m s-1)")
            expected_txt = (f"measured - programmed within +-{tolerance[i]:.3g} m s-1 (max of "
                            f"{AGREEMENT_FLOOR:g} m s-1, {AGREEMENT_K:g} x the bin's robust spread "
                            f"{scale[i]:.3g} m s-1 and {AGREEMENT_Z:g} standard errors of its median)")
        return (f"{both} do not describe the same run (another bin length, start or LOS order?): programmed "
                f"bin {_bin_name(control, i)}: expected {expected_txt}, found {found}; {n} of {n_bins} "
                "bins disagree")
    raise_first_bad(off | no_los, message)


def build_cube(
    rtd: RtdTable,
    control: ControlLog,
    *,
    settling_s: float = 5.0,
    outlier_rule: str = "mad",
    outlier_k: float = 4.0,
    outlier_threshold: float = 3.0,
    min_scale: float = 0.005,
) -> tuple[xr.Dataset, dict[str, int]]:
    """Bin matched RTD samples into the ℓcv cube; SI floats in, un-stamped Dataset and counts out."""
    if outlier_rule not in OUTLIER_RULES:
        raise InputError(f"outlier rule {outlier_rule!r} is unknown; expected one of {list(OUTLIER_RULES)}")
    if rtd.lidar_serial != control.metadata.get("lidar_serial"):
        raise InputError(
            f"{rtd.source}: lidar_serial is {rtd.lidar_serial!r} but {control.source} declares "
            f"lidar_serial {control.metadata.get('lidar_serial')!r}; they must be the same lidar")
    span_ok = (rtd.time_ns[-1] >= control.start_ns[0]) and (rtd.time_ns[0] < control.end_ns[-1])
    if not span_ok:
        raise InputError(
            f"{control.source}: the control log ({iso_utc(control.start_ns[0])} to "
            f"{iso_utc(control.end_ns[-1])}) does not overlap the RTD in {rtd.source} "
            f"({iso_utc(rtd.time_ns[0])} to {iso_utc(rtd.time_ns[-1])})")
    cell_of_bin = _cells(control)
    n_cells = int(np.prod(_SHAPE))
    settling_ns = round(settling_s * 1e9)
    bin_idx, status = kernels.match_to_bins(rtd.time_ns, rtd.los, control.start_ns, control.end_ns,
                                            control.los, settling_ns)
    check_agreement(rtd, control, bin_idx, status, settling_ns, cell_of_bin // len(VELOCITY_NODES))
    cand = np.flatnonzero(status == kernels.USED)
    cell = cell_of_bin[bin_idx[cand]]
    residual = rtd.velocity[cand] - control.velocity[bin_idx[cand]]
    keep = kernels.reject_outliers(residual, cell, n_cells, rule=outlier_rule, k=outlier_k,
                                   threshold=outlier_threshold, min_scale=min_scale)
    status[cand[~keep]] = kernels.REJECTED
    count, mean, std = group_statistics(residual[keep], cell[keep], n_cells)
    _, cnr_mean, _ = group_statistics(rtd.cnr[cand][keep], cell[keep], n_cells)
    rejected = np.bincount(cell[~keep], minlength=n_cells)
    tally = np.bincount(status, minlength=5)
    counts = {"records_total": len(rtd), "records_outside_bins": int(tally[kernels.OUTSIDE]),
              "records_transition": int(tally[kernels.TRANSITION]),
              "records_los_mismatch": int(tally[kernels.LOS_MISMATCH]),
              "records_rejected_bad_estimate": int(tally[kernels.REJECTED]),
              "records_used": int(tally[kernels.USED])}
    if counts["records_used"] == 0:
        raise InputError(f"{rtd.source}: no RTD record survived matching to {control.source} "
                         f"({json.dumps(counts)}); check the settling time and the LOS columns")
    used_t = rtd.time_ns[status == kernels.USED]

    dims = ("los", "cnr", "velocity")
    ds = cube_template()
    values = {"los_bias": mean, "los_std": std, "sample_count": count.astype(np.int32),
              "outlier_count": rejected.astype(np.int32), "mean_measured_cnr": cnr_mean}
    for name, data in values.items():
        ds[name] = (dims, data.reshape(_SHAPE), output_attrs("bench_cube", name))
    ds["los_residual"] = ((*dims, "sample"), kernels.pad_groups(residual, cell, n_cells).reshape(
        (*_SHAPE, -1)), output_attrs("bench_cube", "los_residual"))
    meta = control.metadata
    ds.attrs.update({
        "lidar_serial": meta["lidar_serial"], "bench_id": meta["bench_id"], "operator": meta["operator"],
        "run_id": str(meta["run_id"]),
        "time_coverage_start": iso_utc(used_t.min()), "time_coverage_end": iso_utc(used_t.max()),
        "rf_driver_calibration_reference": meta["rf_driver_calibration_reference"],
        "rf_driver_relative_uncertainty": float(meta["rf_driver_relative_uncertainty_percent"]),
        "rf_driver_relative_uncertainty_units": "%",
        "los_sign_convention": "as reported by the lidar (bench programmed shift in the lidar's convention)",
        **{f"ingest_{k}": v for k, v in counts.items()},
    })
    if meta.get("data_origin"):  # "simulated by lidarcal bench simulate ...": a demonstration run
        ds.attrs["data_origin"] = str(meta["data_origin"])
    return ds, counts


def ingest(
    rtd: str | os.PathLike | RtdTable,
    control: str | os.PathLike | ControlLog,
    *,
    settling_time: Any = "5 s",
    outlier_rule: str = "mad",
    outlier_k: float = 4.0,
    outlier_threshold: Any = "3 m s-1",
    min_scale: Any = "0.005 m s-1",
    call: str | None = None,
) -> xr.Dataset:
    """Read (or take) an RTD and a control log and return the stamped ``bench_cube`` Dataset.

    Parameters
    ----------
    rtd, control : path or table
        The lidar's RTD CSV and the bench control log (see :mod:`lidarcal.bench.formats`).
    settling_time : quantity or str
        Records within this time after a bin's start are transition samples and dropped.
    outlier_rule : {"mad", "fixed", "none"}
        Bad-estimate rule (module docstring); ``outlier_k`` is the MAD multiple,
        ``outlier_threshold`` the fixed limit on |measured − programmed|, ``min_scale`` the
        floor of the robust scale.
    """
    settling = float(to_magnitude(settling_time, "s", name="settling_time"))
    threshold = float(to_magnitude(outlier_threshold, "m s-1", name="outlier_threshold"))
    floor = float(to_magnitude(min_scale, "m s-1", name="min_scale"))
    if settling < 0 or threshold <= 0 or floor < 0 or outlier_k <= 0:
        raise InputError("settling_time and min_scale must be >= 0, outlier_threshold and outlier_k > 0")
    inputs = {}
    if not isinstance(rtd, RtdTable):
        inputs["rtd"] = Path(rtd)
        rtd = read_rtd(rtd)
    if not isinstance(control, ControlLog):
        inputs["control_log"] = Path(control)
        control = read_control_log(control)
    ds, counts = build_cube(rtd, control, settling_s=settling, outlier_rule=outlier_rule, outlier_k=outlier_k,
                            outlier_threshold=threshold, min_scale=floor)
    config = {"settling_time_s": settling, "outlier_rule": outlier_rule, "outlier_k": outlier_k,
              "outlier_threshold_m_s": threshold, "min_scale_m_s": floor, "grid": "Table 1",
              "control_metadata": control.metadata}
    meta = control.metadata
    return stamp(
        ds, "bench_cube",
        title=f"SAFO-MV bench calibration cube, lidar {meta['lidar_serial']}, run {meta['run_id']}",
        summary=("Mean (los_bias), standard deviation (los_std) and count of the lidar's radial-velocity "
                 "error against the SI-traceable Doppler shift programmed by the SAFO-MV fiber-optic bench, "
                 "per line of sight, CNR and velocity bin, after removal of transition samples and "
                 f"bad estimates ({counts['records_used']} of {counts['records_total']} RTD records used)."),
        call=call or f"lidarcal.bench.ingest({rtd.source!r}, {control.source!r})",
        inputs=inputs, config=config,
    )
