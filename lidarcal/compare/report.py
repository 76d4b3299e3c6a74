"""Offline HTML report of a ``comparison`` artefact: the paper's Figures 8 and 9 for one campaign.

Two figures, drawn with plain bokeh and written by :func:`lidarcal.htmlpage.offline_html` (BokehJS
inline, nothing from the network):

1. per environmental variable, the sensitivity slope against height, measured and simulated,
   each with its 95 % interval (slope ± 1.96 standard errors); the heights of a disagreeing
   cell are named in the panel title;
2. per height, the combined standard uncertainty (% of the bin's mean reference speed) against
   wind speed: the IEC field budget of the measured pair beside the Monte Carlo budget of the
   simulated pair.
"""

from __future__ import annotations

import html
import os
from pathlib import Path

import numpy as np
import xarray as xr

from lidarcal.htmlpage import grid, legend_outside, offline_html, plot, write_text
from lidarcal.readback import read_attr

__all__ = ["write_report", "slope_figure", "budget_figure"]

#: Colours of the two sides (measured, simulated), the same in both figures.
COLOURS = {"measured": "#1f77b4", "simulated": "#d62728"}
Z95 = 1.959963984540054


def _header(ds: xr.Dataset) -> str:
    js = read_attr(ds, "comparison_json", kind="comparison")
    rows = "".join(
        f"<tr><td>{html.escape(c['variable'])}</td><td>{c['height']:g}</td>"
        f"<td>{c['measured_slope']:.3g} ± {c['measured_se']:.2g}</td>"
        f"<td>{c['simulated_slope']:.3g} ± {c['simulated_se']:.2g}</td><td>{html.escape(c['units'])}</td>"
        f"<td>{c['z']:+.2f}</td><td>{c['p_adjusted']:.3g}</td>"
        f"<td>{'agree' if c['agree'] else '<b>disagree</b>'}</td></tr>"
        for c in js["cells"]
    )
    nxt = f"<br><b>Next:</b> <code>{html.escape(js['next'])}</code>" if js["next"] else ""
    return (
        f"<h2>Verdict: {html.escape(js['verdict'])}</h2>"
        f"<p>Simulated lidar: {html.escape(js['model'])}. "
        f"Field: {html.escape(read_attr(ds, 'field_source', kind='comparison'))}."
        f"<br>Cells agree when the Holm-adjusted p-value of equal slopes is at least alpha = {js['alpha']:g}."
        f"{nxt}</p>"
        f"<table class='numbers'><tr><th>variable</th><th>height (m)</th><th>measured slope</th>"
        f"<th>simulated slope</th><th>units</th><th>z</th><th>Holm p</th><th></th></tr>{rows}</table>"
    )


def _side(p, x: np.ndarray, y: np.ndarray, side: str, label: str | None, size: int,
          err: np.ndarray | None = None) -> None:
    """Draw one side's finite points: line and markers (legend ``label``), and ± ``err`` whiskers."""
    from bokeh.models import ColumnDataSource, Whisker

    ok = np.isfinite(y) & (np.isfinite(err) if err is not None else True)
    data = {"x": x[ok], "y": y[ok]}
    if err is not None:
        data.update(lower=y[ok] - err[ok], upper=y[ok] + err[ok])
    src = ColumnDataSource(data)
    if err is not None:
        whisker = Whisker(base="x", lower="lower", upper="upper", source=src, line_color=COLOURS[side])
        for head in (whisker.upper_head, whisker.lower_head):
            head.line_color = COLOURS[side]
        p.add_layout(whisker)
    legend = {"legend_label": label} if label else {}
    p.line("x", "y", source=src, color=COLOURS[side], line_width=2, **legend)
    p.scatter("x", "y", source=src, color=COLOURS[side], size=size, **legend)


def slope_figure(ds: xr.Dataset) -> list:
    """Figure 1: slope vs height with 95 % intervals, measured vs simulated, one panel per variable."""
    panels = []
    h = np.asarray(ds.height.values, dtype=float)
    shift = 0.01 * (h.max() - h.min() if h.size > 1 else 10.0)  # side by side, not on top of each other
    for v in map(str, ds.variable.values):
        units = ds[f"{v}_measured_slope"].attrs["units"]
        bad = [f"{x:g}" for x, a in zip(h, ds["agree"].sel(variable=v).values, strict=True) if int(a) == 0]
        p = plot(v + (f": disagree at {', '.join(bad)} m" if bad else ": agree"), "height (m)",
                 f"slope ({units})", width=540, height=320)
        for k, side in enumerate(("measured", "simulated")):
            _side(p, h + (k - 0.5) * shift, np.asarray(ds[f"{v}_{side}_slope"].values, float), side, side, 7,
                  err=Z95 * np.asarray(ds[f"{v}_{side}_slope_stderr"].values, float))
        legend_outside(p, "mute")
        panels.append(p)
    return panels


def budget_figure(ds: xr.Dataset) -> list:
    """Figure 2: relative combined uncertainty vs wind speed, IEC (measured) vs Monte Carlo, per height."""
    panels = []
    ws = np.asarray(ds.wind_speed.values, dtype=float)
    label = {"measured": "IEC field approach (measured)", "simulated": "Monte Carlo (simulated)"}
    for h in ds.height.values:
        p = plot(f"Budget vs wind speed at {float(h):g} m", "reference wind speed (m s-1)",
                 "combined standard uncertainty (%)", width=460, height=320)
        for side in ("measured", "simulated"):
            _side(p, ws, np.asarray(ds[f"{side}_relative_uncertainty"].sel(height=h).values, float), side,
                  label[side], 6)
        legend_outside(p, "mute", location="top_right")
        panels.append(p)
    return panels


def write_report(ds: xr.Dataset, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write the self-contained HTML report (both figures) atomically."""
    slopes, budgets = grid(slope_figure(ds)), grid(budget_figure(ds))
    titles = {
        "slopes": "Figure 1. Sensitivity slopes against height: measured and simulated (95 % intervals)",
        "budgets": "Figure 2. Uncertainty budgets against wind speed: IEC field approach and Monte Carlo",
    }
    page = offline_html(
        {"slopes": slopes, "budgets": budgets},
        title=f"lidarcal compare: {ds.attrs.get('comparison_verdict', '')}",
        header=_header(ds),
        titles=titles,
    )
    return write_text(path, page, overwrite=overwrite)
