"""The certificate document: a paginated A4 PDF of a calibration certificate (matplotlib only).

:func:`write_document` writes ``report.pdf``: page 1 is the certificate itself (status,
certificate id, issuer, customer, calibrated item, dates and place, method, traceability of
the bench, signature status and the certified result under the headline sentence: per height
and wind-speed bin the relative expanded uncertainty for k = 2 with its numerical tolerance
where the budget has one, then the expanded uncertainty in m/s).  The following pages hold the
figures (:mod:`lidarcal.certificate.document.figures`), every bin of the budget, and the inputs with their
SHA-256.  Every page carries the certificate id, the status and "page x of y" in its footer.
What the pages say comes from :mod:`lidarcal.certificate.document.facts`; this module lays it out.

Nothing is drawn below :data:`BOTTOM`, above the footer rule: a table or a list that does not
fit goes on to a continuation page, whatever its length (more heights, more bins, more lines
of facts).  A page whose text is all in Windows-1252 is written with the PDF's standard
Helvetica (no font embedded: the PDF is written several times faster); a page with any other
character (a customer's name in another script) embeds DejaVu Sans as TrueType, so every
character shows.  Either way the text can be searched and extracted.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
import textwrap
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate.document.facts import (
    NOT_STATED,
    certificate_facts,
    certificate_id,
    certified_grid,
    certified_rows,
    extent_text,
    fmt,
    grid_cell,
    model_form_grid,
    not_settled_text,
    stated,
)
from lidarcal.certificate.document.figures import A4, FONT, STYLE, draw, figure_names, parts_of
from lidarcal.certificate.measurand import MEASURAND, model_form_summary
from lidarcal.certificate.results import headline_text
from lidarcal.certificate.seal import VerificationReport, invalid_seal_banner, require_valid_seal
from lidarcal.io import atomic_path, check_writable
from lidarcal.readback import read_attr

__all__ = ["write_document", "gc_paused", "BOTTOM", "FOOTER_RULE"]

#: Height (figure fraction) of the footer rule; the footer's text is below it.
FOOTER_RULE = 0.035
#: The lowest a line of content may reach (figure fraction): clear of the footer rule.
BOTTOM = 0.055
#: Where a continuation page's content starts, below its title.
_TOP = 0.91
_TABLE_FONT = FONT - 0.5


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector inside (a context or a decorator); after, collect once.

    Drawing a document creates some hundred thousand objects (artists, bokeh models), which
    start the collector's full passes over every object of the process (the loaded datasets
    and libraries): on the default run, four of them were an eighth of the report's CPU.  With
    the collector paused, the objects made inside stay in its youngest generation; one pass
    over that generation at the end frees their cycles (a decorated function's figures, gone
    with its frame).  The cycles made meanwhile wait for that pass (the default run's report:
    a peak resident memory about 1 % higher).  Nested use pauses once; a collector the caller
    disabled stays disabled.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
            gc.collect(0)


def _line(size: float, spacing: float = 1.4) -> float:
    """Height of one line of ``size`` pt text, as a figure fraction."""
    return size * spacing / 72 / A4[1]


def _rule(y: float):
    from matplotlib.lines import Line2D

    return Line2D([0.07, 0.95], [y, y], lw=0.5, color="0.3")


def _title(fig, text: str, sub: str = "") -> None:
    fig.text(0.07, 0.965, text, fontsize=FONT + 6, weight="bold", va="top")
    if sub:
        fig.text(0.07, 0.94, sub, fontsize=FONT, va="top", color="0.3")


class _Pages:
    """The document's pages, in order; :meth:`next` starts a continuation page of a flowing block."""

    def __init__(self) -> None:
        from matplotlib.figure import Figure

        self._figure = Figure
        self.figs: list[Any] = []

    def new(self):
        fig = self._figure(figsize=A4)
        self.figs.append(fig)
        return fig

    def next(self, title: str) -> tuple[Any, float]:
        """Start a new page titled ``title``; return it and the height its content starts at."""
        fig = self.new()
        _title(fig, title)
        return fig, _TOP


def _text_rows(pages: _Pages | None, fig, y: float, lines: list[tuple[str, str, dict]], *,
               continued: str = "", x0: float = 0.07, x1: float = 0.33, width: int = 80) -> tuple[Any, float]:
    """Write (label, value, style) rows from ``y`` down, on to new pages when one is full (``pages``).

    Returns the page and the height where the next content may start.  Without ``pages`` (page
    1's facts, a fixed set of short sections) the rows stay on ``fig``.
    """
    line = _line(FONT, 1.45)
    for label, value, style in lines:
        if style.get("section"):
            if pages is not None and y - 2.5 * line < BOTTOM:
                fig, y = pages.next(continued)
            y -= 0.4 * line
            fig.text(x0, y, label, fontsize=FONT + 1.5, weight="bold", va="top")
            y -= 1.25 * line
            continue
        wrapped = [w for part in str(value).split("\n")
                   for w in (textwrap.wrap(part, width, break_on_hyphens=False) or [""])]
        if pages is not None and y - line * len(wrapped) < BOTTOM:
            fig, y = pages.next(continued)
        fig.text(x0 + 0.015, y, label, fontsize=FONT, va="top", color="0.25")
        fig.text(x1, y, "\n".join(wrapped), fontsize=FONT, va="top", linespacing=1.3,
                 color=style.get("color", "black"), weight=style.get("weight", "normal"))
        y -= line * len(wrapped)
    return fig, y


def _columns(fig, y: float, blocks: list[list[tuple[str, str, dict]]]) -> float:
    """Page 1's facts: the first block across the page, the other two side by side; return the y below."""
    y = _text_rows(None, fig, y, blocks[0], x0=0.07, x1=0.22, width=100)[1]
    return min(_text_rows(None, fig, y, blocks[1], x0=0.07, x1=0.22, width=44)[1],
               _text_rows(None, fig, y, blocks[2], x0=0.52, x1=0.67, width=40)[1])


@dataclass
class _Table:
    """A wind speed x height table: heading, cells, and the title of its continuation pages.

    ``heading`` holds lines of (text, size, style); ``cells(i, j)`` gives a cell's text and
    whether it is certified (black) or not (grey).
    """

    heading: list[tuple[str, float, dict]]
    g: dict[str, Any]
    rows: np.ndarray
    cells: Callable[[int, int], tuple[str, bool]]
    continued: str


def _heading_height(heading: list[tuple[str, float, dict]]) -> float:
    return sum(_line(size, 1.25) * (text.count("\n") + 1) + 0.004 for text, size, _ in heading)


def _flow_table(pages: _Pages, fig, y: float, table: _Table) -> tuple[Any, float]:
    """Draw ``table`` from ``y`` down, on continuation pages as needed; return the page and the next y.

    The heading and at least three rows (or all, when fewer) start together; each page repeats
    the column headers.
    """
    line = _line(_TABLE_FONT)
    header = 2.3 * line
    rows = list(table.rows)
    if y - _heading_height(table.heading) - header - line * (min(3, len(rows)) + 0.5) < BOTTOM:
        fig, y = pages.next(table.continued)
    for text, size, style in table.heading:
        # a text per line, placed by its baseline: matplotlib spaces (and, placed by its top,
        # shifts) a line with taller or deeper glyphs than the others, so lines ran unevenly
        for part in text.split("\n"):
            fig.text(0.07, y - _line(size, 0.9), part, fontsize=size, va="baseline", **style)
            y -= _line(size, 1.25)
        y -= 0.004
    y -= 0.006
    while True:
        fits = max(1, int((y - BOTTOM - header) / line - 0.5))
        part, rows = rows[:fits], rows[fits:]
        y = _grid(fig, y, table, part)
        if not rows:
            return fig, y
        fig, y = pages.next(table.continued)


def _grid(fig, y: float, table: _Table, rows: list[int]) -> float:
    """Write the column headers and ``rows`` of ``table`` from ``y`` down; return the next free y."""
    g, size = table.g, _TABLE_FONT
    heights, ws = g["height"], g["wind_speed"]
    x0, first, x1 = 0.07, 0.19, 0.95
    cols = np.linspace(first, x1, len(heights) + 1)[1:]
    line = _line(size)
    fig.text(x0, y, "wind speed\nbin (m/s)", fontsize=size, va="top", weight="bold", linespacing=1.1)
    for c, h in zip(cols, heights, strict=True):
        fig.text(c, y, f"{fmt(h)} m", fontsize=size, va="top", ha="right", weight="bold")
    y -= 2.3 * line
    fig.add_artist(_rule(y + 0.4 * line))
    # one text per column and colour (not per cell): hundreds of text artists are what costs
    style = dict(fontsize=size, va="top", linespacing=1.4)
    fig.text(x0 + 0.02, y, "\n".join(fmt(ws[i]) for i in rows), **style)
    for j, c in enumerate(cols):
        black, grey = [], []
        for i in rows:
            text, ok = table.cells(i, j)
            (black if ok else grey).append(text)
            (grey if ok else black).append(" ")
        fig.text(c, y, "\n".join(black), ha="right", multialignment="right", color="black", **style)
        fig.text(c, y, "\n".join(grey), ha="right", multialignment="right", color="0.45", **style)
    return y - line * len(rows) - 0.5 * line


def _relative_cell(g: dict[str, Any], only_certified: bool) -> Callable[[int, int], tuple[str, bool]]:
    """Cells of U (%): what each bin certifies (:func:`grid_cell`), n/t/o marks on those not certified.

    A certified bin shows U ± its numerical tolerance, or its coverage interval.  Every bin's table
    (``only_certified`` false) shows U (k = 2) for all, the IEC-style value.
    """
    shown = g if only_certified else {**g, "statement": None}

    def cell(i: int, j: int) -> tuple[str, bool]:
        v, ok = g["value"][i, j], bool(g["certified"][i, j])
        if (only_certified and not ok) or not np.isfinite(v):
            return "–", ok
        text = grid_cell(shown, i, j)
        if not ok:
            text += " n" if g["not_settled"][i, j] else " t" if int(g["flag"][i, j]) == 1 else " o"
        return text, ok
    return cell


def _result_tables(budget: xr.Dataset) -> list[_Table]:
    """Page 1's certified result: U (%) with its tolerance, then U (m/s), on the certified bins."""
    k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
    g = certified_grid(budget)
    rows = certified_rows(g)
    tol = "; ± its numerical tolerance (Monte Carlo)" if g["tolerance"] is not None else ""
    intervals = g["statement"] is not None and bool((g["certified"] & (g["statement"] == 1)).any())
    heading = [
        (f"Certified result: relative expanded uncertainty U (%), k = {k:g}"
         + ("; low…high: the Monte Carlo 95 % coverage interval of the error (%)" if intervals else ""),
         FONT + 1.5, {"weight": "bold"}),
        (textwrap.fill(headline_text(budget), 105), FONT + 0.5, {"weight": "bold"}),
    ]
    extent = extent_text(budget, g)
    if extent:
        heading.append((textwrap.fill(extent, 118), FONT, {}))
    mf = " It includes the simulation's model form (contributor model_form, on its own page)." if (
        model_form_grid(budget) is not None) else ""
    heading.append((textwrap.fill(MEASURAND + mf, 125), FONT - 0.5, {}))
    heading.append((f"Per height and wind-speed bin (bin centre){tol}; – : bin not certified (too few "
                    "periods, not settled or no data).", FONT - 0.5, {"color": "0.3"}))
    tables = [_Table(heading, g, rows, _relative_cell(g, True), "Certified result (continued)")]
    if "expanded_uncertainty" in budget and rows.size:
        absolute = budget["expanded_uncertainty"].transpose("wind_speed", "height").values
        units = budget["expanded_uncertainty"].attrs.get("units", "m s-1")

        def cell(i: int, j: int) -> tuple[str, bool]:
            ok = bool(g["certified"][i, j])
            return (f"{absolute[i, j]:.3f}" if ok and np.isfinite(absolute[i, j]) else "–"), ok

        tables.append(_Table(
            [(f"Certified result in m/s: expanded uncertainty U (m/s), k = {k:g}", FONT + 1.5,
              {"weight": "bold"}),
             (f"The same bins: U of the lidar's horizontal wind speed ({units}); – : bin not certified.",
              FONT - 0.5, {"color": "0.3"})],
            g, rows, cell, "Certified result in m/s (continued)"))
    return tables


def _page_one(pages: _Pages, cert: xr.Dataset, budget: xr.Dataset | None, seal: str | None = None) -> None:
    fig = pages.new()
    attrs = cert.attrs
    status = stated(attrs, "calibration_status")
    _title(fig, "Calibration certificate: pulsed Doppler wind lidar", stated(attrs, "title"))
    reason = read_attr(attrs, "calibration_status_reason", kind="certificate")
    banner = {
        "demonstration": (
            "DEMONSTRATION: not a calibration of a real instrument"
            + ("" if reason else " (made from simulated or sample data)"),
            "#b22222",
        ),
        "issued": ("ISSUED calibration certificate", "#1a6b1a"),
    }.get(status, (f"Calibration status: {status}", "#8a5a00"))
    text = textwrap.fill(banner[0], 95)
    fig.text(0.07, 0.915, text, fontsize=FONT + 2, weight="bold", color=banner[1], va="top")
    shift = 0.016 * text.count("\n")  # a long reason takes more lines: the columns start lower
    # the status block (status, id, date of issue) across the page, the other sections in two columns
    blocks: list[list[tuple[str, str, dict]]] = [[], [], []]
    facts = certificate_facts(attrs, seal)
    for n, (section, items) in enumerate(facts):
        rows = blocks[0 if n == 0 else 1 if n <= len(facts) // 2 else 2]
        rows.append((section, "", {"section": True}))
        for label, value in items:
            style = {"color": "#b22222", "weight": "bold"} if label == "Calibration status" else {}
            if value == NOT_STATED:
                style = {"color": "0.5"}
            rows.append((label, value, style))
    y = _columns(fig, 0.9 - shift, blocks)
    if budget is None:
        fig.text(0.07, y - 0.02, "This certificate carries no uncertainty budget.", fontsize=FONT + 1,
                 va="top")
        return
    y -= 0.012
    for table in _result_tables(budget):
        fig, y = _flow_table(pages, fig, y, table)
        y -= 0.015


def _all_bins_pages(pages: _Pages, budget: xr.Dataset) -> None:
    k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
    fig = pages.new()
    _title(
        fig,
        f"Every bin of the budget: U (%), k = {k:g}",
        "Grey: not certified (t: too few periods; o: outside the certified range; n: not settled); "
        "– : no data. Black: certified (page 1 says what each certifies).",
    )
    g = certified_grid(budget)
    continued = "Every bin of the budget (continued)"
    table = _Table([], g, np.arange(g["wind_speed"].size), _relative_cell(g, False), continued)
    fig, y = _flow_table(pages, fig, _TOP, table)
    missed = not_settled_text(budget)
    if missed:  # listed apart from the certified result, with their tolerances (JCGM 101 7.9)
        _text_rows(pages, fig, y - 0.004, [("Not settled", missed, {"color": "#8a5a00"})],
                   continued=continued, x1=0.2, width=110)


def _model_form_pages(pages: _Pages, budget: xr.Dataset) -> None:
    """Lay out the model-form contributor per certified bin, its standard error and its shifts."""
    g = model_form_grid(budget)
    fig = pages.new()
    _title(fig, "Model form of the simulation: contributor model_form (%, k = 1)",
           "Per height and certified wind-speed bin: the standard uncertainty ± its standard error "
           "(subsample of periods); – : bin not certified.")
    continued = "Model form of the simulation (continued)"
    text = textwrap.fill(model_form_summary(budget) or "", 120)
    fig.text(0.07, _TOP, text, fontsize=FONT, va="top")
    y = _TOP - (text.count("\n") + 1) * _line(FONT, 1.3) - 0.01
    if "model_form_shift" in budget:  # the largest shift of U each alternative makes, per height
        ok = xr.DataArray(g["certified"], dims=("wind_speed", "height"))
        shift = budget["model_form_shift"].where(ok)
        rows: list[tuple[str, str, dict]] = [("Largest shift of U under each alternative (percentage points)",
                                              "", {"section": True})]
        for alt in shift["model_form_alternative"].values:
            s = shift.sel(model_form_alternative=alt).transpose("height", "wind_speed").values
            worst = [s[i][np.nanargmax(np.abs(s[i]))] if np.isfinite(s[i]).any() else np.nan
                     for i in range(s.shape[0])]
            cells = [f"{fmt(z)} m: {w:+.2f}" if np.isfinite(w) else f"{fmt(z)} m: –"
                     for z, w in zip(budget["height"].values, worst, strict=True)]
            rows.append((str(alt), "   ".join(cells), {}))
        fig, y = _text_rows(pages, fig, y, rows, continued=continued, x1=0.26, width=88)
        y -= 0.01
    _flow_table(pages, fig, y, _Table([], g, certified_rows(g), _relative_cell(g, True), continued))


def _provenance_pages(pages: _Pages, cert: xr.Dataset) -> None:
    fig = pages.new()
    _title(
        fig,
        "Inputs and provenance",
        "Each input file of the certificate with its SHA-256; the full chain, "
        "configuration and seeds are in the certificate's lidarcal_* attributes.",
    )
    rows: list[tuple[str, str, dict]] = [("Inputs", "", {"section": True})]
    for item in read_attr(cert, "lidarcal_provenance_chain", kind="certificate") or []:
        rows.append((f"{item.get('role')}",
                     f"{item.get('file')} ({item.get('kind', '')}), SHA-256:\n{item.get('sha256')}", {}))
    rows.append(("Certificate", "", {"section": True}))
    for key in ("certificate_components", "lidarcal_version", "date_created", "history"):
        if key in cert.attrs:
            rows.append((key, str(cert.attrs[key]), {}))
    _text_rows(pages, fig, 0.9, rows, continued="Inputs and provenance (continued)", x1=0.4, width=85)


def _windows_1252(fig) -> bool:
    """Return whether every text on ``fig`` can be written in the standard PDF fonts' encoding.

    The texts are the figure's, its legends', and each axes' titles, labels and texts; tick
    labels are numbers, written in ASCII (:data:`~lidarcal.certificate.document.figures.STYLE`).  (Asking
    matplotlib for every Text artist would create each axis's ticks once more.)
    """
    texts = [t.get_text() for t in fig.texts]
    for ax in fig.axes:
        texts += [ax.get_title(loc) for loc in ("left", "center", "right")]
        texts += [ax.get_xlabel(), ax.get_ylabel(), *(t.get_text() for t in ax.texts)]
    for legend in [*fig.legends, *(ax.get_legend() for ax in fig.axes)]:
        if legend is not None:
            texts += [legend.get_title().get_text(), *(t.get_text() for t in legend.get_texts())]
    try:
        "".join(texts).encode("cp1252")
    except UnicodeEncodeError:
        return False
    return True


@gc_paused()
def write_document(
    path: str | os.PathLike,
    cert: xr.Dataset,
    *,
    overwrite: bool = False,
    parts: Mapping[str, Any] | None = None,
    seal: str | None = None,
    allow_invalid: bool = False,
    check: VerificationReport | None = None,
) -> dict[str, Any]:
    """Write the certificate document ``path`` (A4 PDF) of certificate ``cert``.

    ``parts`` (from :func:`parts_of`) saves extracting the components again; ``seal``
    (:func:`seal_statement`) states the seal of a certificate written after its document.

    A certificate read from a file has its seal checked first
    (:func:`lidarcal.certificate.seal.require_valid_seal`; a certificate being built, never sealed and read
    from no file, has none): an altered one is refused with nothing written, or with
    ``allow_invalid`` written with the warning that its numbers are not certified in red on
    page 1 and in every page's footer.  ``check``: the caller's own result of that check (the
    HTML report's), not repeated.

    Returns
    -------
    dict
        ``{"pdf": Path, "pages": int}``.

    Raises
    ------
    SealError
        The certificate's seal does not match its contents (unless ``allow_invalid``).
    """
    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages

    if check is None:
        check = require_valid_seal(cert, allow_invalid=allow_invalid)
    warning = invalid_seal_banner(check) if check is not None and not check.ok else None
    path = Path(path)
    check_writable(path, overwrite=overwrite)
    parts = parts_of(cert) if parts is None else parts
    budget = parts.get("budget")
    pages = _Pages()

    with matplotlib.rc_context(STYLE):
        _page_one(pages, cert, budget, seal)
        if warning:  # over the title block, in red: the numbers below are not certified
            pages.figs[0].text(0.07, 0.99, textwrap.fill(warning, 110), fontsize=FONT, color="#b22222",
                               weight="bold", va="top")
        for name in figure_names(parts):
            draw(pages.new(), name, parts)
        if budget is not None:
            _all_bins_pages(pages, budget)
            if model_form_grid(budget) is not None:
                _model_form_pages(pages, budget)
        _provenance_pages(pages, cert)
        cid, status = certificate_id(cert.attrs), stated(cert.attrs, "calibration_status")
        n = len(pages.figs)
        for i, fig in enumerate(pages.figs, 1):
            fig.add_artist(_rule(FOOTER_RULE))
            invalid = " · INVALID SEAL: these numbers are NOT certified" if warning else ""
            fig.text(0.07, FOOTER_RULE - 0.01, f"Certificate {cid} · status: {status}{invalid}",
                     fontsize=FONT - 1, va="top", color="#b22222" if warning else "black")
            fig.text(0.95, FOOTER_RULE - 0.01, f"page {i} of {n}", fontsize=FONT - 1, va="top", ha="right")
        # the standard fonts' weights are named 'medium': matplotlib warns for every 'normal' text
        fonts = logging.getLogger("matplotlib.font_manager")
        level = fonts.level
        fonts.setLevel(logging.ERROR)
        try:
            with atomic_path(path, overwrite=overwrite) as tmp:
                with PdfPages(tmp, metadata={"Title": f"Calibration certificate {cid}", "Creator": "lidarcal",
                                             "Subject": f"status: {status}"}) as pdf:
                    for fig in pages.figs:
                        with matplotlib.rc_context({"pdf.use14corefonts": _windows_1252(fig)}):
                            pdf.savefig(fig)
        finally:
            fonts.setLevel(level)
    return {"pdf": path, "pages": len(pages.figs)}
