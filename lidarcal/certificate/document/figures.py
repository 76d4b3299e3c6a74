"""The figures of the certificate's documents, drawn with matplotlib on a given Figure.

One small function per figure (:data:`DRAWERS`, :func:`draw`), each drawing the data its
:mod:`lidarcal.certificate.document.figure_data` function prepares (the HTML report's bokeh figures draw
the same records): the budget's expanded uncertainty on the certified range (bins outside it
drawn apart, in their own panel, never setting the axes), its contributors, each sensitivity
with its regression and 95 % confidence band, their significance (Eq. 12), the bench cube's
heatmaps (colour scale from the CNR bins the simulation drew from) and the RWF with its zero
distance.  The PDF's pages (:mod:`lidarcal.certificate.document.pages`) and the HTML report's static PNGs
are the same drawings, in the same style (:data:`STYLE`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import DEFAULT_CERTIFIED_RANGE
from lidarcal.certificate.document.facts import fmt
from lidarcal.certificate.document.figure_data import (
    CubeData,
    budget_data,
    contributors_data,
    cube_data,
    drawn_cnr_range,
    rwf_data,
    sensitivity_data,
    significance_data,
)
from lidarcal.certificate.layout import components, extract_component
from lidarcal.readback import read_attr

__all__ = [
    "A4",
    "FONT",
    "STYLE",
    "DRAWERS",
    "draw",
    "figure_names",
    "parts_of",
    "draw_budget",
    "draw_contributors",
    "draw_sensitivity",
    "draw_significance",
    "draw_cube",
    "draw_rwf",
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
#: (type 42) where a page needs them (:mod:`lidarcal.certificate.document.pages`), so that the PDF's text
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


def draw_budget(fig, budget: xr.Dataset, wind_speeds: tuple[float, float] = DEFAULT_CERTIFIED_RANGE) -> None:
    """U (k = 2) per height on the certified bins, ± numerical tolerance; the others in their own panel."""
    d = budget_data(budget, wind_speeds)
    k, ws, val, cert, tol, step = d.k, d.wind_speed, d.value, d.certified, d.tolerance, d.step
    top, bottom = _axes(fig, 2, 1, height_ratios=[2.2, 1], top=0.9, bottom=0.1, hspace=0.45, right=0.8)
    for j, h in enumerate(d.height):
        c = _COLORS[j % len(_COLORS)]
        y = np.where(cert[:, j], val[:, j], np.nan)
        if tol is not None:  # JCGM 101 7.9: how far each value has settled
            top.errorbar(ws, y, yerr=np.where(cert[:, j], tol[:, j], np.nan), fmt="-o", color=c, ms=3, lw=1.5,
                         elinewidth=1.2, capsize=2.5, label=f"{fmt(h)} m")
        else:
            top.plot(ws, y, "-o", color=c, ms=3, lw=1.5, label=f"{fmt(h)} m")
        apart = d.apart[:, j]
        bottom.plot(ws[apart], val[apart, j], "x", color=c, ms=4, label=f"{fmt(h)} m")
    certified_values = val[cert] + (np.nan_to_num(tol[cert]) if tol is not None else 0)  # with its bar
    finite = certified_values[np.isfinite(certified_values)]
    top.set_xlim(d.held[0] - step / 2, d.held[1] + step / 2)
    top.set_ylim(0, float(finite.max()) * 1.15 if finite.size else 1.0)
    bars = "; bars: ± numerical tolerance (Monte Carlo)" if tol is not None else ""
    _small(
        top,
        f"Relative expanded uncertainty (k = {k:g}) of the certified bins ({fmt(d.held[0])} to "
        f"{fmt(d.held[1])} m/s, settled{bars})",
        f"reference wind speed bin{d.wind_speed_units}",
        f"U, k = {k:g} (%)",
    )
    top.legend(
        fontsize=FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1), title="height", title_fontsize=FONT
    )
    if bottom.lines and any(line.get_xdata().size for line in bottom.lines):
        from matplotlib.ticker import NullLocator

        bottom.set_yscale("log")
        bottom.yaxis.set_minor_locator(NullLocator())  # minor ticks of a log axis: dozens of texts
    bottom.axvspan(*d.range_limits, color="0.9", zorder=0)
    _small(
        bottom,
        f"Not certified: bins outside {wind_speeds[0]:g} to {wind_speeds[1]:g} m/s (grey: inside), with "
        "too few periods or not settled (own scale)",
        f"reference wind speed bin{d.wind_speed_units}",
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

    d = contributors_data(budget, wind_speeds)
    names, heights, ws = d.names, d.height, d.wind_speed
    ncol = 1 if len(heights) <= 8 else 2
    nrow = int(np.ceil(len(heights) / ncol))
    axes = _axes(fig, nrow, ncol, sharex=True, sharey=True, top=0.9, bottom=0.1, hspace=0.25)
    width = 0.85 * d.step / len(names)
    xlim = (d.held[0] - 0.6 * d.step, d.held[1] + 0.6 * d.step)
    points = axes[0].get_position().width * fig.get_figwidth() * 72 / (xlim[1] - xlim[0])  # points per m/s
    for j, (ax, h) in enumerate(zip(axes, heights, strict=False)):
        ok = d.certified[:, j]
        for i, v in enumerate(d.values[ok, j, :].T):
            # bars as one line collection each (butt caps, width in points): ~1,000 rectangles are slow
            ax.vlines(ws[ok] + (i - (len(names) - 1) / 2) * width, 0, v, color=_COLORS[i % 10],
                      linewidth=0.9 * points * width, capstyle="butt")
        ax.set_ylabel(f"{fmt(h)} m\nu (%)")
    axes[0].set_xlim(*xlim)
    axes[0].set_ylim(bottom=0)
    for ax in axes[len(heights):]:
        ax.set_visible(False)
    for ax in axes[len(heights) - ncol:len(heights)]:
        ax.set_xlabel(f"wind speed bin{d.wind_speed_units}")
    fig.legend(handles=[Patch(color=_COLORS[i % 10], label=n) for i, n in enumerate(names)],
               loc="upper center", bbox_to_anchor=(0.5, 0.945), ncol=min(len(names), 6), fontsize=FONT - 1,
               frameon=False)
    fig.suptitle("Relative standard uncertainty (k = 1) of each contributor, certified bins",
                 fontsize=FONT + 3, y=0.985)


def draw_sensitivity(fig, ds: xr.Dataset) -> None:
    """Bin means (± s.e.), the regression and its 95 % band, one panel per height."""
    d = sensitivity_data(ds)
    axes = _axes(fig, int(np.ceil(len(d.heights) / 2)), 2, top=0.9, bottom=0.1, hspace=0.7)
    for ax, one in zip(axes, d.heights, strict=False):
        ax.errorbar(one.x, one.y, yerr=one.sem, fmt="o", color="black", ms=3, lw=0.8, label="bin mean ± s.e.")
        if one.line is not None:
            x, fit, lo, hi = one.line
            ax.fill_between(x, lo, hi, color="#1f77b4", alpha=0.25, lw=0, label="95 % band")
            ax.plot(x, fit, color="#1f77b4", lw=1.5, label="regression")
        _small(
            ax,
            f"{fmt(one.height)} m: m = {fmt(one.slope)} ± {fmt(one.slope_standard_error)} {d.slope_units}, "
            f"R = {fmt(one.correlation, 2)}",
            f"{d.readable}{d.bin_units}",
            f"lidar – ref.{d.difference_units}",
        )
    for ax in axes[len(d.heights) :]:
        ax.set_visible(False)
    axes[0].legend(fontsize=FONT - 1)
    fig.suptitle(f"Sensitivity to {d.readable}", fontsize=FONT + 3)


def draw_significance(fig, sens: Iterable[xr.Dataset]) -> None:
    """Eq. 12 statistic m·std per height for every variable, against the ±0.5 % threshold."""
    d = significance_data(sens)
    ax = _axes(fig, 1, 1, top=0.85, bottom=0.15, right=0.75)[0]
    for i, (name, h, y) in enumerate(d.variables):
        ax.plot(h, y, "-o", ms=3, color=_COLORS[i % 10], label=name)
    for s in (0.5, -0.5):
        ax.axhline(s, color="grey", ls="--", lw=0.8)
    ax.set_ylim(-d.limit, d.limit)
    ax.legend(fontsize=FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1))
    _small(ax, "Significance (Eq. 12): m · std per height; threshold ±0.5 %", "height (m)", "m · std (%)")


def _heatmap(ax, d: CubeData, i: int, cmap: str) -> Any:
    """Draw line of sight ``i``'s heatmap: an image on a regular grid (cheap in a PDF), else a mesh."""
    vmin, vmax = d.limits
    if d.regular:
        return ax.imshow(d.values[i], origin="lower", extent=d.extent, aspect="auto", interpolation="nearest",
                         cmap=cmap, vmin=vmin, vmax=vmax)
    return ax.pcolormesh(d.velocity, d.cnr, d.values[i], cmap=cmap, vmin=vmin, vmax=vmax, shading="nearest")


def draw_cube(fig, cube: xr.Dataset, name: str, drawn: tuple[float, float] | None = None) -> None:
    """CNR × programmed velocity heatmaps of ``los_bias`` or ``los_std``, one per line of sight."""
    d = cube_data(cube, name, drawn)
    n = len(d.los_labels)
    axes = _axes(fig, int(np.ceil(n / 2)), 2, top=0.87, bottom=0.1, right=0.86, hspace=0.6,
                 sharex=True, sharey=True)
    mesh = None
    for i, (ax, label) in enumerate(zip(axes, d.los_labels, strict=False)):
        ax.grid(False)  # a heatmap fills its axes: grid lines would cross the cells
        mesh = _heatmap(ax, d, i, "RdBu_r" if d.symmetric else "viridis")
        if drawn is not None:
            for y in drawn:
                ax.axhline(y, color="black", lw=0.8, ls=":")
        _small(ax, label, f"programmed radial velocity{d.velocity_units}", f"CNR{d.cnr_units}")
    for ax in axes[n:]:
        ax.set_visible(False)
    if mesh is not None:
        cax = fig.add_axes([0.89, 0.3, 0.02, 0.4])
        fig.colorbar(mesh, cax=cax, extend="both").set_label(d.label, fontsize=FONT)
    what = (
        "mean LOS velocity error (measured – programmed)"
        if d.symmetric
        else "standard deviation of the measured LOS velocity"
    )
    scale = (
        f"colour scale: 99th percentile of the CNR bins the simulation draws from ({fmt(drawn[0])} to "
        f"{fmt(drawn[1])} dB, dotted lines)"
        if drawn
        else "colour scale: 99th percentile of all bins"
    )
    fig.suptitle(f"Bench: {what}\n{scale}\nblank cells had no bench samples", fontsize=FONT + 2)


def draw_rwf(fig, rwf: xr.Dataset) -> None:
    """Pulse, apodization and RWF (normalised) with Zd; the RWF for a few CNR gradients."""
    d = rwf_data(rwf)
    a, b = _axes(fig, 2, 1, top=0.92, bottom=0.1, right=0.78, hspace=0.35)
    for name, y in d.shapes.items():
        a.plot(d.x, y, label=name)
    a.legend(fontsize=FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1))
    _small(
        a,
        f"Pulse, apodization and RWF (normalised), Zd = {fmt(d.zero_distance)} m",
        "range offset from gate centre (m)",
        "normalised amplitude",
    )
    for label, y in d.gradients:
        b.plot(d.x, y, label=label)
    b.legend(
        fontsize=FONT - 1,
        loc="upper left",
        bbox_to_anchor=(1.01, 1),
        title="CNR gradient",
        title_fontsize=FONT,
    )
    _small(b, "RWF for several CNR gradients (Eq. 2)", "range offset from gate centre (m)",
           f"RWF{d.rwf_units}")


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
        var = read_attr(ds, "environmental_variable", kind="sensitivity", default="variable")
        names.append(f"sensitivity_{var}")
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
            d for d in parts["sensitivities"]
            if read_attr(d, "environmental_variable", kind="sensitivity", default="variable") == var
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
    summary = read_attr(cert, "lidarcal_records_summary", kind="certificate")
    if parts.get("cube") is not None and summary:
        parts["drawn_cnr"] = drawn_cnr_range(parts["cube"], summary)
    return parts
