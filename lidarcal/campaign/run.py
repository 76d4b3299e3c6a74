"""Dask-parallel, resumable Monte Carlo over a campaign of 10-minute periods.

:func:`simulate_campaign` splits the periods of a ``conditions`` input into chunks of
``execution.chunk`` consecutive periods, runs one Dask task per chunk (deterministic task names
``lidarcal-chunk-<key>-<start>-<stop>``) and assembles the ``simulated_rtd`` artefact.

* **Seeds** — a period uses the entropy ``(base_seed, period_key)``, the key being the whole
  seconds of its timestamp since 1970-01-01 (:func:`~lidarcal.campaign.chunks.period_keys`),
  never its position; the engine adds ``round(height * 1000)``.  Results therefore do not
  depend on chunk size, worker count, scheduler, which other heights are simulated, or how a
  conditions file is split: parts simulated separately and concatenated (``xr.concat``,
  ``xr.open_mfdataset``) equal the whole run bit for bit.  Every record carries its
  ``period_key`` and ``base_seed`` (time variables), so ensemble members with different base
  seeds stay distinguishable after concatenation.
* **Execution** — where and how the chunks run is one :class:`~lidarcal.campaign.settings.Execution`
  (``execution``: chunk size, scheduler, workers, chunk cache, progress, timeouts); none of it
  changes a number.
* **Schedulers** — ``None``/``"processes"`` (local process pool, the default), ``"threads"``,
  ``"synchronous"``, ``"local"`` (a ``distributed.LocalCluster`` of single-threaded worker
  processes), an address ``"tcp://host:port"`` of a running ``dask.distributed`` scheduler,
  or a ``distributed.Client``.  Worker processes get ``OPENBLAS/MKL/OMP_NUM_THREADS=1``.
* **Resume** — with ``execution.workdir`` every finished chunk is saved atomically as
  ``chunk-<start>-<stop>-<key>.npz`` where the key hashes (conditions checksum, model, base
  seed, chunk bounds, period keys, heights, duration); a re-run loads finished chunks instead of
  recomputing them, so a killed run resumes and gives the identical result.  With
  ``dask.distributed`` a lost worker's tasks are recomputed elsewhere: it costs time, not data.
* **Faults** (``dask.distributed``) — before any task, every worker must report this lidarcal
  version (a probe shipped by value, so it also runs where lidarcal is missing); the dashboard
  link is logged; while waiting, the scheduler's worker list is polled, and no worker for
  ``worker_timeout`` s or a scheduler that stops answering ends the run with
  :class:`~lidarcal.errors.ComputeError` (exit status 2), never a hang or a traceback.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.campaign.chunks import INPUTS, OUTPUTS, ChunkTask, chunk_key, make_workdir, period_keys
from lidarcal.campaign.los import los_variables
from lidarcal.campaign.scheduler import execute
from lidarcal.campaign.settings import Execution
from lidarcal.cf import height_coord, time_coord
from lidarcal.conditions import SkippedPeriodsWarning, load_conditions
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.errors import InputError
from lidarcal.io import source_name
from lidarcal.lidar import LidarModel
from lidarcal.lidar.geometry import check_reachable
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs

__all__ = ["simulate_campaign", "simulate_replicas", "DEFAULT_BASE_SEED"]

log = logging.getLogger(__name__)

DEFAULT_BASE_SEED = 20240101


def _select_heights(cond: xr.Dataset, heights: Sequence[float] | None, source: str) -> np.ndarray:
    available = cond.height.values
    if heights is None:
        return np.arange(available.size)
    idx = []
    for h in np.atleast_1d(np.asarray(heights, dtype=float)):
        j = int(np.abs(available - h).argmin())
        if abs(available[j] - h) > 1e-6:
            raise InputError(
                f"{source}: height {h:g} m is not in the conditions; available heights (m): "
                f"{[float(a) for a in available]}"
            )
        idx.append(j)
    if len(set(idx)) != len(idx):
        raise InputError(f"heights {list(heights)} repeat a height")
    return np.asarray(sorted(idx))


def simulate_campaign(
    conditions: str | os.PathLike | xr.Dataset,
    model,
    *,
    heights: Sequence[float] | None = None,
    base_seed: int = DEFAULT_BASE_SEED,
    los_periods: Sequence[int] = (),
    duration: float = 600.0,
    execution: Execution | Mapping[str, Any] | None = None,
    call: str | None = None,
    inputs: dict[str, str | os.PathLike] | None = None,
) -> xr.Dataset:
    """Simulate every 10-minute period of ``conditions`` with the virtual lidar ``model``.

    Parameters
    ----------
    conditions : path or xarray.Dataset
        A ``conditions`` (or ``field_campaign``) input; see :func:`lidarcal.conditions.load_conditions`.
    model : lidarcal.lidar.LidarModel
        The virtual lidar.
    heights : sequence of float, optional
        Heights (m) to simulate; each must be one of the conditions' heights.  Default: all.
    base_seed : int
        A period at time ``t`` uses ``SeedSequence([base_seed, period_key, round(height * 1000)])``
        with ``period_key`` the whole seconds of ``t`` since 1970-01-01T00:00:00 (docs/seeds.md).
    los_periods : sequence of int
        Period indices whose LOS time series are kept (``return_los=True``).
    duration : float
        Period length in s (600).
    execution : Execution or mapping, optional
        Where and how the chunks run (:class:`~lidarcal.campaign.settings.Execution`: ``chunk``,
        ``scheduler``, ``workers``, ``workdir``, ``progress``, ``connect_timeout``,
        ``worker_timeout``; a mapping of these fields, or None for the defaults: a local process
        pool, 64 periods a chunk, no cache).  With ``dask.distributed`` workers are checked for
        this lidarcal version before any task is submitted.  None of it changes the result.
    call : str, optional
        Command line recorded in the history (default: a description of this call).
    inputs : mapping of role to path, optional
        Further input files to record with their checksums (e.g. ``cube``, ``rwf``).

    Returns
    -------
    xarray.Dataset
        A ``simulated_rtd`` artefact (CONTRIBUTING.md): dims ``time``, ``height``; the six
        conditions variables used, the four wind speeds, ``availability``, ``simulated``
        (0 where a period was skipped for missing input), ``period_key`` and ``base_seed`` (the
        seed entropy of each period).
    """
    run = Execution.of(execution)
    camp = _prepare(conditions, model, heights, los_periods)
    if run.workdir is not None:
        make_workdir(run.workdir)
    where = None if run.workdir is None else os.fspath(run.workdir)
    model_dict = model.to_dict()
    tasks = [_task(camp, model_dict, base_seed, duration, np.arange(start, min(start + run.chunk, camp.n)),
                   start, name="lidarcal-chunk-{key}-{start}-{stop}", los=camp.los, workdir=where)
             for start in range(0, camp.n, run.chunk)]
    results = _run(model, tasks, run)
    out = {name: np.concatenate([res[name] for res in results], axis=0) for name in OUTPUTS}
    los_data = {p: v for res in results for p, v in res["los"].items()}
    ds = _assemble(camp.cond, camp.hidx, out, camp.valid, los_data, camp.keys, base_seed)
    return _describe(ds, camp, model, base_seed=base_seed, duration=duration, execution=run, call=call,
                     inputs=inputs)


def simulate_replicas(
    conditions: str | os.PathLike | xr.Dataset,
    model,
    cells: np.ndarray | Mapping[int, np.ndarray],
    replicas: Sequence[int],
    *,
    heights: Sequence[float] | None = None,
    base_seed: int = DEFAULT_BASE_SEED,
    duration: float = 600.0,
    execution: Execution | Mapping[str, Any] | None = None,
) -> dict[int, dict[str, np.ndarray]]:
    """Monte Carlo replicas (>= 1) of the (period, height) ``cells`` of a campaign (JCGM 101 7.9).

    Replica ``r`` re-simulates the cells marked in ``cells`` ((time, height) bool over the
    simulated heights; or a mapping replica -> such a mask, each replica its own) with the seed
    entropy ``(base_seed, r, period_key)`` (docs/seeds.md), as Dask tasks of ``execution.chunk``
    selected periods, one set of tasks per replica, all submitted together.  Replica 0 re-uses the
    campaign's own streams ``(base_seed, period_key)``: with another ``model`` that is a
    common-random-numbers run (:mod:`lidarcal.campaign.model_form`).  Like
    :func:`simulate_campaign` the result does not depend on the chunk size, the workers or the
    scheduler, and with ``workdir`` finished chunks are kept (in ``workdir/replica-<r>``) so an
    interrupted run resumes.

    Returns
    -------
    dict
        Per replica: ``period`` (index into the conditions), ``height`` (m), the
        :data:`~lidarcal.campaign.chunks.OUTPUTS` of every simulated cell (1-D, in period then height
        order).
    """
    with warnings.catch_warnings():  # replica 0 has reported the periods it skips
        warnings.simplefilter("ignore", SkippedPeriodsWarning)
        camp = _prepare(conditions, model, heights, ())
    run = Execution.of(execution)
    chunk, workdir = run.chunk, run.workdir
    replicas = [int(r) for r in replicas]
    masks = {r: np.asarray(cells[r] if isinstance(cells, Mapping) else cells, dtype=bool) for r in replicas}
    for r, mask in masks.items():
        if mask.shape != camp.valid.shape:
            raise InputError(f"cells{'' if not isinstance(cells, Mapping) else f' of replica {r}'} has shape "
                             f"{mask.shape}; expected {camp.valid.shape} (time, height)")
    if any(r < 0 for r in replicas):
        raise InputError(f"replicas are numbered from 0 (replica 0: the campaign's own streams); "
                         f"got {replicas}")
    todo = {r: camp.valid & masks[r] for r in replicas}
    sel = {r: np.flatnonzero(todo[r].any(axis=1)) for r in replicas}
    model_dict = model.to_dict()
    tasks: list[ChunkTask] = []
    for r in replicas:
        where = None if workdir is None else os.path.join(os.fspath(workdir), f"replica-{r:04d}")
        if where is not None:
            os.makedirs(where, exist_ok=True)
        for a in range(0, sel[r].size, chunk):
            idx = sel[r][a:a + chunk]
            # "rate_draw": a replica's p_bad(CNR) curves are drawn per period (were per replica)
            extra = {"replica": r, "periods": idx.tolist(), "cells": todo[r][idx].astype(int).tolist(),
                     "rate_draw": "trial"}
            tasks.append(_task(camp, model_dict, base_seed, duration, idx, a,
                               name=f"lidarcal-replica-{r}-{{key}}-{a}", valid=todo[r][idx], replica=r,
                               extra=extra, workdir=where))
    results = iter(_run(model, tasks, run))  # in the order of the tasks: replica, then chunk
    out: dict[int, dict[str, np.ndarray]] = {}
    for r in replicas:
        rows, cols = np.nonzero(todo[r][sel[r]])
        parts = [next(results) for _ in range(0, sel[r].size, chunk)]
        full = {name: (np.concatenate([p[name] for p in parts], axis=0) if parts
                       else np.empty((0, camp.z.size))) for name in OUTPUTS}
        out[r] = {"period": sel[r][rows], "height": camp.z[cols],
                  **{name: full[name][rows, cols] for name in OUTPUTS}}
    return out


def _task(camp: _Campaign, model_dict: dict, base_seed: int, duration: float, rows: np.ndarray, start: int, *,
          name: str, valid: np.ndarray | None = None, los: Sequence[int] = (), replica: int = 0,
          extra: dict | None = None, workdir: str | None = None) -> ChunkTask:
    """Return the chunk simulating the periods ``rows`` of ``camp`` (the cells ``valid``; default: all valid).

    ``start`` is the chunk's first position (its cache entry runs from ``start`` to ``start`` +
    the periods), ``model_dict`` (the attribute form, residuals by digest) and ``extra`` enter its
    key (:func:`~lidarcal.campaign.chunks.chunk_key`), ``name`` (with ``{key}``, ``{start}``,
    ``{stop}``) names its Dask task.
    """
    stop = start + rows.size
    key = chunk_key(camp.checksum, model_dict, base_seed, start, stop, camp.z, duration, tuple(los),
                    keys=camp.keys[rows], extra=extra)
    return ChunkTask(
        name=name.format(key=key[:16], start=start, stop=stop), heights=camp.z,
        inputs={k: v[rows] for k, v in camp.arrays.items()},
        valid=camp.valid[rows] if valid is None else valid, period_index=rows, period_key=camp.keys[rows],
        los=np.isin(rows, list(los)), base_seed=int(base_seed), duration=float(duration), key=key,
        start=start, stop=stop, replica=int(replica), workdir=workdir,
    )


def _run(model, tasks: list[ChunkTask], run: Execution) -> list[dict[str, Any]]:
    """Return the result of every chunk in ``tasks`` (in their order): from the cache, else simulated."""
    results = [task.cached() for task in tasks]
    todo = [task for task, result in zip(tasks, results, strict=True) if result is None]
    _say_reused(len(tasks) - len(todo), len(tasks), run)
    index = {task.name: i for i, task in enumerate(tasks)}
    # the chunk key takes the attribute form (residuals by digest), the workers the full model
    for name, result in execute(model.to_dict(residuals=True), todo, run):
        results[index[name]] = result
    return results


def _say_reused(reused: int, total: int, run: Execution) -> None:
    """Log how many of the chunks were found finished in the chunk cache (a resumed run)."""
    if reused:
        log.info("%s: reusing %d of %d chunks finished earlier (kept in %s)", run.progress.label, reused,
                 total, run.workdir)


@dataclass(frozen=True)
class _Campaign:
    """The validated inputs of one campaign: what is simulated, at which heights, from which file."""

    cond: xr.Dataset  # the loaded conditions (all heights)
    path: str | None  # the conditions file, if given as a path
    source: str  # how errors and the history name the conditions
    hidx: np.ndarray  # indices of the simulated heights in ``cond``
    los: list[int]  # periods whose LOS time series are kept
    arrays: dict[str, np.ndarray]  # INPUTS at the simulated heights, (time, height)
    valid: np.ndarray  # (time, height): complete input and wind > 0
    keys: np.ndarray  # (time,): seed key of each period, from its timestamp

    @property
    def z(self) -> np.ndarray:
        return self.cond.height.values[self.hidx]

    @property
    def n(self) -> int:
        return self.cond.sizes["time"]

    @property
    def checksum(self) -> str:
        return read_attr(self.cond, "lidarcal_conditions_checksum", kind="conditions")


def _prepare(conditions, model, heights, los_periods) -> _Campaign:
    """Check the model and options against the conditions; load the inputs the chunks need."""
    if not isinstance(model, LidarModel):
        raise InputError(f"model must be a lidarcal.lidar.LidarModel; got {type(model).__name__}")
    path = None if isinstance(conditions, xr.Dataset) else os.fspath(conditions)
    cond = load_conditions(conditions)
    source = path or source_name(cond)
    hidx = _select_heights(cond, heights, source)
    problems = check_reachable(model, cond.height.values[hidx])
    if problems:
        raise InputError(
            f"{source}: heights the lidar cannot measure with this RWF/geometry: " + "; ".join(problems)
        )
    n = cond.sizes["time"]
    los = sorted({int(i) for i in los_periods})
    bad = [i for i in los if not 0 <= i < n]
    if bad:
        raise InputError(f"los_periods {bad} outside the {n} periods of {source}")
    keys = period_keys(cond["time"].values)
    order = np.argsort(keys, kind="stable")
    same = np.flatnonzero(np.diff(keys[order]) == 0)
    if same.size:
        i, j = sorted((int(order[same[0]]), int(order[same[0] + 1])))
        raise InputError(
            f"{source}: periods {i} and {j} have the same time to the second "
            f"({np.datetime_as_string(cond['time'].values[j], unit='s')}); a period's random streams are "
            "keyed by its time, so every period needs its own"
        )
    arrays = {name: cond[name].values[:, hidx] for name in INPUTS}
    # a calm period (0 m/s) is valid input but has no turbulence box to simulate: skip it too
    with np.errstate(invalid="ignore"):
        valid = cond["input_complete"].values[:, hidx].astype(bool) & (arrays["wind_speed"] > 0)
    return _Campaign(cond=cond, path=path, source=source, hidx=hidx, los=los, arrays=arrays, valid=valid,
                     keys=keys)


def _describe(ds: xr.Dataset, camp: _Campaign, model, *, base_seed, duration, execution: Execution,
              call, inputs) -> xr.Dataset:
    """Add the run's attributes and provenance: the ``simulated_rtd`` artefact."""
    z, valid = camp.z, camp.valid
    ds.attrs["lidarcal_base_seed"] = int(base_seed)
    ds.attrs["lidarcal_lidar_model"] = model.to_json()
    ds.attrs["lidarcal_conditions_checksum"] = camp.checksum
    ds.attrs["lidarcal_skipped_count"] = int((~valid).sum())
    ds.attrs["lidarcal_filtered_count"] = int((ds["simulated"].values == 2).sum())
    config = {
        "model": model.to_dict(),
        "heights": z.tolist(),
        **execution.record(),
        "duration": duration,
        "los_periods": camp.los,
        "conditions_checksum": camp.checksum,
    }
    path, source = camp.path, camp.source
    return stamp(
        ds,
        "simulated_rtd",
        title="Simulated 10-minute records of a virtual DBS lidar and a virtual point reference",
        summary=(
            f"Monte Carlo simulation of {camp.n} ten-minute periods at {z.size} height(s): virtual lidar "
            f"({model.description}) in synthetic turbulence driven by the conditions time series, "
            f"compared with a virtual cup-like point reference."
        ),
        call=call or (f"lidarcal.campaign.simulate_campaign({source!r}, base_seed={base_seed}, "
                      f"chunk={execution.chunk})"),
        inputs={**({"conditions": path} if path else {}), **(inputs or {})},
        input_datasets={"conditions": camp.cond},
        config=config,
        seeds={
            "base_seed": int(base_seed),
            "scheme": "numpy SeedSequence([base_seed, period_key, round(height_m * 1000)]), period_key = "
                      "whole seconds of the period's time since 1970-01-01T00:00:00 (modulo 2**64)",
        },
        keywords="Doppler lidar, wind speed, Monte Carlo, calibration, simulation",
    )


def _assemble(
    cond: xr.Dataset,
    hidx: np.ndarray,
    out: dict[str, np.ndarray],
    valid: np.ndarray,
    los_data: dict[int, dict],
    keys: np.ndarray,
    base_seed: int,
) -> xr.Dataset:
    dims = ("time", "height")
    ds = xr.Dataset(
        coords={"time": time_coord(cond.time.values), "height": height_coord(cond.height.values[hidx])}
    )
    for name in CONDITION_NAMES:
        ds[name] = (
            dims,
            cond[name].values[:, hidx],
            {**cond[name].attrs, "coverage_content_type": "modelResult"},
        )
    for name in OUTPUTS:
        ds[name] = (dims, out[name], output_attrs("simulated_rtd", name))
    flag = valid.astype(np.int8)
    flag[valid & (out["availability"] == 0)] = 2  # the lidar's CNR filter dropped every LOS
    ds["simulated"] = (dims, flag, output_attrs("simulated_rtd", "simulated"))
    # the seed entropy of every period, as time variables: position-free, so parts of a campaign
    # concatenate to the whole, and members of an ensemble keep their base seed when joined
    ds["period_key"] = ("time", np.asarray(keys, dtype=np.int64), output_attrs("simulated_rtd", "period_key"))
    ds["base_seed"] = ("time", np.full(cond.sizes["time"], int(base_seed), dtype=np.int64),
                       output_attrs("simulated_rtd", "base_seed"))
    if los_data:
        ds = ds.merge(los_variables(los_data, ds.height.values))
    return ds
