"""The processes and threads that run the engine: one BLAS thread, and no life after their parent.

**One BLAS thread, on every execution path.**  OpenBLAS splits a matrix product over its
threads in a way that changes the last bits of the sums, so a period simulated with two BLAS
threads differs from one simulated with one by ~1e-11 m/s.  :func:`one_blas_thread` holds the
BLAS/OpenMP thread pools of the process at one thread (``threadpoolctl``) while any engine call
is running in it, whatever started the call: the default process pool, the ``threads`` or
``synchronous`` scheduler in the caller's own process, a ``LocalCluster`` worker or a plain
``dask worker`` started by the user.  The environment variables of :data:`BLAS_ENV` are set too
for the processes lidarcal spawns (they take effect before any library is loaded).

**Workers end with their parent.**  A process pool worker blocked on its task queue never sees
its parent die (every worker holds both ends of the queue's pipe), nor does multiprocessing's
resource tracker while a worker is alive.  :func:`init_pool_worker`, the initializer of every
pool worker lidarcal starts, makes the kernel kill the worker when its parent dies
(``prctl(PR_SET_PDEATHSIG, SIGKILL)`` on Linux) and starts a watchdog thread that ends the
worker when it is re-parented (any POSIX system, and the window before the ``prctl``).  With
the workers gone the resource tracker reads end-of-file and exits.  ``LocalCluster`` workers
are preloaded with this module (:func:`dask_setup`) and get the same two guards, on top of
distributed's own parent pipe.

Also here: :func:`quiet_orphaned_gathers`, which keeps distributed's ``AllExit`` (an internal
signal of a gather abandoned after its worker died) out of the log once the run has ended
with its own message.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator

__all__ = ["BLAS_ENV", "PARENT_PID_ENV", "one_blas_thread", "init_pool_worker", "watch_parent",
           "dask_setup", "quiet_orphaned_gathers"]

#: Environment of every simulation worker: one BLAS/OpenMP thread (docs/performance.md).
BLAS_ENV = {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
#: Environment variable carrying the pid of the lidarcal process to a LocalCluster worker.
PARENT_PID_ENV = "LIDARCAL_PARENT_PID"
#: Seconds between two looks of the watchdog at its parent.
WATCH_INTERVAL = 0.25
_PR_SET_PDEATHSIG = 1

_lock = threading.Lock()
_active = 0
_limiter = None


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Hold this process's BLAS and OpenMP pools at one thread while any caller is inside.

    Re-entrant and thread-safe: the first caller in sets the limit, the last one out restores
    the previous numbers, so concurrent engine calls of the ``threads`` scheduler never see a
    pool of more than one thread.
    """
    global _active, _limiter
    with _lock:
        if _active == 0:
            from threadpoolctl import threadpool_limits

            _take_control()
            # looked up afresh each time: a library loaded since (scipy's own OpenBLAS) is covered
            _limiter = threadpool_limits(limits=1)
        _active += 1
    try:
        yield
    finally:
        with _lock:
            _active -= 1
            if _active == 0 and _limiter is not None:
                _take_control()  # the last one out may be another thread than the first one in
                _limiter.restore_original_limits()
                _limiter = None
                _take_control()  # and leave no thread in control, as before


def _take_control() -> None:
    """Let this thread set OpenBLAS's (process-wide) thread count.

    threadpoolctl >= 3.8 lets only one "controlling" Python thread change a pthreads OpenBLAS
    and silently ignores the others: the first thread that ever set a limit (the caller's main
    thread, say) would keep the ``threads`` scheduler's workers from setting one.  Inside the
    engine lidarcal needs the limit whatever thread it runs in.
    """
    from threadpoolctl import OpenBLASController

    clear = getattr(OpenBLASController, "clear_controlling_thread", None)  # threadpoolctl >= 3.8
    if clear is not None:
        clear(force=True)


def _exit_now() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _watch(ppid: int, interval: float) -> None:
    while os.getppid() == ppid:
        time.sleep(interval)
    _exit_now()  # re-parented: the process that started us is gone


def watch_parent(ppid: int, interval: float = WATCH_INTERVAL) -> None:
    """End this process when process ``ppid`` (its parent) dies, however it dies.

    On Linux the kernel is asked to send SIGKILL on the parent's death (``PR_SET_PDEATHSIG``);
    everywhere a daemon thread checks every ``interval`` s that the parent is still ``ppid``.
    A parent already gone when this is called ends the process at once.
    """
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != ppid:
        _exit_now()
    threading.Thread(target=_watch, args=(ppid, interval), name="lidarcal-parent-watchdog",
                     daemon=True).start()


def init_pool_worker(ppid: int) -> None:
    """Set up a process-pool worker lidarcal starts (its initializer): die with ``ppid``."""
    watch_parent(ppid)


def dask_setup(worker=None) -> None:
    """Run as the distributed preload hook (``distributed.worker.preload``): die with the lidarcal process.

    The lidarcal process that started the ``LocalCluster`` passes its pid in
    :data:`PARENT_PID_ENV`; a worker without it (a user's own ``dask worker`` that preloads this
    module by mistake) is left alone.
    """
    ppid = os.environ.get(PARENT_PID_ENV)
    if ppid and ppid.isdigit():
        watch_parent(int(ppid))


class _DropAllExit(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if exc is not None and type(exc).__name__ == "AllExit":
            return False
        return "AllExit" not in record.getMessage()


_FILTER = _DropAllExit()


def quiet_orphaned_gathers() -> None:
    """Keep distributed's internal ``AllExit`` out of the log (idempotent).

    When a worker dies while its result is being fetched, distributed abandons the gather; the
    abandoned asyncio task later fails with ``distributed.client.AllExit`` and asyncio logs it
    as "Task exception was never retrieved" with a traceback, after lidarcal has already said
    what happened.  The record carries nothing for the user and is dropped.
    """
    for name in ("asyncio", "distributed.client", "distributed.utils"):
        logger = logging.getLogger(name)
        if _FILTER not in logger.filters:
            logger.addFilter(_FILTER)
