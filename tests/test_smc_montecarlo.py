"""``lidarcal smc``'s Monte Carlo route on a real (short) calibration: slow statistical checks.

- A campaign in the calibration's own conditions (another seed) gives the certificate's budget
  back within the two values' stated numerical tolerances (JCGM 101 §7.9).
- A campaign at markedly higher turbulence intensity moves the environmental term in the
  direction, and by about the amount, of the certificate's TI slope.
- ``.sta`` files of both dialects end to end to the HTML and PDF report.
- A Dask cluster (a LocalCluster of worker processes on loopback) gives the local result bit for bit.
- docs/smc.md, executed.
"""

import json
import subprocess

import netCDF4
import numpy as np
import pytest
import xarray as xr
from smc_factories import SERIAL
from test_sta import ends, make_values, write_newer, write_older
from test_walkthroughs import ROOT, run_page

import lidarcal
from lidarcal.cli import main
from lidarcal.smc import binned, smc, smc_dataset

pytestmark = pytest.mark.slow

HEIGHTS = (80.0, 120.0)
CALIBRATION_SEED = 20240101  # lidarcal calibrate's default base seed


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    out = tmp_path_factory.mktemp("smc-cal") / "cal"
    code = main(
        [
            "calibrate",
            "--periods",
            "288",
            "--heights",
            *map(str, HEIGHTS),
            "--max-replicas",
            "8",
            "--workers",
            "2",
            "--no-progress",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    return out


def own_conditions(calibrated, path, *, ti_added=0.0):
    """The calibration's own conditions file, as the campaign lidar's (its serial and cone angle)."""
    ds = xr.open_dataset(calibrated / "conditions.nc").load()
    ds.attrs.update(lidar_serial_number=SERIAL, lidar_cone_angle=28.0)
    ds["turbulence_intensity"] = ds["turbulence_intensity"] + ti_added
    ds.to_netcdf(path)
    return path


def test_the_calibrations_own_conditions_give_the_certificates_budget_back(calibrated, tmp_path):
    cond = own_conditions(calibrated, tmp_path / "own.nc")
    # another base seed: independent of the calibration's streams
    c = smc(
        calibrated / "certificate.nc",
        conditions=cond,
        base_seed=7,
        max_replicas=8,
        execution={"workers": 2},
    )
    b = binned(smc_dataset(c))
    both = (
        np.isfinite(b.certified_relative_expanded_uncertainty)
        & np.isfinite(b.simulated_relative_expanded_uncertainty)
        & np.isfinite(b.certified_numerical_tolerance)
        & np.isfinite(b.simulated_numerical_tolerance)
    )
    assert int(both.sum()) >= 20  # most certified bins of both heights are compared
    diff = np.abs(b.simulated_relative_expanded_uncertainty - b.certified_relative_expanded_uncertainty)
    # each tolerance is at least twice the standard deviation of its value (JCGM 101 7.9.4: 2 s/sqrt(h),
    # rounded up to half a decade), so their sum is at least 2 sqrt(2) = 2.8 standard deviations of
    # the difference of the two independent estimates.  A family of ~25 bins at a family-wise 1 %
    # needs 3.2 (Bonferroni), and each s comes from only 4 to 8 sequences or replicas (its 95 % upper
    # bound is 1.5 to 2.5 s): 1.5 times the sum
    allowed = 1.5 * (b.simulated_numerical_tolerance + b.certified_numerical_tolerance)
    assert bool((diff <= allowed).where(both, True).all()), (diff.where(both), allowed.where(both))
    # and the environmental term is small beside the calibration's where nothing changed
    ds = smc_dataset(c)
    ok = ds.coverage_flag.transpose("time", "height").values == 0
    env = ds.contribution.sel(contributor="environmental_monte_carlo").transpose("time", "height")
    cal = ds.contribution.sel(contributor="calibration").transpose("time", "height").values[ok]
    assert float(np.sqrt(np.mean(env.values[ok] ** 2))) < 0.5 * float(np.sqrt(np.mean(cal**2)))


def test_higher_turbulence_moves_the_environmental_term_as_the_slopes_say(calibrated, tmp_path):
    delta = 0.1  # 2.5 standard deviations of the calibration's TI (about 0.04)
    cond = own_conditions(calibrated, tmp_path / "ti.nc", ti_added=delta)
    # the calibration's seed: each period's turbulence as in the calibration, only its TI differs
    c = smc(
        calibrated / "certificate.nc",
        conditions=cond,
        base_seed=CALIBRATION_SEED,
        max_replicas=4,
        execution={"workers": 2},
    )
    ds = smc_dataset(c)
    with netCDF4.Dataset(calibrated / "certificate.nc") as nc:
        slope = np.asarray(nc["sensitivity_turbulence_intensity_slope"][:])  # % per unit TI, per height
        heights = list(np.asarray(nc["sensitivity_turbulence_intensity_height"][:]))
    for z in HEIGHTS:
        one = ds.sel(height=z)
        ok = one.coverage_flag.values == 0
        shift = one.environmental_deviation_monte_carlo.values[ok]
        predicted = slope[heights.index(z)] / 100.0 * delta * one.wind_speed.values[ok]  # m s-1
        assert ok.sum() >= 150
        # direction: the slope's sign, clearly (the mean shift more than 5 standard errors from 0)
        assert np.sign(shift.mean()) == np.sign(predicted.mean())
        assert abs(shift.mean()) > 5 * shift.std(ddof=1) / np.sqrt(shift.size)
        # amount: a factor 2 either way and a little more on the large side.  The TI response is
        # not linear (the WFR's scalar/vector averaging and the point reference differ by terms in
        # sigma^2 = (TI U)^2): for a response in TI^2 a linear slope fitted about the calibration's
        # mean TI (~0.1) under-predicts a shift of +0.1 by 1 + 0.1 / (2 x 0.1) = 1.5; the slope's own
        # 95 % interval adds about +-30 % (288 periods); 3 covers both
        ratio = shift.mean() / predicted.mean()
        assert 0.5 < ratio < 3.0, (z, ratio)
        # the term the route adds is raised well above the own-conditions level (< 0.5 x calibration)
        env = one.contribution.sel(contributor="environmental_monte_carlo").values[ok]
        assert np.sqrt(np.mean(env**2)) > 0.5 * abs(predicted.mean())


@pytest.mark.parametrize("dialect", ["newer", "older"])
def test_sta_files_of_both_dialects_end_to_end_to_a_report(calibrated, tmp_path, dialect, poppler, capsys):
    z = np.array([60.0, 80.0, 100.0, 120.0])
    writer = write_newer if dialect == "newer" else write_older
    first = writer(tmp_path / "day1.sta", ends(6), z, make_values(6, z, seed=8), serial=SERIAL)
    second = writer(
        tmp_path / "day2.sta", ends(6, start="2024-03-01T01:10"), z, make_values(6, z, seed=9), serial=SERIAL
    )
    out = tmp_path / "smc.nc"
    code = main(
        [
            "smc",
            str(calibrated / "certificate.nc"),
            str(first),
            str(second),
            "-o",
            str(out),
            "--report",
            str(tmp_path / "smc.html"),
            "--max-replicas",
            "2",
            "--workers",
            "2",
            "--no-progress",
        ]
    )
    assert code == 0, capsys.readouterr().err
    ds = lidarcal.open_artefact(out)
    assert ds.sizes["time"] == 12 and ds.attrs["environmental_route"] == "monte_carlo"
    assert json.loads(ds.attrs["heights_not_covered_m"]) == [60.0, 100.0]
    assert main(["validate", str(out)]) == 0  # schema, CF-1.11 and ACDD-1.3
    files = {r["file"] for r in json.loads(ds.attrs["lidarcal_inputs"])}
    assert {"day1.sta", "day2.sta", "certificate.nc"} <= files
    html = (tmp_path / "smc.html").read_text(encoding="utf-8")
    # three figures inline, nothing fetched from the network, the status said
    assert html.count("data:image/png;base64,") == 3 and 'src="http' not in html and "DEMONSTRATION" in html
    text = subprocess.run([poppler[1], str(tmp_path / "smc.pdf"), "-"], capture_output=True, text=True).stdout
    assert "DEMONSTRATION" in text and "WLS866-0195" in text and "day1.sta" in text
    assert text.count("\f") == 4  # pdftotext ends every page with a form feed: facts + three figures


def test_a_dask_cluster_gives_the_local_result_bit_for_bit(calibrated, tmp_path):
    v = xr.open_dataset(calibrated / "conditions.nc").load().isel(time=slice(100, 112))
    v.attrs.update(lidar_serial_number=SERIAL, lidar_cone_angle=28.0)
    v.to_netcdf(tmp_path / "c.nc")
    runs = {}
    for name, opts in (
        ("local", {"scheduler": "synchronous"}),
        ("cluster", {"scheduler": "local", "workers": 2, "chunk": 3}),
    ):
        c = smc(
            calibrated / "certificate.nc", conditions=tmp_path / "c.nc", max_replicas=3, execution=opts
        )
        runs[name] = smc_dataset(c)
    a, b = runs["local"], runs["cluster"]
    assert sorted(a.data_vars) == sorted(b.data_vars)
    for name in a.data_vars:
        np.testing.assert_array_equal(a[name].values, b[name].values, err_msg=name)
    assert int((a.monte_carlo_trials > 1).sum()) > 0  # replicas ran, on both


def test_smc_page(tmp_path, monkeypatch):
    assert (
        run_page("smc.md", tmp_path, monkeypatch, replace={"sample_data/": f"{ROOT / 'sample_data'}/"}) >= 4
    )
