"""Bad estimates as a property of CNR (issue 24 section 1): classification, p_bad(CNR), draws, replicas.

Independent references: synthetic bench cubes written here with a known planted rate and
search band (and the flags of the planted bad estimates), the sample bench's true response
(``TrueResponse().bad_probability``, which simulated it), per-CNR counts of residuals more than
1 m/s off computed by hand, the noise-free radial velocity of a period without turbulence
computed from the beam geometry, and hand-built pools for the minimum-sample rule.
"""

import json

import numpy as np
import pytest
import xarray as xr
from scipy import stats
from scipy.special import expit

from lidarcal.bench import ingest
from lidarcal.bench.response import TrueResponse
from lidarcal.campaign.chunks import period_keys
from lidarcal.campaign.run import simulate_replicas
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import synthetic_conditions
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.data import sample_file
from lidarcal.errors import InputError
from lidarcal.lidar import LidarModel, simulate_period
from lidarcal.lidar.bad_estimates import MIN_GOOD, BadEstimates, good_pools

CNR = np.arange(-28.0, -4.0, 2.0)
VEL = np.arange(-18.0, 19.0, 1.0)
SHAPE = (5, CNR.size, VEL.size)
CONE = np.radians(28.0)
BAND = (-30.0, 30.0)


def true_rate(c):
    """The sample bench simulator's rate (TrueResponse defaults): 0.5 expit(-(c + 26) / 1.5)."""
    return 0.5 * expit(-(np.asarray(c, float) + 26.0) / 1.5)


def sigma(c):
    """Good-estimate std (m/s) of the sample bench simulator at LOS gain 1, v = 0."""
    return 0.04 + 0.26 * np.exp(-0.2036 * (np.asarray(c, float) + 26.0))


def synthetic_cube(rate, *, n=13, seed=1):
    """A bench_cube whose every bin holds n candidates: Gaussian good estimates, bad ones with
    probability rate(CNR), their *measured* velocity uniform over BAND.  Returns (cube, bad flags)."""
    rng = np.random.default_rng(seed)
    _, c, v = np.meshgrid(np.arange(5), CNR, VEL, indexing="ij")
    bias = 0.01 + 0.0008 * v
    good = bias[..., None] + sigma(c)[..., None] * rng.standard_normal((*SHAPE, n))
    bad = rng.random((*SHAPE, n)) < rate(c)[..., None]
    measured_bad = rng.uniform(*BAND, (*SHAPE, n))
    return cube_of(np.where(bad, measured_bad - v[..., None], good), bias, sigma(c)), bad


def cube_of(residuals, bias=None, std=None):
    dims = ("los", "cnr", "velocity")
    bias = np.zeros(SHAPE) if bias is None else bias
    std = np.full(SHAPE, 0.1) if std is None else std
    return xr.Dataset(
        {"los_bias": (dims, bias, {"units": "m s-1"}), "los_std": (dims, std, {"units": "m s-1"}),
         "sample_count": (dims, np.full(SHAPE, 13, np.int32), {"units": "1"}),
         "los_residual": ((*dims, "sample"), residuals, {"units": "m s-1"})},
        coords={"los": ["0", "90", "180", "270", "V"],
                "los_azimuth": ("los", [0.0, 90.0, 180.0, 270.0, 0.0], {"units": "degree"}),
                "los_elevation": ("los", [62.0, 62.0, 62.0, 62.0, 90.0], {"units": "degree"}),
                "cnr": ("cnr", CNR, {"units": "dB"}), "velocity": ("velocity", VEL, {"units": "m s-1"})},
        attrs={"lidarcal_artefact": "bench_cube", "lidarcal_source_file": "synthetic_cube.nc"})


def relative_deviation(model, *, U, direction, cnr, periods, seed=11):
    """(L - R)/R in % of ``periods`` periods without turbulence or shear (the reference reads U)."""
    out = np.empty(periods)
    for k in range(periods):
        r = simulate_period(model, heights=[200.0], wind_speed=U, wind_from_direction=direction, cnr=cnr,
                            turbulence_intensity=0.0, wind_shear_exponent=0.0, cnr_gradient=0.0,
                            seed=(seed, k))
        out[k] = 100.0 * (r["lidar_wind_speed"][0] / r["reference_wind_speed"][0] - 1.0)
    return out


@pytest.fixture(scope="module")
def clean():
    return synthetic_cube(true_rate, seed=3)


def test_a_planted_outlier_in_a_sparse_bin_no_longer_reads_30_percent_high(clean):
    cube, bad = clean
    # beam 270° (cube row 3), -18 dB, 0 m/s
    row, ci, vi = 3, int(np.flatnonzero(CNR == -18.0)[0]), int(np.flatnonzero(VEL == 0.0)[0])
    assert not bad[row, ci, vi].any()  # the bin the outlier goes into holds none of its own
    planted = cube.copy(deep=True)
    planted["los_residual"].values[row, ci, vi, 0] = -28.5  # one bad estimate among 13
    # the worst period: 3.84 m/s from 184° (beam 270 crosswind, radial velocity -0.13 m/s), -18.1 dB
    period = {"U": 3.84, "direction": 184.0, "cnr": -18.1, "periods": 120}
    old = relative_deviation(LidarModel.from_artefacts(cube=planted, los_noise_model="residuals"), **period)
    old_clean = relative_deviation(LidarModel.from_artefacts(cube=cube, los_noise_model="residuals"),
                                   **period)
    # resampling the bin draws the outlier with probability ~0.95 x 0.87 / 13 per beam-270 sample
    assert old.mean() - old_clean.mean() > 20.0
    with_outlier = LidarModel.from_artefacts(cube=planted)
    without = LidarModel.from_artefacts(cube=cube)
    assert with_outlier.los_noise_model == without.los_noise_model == "mixture"
    new = relative_deviation(with_outlier, **period)
    new_clean = relative_deviation(without, **period)
    # the same 120 seeds for both; treating the two means as independent (their common random numbers
    # only correlate them positively, which shrinks the real scatter of the difference) 4 standard
    # errors bound the difference with a false-alarm probability of 6e-5
    bound = 4.0 * np.sqrt(new.var(ddof=1) / new.size + new_clean.var(ddof=1) / new_clean.size)
    assert abs(new.mean() - new_clean.mean()) < bound, (new.mean(), new_clean.mean(), bound)
    assert new.mean() < 5.0 and bound < 2.0  # far from the +30 % of the resampled outlier
    # one more bad estimate among the 1776 bench candidates at -18 dB moves p_bad(-18) by about 1/1776,
    # within its standard uncertainty
    moved = float(with_outlier.bad_estimates.rate(-18.0) - without.bad_estimates.rate(-18.0))
    assert 0 < moved < float(without.bad_estimates.rate_standard_uncertainty(-18.0))


@pytest.fixture(scope="module")
def sample_cube():
    return ingest(sample_file("bench/rtd.csv.gz"), sample_file("bench/control_log.csv"))


def test_fitted_rate_on_the_sample_bench_against_its_true_response_and_hand_counts(sample_cube):
    model = LidarModel.from_artefacts(cube=sample_cube)
    bad = model.bad_estimates
    assert model.los_noise_model == "mixture" and bad.fit_cnr_min == -24.0  # the -23 dB filter's lowest bin
    assert TrueResponse().velocity_range == 30.0
    # the search band: the simulator's bad estimates are uniform in +-30 m/s; the ends are estimated from
    # ~1,400 flagged values, so to about 60 / 1400 = 0.04 m/s (0.2 m/s: 5 of those)
    assert abs(bad.band[0] + 30.0) < 0.2 and abs(bad.band[1] - 30.0) < 0.2
    assert bad.band_uniformity_p > 0.01  # uniform over the band (KS), as simulated
    # against the response that simulated the bench: within 3 standard uncertainties of the fit at
    # every CNR the filtered lidar uses (-24 to -14 dB; above it the counts are 0 or 1)
    for c in (-24.0, -22.0, -20.0, -18.0, -16.0, -14.0):
        fit, u = float(bad.rate(c)), float(bad.rate_standard_uncertainty(c))
        assert abs(fit - true_rate(c)) < 3.0 * u, (c, fit, u, true_rate(c))
    # hand count: residuals of the four oblique beams more than 1 m/s off; a bad estimate lands within
    # 1 m/s of the truth with probability 2/60, a good one (sigma <= 0.22 m/s here) is > 1 m/s off with
    # probability < 1e-5, so (count / n) / (1 - 2/60) estimates p_bad; binomial error sqrt(p (1 - p) / n)
    res = sample_cube.los_residual.sel(los=["0", "90", "180", "270"])
    for c in (-24.0, -22.0, -20.0, -18.0):
        r = res.sel(cnr=c).values
        n = int(np.isfinite(r).sum())
        hand = (np.abs(r) > 1.0).sum() / n / (1.0 - 2.0 / 60.0)
        fit = float(bad.rate(c))
        u_fit = float(bad.rate_standard_uncertainty(c))
        assert abs(hand - fit) < 4.0 * np.sqrt(fit * (1 - fit) / n) + 2.0 * u_fit
    # the logistic describes the counts (Pearson chi-square of the 10 CNRs' counts grouped so that each
    # group expects at least 5 bad estimates: -24, -22, -20 and -18...-6 dB, 2 degrees of freedom)
    assert bad.fit_dof == 2 and bad.fit_pvalue > 0.01
    # the old statement "0.2 % at -18 dB" holds for the pooled bench; a period of the old model saw a
    # beam bin's own share instead: 0 of 14, 1 of 13 (7.7 %) or 2 of 13 (15 %)
    per_bin = (np.abs(res.sel(cnr=-18.0)) > 1.0).sum("sample") / res.sel(cnr=-18.0).notnull().sum("sample")
    assert set(np.round(np.unique(per_bin.values), 3)) <= {0.0, round(1 / 13, 3), round(1 / 14, 3)}


def test_a_planted_rate_is_recovered_within_its_covariance():
    # p = expit(a0 + b0 (c + 17)): 26 % at -28 dB, 2e-5 at -6 dB; c_ref = mean(CNR) = -17
    a0, b0 = -6.0, -0.45
    cube, bad = synthetic_cube(lambda c: expit(a0 + b0 * (c + 17.0)), n=60, seed=8)
    model = LidarModel.from_artefacts(cube=cube, cnr_threshold=None)
    fit = model.bad_estimates
    assert fit.cnr_reference == -17.0 and fit.fit_cnr_min == -28.0
    diff = np.asarray(fit.rate_parameters) - [a0, b0]
    mahalanobis = float(diff @ np.linalg.inv(np.asarray(fit.rate_covariance)) @ diff)
    assert mahalanobis < stats.chi2.ppf(1 - 1e-4, 2), (fit.rate_parameters, fit.rate_covariance)
    # the planted flags (of the four oblique beams) per CNR against the fitted curve: binomial error
    n = 4 * VEL.size * 60
    planted = bad[:4].sum(axis=(0, 2, 3)) / n
    p = fit.rate(CNR)
    bound = 4.0 * np.sqrt(p * (1 - p) / n) + 3.0 * fit.rate_standard_uncertainty(CNR)
    assert np.all(np.abs(planted - p) < bound)
    n_bad = int(bad[:4].sum())
    assert abs(fit.band[0] - BAND[0]) < 5 * 60 / n_bad and abs(fit.band[1] - BAND[1]) < 5 * 60 / n_bad


def test_drawn_bad_estimates_follow_p_bad(clean):
    cube, _ = clean
    model = LidarModel.from_artefacts(cube=cube)
    lo, hi = model.bad_estimates.band
    U, cnr, periods = 8.0, -21.0, 30
    errors, values = [], []
    for k in range(periods):
        r = simulate_period(model, heights=[100.0], wind_speed=U, wind_from_direction=0.0, cnr=cnr,
                            turbulence_intensity=0.0, wind_shear_exponent=0.0, cnr_gradient=0.0,
                            seed=(5, k), return_los=True)
        truth = -U * np.sin(CONE) * np.cos(np.radians(90.0 * r["los_beam"]))  # wind from north, no turbulence
        errors.append(r["los"][0] - truth)
        values.append(r["los"][0])
    err, los = np.concatenate(errors), np.concatenate(values)
    off = np.abs(err) > 1.0  # a good error (sigma 0.14 m/s at -21 dB) is never 1 m/s off
    # a bad estimate is uniform over the band; it lands within 1 m/s of the truth with probability
    # 2 / (hi - lo)
    p = float(model.bad_estimates.rate(cnr)) * (1.0 - 2.0 / (hi - lo))
    assert abs(off.mean() - p) < 5.0 * np.sqrt(p * (1 - p) / err.size), (off.mean(), p)
    assert np.all((los[off] >= lo) & (los[off] <= hi))
    assert stats.kstest((los[off] - lo) / (hi - lo), "uniform").pvalue > 1e-3  # about 200 values


def test_trials_draw_their_rate_curve_from_the_fit(clean):
    cube, _ = clean
    bad = LidarModel.from_artefacts(cube=cube).bad_estimates
    assert bad.for_trial(7, 0, 5) == bad and bad.for_trial(7, 0, 5).parameters == bad.rate_parameters
    one = bad.for_trial(7, 1, 5)
    assert one == bad.for_trial(7, 1, 5)  # keyed, deterministic
    assert one.drawn != bad.for_trial(7, 2, 5).drawn and one.drawn != bad.for_trial(7, 1, 6).drawn
    assert one.drawn != bad.for_trial(8, 1, 5).drawn
    assert bad.for_trial(7, 1, -5).drawn == bad.for_trial(7, 1, 2**64 - 5).drawn  # keys before 1970 wrap
    # 4000 trials: replicas and periods both vary the draw
    draws = np.array([bad.for_trial(7, r, key).drawn for r in range(1, 41) for key in range(100)])
    cov = np.asarray(bad.rate_covariance)
    # the mean of 4000 draws is within 4 standard errors of the estimate; the sample covariance within
    # 10 % (relative standard error sqrt(2 / 4000) = 2.2 % of a variance)
    se = np.sqrt(np.diag(cov) / draws.shape[0])
    assert np.all(np.abs(draws.mean(axis=0) - bad.rate_parameters) < 4 * se)
    np.testing.assert_allclose(np.cov(draws.T), cov, rtol=0.1, atol=0.1 * np.sqrt(cov[0, 0] * cov[1, 1]))
    # the trial's model simulates the drawn curve: the other models are the same for every trial
    model = LidarModel.from_artefacts(cube=cube)
    assert model.for_trial(7, 1, 5).bad_estimates.drawn == one.drawn
    assert LidarModel.ideal().for_trial(7, 1, 5) == LidarModel.ideal()


REPLICAS = {"duration": 120.0, "base_seed": 99}


@pytest.fixture(scope="module")
def replica_case(clean):
    cube, _ = clean
    model = LidarModel.from_artefacts(cube=cube, cnr_threshold=None)
    cond = synthetic_conditions(6, (60, 120), seed=4)
    cells = np.ones((6, 2), dtype=bool)
    return model, cond, cells, simulate_replicas(cond, model, cells, [1, 2],
                                                 execution=Execution(scheduler="synchronous", chunk=4),
                                                 **REPLICAS)


def test_a_replica_trial_is_the_engine_with_its_own_rate_curve(replica_case):
    model, cond, _, sync = replica_case
    keys = period_keys(cond["time"].values)
    p, h = 3, 1
    inputs = {n: [float(cond[n].values[p, h])] for n in CONDITION_NAMES}
    t = int(np.flatnonzero((sync[2]["period"] == p) & (sync[2]["height"] == 120.0))[0])
    direct = simulate_period(model.for_trial(99, 2, keys[p]), heights=[120.0], **inputs,
                             seed=(99, 2, int(keys[p])), duration=120.0)
    assert sync[2]["lidar_wind_speed"][t] == direct["lidar_wind_speed"][0]
    nominal = simulate_period(model, heights=[120.0], **inputs, seed=(99, 2, int(keys[p])), duration=120.0)
    assert model.for_trial(99, 2, keys[p]).bad_estimates.drawn != model.bad_estimates.rate_parameters
    # another period of the same replica simulates another curve
    other = model.for_trial(99, 2, keys[p + 1]).bad_estimates.drawn
    assert other != model.for_trial(99, 2, keys[p]).bad_estimates.drawn
    assert nominal["reference_wind_speed"][0] == direct["reference_wind_speed"][0]  # the same turbulence


@pytest.mark.slow
def test_mixture_replicas_do_not_depend_on_workers_or_chunk(replica_case):
    model, cond, cells, sync = replica_case
    procs = simulate_replicas(cond, model, cells, [1, 2],
                              execution=Execution(scheduler="processes", workers=2, chunk=2),
                              **REPLICAS)
    for r in (1, 2):
        for name in ("period", "height", "lidar_wind_speed", "reference_wind_speed"):
            np.testing.assert_array_equal(sync[r][name], procs[r][name])  # bit for bit


def test_a_sparse_bin_borrows_good_residuals_from_its_cnr_neighbours():
    count = np.array([[[4], [3], [12], [5]]])  # one beam, four CNRs, one velocity
    values = np.concatenate([
        [0.1, 0.2, 0.3, 25.0],            # CNR 0: 3 good, one bad (25 m/s)
        [1.0, 1.1, 1.2],                  # CNR 1: 3 good
        0.01 * np.arange(12) + 2.0,       # CNR 2: 12 good
        [3.0, 3.1, 3.2, 3.3, -20.0],      # CNR 3: 4 good, one bad
    ])
    threshold = np.array([1.0, 1.0, 1.0, 1.0])
    pools, pooled, own = good_pools(count, values, threshold, min_good=10)
    np.testing.assert_array_equal(own.ravel(), [3, 3, 12, 4])
    start = np.concatenate([[0], np.cumsum(pools.ravel())[:-1]])
    got = [pooled[s:s + n] for s, n in zip(start, pools.ravel(), strict=True)]
    # CNR 0: its 3, then CNR 1 (3): 6 < 10, then CNR 2 (12): 18 >= 10
    np.testing.assert_array_equal(got[0], [0.1, 0.2, 0.3, 1.0, 1.1, 1.2, *(0.01 * np.arange(12) + 2.0)])
    # CNR 1: its 3, then both neighbours at one step (CNR 0's 3 good, CNR 2's 12): 18
    np.testing.assert_array_equal(got[1], [1.0, 1.1, 1.2, 0.1, 0.2, 0.3, *(0.01 * np.arange(12) + 2.0)])
    np.testing.assert_array_equal(got[2], 0.01 * np.arange(12) + 2.0)  # 12 >= 10: its own only
    # CNR 3: its 4, CNR 2 (12) at one step: 16
    np.testing.assert_array_equal(got[3], [3.0, 3.1, 3.2, 3.3, *(0.01 * np.arange(12) + 2.0)])
    assert MIN_GOOD == 10 and np.all(pools >= 10)


def test_the_sample_bench_resamples_no_bin_from_fewer_than_ten(sample_cube):
    model = LidarModel.from_artefacts(cube=sample_cube)
    bad, table = model.bad_estimates, model.noise_table
    count, _, _ = table.good_pools(bad.threshold, bad.min_good)
    assert count.min() >= 10
    _, _, own = good_pools(np.asarray(table.residual_count), np.asarray(table.residuals),
                           np.asarray(bad.threshold), bad.min_good)
    # the bins that borrow are the low-CNR ones, where bad estimates take the place of good ones
    borrowing = np.asarray(table.cnr)[np.nonzero(own < 10)[1]]
    assert borrowing.size > 0 and borrowing.max() <= -22.0


def test_the_record_holds_the_fit_and_old_records_keep_their_model(clean):
    cube, _ = clean
    model = LidarModel.from_artefacts(cube=cube)
    record = json.loads(model.to_json())
    fit = record["bad_estimates"]
    assert fit["rate_parameters"] == list(model.bad_estimates.rate_parameters) and "drawn" not in fit
    assert len(model.to_json()) < 4000  # the fit adds about 1.3 kB to the record; the residuals are a digest
    back = LidarModel.from_dict(model.to_json(), cube=cube)
    assert back == model and back.bad_estimates == model.bad_estimates
    np.testing.assert_array_equal(relative_deviation(back, U=8.0, direction=30.0, cnr=-21.0, periods=2),
                                  relative_deviation(model, U=8.0, direction=30.0, cnr=-21.0, periods=2))
    # a record of the old resampling (no bad_estimates) keeps reading back as that model
    old = LidarModel.from_artefacts(cube=cube, los_noise_model="residuals")
    old_record = json.loads(old.to_json())
    assert "bad_estimates" not in old_record
    assert LidarModel.from_dict(old_record, cube=cube).los_noise_model == "residuals"
    # a mixture record without its fit is refused, never silently another model
    del record["bad_estimates"]
    with pytest.raises(InputError, match="'mixture' needs bad_estimates"):
        LidarModel.from_dict(record)
    # switching models: the fit is dropped for another model, and fitted again from the cube
    assert model.with_los_noise("gaussian").bad_estimates is None
    assert old.with_los_noise("mixture", cube) == model.replace(description=old.description)
    with pytest.raises(InputError, match="needs the bench cube"):
        old.with_los_noise("mixture")
    with pytest.raises(InputError, match="cannot give the bad-estimate rate: the search band needs at least"):
        LidarModel.from_artefacts(cube=cube.isel(cnr=[11]), los_noise_model="mixture")


def test_the_sta_headers_cnr_threshold_sets_the_filter_and_the_fitted_range(clean):
    cube, _ = clean
    cond = xr.Dataset(attrs={"lidarcal_source_file": "site.nc", "lidar_cnr_threshold": -20.5})
    model = LidarModel.from_attrs(cond, cube=cube)
    assert model.cnr_threshold == -20.5 and model.bad_estimates.fit_cnr_min == -22.0
    unset = cond.assign_attrs(lidar_cnr_threshold="not given")
    assert LidarModel.from_attrs(unset, cube=cube).cnr_threshold == -23.0
    with pytest.raises(InputError, match=r"site\.nc: global attribute 'lidar_cnr_threshold'.*'-22 dB'"):
        LidarModel.from_attrs(cond.assign_attrs(lidar_cnr_threshold="-22 dB"), cube=cube)
    # the ideal lidar (no cube) has no bad estimates and keeps every period
    assert LidarModel.from_attrs(cond).cnr_threshold is None
    # below the filter a period is unavailable: no lidar speed, availability 0
    r = simulate_period(model, heights=[100.0], wind_speed=8.0, wind_from_direction=0.0, cnr=-20.6,
                        turbulence_intensity=0.1, wind_shear_exponent=0.1, cnr_gradient=0.0, seed=(1, 2))
    assert np.isnan(r["lidar_wind_speed"][0]) and r["availability"][0] == 0.0


def test_bad_estimate_records_are_checked():
    fields = dict(cnr=[-20.0, -18.0], scale=[0.1, 0.1], threshold=[0.6, 0.6], total=[10, 10], flagged=[1, 0],
                  detection=[0.99, 0.99], band=[-30.0, 30.0], fit_cnr_min=-20.0, cnr_reference=-19.0,
                  rate_parameters=[-5.0, -0.5], rate_covariance=[[0.1, 0.01], [0.01, 0.01]], fit_chi2=0.0,
                  fit_dof=0, band_uniformity_p=1.0)
    assert BadEstimates(**fields).rate(-19.0) == pytest.approx(expit(-5.0))
    with pytest.raises(ValueError, match="band must be"):
        BadEstimates(**{**fields, "band": [30.0, -30.0]})
    with pytest.raises(ValueError, match="positive definite"):
        BadEstimates(**{**fields, "rate_covariance": [[0.1, 0.5], [0.5, 0.01]]})
    with pytest.raises(ValueError, match="one value per CNR"):
        BadEstimates(**{**fields, "flagged": [1]})


def test_a_cnr_without_residuals_takes_the_nearest_cnrs_scale(clean):
    cube, _ = clean
    holes = cube.copy(deep=True)
    holes["los_residual"].values[:, [2, 4]] = np.nan  # no residual at -24 and -20 dB
    model = LidarModel.from_artefacts(cube=holes, cnr_threshold=None)
    bad, full = model.bad_estimates, LidarModel.from_artefacts(cube=cube, cnr_threshold=None).bad_estimates
    assert bad.total[2] == bad.total[4] == 0
    # -24 dB is one step from -26 and -22: the lower index (-26 dB) wins the tie; -20 dB likewise takes -22 dB
    assert bad.scale[2] == bad.scale[1] and bad.scale[4] == bad.scale[3]
    assert bad.scale[1] == full.scale[1] and np.all(np.isfinite(bad.scale))
    assert LidarModel.from_dict(model.to_json(), cube=holes) == model  # no NaN in the record
