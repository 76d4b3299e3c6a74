"""The certificate document: a paginated A4 PDF of a calibration certificate (matplotlib only).

:func:`write_document` writes ``report.pdf``: page 1 is the certificate itself (status,
certificate id, issuer, customer, calibrated item, dates and place, method, traceability of
the bench, signature status and the certified result: per height and wind-speed bin the
relative expanded uncertainty for k = 2, with its numerical tolerance where the budget has
one, under the headline sentence).  The following pages hold the figures
(:mod:`lidarcal.document.figures`), every bin of the budget, and the inputs with their SHA-256.
Every page carries the certificate id, the status and "page x of y" in its footer.  What the
pages say comes from :mod:`lidarcal.document.facts`; this module lays it out.
"""

from __future__ import annotations

import json
import os
import textwrap
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate import MEASURAND, model_form_summary
from lidarcal.document.facts import (
    NOT_STATED,
    certificate_facts,
    certificate_id,
    certified_grid,
    fmt,
    grid_cell,
    headline_text,
    model_form_grid,
    not_settled_text,
    stated,
)
from lidarcal.document.figures import A4, FONT, STYLE, draw, figure_names, parts_of
from lidarcal.io import atomic_path, check_writable

__all__ = ["write_document"]


def _text_page(
    fig, y: float, lines: list[tuple[str, str, dict]], *, x0: float = 0.07, x1: float = 0.33, width: int = 80
) -> float:
    """Write (label, value, style) rows from ``y`` (figure fraction) down; return the next free y."""
    line = FONT * 1.45 / 72 / A4[1]
    for label, value, style in lines:
        if style.get("section"):
            y -= 0.4 * line
            fig.text(x0, y, label, fontsize=FONT + 1.5, weight="bold", va="top")
            y -= 1.25 * line
            continue
        wrapped = [
            w
            for part in str(value).split("\n")
            for w in (textwrap.wrap(part, width, break_on_hyphens=False) or [""])
        ]
        fig.text(x0 + 0.015, y, label, fontsize=FONT, va="top", color="0.25")
        fig.text(
            x1,
            y,
            "\n".join(wrapped),
            fontsize=FONT,
            va="top",
            linespacing=1.3,
            color=style.get("color", "black"),
            weight=style.get("weight", "normal"),
        )
        y -= line * len(wrapped)
    return y


def _grid_table(
    fig, y: float, g: dict[str, Any], rows: np.ndarray, *, only_certified: bool, bottom: float = 0.05
) -> float:
    """Write a wind speed × height table of U (k = 2, %) from ``y`` down; returns the next free y.

    The font shrinks (to 5.5 pt at least) when the rows would not fit above ``bottom``.
    """
    heights, ws = g["height"], g["wind_speed"]
    x0, first, x1 = 0.07, 0.19, 0.95
    cols = np.linspace(first, x1, len(heights) + 1)[1:]
    size = FONT - 0.5 if g["tolerance"] is not None else FONT
    fits = (y - bottom) / (len(rows) + 2.8) * 72 * A4[1] / 1.4  # the font size whose rows fit
    size = max(5.5, min(size, fits))
    line = size * 1.4 / 72 / A4[1]
    fig.text(x0, y, "wind speed\nbin (m/s)", fontsize=size, va="top", weight="bold", linespacing=1.1)
    for c, h in zip(cols, heights, strict=True):
        fig.text(c, y, f"{fmt(h)} m", fontsize=size, va="top", ha="right", weight="bold")
    y -= 2.3 * line
    fig.add_artist(_rule(y + 0.4 * line))
    # one text per column and colour (not per cell): hundreds of text artists are what costs
    rows = list(rows)
    style = dict(fontsize=size, va="top", linespacing=1.4)
    fig.text(x0 + 0.02, y, "\n".join(fmt(ws[i]) for i in rows), **style)
    for j, c in enumerate(cols):
        black, grey = [], []
        for i in rows:
            v, ok = g["value"][i, j], g["certified"][i, j]
            if only_certified:
                text = grid_cell(g, i, j) if ok else "–"
            else:
                g_all = {**g, "statement": None}  # every bin's U (k = 2), the IEC-style value
                text = grid_cell(g_all, i, j)
                if not ok and np.isfinite(v):
                    text += " n" if g["not_settled"][i, j] else " t" if int(g["flag"][i, j]) == 1 else " o"
            (black if ok else grey).append(text)
            (grey if ok else black).append(" ")
        fig.text(c, y, "\n".join(black), ha="right", multialignment="right", color="black", **style)
        fig.text(c, y, "\n".join(grey), ha="right", multialignment="right", color="0.45", **style)
    return y - line * len(rows) - 0.5 * line


def _rule(y: float):
    from matplotlib.lines import Line2D

    return Line2D([0.07, 0.95], [y, y], lw=0.5, color="0.3")


def _title(fig, text: str, sub: str = "") -> None:
    fig.text(0.07, 0.965, text, fontsize=FONT + 6, weight="bold", va="top")
    if sub:
        fig.text(0.07, 0.94, sub, fontsize=FONT, va="top", color="0.3")


def _page_one(fig, cert: xr.Dataset, budget: xr.Dataset | None, seal: str | None = None) -> None:
    attrs = cert.attrs
    status = stated(attrs, "calibration_status")
    _title(fig, "Calibration certificate: pulsed Doppler wind lidar", stated(attrs, "title"))
    reason = attrs.get("calibration_status_reason")
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
    y = _text_page(fig, 0.9 - shift, blocks[0], x0=0.07, x1=0.22, width=100)
    y = min(
        _text_page(fig, y, blocks[1], x0=0.07, x1=0.22, width=44),
        _text_page(fig, y, blocks[2], x0=0.52, x1=0.67, width=40),
    )
    if budget is None:
        fig.text(
            0.07, y - 0.02, "This certificate carries no uncertainty budget.", fontsize=FONT + 1, va="top"
        )
        return
    k = float(budget.attrs.get("coverage_factor", 2.0))
    y -= 0.012
    g = certified_grid(budget)
    intervals = g["statement"] is not None and bool((g["certified"] & (g["statement"] == 1)).any())
    fig.text(
        0.07,
        y,
        f"Certified result: relative expanded uncertainty U (%), k = {k:g}"
        + ("; low…high: the Monte Carlo 95 % coverage interval of the error (%)" if intervals else ""),
        fontsize=FONT + 1.5,
        weight="bold",
        va="top",
    )
    y -= 0.018
    headline = textwrap.fill(headline_text(budget), 105)
    fig.text(0.07, y, headline, fontsize=FONT + 0.5, va="top", weight="bold")
    y -= (headline.count("\n") + 1) * (FONT + 0.5) * 1.25 / 72 / A4[1] + 0.006  # however many lines it takes
    tol = "; ± its numerical tolerance (Monte Carlo)" if g["tolerance"] is not None else ""
    mf = " It includes the simulation's model form (contributor model_form, on its own page)." if (
        model_form_grid(budget) is not None) else ""
    notes = textwrap.fill(MEASURAND + mf, 125)
    fig.text(0.07, y, notes, fontsize=FONT - 0.5, va="top")
    y -= (notes.count("\n") + 1) * (FONT - 0.5) * 1.25 / 72 / A4[1] + 0.006
    fig.text(
        0.07,
        y,
        f"Per height and wind-speed bin (bin centre){tol}; – : bin not certified (too few periods, "
        "not settled or no data).",
        fontsize=FONT - 0.5,
        va="top",
        color="0.3",
    )
    _grid_table(fig, y - 0.016, g, np.flatnonzero(g["inside"]), only_certified=True)


def _all_bins_page(fig, budget: xr.Dataset) -> None:
    k = float(budget.attrs.get("coverage_factor", 2.0))
    _title(
        fig,
        f"Every bin of the budget: U (%), k = {k:g}",
        "Grey: not certified (t: too few periods; o: outside the certified range; n: not settled); "
        "– : no data. Black: certified (page 1 says what each certifies).",
    )
    g = certified_grid(budget)
    missed = textwrap.fill(not_settled_text(budget), 125)
    lines = missed.count("\n") + 1 if missed else 0
    bottom = 0.05 + (lines + 0.8) * (FONT - 0.5) * 1.3 / 72 / A4[1] if missed else 0.05
    y = _grid_table(fig, 0.91, g, np.arange(g["wind_speed"].size), only_certified=False, bottom=bottom)
    if missed:  # listed apart from the certified result, with their tolerances (JCGM 101 7.9)
        fig.text(0.07, y - 0.004, missed, fontsize=FONT - 0.5, va="top", color="#8a5a00")


def _model_form_page(fig, budget: xr.Dataset) -> None:
    """Lay out the model-form contributor per certified bin, its standard error and its shifts."""
    g = model_form_grid(budget)
    _title(fig, "Model form of the simulation: contributor model_form (%, k = 1)",
           "Per height and certified wind-speed bin: the standard uncertainty ± its standard error "
           "(subsample of periods); – : bin not certified.")
    text = textwrap.fill(model_form_summary(budget) or "", 120)
    fig.text(0.07, 0.91, text, fontsize=FONT, va="top")
    y = 0.91 - (text.count("\n") + 1) * FONT * 1.3 / 72 / A4[1] - 0.01
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
        y = _text_page(fig, y, rows, x1=0.26, width=88) - 0.01
    _grid_table(fig, y, g, np.flatnonzero(g["inside"]), only_certified=True)


def _provenance_page(fig, cert: xr.Dataset) -> None:
    _title(
        fig,
        "Inputs and provenance",
        "Each input file of the certificate with its SHA-256; the full chain, "
        "configuration and seeds are in the certificate's lidarcal_* attributes.",
    )
    rows: list[tuple[str, str, dict]] = [("Inputs", "", {"section": True})]
    chain = cert.attrs.get("lidarcal_provenance_chain")
    for item in json.loads(chain) if chain else []:
        rows.append(
            (
                f"{item.get('role')}",
                f"{item.get('file')} ({item.get('kind', '')}), SHA-256:\n{item.get('sha256')}",
                {},
            )
        )
    rows.append(("Certificate", "", {"section": True}))
    for key in ("certificate_components", "lidarcal_version", "date_created", "history"):
        if key in cert.attrs:
            rows.append((key, str(cert.attrs[key]), {}))
    _text_page(fig, 0.9, rows, x1=0.4, width=85)


def write_document(
    path: str | os.PathLike,
    cert: xr.Dataset,
    *,
    overwrite: bool = False,
    parts: Mapping[str, Any] | None = None,
    seal: str | None = None,
    warning: str | None = None,
) -> dict[str, Any]:
    """Write the certificate document ``path`` (A4 PDF) of certificate ``cert``.

    ``parts`` (from :func:`parts_of`) saves extracting the components again; ``seal``
    (:func:`seal_statement`) states the seal of a certificate written after its document;
    ``warning`` (an invalid seal) is printed in red on page 1 and in every page's footer.

    Returns
    -------
    dict
        ``{"pdf": Path, "pages": int}``.
    """
    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    path = Path(path)
    check_writable(path, overwrite=overwrite)
    parts = parts_of(cert) if parts is None else parts
    budget = parts.get("budget")
    pages: list[Figure] = []

    def page() -> Figure:
        fig = Figure(figsize=A4)
        pages.append(fig)
        return fig

    with matplotlib.rc_context(STYLE):
        first = page()
        _page_one(first, cert, budget, seal)
        if warning:  # over the title block, in red: the numbers below are not certified
            first.text(
                0.07,
                0.99,
                textwrap.fill(warning, 110),
                fontsize=FONT,
                color="#b22222",
                weight="bold",
                va="top",
            )
        for name in figure_names(parts):
            fig = page()
            draw(fig, name, parts)
        if budget is not None:
            _all_bins_page(page(), budget)
            if model_form_grid(budget) is not None:
                _model_form_page(page(), budget)
        _provenance_page(page(), cert)
        cid, status = certificate_id(cert.attrs), stated(cert.attrs, "calibration_status")
        for i, fig in enumerate(pages, 1):
            fig.add_artist(_rule(0.035))
            invalid = " · INVALID SEAL: these numbers are NOT certified" if warning else ""
            fig.text(
                0.07,
                0.025,
                f"Certificate {cid} · status: {status}{invalid}",
                fontsize=FONT - 1,
                va="top",
                color="#b22222" if warning else "black",
            )
            fig.text(0.95, 0.025, f"page {i} of {len(pages)}", fontsize=FONT - 1, va="top", ha="right")
        with atomic_path(path, overwrite=overwrite) as tmp:
            with PdfPages(
                tmp,
                metadata={
                    "Title": f"Calibration certificate {cid}",
                    "Creator": "lidarcal",
                    "Subject": f"status: {status}",
                },
            ) as pdf:
                for fig in pages:
                    pdf.savefig(fig)
    return {"pdf": path, "pages": len(pages)}
