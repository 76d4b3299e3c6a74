"""The processes lidarcal starts end with it, and every scheduler gives the same bits (issue 20, items 7, 11).

* A ``lidarcal simulate`` killed with SIGKILL (or SIGTERM) must not leave its worker processes
  or multiprocessing's resource tracker behind: each child is listed with psutil while the run
  is under way, the parent is killed, and every child must be gone within a bounded wait.
* The engine runs with one BLAS thread whatever the caller's BLAS was set to, on every path:
  the process pool, the ``threads`` and ``synchronous`` schedulers in the caller's process, and
  a plain ``dask worker`` the user started; the four give bit-identical records, with the
  ``*_NUM_THREADS`` variables removed from every process's environment.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import psutil
import pytest
import xarray as xr
from threadpoolctl import threadpool_info, threadpool_limits

from lidarcal.campaign import chunks as campaign_chunks
from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import synthetic_conditions
from lidarcal.lidar import LidarModel

LIDARCAL = [sys.executable, "-c", "import sys; from lidarcal.cli import main; sys.exit(main())"]
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")
RESULTS = ("lidar_wind_speed", "lidar_wind_speed_scalar", "lidar_wind_speed_vector", "reference_wind_speed",
           "availability")


def _bare_env() -> dict[str, str]:
    """This environment without the BLAS/OpenMP thread variables (.ci/run exports them)."""
    return {k: v for k, v in os.environ.items() if k not in THREAD_VARS}


def _blas_threads() -> int:
    return max((i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"), default=1)


# ---- item 11: one BLAS thread inside every engine call ------------------------------------------

@pytest.mark.parametrize("scheduler", ["synchronous", "threads"])
def test_engine_runs_with_one_blas_thread_whatever_the_caller_set(monkeypatch, scheduler):
    """In the caller's own process (threads, synchronous) the engine used the caller's BLAS pool."""
    seen: list[int] = []
    original = campaign_chunks.simulate_period

    def probe(*args, **kwargs):
        seen.append(_blas_threads())
        return original(*args, **kwargs)

    monkeypatch.setattr(campaign_chunks, "simulate_period", probe)
    cond = synthetic_conditions(4, (40.0, 80.0), seed=2)
    with threadpool_limits(limits=2, user_api="blas"):  # a caller with a multi-threaded BLAS
        assert _blas_threads() == 2
        simulate_campaign(cond, LidarModel.ideal(),
                          execution=Execution(scheduler=scheduler, workers=2, chunk=1, progress=False))
        assert _blas_threads() == 2  # the caller's setting is given back
    assert seen and set(seen) == {1}, seen


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=30)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_four_execution_paths_give_bit_identical_records_without_blas_variables(tmp_path):
    env = _bare_env()
    cond = tmp_path / "c.nc"
    synthetic_conditions(12, (80.0, 120.0), seed=4).to_netcdf(cond)

    def simulate(name, *extra):
        out = tmp_path / f"{name}.nc"
        cmd = [*LIDARCAL, "simulate", "--conditions", str(cond), "--chunk", "3", "--no-progress",
               "-o", str(out)]
        run = subprocess.run([*cmd, *extra], env=env, capture_output=True, text=True, timeout=400)
        assert run.returncode == 0, run.stderr
        return xr.open_dataset(out)

    runs = {
        "processes": simulate("processes", "--workers", "2"),
        "threads": simulate("threads", "--scheduler", "threads", "--workers", "2"),
        "synchronous": simulate("synchronous", "--scheduler", "synchronous"),
    }
    port = _port()
    address = f"tcp://127.0.0.1:{port}"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env, "cwd": tmp_path}
    scheduler = subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port",
                                  str(port), "--no-dashboard"], **quiet)
    worker = subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nthreads", "2",
                               "--no-nanny", "--no-dashboard", "--host", "127.0.0.1"], **quiet)
    try:
        runs["dask worker"] = simulate("dask_worker", "--scheduler", address)
    finally:
        _stop(worker)
        _stop(scheduler)
    ref = runs["processes"]
    for name, ds in runs.items():
        for var in RESULTS:
            np.testing.assert_array_equal(ds[var].values, ref[var].values, err_msg=f"{name}: {var}")


# ---- item 7: nothing outlives a killed run ------------------------------------------------------

def _alive(procs: list[psutil.Process]) -> list[psutil.Process]:
    out = []
    for p in procs:
        try:
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except psutil.NoSuchProcess:
            pass
    return out


def _describe(procs: list[psutil.Process]) -> list[str]:
    out = []
    for p in procs:
        try:
            out.append(f"{p.pid}: {' '.join(p.cmdline())[:120]}")
        except psutil.Error:
            out.append(str(p.pid))
    return out


@pytest.mark.slow
@pytest.mark.timeout(300)
@pytest.mark.parametrize(("scheduler", "sig", "n_children"), [
    ("processes", signal.SIGKILL, 3),  # two pool workers + the resource tracker
    ("processes", signal.SIGTERM, 3),
    ("local", signal.SIGKILL, 2),  # two LocalCluster workers
])
def test_no_child_survives_a_killed_simulate(tmp_path, scheduler, sig, n_children):
    cond = tmp_path / "c.nc"
    synthetic_conditions(400, (40.0, 80.0), seed=6).to_netcdf(cond)
    work = tmp_path / "work"
    cmd = [*LIDARCAL, "simulate", "--conditions", str(cond), "--scheduler", scheduler, "--workers", "2",
           "--chunk", "2", "--heights", "40", "--no-progress", "--workdir", str(work),
           "-o", str(tmp_path / "s.nc")]
    run = subprocess.Popen(cmd, env=_bare_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    parent = psutil.Process(run.pid)
    children: list[psutil.Process] = []
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and run.poll() is None:
            children = parent.children(recursive=True)
            if len(list(work.glob("chunk-*.npz"))) >= 2 and len(children) >= n_children:
                break
            time.sleep(0.05)
        assert run.poll() is None, "the run ended before it could be killed"
        assert len(children) >= n_children, _describe(children)
        run.send_signal(sig)
        run.wait(timeout=60)
        # bounded wait: the watchdog looks every 0.25 s, PR_SET_PDEATHSIG acts at once
        deadline = time.monotonic() + 10
        while _alive(children) and time.monotonic() < deadline:
            time.sleep(0.1)
        survivors = _alive(children)
        assert not survivors, f"still running after the parent's death: {_describe(survivors)}"
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
        for p in _alive(children):  # never leave a process behind, even when the test fails
            p.kill()


def test_a_pool_worker_whose_parent_is_already_gone_exits_at_once(tmp_path):
    """The guard against the window before ``prctl``: a re-parented worker ends by itself."""
    code = ("import os, sys, time; from lidarcal.campaign.workers import watch_parent; "
            "watch_parent(os.getppid() + 10**6); time.sleep(30); sys.exit(3)")
    proc = subprocess.run([sys.executable, "-c", code], timeout=60)
    assert proc.returncode == -signal.SIGKILL


def test_pool_worker_dies_with_its_parent_thread_kept_alive(tmp_path):
    """A child set up by ``watch_parent`` of a parent that is SIGKILLed ends with it."""
    ready = tmp_path / "grandchild.pid"
    grand = tmp_path / "grandchild.py"
    grand.write_text("import os, sys, time\nfrom lidarcal.campaign.workers import watch_parent\n"
                     "watch_parent(os.getppid())\n"
                     f"open({str(ready)!r}, 'w').write(str(os.getpid()))\ntime.sleep(120)\n")
    code = (f"import subprocess, sys, time\nsubprocess.Popen([sys.executable, {str(grand)!r}])\n"
            "time.sleep(120)\n")
    mid = subprocess.Popen([sys.executable, "-c", code])
    grandchild = None
    try:
        deadline = time.monotonic() + 60
        while not (ready.exists() and ready.read_text()) and time.monotonic() < deadline:
            time.sleep(0.05)
        grandchild = psutil.Process(int(ready.read_text()))
        mid.send_signal(signal.SIGKILL)
        mid.wait(timeout=30)
        deadline = time.monotonic() + 10
        while _alive([grandchild]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive([grandchild])
    finally:
        if mid.poll() is None:
            mid.kill()
            mid.wait()
        if grandchild is not None:
            for p in _alive([grandchild]):
                p.kill()


def test_one_blas_thread_holds_while_threads_overlap():
    """Two threads inside the engine at once: neither sees the other's exit restore the pool."""
    from lidarcal.campaign.workers import one_blas_thread

    seen: list[int] = []
    inside = threading.Barrier(2)
    a_left = threading.Event()

    def a():
        with one_blas_thread():
            inside.wait()
        a_left.set()

    def b():
        with one_blas_thread():
            inside.wait()
            a_left.wait(10)
            seen.append(_blas_threads())  # a has left, b is still inside

    with threadpool_limits(limits=2, user_api="blas"):
        ts = [threading.Thread(target=a), threading.Thread(target=b)]
        for t in ts:
            t.start()
        for t in ts:
            t.join(30)
        assert _blas_threads() == 2
    assert seen == [1]


@pytest.mark.slow
def test_local_cluster_workers_run_the_parent_watchdog():
    """``local_cluster`` preloads campaign.workers into each worker, told the lidarcal process's pid."""
    from distributed import Client

    from lidarcal.campaign import local_cluster

    def probe():
        import os
        import threading

        return ([t.name for t in threading.enumerate() if t.name == "lidarcal-parent-watchdog"],
                os.environ.get("LIDARCAL_PARENT_PID"))

    with local_cluster(2, dashboard_address=None) as lc, Client(lc, set_as_default=False) as client:
        seen = client.run(probe)
    assert len(seen) == 2
    assert all(v == (["lidarcal-parent-watchdog"], str(os.getpid())) for v in seen.values()), seen
