"""The offline HTML report of a calibration, and beside it the certificate document and PNGs.

The page embeds BokehJS inline (:mod:`lidarcal.htmlpage`), so it opens without network access.
It opens with the calibration status, the headline sentence and the certified result (per
height and wind-speed bin, U for k = 2), then the certificate's administrative data, the
figures (:mod:`lidarcal.certificate.report.plots`), and last the inputs with their SHA-256.  Beside the
page, :func:`write_report` writes the certificate document (:mod:`lidarcal.certificate.document`,
``<stem>.pdf``) and, on request, a PNG of each of its figures.
"""

from __future__ import annotations

import contextlib
import html
import os
from collections.abc import Iterable, Iterator, Mapping
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
)
from lidarcal.certificate.document.figure_data import drawn_cnr_range
from lidarcal.certificate.document.figures import A4, STYLE, draw, figure_names, parts_of
from lidarcal.certificate.document.pages import gc_paused, write_document
from lidarcal.certificate.measurand import MEASURAND, model_form_summary
from lidarcal.certificate.report.plots import report_figures
from lidarcal.certificate.results import headline_text
from lidarcal.certificate.seal import invalid_seal_banner, require_valid_seal
from lidarcal.htmlpage import html_table, offline_html, write_text
from lidarcal.io import atomic_path, check_writable
from lidarcal.readback import read_attr

__all__ = ["write_report"]

_PNG_DPI = 150  # static figures: at least 150 dpi, written into the PNG's pHYs chunk


def _header(cert: xr.Dataset | None, budget: xr.Dataset | None, seal: str | None = None) -> str:
    """Return the top of the page: status, headline, certified result, then the certificate's facts."""
    out = []
    if cert is not None:
        status = read_attr(cert, "calibration_status", kind="certificate", default=NOT_STATED)
        cid = html.escape(certificate_id(cert.attrs))
        out.append(f'<p class="status status-{html.escape(str(status))}"><strong>Calibration status: '
                   f"{html.escape(str(status))}</strong> · certificate {cid}</p>")
    if budget is not None:
        out.append(f'<p class="headline"><strong>{html.escape(headline_text(budget))}</strong></p>')
        g = certified_grid(budget)
        extent = extent_text(budget, g)
        if extent:
            out.append(f"<p>{html.escape(extent)}</p>")
        rows = []
        for i in certified_rows(g):
            cells = [grid_cell(g, i, j) if g["certified"][i, j] else "–" for j in range(g["height"].size)]
            rows.append([fmt(g["wind_speed"][i]), *cells])
        k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
        intervals = g["statement"] is not None and bool((g["certified"] & (g["statement"] == 1)).any())
        header = ["wind speed bin (m/s)", *[f"{fmt(h)} m" for h in g["height"]]]
        out.append(html_table(header, rows,
                          f"Certified result: relative expanded uncertainty U (%), k = {k:g}, per height and "
                          "wind-speed bin"
                          + ("; low…high: the Monte Carlo 95 % coverage interval of the error (%), certified "
                             "where it differs materially from ±U" if intervals else "")
                          + "; – : not certified (too few periods, not settled, or no data)"))
        if "expanded_uncertainty" in budget:
            absolute = budget["expanded_uncertainty"].transpose("wind_speed", "height").values
            out.append(html_table(header, [[fmt(g["wind_speed"][i]), *[
                f"{absolute[i, j]:.3f}" if g["certified"][i, j] and np.isfinite(absolute[i, j]) else "–"
                for j in range(g["height"].size)]] for i in certified_rows(g)],
                f"Certified result in m/s: expanded uncertainty U (m/s), k = {k:g}, the same bins"))
        if missed := not_settled_text(budget):
            out.append(f'<p class="not-settled">{html.escape(missed)}</p>')
        out.append(f'<p class="measurand">{html.escape(MEASURAND)}</p>')
        out.append(_model_form_table(budget))
    if cert is not None:
        facts = "\n".join(
            f"<tr><th>{html.escape(section if n == 0 else '')}</th><td>{html.escape(label)}</td>"
            f"<td>{html.escape(value).replace(chr(10), '<br>')}</td></tr>"
            for section, items in certificate_facts(cert.attrs, seal)
            for n, (label, value) in enumerate(items))
        out.append(f'<table class="facts">\n{facts}\n</table>')
    return "\n".join(out)


def _model_form_table(budget: xr.Dataset) -> str:
    """Return the model-form contributor per certified bin (%, k = 1, ± standard error) as HTML."""
    g = model_form_grid(budget)
    if g is None:
        return ""
    rows = []
    for i in np.flatnonzero(g["inside"]):
        cells = []
        for j in range(g["height"].size):
            v, se = g["value"][i, j], g["tolerance"][i, j]
            ok = g["certified"][i, j] and np.isfinite(v)
            cells.append((f"{v:.2f}" + (f" ± {se:.2g}" if np.isfinite(se) else "")) if ok else "–")
        rows.append([fmt(g["wind_speed"][i]), *cells])
    return (f'<p class="model-form">{html.escape(model_form_summary(budget) or "")}</p>\n'
            + html_table(["wind speed bin (m/s)", *[f"{fmt(h)} m" for h in g["height"]]], rows,
                         "Model form of the simulation: contributor model_form (%, k = 1) ± its standard "
                         "error, per height and certified wind-speed bin; – : not certified"))


def _provenance(cert: xr.Dataset | None) -> str:
    """Return the end of the page: the certificate's components and inputs with their SHA-256."""
    if cert is None:
        return ""
    rows = []
    for key, label in (("title", "Title"), ("id", "Id"), ("date_created", "Created"),
                       ("lidarcal_version", "lidarcal version"), ("certificate_components", "Components"),
                       ("zero_distance_m", "Zero distance Zd (m)")):
        if key in cert.attrs:
            rows.append((label, fmt(cert.attrs[key]) if key.endswith("_m") else str(cert.attrs[key])))
    for item in read_attr(cert, "lidarcal_provenance_chain", kind="certificate") or []:
        rows.append((f"Input: {item.get('role')}", f"{item.get('file')}  sha256 {item.get('sha256')}"))
    body = "\n".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows)
    return f'<div id="provenance"><h2>Inputs and provenance</h2>\n<table>\n{body}\n</table></div>'


@contextlib.contextmanager
def _all_or_nothing(published: list[Path]) -> Iterator[None]:
    """On a failure inside, remove the files of this report already published, then re-raise."""
    try:
        yield
    except BaseException:
        for done in published:
            done.unlink(missing_ok=True)
        raise


@gc_paused()
def write_report(
    path: str | os.PathLike,
    *,
    certificate: xr.Dataset | None = None,
    budget: xr.Dataset | None = None,
    sensitivities: Iterable[xr.Dataset] | Mapping[str, xr.Dataset] = (),
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
    title: str | None = None,
    png: bool = False,
    pdf: bool = True,
    overwrite: bool = False,
    allow_invalid: bool = False,
    seal: str | None = None,
) -> dict[str, Any]:
    """Write the offline HTML report, and beside it the certificate document (PDF) and PNGs.

    With ``certificate`` the components are taken from it; explicit arguments override them.
    The page opens with the status, the headline and the certified result; the inputs'
    SHA-256 come last.  With ``certificate`` and ``pdf`` the certificate document
    (:func:`lidarcal.certificate.document.write_document`) is written to ``<stem>.pdf``; ``seal``
    (:func:`lidarcal.certificate.document.seal_statement`) states the seal of a certificate written after
    its report.  With ``png`` every figure of the document is also written as
    ``<stem>_<figure>.png`` (150 dpi).  The files are published whole or not at all: when one
    cannot be written (a full disk), those this call had published are removed again.

    A certificate read from a file has its seal checked first
    (:func:`lidarcal.certificate.seal.require_valid_seal`): an altered one is refused
    (:class:`~lidarcal.errors.SealError`), or with ``allow_invalid`` reported under a
    warning banner (on the page and on every page of the document).

    Returns
    -------
    dict
        ``{"html": Path, "figures": [names], "png": [Paths], "pdf": Path or None}``.
    """
    check = require_valid_seal(certificate, allow_invalid=allow_invalid) if certificate is not None else None
    banner = invalid_seal_banner(check) if check is not None and not check.ok else None
    parts: dict[str, Any] = parts_of(certificate) if certificate is not None else {"sensitivities": []}
    for name, value in (("budget", budget), ("cube", cube), ("rwf", rwf)):
        if value is not None:
            parts[name] = value
    sens = list(sensitivities.values()) if isinstance(sensitivities, Mapping) else list(sensitivities)
    if sens:
        parts["sensitivities"] = sens
    summary = (read_attr(certificate, "lidarcal_records_summary", kind="certificate")
               if certificate is not None else None)
    if summary and parts.get("cube") is not None:
        parts["drawn_cnr"] = drawn_cnr_range(parts["cube"], summary)
    figs = report_figures(**parts)
    path = Path(path)
    pdf_path = path.with_suffix(".pdf") if pdf and certificate is not None else None
    pngs = {name: path.with_name(f"{path.stem}_{name}.png") for name in figure_names(parts)} if png else {}
    for p in [path, *([pdf_path] if pdf_path else []), *pngs.values()]:
        check_writable(p, overwrite=overwrite)

    title = title or (
        certificate.attrs.get("title") if certificate is not None else "lidarcal calibration report"
    )
    models = {name: fig.bokeh() for name, fig in figs.items()}
    after = {name: fig.note for name, fig in figs.items()}
    warning = f'<p class="invalid"><strong>{html.escape(banner)}</strong></p>\n' if banner else ""
    page = offline_html(models, title=title, header=warning + _header(certificate, parts.get("budget"), seal),
                        after=after, titles={name: fig.heading for name, fig in figs.items()},
                        footer=_provenance(certificate))
    written = []
    if pngs:
        import matplotlib
        from matplotlib.figure import Figure as MplFigure

        with matplotlib.rc_context(STYLE):
            for name, target in pngs.items():
                fig = MplFigure(figsize=A4)
                draw(fig, name, parts)
                with _all_or_nothing(written), atomic_path(target, overwrite=overwrite) as tmp:
                    fig.savefig(tmp, dpi=_PNG_DPI, format="png")
                written.append(target)
    document = None
    if pdf_path:
        with _all_or_nothing(written):
            document = write_document(pdf_path, certificate, overwrite=overwrite, parts=parts, seal=seal,
                                      allow_invalid=allow_invalid, check=check)
        written.append(pdf_path)
    with _all_or_nothing(written):
        write_text(path, page, overwrite=overwrite)
    return {"html": path, "figures": list(figs), "png": [p for p in written if p != pdf_path],
            "pdf": document["pdf"] if document else None,
            "pages": document["pages"] if document else 0}
