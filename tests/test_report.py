"""HTML report: content of the plots, offline page, PNGs, and rendering in headless Chromium."""

import json
import re
import time

import numpy as np
import pytest
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.analysis.rule import CertificationRule
from lidarcal.bench import build_cube, simulate_run
from lidarcal.certificate.document.facts import fmt
from lidarcal.certificate.document.figure_data import confidence_band
from lidarcal.certificate.report import report_figures, write_report
from lidarcal.cli import main
from lidarcal.errors import OutputExistsError
from lidarcal.io import write_artefact
from lidarcal.provenance import stamp
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
# plots each section shows at once: one per figure (the cube's line of sight is chosen by a menu)
VISIBLE = dict.fromkeys(FIGURES, 1)
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
    # eight Monte Carlo replicas, settled to one significant digit: certified bins to draw
    records = make_records(n=600, heights=(80.0, 100.0, 120.0), replicas=8)
    run = simulate_run(seed=5, accumulation_time="20 s", lidar_serial="WLS7-TEST")
    cube, _ = build_cube(run.rtd, run.control)
    return {
        "records": records,
        "budget": budget(records, rule=CertificationRule(significant_digits=1)),
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


def test_budget_plot_shows_every_height_and_marks_thin_bins(inputs):
    from bokeh.models import GlyphRenderer, Line, Scatter, Select

    # the factory fills every bin with 10-39 periods: min_periods=20 leaves bins not certified with a finite U
    b = budget(inputs["records"], rule=CertificationRule(min_periods=20, significant_digits=1))
    figs = report_figures(budget=b)
    assert list(figs) == ["budget", "budget_contributors"]
    page = figs["budget"].bokeh()
    select, plot = page.children
    assert isinstance(select, Select)
    assert select.options == ["all heights", "80 m", "100 m", "120 m"] and select.value == "all heights"
    renderers = [r for r in plot.renderers if isinstance(r, GlyphRenderer)]
    assert all(r.visible for r in renderers)  # "all heights" shows every height
    # the axes are the certified range: bins with enough periods, centres 4-16 m/s
    inside = (b.wind_speed >= 4) & (b.wind_speed <= 16) & (b.bin_flag == 0)
    step = float(b.wind_speed[1] - b.wind_speed[0])
    assert (plot.x_range.start, plot.x_range.end) == pytest.approx((4 - step / 2, 16 + step / 2))
    top = 1.15 * float(b.relative_expanded_uncertainty.where(inside).max())
    assert plot.y_range.end == pytest.approx(top)
    k = b.attrs["coverage_factor"]
    thin_seen = 0
    for h in b.height.values:
        mine = [r for r in renderers if r.name == f"{h:g} m"]
        (line,) = [r for r in mine if isinstance(r.glyph, Line)]
        data = line.data_source.data
        flag = b.bin_flag.sel(height=h).values
        # U = k u_c, recomputed from the combined standard uncertainty; thin and empty bins not on the line
        expected = np.where(flag == 0, k * b.relative_uncertainty.sel(height=h).values, np.nan)
        # one source holds every height's columns (fewer models to write): this height's are its own
        np.testing.assert_array_equal(data[line.glyph.x], b.wind_speed.values)
        np.testing.assert_allclose(data[line.glyph.y], expected, rtol=1e-12)
        thin = [r for r in mine if isinstance(r.glyph, Scatter) and r.glyph.marker == "x"]
        assert len(thin) == 1
        finite = np.isfinite(b.relative_expanded_uncertainty.sel(height=h).values)
        expect_x = b.wind_speed.values[(flag == 1) & finite]  # too few periods
        drawn = np.isfinite(np.asarray(thin[0].data_source.data[thin[0].glyph.y], dtype=float))
        np.testing.assert_array_equal(np.asarray(thin[0].data_source.data[thin[0].glyph.x])[drawn], expect_x)
        thin_seen += len(expect_x)
    assert thin_seen > 0  # the factory's records do leave thin bins, so the marker is exercised
    contributors = figs["budget_contributors"].bokeh()
    assert contributors.children[0].value == "120 m"
    bars = contributors.children[1].renderers
    assert len(bars) == b.sizes["contributor"] + 1  # one per contributor, and the combined
    combined = bars[-1].data_source.data
    ok = inside.sel(height=120.0).values
    np.testing.assert_allclose(combined["top"], np.where(ok, b.relative_uncertainty.sel(height=120.0).values,
                                                         np.nan))


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


def test_pdf_and_html_draw_one_preparation_of_a_sensitivity(inputs):
    """The PDF panel and the HTML plot of a sensitivity draw the same bin means and regression line,
    prepared once (lidarcal.certificate.document.figure_data), and that line is intercept + slope * x."""
    from matplotlib.figure import Figure as MplFigure

    from lidarcal.certificate.document.figures import draw_sensitivity

    ds = inputs["sensitivities"][0]
    fig = MplFigure()
    draw_sensitivity(fig, ds)
    ax = fig.axes[0]  # the first height's panel
    h = float(ds.height[0])
    one = ds.sel(height=h)
    (regression,) = ax.lines[-1:]  # the fitted line, drawn last
    x_pdf, fit_pdf = regression.get_xdata(), regression.get_ydata()
    # hand computation: the line through the artefact's own slope and intercept
    np.testing.assert_allclose(fit_pdf, float(one.intercept) + float(one.slope) * x_pdf, rtol=1e-12)
    model = report_figures(sensitivities=[ds])[f"sensitivity_{ds.attrs['environmental_variable']}"].bokeh()
    label = f"{fmt(h)} m"
    curve = next(r.data_source.data for r in model.children[1].renderers
                 if f"fit|{label}" in r.data_source.data)
    points = next(r.data_source.data for r in model.children[1].renderers
                  if f"y|{label}" in r.data_source.data)
    drawn = np.isfinite(curve[f"xf|{label}"])
    np.testing.assert_array_equal(curve[f"xf|{label}"][drawn], x_pdf)  # the same points, not a re-sampling
    np.testing.assert_array_equal(curve[f"fit|{label}"][drawn], fit_pdf)
    # the kept bins (bin_flag 0), the same in both: PDF error-bar markers and HTML points
    kept = (one.bin_flag.values == 0) & np.isfinite(one.mean_difference.values)
    x_html = np.asarray(points[f"x|{label}"], float)
    np.testing.assert_array_equal(x_html[np.isfinite(x_html)], one.bin.values[kept])
    np.testing.assert_array_equal(ax.lines[0].get_xdata(), one.bin.values[kept])


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
    assert not list(report.parent.glob("cert_*.png"))  # PNGs only when asked (write_report(png=True))
    body = re.sub(r"<script.*?</script>", "", text, flags=re.S)
    headings = re.findall(r"<h2>(.*?)</h2>", body)
    assert headings[-1] == "Inputs and provenance"
    headings = headings[:-1]
    assert len(headings) == len(FIGURES) and not any("_" in h for h in headings), headings
    assert "Expanded uncertainty (k = 2) vs wind speed" in headings
    # numbers a reader sees are rounded to 3 significant digits (4 allowed: "1230.5" style integer parts)
    body = body.split('<div id="provenance">')[0]  # the inputs' file names and hashes are not numbers
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
        # the height menu: choosing 100 m shows that height's renderers alone, and the plot draws
        menu = """
          const root = Bokeh.documents[0].roots().find((r) => r.children && r.children[0].options);
          if (arguments[0]) root.children[0].value = arguments[0];
          const names = root.children[1].renderers.filter((r) => r.visible).map((r) => r.name);
          return [...new Set(names)];
        """
        driver.execute_script(menu, "100 m")
        deadline = time.monotonic() + 30  # BokehJS compiles and runs the CustomJS asynchronously
        while (shown := driver.execute_script(menu, "")) != ["100 m"]:
            if time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert shown == ["100 m"], shown
        # a sensitivity's menu copies that height's columns into the drawn ones, and retitles the plot
        sens_menu = """
          const root = Bokeh.documents[0].roots().find((r) => r.children && r.children[0].options
                                                       && r.children[1].title.text.includes(" m = "));
          if (arguments[0]) root.children[0].value = arguments[0];
          const src = root.children[1].renderers.map((r) => r.data_source.data)
                          .find((d) => d["x|100 m"] !== undefined);
          return [root.children[1].title.text.split(":")[0],
                  Array.from(src["y"]).every((v, i) => Object.is(v, src["y|100 m"][i]))
                  && !Array.from(src["y"]).every((v, i) => Object.is(v, src["y|80 m"][i]))];
        """
        driver.execute_script(sens_menu, "100 m")
        deadline = time.monotonic() + 30
        while (state := driver.execute_script(sens_menu, "")) != ["100 m", True]:
            if time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert state == ["100 m", True], state
        # the cube's menu shows one line of sight at a time, and the plot draws it
        cube_menu = """
          const root = Bokeh.documents[0].roots().find((r) => r.children && r.children[0].options
                                                       && r.children[1].title.text.includes("LOS"));
          if (arguments[0]) root.children[0].value = arguments[0];
          return [root.children[0].options.length,
                  root.children[1].renderers.filter((r) => r.visible).map((r) => r.name)];
        """
        los = driver.execute_script(cube_menu, "")[1]
        assert len(los) == 1 and los[0].startswith("LOS "), los
        driver.execute_script(cube_menu, "LOS V (vertical beam)")
        deadline = time.monotonic() + 30
        while (state := driver.execute_script(cube_menu, "")) != [5, ["LOS V (vertical beam)"]]:
            if time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert state == [5, ["LOS V (vertical beam)"]], state
        state = wait_for(all_drawn)
        assert all_drawn(state), state
        errors = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        assert errors == [], errors
    finally:
        driver.quit()


# ------------------------------------------------------------------ the certificate document (PDF)


def _pdf_pages(pdf, poppler, mode="-layout"):
    """Text of every page (pdftotext ``mode``) and the pages rendered to PNG (pdftoppm, 40 dpi).

    ``-layout`` keeps a table's rows; ``-raw`` (content order) keeps each label with its value,
    whatever pdftotext makes of the two columns of page 1.
    """
    import subprocess

    from PIL import Image

    text = subprocess.run([poppler[1], mode, str(pdf), "-"], check=True, capture_output=True,
                          text=True).stdout
    pages = text.split("\f")[:-1]  # pdftotext ends every page with a form feed
    prefix = pdf.with_name(pdf.stem + "-page")
    subprocess.run([poppler[0], "-r", "40", "-png", str(pdf), str(prefix)], check=True)
    images = []
    for png in sorted(pdf.parent.glob(prefix.name + "-*.png")):
        with Image.open(png) as im:
            images.append(np.asarray(im.convert("L")))
    return pages, images


def test_certificate_document_pages(report, poppler):
    import xarray as xr

    from lidarcal.certificate import headline_range

    pdf = report.with_suffix(".pdf")
    assert pdf.read_bytes()[:5] == b"%PDF-"
    cert = xr.open_dataset(report.with_name("cert.nc"))
    pages, images = _pdf_pages(pdf, poppler)
    cid = cert.attrs["certificate_id"]  # the lab's id (the ACDD id only when there is none)
    n = len(pages)
    assert n == len(images) >= 8  # page 1, budget, contributors, 2 sensitivities + Eq. 12, cube x2, RWF ...
    for i, (page, image) in enumerate(zip(pages, images, strict=True), 1):
        assert f"Certificate {cid} · status: demonstration" in " ".join(page.split()), (i, page[-300:])
        assert f"page {i} of {n}" in page, (i, page[-300:])
        assert image.shape == (468, 331)  # A4 portrait at 40 dpi: 11.69 x 8.27 in
        assert (image < 128).mean() > 0.005  # something is drawn on every page
    first = " ".join(pages[0].split())
    raw, _ = _pdf_pages(pdf, poppler, "-raw")
    facts = " ".join(raw[0].split())
    for words in ("DEMONSTRATION: not a calibration of a real instrument", "Calibration status demonstration",
                  f"Certificate id {cid}", "Serial number WLS7-TEST", "Bench run",
                  "Seal sealed, unsigned",
                  "Certified result: relative expanded uncertainty U (%), k = 2"):
        assert words in facts, words
    lo, hi = headline_range(cert)
    assert f"{lo:.2f} % to {hi:.2f} %" in first
    # the result table: every certified bin's value, in its row, under the heights' header; the
    # rows that do not fit above page 1's footer go on to the next page(s), headers repeated
    budget = cert.rename({v: v[len("budget_"):] for v in cert.variables if v.startswith("budget_")})
    header = [f"{h:g} m" for h in budget.height.values]
    assert " ".join(header) in first
    first = " ".join(" ".join(page.split()) for page in pages if "Certified result" in page)

    def grid(name):
        return budget[name].transpose("wind_speed", "height").values

    rel, tol = grid("relative_expanded_uncertainty"), grid("numerical_tolerance")
    lo_end, hi_end = grid("relative_coverage_interval_lower"), grid("relative_coverage_interval_upper")
    statement = grid("certified_statement")
    ok = grid("bin_flag") == 0
    assert (statement[ok] == 1).any() and (statement[ok] == 0).any()  # both kinds of statement on the page
    for i, u in enumerate(budget.wind_speed.values):
        if 4 <= u <= 16 and ok[i].any():
            # U ± its tolerance, or the certified interval low…high where the bin certifies it
            cells = [("–" if not ok[i, j] else f"{lo_end[i, j]:+.2f}…{hi_end[i, j]:+.2f}"
                      if statement[i, j] == 1 else f"{rel[i, j]:.2f} ± {tol[i, j]:.2g}")
                     for j in range(rel.shape[1])]
            assert f"{u:g} " + " ".join(cells) in first, u
    # the SHA-256 of every input comes last
    last = " ".join(pages[-1].split())
    assert all(c["sha256"] in last for c in json.loads(cert.attrs["lidarcal_provenance_chain"]))


def test_certificate_document_states_status_admin_data_and_tolerance(inputs, report, tmp_path, poppler):
    import xarray as xr

    from lidarcal.certificate.document import parts_of, write_document

    cert = xr.open_dataset(report.with_name("cert.nc")).load()
    cert.attrs.update(calibration_status="demonstration", certificate_id="LAB-2026-0042",
                      item_manufacturer="Acme Lidar", item_model="WL-7", item_firmware="3.2.1",
                      laboratory_name="Test Lab", responsible_persons="A. Person (head); B. Other (operator)",
                      rf_driver_calibration_reference="RF-CAL-17", lidarcal_signature="c2ln",
                      lidarcal_signature_key="ed25519:0123abcd")
    parts = parts_of(cert)
    parts["budget"]["numerical_tolerance"] = parts["budget"]["relative_expanded_uncertainty"] * 0 + 0.012
    out = write_document(tmp_path / "doc.pdf", cert, parts=parts)
    pages, _ = _pdf_pages(out["pdf"], poppler, "-raw")
    first = " ".join(pages[0].split())
    for words in ("DEMONSTRATION", "Calibration status demonstration", "Certificate id LAB-2026-0042",
                  "Manufacturer Acme Lidar", "Model WL-7", "Firmware 3.2.1", "Laboratory Test Lab",
                  "A. Person (head)", "B. Other (operator)", "RF driver cal. RF-CAL-17", "± 0.012",
                  "Seal signed (Ed25519) by key ed25519:0123abcd"):
        assert words in first, words
    assert all("LAB-2026-0042 · status: demonstration" in p for p in pages)
    with pytest.raises(OutputExistsError):
        write_document(tmp_path / "doc.pdf", cert, parts=parts)


def test_budget_figure_is_scaled_to_the_certified_range(inputs):
    from matplotlib.figure import Figure

    from lidarcal.certificate.document.figures import draw_budget

    b = budget(inputs["records"], rule=CertificationRule(min_periods=20, significant_digits=1))
    fig = Figure()
    draw_budget(fig, b)
    top, bottom = fig.axes
    inside = (b.wind_speed >= 4) & (b.wind_speed <= 16) & (b.bin_flag == 0)
    certified = b.relative_expanded_uncertainty.where(inside)
    step = float(b.wind_speed[1] - b.wind_speed[0])
    # x: the bins that hold certified values (inside 4-16 m/s), half a bin beyond: not the empty ends
    held = b.wind_speed.values[inside.any("height").values]
    assert 4 < held.min() or held.max() < 16  # the factory's records do not fill the range
    assert top.get_xlim() == pytest.approx((held.min() - step / 2, held.max() + step / 2))
    tol = b["numerical_tolerance"].where(inside).fillna(0) if "numerical_tolerance" in b else 0
    assert top.get_ylim() == pytest.approx((0, 1.15 * float((certified + tol).max())))
    # the other bins (thin, or outside 4-16 m/s) are in the second panel, not on the first
    drawn = np.concatenate([line.get_xdata()[np.isfinite(line.get_ydata())] for line in top.lines])
    assert drawn.min() >= 4 and drawn.max() <= 16
    apart = int((np.isfinite(b.relative_expanded_uncertainty) & ~inside).sum())
    assert apart > 0 and sum(line.get_xdata().size for line in bottom.lines) == apart


def test_cube_colour_scale_from_the_cnr_bins_drawn(inputs):
    from lidarcal.certificate.document.figure_data import cube_colour_limits, drawn_cnr_range

    cube = inputs["cube"]
    axis = np.sort(cube.cnr.values)
    lo, hi = axis[1] + 0.3, axis[-2] - 0.3  # records between bins: the bracketing bins are drawn from
    assert drawn_cnr_range(cube, {"cnr_min_db": lo, "cnr_max_db": hi}) == (axis[1], axis[-2])
    assert drawn_cnr_range(cube, {}) is None
    drawn = (axis[1], axis[-1])
    keep = (cube.cnr >= drawn[0]) & (cube.cnr <= drawn[1])
    values = cube.los_std.where(keep).values
    values = values[np.isfinite(values)]
    assert cube_colour_limits(cube.los_std, drawn, False) == pytest.approx(
        (values.min(), np.percentile(values, 99)))
    bias = np.abs(cube.los_bias.where(keep).values)
    top = np.percentile(bias[np.isfinite(bias)], 99)
    assert cube_colour_limits(cube.los_bias, drawn, True) == pytest.approx((-top, top))


def test_report_page_order_result_first_hashes_last(report):
    text = re.sub(r"<script.*?</script>", "", report.read_text(), flags=re.S)
    status, headline = text.index("Calibration status"), text.index("Expanded uncertainty: ")
    first_plot, hashes = text.index("<section id="), text.index("sha256")
    assert status < headline < first_plot < hashes


def test_report_pngs_on_request(inputs, tmp_path):
    from PIL import Image

    out = write_report(tmp_path / "r.html", budget=inputs["budget"], rwf=inputs["rwf"], png=True)
    assert out["pdf"] is None  # the document needs a certificate
    assert [p.name for p in out["png"]] == ["r_budget.png", "r_budget_contributors.png", "r_rwf.png"]
    for png in out["png"]:
        with Image.open(png) as im:
            assert min(im.info["dpi"]) >= 149.9 and im.size[0] > 1000
    # with a certificate the document is written too, and is not listed as a PNG
    from lidarcal.certificate import make_certificate

    cert = make_certificate(budget=inputs["budget"], sensitivities=[], demonstration=True)
    out = write_report(tmp_path / "c.html", certificate=cert, png=False)
    assert out["png"] == [] and out["pdf"].name == "c.pdf"


def test_report_figures_pass_bokehs_document_checks(inputs):
    """offline_html skips bokeh's validation (a fifth of the page's cost): the figures pass it here."""
    from lidarcal.htmlpage import check_models

    figs = report_figures(budget=inputs["budget"], sensitivities=inputs["sensitivities"], cube=inputs["cube"],
                          rwf=inputs["rwf"])
    assert check_models({name: fig.bokeh() for name, fig in figs.items()}) == []
    # the check does find what bokeh calls a problem: a plot without renderers
    from bokeh.plotting import figure

    assert any("MISSING_RENDERERS" in issue for issue in check_models({"empty": figure()}))


def test_report_figures_one_legend_right_and_no_unused_glyphs(inputs):
    """Each plot's legend is moved right of it (no hidden copy left in the plot), and every glyph
    renderer, as bokeh's own full walk of the model finds them, draws no selection/mute variant."""
    from bokeh.models import GlyphRenderer, Legend, Plot

    figs = report_figures(budget=inputs["budget"], sensitivities=inputs["sensitivities"], cube=inputs["cube"],
                          rwf=inputs["rwf"])
    with_legend = 0
    for name, fig in figs.items():
        model = fig.bokeh()
        (plot,) = model.select({"type": Plot})
        legends = list(model.select({"type": Legend}))
        assert [x for x in plot.right if isinstance(x, Legend)] == legends, name
        assert not [x for x in plot.center if isinstance(x, Legend)], name
        with_legend += len(legends)
        renderers = list(model.select({"type": GlyphRenderer}))
        assert renderers, name
        assert all(r.nonselection_glyph is None and r.muted_glyph is None for r in renderers), name
    # every figure but the two cube heatmaps (a colour bar, no legend) has one
    assert with_legend == len(figs) - 2


def test_gc_paused_restores_the_collector():
    import gc

    from lidarcal.certificate.document.pages import gc_paused

    assert gc.isenabled()
    with gc_paused():
        assert not gc.isenabled()
        with gc_paused():  # nested: still paused, and the outer one restores it
            pass
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError), gc_paused():
        raise RuntimeError("a failure while drawing")
    assert gc.isenabled()
    gc.disable()
    try:
        with gc_paused():
            pass
        assert not gc.isenabled()  # a collector the caller disabled stays disabled
    finally:
        gc.enable()
