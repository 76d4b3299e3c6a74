"""Offline HTML report of a calibration: interactive hvplot/bokeh plots plus static PNGs.

The page embeds BokehJS inline (``resources=INLINE``), so it opens without network access,
and shows, as available, budget first:

- the expanded (k = 2) uncertainty vs wind speed (paper Figure 9), a menu choosing all
  heights or one, thin bins (fewer periods than ``min_samples``) marked with red crosses;
- the uncertainty contributors as grouped bars per wind-speed bin, a menu choosing the height;
- the sensitivities (Figure 7): per height (menu) the bin means with the standard error of
  the mean, the regression line and its 95 % confidence band, plus a table of the slopes,
  R and the Eqs. 12-13 statistics rounded to 3 significant digits; and (Figure 8) the Eq. 12
  statistic m·std per height for every variable against the ±0.5 % threshold;
- the bench cube (Figure 5): CNR x programmed velocity heatmaps of the LOS bias and of the
  LOS standard deviation, one per line of sight on one colour scale;
- the range-weighting function (Figure 6): pulse, apodization and RWF, and the RWF for a few
  CNR gradients, with the zero distance Zd.

Every figure is also written as a PNG at 150 dpi through HoloViews' matplotlib backend (or
matplotlib itself), next to the page (``<stem>_<figure>.png``); a menu's PNG shows every
height.
"""

from __future__ import annotations

import html
import json
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate import (
    HEADLINE_WIND_SPEEDS,
    components,
    extract_component,
    headline_range,
    invalid_seal_banner,
    require_valid_seal,
)
from lidarcal.errors import InputError
from lidarcal.htmlpage import offline_html, write_text
from lidarcal.io import atomic_path, check_writable

__all__ = ["Figure", "confidence_band", "fmt", "report_figures", "write_report"]

_WIDTH, _HEIGHT = 900, 380
_PNG_DPI = 150  # static figures: at least 150 dpi, written into the PNG's pHYs chunk
_THIN = "#d62728"  # marker colour of thin bins (fewer periods than min_samples)
_VARIABLES = {  # readable names of the environmental variables
    "wind_shear_exponent": "wind shear exponent",
    "turbulence_intensity": "turbulence intensity",
    "cnr_gradient": "CNR gradient",
    "cnr": "CNR",
}


@dataclass
class Figure:
    """One report figure: its heading, panels and how the page and the PNG show them.

    ``kind`` is ``"single"`` (one panel), ``"grid"`` (all panels side by side, e.g. one
    heatmap per line of sight) or ``"select"`` (one panel at a time, chosen with a drop-down
    menu above the plot, e.g. one panel per height).  ``png`` is what the static PNG shows
    (default: the single panel, or all panels as a grid); ``note`` is HTML shown below the
    plot (a table of the numbers, rounded).
    """

    heading: str
    panels: dict[str, Any]
    kind: str = "single"
    png: Any = None
    note: str = ""
    columns: int = 3
    default: str | None = None

    def png_object(self) -> Any:
        """Return what the static PNG shows: a HoloViews object or a matplotlib figure."""
        hv = _hv()
        if callable(self.png):
            return self.png()
        if self.png is not None:
            return self.png
        if self.kind == "single":
            return next(iter(self.panels.values()))
        return hv.Layout(list(self.panels.values())).cols(self.columns if self.kind == "grid" else 2).opts(
            hv.opts.Layout(sublabel_format="", fig_inches=7, hspace=0.4, vspace=0.5), backend="matplotlib"
        )

    def bokeh(self) -> Any:
        """Render the page's bokeh model: one plot, a grid, or a drop-down menu and its plots."""
        hv = _hv()
        from bokeh.layouts import column
        from bokeh.models import CustomJS, Select

        if self.kind == "single":
            return hv.render(next(iter(self.panels.values())), backend="bokeh")
        if self.kind == "grid":
            return hv.render(hv.Layout(list(self.panels.values())).cols(self.columns), backend="bokeh")
        labels = list(self.panels)
        shown = self.default if self.default in self.panels else labels[0]
        plots = [hv.render(p, backend="bokeh") for p in self.panels.values()]
        for label, plot in zip(labels, plots, strict=True):
            plot.visible = label == shown
        select = Select(title="Show:", value=shown, options=labels, width=220)
        select.js_on_change(
            "value",
            CustomJS(
                args={"plots": plots, "labels": labels},
                code="const i = labels.indexOf(cb_obj.value);"
                "plots.forEach((p, k) => { p.visible = k === i; });",
            ),
        )
        return column(select, *plots)


def _hv():
    import holoviews as hv
    import holoviews.plotting.mpl  # noqa: F401  (matplotlib backend for the PNGs)
    import hvplot.xarray  # noqa: F401  (registers .hvplot)

    hv.Store.set_current_backend("bokeh")
    return hv


def fmt(value: Any, digits: int = 3) -> str:
    """``value`` with ``digits`` significant digits (``-1.93``, ``0.000123``, ``1230``, ``3.09e-16``)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not np.isfinite(x):
        return "–" if np.isnan(x) else str(x)
    if x == int(x) and abs(x) < 10**digits:
        return f"{int(x):d}"
    if abs(x) < 1e-4 or abs(x) >= 1e6:
        return f"{x:.{digits - 1}e}"
    return np.format_float_positional(x, precision=digits, unique=False, fractional=False, trim="-")


def _units(da: xr.DataArray) -> str:
    u = da.attrs.get("units", "")
    return f" ({u})" if u and u != "1" else ""


def _style(obj: Any, title: str, xlabel: str, ylabel: str, *, width: int = _WIDTH, height: int = _HEIGHT,
           legend: bool = True) -> Any:
    """Apply the same labels for both backends (bokeh page, matplotlib PNG); legends outside the plot area."""
    bk = dict(title=title, xlabel=xlabel, ylabel=ylabel, width=width, height=height, fontscale=1.1)
    mp = dict(title=title, xlabel=xlabel, ylabel=ylabel, aspect=width / height, fig_size=200)
    if legend:
        bk["legend_position"] = mp["legend_position"] = "right"
    return obj.opts(**bk, backend="bokeh").opts(**mp, backend="matplotlib")


def _table(header: list[str], rows: list[list[str]], caption: str) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "\n".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return (f'<table class="numbers"><caption>{html.escape(caption)}</caption>'
            f"<tr>{head}</tr>\n{body}</table>")


def _los_label(cube: xr.Dataset, los: Any) -> str:
    name = str(los)
    if name.upper() == "V":
        return "LOS V (vertical beam)"
    if "los_azimuth" in cube.coords:
        return f"LOS {name} (azimuth {fmt(cube.los_azimuth.sel(los=los).item())}°)"
    return f"LOS {name}"


def _cube_plots(cube: xr.Dataset) -> dict[str, Figure]:
    """CNR x programmed velocity heatmaps, one per line of sight, one colour scale for all."""
    hv = _hv()
    out = {}
    for name, heading, cmap, symmetric in (
        ("los_bias", "Bench: mean LOS velocity error (measured − programmed)", "RdBu_r", True),
        ("los_std", "Bench: standard deviation of the measured LOS velocity", "viridis", False),
    ):
        if name not in cube:
            continue
        da = cube[name].transpose("los", "cnr", "velocity")
        finite = da.values[np.isfinite(da.values)]
        if finite.size:
            top = float(np.percentile(np.abs(finite) if symmetric else finite, 99))
            clim = (-top, top) if symmetric else (float(finite.min()), top)
        else:
            clim = (np.nan, np.nan)
        label = f"{name.replace('_', ' ')}{_units(da)}"
        panels = {}
        for los in da.los.values:
            mesh = hv.QuadMesh(
                (cube.velocity.values, cube.cnr.values, da.sel(los=los).values),
                kdims=["velocity", "cnr"], vdims=[hv.Dimension(name, label=label)],
            )
            mesh = mesh.opts(cmap=cmap, clim=clim, colorbar=True, tools=["hover"], backend="bokeh")
            mesh = mesh.opts(cmap=cmap, clim=clim, colorbar=True, backend="matplotlib")
            panels[str(los)] = _style(
                mesh, _los_label(cube, los), f"programmed radial velocity{_units(cube.velocity)}",
                f"CNR{_units(cube.cnr)}", width=360, height=280, legend=False,
            )
        out[f"cube_{name}"] = Figure(
            f"{heading}, per line of sight", panels, kind="grid",
            png=lambda da=da, cmap=cmap, clim=clim, label=label, heading=heading: _cube_png(
                cube, da, cmap, clim, label, heading),
            note=f"<p>Colour: {html.escape(label)}; blank cells had no bench samples. "
                 "The colour scale is the same for every line of sight "
                 f"({fmt(clim[0])} to {fmt(clim[1])}, 99th percentile).</p>",
        )
    return out


def _grid(n: int, ncol: int, width: float, height: float) -> tuple[Any, Any]:
    import matplotlib.pyplot as plt

    nrow = int(np.ceil(n / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(width * ncol, height * nrow), squeeze=False,
                             layout="constrained")
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, list(axes.flat[:n])


def _cube_png(cube: xr.Dataset, da: xr.DataArray, cmap: str, clim: tuple, label: str, heading: str) -> Any:
    """All lines of sight as heatmaps on one colour scale, drawn with matplotlib (fast)."""
    fig, axes = _grid(da.sizes["los"], 3, 4.6, 3.6)
    mesh = None
    for ax, los in zip(axes, da.los.values, strict=False):
        mesh = ax.pcolormesh(cube.velocity.values, cube.cnr.values, da.sel(los=los).values, cmap=cmap,
                             vmin=clim[0], vmax=clim[1], shading="nearest")
        ax.set_title(_los_label(cube, los), fontsize=10)
        ax.set_xlabel(f"programmed radial velocity{_units(cube.velocity)}", fontsize=9)
        ax.set_ylabel(f"CNR{_units(cube.cnr)}", fontsize=9)
    fig.suptitle(heading)
    if mesh is not None:
        fig.colorbar(mesh, ax=axes, label=label, shrink=0.8)
    return fig


def _sensitivity_png(ds: xr.Dataset, readable: str, xl: str, yl: str, units: str) -> Any:
    """Every height's bin means, fit and 95 % band, drawn with matplotlib (fast)."""
    fig, axes = _grid(ds.sizes["height"], 2, 6.0, 3.4)
    for ax, h in zip(axes, ds.height.values, strict=False):
        one = ds.sel(height=h)
        used = (one["bin_flag"] == 0).values & np.isfinite(one["mean_difference"].values)
        xb, yb = one["bin"].values[used], one["mean_difference"].values[used]
        sem = (one["std_difference"].values / np.sqrt(np.maximum(one["sample_count"].values, 1)))[used]
        ax.errorbar(xb, yb, yerr=sem, fmt="o", color="black", ms=4, label="bin mean ± s.e.")
        if used.sum() >= 2 and np.isfinite(float(one["slope"])):
            x = np.linspace(xb.min(), xb.max(), 60)
            fit, lo, hi = confidence_band(ds, h, x)
            ax.fill_between(x, lo, hi, color="#1f77b4", alpha=0.25, lw=0, label="95 % confidence band")
            ax.plot(x, fit, color="#1f77b4", lw=2, label="regression")
        se = float(one["slope_standard_error"]) if "slope_standard_error" in one else np.nan
        ax.set_title(f"{fmt(h)} m: m = {fmt(float(one['slope']))} ± {fmt(se)} {units}, "
                     f"R = {fmt(float(one['correlation']), 2)}", fontsize=10)
        ax.set_xlabel(xl, fontsize=9)
        ax.set_ylabel(yl, fontsize=8)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Sensitivity to {readable}")
    return fig


def _rwf_plots(rwf: xr.Dataset) -> dict[str, Figure]:
    out = {}
    zd = float(rwf["zero_distance"]) if "zero_distance" in rwf else float("nan")
    column = rwf["rwf"].sel(cnr_gradient=0.0, method="nearest")
    curves = {"RWF": column / float(column.max())}
    for name in ("pulse", "apodization"):
        if name in rwf:
            curves[name] = rwf[name] / float(rwf[name].max())
    norm = xr.Dataset(curves)
    support = np.flatnonzero((norm["RWF"] > 1e-3).values)
    lo, hi = (support.min(), support.max()) if support.size else (0, rwf.sizes["range_offset"] - 1)
    pad = max(5, (hi - lo) // 4)
    sl = slice(max(lo - pad, 0), min(hi + pad, rwf.sizes["range_offset"] - 1) + 1)
    norm = norm.isel(range_offset=sl)
    xl = "range offset from gate centre (m)"
    shape = _style(
        norm.hvplot.line(x="range_offset", y=list(curves)),
        f"Pulse, apodization and RWF (normalised), Zd = {fmt(zd)} m", xl, "normalised amplitude",
    )
    out["rwf_shape"] = Figure("Range-weighting function", {"shape": shape})
    g = rwf["cnr_gradient"].values
    pick = sorted(set(np.linspace(0, len(g) - 1, min(5, len(g))).round().astype(int).tolist()))
    sub = rwf["rwf"].isel(cnr_gradient=pick, range_offset=sl)
    sub = sub.assign_coords(cnr_gradient=[f"{fmt(v)} dB/m" for v in g[pick]])
    grad = _style(
        sub.hvplot.line(x="range_offset", by="cnr_gradient"),
        "RWF for several CNR gradients (Eq. 2)", xl, f"RWF{_units(rwf['rwf'])}",
    )
    out["rwf_gradients"] = Figure("Range-weighting function for several CNR gradients", {"gradients": grad})
    return out


def confidence_band(ds: xr.Dataset, height: Any, x: np.ndarray,
                    level: float = 0.95) -> tuple[np.ndarray, ...]:
    """Fitted line and its two-sided ``level`` confidence band at ``x`` for one height.

    The regression is of the kept bin means (``bin_flag == 0``) on the bins' mean of the
    variable (``variable_mean``) with weights ``regression_weight`` (weighted least squares,
    ``docs/sensitivity.md``); an artefact without them was fitted on the bin centres with equal
    weights.  With ``S = Σ w (x_i − x̄_w)²`` and the scale ``c²`` of the weights' errors, the band
    of the mean line is ``t(k-2) · c · sqrt(1/Σw + (x − x̄_w)² / S)``; ``c² = s_m² S`` from the
    slope's standard error ``s_m`` (``slope_standard_error``), else ``max(1, χ²_ν)`` of the
    residuals (equal weights: their variance).

    Returns
    -------
    fit, lower, upper : arrays like ``x`` (band NaN with fewer than three bins)
    """
    from scipy import stats

    one = ds.sel(height=height)
    weighted = "regression_weight" in one and "variable_mean" in one
    xs = one["variable_mean"].values if weighted else one["bin"].values
    ws = one["regression_weight"].values if weighted else np.ones(xs.shape)
    yb_all = one["mean_difference"].values
    used = (one["bin_flag"] == 0).values & np.isfinite(yb_all) & np.isfinite(xs) & np.isfinite(ws) & (ws > 0)
    xb, yb, wb = xs[used], yb_all[used], ws[used]
    slope, intercept = float(one["slope"]), float(one["intercept"])
    fit = intercept + slope * x
    n = int(used.sum())
    if n < 3:
        return fit, np.full_like(fit, np.nan), np.full_like(fit, np.nan)
    xm = float((wb * xb).sum() / wb.sum())
    sxx = float((wb * (xb - xm) ** 2).sum())
    if "slope_standard_error" in one and np.isfinite(float(one["slope_standard_error"])):
        scale2 = float(one["slope_standard_error"]) ** 2 * sxx
    else:
        chi2 = float((wb * (yb - (intercept + slope * xb)) ** 2).sum() / (n - 2))
        scale2 = max(1.0, chi2) if weighted else chi2
    half = stats.t.ppf(0.5 + level / 2, n - 2) * np.sqrt(scale2 * (1.0 / wb.sum() + (x - xm) ** 2 / sxx))
    return fit, fit - half, fit + half


def _sensitivity_figure(ds: xr.Dataset) -> Figure:
    hv = _hv()
    var = str(ds.attrs.get("environmental_variable", "variable"))
    readable = _VARIABLES.get(var, var.replace("_", " "))
    xl = f"{readable}{_units(ds['bin'])}"
    yl = f"mean lidar − reference difference{_units(ds['mean_difference'])}"
    units = ds["slope"].attrs.get("units", "")
    panels, rows = {}, []
    for h in ds.height.values:
        one = ds.sel(height=h)
        used = (one["bin_flag"] == 0).values & np.isfinite(one["mean_difference"].values)
        xb = one["bin"].values
        n = np.maximum(one["sample_count"].values, 1)
        sem = one["std_difference"].values / np.sqrt(n)
        means = hv.Scatter((xb[used], one["mean_difference"].values[used]), "bin", "mean",
                           label="bin mean").opts(color="black", size=7, backend="bokeh")
        means = means.opts(color="black", s=30, backend="matplotlib")
        bars = hv.ErrorBars((xb[used], one["mean_difference"].values[used], sem[used]),
                            "bin", ["mean", "sem"]).opts(color="black", backend="bokeh")
        layers = [bars, means]
        slope, se, r = (float(one[k]) if k in one else np.nan
                        for k in ("slope", "slope_standard_error", "correlation"))
        if used.sum() >= 2 and np.isfinite(slope):
            x = np.linspace(xb[used].min(), xb[used].max(), 60)
            fit, lo, hi = confidence_band(ds, h, x)
            if np.isfinite(lo).any():
                band = hv.Area((x, lo, hi), "bin", ["mean", "upper"], label="95 % confidence band")
                layers.insert(0, band.opts(color="#1f77b4", alpha=0.25, line_alpha=0, backend="bokeh")
                              .opts(color="#1f77b4", alpha=0.25, backend="matplotlib"))
            layers.append(hv.Curve((x, fit), "bin", "mean", label="regression").opts(
                color="#1f77b4", line_width=2, backend="bokeh").opts(color="#1f77b4", backend="matplotlib"))
        title = f"{fmt(h)} m: m = {fmt(slope)} ± {fmt(se)} {units}, R = {fmt(r, 2)}"
        overlay = hv.Overlay(layers).opts(padding=0.05)
        panels[f"{fmt(h)} m"] = _style(overlay, title, xl, yl, width=_WIDTH - 80)
        sig = [name for name, key in (("Eq. 12", "significant_eq12"), ("Eq. 13", "significant_eq13"))
               if key in one and int(one[key]) == 1]
        rows.append([fmt(h), f"{fmt(slope)} ± {fmt(se)}", fmt(r, 2),
                     fmt(float(one["slope_times_std"])) if "slope_times_std" in one else "–",
                     fmt(float(one["slope_times_std_times_r"])) if "slope_times_std_times_r" in one else "–",
                     str(int(one["bins_used"])) if "bins_used" in one else str(int(used.sum())),
                     ", ".join(sig) or "no"])
    note = (
        "<p>Points: bin means of the difference with the standard error of the mean "
        "(standard deviation / √periods); bins with fewer periods than the minimum are left out of "
        "the regression and not drawn. Line: least-squares fit of the bin means on the bin centres; "
        "band: its 95 % confidence band (from the slope's standard error).</p>"
        + _table(["height (m)", f"slope m ({units})", "R", "m·std (%)", "m·std·R (%)", "bins", "significant"],
                 rows, f"Sensitivity to {readable} (3 significant digits; Eq. 12: |m·std| > 0.5 %, "
                       "Eq. 13: |m·std·R| > 0.1 %)")
    )
    return Figure(f"Sensitivity to {readable}", panels, kind="select", note=note,
                  png=lambda: _sensitivity_png(ds, readable, xl, yl, units))


def _sensitivity_plots(sens: Iterable[xr.Dataset]) -> dict[str, Figure]:
    hv = _hv()
    out = {}
    stats = []
    for ds in sens:
        var = str(ds.attrs.get("environmental_variable", "variable"))
        out[f"sensitivity_{var}"] = _sensitivity_figure(ds)
        stats.append(ds["slope_times_std"].expand_dims(variable=[_VARIABLES.get(var, var.replace("_", " "))])
                     .reset_coords(drop=True))
    if stats:
        all_stats = xr.concat(stats, dim="variable", join="outer").rename("slope_times_std")
        lo, hi = (1.1 * float(f(all_stats)) for f in (np.nanmin, np.nanmax))
        limit = hv.HLine(0.5) * hv.HLine(-0.5)
        limit = limit.opts(
            hv.opts.HLine(color="grey", line_dash="dashed", backend="bokeh"),
            hv.opts.HLine(color="grey", linestyle="--", backend="matplotlib"),
        )
        lines = all_stats.hvplot.line(x="height", by="variable") * all_stats.hvplot.scatter(
            x="height", by="variable").opts(hv.opts.Scatter(size=7, backend="bokeh"))
        out["sensitivity_slopes"] = Figure(
            "Significance of the sensitivities (Eq. 12)",
            {"slopes": _style((lines * limit).opts(ylim=(min(-0.6, lo), max(0.6, hi))),
                              "m · std of each variable per height; threshold ±0.5 %",
                              "height (m)", "m · std (%)")},
        )
    return out


def _budget_plots(budget: xr.Dataset) -> dict[str, Figure]:
    """Plot the expanded (k = 2) uncertainty per height (menu: all heights or one) and the contributors."""
    hv = _hv()
    k = float(budget.attrs.get("coverage_factor", 2.0))
    xl = f"reference wind speed bin{_units(budget.wind_speed)}"
    rel = budget["relative_expanded_uncertainty"]
    flag = budget["bin_flag"]
    ws = budget.wind_speed.values
    finite = rel.values[np.isfinite(rel.values)]
    ylim = (0.0, float(np.percentile(finite, 98)) * 1.15) if finite.size else (0.0, 1.0)
    yl = f"relative expanded uncertainty, k = {fmt(k)} (%)"

    def layers(h: Any, color: str, label: str) -> list[Any]:
        y = rel.sel(height=h).values
        f = flag.sel(height=h).values
        ok = np.where(f == 0, y, np.nan)
        thin = (f == 1) & np.isfinite(y)
        curve = hv.Curve((ws, ok), "wind_speed", "U", label=label)
        dots = hv.Scatter((ws[f == 0], y[f == 0]), "wind_speed", "U", label=label)
        thin_pts = hv.Scatter((ws[thin], y[thin]), "wind_speed", "U", label="thin bin (too few periods)")
        return [
            curve.opts(line_width=2, color=color, backend="bokeh").opts(color=color, backend="matplotlib"),
            dots.opts(size=5, color=color, backend="bokeh").opts(s=12, color=color, backend="matplotlib"),
            thin_pts.opts(marker="x", size=11, line_width=2, color=_THIN, backend="bokeh")
            .opts(marker="X", s=60, color=_THIN, backend="matplotlib"),
        ]

    colors = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
              "#17becf", "#000000"]
    heights = budget.height.values
    all_layers = []
    for i, h in enumerate(heights):
        lay = layers(h, colors[i % len(colors)], f"{fmt(h)} m")
        all_layers += lay[:2] + ([lay[2].relabel("thin bin (too few periods)")] if i == 0 else [lay[2]])
    title = f"Expanded uncertainty (k = {fmt(k)}), {budget.attrs.get('approach', '')} approach".rstrip(", ")
    everything = _style(hv.Overlay(all_layers).opts(ylim=ylim), f"{title}, all heights", xl, yl)
    panels = {"all heights": everything}
    for h in heights:
        panels[f"{fmt(h)} m"] = _style(hv.Overlay(layers(h, "#1f77b4", "bins with enough periods"))
                                       .opts(ylim=ylim), f"{title}, {fmt(h)} m", xl, yl)
    out = {"budget": Figure(
        f"Expanded uncertainty (k = {fmt(k)}) vs wind speed", panels, kind="select", png=everything,
        note="<p>Red crosses: thin bins (fewer periods than the minimum); they are kept in the budget "
             "but left out of the certificate's headline range. Empty bins are not drawn.</p>",
    )}
    contrib = budget["relative_contribution"]
    names = [str(c).replace("_", " ") for c in contrib.contributor.values]
    cpanels = {}
    for h in heights:
        ok = flag.sel(height=h).values == 0
        rows = []
        for j, w in enumerate(ws):
            if not ok[j]:
                continue
            for c, name in zip(contrib.contributor.values, names, strict=True):
                rows.append((fmt(w), name, float(contrib.sel(height=h, wind_speed=w, contributor=c))))
            combined = budget["relative_uncertainty"].sel(height=h, wind_speed=w)
            rows.append((fmt(w), "combined", float(combined)))
        bars = hv.Bars(rows, ["wind_speed", "contributor"], "u").opts(
            tools=["hover"], xrotation=90, multi_level=False, show_legend=True, backend="bokeh")
        bars = bars.opts(xrotation=90, multi_level=False, show_legend=True, backend="matplotlib")
        cpanels[f"{fmt(h)} m"] = _style(bars, f"Standard uncertainty contributors at {fmt(h)} m", xl,
                                        "relative standard uncertainty (%)", width=_WIDTH + 140)
    default = f"{fmt(float(budget.height.sel(height=120.0, method='nearest')))} m"
    out["budget_contributors"] = Figure(
        "Uncertainty contributors per height", cpanels, kind="select", default=default,
        png=lambda: _contributors_png(budget),
        note="<p>Relative standard uncertainty (k = 1) of each contributor per wind-speed bin with enough "
             "periods; <em>combined</em> is their root sum of squares.</p>",
    )
    return out


def _contributors_png(budget: xr.Dataset) -> Any:
    """All heights' contributors as grouped bars, drawn with matplotlib (HoloViews' bars are slow)."""
    import matplotlib.pyplot as plt

    heights = budget.height.values
    ncol = 2
    nrow = int(np.ceil(len(heights) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(13, 2.8 * nrow), squeeze=False, sharey=True)
    names = [str(c).replace("_", " ") for c in budget.contributor.values] + ["combined"]
    for ax, h in zip(axes.flat, heights, strict=False):
        ok = budget["bin_flag"].sel(height=h).values == 0
        ws = budget.wind_speed.values[ok]
        values = np.concatenate(
            [budget["relative_contribution"].sel(height=h).values[ok].T,
             budget["relative_uncertainty"].sel(height=h).values[ok][None, :]])
        step = float(np.median(np.diff(budget.wind_speed.values))) if budget.sizes["wind_speed"] > 1 else 1.0
        width = 0.8 * step / len(names)
        for i, (name, v) in enumerate(zip(names, values, strict=True)):
            ax.bar(ws + (i - (len(names) - 1) / 2) * width, v, width, label=name)
        ax.set_title(f"{fmt(h)} m", fontsize=10)
        ax.set_xlabel(f"reference wind speed bin{_units(budget.wind_speed)}", fontsize=9)
        ax.set_ylabel("relative std. uncertainty (%)", fontsize=9)
    for ax in axes.flat[len(heights):]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=8, ncol=len(names), loc="lower left", bbox_to_anchor=(0, 1.15))
    fig.suptitle("Standard uncertainty contributors per height (bins with enough periods)")
    fig.tight_layout()
    return fig


def report_figures(
    *,
    budget: xr.Dataset | None = None,
    sensitivities: Iterable[xr.Dataset] | Mapping[str, xr.Dataset] = (),
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
) -> dict[str, Figure]:
    """Build the report's :class:`Figure` for every component given, by figure name, in page order.

    The budget comes first (what an engineer reads first), then the sensitivities, the bench
    cube and the range-weighting function.
    """
    _hv()
    sens = list(sensitivities.values()) if isinstance(sensitivities, Mapping) else list(sensitivities)
    figs: dict[str, Figure] = {}
    if budget is not None:
        figs.update(_budget_plots(budget))
    if sens:
        figs.update(_sensitivity_plots(sens))
    if cube is not None:
        figs.update(_cube_plots(cube))
    if rwf is not None:
        figs.update(_rwf_plots(rwf))
    if not figs:
        raise InputError("nothing to report: give a certificate, a budget, sensitivities, a cube or an RWF")
    return figs


def _from_certificate(cert: xr.Dataset) -> dict[str, Any]:
    parts: dict[str, Any] = {"sensitivities": []}
    for comp in components(cert):
        ds = extract_component(cert, comp["name"])
        if comp["name"].startswith("sensitivity_"):
            parts["sensitivities"].append(ds)
        elif comp["name"] in ("budget", "cube", "rwf"):
            parts[comp["name"]] = ds
    return parts


def _summary_rows(meta: xr.Dataset | None, budget: xr.Dataset | None) -> list[tuple[str, str]]:
    rows = []
    if meta is not None:
        for key, label in (
            ("lidar_serial", "Lidar serial"),
            ("title", "Title"),
            ("id", "Certificate id"),
            ("date_created", "Created"),
            ("lidarcal_version", "lidarcal version"),
            ("certificate_components", "Components"),
            ("zero_distance_m", "Zero distance Zd (m)"),
        ):
            if key in meta.attrs:
                rows.append((label, fmt(meta.attrs[key]) if key.endswith("_m") else str(meta.attrs[key])))
        chain = meta.attrs.get("lidarcal_provenance_chain")
        if chain:
            for item in json.loads(chain):
                rows.append(
                    (f"Input: {item.get('role')}", f"{item.get('file')}  sha256 {item.get('sha256')}")
                )
    # the headline: bins flagged ok, centres 4-16 m/s (certificate.headline_range, as `lidarcal table`)
    rng = headline_range(budget) if budget is not None else None
    if rng is not None:
        lo, hi = HEADLINE_WIND_SPEEDS
        rows.append(
            (
                f"Expanded uncertainty (k = {float(budget.attrs.get('coverage_factor', 2)):g}), "
                f"bins with enough samples, {lo:g} to {hi:g} m/s",
                f"{rng[0]:.2f} % to {rng[1]:.2f} %",
            )
        )
    return rows


def write_report(
    path: str | os.PathLike,
    *,
    certificate: xr.Dataset | None = None,
    budget: xr.Dataset | None = None,
    sensitivities: Iterable[xr.Dataset] | Mapping[str, xr.Dataset] = (),
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
    title: str | None = None,
    png: bool = True,
    overwrite: bool = False,
    allow_invalid: bool = False,
) -> dict[str, Any]:
    """Write the offline HTML report (and PNGs next to it).

    With ``certificate`` the components are taken from it; explicit arguments override them.
    A certificate read from a file has its seal checked first
    (:func:`lidarcal.seal.require_valid_seal`): an altered one is refused
    (:class:`~lidarcal.errors.SealError`), or with ``allow_invalid`` reported under a
    warning banner.

    Returns
    -------
    dict
        ``{"html": Path, "figures": [names], "png": [Paths]}``.
    """
    seal = require_valid_seal(certificate, allow_invalid=allow_invalid) if certificate is not None else None
    banner = invalid_seal_banner(seal) if seal is not None and not seal.ok else None
    hv = _hv()
    parts: dict[str, Any] = (
        _from_certificate(certificate) if certificate is not None else {"sensitivities": []}
    )
    for name, value in (("budget", budget), ("cube", cube), ("rwf", rwf)):
        if value is not None:
            parts[name] = value
    sens = list(sensitivities.values()) if isinstance(sensitivities, Mapping) else list(sensitivities)
    if sens:
        parts["sensitivities"] = sens
    figs = report_figures(**parts)
    path = Path(path)
    pngs = {name: path.with_name(f"{path.stem}_{name}.png") for name in figs} if png else {}
    for p in [path, *pngs.values()]:
        check_writable(p, overwrite=overwrite)

    title = title or (
        certificate.attrs.get("title") if certificate is not None else "lidarcal calibration report"
    )
    rows = _summary_rows(certificate, parts.get("budget"))
    table = "\n".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in rows)
    models = {name: fig.bokeh() for name, fig in figs.items()}
    links = {name: f'<p class="png"><a href="{p.name}">static PNG</a></p>' for name, p in pngs.items()}
    after = {name: fig.note + links.get(name, "") for name, fig in figs.items()}
    warning = f'<p class="invalid"><strong>{html.escape(banner)}</strong></p>\n' if banner else ""
    page = offline_html(models, title=title, header=f"{warning}<table>\n{table}\n</table>", after=after,
                        titles={name: fig.heading for name, fig in figs.items()})
    written = []
    if png:
        renderer = hv.renderer("matplotlib").instance(dpi=_PNG_DPI)
        for name, fig in figs.items():
            with atomic_path(pngs[name], overwrite=overwrite) as tmp:
                obj = fig.png_object()
                if hasattr(obj, "savefig"):  # a matplotlib figure
                    obj.savefig(tmp.with_suffix(".png"), dpi=_PNG_DPI, format="png")
                    import matplotlib.pyplot as plt

                    plt.close(obj)
                else:
                    renderer.save(obj, str(tmp.with_suffix("")), fmt="png")
                tmp.with_suffix(".png").replace(tmp)
            written.append(pngs[name])
    write_text(path, page, overwrite=overwrite)
    return {"html": path, "figures": list(figs), "png": written}
