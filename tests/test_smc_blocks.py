"""A campaign of any length, block by block: the same numbers, one block in memory, no handle left open.

``lidarcal smc`` reads a conditions file, computes each period's values and writes ``smc.nc`` one
block of periods at a time (``lidarcal.smc.periods``, ``load_conditions(block=...)``).  The
references here are the same computations done whole: the eager loader, the artefact computed in
one block, and :func:`~lidarcal.conditions.load.conditions_checksum` of the loaded data.  How much
memory a long campaign takes is measured by ``benchmarks/bench_smc.py`` (its ``memory`` part).
"""

import weakref

import netCDF4
import numpy as np
import pytest
import xarray as xr
from smc_factories import HEIGHTS, campaign_values, conditions_file, small_certificate

import lidarcal.smc.dataset as smc_dataset_module
from lidarcal.conditions.load import conditions_checksum, load_conditions
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.smc import smc, smc_dataset

BLOCK = 7  # periods per block here: a 60-period campaign is 9 blocks, the last one short


@pytest.fixture(scope="module")
def cert(tmp_path_factory):
    return small_certificate(tmp_path_factory.mktemp("blocks-cert"))


def _campaign(path, n=60, **edits):
    values = campaign_values(n, HEIGHTS, seed=23)
    values["wind_speed"][[3, 17], [0, 1]] = np.nan  # two missing values, in two blocks
    for name, (row, col, value) in edits.items():
        values[name][row, col] = value
    return conditions_file(path, values, HEIGHTS)


def test_lazy_load_is_the_eager_load(tmp_path):
    path = _campaign(tmp_path / "c.nc")
    eager = load_conditions(path, warn=False)
    lazy = load_conditions(path, warn=False, block=BLOCK)
    assert lazy["wind_speed"].chunks is not None and len(lazy["wind_speed"].chunks[0]) == 9
    for name in eager.data_vars:
        assert np.array_equal(eager[name].values, lazy[name].values, equal_nan=True), name
    # the checksum hashed block by block is the one of the whole data
    assert lazy.attrs["lidarcal_conditions_checksum"] == eager.attrs["lidarcal_conditions_checksum"]
    assert eager.attrs["lidarcal_conditions_checksum"] == conditions_checksum(eager)
    assert lazy.attrs["lidarcal_skipped_count"] == eager.attrs["lidarcal_skipped_count"] == 2


def test_lazy_load_names_the_first_bad_value_and_counts_them_all(tmp_path):
    # out-of-range turbulence intensity in the fourth and the seventh block: one message, both counted
    path = _campaign(tmp_path / "bad.nc", turbulence_intensity=([25, 44], [1, 0], 3.5))
    with pytest.raises(InputError) as whole:
        load_conditions(path, warn=False)
    with pytest.raises(InputError) as blocks:
        load_conditions(path, warn=False, block=BLOCK)
    assert str(blocks.value) == str(whole.value)
    assert "2 value(s) outside" in str(whole.value) and "(index 25)" in str(whole.value)


def test_a_file_changed_under_a_lazy_load_is_refused(tmp_path):
    path = _campaign(tmp_path / "c.nc")
    lazy = load_conditions(path, warn=False, block=BLOCK)
    _campaign(path, turbulence_intensity=([5], [0], 0.3))  # rewritten: other bytes than those hashed
    with pytest.raises(InputError, match="changed while it was being read"):
        lazy["turbulence_intensity"].load()


@pytest.fixture(scope="module")
def campaign(cert, tmp_path_factory):
    path = _campaign(tmp_path_factory.mktemp("blocks") / "c.nc")
    return smc(cert, conditions=path, max_replicas=2, periods_per_bin=4,
               execution={"scheduler": "synchronous"})


def test_per_period_values_do_not_depend_on_the_block(campaign):
    small, whole = smc_dataset(campaign, block=BLOCK), smc_dataset(campaign, block=10**6)
    assert small["uncertainty"].chunks[0] == (7,) * 8 + (4,)
    for name, var in whole.data_vars.items():
        a, b = var.values, small[name].values
        if "time" in var.dims or not np.issubdtype(var.dtype, np.floating):
            assert np.array_equal(a, b, equal_nan=True), name  # per period: bit for bit
        else:  # per bin: sums added block after block, the last bit may differ
            np.testing.assert_allclose(b, a, rtol=1e-12, atol=0, equal_nan=True, err_msg=name)
    for attr in ("covered_periods", "periods_with_wind_speed"):
        assert small.attrs[attr] == whole.attrs[attr]
    # the threaded scheduler (each block read through its own handle, under one lock) gives the same
    assert small["uncertainty"].compute(scheduler="threads").identical(whole["uncertainty"].compute())


def test_writing_holds_one_block_at_a_time(campaign, tmp_path, monkeypatch):
    alive, most = set(), [0]

    class Block(dict):  # a block's values, whose lifetime is watched
        pass

    def watched(c, periods):
        out = Block(compute(c, periods))
        alive.add(id(out))
        most[0] = max(most[0], len(alive))
        weakref.finalize(out, alive.discard, id(out))
        return out

    compute = smc_dataset_module._block_arrays
    monkeypatch.setattr(smc_dataset_module, "_block_arrays", watched)
    ds = smc_dataset(campaign, block=BLOCK)
    path = write_artefact(ds, tmp_path / "smc.nc")
    # validating and writing take the nine blocks one after the other, never all at once
    assert most[0] <= 2, f"{most[0]} blocks held at once"
    with netCDF4.Dataset(path) as nc:  # one HDF5 chunk per block: each block fills whole chunks
        assert nc["uncertainty"].chunking() == [BLOCK, len(HEIGHTS)]
        assert nc["turbulence_intensity"].chunking() == [BLOCK, len(HEIGHTS)]
    back = open_artefact(path)
    expected = smc_dataset(campaign, block=10**6)
    for name in ("uncertainty", "contribution", "coverage_flag", "turbulence_intensity"):
        assert np.array_equal(back[name].values, expected[name].values, equal_nan=True), name


def test_no_handle_of_the_conditions_file_stays_open(cert, tmp_path):
    path = _campaign(tmp_path / "c.nc")
    c = smc(cert, conditions=path, monte_carlo=False)
    write_artefact(smc_dataset(c, block=BLOCK), tmp_path / "smc.nc")
    # a handle left open would be closed by the garbage collector in whatever thread it runs,
    # maybe while another reads: HDF5 is not thread-safe (lidarcal.conditions.load._canonical)
    held = [key for key in xr.backends.file_manager.FILE_CACHE if str(path) in str(key)]
    assert not held
