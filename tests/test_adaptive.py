"""Adaptive Monte Carlo (JCGM 101 7.9, issue 16 section 2): replicas, seeds, invariance, resume, agreement."""

import numpy as np
import pytest

from lidarcal.analysis.rule import CertificationRule
from lidarcal.campaign import scheduler as campaign_scheduler
from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.adaptive import _batches, adaptive_replicas
from lidarcal.campaign.chunks import OUTPUTS, period_keys, seed_entropy
from lidarcal.campaign.run import simulate_replicas
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import synthetic_conditions
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.lidar import LidarModel, simulate_period

DURATION = 120.0  # s per period: a fifth of the work of a 10-minute period, same code paths


@pytest.fixture(scope="module")
def model():
    return LidarModel.ideal()


@pytest.fixture(scope="module")
def cond():
    return synthetic_conditions(10, (40, 120), seed=11)


@pytest.fixture(scope="module")
def cells(cond):
    """Some (period, height) cells: every other period at 40 m, periods 3-7 at 120 m."""
    mask = np.zeros((cond.sizes["time"], cond.sizes["height"]), dtype=bool)
    mask[::2, 0] = True
    mask[3:8, 1] = True
    return mask


def _same(a, b):
    assert sorted(a) == sorted(b)
    for r in a:
        for name in ("period", "height", *OUTPUTS):
            np.testing.assert_array_equal(a[r][name], b[r][name], err_msg=f"replica {r} {name}")


def test_replica_seeds_are_independent_streams_and_replica_0_keeps_todays():
    assert seed_entropy(7, 123) == seed_entropy(7, 123, 0) == (7, 123)  # the streams before replicas
    assert seed_entropy(7, 123, 2) == (7, 2, 123)
    assert seed_entropy(7, -1, 1) == (7, 1, 2**64 - 1)
    # the first check as soon as a replica scatter exists (h = 2), then at h = 4, 8, 16, 24, 30
    assert _batches(30) == [[1], [2, 3], [4, 5, 6, 7], list(range(8, 16)), list(range(16, 24)),
                            list(range(24, 30))]
    assert _batches(1) == [] and _batches(3) == [[1], [2]]


def test_a_replica_trial_is_the_engine_run_with_its_own_seed(cond, model, cells):
    """Independent reference: each trial equals simulate_period called directly with (base, r, key)."""
    out = simulate_replicas(cond, model, cells, [1, 3],
                            execution=Execution(scheduler="synchronous", chunk=4), duration=DURATION,
                            base_seed=99)
    keys = period_keys(cond["time"].values)
    heights = cond["height"].values
    for r in (1, 3):
        assert out[r]["period"].size == cells.sum()
        for t in (0, out[r]["period"].size - 1):
            p, z = int(out[r]["period"][t]), float(out[r]["height"][t])
            h = int(np.flatnonzero(heights == z)[0])
            assert cells[p, h]
            inputs = {n: [float(cond[n].values[p, h])] for n in CONDITION_NAMES}
            direct = simulate_period(model, heights=[z], **inputs, seed=(99, r, int(keys[p])),
                                     duration=DURATION)
            assert out[r]["lidar_wind_speed"][t] == direct["lidar_wind_speed"][0]
            assert out[r]["reference_wind_speed"][t] == direct["reference_wind_speed"][0]
    assert not np.array_equal(out[1]["lidar_wind_speed"], out[3]["lidar_wind_speed"])
    # replica 0 is the campaign itself: (base, key) as before replicas existed
    zero = simulate_campaign(cond, model,
                             execution=Execution(scheduler="synchronous"), duration=DURATION, base_seed=99)
    inputs = {n: [float(cond[n].values[0, 0])] for n in CONDITION_NAMES}
    direct = simulate_period(model, heights=[40.0], **inputs, seed=(99, int(keys[0])), duration=DURATION)
    assert zero["lidar_wind_speed"].values[0, 0] == direct["lidar_wind_speed"][0]


def test_replicas_resume_from_the_workdir_bit_identical(cond, model, cells, tmp_path, monkeypatch):
    work = tmp_path / "work"
    first = simulate_replicas(cond, model, cells, [1, 2],
                              execution=Execution(scheduler="synchronous", chunk=3, workdir=work),
                              duration=DURATION)
    files = sorted(work.glob("replica-*/chunk-*.npz"))
    assert len(files) == 2 * 3  # 8 selected periods in chunks of 3, per replica
    monkeypatch.setattr(campaign_scheduler, "run_chunk",
                        lambda task, model: pytest.fail("recomputed a finished chunk"))
    _same(simulate_replicas(cond, model, cells, [1, 2],
                            execution=Execution(scheduler="synchronous", chunk=3, workdir=work),
                            duration=DURATION), first)
    monkeypatch.undo()
    files[1].unlink()  # interrupted before this chunk was written: it is simulated again, the same
    files[4].write_bytes(b"torn")
    _same(simulate_replicas(cond, model, cells, [1, 2],
                            execution=Execution(scheduler="synchronous", chunk=3, workdir=work),
                            duration=DURATION), first)


@pytest.mark.slow
def test_replicas_do_not_depend_on_workers_scheduler_or_chunk(cond, model, cells):
    one = simulate_replicas(cond, model, cells, [1, 2],
                            execution=Execution(scheduler="processes", workers=1, chunk=5),
                            duration=DURATION)
    two = simulate_replicas(cond, model, cells, [1, 2],
                            execution=Execution(scheduler="processes", workers=2, chunk=2),
                            duration=DURATION)
    _same(one, two)
    _same(one, simulate_replicas(cond, model, cells, [1, 2],
                                 execution=Execution(scheduler="synchronous", chunk=100),
                                 duration=DURATION))


@pytest.mark.slow
def test_two_seeds_agree_on_every_certified_value_within_their_tolerances(model):
    """JCGM 101 7.9 end to end: two calibrations with different seeds, each stating its tolerances.

    Every value of a bin both certify — the estimate, its standard uncertainty, both ends of the
    coverage interval and U — differs between the two by at most the sum of the tolerances the
    two runs state for it (each a 95 % half-width rounded up to 1/2 10^l).  A small campaign
    (90 two-minute periods at one height, 8 to 18 periods a bin) settles one significant digit.
    """
    cond = synthetic_conditions(90, (80, 120), seed=3)
    results = []
    for seed in (1, 2):
        zero = simulate_campaign(cond, model, heights=[120.0], base_seed=seed, duration=DURATION,
                                 execution=Execution(scheduler="synchronous"))
        records, bud = adaptive_replicas(zero, cond, model, base_seed=seed, max_replicas=16,
                                         duration=DURATION, execution=Execution(scheduler="synchronous"),
                                         rule=CertificationRule(significant_digits=1))
        # replicas never touch replica 0
        for name in ("lidar_wind_speed", "reference_wind_speed"):
            np.testing.assert_array_equal(records[name].values, zero[name].values)
        assert bud.attrs["monte_carlo_replicas"] >= 2 and records.sizes["trial"] > 0
        assert bud.attrs["monte_carlo_trials"] == int(bud.sample_count.sum())
        results.append(bud)
    a, b = results
    both = (a.bin_flag == 0) & (b.bin_flag == 0)
    assert int(both.sum()) >= 3
    pairs = {"relative_mean_difference": "numerical_tolerance_mean_difference",
             "relative_error_standard_uncertainty": "numerical_tolerance_error_standard_uncertainty",
             "relative_coverage_interval_lower": "numerical_tolerance_coverage_interval_lower",
             "relative_coverage_interval_upper": "numerical_tolerance_coverage_interval_upper",
             "relative_expanded_uncertainty": "numerical_tolerance"}
    for value, tolerance in pairs.items():
        va, vb = a[value].where(both), b[value].where(both)
        ta, tb = a[tolerance].where(both), b[tolerance].where(both)
        assert int(np.isfinite(ta).sum()) == int(both.sum()) == int(np.isfinite(tb).sum()), value
        gap = abs(va - vb)
        assert bool((gap <= ta + tb).where(both, True).all()), (value, gap.values, ta.values, tb.values)


def test_simulate_with_replicas_then_budget_on_the_command_line(tmp_path, capsys):
    """``simulate --max-replicas`` stores the trials; ``budget`` pools them and states the tolerance."""
    from lidarcal.cli import main
    from lidarcal.io import open_artefact

    cond_path = tmp_path / "c.nc"
    synthetic_conditions(30, (80, 120), seed=4).to_netcdf(cond_path)
    sim, bud = tmp_path / "sim.nc", tmp_path / "b.nc"
    assert main(["simulate", "--conditions", str(cond_path), "--heights", "120", "--duration", "120",
                 "--scheduler", "synchronous", "--max-replicas", "4", "--min-periods", "3",
                 "-o", str(sim)]) == 0
    assert "Monte Carlo: 4 replica(s)" in capsys.readouterr().out
    assert main(["budget", str(sim), "--min-periods", "3", "-o", str(bud)]) == 0
    b = open_artefact(bud, "uncertainty_budget")
    records = open_artefact(sim, "simulated_rtd")
    assert b.attrs["monte_carlo_replicas"] == 4 and set(np.unique(records.trial_replica.values)) == {1, 2, 3}
    # every bin certified but for its numerical state is assessed and states its tolerances; those that
    # did not settle within the 4 replicas are flagged not_settled, never certified
    assessed = b.numerical_flag <= 1
    assert int(assessed.sum()) >= 1
    for name in ("numerical_tolerance", "numerical_tolerance_mean_difference",
                 "numerical_tolerance_coverage_interval_lower",
                 "numerical_tolerance_coverage_interval_upper"):
        assert int(np.isfinite(b[name].where(assessed)).sum()) == int(assessed.sum()), name
    assert bool((b.bin_flag.where(b.numerical_flag == 1) == 4).where(b.numerical_flag == 1, True).all())
    assert bool((b.bin_flag.where(b.numerical_flag == 0) == 0).where(b.numerical_flag == 0, True).all())
    certified = assessed
    assert int(b.sample_count.sum()) == int(np.isfinite(records.lidar_wind_speed).sum()) + int(
        (np.isfinite(records.trial_lidar_wind_speed) & np.isfinite(records.trial_reference_wind_speed)).sum())
    assert bool((b.period_count <= b.sample_count).all())
    assert bool((b.period_count.where(certified, 99) >= 3).all())
