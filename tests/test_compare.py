"""``lidarcal compare``: the slope test, the command and the artefact, and the verdict on campaigns it
did not generate (``tests/independent_campaign.py``, nothing from lidarcal's engine).

Default suite: the two-slope test against an independent computation and its false-alarm rate, the
command on a small hand-made campaign (one JSON object, a valid artefact, the report, ``--model``,
bad input).  Slow: effect-free independent campaigns agree (at most 5 % of the cells flagged over
three seeds), an over-speeding cup makes the turbulence slopes disagree, a zero-distance error the
shear slopes at the lower heights, and the worked example of ``docs/compare.md`` runs.
"""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
import xarray as xr
from independent_campaign import make_field_campaign

from lidarcal.analysis.kernels import bin_mean_weights, weighted_linear_regression
from lidarcal.cli import main
from lidarcal.compare import compare, summary, to_dataset
from lidarcal.compare.core import slope_test
from lidarcal.conditions import synthetic_conditions
from lidarcal.errors import InputError
from lidarcal.io import open_artefact

SIM = {"scheduler": "synchronous"}


# -- the test of one cell ------------------------------------------------------------------------


def test_slope_test_matches_a_hand_computation():
    # two slopes 1.0 +- 0.3 and 0.2 +- 0.4: se 0.5, z 1.6, p = 2 (1 - Phi(1.6)) = 0.1096
    out = slope_test(1.0, 0.3, 0.2, 0.4)
    assert out["difference"] == pytest.approx(0.8)
    assert out["stderr"] == pytest.approx(0.5)
    assert out["z"] == pytest.approx(1.6)
    assert out["p_value"] == pytest.approx(0.109599, abs=1e-6)
    # a missing slope or standard error: no test
    assert np.isnan(slope_test(np.nan, 0.3, 0.2, 0.4)["p_value"])
    assert np.isnan(slope_test(1.0, np.nan, 0.2, 0.4)["z"])


def _fits(rng, draws, k, n):
    """Slopes and standard errors of ``draws`` sensitivity-like fits: k bins of n periods each."""
    x = np.arange(k, dtype=float)
    y = 0.7 * x[None, :, None] + rng.standard_normal((draws, k, n)) * (1.0 + 0.3 * x[None, :, None])
    w = bin_mean_weights(np.full((draws, k), n), y.std(axis=-1, ddof=1))
    fit = weighted_linear_regression(np.broadcast_to(x, (draws, k)), y.mean(axis=-1), w)
    return fit["slope"], fit["stderr"]


@pytest.mark.parametrize("k, n, low, high", [(5, 40, 0.030, 0.050), (8, 10, 0.045, 0.075)])
def test_slope_test_false_alarm_rate_is_near_alpha(k, n, low, high):
    # equal true slopes, each fitted like a sensitivity (bin means, weights n/s2 from the bins' own
    # spreads, the standard error floored at the weights' scale and Birge-inflated): the z-test's
    # rate at 5 % is below 5 % with 40 periods per bin and about 6 % with 10 (the weights of small
    # bins are inflated by E[1/s2] = 9/7 / sigma2), as docs/compare.md states.  20,000 draws: 3 sigma
    # of a rate near 5 % is 0.46 %.
    rng = np.random.default_rng(5)
    (a, sa), (b, sb) = _fits(rng, 20_000, k, n), _fits(rng, 20_000, k, n)
    rate = np.mean(slope_test(a, sa, b, sb)["p_value"] < 0.05)
    assert low < rate < high, rate


# -- the command on a small hand-made campaign ----------------------------------------------------


@pytest.fixture(scope="module")
def field_file(tmp_path_factory):
    """A field campaign whose 'lidar' is the cup with 1.5 % noise: no volume averaging, no turbulence bias."""
    cond = synthetic_conditions(90, (40.0, 120.0), seed=4)
    rng = np.random.default_rng(8)
    ref = cond["wind_speed"]
    cond["reference_wind_speed"] = ref.copy()
    cond["lidar_wind_speed"] = ref * (1.0 + 0.015 * rng.standard_normal(ref.shape))
    cond["lidar_wind_speed"].attrs = dict(ref.attrs)
    cond.attrs.update(lidarcal_artefact="field_campaign", lidar_cone_angle=28.0, lidar_hybrid_weight=2 / 3,
                      lidar_rwf_fwhm=30.0)
    path = tmp_path_factory.mktemp("compare") / "field.nc"
    cond.to_netcdf(path)
    return path


ARGS = ["--json", "--scheduler", "synchronous", "--min-periods", "5", "--no-progress"]


def _run(argv: list[str]) -> tuple[int, str]:
    """Run the command; return its exit status and stdout."""
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        status = main(argv)
    return status, buffer.getvalue()


@pytest.fixture(scope="module")
def run(field_file):
    """``lidarcal compare field.nc -o c.nc --report c.html --json``: (status, stdout, artefact, report)."""
    out, report = field_file.parent / "c.nc", field_file.parent / "c.html"
    status, stdout = _run(["compare", str(field_file), "-o", str(out), "--report", str(report), *ARGS])
    return status, stdout, out, report


def test_compare_command_writes_one_json_object_and_the_artefact(run, field_file):
    status, stdout, out, _ = run
    assert status == 0
    js = json.loads(stdout)  # exactly one object: json.loads refuses trailing text
    assert list(js)[:6] == ["verdict", "alpha", "correction", "cells", "budgets", "next"]
    assert js["alpha"] == 0.05 and js["correction"] == "holm" and js["verdict"] in ("agree", "disagree")
    keys = {
        "height",
        "variable",
        "measured_slope",
        "measured_se",
        "simulated_slope",
        "simulated_se",
        "z",
        "agree",
    }
    assert js["cells"] and all(keys <= set(c) for c in js["cells"])
    assert (js["next"] is None) == (js["verdict"] == "agree")
    if js["next"]:
        assert js["next"].startswith(f"lidarcal diagnose {field_file} ")
    # a cell agrees exactly when its Holm-adjusted p-value is at least alpha; z is the difference over se
    for c in js["cells"]:
        assert c["agree"] == (c["p_adjusted"] >= 0.05)
        se = np.hypot(c["measured_se"], c["simulated_se"])
        assert c["z"] == pytest.approx((c["measured_slope"] - c["simulated_slope"]) / se)
    assert sorted(js["budgets"]["heights"]) == ["120.0", "40.0"]
    ds = open_artefact(out, "comparison")  # written through the schema: validated
    assert ds.attrs["lidarcal_artefact"] == "comparison" and json.loads(ds.attrs["comparison_json"]) == js
    assert json.loads(ds.attrs["lidarcal_config"])["min_periods"] == 5  # --min-periods, the budget's name
    assert ds["turbulence_intensity_measured_slope"].attrs["units"] == "%"
    assert ds["cnr_gradient_simulated_slope"].attrs["units"] == "% m dB-1"
    assert ds["measured_contribution"].attrs["units"] == "m s-1"
    assert set(ds["measured_contributor"].values) >= {"reference_sensor", "statistical"}
    assert set(ds["simulated_contributor"].values) >= {"virtual_reference", "statistical"}
    # the IEC reference-sensor term is the option's value in every populated bin
    ref = ds["measured_contribution"].sel(measured_contributor="reference_sensor").values
    assert np.allclose(ref[np.isfinite(ref)], 0.1)


def test_the_comparison_passes_the_cf_and_acdd_checks(run):
    from lidarcal.compliance import check_compliance, exception_kind

    report = check_compliance(run[2])
    assert report.passed, report.failures
    # CF's one documented exception is the decibel (the CNR-gradient slopes are in % m dB-1)
    assert {exception_kind(line) for line in report.exceptions if line.startswith("cf")} <= {"dB"}


def test_compare_with_model_simulates_the_stored_lidar_again(run, field_file):
    # --model: the lidar stored in the comparison, simulated again with the same seed: the same numbers
    _, stdout, out, _ = run
    status, stdout2 = _run(
        ["compare", str(field_file), "-o", str(out.parent / "c2.nc"), "--model", str(out), *ARGS]
    )
    js, js2 = json.loads(stdout), json.loads(stdout2)
    assert status == 0 and js2["cells"] == js["cells"]
    assert js2["model"] == "corrected model of the diagnosis c.nc"


def test_the_lidar_simulated_is_nominal_bench_calibrated_or_a_diagnosis(field_file, run):
    from lidarcal.compare.core import lidar_to_simulate
    from lidarcal.rwf import range_weighting_function

    field = xr.open_dataset(field_file)
    field.attrs["lidar_cone_angle"] = 30.0

    def model(rwf=None, diagnosis=None):
        kw = {"cube": None, "model": None, "los_noise_model": None}
        return lidar_to_simulate(field, "f.nc", rwf=rwf, diagnosis=diagnosis, **kw)

    plain, origin = model()
    assert plain.cone_angle == 30.0 and plain.cnr_weighting_scale == 0.0 and origin.startswith("nominal")
    # --rwf: the RWF from the artefact (Eq. 2 applied), the cone still from the file's attributes
    rwf = range_weighting_function()
    bench, origin = model(rwf=rwf)
    assert bench.cone_angle == 30.0 and bench.cnr_weighting_scale == 1.0 and "bench-calibrated" in origin
    # --model: the stored model; with --rwf as well it is refused
    stored, origin = model(diagnosis=run[2])
    assert stored.cone_angle == 28.0 and origin == "corrected model of the diagnosis c.nc"
    with pytest.raises(ValueError, match="not both"):
        model(rwf=rwf, diagnosis=run[2])
    # a diagnosis made with an RWF records its profile by digest: --rwf restores it (checked)
    diag = xr.Dataset(attrs={"lidarcal_lidar_model": bench.to_json(), "lidarcal_source_file": "d.nc"})
    restored, origin = model(rwf=rwf, diagnosis=diag)
    assert restored == bench and origin == "corrected model of the diagnosis d.nc"
    with pytest.raises(ValueError, match="not the one the model was built from"):
        model(rwf=range_weighting_function(asymmetry=0.3), diagnosis=diag)


def test_compare_report_draws_both_figures_offline(run):
    page = run[3].read_text()
    assert "Figure 1. Sensitivity slopes" in page and "Figure 2. Uncertainty budgets" in page
    assert "<script src=" not in page and '<link rel="stylesheet" href="http' not in page
    # offline_html skips bokeh's document checks (its E-/W- codes): the plain bokeh panels pass them
    from lidarcal.compare.report import budget_figure, slope_figure
    from lidarcal.htmlpage import check_models, grid

    ds = open_artefact(run[2], "comparison")
    assert check_models({"slopes": grid(slope_figure(ds)), "budgets": grid(budget_figure(ds))}) == []


def test_compare_report_renders_offline_in_chromium(run, chromium):
    import time

    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
    ):
        opts.add_argument(flag)
    opts.binary_location = chromium[0]
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=opts, service=Service(chromium[1]))
    try:
        driver.execute_cdp_cmd("Network.enable", {})
        driver.execute_cdp_cmd(
            "Network.emulateNetworkConditions",
            {"offline": True, "latency": 0, "downloadThroughput": 0, "uploadThroughput": 0},
        )
        driver.get(run[3].as_uri())
        deadline, n_plots = time.time() + 30, 0
        while time.time() < deadline and n_plots < 5:
            time.sleep(0.5)
            n_plots = driver.execute_script(
                "if (!(window.Bokeh && Bokeh.documents.length)) return 0;"
                "let n = 0; for (const d of Bokeh.documents) for (const m of d.all_models) {"
                "  if (m.type === 'Figure') n++; }"
                "return n;"
            )
        assert n_plots == 5  # three slope panels (one per variable) + two budget panels (one per height)
        assert [e for e in driver.get_log("browser") if e["level"] == "SEVERE"] == []
    finally:
        driver.quit()


def test_compare_refuses_bad_input_before_simulating(tmp_path, field_file, capsys):
    no_pair = tmp_path / "conditions.nc"
    xr.open_dataset(field_file).drop_vars("lidar_wind_speed").to_netcdf(no_pair)
    assert main(["compare", str(no_pair), "-o", str(tmp_path / "x.nc")]) == 2
    err = capsys.readouterr().err
    assert "conditions.nc" in err and "lidar_wind_speed" in err and "missing" in err
    assert (
        main(["compare", str(field_file), "--model", "d.nc", "--rwf", "r.nc", "-o", str(tmp_path / "y.nc")])
        == 2
    )
    assert "--model" in capsys.readouterr().err
    assert not (tmp_path / "x.nc").exists() and not (tmp_path / "y.nc").exists()
    with pytest.raises(SystemExit):
        main(["compare", str(field_file), "--alpha", "1.5", "-o", str(tmp_path / "z.nc")])
    # a campaign too short for any slope: an error, not a vacuous "agree"
    short = tmp_path / "short.nc"
    xr.open_dataset(field_file).isel(time=slice(0, 40)).to_netcdf(short)
    assert main(["compare", str(short), "--scheduler", "synchronous", "-o", str(tmp_path / "s.nc")]) == 2
    assert "no slope can be compared" in capsys.readouterr().err and not (tmp_path / "s.nc").exists()
    # the bench-calibrated lidar's LOS error model: residuals need a bench cube
    assert main(["compare", str(field_file), "--los-noise", "residuals", "-o", str(tmp_path / "w.nc")]) == 2
    assert "needs a bench cube" in capsys.readouterr().err
    with pytest.raises(ValueError, match="variables"):
        compare(field_file, variables=["wind_from_direction"])


# -- the verdict on independent campaigns (slow) ---------------------------------------------------

N = 150
HEIGHTS = (40.0, 80.0, 160.0)


def _compare(effects, seed):
    field = make_field_campaign(effects, n_periods=N, heights=HEIGHTS, seed=seed)
    js = summary(to_dataset(compare(field, execution=SIM)))
    print(
        f"\n[compare] {effects} seed {seed}: {js['verdict']}; "
        + ", ".join(f"{c['variable'][:5]}@{c['height']:g} z {c['z']:+.1f}" for c in js["cells"])
    )
    return js


def _cell(js, variable, height):
    return next(c for c in js["cells"] if c["variable"] == variable and c["height"] == height)


@pytest.mark.slow
def test_effect_free_independent_campaigns_agree():
    # three seeds x 3 heights x 3 variables = 27 cells; the Holm correction keeps the chance of any
    # flag in a matched campaign at 5 %, so at most 5 % of the cells (one of 27) may disagree
    flagged = tested = 0
    for seed in (1, 2, 3):
        js = _compare({}, seed)
        tested += len(js["cells"])
        flagged += sum(not c["agree"] for c in js["cells"])
    assert tested >= 24 and flagged <= 0.05 * tested, (flagged, tested)


@pytest.mark.slow
def test_an_overspeeding_cup_makes_the_turbulence_slopes_disagree():
    # the cup reads (1 + 0.08 TI): (L - R)/R falls by 8 % per unit TI more than the virtual lidar's.
    # Every TI slope is steeper measured than simulated; the test has the power to say so where the
    # campaign spans enough TI bins of 10 periods (80 and 160 m; at 40 m, 150 periods fill only 5
    # bins and the slope's standard error is ~5 % per unit TI: z -0.4 here, -8 with 400 periods)
    js = _compare({"reference_overspeeding": {"coefficient": 0.08}}, 1)
    assert js["verdict"] == "disagree" and js["next"].startswith("lidarcal diagnose ")
    ti = [_cell(js, "turbulence_intensity", h) for h in HEIGHTS]
    assert all(c["measured_slope"] < c["simulated_slope"] for c in ti), ti
    assert sum(not c["agree"] for c in ti) >= 2, ti
    # the cup's error is in TI alone: no other slope disagrees
    assert all(c["agree"] for c in js["cells"] if c["variable"] != "turbulence_intensity")


@pytest.mark.slow
def test_a_zero_distance_error_makes_the_shear_slopes_disagree_at_the_lower_heights():
    # gates 4 m further out: the lidar measures higher than it believes and over-reads with shear,
    # by about alpha * 4 cos(28 deg) / z: 8.8 % per unit shear at 40 m, 2.2 % at 160 m
    js = _compare({"zero_distance_offset": {"offset": 4.0}}, 1)
    assert js["verdict"] == "disagree"
    low, mid, high = (_cell(js, "wind_shear_exponent", h) for h in HEIGHTS)
    assert not low["agree"] and not mid["agree"], (low, mid)
    assert low["measured_slope"] > low["simulated_slope"]
    assert low["z"] > mid["z"] > high["z"]  # the error fades with height


@pytest.mark.slow
def test_the_worked_example_of_docs_compare_runs(tmp_path, monkeypatch):
    from test_walkthroughs import run_page

    assert run_page("compare.md", tmp_path, monkeypatch) >= 3


# -- issue 27 §3: the pair's units are checked wherever a field campaign is opened -----------------


def _mislabelled(field_file, path, factor=3.6):
    """The campaign with its reference in km/h still labelled m s-1 (lidar / reference ratio 1/3.6)."""
    ds = xr.open_dataset(field_file).load()
    ds["reference_wind_speed"] = ds["reference_wind_speed"] * factor
    ds["reference_wind_speed"].attrs = dict(xr.open_dataset(field_file)["reference_wind_speed"].attrs)
    ds.to_netcdf(path)
    return path


@pytest.mark.parametrize("command", ["compare", "diagnose", "conditions check"])
def test_a_reference_in_km_h_labelled_m_s_is_refused_naming_the_pair_and_the_ratio(field_file, tmp_path,
                                                                                   capsys, command):
    """Before: compare refused it only by accident ("no (height, variable) has three bins ..."),
    diagnose not at all; field from-sta alone checked the ratio."""
    bad = _mislabelled(field_file, tmp_path / "kmh.nc")
    argv = {"compare": ["compare", str(bad), "--scheduler", "synchronous", "-o", str(tmp_path / "c.nc")],
            "diagnose": ["diagnose", str(bad), "--scheduler", "synchronous", "-o", str(tmp_path / "d.nc")],
            "conditions check": ["conditions", "check", str(bad), "--kind", "field_campaign"]}[command]
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err
    # the ratio, computed here by hand from the file: lidar / reference per finite period-height
    ds = xr.open_dataset(bad)
    a, b = ds["lidar_wind_speed"].values, ds["reference_wind_speed"].values
    ok = np.isfinite(a) & np.isfinite(b) & (b > 0)
    assert f"{np.median(a[ok] / b[ok]):.3f}" == "0.278"  # 1/3.6 with the 1.5 % noise of the field_file
    assert ("kmh.nc: the median ratio of variable 'lidar_wind_speed' (m s-1) to variable "
            "'reference_wind_speed' (m s-1) is 0.278 over") in err, err
    assert "outside the plausible [0.8, 1.25]" in err and not list(tmp_path.glob("[cd].nc"))


def test_the_ratio_check_keeps_a_campaign_that_recorded_skipping_it(field_file, tmp_path):
    """field from-sta --skip-ratio-check records the choice; the campaign is opened with a warning."""
    from lidarcal.diagnose.inputs import open_field

    bad = _mislabelled(field_file, tmp_path / "kmh.nc", factor=1.4)
    with pytest.raises(InputError, match="is 0.71[0-9] over"):
        open_field(bad)
    ds = xr.open_dataset(bad).load()
    ds.attrs["lidar_reference_ratio_checked"] = "no (--skip-ratio-check): the mast is 60 m upstream"
    raw, _ = open_field(ds)
    assert raw is ds
    # a pair within [0.8, 1.25] is opened as it is
    assert open_field(_mislabelled(field_file, tmp_path / "ok.nc", factor=1.2))[0] is not None


def test_compare_on_an_all_nan_reference_names_the_variable(field_file, tmp_path, capsys):
    nan = tmp_path / "nan.nc"
    ds = xr.open_dataset(field_file).load()
    ds["reference_wind_speed"][:] = np.nan
    ds.to_netcdf(nan)
    capsys.readouterr()
    assert main(["compare", str(nan), "--scheduler", "synchronous", "-o", str(tmp_path / "c.nc")]) == 2
    err = capsys.readouterr().err
    assert "nan.nc: variable 'reference_wind_speed' is NaN everywhere" in err, err
    assert not (tmp_path / "c.nc").exists()
