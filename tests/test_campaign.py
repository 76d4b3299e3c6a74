"""Tests of lidarcal.campaign: determinism across schedulers/chunks/workers, resume, errors."""

import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

from lidarcal.campaign import BLAS_ENV, simulate_campaign
from lidarcal.campaign import scheduler as campaign_scheduler
from lidarcal.campaign.settings import Execution
from lidarcal.compliance import check_compliance
from lidarcal.conditions import SkippedPeriodsWarning, synthetic_conditions
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.lidar import LidarModel, simulate_period
from lidarcal.schema import validate_dataset

LIDARCAL = [sys.executable, "-c", "import sys; from lidarcal.cli import main; sys.exit(main())"]
RESULTS = [
    "lidar_wind_speed",
    "lidar_wind_speed_scalar",
    "lidar_wind_speed_vector",
    "reference_wind_speed",
    "availability",
    "simulated",
    "period_key",
    "base_seed",
]


@pytest.fixture(scope="module")
def model():
    return LidarModel.ideal()


@pytest.fixture(scope="module")
def cond():
    return synthetic_conditions(24, (40, 80, 120), seed=5)


@pytest.fixture(scope="module")
def reference(cond, model):
    """The in-process, single-chunk result every other configuration must reproduce bit for bit."""
    return simulate_campaign(cond, model, execution=Execution(scheduler="synchronous", chunk=1000))


def assert_same_results(a, b):
    for name in RESULTS:
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)  # bit-identical
    assert a.attrs["lidarcal_base_seed"] == b.attrs["lidarcal_base_seed"]
    assert a.attrs["lidarcal_lidar_model"] == b.attrs["lidarcal_lidar_model"]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_result_is_the_engine_run_per_period(cond, model, reference):
    assert reference.sizes == {"time": 24, "height": 3}
    assert reference.lidar_wind_speed.attrs["units"] == "m s-1"
    # the seed key is the period's time in whole seconds since 1970, computed here independently
    seconds = [int(pd.Timestamp(t).timestamp()) for t in cond.time.values]
    assert reference.period_key.values.tolist() == seconds
    assert reference.base_seed.values.tolist() == [20240101] * 24
    i = 17
    direct = simulate_period(
        model,
        heights=cond.height.values,
        **{
            k: cond[k].values[i]
            for k in (
                "wind_speed",
                "wind_from_direction",
                "turbulence_intensity",
                "wind_shear_exponent",
                "cnr",
                "cnr_gradient",
            )
        },
        seed=(20240101, seconds[i]),
    )
    for name in ("lidar_wind_speed", "reference_wind_speed"):
        np.testing.assert_array_equal(reference[name].values[i], direct[name])
    # physics sanity: lidar and reference agree to within a few percent on average (ideal
    # lidar, 0.1 m/s LOS noise; 72 period-heights of ~1 % scatter each)
    rel = (reference.lidar_wind_speed - reference.reference_wind_speed) / reference.reference_wind_speed
    assert abs(float(rel.mean())) < 0.03


@pytest.mark.parametrize(
    "scheduler,workers,chunk", [("threads", 2, 3), ("processes", 2, 5), ("synchronous", 1, 7)]
)
def test_bit_identical_for_any_scheduler_workers_and_chunk(cond, model, reference, scheduler, workers, chunk):
    ds = simulate_campaign(cond, model,
                           execution=Execution(scheduler=scheduler, workers=workers, chunk=chunk))
    assert_same_results(ds, reference)


def test_height_subset_and_seed(cond, model, reference):
    sub = simulate_campaign(cond, model, heights=[120, 40],
                            execution=Execution(scheduler="synchronous", chunk=8))
    assert sub.height.values.tolist() == [40.0, 120.0]
    np.testing.assert_array_equal(sub.lidar_wind_speed.values, reference.lidar_wind_speed.values[:, [0, 2]])
    other = simulate_campaign(cond, model, heights=[40], base_seed=7,
                              execution=Execution(scheduler="synchronous"))
    assert not np.array_equal(other.lidar_wind_speed.values[:, 0], reference.lidar_wind_speed.values[:, 0])
    assert other.attrs["lidarcal_base_seed"] == 7


def test_nan_periods_are_skipped_and_reported(cond, model, reference):
    bad = cond.copy(deep=True)
    bad["cnr"][3, 1] = np.nan
    bad["wind_speed"][10, :] = np.nan
    with pytest.warns(SkippedPeriodsWarning, match=r"4 \(period, height\)"):
        ds = simulate_campaign(bad, model, execution=Execution(scheduler="synchronous", chunk=4))
    assert ds.attrs["lidarcal_skipped_count"] == 4
    assert ds.simulated.values[3].tolist() == [1, 0, 1] and ds.simulated.values[10].tolist() == [0, 0, 0]
    assert np.isnan(ds.lidar_wind_speed.values[3, 1]) and np.isnan(ds.lidar_wind_speed.values[10]).all()
    # every other value is exactly the unperturbed run (seeds depend on period and height only)
    keep = ds.simulated.values.astype(bool)
    np.testing.assert_array_equal(ds.lidar_wind_speed.values[keep], reference.lidar_wind_speed.values[keep])


def test_unreachable_heights_and_bad_arguments(cond, model):
    low = synthetic_conditions(4, (5, 40), seed=1)
    with pytest.raises(InputError, match=r"height 5 m needs range .* below the lidar"):
        simulate_campaign(low, model, execution=Execution(scheduler="synchronous"))
    with pytest.raises(InputError, match=r"height 40 m needs range"):
        simulate_campaign(
            cond, LidarModel.ideal(zero_distance_offset=-60.0), heights=[40],
            execution=Execution(scheduler="synchronous")
        )
    with pytest.raises(InputError, match=r"height 50 m is not in the conditions; available heights"):
        simulate_campaign(cond, model, heights=[50])
    with pytest.raises(InputError, match="los_periods"):
        simulate_campaign(cond, model, los_periods=[99])
    with pytest.raises(InputError, match="unknown scheduler 'gpu'"):
        simulate_campaign(cond, model, execution=Execution(scheduler="gpu"))


def test_unreachable_scheduler_fails_fast(cond, model):
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    t0 = time.perf_counter()
    with pytest.raises(
        InputError, match=r"cannot reach the dask scheduler at 'tcp://127\.0\.0\.1:\d+' within 2 s"
    ):
        simulate_campaign(cond, model, execution=Execution(scheduler=address, connect_timeout=2.0))
    assert time.perf_counter() - t0 < 10  # "within a few seconds": 2 s timeout + client teardown


def test_workdir_resume_reuses_finished_chunks(cond, model, reference, tmp_path, monkeypatch):
    work = tmp_path / "work"
    first = simulate_campaign(cond, model,
                              execution=Execution(scheduler="synchronous", chunk=5, workdir=work))
    files = sorted(work.glob("chunk-*.npz"))
    assert [f.name[:21] for f in files] == [
        f"chunk-{a:07d}-{b:07d}" for a, b in [(0, 5), (5, 10), (10, 15), (15, 20), (20, 24)]
    ]
    assert_same_results(first, reference)
    # a rerun must not simulate anything: make any attempt fail loudly
    monkeypatch.setattr(campaign_scheduler, "run_chunk",
                        lambda task, model: pytest.fail("recomputed a cached chunk"))
    again = simulate_campaign(cond, model,
                              execution=Execution(scheduler="synchronous", chunk=5, workdir=work))
    assert_same_results(again, reference)
    monkeypatch.undo()
    # a corrupt cache file is recomputed, not trusted; a different seed does not reuse the cache
    files[1].write_bytes(b"garbage")
    assert_same_results(
        simulate_campaign(cond, model,
                          execution=Execution(scheduler="synchronous", chunk=5, workdir=work)), reference
    )
    simulate_campaign(cond, model, base_seed=1,
                      execution=Execution(scheduler="synchronous", chunk=5, workdir=work))
    assert len(list(work.glob("chunk-*.npz"))) == 10 and not list(work.glob(".*part"))


def test_output_is_a_valid_artefact_with_provenance_and_los(cond, model, tmp_path):
    path = tmp_path / "c.nc"
    cond.to_netcdf(path)
    ds = simulate_campaign(path, model, execution=Execution(scheduler="synchronous"), los_periods=[2, 5])
    assert validate_dataset(ds) == []
    out = write_artefact(ds, tmp_path / "sim.nc")
    report = check_compliance(out)
    assert report.passed, report.failures
    back = open_artefact(out, "simulated_rtd")
    assert LidarModel.from_dict(back.attrs["lidarcal_lidar_model"]) == model
    assert back.attrs["lidarcal_base_seed"] == 20240101
    assert '"role": "conditions"' in back.attrs["lidarcal_inputs"]
    assert back.los_radial_velocity.sizes == {"los_period": 2, "los_time": 600, "height": 3}  # 1 s for 10 min
    assert back.los_period.values.tolist() == [2, 5]
    # each beam contributes 150 samples per period (paper §2.3)
    assert np.bincount(back.los_beam.values).tolist() == [150] * 4
    # the LOS series of period 2 holds the sampled radial velocities: |v_r| <= U sin(28°) + turbulence
    assert np.nanmax(np.abs(back.los_radial_velocity.values)) < 3 * float(cond.wind_speed.max())


def test_cli_simulate_refuses_overwrite_before_work(cond, tmp_path):
    cpath = tmp_path / "c.nc"
    cond.isel(time=slice(0, 3)).to_netcdf(cpath)
    out = tmp_path / "sim.nc"
    cmd = [
        *LIDARCAL,
        "simulate",
        "--conditions",
        str(cpath),
        "--heights",
        "40",
        "--scheduler",
        "synchronous",
        "--no-progress",
        "-o",
        str(out),
    ]
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert "3 periods x 1 heights" in res.stdout
    ds = open_artefact(out, "simulated_rtd")
    assert ds.sizes == {"time": 3, "height": 1}
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 2 and "file exists" in res.stderr
    bad = subprocess.run(
        [
            *LIDARCAL,
            "simulate",
            "--conditions",
            str(cpath),
            "--scheduler",
            f"tcp://127.0.0.1:{free_port()}",
            "--timeout",
            "1",
            "-o",
            str(tmp_path / "x.nc"),
        ],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "cannot reach the dask scheduler" in bad.stderr
    assert not (tmp_path / "x.nc").exists()


@pytest.mark.slow  # ~20 s; SIGKILL + resume stays in the default suite through
# test_pipeline.py::test_killed_calibration_resumes_with_the_same_result (the same chunk cache) and
# test_first_run.py::test_ctrl_c_says_what_it_kept_and_the_resumed_run_what_it_reused (simulate --workdir)
def test_killed_cli_run_resumes_bit_identical(tmp_path, model):
    cond = synthetic_conditions(96, (40, 80), seed=7)
    cpath = tmp_path / "c.nc"
    cond.to_netcdf(cpath)
    work, out = tmp_path / "work", tmp_path / "sim.nc"
    cmd = [
        *LIDARCAL,
        "simulate",
        "--conditions",
        str(cpath),
        "--scheduler",
        "synchronous",
        "--chunk",
        "4",
        "--workdir",
        str(work),
        "--no-progress",
        "-o",
        str(out),
    ]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while len(list(work.glob("chunk-*.npz"))) < 4 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.01)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done = {p: p.stat().st_mtime_ns for p in work.glob("chunk-*.npz")}
    assert 4 <= len(done) < 24 and not out.exists()
    res = subprocess.run(cmd, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert all(p.stat().st_mtime_ns == t for p, t in done.items())  # finished chunks were not redone
    assert len(list(work.glob("chunk-*.npz"))) == 24
    resumed = open_artefact(out)
    uninterrupted = simulate_campaign(cond, model, execution=Execution(scheduler="synchronous", chunk=24))
    assert_same_results(resumed, uninterrupted)


# -- a real dask.distributed cluster: `dask scheduler` + two `dask worker --nthreads 1` --------------


class Cluster:
    def __init__(self, tmp_path, nanny=True):
        self.port = free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        env = {**os.environ, **BLAS_ENV}
        dask_cli = [sys.executable, "-m", "dask"]
        self.procs = [
            subprocess.Popen(
                [*dask_cli, "scheduler", "--host", "127.0.0.1", "--port", str(self.port), "--no-dashboard"],
                env=env,
                cwd=tmp_path,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        ]
        self.workers = [
            subprocess.Popen(
                [
                    *dask_cli,
                    "worker",
                    self.address,
                    "--nthreads",
                    "1",
                    "--nworkers",
                    "1",
                    "--no-dashboard",
                    "--host",
                    "127.0.0.1",
                    *([] if nanny else ["--no-nanny"]),
                ],
                env=env,
                cwd=tmp_path,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            for _ in range(2)
        ]
        self.procs += self.workers

    def close(self):
        for p in reversed(self.procs):
            if p.poll() is None:
                p.terminate()
        for p in self.procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture
def cluster(tmp_path, request):
    from distributed import Client

    c = Cluster(tmp_path, nanny=getattr(request, "param", True))
    try:
        client = Client(c.address, timeout=30, set_as_default=False)
        client.wait_for_workers(2, timeout=60)
        yield c, client
        client.close()
    finally:
        c.close()


def test_distributed_cluster_bit_identical(cluster, cond, model, reference):
    c, client = cluster
    by_address = simulate_campaign(cond, model, execution=Execution(scheduler=c.address, chunk=4))
    assert_same_results(by_address, reference)
    by_client = simulate_campaign(cond, model, execution=Execution(scheduler=client, chunk=6))
    assert_same_results(by_client, reference)
    # each worker ran with one BLAS thread
    envs = client.run(lambda: os.environ.get("OPENBLAS_NUM_THREADS"))
    assert set(envs.values()) == {"1"} and len(envs) == 2


def test_local_cluster_workers_keep_glibcs_malloc_tuning():
    """distributed's nannies set MALLOC_TRIM_THRESHOLD_=65536, which made every period 1.5x dearer
    (docs/performance.md): the workers lidarcal starts must not have it, and keep one BLAS thread."""
    from distributed import Client

    from lidarcal.campaign import local_cluster

    with local_cluster(1, dashboard_address=None) as lc, Client(lc, set_as_default=False) as client:
        envs = client.run(lambda: tuple(os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_",
                                                                    "OPENBLAS_NUM_THREADS")))
    assert list(envs.values()) == [(None, "1")]


@pytest.mark.parametrize("cluster", [False], indirect=True)  # no nanny: a killed worker stays dead
def test_lost_worker_costs_time_not_data(cluster, model, tmp_path):
    import threading

    c, client = cluster
    cond = synthetic_conditions(100, (40, 80, 120), seed=9)
    expected = simulate_campaign(cond, model, execution=Execution(scheduler="synchronous", chunk=100))
    work = tmp_path / "work"
    box = {}

    def target():
        try:
            box["ds"] = simulate_campaign(cond, model,
                                          execution=Execution(scheduler=client, chunk=2, workdir=work))
        except BaseException as exc:  # reported by the assertion below
            box["error"] = exc

    thread = threading.Thread(target=target)
    thread.start()
    deadline = time.time() + 120
    while len(list(work.glob("chunk-*.npz"))) < 3 and time.time() < deadline:
        time.sleep(0.01)
    victim = c.workers[0]
    assert thread.is_alive(), "the run finished before a worker could be killed"
    victim.send_signal(signal.SIGKILL)
    victim.wait()
    thread.join(timeout=300)
    assert not thread.is_alive() and "ds" in box, repr(box.get("error"))
    assert len(client.scheduler_info()["workers"]) == 1  # really one worker fewer
    assert_same_results(box["ds"], expected)
    assert len(list(work.glob("chunk-*.npz"))) == 50


def test_periods_below_the_cnr_filter_are_flagged_not_silently_nan(cond):
    # a threshold inside the fixture's CNR range, so that both sides are exercised
    threshold = float(np.round(np.median(cond.cnr.values), 1)) + 0.05
    filtered = LidarModel.ideal(cnr_threshold=threshold)
    ds = simulate_campaign(cond, filtered, execution=Execution(scheduler="synchronous", chunk=8))
    low = cond.cnr.values < threshold
    assert low.any() and (~low).any()
    np.testing.assert_array_equal(ds.simulated.values == 2, low)
    assert np.isnan(ds.lidar_wind_speed.values[low]).all()
    assert np.isfinite(ds.lidar_wind_speed.values[~low]).all()
    assert ds.attrs["lidarcal_filtered_count"] == int(low.sum())
    assert validate_dataset(ds, "simulated_rtd") == []
