"""Offline HTML report of a ``diagnosis`` artefact (plain bokeh, :mod:`lidarcal.htmlpage`; BokehJS inline).

Plots: the gap per height before and after the correction; for every environmental variable
the binned residual before and after; the Eq. 12 sensitivity statistic m·std of the measured
records against the nominal and the corrected simulations (paper Figure 8 style); the
candidate scores.  The page embeds bokeh's JavaScript, so it opens without network access.
"""

from __future__ import annotations

import html
import os
from pathlib import Path

import numpy as np
import xarray as xr

from lidarcal.htmlpage import COLORS, grid, legend_outside, offline_html, plot, write_text
from lidarcal.readback import read_attr

__all__ = ["write_report", "report_layout"]


def _header(ds: xr.Dataset) -> str:
    js = read_attr(ds, "diagnosis_json", kind="diagnosis")
    rows = "".join(
        f"<tr><td>{html.escape(c['effect'])}</td><td>{c['score']:.1f}</td></tr>"
        for c in js["candidates"] if c["score"] is not None)
    def params(e):
        unc, units, ivl = e["uncertainties"], e["units"], e.get("intervals", {})
        return ", ".join(
            f"{k} = {v:.4g} ± {unc.get(k) or float('nan'):.2g} {units.get(k, '')}"
            + (f" (95 %: {ivl[k][0]:.4g} to {ivl[k][1]:.4g})" if k in ivl and None not in ivl[k] else "")
            for k, v in e["parameters"].items() if v is not None)
    effects = "<br>".join(f"{html.escape(e['effect'])}: {html.escape(params(e))}"
                          + (f" (tied with {html.escape(', '.join(e['tied']))})" if e["tied"] else "")
                          for e in js["effects"]) or "—"
    drivers = "; ".join(f"{d['variable']} {d['range'][0]:.4g} to {d['range'][1]:.4g} {d['units']} "
                        f"(z {d['z']:+.1f})" for d in js["drivers"] if None not in d["range"]) or "—"
    return (
        f"<h2>lidarcal diagnose: {html.escape(js['effect'])}</h2>"
        f"<p><b>Effects:</b> {effects}<br>"
        f"<b>Where the residual lies:</b> {html.escape(drivers)}"
        f"<br><b>Gap:</b> {js['gap_before']:.3f} % → {js['gap_after']:.3f} % "
        f"(noise floor {js['gap_noise_floor']:.3f} %, tolerance {js['tolerance']:g} %)"
        f"<br><b>Note:</b> {html.escape(js['note'])}"
        f"<br><small>gap metric: {html.escape(js['gap_metric'])}</small></p>"
        f"<table><tr><th>candidate</th><th>score (ΔBIC vs none)</th></tr>{rows}</table>"
    )


def _lines(p, groups: list[tuple[str, np.ndarray, np.ndarray]], x: str, y: str, by: str, *,
           points: bool = False) -> None:
    """Draw one line (and its points) per group ``(label, x, y)``, legend by label, hover naming all three."""
    from bokeh.models import ColumnDataSource, HoverTool

    renderers = []
    for i, (label, xs, ys) in enumerate(groups):
        src = ColumnDataSource({x: xs, y: ys, by: [label] * len(xs)})
        color = COLORS[i % len(COLORS)]
        renderers.append(p.line(x, y, source=src, color=color, line_width=2, legend_label=label))
        if points:
            renderers.append(p.scatter(x, y, source=src, color=color, size=6, legend_label=label))
    p.add_tools(HoverTool(renderers=renderers, tooltips=[(by, f"@{{{by}}}"), (x, f"@{{{x}}}"),
                                                         (y, f"@{{{y}}}")]))
    legend_outside(p, "mute")


def report_layout(ds: xr.Dataset):
    """Build the report's plots (plain bokeh), two to a row: gap, binned residuals, sensitivities, scores."""
    from bokeh.models import ColumnDataSource, HoverTool

    size = {"width": 450, "height": 300}
    plots = []
    h = ds.height.values
    p = plot("Gap per height (%)", "height (m)", "gap (%)", **size)
    _lines(p, [(when, h, ds[f"gap_{when}"].values) for when in ("before", "after")], "height", "gap", "model",
           points=True)
    plots.append(p)
    for var in map(str, ds.variable.values):
        centre = ds[f"{var}_bin_mean"]
        groups = []
        for when in ("before", "after"):
            r = ds[f"binned_residual_{when}"].sel(variable=var)
            for z in h:
                xs, ys = centre.sel(height=z).values, r.sel(height=z).values
                ok = np.isfinite(xs) & np.isfinite(ys)  # the bins with a residual, joined by the line
                groups.append((f"{when}, {z:g} m", xs[ok], ys[ok]))
        p = plot(f"Binned residual vs {var} (%)", f"{var} ({centre.attrs['units']})", "field − model (%)",
                 **size)
        _lines(p, groups, var, "residual", "series")
        plots.append(p)
    if "sensitivity_measured" in ds:
        for var in map(str, ds.variable.values):
            p = plot(f"Sensitivity m·std to {var} (%)", "height (m)", "m·std (%)", **size)
            _lines(p, [(label, h, ds[f"sensitivity_{k}"].sel(variable=var).values)
                       for k, label in (("measured", "measured"), ("before", "simulated, nominal"),
                                        ("after", "simulated, corrected"))], "height", "m_std", "source")
            plots.append(p)
    names = [str(c) for c in ds.candidate.values]
    p = plot("Candidate score (ΔBIC vs none; lower is better)", "candidate", "score", x_range=names, **size)
    bars = p.vbar(x="candidate", top="score", width=0.8, source=ColumnDataSource(
        {"candidate": names, "score": np.asarray(ds.candidate_score.values, float)}))
    p.add_tools(HoverTool(renderers=[bars], tooltips=[("candidate", "@{candidate}"), ("score", "@{score}")]))
    p.xaxis.major_label_orientation = np.deg2rad(30)
    p.xgrid.visible = False
    plots.append(p)
    return grid(plots, ncols=2)


def write_report(ds: xr.Dataset, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write the self-contained HTML report atomically (:func:`lidarcal.htmlpage.offline_html`)."""
    model = report_layout(ds)
    title = f"lidarcal diagnosis: {ds.attrs.get('diagnosis_effect', '')}"
    page = offline_html({"diagnosis": model}, title=title, header=_header(ds), headings=False)
    return write_text(path, page, overwrite=overwrite)
