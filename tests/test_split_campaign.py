"""A campaign split into parts equals the whole, bit for bit (issue 9, item 2).

A period's random streams are keyed by its timestamp (and height), not by its position in the
conditions file: halves simulated separately reproduce the single run, their files
concatenate (``xr.open_mfdataset``) to the single file, and the same conditions at another
time draw other numbers.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.chunks import chunk_key
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import synthetic_conditions
from lidarcal.errors import InputError
from lidarcal.io import write_artefact
from lidarcal.lidar import LidarModel

BASE = 4321


@pytest.fixture(scope="module")
def model():
    return LidarModel.ideal()


@pytest.fixture(scope="module")
def cond():
    return synthetic_conditions(30, (40.0, 80.0), seed=11)


@pytest.fixture(scope="module")
def whole(cond, model):
    return simulate_campaign(cond, model, base_seed=BASE,
                             execution=Execution(scheduler="synchronous", chunk=8))


def assert_bitwise_equal(a: xr.Dataset, b: xr.Dataset) -> None:
    assert sorted(a.variables) == sorted(b.variables)
    for name in a.variables:
        x, y = a[name].values, b[name].values
        assert x.shape == y.shape and x.dtype == y.dtype, name
        if x.dtype.kind == "f":  # bits, so NaN == NaN and -0.0 != 0.0
            x, y = x.view(f"u{x.itemsize}"), y.view(f"u{y.itemsize}")
        np.testing.assert_array_equal(x, y, err_msg=name)


def test_halves_equal_the_whole_bit_for_bit(cond, model, whole):
    # different cut points and chunk sizes: nothing about the split may matter
    opts = {"model": model, "base_seed": BASE}
    a = simulate_campaign(cond.isel(time=slice(0, 13)),
                          execution=Execution(scheduler="synchronous", chunk=5), **opts)
    b = simulate_campaign(cond.isel(time=slice(13, None)),
                          execution=Execution(scheduler="synchronous", chunk=3),
                          **opts)
    assert_bitwise_equal(xr.concat([a, b], dim="time"), whole)


def test_open_mfdataset_of_parts_equals_the_single_file(cond, model, whole, tmp_path):
    parts = []
    for i, sl in enumerate((slice(0, 9), slice(9, 21), slice(21, None))):
        part = simulate_campaign(cond.isel(time=sl), model, base_seed=BASE,
                                 execution=Execution(scheduler="synchronous", chunk=4))
        parts.append(write_artefact(part, tmp_path / f"part{i}.nc"))
    single = write_artefact(whole, tmp_path / "whole.nc")
    with xr.open_mfdataset(parts, engine="netcdf4") as joined, xr.open_dataset(single) as one:
        joined, one = joined.load(), one.load()
    assert_bitwise_equal(joined, one)


def test_same_conditions_at_another_time_draw_other_numbers(cond, model):
    """Under position keys, a copy of a campaign moved in time gave the identical result."""
    later = cond.assign_coords(time=cond.time.values + np.timedelta64(7, "D"))
    a = simulate_campaign(cond, model, base_seed=BASE, execution=Execution(scheduler="synchronous", chunk=30))
    b = simulate_campaign(later, model, base_seed=BASE,
                          execution=Execution(scheduler="synchronous", chunk=30))
    err_a = (a.lidar_wind_speed - a.reference_wind_speed).values.ravel()
    err_b = (b.lidar_wind_speed - b.reference_wind_speed).values.ravel()
    ok = np.isfinite(err_a) & np.isfinite(err_b)
    assert ok.sum() >= 40
    assert not np.any(err_a[ok] == err_b[ok])  # not one period-height repeats its draw
    # independent draws: the errors share only their deterministic part (the conditions' RWF and
    # shear bias), so they correlate no more than with a run of another base seed at the same
    # times (40+ pairs: the two correlations' sampling spread is ~0.1; 0.3 allows 3 sigma)
    c = simulate_campaign(cond, model, base_seed=BASE + 1,
                          execution=Execution(scheduler="synchronous", chunk=30))
    err_c = (c.lidar_wind_speed - c.reference_wind_speed).values.ravel()
    ok &= np.isfinite(err_c)
    r_ab, r_ac = np.corrcoef(err_a[ok], err_b[ok])[0, 1], np.corrcoef(err_a[ok], err_c[ok])[0, 1]
    assert r_ab < 0.99 and abs(r_ab - r_ac) < 0.3, (r_ab, r_ac)
    # the key is the time in whole seconds, computed here independently of lidarcal
    seconds = np.array([int(pd.Timestamp(t).timestamp()) for t in later.time.values])
    np.testing.assert_array_equal(b.period_key.values, seconds)
    assert (b.period_key.values - a.period_key.values == 7 * 86400).all()


def test_ensemble_members_stay_distinguishable(cond, model, whole):
    other = simulate_campaign(cond, model, base_seed=BASE + 1,
                              execution=Execution(scheduler="synchronous", chunk=30))
    ensemble = xr.concat([whole, other], dim="member")
    assert ensemble.base_seed.dims == ("member", "time")
    assert ensemble.base_seed.values[:, 0].tolist() == [BASE, BASE + 1]
    lw = ensemble.lidar_wind_speed.values
    ok = np.isfinite(lw[0]) & np.isfinite(lw[1])
    assert not np.any(lw[0][ok] == lw[1][ok])  # another base seed: other draws


def test_periods_sharing_a_second_are_refused(cond, model):
    times = cond.time.values.copy()
    times[5] = times[4] + np.timedelta64(500, "ms")  # 4 and 5 now fall in the same second
    with pytest.raises(InputError, match=r"periods 4 and 5 have the same time to the second"):
        simulate_campaign(cond.assign_coords(time=times), model, execution=Execution(scheduler="synchronous"))


def test_chunk_cache_key_includes_the_period_keys():
    args = ("checksum", {"m": 1}, BASE, 0, 3, np.array([40.0]), 600.0, ())
    assert chunk_key(*args, keys=np.array([1, 2, 3])) != chunk_key(*args, keys=np.array([1, 2, 4]))
