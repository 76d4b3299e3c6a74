"""``lidarcal smc`` and the certificate's budget: the model-form term counts once, the measurand holds.

The certificate's U is that of a single 10-minute mean per bin and its Table 4 terms are fully
correlated across bins and heights (``lidarcal.certificate.MEASURAND``).  So the campaign's
calibration contributor is the certified value with every contributor of the budget, model form
included; the per-bin values are root mean squares of single-period values, which more periods
leave unchanged (never divided by sqrt(n)); and the Monte Carlo route, whose trials cannot give
the model-form term, carries the certificate's.  Expected values are computed here by hand from
the numbers stored in the files (netCDF4) with numpy.
"""

import netCDF4
import numpy as np
import pytest
import xarray as xr
from analysis_factories import make_records
from smc_factories import HEIGHTS, add_model_form, campaign_values, conditions_file, small_certificate

import lidarcal
from lidarcal.analysis import budget
from lidarcal.cli import main
from lidarcal.smc import binned, smc
from lidarcal.smc.montecarlo import with_carried

MODEL_FORM_PCT = 0.8  # add_model_form's default: 0.8 % of each bin's mean reference speed


@pytest.fixture(scope="module")
def cert_mf(tmp_path_factory):
    return small_certificate(tmp_path_factory.mktemp("smc-cert-mf"), flags=add_model_form)


def stored(path, name, order):
    """A variable as stored (netCDF4, no lidarcal), transposed to the dimension names ``order``."""
    with netCDF4.Dataset(path) as nc:
        var = nc.variables[name]
        data = var[:]
        data = np.asarray(data.filled(np.nan) if np.ma.isMaskedArray(data) else data)
        return np.transpose(data, [var.dimensions.index(d) for d in order])


def run(tmp_path, cert, cond, out):
    code = main(["smc", str(cert), "--conditions", str(cond), "--no-monte-carlo", "--no-progress",
                 "-o", str(tmp_path / out)])
    assert code == 0
    return lidarcal.open_artefact(tmp_path / out)


def test_calibration_contributor_is_the_certified_u_with_its_model_form(tmp_path, cert_mf):
    v = campaign_values(40, HEIGHTS)
    ds = run(tmp_path, cert_mf, conditions_file(tmp_path / "c.nc", v, HEIGHTS), "smc.nc")
    # by hand: the certificate's relative standard uncertainty from its stored contributors
    order = ("budget_wind_speed", "budget_height", "budget_contributor")
    contrib = stored(cert_mf, "budget_contribution", order)
    mref = stored(cert_mf, "budget_mean_reference_wind_speed", order[:2])
    with netCDF4.Dataset(cert_mf) as nc:
        names = list(nc.variables["budget_contributor"][:])
        meanings = nc["budget_bin_flag"].flag_meanings.split()
        values = np.atleast_1d(nc["budget_bin_flag"].flag_values).tolist()
        certified = dict(zip(meanings, values, strict=True))["certified"]
        measurand = nc.getncattr("measurand")
    assert "model_form" in names
    flag = stored(cert_mf, "budget_bin_flag", order[:2])
    centres = stored(cert_mf, "budget_wind_speed", order[:1])
    rel_all = 100 * np.sqrt((contrib**2).sum(axis=-1)) / mref
    without = [i for i, n in enumerate(names) if n != "model_form"]
    rel_without = 100 * np.sqrt((contrib[..., without] ** 2).sum(axis=-1)) / mref
    u = v["wind_speed"]
    expected, lower = np.full(u.shape, np.nan), np.full(u.shape, np.nan)
    for j in range(len(HEIGHTS)):
        for t in range(u.shape[0]):
            b = int(np.argmin(np.abs(centres - u[t, j])))
            if abs(centres[b] - u[t, j]) <= 0.25 and flag[b, j] == certified:
                expected[t, j] = rel_all[b, j] * u[t, j] / 100
                lower[t, j] = rel_without[b, j] * u[t, j] / 100
    got = ds.contribution.sel(contributor="calibration").transpose("time", "height").values
    np.testing.assert_allclose(got, expected, rtol=1e-12, equal_nan=True)
    ok = np.isfinite(expected)
    assert ok.sum() >= 30  # most of the 80 period-heights are covered
    # the model-form term is in it: 0.8 % in quadrature raises every value measurably
    assert (got[ok] > lower[ok] * (1 + 1e-3)).all()
    # the measurand travels with the result
    assert ds.attrs["certificate_measurand"] == measurand
    assert "single 10-minute mean" in ds.attrs["measurand"] and "must not divide" in ds.attrs["measurand"]
    assert ds.attrs["certificate_model_form"].startswith("The uncertainty includes the simulation's model")


def test_bins_are_never_averaged_down(tmp_path, cert_mf):
    """The bin value is the RMS of single-period values: the same periods twice give the same value."""
    v = campaign_values(40, HEIGHTS, seed=3)
    once = run(tmp_path, cert_mf, conditions_file(tmp_path / "c1.nc", v, HEIGHTS), "once.nc")
    twice_v = {k: np.concatenate([a, a]) for k, a in v.items()}
    twice = run(tmp_path, cert_mf, conditions_file(tmp_path / "c2.nc", twice_v, HEIGHTS), "twice.nc")
    a, b = binned(once), binned(twice)
    np.testing.assert_array_equal(b.covered_count.values, 2 * a.covered_count.values)
    np.testing.assert_allclose(b.uncertainty.values, a.uncertainty.values, rtol=1e-12, equal_nan=True)
    # and by hand: sqrt(mean(u^2)) over the covered periods of each bin
    u = once.uncertainty.transpose("time", "height").values
    speed = once.wind_speed.transpose("time", "height").values
    bounds = once.wind_speed_bin_bounds.values
    covered = once.coverage_flag.transpose("time", "height").values == 0
    for i, (lo, hi) in enumerate(bounds):
        for j in range(len(HEIGHTS)):
            mine = covered[:, j] & (speed[:, j] >= lo) & (speed[:, j] < hi)
            want = np.sqrt(np.mean(u[mine, j] ** 2)) if mine.any() else np.nan
            np.testing.assert_allclose(once.bin_uncertainty.values[i, j], want, rtol=1e-12, equal_nan=True)


def test_with_carried_adds_the_certificates_term_by_hand():
    bud = budget(make_records(n=400, heights=HEIGHTS, seed=9))
    b = bud.transpose("height", "wind_speed", "contributor", ...)
    centres = np.array([5.0, 9.0, 13.0])  # coarser than the budget's bins: each takes the nearest
    rel = np.array([[0.2, 0.5, 1.0], [0.3, 0.6, 1.2]])  # (height, centre) %
    carried = xr.Dataset(
        {"relative_contribution": (("height", "wind_speed", "contributor"), rel[..., None])},
        coords={"height": list(HEIGHTS), "wind_speed": centres, "contributor": ["model_form"]})
    out = with_carried(bud, carried)
    assert [str(c) for c in out.contributor.values] == [*map(str, b.contributor.values), "model_form"]
    k = float(bud.attrs["coverage_factor"])
    ws, mref = b.wind_speed.values, b.mean_reference_wind_speed.values
    old = b.contribution.values
    for i in range(len(HEIGHTS)):
        for w in range(ws.size):
            near = int(np.argmin(np.abs(centres - ws[w])))
            c_mf = rel[i, near] / 100 * mref[i, w]
            want = k * np.sqrt(np.sum(old[i, w] ** 2) + c_mf**2) * 100 / mref[i, w]
            np.testing.assert_allclose(out.relative_expanded_uncertainty.values[i, w], want, rtol=1e-12,
                                       equal_nan=True)
            np.testing.assert_allclose(out.contribution.sel(contributor="model_form").values[i, w], c_mf,
                                       rtol=1e-12, equal_nan=True)
    assert out.attrs["carried_from_certificate"] == "model_form"
    assert with_carried(out, carried) is out  # already there: not added twice


def test_the_monte_carlo_route_carries_the_model_form(tmp_path, cert_mf):
    v = campaign_values(6, HEIGHTS[1:])
    c = smc(cert_mf, conditions=conditions_file(tmp_path / "c.nc", v, HEIGHTS[1:]), max_replicas=1,
            execution={"scheduler": "synchronous"})
    sim = c.monte_carlo.budget
    rel = sim.relative_contribution.sel(contributor="model_form").values
    ok = np.isfinite(sim.mean_reference_wind_speed.values)
    assert ok.any()
    # every certificate bin states 0.8 % of its mean reference speed: the nearest is 0.8 % as well
    np.testing.assert_allclose(rel[ok], MODEL_FORM_PCT, rtol=1e-12)


def test_uncertainty_of_a_bins_mean_by_hand(tmp_path, cert_mf):
    """The bin mean's uncertainty: correlated parts averaged linearly, the single-period spread divided down.

    Expected side by hand from the certificate's stored budget (netCDF4) and the campaign's speeds:
    per covered period the calibration contributor split into its std_difference part
    (independent between periods) and the rest (Table 4 terms, mean difference, statistical, model
    form: fully correlated); the user term (0.5 % rectangular: 0.5 / sqrt(3) % of the speed) and
    the 50-2 route's per-period value (checked by hand in test_smc) fully correlated.
    """
    (tmp_path / "terms.yaml").write_text(
        "terms:\n  - {name: flow, value: 0.5, unit: '%', distribution: rectangular, source: CFD (test)}\n"
    )
    v = campaign_values(120, HEIGHTS, seed=4)
    cond = conditions_file(tmp_path / "c.nc", v, HEIGHTS)
    out = tmp_path / "smc.nc"
    code = main(["smc", str(cert_mf), "--conditions", str(cond), "--no-monte-carlo", "--no-progress",
                 "--user-terms", str(tmp_path / "terms.yaml"), "-o", str(out)])
    assert code == 0
    order = ("budget_wind_speed", "budget_height", "budget_contributor")
    contrib = stored(cert_mf, "budget_contribution", order)
    mref = stored(cert_mf, "budget_mean_reference_wind_speed", order[:2])
    centres = stored(cert_mf, "budget_wind_speed", order[:1])
    with netCDF4.Dataset(cert_mf) as nc:
        names = list(nc.variables["budget_contributor"][:])
    rel = 100 * contrib / mref[..., None]  # % per contributor
    rel_all = np.sqrt((rel**2).sum(axis=-1))
    rel_sd = rel[..., names.index("std_difference")]
    speed = stored(out, "wind_speed", ("time", "height"))
    covered = stored(out, "coverage_flag", ("time", "height")) == 0
    iec = stored(out, "contribution", ("contributor", "time", "height"))[1]  # environmental_iec
    bounds = stored(out, "wind_speed_bin_bounds", ("wind_speed_bin", "nv"))
    got = stored(out, "bin_mean_uncertainty", ("wind_speed_bin", "height"))
    got_rel = stored(out, "bin_mean_relative_uncertainty", ("wind_speed_bin", "height"))
    got_cal = stored(out, "bin_mean_contribution", ("wind_speed_bin", "contributor", "height"))[:, 0]
    single = stored(out, "bin_uncertainty", ("wind_speed_bin", "height"))
    checked = 0
    for i, (lo, hi) in enumerate(bounds):
        for j in range(len(HEIGHTS)):
            mine = covered[:, j] & (speed[:, j] >= lo) & (speed[:, j] < hi)
            n = int(mine.sum())
            if n == 0:
                assert np.isnan(got[i, j])
                continue
            u = speed[mine, j]
            b = int(np.argmin(np.abs(centres - 0.5 * (lo + hi))))
            sys_part = np.sqrt(rel_all[b, j] ** 2 - rel_sd[b, j] ** 2) / 100 * u  # fully correlated
            rand_part = rel_sd[b, j] / 100 * u  # independent between periods
            cal = np.sqrt(sys_part.mean() ** 2 + (rand_part**2).sum() / n**2)
            user = (0.5 / np.sqrt(3) / 100 * u).mean()
            env = iec[mine, j].mean()
            want = np.sqrt(cal**2 + env**2 + user**2)
            np.testing.assert_allclose(got_cal[i, j], cal, rtol=1e-10)
            np.testing.assert_allclose(got[i, j], want, rtol=1e-10)
            np.testing.assert_allclose(got_rel[i, j], 100 * want / u.mean(), rtol=1e-10)
            if n > 1:  # the spread averages down, nothing else does: below the single period's RMS
                assert got[i, j] < single[i, j]
                assert got[i, j] > np.sqrt(sys_part.mean() ** 2 + env**2 + user**2) * (1 - 1e-12)
            checked += 1
    assert checked >= 20
    # the table prints it beside the single-period value
    table = lidarcal.smc.binned_table(out)
    row = table.iloc[0]
    assert {"mean_uncertainty_m_s", "mean_relative_uncertainty_pct"} <= set(table.columns)
    assert row["mean_uncertainty_m_s"] <= row["uncertainty_m_s"]
