"""Offline HTML report of a ``diagnosis`` artefact (hvplot/bokeh with INLINE resources).

Plots: the gap per height before and after the correction; for every environmental variable
the binned residual before and after; the Eq. 12 sensitivity statistic m·std of the measured
records against the nominal and the corrected simulations (paper Figure 8 style); the
candidate scores.  The page embeds bokeh's JavaScript, so it opens without network access.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from lidarcal.htmlpage import offline_html, write_text

__all__ = ["write_report", "report_layout"]


def _header(ds: xr.Dataset) -> str:
    js = json.loads(ds.attrs["diagnosis_json"])
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


def report_layout(ds: xr.Dataset):
    """Build the holoviews layout of the report's plots."""
    import holoviews as hv
    import hvplot.pandas  # noqa: F401  (registers .hvplot)

    hv.extension("bokeh", logo=False)
    plots = []
    gaps = pd.DataFrame({"height": ds.height.values, "before": ds.gap_before.values,
                         "after": ds.gap_after.values}).melt("height", var_name="model", value_name="gap")
    plots.append(gaps.hvplot.line(x="height", y="gap", by="model", title="Gap per height (%)",
                                  xlabel="height (m)", ylabel="gap (%)", width=450, height=300)
                 * gaps.hvplot.scatter(x="height", y="gap", by="model"))
    for var in ds.variable.values:
        var = str(var)
        centre = ds[f"{var}_bin_mean"]
        frames = []
        for when in ("before", "after"):
            r = ds[f"binned_residual_{when}"].sel(variable=var)
            for h in ds.height.values:
                frames.append(pd.DataFrame({"x": centre.sel(height=h).values,
                                            "residual": r.sel(height=h).values,
                                            "series": f"{when}, {h:g} m"}))
        df = pd.concat(frames).dropna().rename(columns={"x": var})
        plots.append(df.hvplot.line(x=var, y="residual", by="series", width=450, height=300,
                                    title=f"Binned residual vs {var} (%)",
                                    xlabel=f"{var} ({ds[f'{var}_bin_mean'].attrs['units']})",
                                    ylabel="field − model (%)"))
    if "sensitivity_measured" in ds:
        for var in ds.variable.values:
            var = str(var)
            df = pd.concat([pd.DataFrame({"height": ds.height.values,
                                          "m_std": ds[f"sensitivity_{k}"].sel(variable=var).values,
                                          "source": label})
                            for k, label in (("measured", "measured"), ("before", "simulated, nominal"),
                                             ("after", "simulated, corrected"))])
            plots.append(df.hvplot.line(x="height", y="m_std", by="source", width=450, height=300,
                                        title=f"Sensitivity m·std to {var} (%)", xlabel="height (m)",
                                        ylabel="m·std (%)"))
    scores = pd.DataFrame({"candidate": [str(c) for c in ds.candidate.values],
                           "score": np.asarray(ds.candidate_score.values, float)})
    plots.append(scores.hvplot.bar(x="candidate", y="score", rot=30, width=450, height=300,
                                   title="Candidate score (ΔBIC vs none; lower is better)"))
    return hv.Layout(plots).cols(2).opts(shared_axes=False)


def write_report(ds: xr.Dataset, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Write the self-contained HTML report atomically.

    The layout is rendered to bokeh and written by :func:`lidarcal.htmlpage.offline_html` (the
    page writer shared with the calibration report: BokehJS inline).  ``hvplot.save`` would go
    through panel, whose page template links its CSS from a CDN, so the page would try the
    network when opened offline.
    """
    import holoviews as hv

    model = hv.render(report_layout(ds), backend="bokeh")
    title = f"lidarcal diagnosis: {ds.attrs.get('diagnosis_effect', '')}"
    page = offline_html({"diagnosis": model}, title=title, header=_header(ds), headings=False)
    return write_text(path, page, overwrite=overwrite)
