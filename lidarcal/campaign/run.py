"""Dask-parallel, resumable Monte Carlo over a campaign of 10-minute periods.

:func:`simulate_campaign` splits the periods of a ``conditions`` input into chunks of
``chunk`` consecutive periods, runs one Dask task per chunk (deterministic task names
``lidarcal-chunk-<key>-<start>-<stop>``) and assembles the ``simulated_rtd`` artefact.

* **Seeds** — a period uses the entropy ``(base_seed, period_key)``, the key being the whole
  seconds of its timestamp since 1970-01-01 (:func:`~lidarcal.campaign.chunks.period_keys`),
  never its position; the engine adds ``round(height * 1000)``.  Results therefore do not
  depend on chunk size, worker count, scheduler, which other heights are simulated, or how a
  conditions file is split: parts simulated separately and concatenated (``xr.concat``,
  ``xr.open_mfdataset``) equal the whole run bit for bit.  Every record carries its
  ``period_key`` and ``base_seed`` (time variables), so ensemble members with different base
  seeds stay distinguishable after concatenation.
* **Schedulers** — ``None``/``"processes"`` (local process pool, the default), ``"threads"``,
  ``"synchronous"``, ``"local"`` (a ``distributed.LocalCluster`` of single-threaded worker
  processes), an address ``"tcp://host:port"`` of a running ``dask.distributed`` scheduler,
  or a ``distributed.Client``.  Worker processes get ``OPENBLAS/MKL/OMP_NUM_THREADS=1``.
* **Resume** — with ``workdir`` every finished chunk is saved atomically as
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

import contextlib
import functools
import logging
import os
import time
import uuid
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from lidarcal import __version__
from lidarcal.campaign.chunks import (
    INPUTS,
    OUTPUTS,
    chunk_key,
    chunk_path,
    load_chunk,
    make_workdir,
    period_keys,
    run_chunk,
    unflatten_los,
)
from lidarcal.campaign.los import los_variables
from lidarcal.campaign.workers import BLAS_ENV, PARENT_PID_ENV, init_pool_worker, quiet_orphaned_gathers
from lidarcal.cf import height_coord, time_coord, var_attrs
from lidarcal.conditions import CONDITION_VARIABLES, SkippedPeriodsWarning, load_conditions
from lidarcal.errors import ComputeError, InputError
from lidarcal.io import source_name
from lidarcal.lidar import LidarModel
from lidarcal.lidar.geometry import check_reachable
from lidarcal.provenance import stamp

__all__ = ["simulate_campaign", "simulate_replicas", "local_cluster", "DEFAULT_BASE_SEED", "BLAS_ENV",
           "WORKER_CONFIG",
           "WORKER_TIMEOUT"]

log = logging.getLogger(__name__)

DEFAULT_BASE_SEED = 20240101
#: Dask configuration for the worker processes lidarcal starts itself.  distributed sets
#: ``MALLOC_TRIM_THRESHOLD_=65536`` in every nanny-spawned worker; any value of it switches off
#: glibc's adaptive mmap threshold, so the engine's temporaries are mapped and unmapped on every
#: call and a period costs 1.5x the CPU (measured: 40-45 against 27 ms; docs/performance.md).
WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: LocalCluster workers import campaign.workers at start: they end with the lidarcal process.
WORKER_PRELOAD = {"distributed.worker.preload": ["lidarcal.campaign.workers"]}

_OUTPUT_ATTRS = {
    "lidar_wind_speed": var_attrs(
        "virtual lidar 10-minute horizontal wind speed (hybrid reconstruction)", "m s-1", "wind_speed"
    ),
    "lidar_wind_speed_scalar": var_attrs(
        "virtual lidar 10-minute horizontal wind speed (scalar average, Eq. 3)", "m s-1", "wind_speed"
    ),
    "lidar_wind_speed_vector": var_attrs(
        "virtual lidar 10-minute horizontal wind speed (vector average, Eq. 4)", "m s-1", "wind_speed"
    ),
    "reference_wind_speed": var_attrs(
        "virtual point reference 10-minute scalar mean horizontal wind speed", "m s-1", "wind_speed"
    ),
    "availability": var_attrs("fraction of LOS samples kept in the period", "1"),
}


def local_cluster(n_workers: int, **kwargs):
    """Start a ``distributed.LocalCluster`` of single-threaded worker processes set up for the engine.

    One BLAS thread per worker (:data:`BLAS_ENV`) and glibc's default allocator behaviour
    (:data:`WORKER_CONFIG`); ``kwargs`` go to ``LocalCluster`` (e.g. ``dashboard_address``).
    """
    import dask
    from distributed import LocalCluster

    # workers die with this process (campaign.workers: preloaded, told our pid)
    env = {**BLAS_ENV, PARENT_PID_ENV: str(os.getpid())}
    kwargs = {"threads_per_worker": 1, "processes": True, "env": env, **kwargs}
    with _blas_env(), dask.config.set({**WORKER_CONFIG, **WORKER_PRELOAD}):
        return LocalCluster(n_workers=n_workers, **kwargs)


@contextlib.contextmanager
def _blas_env() -> Iterator[None]:
    """Set one BLAS thread in the environment inherited by spawned worker processes."""
    old = {k: os.environ.get(k) for k in BLAS_ENV}
    os.environ.update(BLAS_ENV)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _connect(address: str, timeout: float):
    from distributed import Client

    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(
            f"cannot reach the dask scheduler at {address!r} within {timeout:g} s "
            f"({type(exc).__name__}: {exc}); is `dask scheduler` running there?"
        ) from None


#: Seconds a distributed run waits while no worker is connected (none yet, or all lost) before
#: it fails with :class:`~lidarcal.errors.ComputeError`.
WORKER_TIMEOUT = 60.0
_POLL = 0.25  # s between checks of the workers while waiting for results

# Run on every worker before any task: defined from source, so cloudpickle ships it by value and
# it runs (and reports) on a worker where lidarcal cannot even be imported.
_PROBE_SOURCE = """
def lidarcal_version_probe():
    try:
        import lidarcal
    except BaseException as exc:
        return "no importable lidarcal ({}: {})".format(type(exc).__name__, exc)
    return "lidarcal " + str(getattr(lidarcal, "__version__", "of unknown version"))
"""


def _version_probe():
    namespace: dict[str, Any] = {}
    exec(compile(_PROBE_SOURCE, "<lidarcal worker probe>", "exec"), namespace)
    return namespace["lidarcal_version_probe"]


def _scheduler_gone(address: str, exc: BaseException) -> ComputeError:
    return ComputeError(
        f"lost the dask scheduler at {address} ({type(exc).__name__}: {exc}); the run stopped. "
        "Restart the scheduler and workers and run again (with --workdir, finished chunks are kept)"
    )


def _n_workers(client, address: str) -> int:
    try:
        return len(client.scheduler_info(n_workers=-1)["workers"])
    except Exception as exc:  # comm closed, timeout, cancelled: the scheduler is unreachable
        raise _scheduler_gone(address, exc) from None


def _check_workers(client, address: str, worker_timeout: float) -> None:
    """Wait for a worker, then check that every worker runs this lidarcal (before any task)."""
    try:
        client.wait_for_workers(1, timeout=worker_timeout)
    except TimeoutError:
        raise ComputeError(
            f"no dask worker joined the scheduler at {address} within {worker_timeout:g} s; "
            f"start one with `dask worker {address}`"
        ) from None
    except Exception as exc:
        raise _scheduler_gone(address, exc) from None
    try:
        found = client.run(_version_probe(), on_error="return")
    except Exception as exc:
        raise _scheduler_gone(address, exc) from None
    expected = f"lidarcal {__version__}"
    bad = {w: v if isinstance(v, str) else f"a failed probe ({type(v).__name__}: {v})"
           for w, v in found.items() if v != expected}
    if bad:
        raise ComputeError(
            f"dask workers at {address} cannot run this calculation (client: {expected}): "
            + "; ".join(f"worker {w} has {v}" for w, v in sorted(bad.items()))
            + f"; install lidarcal {__version__} in every worker's environment"
        )


def _close_quietly(client, timeout: float) -> None:
    """Close our own client; if the scheduler is gone, without distributed's reconnect tracebacks."""
    loggers = [logging.getLogger(name) for name in ("distributed", "distributed.client")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL)
    try:
        with contextlib.suppress(Exception):
            client.close(timeout=timeout)
    finally:
        for lg, level in zip(loggers, levels, strict=True):
            lg.setLevel(level)


def _log_dashboard(client) -> None:
    with contextlib.suppress(Exception):
        if "dashboard" in client.scheduler_info(n_workers=0).get("services", {}):
            log.info("dask dashboard: %s", client.dashboard_link)


def _run_distributed(client, tasks: list[tuple[str, dict]], progress: bool,
                     worker_timeout: float = WORKER_TIMEOUT) -> Iterator[tuple[str, dict]]:
    """Run ``tasks`` on a ``distributed.Client``; fail within ``worker_timeout`` s if no worker is left.

    Before submitting: wait for a worker and check every worker's lidarcal version.  While
    waiting: poll the scheduler's worker list; a scheduler that stops answering, or no worker
    for ``worker_timeout`` s, ends the run with :class:`~lidarcal.errors.ComputeError`.
    """
    from distributed import as_completed
    from distributed.scheduler import KilledWorker

    address = str(getattr(getattr(client, "scheduler", None), "address", None) or "the scheduler")
    quiet_orphaned_gathers()  # no AllExit traceback after our own message when workers die
    _log_dashboard(client)
    _check_workers(client, address, worker_timeout)
    tasks = _share_model(client, tasks)
    futures = {client.submit(run_chunk, payload, key=name, pure=False): name for name, payload in tasks}
    bar = _bar(len(tasks), progress)
    finished = False
    # a lost scheduler is reported once, by the ComputeError below, not by the client's own
    # reconnect logging (an ERROR with a traceback)
    quiet = logging.getLogger("distributed.client")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)
    try:
        with client.as_current():  # as_completed looks up the current client
            completed = as_completed(futures)
        alone_since = None
        while not completed.is_empty():
            batch = completed.next_batch(block=False)
            if not batch:
                now = time.monotonic()
                if _n_workers(client, address):
                    alone_since = None
                elif alone_since is None:
                    alone_since = now
                elif now - alone_since > worker_timeout:
                    raise ComputeError(
                        f"every dask worker of the scheduler at {address} is gone and none joined for "
                        f"{worker_timeout:g} s; {completed.count()} of {len(tasks)} chunks unfinished. Start "
                        f"workers (`dask worker {address}`) and run again (with --workdir, finished chunks "
                        "are kept)"
                    )
                time.sleep(_POLL)
                continue
            for fut in batch:
                name = futures[fut]
                if fut.status == "error":
                    exc = fut.exception()
                    if isinstance(exc, KilledWorker):
                        raise ComputeError(
                            f"chunk {name} was running on dask workers that died each time it was tried "
                            f"({exc}); out of memory, or killed?"
                        ) from None
                    fut.result()  # the task's own error: a LidarcalError, else a bug (traceback)
                if fut.status == "cancelled":  # the scheduler forgot it: it went away
                    raise _scheduler_gone(address, RuntimeError(f"chunk {name} was cancelled"))
                if fut.status != "finished":  # lost with its worker: the scheduler computes it again
                    completed.add(fut)
                    continue
                try:
                    result = fut.result(timeout=worker_timeout)
                except Exception:  # its worker died before the result was fetched
                    _n_workers(client, address)  # a ComputeError if the scheduler is gone
                    completed.add(fut)  # else computed again
                    continue
                fut.release()
                bar.update(1)
                yield name, result
        finished = True
    finally:
        bar.close()
        if not finished:
            with contextlib.suppress(Exception):
                client.cancel(list(futures), force=True)
        quiet.setLevel(level)


def _share_model(client, tasks: list[tuple[str, dict]]) -> list[tuple[str, dict]]:
    """Send the model the tasks share (bench residuals: megabytes) to the cluster once, not per task.

    Without this every submitted task carries its own serialised copy, so the client's memory
    grows with the number of tasks in flight (chunks times Monte Carlo replicas).  The model is
    the result of one task rather than scattered data: if every worker holding it dies, the
    scheduler computes it again on the next worker that joins (scattered data would be lost,
    and with it every chunk that needs it).
    """
    shared = tasks[0][1].get("model") if tasks else None
    if shared is None or any(payload.get("model") is not shared for _, payload in tasks):
        return tasks
    try:
        with warnings.catch_warnings():  # "large object in task graph": sent once, on purpose
            warnings.simplefilter("ignore", UserWarning)
            remote = client.submit(_shared_model, shared, pure=False,
                                   key=f"lidarcal-model-{uuid.uuid4().hex}")
    except Exception as exc:  # comm closed, timeout: the scheduler is unreachable
        address = str(getattr(getattr(client, "scheduler", None), "address", None) or "the scheduler")
        raise _scheduler_gone(address, exc) from None
    return [(name, {**payload, "model": remote}) for name, payload in tasks]


def _shared_model(model):
    """Return ``model``: the task whose result the chunks share (:func:`_share_model`)."""
    return model


def _bar(total: int, enabled: bool):
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="chunk", desc="simulate", disable=not enabled, dynamic_ncols=True)


def _run_local(
    tasks: list[tuple[str, dict]], scheduler: str, workers: int | None, progress: bool
) -> Iterator[tuple[str, dict]]:
    import dask

    delayed = [dask.delayed(run_chunk, pure=False)(payload, dask_key_name=name) for name, payload in tasks]
    kw: dict[str, Any] = {"scheduler": scheduler}
    if scheduler in ("processes", "threads") and workers:
        kw["num_workers"] = int(workers)
    callbacks = []
    if progress:
        from tqdm.dask import TqdmCallback

        callbacks.append(TqdmCallback(desc="simulate", unit="chunk", dynamic_ncols=True))
    with _blas_env(), contextlib.ExitStack() as stack:
        for cb in callbacks:
            stack.enter_context(cb)
        if scheduler == "processes":  # pool workers die with this process (campaign.workers)
            stack.enter_context(dask.config.set({
                "multiprocessing.context": "spawn",
                "multiprocessing.initializer": functools.partial(init_pool_worker, os.getpid()),
            }))
        results = dask.compute(*delayed, **kw)
    yield from zip((name for name, _ in tasks), results, strict=True)


def _execute(tasks, scheduler, workers, progress, connect_timeout,
             worker_timeout=WORKER_TIMEOUT) -> Iterator[tuple[str, dict]]:
    if not tasks:
        return
    if scheduler is None:
        scheduler = "processes"
    if hasattr(scheduler, "submit"):  # a distributed.Client
        yield from _run_distributed(scheduler, tasks, progress, worker_timeout)
        return
    if not isinstance(scheduler, str):
        raise InputError(
            f"scheduler must be None, a name, an address or a distributed.Client; got {scheduler!r}"
        )
    if "://" in scheduler:
        client = _connect(scheduler, connect_timeout)
        try:
            yield from _run_distributed(client, tasks, progress, worker_timeout)
        finally:
            _close_quietly(client, connect_timeout)
        return
    if scheduler == "local":
        from distributed import Client

        n = int(workers or os.cpu_count() or 1)
        with (
            local_cluster(n, dashboard_address=None) as cluster,
            Client(cluster, set_as_default=False) as client,
        ):
            yield from _run_distributed(client, tasks, progress, worker_timeout)
        return
    if scheduler not in ("processes", "threads", "synchronous", "sync", "single-threaded"):
        raise InputError(
            f"unknown scheduler {scheduler!r}; use 'processes', 'threads', 'synchronous', 'local', "
            f"an address such as 'tcp://127.0.0.1:8786', or a distributed.Client"
        )
    yield from _run_local(tasks, scheduler, workers, progress)


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
    chunk: int = 64,
    scheduler: Any = None,
    workers: int | None = None,
    workdir: str | os.PathLike | None = None,
    progress: bool = False,
    los_periods: Sequence[int] = (),
    duration: float = 600.0,
    connect_timeout: float = 5.0,
    worker_timeout: float = WORKER_TIMEOUT,
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
    chunk : int
        Periods per Dask task (does not change the result).
    scheduler : None, str or distributed.Client
        See the module docstring; ``None`` runs a local process pool.
    workers : int, optional
        Worker processes/threads for local schedulers (default: number of CPUs).
    workdir : path, optional
        Directory for the resumable chunk cache (created if missing).
    progress : bool
        Show a progress bar (tqdm) on the terminal.
    los_periods : sequence of int
        Period indices whose LOS time series are kept (``return_los=True``).
    duration : float
        Period length in s (600).
    connect_timeout : float
        Seconds to wait for a remote scheduler before raising :class:`~lidarcal.errors.InputError`.
    worker_timeout : float
        With ``dask.distributed``: seconds to wait while no worker is connected (none joined yet,
        or every one was lost) before raising :class:`~lidarcal.errors.ComputeError`.  Workers
        are checked for this lidarcal version before any task is submitted.
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
    camp = _prepare(conditions, model, heights, chunk, los_periods)
    chunk = int(chunk)
    # the chunk key takes the attribute form (residuals by digest), the workers the full model
    results, tasks, bounds = _schedule(camp, model.to_dict(), base_seed, chunk, duration, workdir,
                                       transport=model.to_dict(residuals=True))
    for name, result in _execute(tasks, scheduler, workers, progress, connect_timeout, worker_timeout):
        results[bounds[name][0]] = result
    out = {name: np.concatenate([results[s][name] for s in sorted(results)], axis=0) for name in OUTPUTS}
    los_data = {p: v for s in sorted(results) for p, v in results[s]["los"].items()}
    ds = _assemble(camp.cond, camp.hidx, out, camp.valid, los_data, camp.keys, base_seed)
    return _describe(ds, camp, model, base_seed=base_seed, chunk=chunk, duration=duration,
                     scheduler=scheduler, workers=workers, call=call, inputs=inputs)


def simulate_replicas(
    conditions: str | os.PathLike | xr.Dataset,
    model,
    cells: np.ndarray,
    replicas: Sequence[int],
    *,
    heights: Sequence[float] | None = None,
    base_seed: int = DEFAULT_BASE_SEED,
    chunk: int = 64,
    scheduler: Any = None,
    workers: int | None = None,
    workdir: str | os.PathLike | None = None,
    progress: bool = False,
    duration: float = 600.0,
    connect_timeout: float = 5.0,
    worker_timeout: float = WORKER_TIMEOUT,
) -> dict[int, dict[str, np.ndarray]]:
    """Monte Carlo replicas (>= 1) of the (period, height) ``cells`` of a campaign (JCGM 101 7.9).

    Replica ``r`` re-simulates the cells marked in ``cells`` ((time, height) bool over the
    simulated heights) with the seed entropy ``(base_seed, r, period_key)`` (docs/seeds.md), as
    Dask tasks of ``chunk`` selected periods, one set of tasks per replica, all submitted
    together.  Like :func:`simulate_campaign` the result does not depend on the chunk size, the
    workers or the scheduler, and with ``workdir`` finished chunks are kept (in
    ``workdir/replica-<r>``) so an interrupted run resumes.

    Returns
    -------
    dict
        Per replica: ``period`` (index into the conditions), ``height`` (m), the
        :data:`~lidarcal.campaign.chunks.OUTPUTS` of every simulated cell (1-D, in period then height
        order).
    """
    with warnings.catch_warnings():  # replica 0 has reported the periods it skips
        warnings.simplefilter("ignore", SkippedPeriodsWarning)
        camp = _prepare(conditions, model, heights, chunk, ())
    cells = np.asarray(cells, dtype=bool)
    if cells.shape != camp.valid.shape:
        raise InputError(f"cells has shape {cells.shape}; expected {camp.valid.shape} (time, height)")
    if any(int(r) < 1 for r in replicas):
        raise InputError(f"replicas are numbered from 1 (replica 0 is simulate_campaign); "
                         f"got {list(replicas)}")
    chunk = int(chunk)
    todo = camp.valid & cells
    sel = np.flatnonzero(todo.any(axis=1))
    model_dict, transport = model.to_dict(), model.to_dict(residuals=True)
    results: dict[tuple[int, int], dict] = {}
    tasks: list[tuple[str, dict]] = []
    bounds: dict[str, tuple[int, int]] = {}
    for r in (int(r) for r in replicas):
        where = None if workdir is None else os.path.join(os.fspath(workdir), f"replica-{r:04d}")
        if where is not None:
            os.makedirs(where, exist_ok=True)
        for a in range(0, sel.size, chunk):
            idx = sel[a:a + chunk]
            extra = {"replica": r, "periods": idx.tolist(), "cells": todo[idx].astype(int).tolist()}
            key = chunk_key(camp.checksum, model_dict, base_seed, a, a + idx.size, camp.z, duration, (),
                            keys=camp.keys[idx], extra=extra)
            if where is not None:
                cached = load_chunk(chunk_path(where, a, a + idx.size, key), key, idx.size, camp.z.size)
                if cached is not None:
                    results[(r, a)] = cached
                    continue
            name = f"lidarcal-replica-{r}-{key[:16]}-{a}"
            bounds[name] = (r, a)
            tasks.append((name, {
                "model": transport, "heights": camp.z, **{k: v[idx] for k, v in camp.arrays.items()},
                "valid": todo[idx], "period_index": idx, "period_key": camp.keys[idx],
                "los": np.zeros(idx.size, dtype=bool), "base_seed": int(base_seed), "replica": r,
                "duration": float(duration), "workdir": where, "key": key, "start": a, "stop": a + idx.size,
            }))
    for name, result in _execute(tasks, scheduler, workers, progress, connect_timeout, worker_timeout):
        results[bounds[name]] = result
    out: dict[int, dict[str, np.ndarray]] = {}
    rows, cols = np.nonzero(todo[sel])
    for r in (int(r) for r in replicas):
        parts = [results[(r, a)] for a in range(0, sel.size, chunk)]
        full = {name: (np.concatenate([p[name] for p in parts], axis=0) if parts
                       else np.empty((0, camp.z.size))) for name in OUTPUTS}
        out[r] = {"period": sel[rows], "height": camp.z[cols],
                  **{name: full[name][rows, cols] for name in OUTPUTS}}
    return out


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
        return self.cond.attrs["lidarcal_conditions_checksum"]


def _prepare(conditions, model, heights, chunk, los_periods) -> _Campaign:
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
    if int(chunk) < 1:
        raise InputError(f"chunk must be >= 1 period; got {int(chunk)}")
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


def _schedule(
    camp: _Campaign, model_dict: dict, base_seed: int, chunk: int, duration: float, workdir,
    transport: dict | None = None,
) -> tuple[dict[int, dict], list[tuple[str, dict]], dict[str, tuple[int, int]]]:
    """Split the periods into chunks; return (cached results by start, tasks to run, task bounds).

    ``model_dict`` (the attribute form) keys the chunks; ``transport`` (the full form, default
    ``model_dict``) is what the tasks carry to the workers.
    """
    if workdir is not None:
        make_workdir(workdir)
    z = camp.z
    results: dict[int, dict] = {}
    tasks: list[tuple[str, dict]] = []
    bounds: dict[str, tuple[int, int]] = {}
    for start in range(0, camp.n, chunk):
        stop = min(start + chunk, camp.n)
        key = chunk_key(camp.checksum, model_dict, base_seed, start, stop, z, duration, tuple(camp.los),
                        keys=camp.keys[start:stop])
        if workdir is not None:
            cached = load_chunk(chunk_path(workdir, start, stop, key), key, stop - start, z.size)
            if cached is not None:
                results[start] = unflatten_los(cached)
                continue
        name = f"lidarcal-chunk-{key[:16]}-{start}-{stop}"
        bounds[name] = (start, stop)
        payload = {
            "model": model_dict if transport is None else transport,
            "heights": z,
            **{k: v[start:stop] for k, v in camp.arrays.items()},
            "valid": camp.valid[start:stop],
            "period_index": np.arange(start, stop),
            "period_key": camp.keys[start:stop],
            "los": np.isin(np.arange(start, stop), camp.los),
            "base_seed": int(base_seed),
            "duration": float(duration),
            "workdir": os.fspath(workdir) if workdir is not None else None,
            "key": key,
            "start": start,
            "stop": stop,
        }
        tasks.append((name, payload))
    return results, tasks, bounds


def _describe(ds: xr.Dataset, camp: _Campaign, model, *, base_seed, chunk, duration, scheduler, workers,
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
        "chunk": chunk,
        "duration": duration,
        "scheduler": scheduler if isinstance(scheduler, str | type(None)) else "distributed.Client",
        "workers": workers,
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
        call=call or f"lidarcal.campaign.simulate_campaign({source!r}, base_seed={base_seed}, chunk={chunk})",
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
    for name in CONDITION_VARIABLES:
        ds[name] = (
            dims,
            cond[name].values[:, hidx],
            {**cond[name].attrs, "coverage_content_type": "modelResult"},
        )
    for name in OUTPUTS:
        ds[name] = (dims, out[name], dict(_OUTPUT_ATTRS[name]))
    flag = valid.astype(np.int8)
    flag[valid & (out["availability"] == 0)] = 2  # the lidar's CNR filter dropped every LOS
    ds["simulated"] = (
        dims,
        flag,
        {
            "long_name": "period simulated at this height (0: skipped, a needed input was missing; "
            "2: simulated but below the lidar's CNR threshold, so no lidar value)",
            "flag_values": np.array([0, 1, 2], dtype=np.int8),
            "flag_meanings": "skipped_missing_input simulated filtered_low_cnr",
            "coverage_content_type": "qualityInformation",
        },
    )
    # the seed entropy of every period, as time variables: position-free, so parts of a campaign
    # concatenate to the whole, and members of an ensemble keep their base seed when joined
    ds["period_key"] = (
        "time",
        np.asarray(keys, dtype=np.int64),
        var_attrs(
            "seed key of the period: whole seconds of its time since 1970-01-01T00:00:00 "
            "(random streams: SeedSequence([base_seed, period_key, round(height_m * 1000)]))",
            "s",
            coverage_content_type="auxiliaryInformation",
        ),
    )
    ds["base_seed"] = (
        "time",
        np.full(cond.sizes["time"], int(base_seed), dtype=np.int64),
        var_attrs("base seed of the Monte Carlo run that simulated the period", "1",
                  coverage_content_type="auxiliaryInformation"),
    )
    if los_data:
        ds = ds.merge(los_variables(los_data, ds.height.values))
    return ds
