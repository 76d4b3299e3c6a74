"""Simulated SAFO-MV bench runs: the Table 1 sweep, 1.25 Hz lidar RTD and the control log.

The bench steps through programmed ℓcv-bins (LOS outermost, then CNR, velocity fastest:
5 × 12 × 37 = 2220 bins of ``accumulation_time`` each, 650 s by default, i.e. about 400 h;
shorten it for tests and samples).  The optical switch feeds one of the five telescopes;
the lidar keeps scanning DBS, one LOS estimate every ``sample_interval`` (0.8 s = 1.25 Hz)
cycling ``0, 90, 180, 270, V``, so a fifth of the records carry the bench signal and the
rest see no signal (CNR near the noise floor, random velocity).

Each record is the lidar's estimate over the window ``[t − latency − Δ, t − latency]``
(Δ = sample interval).  A window that straddles a bin switch contains the old and the new
programmed state, power-weighted: the record reports their CNR-weighted mean velocity, or
the stronger one when they differ by more than 2 m/s — the transition samples ingest
must remove.  Every signal record is then ``v + bias + std·z`` of the
:class:`~lidarcal.bench.response.TrueResponse`, and with probability ``p_bad(CNR)`` a bad
estimate, uniform in ±30 m/s.  The lidar also starts 30 s before the first bin and runs
30 s after the last, as on a real bench.

Everything is drawn from one :class:`numpy.random.Generator` seeded by
``SeedSequence(seed)``; the same arguments give the same files, byte for byte.  Files and
columns are described in :mod:`lidarcal.bench.formats` and ``sample_data/bench/README.md``.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from lidarcal.bench.formats import ControlLog, RtdTable, write_control_log, write_rtd
from lidarcal.bench.grid import CNR_NODES, LOS_LABELS, VELOCITY_NODES, los_index
from lidarcal.bench.response import TrueResponse
from lidarcal.errors import InputError
from lidarcal.io import check_writable
from lidarcal.units import to_magnitude

__all__ = ["BenchRun", "simulate_run", "sweep_schedule", "simulate_rtd", "RF_DRIVER_REFERENCE",
           "RF_DRIVER_RELATIVE_UNCERTAINTY_PERCENT", "RTD_NAME", "RTD_NAME_GZ", "CONTROL_NAME",
           "SIMULATED_ORIGIN"]

#: What a simulated run's control log says as its ``data_origin`` metadata (ingest copies it into
#: the cube's ``data_origin`` attribute): the mark by which
#: :func:`lidarcal.certificate.admin.demonstration_reasons` (which looks for the word "simulated")
#: makes every certificate built on the run a demonstration.
SIMULATED_ORIGIN = "simulated by lidarcal bench simulate, not a measurement"

#: Relative uncertainty of the RF-driver calibration, percent (paper §2.1).
RF_DRIVER_RELATIVE_UNCERTAINTY_PERCENT = 5.95622e-8
RF_DRIVER_REFERENCE = "ASERTI Metrology (COFRAC-accredited) RF-driver calibration certificate, simulated"
#: File names written by :meth:`BenchRun.write`.
RTD_NAME = "rtd.csv"
RTD_NAME_GZ = "rtd.csv.gz"  #: with ``compress=True``
CONTROL_NAME = "control_log.csv"
_LEAD_S = 30.0       # lidar running before the first and after the last bin
_MIX_LIMIT = 2.0     # m s-1: closer programmed velocities blend, farther ones: stronger peak wins


@dataclass
class BenchRun:
    """One simulated bench run: the RTD, the control log and what produced them."""

    rtd: RtdTable
    control: ControlLog
    response: TrueResponse
    config: dict

    @staticmethod
    def output_paths(directory: str | os.PathLike, *, overwrite: bool = False,
                     compress: bool = False) -> tuple[Path, Path]:
        """Return the RTD and control-log paths :meth:`write` uses; InputError if not writable.

        Call it before simulating, so a bad directory fails before any work.
        """
        directory = Path(directory)
        if not directory.is_dir():
            what = "is not a directory" if directory.exists() else "does not exist"
            raise InputError(f"{directory}: output directory {what}")
        rtd_path = directory / (RTD_NAME_GZ if compress else RTD_NAME)
        control_path = directory / CONTROL_NAME
        for path in (rtd_path, control_path):  # fail before writing either file
            check_writable(path, overwrite=overwrite)
        return rtd_path, control_path

    def write(self, directory: str | os.PathLike, *, overwrite: bool = False,
              compress: bool = False) -> tuple[Path, Path]:
        """Write ``rtd.csv`` and ``control_log.csv`` into ``directory`` (atomically, no overwrite).

        ``compress=True`` writes the RTD gzip-compressed as ``rtd.csv.gz`` (byte-reproducible,
        about a third of the size); the control log stays plain text.
        """
        rtd_path, control_path = self.output_paths(directory, overwrite=overwrite, compress=compress)
        write_control_log(self.control, control_path, overwrite=overwrite)
        try:
            write_rtd(self.rtd, rtd_path, overwrite=overwrite)
        except BaseException:
            if not overwrite:
                control_path.unlink(missing_ok=True)
            raise
        return rtd_path, control_path


def sweep_schedule(
    start_ns: int,
    accumulation_s: float,
    *,
    los: tuple[str, ...] = LOS_LABELS,
    cnr: np.ndarray = CNR_NODES,
    velocity: np.ndarray = VELOCITY_NODES,
    switch_s: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Programmed bins in sweep order: ``(start_ns, end_ns, los_index, velocity, cnr)``.

    LOS is the outermost loop, then CNR, then velocity; ``switch_s`` is dead time between bins.
    """
    li, ci, vi = np.meshgrid(los_index(np.asarray(los)), np.asarray(cnr, float),
                             np.asarray(velocity, float), indexing="ij")
    n = li.size
    period_ns = round((accumulation_s + switch_s) * 1e9)
    starts = start_ns + np.arange(n, dtype=np.int64) * period_ns
    ends = starts + round(accumulation_s * 1e9)
    return starts, ends, li.ravel(), vi.ravel(), ci.ravel()


def _overlap(idx, a, b, start, end) -> np.ndarray:
    """Length (ns) of [a, b] ∩ bin idx, 0 where idx < 0."""
    j = np.clip(idx, 0, len(start) - 1)
    length = np.minimum(b, end[j]) - np.maximum(a, start[j])
    return np.where(idx >= 0, np.maximum(length, 0), 0).astype(float)


def simulate_rtd(
    control: ControlLog,
    response: TrueResponse,
    rng: np.random.Generator,
    *,
    sample_s: float = 0.8,
    latency_s: float = 2.0,
    lidar_serial: str = "WLS866-0195",
) -> RtdTable:
    """Simulate the lidar's 1.25 Hz RTD during the programmed bins of ``control`` (kernel)."""
    start, end = control.start_ns, control.end_ns
    dt_ns = round(sample_s * 1e9)
    lead_ns = round(_LEAD_S * 1e9)
    t0 = start[0] - lead_ns + int(rng.integers(0, max(dt_ns // 10**6, 1))) * 10**6  # whole ms phase
    n = int((end[-1] + lead_ns - t0) // dt_ns)
    t = t0 + np.arange(n, dtype=np.int64) * dt_ns
    los = (np.arange(n) + int(rng.integers(0, 5))) % 5              # DBS cycle
    b = t - round(latency_s * 1e9)                                   # window end
    a = b - dt_ns                                                    # window start
    ia = np.searchsorted(start, a, side="right") - 1
    ib = np.searchsorted(start, b, side="right") - 1
    wb = _overlap(ib, a, b, start, end) / dt_ns
    wa = np.where(ia != ib, _overlap(ia, a, b, start, end) / dt_ns, 0.0)
    ja, jb = np.clip(ia, 0, None), np.clip(ib, 0, None)
    wa = wa * (control.los[ja] == los)
    wb = wb * (control.los[jb] == los)
    pa, pb = wa * 10 ** (control.cnr[ja] / 10), wb * 10 ** (control.cnr[jb] / 10)
    power = pa + pb
    signal = power > 0
    safe = np.where(signal, power, 1.0)
    va, vb = control.velocity[ja], control.velocity[jb]
    blend = (pa * va + pb * vb) / safe
    v_true = np.where(np.abs(va - vb) <= _MIX_LIMIT, blend, np.where(pa > pb, va, vb))
    cnr_true = np.where(signal, 10 * np.log10(safe), response.noise_floor_cnr)

    z = rng.standard_normal(n)
    u_bad = rng.random(n)
    v_bad = rng.uniform(-response.velocity_range, response.velocity_range, n)
    cnr_noise = rng.standard_normal(n) * response.cnr_noise_std

    measured = v_true + response.bias(los, cnr_true, v_true) + response.std(los, cnr_true, v_true) * z
    bad = ~signal | (u_bad < response.bad_probability(cnr_true))
    measured = np.where(bad, v_bad, measured)
    return RtdTable(t, los, measured, cnr_true + cnr_noise, lidar_serial, "<simulated rtd>")


def simulate_run(
    *,
    seed: int | tuple[int, ...] = 0,
    accumulation_time: Any = "650 s",
    response: TrueResponse | None = None,
    bias_scale: float | None = None,
    lidar_serial: str = "WLS866-0195",
    operator: str = "A",
    run_id: str = "1",
    bench_id: str = "SAFO-MV-01",
    start: str = "2023-02-17T16:07:00Z",
    los: tuple[str, ...] = LOS_LABELS,
    cnr: np.ndarray = CNR_NODES,
    velocity: Any = None,
    sample_interval: Any = "0.8 s",
    latency: Any = "2 s",
    switch_time: Any = "0 s",
    rf_driver_calibration_reference: str = RF_DRIVER_REFERENCE,
) -> BenchRun:
    """Simulate one bench run of the Table 1 sweep.

    Parameters
    ----------
    seed : int or tuple of int
        Entropy of the run's ``SeedSequence``.
    accumulation_time, sample_interval, latency, switch_time : quantity or str
        Time per programmed bin (paper: 650 s), lidar record interval (1.25 Hz), lidar
        processing latency, dead time between bins.  Bare numbers are refused.
    response : TrueResponse, optional
        The lidar's true LOS response (default: the WindCube-like model).
    bias_scale : float, optional
        Overrides ``response.bias_scale``.
    los, cnr, velocity
        The sweep (default: Table 1); ``cnr`` in dB, ``velocity`` a quantity (m s-1).
    """
    response = response or TrueResponse()
    if bias_scale is not None:
        response = dataclasses.replace(response, bias_scale=float(bias_scale))
    acc = float(to_magnitude(accumulation_time, "s", name="accumulation_time"))
    dt = float(to_magnitude(sample_interval, "s", name="sample_interval"))
    lat = float(to_magnitude(latency, "s", name="latency"))
    switch = float(to_magnitude(switch_time, "s", name="switch_time"))
    vel = VELOCITY_NODES if velocity is None else \
        np.atleast_1d(to_magnitude(velocity, "m s-1", name="velocity"))
    if acc < 2 * dt:
        raise InputError(f"argument 'accumulation_time': {acc} s is shorter than two lidar records "
                         f"({2 * dt} s)")
    if min(dt, acc) <= 0 or lat < 0 or switch < 0:
        raise InputError("sample_interval and accumulation_time must be positive; latency, switch_time >= 0")
    bad_los = [x for x in los if x not in LOS_LABELS]
    if bad_los:
        raise InputError(f"argument 'los': unknown LOS id(s) {bad_los}; expected ids from {list(LOS_LABELS)}")
    try:
        stamp0 = pd.Timestamp(start)
    except ValueError as exc:
        raise InputError(f"argument 'start': {start!r} is not an ISO 8601 time ({exc})") from None
    stamp0 = stamp0.tz_localize("UTC") if stamp0.tzinfo is None else stamp0.tz_convert("UTC")
    start_ns = int(stamp0.value)
    starts, ends, li, vi, ci = sweep_schedule(start_ns, acc, los=tuple(los), cnr=np.asarray(cnr, float),
                                              velocity=vel, switch_s=switch)
    meta = {
        "bench_id": bench_id, "operator": operator, "run_id": str(run_id), "lidar_serial": lidar_serial,
        "rf_driver_calibration_reference": rf_driver_calibration_reference,
        "rf_driver_relative_uncertainty_percent": RF_DRIVER_RELATIVE_UNCERTAINTY_PERCENT,
        "accumulation_time_s": acc,
        "sweep_order": "los, cnr, velocity (velocity fastest)",
        # a certificate built from this run is a demonstration (lidarcal.certificate.admin)
        "data_origin": SIMULATED_ORIGIN,
    }
    control = ControlLog(starts, ends, li, vi, ci, meta, "<simulated control log>")
    seed_entropy = list(seed) if isinstance(seed, tuple | list) else int(seed)
    rng = np.random.default_rng(np.random.SeedSequence(seed_entropy))
    rtd = simulate_rtd(control, response, rng, sample_s=dt, latency_s=lat, lidar_serial=lidar_serial)
    config = {"seed": seed_entropy, "accumulation_time_s": acc, "sample_interval_s": dt, "latency_s": lat,
              "switch_time_s": switch, "start": start, "los": list(los), "cnr_dB": np.asarray(cnr).tolist(),
              "velocity_m_s": np.asarray(vel).tolist(), "response": response.to_dict(), **meta}
    return BenchRun(rtd, control, response, config)
