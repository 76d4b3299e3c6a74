"""The certificate document (PDF) as poppler reads it: every page rendered, every word placed.

Issue 27 §5: the last rows of page 1's table were drawn over the footer rule, the rows of the
certified range after the last certified bin were all "–" while the text promised 4-16 m/s,
the seal line named ``CERT.nc`` instead of the file, the budget plot had no numerical
tolerance, the contributors page had hairline bars (and, on short runs, no legend), axis
labels ran into the footer, and the expanded uncertainty in m/s was nowhere.  Checked here on
a certificate whose result table is long (8 heights x 23 certified bins: it must continue on
the next page), with ``pdftotext -bbox`` (where each word is) and ``pdftoppm`` (what is drawn);
``tests/test_pipeline.py`` runs the same checks on a real 48-period calibration.
"""

from __future__ import annotations

import html
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.analysis.rule import CertificationRule
from lidarcal.certificate import make_certificate
from lidarcal.certificate.document import seal_statement, write_document
from lidarcal.certificate.document.pages import BOTTOM, FOOTER_RULE

HEIGHTS = (40.0, 60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 200.0)


def settled_records(**kwargs):
    """Records with 6 Monte Carlo replicas: JCGM 101 7.9 certifies only values that settled (h >= 2)."""
    return make_records(replicas=6, **kwargs)


def settled_budget(records):
    """The budget to one significant digit, which 6 replicas of these records reach in every bin."""
    return budget(records, rule=CertificationRule(significant_digits=1))
_WORD = re.compile(r'<word xMin="([\d.]+)" yMin="([\d.]+)" xMax="([\d.]+)" yMax="([\d.]+)">(.*?)</word>')


def pdf_words(pdf: Path, pdftotext: str) -> list[list[tuple[float, float, float, float, str]]]:
    """Every page's words as (x0, y0, x1, y1, text), in figure fractions measured from the bottom."""
    out = subprocess.run([pdftotext, "-bbox", str(pdf), "-"], check=True, capture_output=True,
                         text=True).stdout
    pages = []
    for page in out.split("<page ")[1:]:
        width, height = (float(v) for v in re.match(r'width="([\d.]+)" height="([\d.]+)"', page).groups())
        pages.append([(float(a) / width, 1 - float(d) / height, float(c) / width, 1 - float(b) / height,
                       html.unescape(t)) for a, b, c, d, t in _WORD.findall(page)])
    return pages


def page_text(words) -> str:
    """The words of a page in reading order (lines top to bottom, each left to right), joined by spaces.

    Words whose tops are within 0.002 of the page height (a third of a line of the smallest
    text) share a line: a table's columns are separate texts, placed to within rounding.
    """
    lines: list[list] = []
    for w in sorted(words, key=lambda w: -w[3]):
        if lines and lines[-1][0][3] - w[3] < 0.002:
            lines[-1].append(w)
        else:
            lines.append([w])
    return " ".join(w[4] for line in lines for w in sorted(line, key=lambda w: w[0]))


def check_document(pdf: Path, poppler: tuple[str, str], tmp_path: Path) -> list[str]:
    """The checks every certificate document passes; returns the pages' texts."""
    pages = pdf_words(pdf, poppler[1])
    n = len(pages)
    texts = [page_text(p) for p in pages]
    for i, words in enumerate(pages, 1):
        # nothing but the footer below the footer rule, nothing at all between it and the content
        footer = [w for w in words if w[3] < FOOTER_RULE]
        said = page_text(footer)
        assert said.startswith("Certificate ") and said.endswith(f"page {i} of {n}"), (i, said)
        assert all(w[1] >= BOTTOM - 0.002 for w in words if w[3] >= FOOTER_RULE), \
            (i, [w for w in words if w[3] >= FOOTER_RULE and w[1] < BOTTOM - 0.002])
    # and nothing drawn there either: rendered at 60 dpi, the band between the rule and the lowest
    # content line is white (a plot's axis or tick labels would show as grey pixels)
    from PIL import Image

    prefix = tmp_path / "page"
    subprocess.run([poppler[0], "-r", "60", "-png", str(pdf), str(prefix)], check=True)
    pngs = sorted(tmp_path.glob("page-*.png"))
    assert len(pngs) == n
    for i, png in enumerate(pngs, 1):
        with Image.open(png) as im:
            grey = np.asarray(im.convert("L"))
        h = grey.shape[0]
        band = grey[int(round((1 - BOTTOM) * h)) + 1:int(round((1 - FOOTER_RULE) * h)) - 1]
        assert band.size and (band > 200).all(), (i, int((band <= 200).sum()))
    return texts


@pytest.fixture(scope="module")
def long_records():
    """8 heights x 3,000 periods with 6 replicas, and their budget (built once: about 5 s)."""
    records = settled_records(n=3000, heights=HEIGHTS, seed=3)
    return records, settled_budget(records)


@pytest.fixture(scope="module")
def long_certificate(long_records):
    """A certificate of 8 heights whose bins are all certified from 4.5 to 15.5 m/s (23 rows)."""
    records, b = long_records
    sens = [sensitivity(records, "wind_shear_exponent")]
    cert = make_certificate(budget=b, sensitivities=sens, config={}, call="test", demonstration=True)
    # a long reason (and, in other branches, more lines of results): page 1 cannot hold the table
    cert.attrs["calibration_status_reason"] = " ".join(["the inputs are lidarcal's sample data"] * 12)
    return cert


def test_a_long_result_table_continues_on_the_next_page(long_certificate, tmp_path, poppler):
    pdf = tmp_path / "doc.pdf"
    write_document(pdf, long_certificate, seal=seal_statement(None, "run-7.nc"))
    texts = check_document(pdf, poppler, tmp_path)
    b = long_certificate.rename({v: v[len("budget_"):] for v in long_certificate.variables
                                 if v.startswith("budget_")})
    rel = b.relative_expanded_uncertainty.transpose("wind_speed", "height").values
    absolute = b.expanded_uncertainty.transpose("wind_speed", "height").values
    tol = b.numerical_tolerance.transpose("wind_speed", "height").values
    statement = b.certified_statement.transpose("wind_speed", "height").values
    lo = b.relative_coverage_interval_lower.transpose("wind_speed", "height").values
    hi = b.relative_coverage_interval_upper.transpose("wind_speed", "height").values
    ok = (b.bin_flag.transpose("wind_speed", "height") == 0).values
    rows = [i for i, u in enumerate(b.wind_speed.values) if ok[i].any()]
    assert len(rows) == 23 and all(ok[rows].ravel())
    result = [t for t in texts if "Certified result" in t]
    assert len(result) >= 2 and texts[1] == result[1]  # page 1 and the page after it
    assert "Certified result (continued)" in texts[1]  # the % table itself goes on to page 2
    joined = " ".join(result)
    header = " ".join(f"{h:g} m" for h in HEIGHTS)
    assert all(header in t for t in result)  # the column headers on every page of the tables
    # every certified value in its row, in %, then in m/s
    for i in rows:
        u = b.wind_speed.values[i]
        # U ± its numerical tolerance, or the coverage interval low…high where the bin certifies that
        cells = [f"{lo[i, j]:+.2f}…{hi[i, j]:+.2f}" if statement[i, j] == 1
                 else f"{rel[i, j]:.2f} ± {tol[i, j]:.2g}" for j in range(rel.shape[1])]
        assert f"{u:g} " + " ".join(cells) in joined, u
        assert f"{u:g} " + " ".join(f"{v:.3f}" for v in absolute[i]) in joined, u
    assert "Certified result in m/s: expanded uncertainty U (m/s), k = 2" in joined
    # the seal line names the file that is checked, not a placeholder
    assert "lidarcal verify run-7.nc" in texts[0] and "CERT.nc" not in " ".join(texts)


def test_the_lines_above_the_result_are_evenly_spaced(long_certificate, tmp_path, poppler):
    """The measurand's line naming the model_form contributor ran 3.4 pt lower than the others.

    (matplotlib spaces, and places by its top, a line by its tallest and deepest glyphs.)  The
    budget's last contributor renamed model_form stands for a run with that contributor.
    """
    names = [str(c) for c in long_certificate.budget_contributor.values]
    cert = long_certificate.assign_coords(budget_contributor=[*names[:-1], "model_form"])
    pdf = tmp_path / "doc.pdf"
    write_document(pdf, cert)
    pages = pdf_words(pdf, poppler[1])
    (page,) = [words for words in pages if "U is the expanded" in page_text(words)]
    start = next(w[3] for i, w in enumerate(page) if w[4] == "U" and page[i + 1][4] == "is")
    end = max(w[3] for w in page if w[4] == "Per" and w[3] < start)
    tops = sorted({round(w[3], 4) for w in page if end < w[3] <= start}, reverse=True)
    assert "model_form," in page_text([w for w in page if end < w[3] <= start])
    gaps = -np.diff(tops)
    # a line of the 7.5-pt text is 0.011 of the page high: equal gaps to 0.4 pt (0.0005 of 842 pt)
    assert len(tops) >= 3 and np.ptp(gaps) < 0.0005, gaps


def test_the_certified_range_says_where_the_values_stop(tmp_path, poppler):
    """Winds of 4.5-11 m/s only: the table stops at 11 m/s and says why, not 'promising' 4-16 m/s."""
    records = settled_records(n=1200, heights=(80.0, 120.0), seed=5)
    ref = records.reference_wind_speed
    # no period above 11.2 m/s: bins above 11 m/s empty.  Only the (time, height) records are
    # masked; the per-period key and the replicas (dimension ``trial``) are selected, not masked:
    # ``records.where`` would broadcast every trial over (time, height), 2,400 NaN-padded copies
    # of each (17 million trials, minutes of budget), which no calibration writes.
    calm = records.isel(trial=np.flatnonzero(records.trial_reference_wind_speed.values <= 11.2))
    for name, var in records.data_vars.items():
        if set(var.dims) == {"time", "height"}:
            calm[name] = var.where(ref <= 11.2)
    cert = make_certificate(budget=settled_budget(calm), sensitivities=[], config={}, call="test",
                            demonstration=True)
    pdf = tmp_path / "doc.pdf"
    write_document(pdf, cert)
    texts = check_document(pdf, poppler, tmp_path)
    page1 = texts[0]
    assert "The certified values span 4.5 to 11 m/s of the 4 to 16 m/s range: below 4.5 m/s and above 11 " \
           "m/s no bin has the 10 distinct periods a certified bin needs, at any height." in page1
    table = page1.split("Certified result in m/s")[0]
    cell = r"(\d\.\d\d(?: ± [\d.e-]+)?|–)"
    rows = re.findall(rf"(?<=\s)(\d+(?:\.5)?) {cell} {cell}(?=\s)", table)
    assert rows and rows[0][0] == "4.5" and rows[-1][0] == "11", rows


def test_the_seal_line_names_the_certificate_file():
    from lidarcal.certificate.document.facts import signature_status
    from lidarcal.certificate.seal import INTEGRITY_ATTR, SIGNATURE_ATTR, SIGNATURE_KEY_ATTR

    # a certificate read from a file (open_artefact records which), sealed, or signed too
    read = {INTEGRITY_ATTR: "x", "lidarcal_source_file": "lab-2026-07.nc"}
    assert signature_status(read).endswith("check with lidarcal verify lab-2026-07.nc")
    signed = {**read, SIGNATURE_ATTR: "s", SIGNATURE_KEY_ATTR: "ed25519:0123abcd"}
    assert signature_status(signed) == ("signed (Ed25519) by key ed25519:0123abcd; check with lidarcal "
                                        "verify lab-2026-07.nc and --public-key with the signer's public key")
    # a certificate about to be written (calibrate, certificate --report): its file and key are known
    assert seal_statement("ed25519:0123abcd", "certificate.nc", "lab.key.pub").endswith(
        "check with lidarcal verify certificate.nc --public-key lab.key.pub")
    # of unknown origin: no placeholder standing for a file name
    assert signature_status({INTEGRITY_ATTR: "x"}).endswith("check its file with lidarcal verify")


def test_budget_plot_bars_are_the_numerical_tolerance():
    from matplotlib.container import ErrorbarContainer
    from matplotlib.figure import Figure

    from lidarcal.certificate.document.figures import draw_budget

    b = settled_budget(settled_records(n=1200, heights=(80.0, 120.0), seed=5))
    b["numerical_tolerance"] = b["relative_expanded_uncertainty"] * 0 + 0.05
    fig = Figure()
    draw_budget(fig, b)
    top = fig.axes[0]
    bars = [c for c in top.containers if isinstance(c, ErrorbarContainer)]
    assert len(bars) == 2  # one per height
    for c in bars:
        segments = c.lines[2][0].get_segments()
        spans = [s[1, 1] - s[0, 1] for s in segments if np.all(np.isfinite(s))]
        assert spans and np.allclose(spans, 2 * 0.05)  # ± the tolerance (0.05 %)
    assert "numerical tolerance" in top.get_title()


def test_contributor_bars_are_wide_and_the_legend_is_always_there(long_records):
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    from lidarcal.certificate.document.figures import draw_contributors

    b = long_records[1].copy()  # the shared budget, not changed for the other tests
    # a short run: the lowest height has no certified bin at all, yet the legend names everything
    b["bin_flag"] = b["bin_flag"].where(b.height != 40.0, 1)
    fig = Figure(figsize=(8.27, 11.69))
    draw_contributors(fig, b)
    (legend,) = fig.legends
    names = [t.get_text() for t in legend.get_texts()]
    assert names == [str(c).replace("_", " ") for c in b.contributor.values] + ["combined"]
    widths = [float(np.atleast_1d(c.get_linewidth())[0]) for ax in fig.axes for c in ax.collections
              if isinstance(c, LineCollection) and len(c.get_segments())]
    # 23 bins x 5 bars over a 7-inch panel: about 4 points each (they were 0.8 pt, hairlines)
    assert widths and min(widths) >= 2.5, min(widths)


def test_a_page_with_other_characters_embeds_a_font_that_has_them(tmp_path, poppler):
    """Standard Helvetica (Windows-1252) where it suffices, TrueType where a name needs more."""
    records = make_records(n=600, heights=(80.0, 120.0), seed=5)
    cert = make_certificate(budget=budget(records), sensitivities=[], config={}, call="test",
                            demonstration=True)
    cert.attrs["customer_name"] = "Łódź Wind Sp. z o.o."  # Ł, ó, ź: not all in Windows-1252
    pdf = tmp_path / "doc.pdf"
    write_document(pdf, cert)
    # poppler-utils' pdffonts (beside pdftotext): page 1 embeds a TrueType font, the others use Helvetica
    fonts = subprocess.run([str(Path(poppler[1]).with_name("pdffonts")), str(pdf)], capture_output=True,
                           text=True, check=True).stdout
    assert "TrueType" in fonts and "Helvetica" in fonts, fonts
    text = page_text(pdf_words(pdf, poppler[1])[0])
    assert "Łódź Wind Sp. z o.o." in text  # not '?' for the letters outside Windows-1252
