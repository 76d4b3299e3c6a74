"""Offline HTML pages: plain bokeh figures on one self-contained page, written atomically.

The one HTML plotting API of lidarcal: every interactive page (the calibration report
:mod:`lidarcal.certificate.report`, the diagnosis :mod:`lidarcal.diagnose.report` and the comparison
:mod:`lidarcal.compare.report`) draws plain bokeh models with :func:`plot`,
:func:`legend_outside` and :func:`grid`, and writes them with :func:`offline_html`.  Plain
bokeh, not holoviews/hvplot: importing and rendering through holoviews costs about a second of
CPU per page before anything is drawn (``docs/performance.md``); ``.hvplot`` stays for users
exploring an artefact themselves (``docs/analyst.md``).
"""

from __future__ import annotations

import html
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from lidarcal.errors import InputError
from lidarcal.io import atomic_path

__all__ = ["COLORS", "plot", "legend_outside", "grid", "offline_html", "html_table", "write_text",
           "check_models"]

#: The categorical colours of every page (bokeh's and matplotlib's Category10).
COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
          "#17becf", "#000000"]
_TOOLS = "pan,box_zoom,wheel_zoom,reset,save"


def plot(title: str, xlabel: str, ylabel: str, *, width: int = 900, height: int = 380,
         tools: str = _TOOLS, **kw: Any) -> Any:
    """Return a bokeh figure with the pages' tools (pan, box and wheel zoom, reset, save) on the right.

    ``kw`` goes to :func:`bokeh.plotting.figure` (``x_range``, ``y_range`` ...).
    """
    from bokeh.plotting import figure

    p = figure(title=title, width=width, height=height, x_axis_label=xlabel, y_axis_label=ylabel,
               tools=tools, toolbar_location="right", **kw)
    p.title.text_font_size = "12pt"
    return p


def legend_outside(p: Any, click_policy: str = "hide", location: str = "right") -> None:
    """Give ``p``'s legend a click policy (``"hide"``, ``"mute"``, ``"none"``) and move it right of the plot.

    ``location`` other than ``"right"`` (``"top_right"``) keeps it inside the plot, there.  The
    plot's own legend is moved, not hidden beside a copy: a hidden legend is one more model to
    build and write into the page.  A plot whose menu hides renderers takes ``"none"``: BokehJS
    greys an item that has a hidden renderer.
    """
    if p.legend:
        legend = p.legend[0]
        legend.click_policy = click_policy
        legend.label_text_font_size = "9pt"
        if location == "right":
            p.center.remove(legend)
            p.add_layout(legend, "right")
        else:
            legend.location = location


def grid(plots: list, ncols: int = 2) -> Any:
    """Lay ``plots`` out ``ncols`` to a row, with one toolbar for all of them (above)."""
    from bokeh.layouts import gridplot

    return gridplot(plots, ncols=ncols, toolbar_location="above")


def html_table(header: list[str], rows: list[list[str]], caption: str) -> str:
    """Return a ``<table class="numbers">`` of text ``rows`` under ``header``, with its caption (escaped)."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "\n".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return (f'<table class="numbers"><caption>{html.escape(caption)}</caption>'
            f"<tr>{head}</tr>\n{body}</table>")


def offline_html(models: Mapping[str, Any], *, title: str, header: str = "",
                 after: Mapping[str, str] | None = None, headings: bool = True,
                 titles: Mapping[str, str] | None = None, footer: str = "") -> str:
    """One self-contained HTML page of bokeh ``models``: BokehJS inline, nothing from the network.

    Each model gets a ``<section>`` (with an ``<h2>`` of ``titles[name]``, default the name, if
    ``headings``, then
    ``after[name]`` if given) below the ``<h1>`` title and the ``header`` HTML.  Only the
    BokehJS bundles the models need are embedded.  In a session that imported hvplot (a user's
    notebook), panel adds URL-loaded files (its ES-module shims) to every bokeh Resources
    object; the plots here are plain bokeh models, so those URLs are dropped, and a model from
    outside bokeh (which would need them) is refused.  ``footer`` HTML goes after the sections.
    """
    from bokeh.embed import components as bokeh_components
    from bokeh.embed.bundle import Bundle, bundle_for_objs_and_resources
    from bokeh.resources import INLINE
    from bokeh.settings import settings

    models = dict(models)
    after = after or {}
    # one document holding every root, its model index built once: bokeh's components()
    # would otherwise add the roots one at a time, re-walking all models after each
    from bokeh.document import Document

    doc = Document()
    with doc.models.freeze():
        for model in models.values():
            doc.add_root(model)
    foreign = sorted({type(x).__module__ for x in doc.models if not type(x).__module__.startswith("bokeh.")})
    if foreign:
        raise InputError(f"report plots use non-bokeh models from {foreign}; cannot embed them offline")
    # bokeh's document checks (its E-/W- validation codes) are a fifth of the page's cost; the
    # report's figures are fixed code, checked once by the tests (lidarcal.htmlpage.check_models),
    # not at every run
    settings.perform_document_validation.set_value(False)
    try:
        script, divs = bokeh_components(list(models.values()))
    finally:
        settings.perform_document_validation.unset_value()
    bundle = bundle_for_objs_and_resources([doc], INLINE)
    resources = "".join(Bundle(js_raw=bundle.js_raw, css_raw=bundle.css_raw, hashes=bundle.hashes))
    sections = "\n".join(
        f'<section id="{html.escape(name)}">'
        + (f"<h2>{html.escape((titles or {}).get(name, name.replace('_', ' ')))}</h2>" if headings else "")
        + div + after.get(name, "") + "</section>"
        for name, div in zip(models, divs, strict=True)
    )
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{html.escape(title)}</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 72em; }}
table {{ border-collapse: collapse; margin-bottom: 2em; }}
th, td {{ text-align: left; padding: 0.2em 1em 0.2em 0; vertical-align: top; font-size: 0.9em; }}
section {{ margin-bottom: 2em; }}
table.numbers td {{ text-align: right; }}
table.numbers caption {{ text-align: left; font-size: 0.9em; padding-bottom: 0.3em; }}
</style>
{resources}
{script}
</head>
<body>
<h1>{html.escape(title)}</h1>
{header}
{sections}
{footer}
<footer><p>Generated by lidarcal; self-contained (BokehJS inline, no network needed).</p></footer>
</body>
</html>
"""


def check_models(models: Mapping[str, Any]) -> list[str]:
    """Return bokeh's validation errors and warnings for ``models`` (what :func:`offline_html` skips)."""
    from bokeh.core.validation import check_integrity
    from bokeh.document import Document

    doc = Document()
    for model in models.values():
        doc.add_root(model)
    issues = check_integrity(list(doc.models))
    return [f"{i.code} {i.name}: {i.text}" for i in [*issues.error, *issues.warning]]


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; refuses an existing file unless ``overwrite``."""
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
