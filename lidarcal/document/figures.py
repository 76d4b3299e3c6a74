"""The figures of the certificate's documents, drawn with matplotlib on a given Figure.

One small function per figure (:data:`DRAWERS`, :func:`draw`): the budget's expanded
uncertainty on the certified range (bins outside it drawn apart, in their own panel, never
setting the axes), its contributors, each sensitivity with its regression and 95 % confidence
band (:func:`confidence_band`), their significance (Eq. 12), the bench cube's heatmaps (colour
scale from the CNR bins the simulation drew from, :func:`drawn_cnr_range`) and the RWF with its
zero distance.  The PDF's pages (:mod:`lidarcal.document.pages`) and the HTML report's static
PNGs are the same drawings, in the same style (:data:`STYLE`).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import DEFAULT_CERTIFIED_RANGE
from lidarcal.certificate import components, extract_component
from lidarcal.document.facts import VARIABLE_NAMES, certified_grid, certified_rows, fmt, units_suffix

__all__ = [
    "A4",
    "FONT",
    "STYLE",
    "DRAWERS",
    "draw",
    "figure_names",
    "parts_of",
    "confidence_band",
    "drawn_cnr_range",
    "cube_colour_limits",
    "draw_budget",
    "draw_contributors",
    "draw_sensitivity",
    "draw_significance",
    "draw_cube",
    "draw_rwf",
    "bin_means",
    "rwf_window",
]

A4 = (8.27, 11.69)  # inches, portrait
#: The documents' font size (pt).
FONT = 8.0
_COLORS = [
    "#1f77b4",
    "#ff7f0e",
    "#2ca02c",
    "#d62728",
    "#9467bd",
    "#8c564b",
    "#e377c2",
    "#7f7f7f",
    "#bcbd22",
    "#17becf",
]


def _axes(
    fig,
    nrows: int,
    ncols: int,
    *,
    top: float = 0.9,
    bottom: float = 0.1,
    left: float = 0.1,
    right: float = 0.96,
    hspace: float = 0.55,
    wspace: float = 0.3,
    **kw,
) -> list:
    axes = fig.subplots(
        nrows,
        ncols,
        squeeze=False,
        gridspec_kw=dict(top=top, bottom=bottom, left=left, right=right, hspace=hspace, wspace=wspace),
        **kw,
    )
    return list(axes.flat)


#: The documents' matplotlib style: sizes and grid from rcParams (``ax.tick_params`` after
#: the fact re-styles every tick, which was a good part of the PDF's cost), TrueType fonts
#: (type 42) where a page needs them (:mod:`lidarcal.document.pages`), so that the PDF's text
#: can be searched and extracted, and ASCII minus signs in tick labels (the standard PDF fonts'
#: encoding has no U+2212).
STYLE = {
    "pdf.fonttype": 42,
    "axes.unicode_minus": False,
    "font.size": FONT,
    "axes.titlesize": FONT + 1,
    "axes.labelsize": FONT,
    "xtick.labelsize": FONT - 1,
    "ytick.labelsize": FONT - 1,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "legend.fontsize": FONT - 1,
}


def _small(ax, title: str, xlabel: str, ylabel: str) -> None:
    # a title at a fixed height: matplotlib otherwise measures the axis's tick labels to place it
    # (a tenth of a page's cost); no axis here has ticks on top
    ax.set_title(title, y=1.0, pad=4)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    from matplotlib.ticker import MaxNLocator

    for axis in (ax.xaxis, ax.yaxis):  # fewer ticks: each tick label is a text to lay out
        if isinstance(axis.get_major_locator(), MaxNLocator):
            axis.get_major_locator().set_params(nbins=4)


def _extent(g: Mapping[str, Any], wind_speeds: tuple[float, float], step: float) -> tuple[float, float]:
    """Return the x limits of the certified values' bins (the range when none), half a bin beyond."""
    rows = certified_rows(g)
    lo, hi = (g["wind_speed"][rows[0]], g["wind_speed"][rows[-1]]) if rows.size else wind_speeds
    return float(lo) - step / 2, float(hi) + step / 2


def draw_budget(fig, budget: xr.Dataset, wind_speeds: tuple[float, float] = DEFAULT_CERTIFIED_RANGE) -> None:
    """U (k = 2) per height on the certified bins, ± numerical tolerance; the others in their own panel."""
    g = certified_grid(budget, wind_speeds)
    k = float(budget.attrs.get("coverage_factor", 2.0))
    ws, val, cert, tol = g["wind_speed"], g["value"], g["certified"], g["tolerance"]
    top, bottom = _axes(fig, 2, 1, height_ratios=[2.2, 1], top=0.9, bottom=0.1, hspace=0.45, right=0.8)
    step = float(np.median(np.diff(ws))) if ws.size > 1 else 1.0
    for j, h in enumerate(g["height"]):
        c = _COLORS[j % len(_COLORS)]
        y = np.where(cert[:, j], val[:, j], np.nan)
        if tol is not None:  # JCGM 101 7.9: how far each value has settled
            top.errorbar(ws, y, yerr=np.where(cert[:, j], tol[:, j], np.nan), fmt="-o", color=c, ms=3, lw=1.5,
                         elinewidth=1.2, capsize=2.5, label=f"{fmt(h)} m")
        else:
            top.plot(ws, y, "-o", color=c, ms=3, lw=1.5, label=f"{fmt(h)} m")
        apart = ~cert[:, j] & np.isfinite(val[:, j])
        bottom.plot(ws[apart], val[apart, j], "x", color=c, ms=4, label=f"{fmt(h)} m")
    certified_values = val[cert] + (np.nan_to_num(tol[cert]) if tol is not None else 0)  # with its bar
    finite = certified_values[np.isfinite(certified_values)]
    top.set_xlim(*_extent(g, wind_speeds, step))
    top.set_ylim(0, float(finite.max()) * 1.15 if finite.size else 1.0)
    lo, hi = _extent(g, wind_speeds, step)
    bars = "; bars: ± numerical tolerance (Monte Carlo)" if tol is not None else ""
    _small(
        top,
        f"Relative expanded uncertainty (k = {k:g}) of the certified bins ({fmt(lo + step / 2)} to "
        f"{fmt(hi - step / 2)} m/s, settled{bars})",
        f"reference wind speed bin{units_suffix(budget.wind_speed)}",
        f"U, k = {k:g} (%)",
    )
    top.legend(
        fontsize=FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1), title="height", title_fontsize=FONT
    )
    if bottom.lines and any(line.get_xdata().size for line in bottom.lines):
        from matplotlib.ticker import NullLocator

        bottom.set_yscale("log")
        bottom.yaxis.set_minor_locator(NullLocator())  # minor ticks of a log axis: dozens of texts
    bottom.axvspan(wind_speeds[0] - step / 2, wind_speeds[1] + step / 2, color="0.9", zorder=0)
    _small(
        bottom,
        f"Not certified: bins outside {wind_speeds[0]:g} to {wind_speeds[1]:g} m/s (grey: inside), with "
        "too few periods or not settled (own scale)",
        f"reference wind speed bin{units_suffix(budget.wind_speed)}",
        f"U, k = {k:g} (%)",
    )


def draw_contributors(
    fig, budget: xr.Dataset, wind_speeds: tuple[float, float] = DEFAULT_CERTIFIED_RANGE
) -> None:
    """Standard-uncertainty contributors per height as grouped bars, certified bins only.

    One full-width panel per height (two columns beyond eight heights), the bins of the
    certified values only, so that each bar is a few points wide; one legend for the page,
    whatever the panels hold.
    """
    from matplotlib.patches import Patch

    g = certified_grid(budget, wind_speeds)
    b = budget.transpose("wind_speed", "height", ...)
    names = [str(c).replace("_", " ") for c in b.contributor.values] + ["combined"]
    heights = g["height"]
    ncol = 1 if len(heights) <= 8 else 2
    nrow = int(np.ceil(len(heights) / ncol))
    axes = _axes(fig, nrow, ncol, sharex=True, sharey=True, top=0.9, bottom=0.1, hspace=0.25)
    ws = g["wind_speed"]
    step = float(np.median(np.diff(ws))) if ws.size > 1 else 1.0
    width = 0.85 * step / len(names)
    xlim = _extent(g, wind_speeds, 1.2 * step)
    contrib = b["relative_contribution"].transpose("wind_speed", "height", "contributor").values
    combined = b["relative_uncertainty"].values
    points = axes[0].get_position().width * fig.get_figwidth() * 72 / (xlim[1] - xlim[0])  # points per m/s
    for j, (ax, h) in enumerate(zip(axes, heights, strict=False)):
        ok = g["certified"][:, j]
        values = np.concatenate([contrib[ok, j, :].T, combined[ok, j][None, :]])
        for i, v in enumerate(values):
            # bars as one line collection each (butt caps, width in points): ~1,000 rectangles are slow
            ax.vlines(ws[ok] + (i - (len(names) - 1) / 2) * width, 0, v, color=_COLORS[i % 10],
                      linewidth=0.9 * points * width, capstyle="butt")
        ax.set_ylabel(f"{fmt(h)} m\nu (%)")
    axes[0].set_xlim(*xlim)
    axes[0].set_ylim(bottom=0)
    for ax in axes[len(heights):]:
        ax.set_visible(False)
    for ax in axes[len(heights) - ncol:len(heights)]:
        ax.set_xlabel(f"wind speed bin{units_suffix(budget.wind_speed)}")
    fig.legend(handles=[Patch(color=_COLORS[i % 10], label=n) for i, n in enumerate(names)],
               loc="upper center", bbox_to_anchor=(0.5, 0.945), ncol=min(len(names), 6), fontsize=FONT - 1,
               frameon=False)
    fig.suptitle("Relative standard uncertainty (k = 1) of each contributor, certified bins",
                 fontsize=FONT + 3, y=0.985)


def confidence_band(
    ds: xr.Dataset, height: Any, x: np.ndarray, level: float = 0.95
) -> tuple[np.ndarray, ...]:
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
    from scipy.special import stdtrit  # the t quantile; scipy.stats costs ~0.4 s more to import

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
    half = stdtrit(n - 2, 0.5 + level / 2) * np.sqrt(scale2 * (1.0 / wb.sum() + (x - xm) ** 2 / sxx))
    return fit, fit - half, fit + half


def bin_means(one: xr.Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return one height's kept bins (``bin_flag`` 0, finite mean): centres, mean differences, s.e.

    The standard error of a bin mean is its standard deviation over the square root of its periods.
    """
    used = (one["bin_flag"] == 0).values & np.isfinite(one["mean_difference"].values)
    sem = one["std_difference"].values / np.sqrt(np.maximum(one["sample_count"].values, 1))
    return one["bin"].values[used], one["mean_difference"].values[used], sem[used]


def draw_sensitivity(fig, ds: xr.Dataset) -> None:
    """Bin means (± s.e.), the regression and its 95 % band, one panel per height."""
    var = str(ds.attrs.get("environmental_variable", "variable"))
    readable = VARIABLE_NAMES.get(var, var.replace("_", " "))
    units = ds["slope"].attrs.get("units", "")
    heights = np.atleast_1d(ds.height.values)
    axes = _axes(fig, int(np.ceil(len(heights) / 2)), 2, top=0.9, bottom=0.1, hspace=0.7)
    for ax, h in zip(axes, heights, strict=False):
        one = ds.sel(height=h)
        xb, yb, sem = bin_means(one)
        ax.errorbar(xb, yb, yerr=sem, fmt="o", color="black", ms=3, lw=0.8, label="bin mean ± s.e.")
        if xb.size >= 2 and np.isfinite(float(one["slope"])):
            x = np.linspace(xb.min(), xb.max(), 40)
            fit, lo, hi = confidence_band(ds, h, x)
            ax.fill_between(x, lo, hi, color="#1f77b4", alpha=0.25, lw=0, label="95 % band")
            ax.plot(x, fit, color="#1f77b4", lw=1.5, label="regression")
        se = float(one["slope_standard_error"]) if "slope_standard_error" in one else np.nan
        _small(
            ax,
            f"{fmt(h)} m: m = {fmt(float(one['slope']))} ± {fmt(se)} {units}, "
            f"R = {fmt(float(one['correlation']), 2)}",
            f"{readable}{units_suffix(ds['bin'])}",
            f"lidar – ref.{units_suffix(ds['mean_difference'])}",
        )
    for ax in axes[len(heights) :]:
        ax.set_visible(False)
    axes[0].legend(fontsize=FONT - 1)
    fig.suptitle(f"Sensitivity to {readable}", fontsize=FONT + 3)


def draw_significance(fig, sens: Iterable[xr.Dataset]) -> None:
    """Eq. 12 statistic m·std per height for every variable, against the ±0.5 % threshold."""
    ax = _axes(fig, 1, 1, top=0.85, bottom=0.15, right=0.75)[0]
    values = []
    for i, ds in enumerate(sens):
        var = str(ds.attrs.get("environmental_variable", "variable"))
        y = np.atleast_1d(ds["slope_times_std"].values)
        values.append(y)
        ax.plot(
            np.atleast_1d(ds.height.values),
            y,
            "-o",
            ms=3,
            color=_COLORS[i % 10],
            label=VARIABLE_NAMES.get(var, var.replace("_", " ")),
        )
    for s in (0.5, -0.5):
        ax.axhline(s, color="grey", ls="--", lw=0.8)
    finite = np.concatenate(values) if values else np.array([])
    finite = finite[np.isfinite(finite)]
    lim = max(0.6, 1.1 * float(np.abs(finite).max())) if finite.size else 0.6
    ax.set_ylim(-lim, lim)
    ax.legend(fontsize=FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1))
    _small(ax, "Significance (Eq. 12): m · std per height; threshold ±0.5 %", "height (m)", "m · std (%)")


def drawn_cnr_range(
    cube: xr.Dataset, records_summary: Mapping[str, Any] | None
) -> tuple[float, float] | None:
    """CNR (dB) span of the cube bins the simulation drew from, from the records' CNR range.

    The virtual lidar interpolates the cube between the two CNR bins around a period's CNR
    (clamped at the ends), so the bins used are those bracketing the records' CNR range;
    None when the certificate does not state that range.
    """
    if not records_summary or "cnr_min_db" not in records_summary:
        return None
    axis = np.sort(np.atleast_1d(cube["cnr"].values).astype(float))
    lo, hi = float(records_summary["cnr_min_db"]), float(records_summary["cnr_max_db"])
    i0 = int(np.clip(np.searchsorted(axis, lo, side="right") - 1, 0, axis.size - 1))
    i1 = int(np.clip(np.searchsorted(axis, hi, side="left"), 0, axis.size - 1))
    return float(axis[i0]), float(axis[i1])


def cube_colour_limits(
    da: xr.DataArray, drawn: tuple[float, float] | None, symmetric: bool
) -> tuple[float, float]:
    """Colour limits of a cube heatmap: the 99th percentile of the bins the simulation draws from.

    All bins when ``drawn`` (dB) is unknown; cells beyond the limits show the end colours.
    """
    used = da if drawn is None else da.where((da["cnr"] >= drawn[0]) & (da["cnr"] <= drawn[1]))
    finite = used.values[np.isfinite(used.values)]
    if not finite.size:
        return (-1.0, 1.0) if symmetric else (0.0, 1.0)
    if symmetric:
        top = float(np.percentile(np.abs(finite), 99))
        return -top, top
    return float(finite.min()), float(np.percentile(finite, 99))


def _heatmap(ax, da: xr.DataArray, cmap: str, vmin: float, vmax: float) -> Any:
    """Draw a (cnr, velocity) heatmap: an image on a regular grid (cheap in a PDF), else a mesh."""
    da = da.sortby("cnr").sortby("velocity").transpose("cnr", "velocity")
    x, y = da["velocity"].values.astype(float), da["cnr"].values.astype(float)
    dx, dy = (np.diff(x) if x.size > 1 else np.ones(1)), (np.diff(y) if y.size > 1 else np.ones(1))
    if np.allclose(dx, dx[0]) and np.allclose(dy, dy[0]):
        extent = (x[0] - dx[0] / 2, x[-1] + dx[0] / 2, y[0] - dy[0] / 2, y[-1] + dy[0] / 2)
        return ax.imshow(
            da.values,
            origin="lower",
            extent=extent,
            aspect="auto",
            interpolation="nearest",
            cmap=cmap,
            vmin=vmin,
            vmax=vmax,
        )
    return ax.pcolormesh(x, y, da.values, cmap=cmap, vmin=vmin, vmax=vmax, shading="nearest")


def draw_cube(fig, cube: xr.Dataset, name: str, drawn: tuple[float, float] | None = None) -> None:
    """CNR × programmed velocity heatmaps of ``los_bias`` or ``los_std``, one per line of sight."""
    symmetric = name == "los_bias"
    da = cube[name].transpose("los", "cnr", "velocity")
    vmin, vmax = cube_colour_limits(da, drawn, symmetric)
    los = list(da.los.values)
    axes = _axes(fig, int(np.ceil(len(los) / 2)), 2, top=0.87, bottom=0.1, right=0.86, hspace=0.6,
                 sharex=True, sharey=True)
    mesh = None
    for ax, one in zip(axes, los, strict=False):
        ax.grid(False)  # a heatmap fills its axes: grid lines would cross the cells
        mesh = _heatmap(ax, da.sel(los=one), "RdBu_r" if symmetric else "viridis", vmin, vmax)
        if drawn is not None:
            for y in drawn:
                ax.axhline(y, color="black", lw=0.8, ls=":")
        label = f"LOS {one}"
        if "los_azimuth" in cube.coords and str(one).upper() != "V":
            label += f" (azimuth {fmt(cube.los_azimuth.sel(los=one).item())}°)"
        _small(ax, label, f"programmed radial velocity{units_suffix(cube.velocity)}",
               f"CNR{units_suffix(cube.cnr)}")
    for ax in axes[len(los) :]:
        ax.set_visible(False)
    if mesh is not None:
        cax = fig.add_axes([0.89, 0.3, 0.02, 0.4])
        fig.colorbar(mesh, cax=cax, extend="both").set_label(
            f"{name.replace('_', ' ')}{units_suffix(da)}", fontsize=FONT
        )
    what = (
        "mean LOS velocity error (measured – programmed)"
        if symmetric
        else "standard deviation of the measured LOS velocity"
    )
    scale = (
        f"colour scale: 99th percentile of the CNR bins the simulation draws from ({fmt(drawn[0])} to "
        f"{fmt(drawn[1])} dB, dotted lines)"
        if drawn
        else "colour scale: 99th percentile of all bins"
    )
    fig.suptitle(f"Bench: {what}\n{scale}\nblank cells had no bench samples", fontsize=FONT + 2)


def rwf_window(rwf: xr.Dataset) -> tuple[np.ndarray, slice, list[int]]:
    """Return the RWF at zero CNR gradient over its peak, the range offsets drawn and the gradients drawn.

    The offsets span where the RWF exceeds 1e-3 of its peak, padded by a quarter of that span
    (at least 5 points); up to five CNR gradients, evenly spread, are drawn.
    """
    column = rwf["rwf"].sel(cnr_gradient=0.0, method="nearest")
    norm = column.values / float(column.max())
    support = np.flatnonzero(norm > 1e-3)
    n = rwf.sizes["range_offset"]
    lo, hi = (support.min(), support.max()) if support.size else (0, n - 1)
    pad = max(5, (hi - lo) // 4)
    g = rwf["cnr_gradient"].values
    pick = sorted(set(np.linspace(0, len(g) - 1, min(5, len(g))).round().astype(int).tolist()))
    return norm, slice(max(lo - pad, 0), min(hi + pad, n - 1) + 1), pick


def draw_rwf(fig, rwf: xr.Dataset) -> None:
    """Pulse, apodization and RWF (normalised) with Zd; the RWF for a few CNR gradients."""
    zd = float(rwf["zero_distance"]) if "zero_distance" in rwf else float("nan")
    norm, sl, pick = rwf_window(rwf)
    x = rwf["range_offset"].values[sl]
    a, b = _axes(fig, 2, 1, top=0.92, bottom=0.1, right=0.78, hspace=0.35)
    a.plot(x, norm[sl], label="RWF")
    for name in ("pulse", "apodization"):
        if name in rwf:
            a.plot(x, (rwf[name] / float(rwf[name].max())).values[sl], label=name)
    a.legend(fontsize=FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1))
    _small(
        a,
        f"Pulse, apodization and RWF (normalised), Zd = {fmt(zd)} m",
        "range offset from gate centre (m)",
        "normalised amplitude",
    )
    g = rwf["cnr_gradient"].values
    for i in pick:
        b.plot(x, rwf["rwf"].isel(cnr_gradient=i).values[sl], label=f"{fmt(g[i])} dB/m")
    b.legend(
        fontsize=FONT - 1,
        loc="upper left",
        bbox_to_anchor=(1.01, 1),
        title="CNR gradient",
        title_fontsize=FONT,
    )
    _small(
        b,
        "RWF for several CNR gradients (Eq. 2)",
        "range offset from gate centre (m)",
        f"RWF{units_suffix(rwf['rwf'])}",
    )


#: Figure name -> drawer(fig, parts); names match the HTML report's sections.
DRAWERS: dict[str, Callable[..., None]] = {
    "budget": lambda fig, p: draw_budget(fig, p["budget"]),
    "budget_contributors": lambda fig, p: draw_contributors(fig, p["budget"]),
    "sensitivity_slopes": lambda fig, p: draw_significance(fig, p["sensitivities"]),
    "cube_los_bias": lambda fig, p: draw_cube(fig, p["cube"], "los_bias", p.get("drawn_cnr")),
    "cube_los_std": lambda fig, p: draw_cube(fig, p["cube"], "los_std", p.get("drawn_cnr")),
    "rwf": lambda fig, p: draw_rwf(fig, p["rwf"]),
}


def figure_names(parts: Mapping[str, Any]) -> list[str]:
    """List the figures ``parts`` (budget, sensitivities, cube, rwf) can draw, in page order."""
    names = []
    if parts.get("budget") is not None:
        names += ["budget", "budget_contributors"]
    sens = parts.get("sensitivities") or []
    for ds in sens:
        names.append(f"sensitivity_{ds.attrs.get('environmental_variable', 'variable')}")
    if sens:
        names.append("sensitivity_slopes")
    if parts.get("cube") is not None:
        names += [n for n in ("cube_los_bias", "cube_los_std") if n.removeprefix("cube_") in parts["cube"]]
    if parts.get("rwf") is not None:
        names.append("rwf")
    return names


def draw(fig, name: str, parts: Mapping[str, Any]) -> None:
    """Draw figure ``name`` of :func:`figure_names` on ``fig``."""
    if name.startswith("sensitivity_") and name != "sensitivity_slopes":
        var = name.removeprefix("sensitivity_")
        ds = next(
            d for d in parts["sensitivities"] if d.attrs.get("environmental_variable", "variable") == var
        )
        draw_sensitivity(fig, ds)
    else:
        DRAWERS[name](fig, parts)


def parts_of(cert: xr.Dataset) -> dict[str, Any]:
    """Return the components of a certificate a document draws (budget, sensitivities, cube, rwf)."""
    parts: dict[str, Any] = {"sensitivities": []}
    for comp in components(cert):
        name = comp["name"]
        if name.startswith("sensitivity_"):
            parts["sensitivities"].append(extract_component(cert, name))
        elif name in ("budget", "cube", "rwf"):
            parts[name] = extract_component(cert, name)
    summary = cert.attrs.get("lidarcal_records_summary")
    if parts.get("cube") is not None and summary:
        parts["drawn_cnr"] = drawn_cnr_range(parts["cube"], json.loads(summary))
    return parts
