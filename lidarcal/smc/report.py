"""The campaign uncertainty's report: an offline HTML page and a PDF, with the same figures (matplotlib).

:func:`write_report` writes ``SMC.html`` and ``SMC.pdf`` from an ``smc`` artefact.  Both open
with the status (a demonstration result says so first), the certificate and the campaign's
files with their SHA-256, the coverage per height and the quoted route, then three figures
(:func:`figures`):

1. per height, the combined standard uncertainty against wind speed (per-bin root mean square,
   % of the bin's mean speed) with each contributor and both routes' combinations;
2. the campaign's conditions against the calibration's envelope, per variable and height: where
   the campaign leaves what the calibration simulated;
3. the two environmental routes side by side, per height and wind-speed bin.

The HTML embeds the figures as PNG (nothing is fetched from the network).
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate.document.figures import A4, FONT, STYLE
from lidarcal.htmlpage import html_table, write_text
from lidarcal.io import atomic_path, check_writable
from lidarcal.readback import read_attr
from lidarcal.smc.dataset import binned
from lidarcal.smc.routes import COVERAGE, ENVELOPE

__all__ = ["write_report", "figures", "facts"]

_COLOURS = {"calibration": "#1f77b4", "environmental_iec": "#ff7f0e", "environmental_monte_carlo": "#2ca02c"}
_USER_COLOURS = ["#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"]


def _covered_heights(ds: xr.Dataset) -> list[float]:
    flag = ds["coverage_flag"].transpose("time", "height").values
    return [float(z) for j, z in enumerate(ds["height"].values) if (flag[:, j] == 0).any()]


def facts(ds: xr.Dataset) -> list[tuple[str, str]]:
    """(label, text) of what the report states first: status, certificate, files, route, coverage."""
    a = ds.attrs
    status = str(a.get("calibration_status"))
    out = [
        (
            "Status",
            (
                "DEMONSTRATION result: the certificate is a demonstration, not a calibration of a real "
                "instrument"
                if status == "demonstration"
                else f"certificate status: {status}"
            ),
        ),
        ("Lidar", str(a.get("lidar_serial"))),
        (
            "Certificate",
            f"{a.get('certificate_file')} (id {a.get('certificate_id')}, {a.get('certificate_seal')}), "
            f"sha256 {a.get('certificate_sha256')}",
        ),
        (
            "Cone angle",
            f"{float(a.get('lidar_cone_angle')):g} degree, from {a.get('lidar_cone_angle_source')}",
        ),
    ]
    for rec in json.loads(a.get("lidarcal_inputs", "[]")):
        if rec.get("role") != "certificate":
            out.append((f"Input ({rec.get('role')})", f"{rec.get('file')}, sha256 {rec.get('sha256')}"))
    out += [
        (
            "Periods",
            f"{ds.sizes['time']} ten-minute periods from {a.get('time_coverage_start', '?')} to "
            f"{a.get('time_coverage_end', '?')}, at {ds.sizes['height']} heights",
        ),
        (
            "Covered",
            f"{a.get('covered_periods')} of {a.get('periods_with_wind_speed')} period-heights with a "
            f"wind speed; heights not certified: {a.get('heights_not_covered_m')} m",
        ),
        (
            "Quoted route",
            f"{a.get('environmental_route')} (Monte Carlo route: {a.get('monte_carlo_route')}); "
            "both routes' combinations are in the file",
        ),
        (
            "User terms",
            ", ".join(
                f"{t['name']} {t['value']:g} {t['unit']} ({t['distribution']}; {t['source']})"
                for t in json.loads(a.get("user_terms", "[]"))
            )
            or "none",
        ),
        ("What u is", str(a.get("measurand", "not stated"))),
        ("Model form", str(a.get("certificate_model_form", "not stated"))),
    ]
    return out


def _coverage_rows(ds: xr.Dataset) -> tuple[list[str], list[list[str]]]:
    flag = ds["coverage_flag"].transpose("time", "height").values
    rel = ds["relative_uncertainty"].transpose("time", "height").values
    header = ["height (m)", *COVERAGE, "median u (%)", "95th percentile u (%)"]
    rows = []
    for j, z in enumerate(ds["height"].values):
        counts = [str(int((flag[:, j] == k).sum())) for k in range(len(COVERAGE))]
        r = rel[:, j][np.isfinite(rel[:, j])]
        q = (f"{np.median(r):.2f}", f"{np.percentile(r, 95):.2f}") if r.size else ("–", "–")
        rows.append([f"{float(z):g}", *counts, *q])
    return header, rows


def _per_height(fig, ds: xr.Dataset, b: xr.Dataset, draw, ylabel: str, title: str) -> None:
    """One panel per covered height of the binned ``b``, ``draw(ax, one, names)`` filling each; a legend."""
    heights = _covered_heights(ds)
    n = max(len(heights), 1)
    cols = 2 if n > 1 else 1
    axes = fig.subplots(
        (n + cols - 1) // cols,
        cols,
        squeeze=False,
        gridspec_kw=dict(top=0.92, bottom=0.06, left=0.1, right=0.97, hspace=0.5, wspace=0.3),
    )
    names = [str(c) for c in b["contributor"].values]
    for ax, z in zip(axes.ravel(), heights, strict=False):
        draw(ax, b.sel(height=z), names)
        ax.set_title(f"{z:g} m", fontsize=FONT + 1)
        ax.set_xlabel("wind speed (m s-1)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(heights) :]:
        ax.set_visible(False)
    if heights:
        axes.ravel()[0].legend(fontsize=FONT - 1.5, loc="upper right")
    fig.suptitle(title, fontsize=FONT + 2)


def _uncertainty_panel(ax, one: xr.Dataset, names: list[str]) -> None:
    """Draw the combined uncertainty, both routes' combinations, each contributor and the bin mean's (%)."""
    user = {c: _USER_COLOURS[k % len(_USER_COLOURS)] for k, c in enumerate(names) if c not in _COLOURS}
    u = one["mean_wind_speed"].values
    ok = np.isfinite(one["uncertainty"].values)
    scale = np.where(ok, 100.0 / u, np.nan)
    ax.plot(u[ok], one["relative_uncertainty"].values[ok], "k-o", ms=3, label="combined (quoted)")
    for route, style in (("iec_route", ":"), ("monte_carlo_route", "--")):
        v = one[f"uncertainty_{route}"].values * scale
        if np.isfinite(v).any():
            ax.plot(u[ok], v[ok], "k" + style, lw=1, label=f"combined, {route.replace('_', ' ')}")
    for k, c in enumerate(names):
        v = one["contribution"].values[:, k] * scale
        if np.isfinite(v[ok]).any():
            ax.plot(u[ok], v[ok], "-", lw=1, color=_COLOURS.get(c, user.get(c)), label=c)
    if "mean_relative_uncertainty" in one:
        v = one["mean_relative_uncertainty"].values
        if np.isfinite(v[ok]).any():
            ax.plot(u[ok], v[ok], "-s", ms=2, lw=1, color="0.5", label="the bin's mean speed")


def _uncertainty_figure(fig, ds: xr.Dataset, b: xr.Dataset) -> None:
    _per_height(fig, ds, b, _uncertainty_panel, "standard uncertainty (%)",
                "Standard uncertainty against wind speed per height (root mean square over each bin's "
                "covered periods; grey: of the bin's mean speed)")


def _conditions_figure(fig, ds: xr.Dataset) -> None:
    axes = fig.subplots(
        2,
        2,
        squeeze=False,
        gridspec_kw=dict(top=0.9, bottom=0.07, left=0.1, right=0.97, hspace=0.4, wspace=0.3),
    ).ravel()
    z = np.asarray(ds["height"].values, dtype=float)
    bits = ds["outside_envelope"].transpose("time", "height").values
    dz = 0.18 * (np.min(np.diff(z)) if z.size > 1 else 10.0)
    for k, (ax, v) in enumerate(zip(axes, ENVELOPE, strict=True)):
        x = ds[v].transpose("time", "height").values
        lo, hi = ds[f"envelope_low_{v}"].values, ds[f"envelope_high_{v}"].values
        name = f"calibration_quantiles_{v}"
        q = (
            ds[name].sel(quantile=[0.05, 0.5, 0.95]).transpose("quantile", "height").values
            if name in ds
            else None
        )
        for j, h in enumerate(z):
            first = j == 0
            if np.isfinite(lo[j]):
                ax.plot(
                    [lo[j], hi[j]],
                    [h - dz, h - dz],
                    color="0.6",
                    lw=0.8,
                    label="calibration: envelope" if first else None,
                )
            if q is not None and np.isfinite(q[:, j]).all():
                ax.plot(
                    [q[0, j], q[2, j]],
                    [h - dz, h - dz],
                    color="0.55",
                    lw=3,
                    label="calibration: 5-95 %" if first else None,
                )
                ax.plot([q[1, j]], [h - dz], "o", color="0.4", ms=3)
            xs = x[:, j][np.isfinite(x[:, j])]
            if xs.size:
                p5, p50, p95 = np.percentile(xs, [5, 50, 95])
                ax.plot(
                    [xs.min(), xs.max()],
                    [h + dz, h + dz],
                    color="#1f77b4",
                    lw=0.8,
                    label="campaign: range" if first else None,
                )
                ax.plot(
                    [p5, p95],
                    [h + dz, h + dz],
                    color="#1f77b4",
                    lw=3,
                    label="campaign: 5-95 %" if first else None,
                )
                ax.plot([p50], [h + dz], "o", color="#1f77b4", ms=3)
                outside = int(((bits[:, j] >> k) & 1).sum())
                if outside:
                    ax.annotate(
                        f"{100 * outside / xs.size:.0f} % outside",
                        (xs.max(), h + dz),
                        fontsize=FONT - 2,
                        xytext=(3, -2),
                        textcoords="offset points",
                        color="#d62728",
                    )
        ax.set_title(v.replace("_", " "), fontsize=FONT + 1)
        ax.set_xlabel(ds[v].attrs.get("units", ""))
        ax.set_ylabel("height (m)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=FONT - 1.5, loc="lower right")
    fig.suptitle(
        "Campaign (blue) against calibration (grey): median, 5-95 %, range / envelope",
        fontsize=FONT + 2,
    )


def _routes_panel(ax, one: xr.Dataset, names: list[str]) -> None:
    """Draw the two environmental routes' contributions (% of the bin's mean speed)."""
    u = one["mean_wind_speed"].values
    for c, label in (
        ("environmental_iec", "IEC 61400-50-2 route"),
        ("environmental_monte_carlo", "Monte Carlo route"),
    ):
        v = one["contribution"].values[:, names.index(c)] * 100.0 / u
        ok = np.isfinite(v)
        if ok.any():
            ax.plot(u[ok], v[ok], "-o", ms=3, color=_COLOURS[c], label=label)


def _routes_figure(fig, ds: xr.Dataset, b: xr.Dataset) -> None:
    _per_height(fig, ds, b, _routes_panel, "environmental term (%)",
                "The two environmental routes side by side (root mean square per bin)")


#: Figure name -> title.
FIGURES = {
    "uncertainty": "Uncertainty against wind speed, with its contributors",
    "conditions": "The campaign's conditions against the calibrated envelope",
    "routes": "The two environmental routes side by side",
}


def figures(ds: xr.Dataset) -> dict[str, Any]:
    """Return the report's matplotlib figures (A4 portrait), by name (:data:`FIGURES`)."""
    import matplotlib
    from matplotlib.figure import Figure

    b = binned(ds)
    out = {}
    with matplotlib.rc_context(STYLE):
        for name in FIGURES:
            fig = Figure(figsize=(A4[0], A4[1] * 0.62))
            {
                "uncertainty": lambda f: _uncertainty_figure(f, ds, b),
                "conditions": lambda f: _conditions_figure(f, ds),
                "routes": lambda f: _routes_figure(f, ds, b),
            }[name](fig)
            out[name] = fig
    return out


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _html(ds: xr.Dataset, figs: dict[str, Any]) -> str:
    demo = read_attr(ds, "calibration_status", kind="smc") == "demonstration"
    banner = (
        '<p class="status"><strong>DEMONSTRATION result: the certificate is a demonstration, not a '
        "calibration of a real instrument.</strong></p>\n"
        if demo
        else ""
    )
    rows = "\n".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in facts(ds))
    header, cov = _coverage_rows(ds)
    table = html_table(
        header,
        cov,
        "Coverage per height (number of periods with each coverage flag) and the "
        "quoted relative standard uncertainty of the covered periods",
    )
    sections = "\n".join(
        f'<section id="{n}"><h2>{html.escape(FIGURES[n])}</h2>'
        f'<img alt="{html.escape(FIGURES[n])}" src="data:image/png;base64,{_png(f)}"></section>'
        for n, f in figs.items()
    )
    title = html.escape(str(ds.attrs.get("title", "lidarcal smc")))
    return (
        f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8"><title>{title}</title>\n'
        "<style>body{font-family:sans-serif;margin:2em;max-width:72em} th,td{text-align:left;padding:0.2em "
        "1em 0.2em 0;vertical-align:top;font-size:0.9em} table{border-collapse:collapse;margin-bottom:2em} "
        "table.numbers td{text-align:right} img{max-width:100%} .status{color:#b22222}</style></head><body>\n"
        f'<h1>{title}</h1>\n{banner}<table class="facts">\n{rows}\n</table>\n{table}\n{sections}\n'
        "<p>Per-bin table: <code>lidarcal table SMC.nc</code>; method: lidarcal docs/smc.md.</p>\n"
        "</body></html>\n"
    )


def _text_page(fig, ds: xr.Dataset) -> None:
    import textwrap

    y = 0.95
    fig.text(
        0.07, y, textwrap.fill(str(ds.attrs.get("title", "")), 95), fontsize=FONT + 3, weight="bold", va="top"
    )
    y -= 0.06
    for label, value in facts(ds):
        lines = textwrap.wrap(value, 85) or [""]
        colour = "#b22222" if label == "Status" and "DEMONSTRATION" in value else "black"
        fig.text(0.07, y, label, fontsize=FONT, va="top", color="0.25")
        fig.text(0.25, y, "\n".join(lines), fontsize=FONT, va="top", color=colour, linespacing=1.3)
        y -= 0.017 * len(lines) + 0.006
    header, rows = _coverage_rows(ds)
    y -= 0.02
    fig.text(
        0.07,
        y,
        "Coverage per height (periods with each flag) and the quoted relative standard uncertainty",
        fontsize=FONT,
        weight="bold",
        va="top",
    )
    y -= 0.025
    xs = np.linspace(0.07, 0.95, len(header) + 1)[:-1]
    for row in [[h.replace("_", " ") for h in header], *rows]:
        for x, cell in zip(xs, row, strict=True):
            fig.text(x, y, textwrap.fill(cell, 12), fontsize=FONT - 1.5, va="top")
        y -= 0.028 if row is not rows[0] else 0.02


def write_report(ds: xr.Dataset, path: str | os.PathLike, *, overwrite: bool = False) -> dict[str, Path]:
    """Write ``path`` (HTML) and the PDF beside it (same name, ``.pdf``); both atomically."""
    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    path = Path(path)
    pdf = path.with_suffix(".pdf")
    for p in (path, pdf):
        check_writable(p, overwrite=overwrite)
    figs = figures(ds)
    page = _html(ds, figs)
    with matplotlib.rc_context(STYLE):
        first = Figure(figsize=A4)
        _text_page(first, ds)
        with (
            atomic_path(pdf, overwrite=overwrite) as tmp,
            PdfPages(
                tmp,
                metadata={
                    "Title": str(ds.attrs.get("title", "")),
                    "Creator": "lidarcal",
                    "Subject": f"status: {read_attr(ds, 'calibration_status', kind='smc')}",
                },
            ) as out,
        ):
            for fig in (first, *figs.values()):
                out.savefig(fig)
    write_text(path, page, overwrite=overwrite)
    return {"html": path, "pdf": pdf}
