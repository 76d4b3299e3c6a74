"""HTML report: content of the plots, offline page, PNGs, and rendering in headless Chromium."""

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
from lidarcal.report import report_figures, write_report
from lidarcal.rwf import range_weighting_function

FIGURES = [
    "cube_los_bias",
    "cube_los_std",
    "rwf_shape",
    "rwf_gradients",
    "sensitivity_wind_shear_exponent",
    "sensitivity_turbulence_intensity",
    "sensitivity_slopes",
    "budget",
    "budget_contributors",
]
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


def test_budget_plot_shows_the_budget_numbers(inputs):
    import holoviews as hv
    from bokeh.models import GlyphRenderer, Line

    b = inputs["budget"]
    figs = report_figures(budget=b)
    assert list(figs) == ["budget", "budget_contributors"]
    model = hv.render(figs["budget"], backend="bokeh")
    lines = [r for r in model.renderers if isinstance(r, GlyphRenderer) and isinstance(r.glyph, Line)]
    assert len(lines) == b.sizes["height"] == 3
    for r, h in zip(lines, b.height.values, strict=True):
        data = r.data_source.data
        np.testing.assert_array_equal(data["wind_speed"], b.wind_speed.values)
        np.testing.assert_array_equal(
            data["relative_uncertainty"], b.relative_uncertainty.sel(height=h).values
        )
    assert model.title.text.startswith("Combined standard uncertainty (monte_carlo approach)")
    contributors = hv.render(figs["budget_contributors"], backend="bokeh")
    n_lines = sum(isinstance(r, GlyphRenderer) and isinstance(r.glyph, Line) for r in contributors.renderers)
    assert n_lines == b.sizes["contributor"] + 1  # contributors and the combined total, at 120 m


def test_report_files_are_self_contained(report):
    text = report.read_text()
    assert "<script src=" not in text and '<link rel="stylesheet" href="http' not in text
    assert text.count("<section id=") == len(FIGURES)
    for name in FIGURES:
        assert f'id="{name}"' in text
    assert "WLS7-TEST" in text  # summary table: lidar serial
    import matplotlib.image

    for name in FIGURES:
        png = report.with_name(f"cert_{name}.png")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        h, w = matplotlib.image.imread(png).shape[:2]
        assert w > 400 and h > 200, (name, w, h)


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
        probe = """
          if (typeof Bokeh === 'undefined' || !Bokeh.documents.length) return null;
          let canvases = 0;
          const walk = (n) => {
            if (!n) return;
            if (n.tagName === 'CANVAS') canvases++;
            if (n.shadowRoot) walk(n.shadowRoot);
            for (const c of n.children || []) walk(c);
          };
          walk(document.body);
          return {roots: Bokeh.documents.reduce((k, d) => k + d.roots().length, 0), canvases: canvases,
                  figures: document.querySelectorAll('.bk-Figure').length};
        """
        deadline = time.monotonic() + 90  # generous: a loaded 2-core CI machine renders in ~5 s
        state = None
        while time.monotonic() < deadline:
            state = driver.execute_script(probe)
            if state and state["roots"] == len(FIGURES) and state["canvases"] >= len(FIGURES):
                break
            time.sleep(0.5)
        assert state is not None, "BokehJS never loaded"
        assert state["roots"] == len(FIGURES) and state["figures"] == len(FIGURES), state
        assert state["canvases"] >= len(FIGURES), state  # every figure drew at least one canvas
        errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        assert errors == [], errors
    finally:
        driver.quit()
