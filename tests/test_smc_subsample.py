"""The Monte Carlo route's stratified subsample (``lidarcal.smc.subsample``) and the tolerance it states.

- The selection is a function of the base seed and the campaign only: the same twice, the same
  with the file's periods in another order, another seed another subsample; every bin is
  covered (at most n periods, every period of a bin that has fewer); each turbulence-intensity
  tercile of a bin gets its proportional share.
- On a small campaign, the subsample's trials are the full campaign's at the same cells (bit
  for bit: the seed is the period's), and its per-bin mean deviation and spread agree with the
  full campaign's within 4 of the standard errors the artefact states, on campaigns of seeds
  disjoint from those the spread's comparison gate was chosen on.
"""

import netCDF4
import numpy as np
import pytest
from smc_factories import HEIGHTS, conditions_file, small_certificate

from lidarcal.errors import InputError
from lidarcal.smc import smc, smc_dataset
from lidarcal.smc.subsample import select


def conditions(n, nh=2, seed=1):
    rng = np.random.default_rng(np.random.SeedSequence([seed, 25]))
    speed = rng.gamma(4.0, 2.0, (n, nh))
    x = rng.uniform(size=(n, nh, 3))
    direction = rng.uniform(0, 360, (n, nh))
    return speed, x, direction


EDGES = np.arange(-0.25, 60.0, 0.5)  # every speed of the gamma(4, 2) draws inside


def test_selection_is_deterministic_covers_every_bin_and_is_stratified():
    speed, x, direction = conditions(3000)
    keys = 1_700_000_000 + 600 * np.arange(3000)
    heights = np.array([80.0, 120.0])
    a = select(speed, x, direction, keys, heights, EDGES, 20, 7)
    assert (a == select(speed, x, direction, keys, heights, EDGES, 20, 7)).all()
    # the file's periods in another order: the same periods chosen (keyed by period_key, not position)
    perm = np.random.default_rng(3).permutation(3000)
    b = select(speed[perm], x[perm], direction[perm], keys[perm], heights, EDGES, 20, 7)
    assert (b == a[perm]).all()
    # another base seed: another subsample (of 2 x ~50 bins of which most have more than 20 periods)
    assert (select(speed, x, direction, keys, heights, EDGES, 20, 8) != a).sum() > 100
    for j in range(2):
        bins = np.searchsorted(EDGES, speed[:, j], side="right") - 1
        population = np.bincount(bins, minlength=EDGES.size - 1)
        chosen = np.bincount(bins[a[:, j]], minlength=EDGES.size - 1)
        np.testing.assert_array_equal(chosen, np.minimum(population, 20))  # every bin, at most 20
        assert (population > 20).sum() >= 10
        for k in np.flatnonzero(population > 20):
            mine = bins == k
            ti = x[mine, j, 0]
            tercile = np.argsort(np.argsort(ti)) * 3 // ti.size
            got = np.bincount(tercile[a[mine, j]], minlength=3)
            # systematic sampling along the TI-major order: each tercile's share within one period
            want = 20 * np.bincount(tercile, minlength=3) / ti.size
            assert (np.abs(got - want) < 1.0 + 1e-9).all(), (k, got, want)
    with pytest.raises(InputError, match="at least 2"):
        smc("no-such.nc", monte_carlo=False, periods_per_bin=1)


@pytest.fixture(scope="module")
def cert(tmp_path_factory):
    return small_certificate(tmp_path_factory.mktemp("smc-sub-cert"))


def campaign(tmp_path, per_bin, seed=25):
    """One height (120 m): ``3 * per_bin`` periods uniform over 7.25-8.75 m/s (three bins), six at 10 m/s."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 2]))
    n = 3 * per_bin + 6
    speed = np.concatenate([rng.uniform(7.26, 8.74, 3 * per_bin), rng.uniform(9.76, 10.24, 6)])
    values = {
        "wind_speed": speed[:, None],
        "wind_from_direction": rng.uniform(0, 360, (n, 1)),
        "turbulence_intensity": rng.uniform(0.05, 0.22, (n, 1)),
        "wind_shear_exponent": rng.uniform(0.0, 0.35, (n, 1)),
        "cnr": rng.uniform(-20, -8, (n, 1)),
        "cnr_gradient": rng.uniform(-0.04, 0.04, (n, 1)),
    }
    return conditions_file(tmp_path / "c.nc", values, HEIGHTS[1:]), speed


def test_the_subsample_is_the_full_campaigns_cells_and_is_marked(tmp_path, cert):
    cond, speed = campaign(tmp_path, 16)
    opts = {"scheduler": "synchronous"}
    full = smc(cert, conditions=cond, max_replicas=1, periods_per_bin=None, execution=opts)
    sub = smc(cert, conditions=cond, max_replicas=1, periods_per_bin=6, execution=opts)
    # 6 of each full bin's periods (by their own speed) and the 6 of the small one
    simulated = smc_dataset(sub).monte_carlo_trials.transpose("time", "height").values[:, 0] > 0
    population = np.bincount(np.floor((speed - 7.25) / 0.5).astype(int))
    assert population[:3].min() > 6 and simulated.sum() == 3 * 6 + 6
    assert smc_dataset(full).monte_carlo_trials.transpose("time", "height").values[:, 0].min() == 1
    # bit for bit the full campaign's trials at the same cells (the seed is the period's)
    rec_f, rec_s = full.monte_carlo.records, sub.monte_carlo.records
    at = np.searchsorted(rec_f.period_key.values, rec_s.period_key.values)
    for name in ("lidar_wind_speed", "reference_wind_speed"):
        s = rec_s[name].transpose("time", "height").values[:, 0]
        f = rec_f[name].transpose("time", "height").values[at, 0]
        ok = np.isfinite(s)
        assert ok.sum() == simulated.sum()
        np.testing.assert_array_equal(s[ok], f[ok])
    path = tmp_path / "sub.nc"
    smc_dataset(sub).to_netcdf(path)
    with netCDF4.Dataset(path) as nc:
        flag = np.asarray(nc["monte_carlo_simulated"][:, 0])
        assert nc["monte_carlo_simulated"].flag_meanings == "not_simulated simulated"
        assert nc["bin_simulated_mean_difference_standard_error"].units == "m s-1"
        assert nc["monte_carlo_expected_deviation_standard_error"].units == "m s-1"
        assert nc.getncattr("monte_carlo_periods_per_bin") == "6"
        e = np.asarray(nc["monte_carlo_expected_deviation"][:, 0].filled(np.nan))
        se = np.asarray(nc["monte_carlo_expected_deviation_standard_error"][:, 0].filled(np.nan))
    np.testing.assert_array_equal(flag == 1, simulated)
    # every period has an expected deviation and its standard error, simulated or not
    assert np.isfinite(e).all() and np.isfinite(se).all() and (se > 0).all()


#: Seeds of the campaigns the spread's kurtosis gate (below) was chosen on: seed 25, where the
#: ungated comparison failed (the 7.5 m/s bin: one period of 110 at +0.44 m/s, kurtosis 23), and
#: 101-104, checked after choosing it.  The test asserts on ``ASSERT_SEEDS`` only, a disjoint set
#: that played no part in choosing it (fit on one set, assert on another).
FIT_SEEDS = (25, 101, 102, 103, 104)
ASSERT_SEEDS = (301, 302, 303)


@pytest.mark.slow
@pytest.mark.parametrize("seed", ASSERT_SEEDS)
def test_subsample_agrees_with_the_full_campaign_within_its_stated_tolerance(tmp_path, cert, seed):
    assert seed not in FIT_SEEDS
    # about 150 periods in each of three bins, 50 simulated: the delta method's regime (m >= 10)
    cond, _ = campaign(tmp_path, 150, seed=seed)
    opts = {"scheduler": "synchronous"}
    full = smc(cert, conditions=cond, max_replicas=1, periods_per_bin=None, execution=opts)
    sub = smc(cert, conditions=cond, max_replicas=1, periods_per_bin=50, execution=opts)
    path = tmp_path / "sub.nc"
    smc_dataset(sub).to_netcdf(path)
    # the stated tolerance, read back from the file (netCDF4, no lidarcal)
    with netCDF4.Dataset(path) as nc:
        se_mean = np.asarray(nc["bin_simulated_mean_difference_standard_error"][:, 0].filled(np.nan))
        se_sd = np.asarray(nc["bin_simulated_std_difference_standard_error"][:, 0].filled(np.nan))
        md_s = np.asarray(nc["bin_simulated_mean_difference"][:, 0].filled(np.nan))
        sd_s = np.asarray(nc["bin_simulated_std_difference"][:, 0].filled(np.nan))
        m = np.asarray(nc["bin_simulated_period_count"][:, 0])
        centres = np.asarray(nc["wind_speed_bin"][:])
    # the full campaign's per-bin statistics by hand from its trials (numpy, binned by reference speed)
    rec_f = full.monte_carlo.records
    ref = rec_f.reference_wind_speed.values[:, 0]
    dev = rec_f.lidar_wind_speed.values[:, 0] - ref
    compared = spreads = 0
    for k, c in enumerate(centres):
        mine = np.isfinite(dev) & (ref >= c - 0.25) & (ref < c + 0.25)
        if not np.isfinite(se_mean[k]):  # a subsampled bin of under 10 simulated periods states none
            continue
        md_f, sd_f = dev[mine].mean(), dev[mine].std(ddof=1)
        if se_mean[k] == 0:  # every period of the bin simulated: the same numbers
            assert md_s[k] == pytest.approx(md_f, abs=1e-12) and sd_s[k] == pytest.approx(sd_f, abs=1e-12)
            continue
        # 4 standard errors: a two-sided 6e-5 chance per comparison were the statistics normal (on the
        # fit seeds' campaigns, 101-104, the 24 z-scores spanned -3.1 ... +1.2)
        assert abs(md_s[k] - md_f) <= 4 * se_mean[k], (seed, c, md_s[k], md_f, se_mean[k])
        # the spread's SE is the delta method's normal approximation for s^2, whose relative standard
        # error is sqrt((kurtosis - 1) / m): it is compared where that is under 1/2 (kurtosis, of the
        # full campaign's bin, under 1 + m/4).  A bin whose spread one or two rare bad estimates set is
        # outside it: a subsample that misses them reads low by more than its SE can say (docs/smc.md
        # states this limit).  The gate was chosen on FIT_SEEDS; these seeds are not among them.
        c_f = dev[mine] - md_f
        kurtosis = np.mean(c_f**4) / np.mean(c_f**2) ** 2
        if kurtosis < 1 + m[k] / 4:
            assert abs(sd_s[k] - sd_f) <= 4 * se_sd[k], (seed, c, sd_s[k], sd_f, se_sd[k], kurtosis)
            spreads += 1
        # and the stated SE is of the size the spread says: s / sqrt(m) * sqrt(1 - m / N), N about 150
        # (reference speeds cross the bins' edges: a factor 2 either way)
        nominal = sd_f * np.sqrt(1 / m[k] - 1 / 150)
        assert 0.5 * nominal < se_mean[k] < 2 * nominal
        compared += 1
    # the three subsampled bins compared, and the gate leaves most spreads in (it is for rare bins an
    # outlier dominates, not the rule): at least 2 of 3, fixed before these seeds were run
    assert compared >= 3 and spreads >= 2, (seed, compared, spreads)


def test_the_option_takes_a_count_or_all(capsys):
    from lidarcal.cli import build_parser
    from lidarcal.smc.subsample import DEFAULT_PERIODS_PER_BIN

    def parse(*extra):
        return build_parser().parse_args(["smc", "c.nc", "x.sta", "-o", "s.nc", *extra]).mc_periods_per_bin

    assert parse() == DEFAULT_PERIODS_PER_BIN == 100
    assert parse("--mc-periods-per-bin", "all") is None
    assert parse("--mc-periods-per-bin", "40") == 40
    for bad in ("1", "many"):
        with pytest.raises(SystemExit) as e:
            parse("--mc-periods-per-bin", bad)
        assert e.value.code == 2 and "integer >= 2 or 'all'" in capsys.readouterr().err


@pytest.mark.slow
def test_the_subsampled_route_on_a_cluster_or_a_pool_is_the_synchronous_run_bit_for_bit(tmp_path, cert):
    # issue 25 section 3: the same run on a Dask cluster (--scheduler ADDRESS) bit-identical to the local
    # one; here the route a long campaign takes (a stratified subsample) with further replicas, on a
    # LocalCluster of two worker processes on loopback given by its address, and on the local pool
    from distributed import Client

    from lidarcal.campaign.scheduler import local_cluster

    cond, _ = campaign(tmp_path, 16)
    runs = {}
    with local_cluster(2, dashboard_address=None, host="127.0.0.1") as lc, Client(lc, set_as_default=False):
        for name, opts in (
            ("synchronous", {"scheduler": "synchronous"}),
            ("processes", {"scheduler": "processes", "workers": 2, "chunk": 4}),
            ("cluster", {"scheduler": lc.scheduler_address, "chunk": 3}),
        ):
            c = smc(cert, conditions=cond, max_replicas=4, periods_per_bin=6, execution=opts)
            runs[name] = smc_dataset(c)
    a = runs["synchronous"]
    assert int(a.monte_carlo_simulated.sum()) == 3 * 6 + 6  # the subsample, not every period
    assert int((a.monte_carlo_trials > 1).sum()) > 0  # further replicas ran
    for name in ("processes", "cluster"):
        b = runs[name]
        assert sorted(a.data_vars) == sorted(b.data_vars)
        for v in a.data_vars:
            np.testing.assert_array_equal(a[v].values, b[v].values, err_msg=f"{name}: {v}")
