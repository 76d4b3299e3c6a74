"""Where a campaign's chunks run: local pools, a ``distributed.LocalCluster`` or a running scheduler.

:func:`execute` runs :class:`~lidarcal.campaign.chunks.ChunkTask` chunks with
:func:`lidarcal.campaign.chunks.run_chunk` where the run's
:class:`~lidarcal.campaign.settings.Execution` says and yields each finished chunk. It holds what
the execution needs and nothing about the campaign itself: starting a cluster
(:func:`local_cluster`, with :data:`WORKER_CONFIG`), one BLAS thread in the workers, connecting to a
scheduler, the version probe of its workers, the polling that turns a lost worker or scheduler into
one :class:`~lidarcal.errors.ComputeError`, and sharing the model the tasks have in common. The
seeds, the chunking and the artefact are :mod:`lidarcal.campaign.run`.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import os
import sys
import time
import types
import uuid
import warnings
from collections.abc import Iterator
from typing import Any

from lidarcal import __version__
from lidarcal.campaign.chunks import ChunkTask, run_chunk
from lidarcal.campaign.progress import Progress, Tracker
from lidarcal.campaign.settings import WORKER_TIMEOUT, Execution
from lidarcal.campaign.workers import BLAS_ENV, PARENT_PID_ENV, init_pool_worker, quiet_orphaned_gathers
from lidarcal.errors import ComputeError, InputError

__all__ = ["execute", "local_cluster", "WORKER_CONFIG", "WORKER_PRELOAD", "WORKER_TIMEOUT"]

log = logging.getLogger(__name__)

#: Dask configuration for the worker processes lidarcal starts itself.  distributed sets
#: ``MALLOC_TRIM_THRESHOLD_=65536`` in every nanny-spawned worker; any value of it switches off
#: glibc's adaptive mmap threshold, so the engine's temporaries are mapped and unmapped on every
#: call and a period costs 1.5x the CPU (measured: 40-45 against 27 ms; docs/performance.md).
WORKER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
#: LocalCluster workers import campaign.workers at start: they end with the lidarcal process.
WORKER_PRELOAD = {"distributed.worker.preload": ["lidarcal.campaign.workers"]}


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
    with _blas_env(), _workers_skip_main(), dask.config.set({**WORKER_CONFIG, **WORKER_PRELOAD}):
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


@contextlib.contextmanager
def _workers_skip_main() -> Iterator[None]:
    """Start worker processes that import lidarcal, not the user's ``__main__`` script.

    The spawn start method runs the parent's main script (or module) again in every new
    process, so that functions defined there can be unpickled.  The chunks need only lidarcal
    (and dask's cloudpickle sends anything defined in ``__main__`` by value), while a script that
    calls :func:`lidarcal.calibrate` at top level, without an ``if __name__ == "__main__":``
    guard, would run the calibration again in every worker.  So while the pool starts,
    multiprocessing sees a bare ``__main__`` with no file to run.
    """
    main = sys.modules.get("__main__")
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        if main is None:
            del sys.modules["__main__"]
        else:
            sys.modules["__main__"] = main


def _connect(address: str, timeout: float):
    from distributed import Client

    try:
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(
            f"cannot reach the dask scheduler at {address!r} within {timeout:g} s "
            f"({type(exc).__name__}: {exc}); is `dask scheduler` running there?"
        ) from None


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


def _log_dashboard(client, progress: Progress) -> None:
    """Say where the scheduler's dashboard is, once per command (not once per batch of replicas)."""
    with contextlib.suppress(Exception):
        if "dashboard" in client.scheduler_info(n_workers=0).get("services", {}):
            progress.once(f"dask dashboard: {client.dashboard_link}")


def _run_distributed(client, model: dict, tasks: list[ChunkTask], tracker: Tracker,
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
    _log_dashboard(client, tracker.progress)
    _check_workers(client, address, worker_timeout)
    periods = {task.name: task.periods for task in tasks}
    shared = _share_model(client, model)
    futures = {client.submit(run_chunk, task, shared, key=task.name, pure=False): task.name for task in tasks}
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
                tracker.done(periods[name])
                yield name, result
        finished = True
    finally:
        if not finished:
            with contextlib.suppress(Exception):
                client.cancel(list(futures), force=True)
        quiet.setLevel(level)


def _share_model(client, model: dict):
    """Send the model the tasks share (bench residuals: megabytes) to the cluster once, not per task.

    Without this every submitted task carries its own serialised copy, so the client's memory
    grows with the number of tasks in flight (chunks times Monte Carlo replicas).  The model is
    the result of one task rather than scattered data: if every worker holding it dies, the
    scheduler computes it again on the next worker that joins (scattered data would be lost,
    and with it every chunk that needs it).
    """
    try:
        with warnings.catch_warnings():  # "large object in task graph": sent once, on purpose
            warnings.simplefilter("ignore", UserWarning)
            return client.submit(_shared_model, model, pure=False, key=f"lidarcal-model-{uuid.uuid4().hex}")
    except Exception as exc:  # comm closed, timeout: the scheduler is unreachable
        address = str(getattr(getattr(client, "scheduler", None), "address", None) or "the scheduler")
        raise _scheduler_gone(address, exc) from None


def _shared_model(model):
    """Return ``model``: the task whose result the chunks share (:func:`_share_model`)."""
    return model


def _run_local(
    model: dict, tasks: list[ChunkTask], scheduler: str, workers: int | None, tracker: Tracker
) -> Iterator[tuple[str, dict]]:
    import dask
    from dask.callbacks import Callback

    # the model (bench residuals: tens of thousands of list items) is one node of the graph that every
    # chunk depends on, not an argument of each: dask walks a call's arguments for collections, and
    # walking the model once per chunk cost the client ~0.1 s of CPU a chunk (a year's SMC: minutes)
    shared = dask.delayed(model, name=f"lidarcal-model-{uuid.uuid4().hex}", traverse=False)
    delayed = [dask.delayed(run_chunk, pure=False)(task, shared, dask_key_name=task.name)
               for task in tasks]
    kw: dict[str, Any] = {"scheduler": scheduler}
    if scheduler in ("processes", "threads") and workers:
        kw["num_workers"] = int(workers)
    if scheduler == "processes":  # one chunk per dispatch (dask's default is 6): each is reported as it
        kw["chunksize"] = 1  # finishes, and a few long chunks are not queued behind one worker
    periods = {task.name: task.periods for task in tasks}

    def finished(key, result, dsk, state, worker_id) -> None:
        if key in periods:
            tracker.done(periods[key])

    with _blas_env(), contextlib.ExitStack() as stack:
        stack.enter_context(Callback(posttask=finished))
        if scheduler == "processes":  # pool workers die with this process (campaign.workers)
            stack.enter_context(dask.config.set({
                "multiprocessing.context": "spawn",
                "multiprocessing.initializer": functools.partial(init_pool_worker, os.getpid()),
            }))
            stack.enter_context(_workers_skip_main())
        results = dask.compute(*delayed, **kw)
    yield from zip((task.name for task in tasks), results, strict=True)


def execute(model: dict, tasks: list[ChunkTask], execution: Execution) -> Iterator[tuple[str, dict]]:
    """Run the chunk ``tasks`` of ``model`` as ``execution`` says; yield each ``(task name, result)``.

    ``execution.scheduler`` is a dask scheduler name, ``"local"``, an address or a
    ``distributed.Client`` (see :mod:`lidarcal.campaign.run`); faults end with one
    :class:`~lidarcal.errors.ComputeError`.  ``execution.progress`` reports the periods of the
    finished chunks.
    """
    if not tasks:
        return
    with execution.progress.tracker(sum(task.periods for task in tasks), len(tasks)) as tracker:
        yield from _execute(model, tasks, execution.scheduler, execution.workers, tracker,
                            execution.connect_timeout, execution.worker_timeout)


def _execute(model, tasks, scheduler, workers, tracker: Tracker, connect_timeout,
             worker_timeout) -> Iterator[tuple[str, dict]]:
    if scheduler is None:
        scheduler = "processes"
    if hasattr(scheduler, "submit"):  # a distributed.Client
        yield from _run_distributed(scheduler, model, tasks, tracker, worker_timeout)
        return
    if not isinstance(scheduler, str):
        raise InputError(
            f"scheduler must be None, a name, an address or a distributed.Client; got {scheduler!r}"
        )
    if "://" in scheduler:
        client = _connect(scheduler, connect_timeout)
        try:
            yield from _run_distributed(client, model, tasks, tracker, worker_timeout)
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
            yield from _run_distributed(client, model, tasks, tracker, worker_timeout)
        return
    if scheduler not in ("processes", "threads", "synchronous", "sync", "single-threaded"):
        raise InputError(
            f"unknown scheduler {scheduler!r}; use 'processes', 'threads', 'synchronous', 'local', "
            f"an address such as 'tcp://127.0.0.1:8786', or a distributed.Client"
        )
    yield from _run_local(model, tasks, scheduler, workers, tracker)
