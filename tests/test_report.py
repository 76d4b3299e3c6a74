"""HTML report: content of the plots, offline page, PNGs, and rendering in headless Chromium."""

import re
import time

import numpy as np
import pytest
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.bench import build_cube, simulate_run
from lidarcal.cli import main
from lidarcal.errors import OutputExistsError
from lidarcal.io import write_artefact
from lidarcal.provenance import stamp
from lidarcal.report import confidence_band, fmt, report_figures, write_report
from lidarcal.rwf import range_weighting_function

FIGURES = [  # page order: budget first
    "budget",
    "budget_contributors",
    "sensitivity_wind_shear_exponent",
    "sensitivity_turbulence_intensity",
    "sensitivity_slopes",
    "cube_los_bias",
    "cube_los_std",
    "rwf_shape",
    "rwf_gradients",
]
# plots each section shows at once: one per figure, one heatmap per line of sight for the cube
VISIBLE = {name: 5 if name.startswith("cube_") else 1 for name in FIGURES}
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]


@pytest.fixture(scope="module")
def inputs():
    records = make_records(n=600, heights=(80.0, 100.0, 120.0))
    run = simulate_run(seed=5, accumulation_time="20 s", lidar_serial="WLS7-TEST")
    cube, _ = build_cube(run.rtd, run.control)
    return {
        "records": records,
        "budget": budget(records),
        "sensitivities": [
            sensitivity(records, "wind_shear_exponent"),
            sensitivity(records, "turbulence_intensity"),
        ],
        "cube": stamp(cube, "bench_cube", title="cube", summary="test cube", call="test"),
        "rwf": range_weighting_function(),
    }


@pytest.fixture(scope="module")
def report(inputs, tmp_path_factory):
    """The report as a user gets it: `lidarcal certificate ... --report cert.html`."""
    d = tmp_path_factory.mktemp("report")
    rec = d / "records.nc"
    inputs["records"].to_netcdf(rec)
    files = {
        "budget": write_artefact(inputs["budget"], d / "budget.nc"),
        "cube": write_artefact(inputs["cube"], d / "cube.nc"),
        "rwf": write_artefact(inputs["rwf"], d / "rwf.nc"),
    }
    sens = [write_artefact(s, d / f"sens{i}.nc") for i, s in enumerate(inputs["sensitivities"])]
    args = [
        "certificate",
        "--budget",
        str(files["budget"]),
        "--cube",
        str(files["cube"]),
        "--rwf",
        str(files["rwf"]),
        "-o",
        str(d / "cert.nc"),
        "--report",
        str(d / "cert.html"),
    ]
    for s in sens:
        args += ["--sensitivity", str(s)]
    assert main(args) == 0
    return d / "cert.html"


def _glyphs(plot, glyph_type):
    from bokeh.models import GlyphRenderer

    return [r for r in plot.renderers if isinstance(r, GlyphRenderer) and isinstance(r.glyph, glyph_type)]


def test_budget_plot_shows_every_height_and_marks_thin_bins(inputs):
    from bokeh.models import Line, Scatter, Select

    # the factory fills every bin with 10-39 periods: min_periods=20 leaves bins not certified with a finite U
    b = budget(inputs["records"], min_periods=20)
    figs = report_figures(budget=b)
    assert list(figs) == ["budget", "budget_contributors"]
    page = figs["budget"].bokeh()
    select, plots = page.children[0], page.children[1:]
    assert isinstance(select, Select)
    assert select.options == ["all heights", "80 m", "100 m", "120 m"] and select.value == "all heights"
    assert [p.visible for p in plots] == [True, False, False, False]
    k = b.attrs["coverage_factor"]
    thin_seen = 0
    for plot, h in zip(plots[1:], b.height.values, strict=True):
        assert plot.title.text.endswith(f"{h:g} m")
        (line,) = _glyphs(plot, Line)
        data = line.data_source.data
        flag = b.bin_flag.sel(height=h).values
        # U = k u_c, recomputed from the combined standard uncertainty; thin and empty bins not on the line
        expected = np.where(flag == 0, k * b.relative_uncertainty.sel(height=h).values, np.nan)
        np.testing.assert_array_equal(data["wind_speed"], b.wind_speed.values)
        np.testing.assert_allclose(data["U"], expected, rtol=1e-12)
        thin = [r for r in _glyphs(plot, Scatter) if r.glyph.marker == "x"]
        assert len(thin) == 1
        finite = np.isfinite(b.relative_expanded_uncertainty.sel(height=h).values)
        expect_x = b.wind_speed.values[((flag == 1) | (flag == 3)) & finite]  # not certified, not empty
        np.testing.assert_array_equal(thin[0].data_source.data["wind_speed"], expect_x)
        thin_seen += len(expect_x)
    assert thin_seen > 0  # the factory's records do leave thin bins, so the marker is exercised
    contributors = figs["budget_contributors"].bokeh()
    assert contributors.children[0].value == "120 m"
    assert len(contributors.children) == 1 + b.sizes["height"]


def test_confidence_band_matches_numpy_polyfit_covariance(inputs):
    """The band is t(k-2) times the standard error of the fitted mean, here from polyfit's covariance.

    The slopes are weighted least squares of the bin means on the bins' mean variable with
    weights w = n/s² whose error scale is inflated by the Birge ratio (never deflated):
    polyfit with ``w = sqrt(w)`` and the unscaled covariance, times max(1, χ²_ν), is the same fit.
    """
    from scipy import stats

    ds = inputs["sensitivities"][1]
    h = float(ds.height[1])
    one = ds.sel(height=h)
    w_all = one.regression_weight.values
    used = (one.bin_flag.values == 0) & np.isfinite(w_all) & (w_all > 0)
    xb, yb, wb = one.variable_mean.values[used], one.mean_difference.values[used], w_all[used]
    coef, cov = np.polyfit(xb, yb, 1, w=np.sqrt(wb), cov="unscaled")
    chi2 = np.sum(wb * (yb - np.polyval(coef, xb)) ** 2) / (used.sum() - 2)
    x = np.linspace(xb.min() - 0.05, xb.max() + 0.05, 7)
    design = np.stack([x, np.ones_like(x)], axis=1)
    half = stats.t.ppf(0.975, used.sum() - 2) * np.sqrt(
        max(1.0, chi2) * np.einsum("ij,jk,ik->i", design, cov, design))
    fit, lo, hi = confidence_band(ds, h, x)
    np.testing.assert_allclose(fit, np.polyval(coef, x), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(hi - fit, half, rtol=1e-9)  # both exact least squares: rounding only
    np.testing.assert_allclose(fit - lo, half, rtol=1e-9)
    # without the stored standard error the band comes from the bins' residuals: the same numbers
    _, lo2, hi2 = confidence_band(ds.drop_vars("slope_standard_error"), h, x)
    np.testing.assert_allclose(hi2 - lo2, 2 * half, rtol=1e-9)


def test_fmt_rounds_to_three_significant_digits():
    assert fmt(-1.933306920669788) == "-1.93"
    assert fmt(0.000123456) == "0.000123"
    assert fmt(1234.5) == "1230"
    assert fmt(120.0) == "120"
    assert fmt(3.0912e-16) == "3.09e-16"
    assert fmt(float("nan")) == "–"


def test_report_files_are_self_contained(report):
    text = report.read_text()
    assert "<script src=" not in text and '<link rel="stylesheet" href="http' not in text
    assert text.count("<section id=") == len(FIGURES)
    for name in FIGURES:
        assert f'id="{name}"' in text
    assert "WLS7-TEST" in text  # summary table: lidar serial
    from PIL import Image

    for name in FIGURES:
        png = report.with_name(f"cert_{name}.png")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        with Image.open(png) as im:
            w, h = im.size
            dpi = im.info.get("dpi")
        assert w > 400 and h > 200, (name, w, h)
        assert dpi is not None and min(dpi) >= 149.9, (name, dpi)  # pHYs chunk; 150 dpi stored as 5906 px/m
    body = re.sub(r"<script.*?</script>", "", text, flags=re.S)
    headings = re.findall(r"<h2>(.*?)</h2>", body)
    assert len(headings) == len(FIGURES) and not any("_" in h for h in headings), headings
    assert "Expanded uncertainty (k = 2) vs wind speed" in headings
    # numbers a reader sees are rounded to 3 significant digits (4 allowed: "1230.5" style integer parts)
    numbers = re.findall(r"\d+\.\d+", body)
    long_numbers = [s for s in numbers if len(s.replace(".", "").lstrip("0")) > 4]
    assert numbers and long_numbers == [], long_numbers[:5]


def test_report_never_overwrites(report, inputs):
    before = report.stat().st_mtime_ns
    with pytest.raises(OutputExistsError):
        write_report(report, budget=inputs["budget"])
    assert report.stat().st_mtime_ns == before


def test_report_renders_offline_in_headless_chromium(report, chromium):
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    opts = Options()
    for flag in CHROMIUM_FLAGS:
        opts.add_argument(flag)
    opts.binary_location = chromium[0]
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(chromium[1]), options=opts)
    try:
        # no network at all: anything the page tried to fetch would fail and be logged as SEVERE
        driver.execute_cdp_cmd("Network.enable", {})
        driver.execute_cdp_cmd(
            "Network.emulateNetworkConditions",
            {"offline": True, "latency": 0, "downloadThroughput": 0, "uploadThroughput": 0},
        )
        driver.get(report.as_uri())
        # per <section>: canvases that drew something (pixels not all equal), through shadow roots
        probe = """
          if (typeof Bokeh === 'undefined' || !Bokeh.documents.length) return null;
          const drawn = {};
          for (const sec of document.querySelectorAll('section')) {
            let k = 0;
            const walk = (n) => {
              if (!n) return;
              if (n.tagName === 'CANVAS' && n.width > 0 && n.height > 0) {
                const px = n.getContext('2d').getImageData(0, 0, n.width, n.height).data;
                for (let i = 4; i < px.length; i += 4) {
                  if (px[i] !== px[0] || px[i + 1] !== px[1] || px[i + 2] !== px[2] || px[i + 3] !== px[3]) {
                    k++; break;
                  }
                }
              }
              if (n.shadowRoot) walk(n.shadowRoot);
              for (const c of n.children || []) walk(c);
            };
            walk(sec);
            drawn[sec.id] = k;
          }
          return {roots: Bokeh.documents.reduce((k, d) => k + d.roots().length, 0), drawn: drawn};
        """

        def wait_for(done):
            deadline = time.monotonic() + 90  # generous: a loaded 2-core CI machine renders in ~5 s
            state = None
            while time.monotonic() < deadline:
                state = driver.execute_script(probe)
                if state and done(state):
                    break
                time.sleep(0.5)
            return state

        def all_drawn(s):
            return s["roots"] == len(FIGURES) and all(s["drawn"].get(n, 0) >= VISIBLE[n] for n in FIGURES)

        state = wait_for(all_drawn)
        assert state is not None, "BokehJS never loaded"
        assert all_drawn(state), state  # one root per figure, every visible plot drew pixels
        # the height menu: choosing 100 m shows that plot alone, and it draws
        menu = """
          const root = Bokeh.documents[0].roots().find((r) => r.children && r.children[0].options);
          if (arguments[0]) root.children[0].value = arguments[0];
          return root.children.slice(1).map((p) => p.visible);
        """
        driver.execute_script(menu, "100 m")
        deadline = time.monotonic() + 30  # BokehJS compiles and runs the CustomJS asynchronously
        while (shown := driver.execute_script(menu, "")) != [False, False, True, False]:
            if time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert shown == [False, False, True, False], shown
        state = wait_for(all_drawn)
        assert all_drawn(state), state
        errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        assert errors == [], errors
    finally:
        driver.quit()
