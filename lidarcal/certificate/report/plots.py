"""The HTML report's interactive figures: one plain bokeh model each, built when the page is written.

As available (:func:`report_figures`, in page order):

- the expanded (k = 2) uncertainty vs wind speed (paper Figure 9), the axes set by the
  certified bins (4-16 m/s, enough periods), a menu choosing all heights or one, thin bins
  (fewer periods than ``min_periods``) marked with red crosses;
- the uncertainty contributors as grouped bars per certified wind-speed bin, a menu choosing
  the height;
- the sensitivities (Figure 7): per height (menu) the bin means with the standard error of
  the mean, the regression line and its 95 % confidence band, plus a table of the slopes,
  R and the Eqs. 12-13 statistics rounded to 3 significant digits; and (Figure 8) the Eq. 12
  statistic m·std per height for every variable against the ±0.5 % threshold;
- the bench cube (Figure 5): CNR x programmed velocity heatmaps of the LOS bias and of the
  LOS standard deviation, a menu choosing the line of sight, one colour scale for all, set by
  the CNR bins the simulation draws from;
- the range-weighting function (Figure 6): pulse, apodization and RWF, and the RWF for a few
  CNR gradients, with the zero distance Zd.

A menu shows one height's renderers of a single plot (or copies its columns into the drawn
ones), which keeps the page cheap to write.  Each figure draws the record its
:mod:`lidarcal.certificate.document.figure_data` function prepares, the one the PDF draws too; numbers and
words are those of the PDF (:mod:`lidarcal.certificate.document.facts`).
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate.document.facts import fmt
from lidarcal.certificate.document.figure_data import (
    budget_data,
    contributors_data,
    cube_data,
    rwf_data,
    sensitivity_data,
    significance_data,
)
from lidarcal.errors import InputError
from lidarcal.htmlpage import COLORS, html_table, legend_outside, plot
from lidarcal.readback import read_attr

__all__ = ["Figure", "report_figures"]

_WIDTH = 900
_THIN = "#d62728"  # marker colour of thin bins (fewer periods than min_periods)


@dataclass
class Figure:
    """One report figure: its heading, its bokeh model and a note (HTML) shown below it.

    ``build`` makes the bokeh model when the page is written (:meth:`bokeh`).  A figure with
    a menu (``select``) is a column of a :class:`bokeh.models.Select` and one plot whose
    renderers are grouped by the menu's labels (``name`` = label): choosing a label shows
    its renderers only.
    """

    heading: str
    build: Any
    note: str = ""

    def bokeh(self) -> Any:
        """Return the page's bokeh model.

        Its renderers draw no selected/unselected or muted variants (no figure has a selection
        tool or a "mute" legend): bokeh would otherwise add two glyphs to each renderer, and
        every model is written to the page and serialised (most of the HTML report's cost).
        """
        from bokeh.models import GlyphRenderer, Plot

        model = self.build()
        # the model is a plot or a column of a menu and a plot: their renderers are found
        # directly (model.select would walk every model of the figure, a tenth of its cost)
        for p in (model, *getattr(model, "children", ())):
            for r in p.renderers if isinstance(p, Plot) else ():
                if isinstance(r, GlyphRenderer):
                    r.nonselection_glyph = None
                    r.muted_glyph = None
        return model


def _menu(p: Any, groups: Mapping[str, list], shown: str, titles: Mapping[str, str]) -> Any:
    """Add a drop-down above ``p`` choosing which group of its renderers is shown (and the title)."""
    from bokeh.layouts import column
    from bokeh.models import CustomJS, Select

    for r in p.renderers:
        r.visible = r in groups[shown]
    p.title.text = titles[shown]
    select = Select(title="Show:", value=shown, options=list(groups), width=220)
    select.js_on_change("value", CustomJS(
        args={"groups": dict(groups), "all": list(p.renderers), "plot": p, "titles": dict(titles)},
        code="const on = new Set(groups[cb_obj.value]);"
             "all.forEach((r) => { r.visible = on.has(r); });"
             "plot.title.text = titles[cb_obj.value];"))
    return column(select, p)


def _by_name(p: Any) -> dict[str, list]:
    groups: dict[str, list] = {}
    for r in p.renderers:
        groups.setdefault(r.name, []).append(r)
    return groups


def _wind_speed_label(units: str) -> str:
    return f"reference wind speed bin{units}"


def _budget_figure(budget: xr.Dataset) -> Figure:
    """Plot U (k = 2) per height on the certified range (menu: all heights or one), thin bins marked."""
    d = budget_data(budget)
    k, heights = d.k, d.height
    # the axes show the certified bins (flag ok, 4-16 m/s); the others stay reachable by panning
    certified = d.value[d.certified]
    ylim = (0.0, float(certified.max()) * 1.15) if certified.size else (0.0, 1.0)
    yl = f"relative expanded uncertainty, k = {fmt(k)} (%)"
    title = f"Expanded uncertainty (k = {fmt(k)}), {d.approach} approach".rstrip(", ")
    labels = ["all heights", *[f"{fmt(h)} m" for h in heights]]

    def build() -> Any:
        from bokeh.models import ColumnDataSource

        p = plot(f"{title}, all heights", _wind_speed_label(d.wind_speed_units), yl, x_range=d.range_limits,
                 y_range=ylim)
        # one source (and view) for every height's columns: a source per renderer is 4 more models
        data: dict[str, np.ndarray] = {"wind_speed": d.wind_speed}
        for j, h in enumerate(heights):
            y = d.value[:, j]
            data[f"U|{fmt(h)} m"] = np.where(d.kept[:, j], y, np.nan)
            data[f"thin|{fmt(h)} m"] = np.where(d.thin[:, j], y, np.nan)
            if d.not_settled[:, j].any():  # a column only where a bin did not settle: no empty renderers
                data[f"missed|{fmt(h)} m"] = np.where(d.not_settled[:, j], y, np.nan)
        src, view = ColumnDataSource(data), None
        for i, h in enumerate(heights):
            color, name = COLORS[i % len(COLORS)], f"{fmt(h)} m"
            renderers = [
                p.line("wind_speed", f"U|{name}", source=src, color=color, line_width=2, legend_label=name,
                       name=name, **({"view": view} if view else {})),
                p.scatter("wind_speed", f"U|{name}", source=src, color=color, size=5, legend_label=name,
                          name=name),
                p.scatter("wind_speed", f"thin|{name}", source=src, marker="x", size=11, line_width=2,
                          color=_THIN, legend_label="thin bin (too few periods)", name=name),
            ]
            if f"missed|{name}" in data:
                renderers.append(p.scatter("wind_speed", f"missed|{name}", source=src, marker="triangle",
                                           size=9, color=_THIN, fill_alpha=0.2,
                                           legend_label="not settled (Monte Carlo)", name=name))
            for r in renderers:
                view = view or r.view
                r.view = view
        legend_outside(p, "none")
        groups = {"all heights": list(p.renderers), **_by_name(p)}
        return _menu(p, groups, "all heights", {lab: f"{title}, {lab}" for lab in labels})

    return Figure(
        f"Expanded uncertainty (k = {fmt(k)}) vs wind speed", build,
        note="<p>The axes show the certified bins (enough periods, 4 to 16 m/s); pan or zoom out for the "
             "others. Red crosses: thin bins (fewer periods than the minimum); red triangles: bins whose "
             "Monte Carlo values did not settle; both are kept in the budget but not certified and left "
             "out of the certificate's headline range. Empty bins are not drawn.</p>",
    )


def _contributors_figure(budget: xr.Dataset) -> Figure:
    """Plot the contributors as grouped bars per certified wind-speed bin (menu: the height)."""
    d = contributors_data(budget)
    names, step, xlim = d.names, d.step, d.range_limits
    default = f"{fmt(float(budget.height.sel(height=120.0, method='nearest')))} m"
    hlabels = [f"{fmt(h)} m" for h in d.height]

    def build() -> Any:
        from bokeh.layouts import column
        from bokeh.models import ColumnDataSource, CustomJS, Select

        width = 0.85 * step / len(names)
        p = plot(f"Standard uncertainty contributors at {default}", _wind_speed_label(d.wind_speed_units),
                 "relative standard uncertainty (%)", width=_WIDTH + 140,
                 x_range=(xlim[0] - step / 2, xlim[1] + step / 2))
        j0 = hlabels.index(default)
        for i, name in enumerate(names):
            data = {"x": d.wind_speed + (i - (len(names) - 1) / 2) * width}
            for j, lab in enumerate(hlabels):
                data[lab] = np.where(d.certified[:, j], d.values[:, j, i], np.nan)
            data["top"] = data[hlabels[j0]]
            p.vbar(x="x", top="top", width=width, source=ColumnDataSource(data), color=COLORS[i % 10],
                   legend_label=name)
        legend_outside(p)
        select = Select(title="Show:", value=default, options=hlabels, width=220)
        select.js_on_change("value", CustomJS(
            args={"renderers": p.renderers, "plot": p},
            code="for (const r of renderers) { const d = r.data_source.data;"
                 "  d.top = d[cb_obj.value]; r.data_source.change.emit(); }"
                 "plot.title.text = 'Standard uncertainty contributors at ' + cb_obj.value;"))
        return column(select, p)

    return Figure(
        "Uncertainty contributors per height", build,
        note="<p>Relative standard uncertainty (k = 1) of each contributor per certified wind-speed bin "
             "(enough periods, 4 to 16 m/s); <em>combined</em> is their root sum of squares.</p>",
    )


def _sensitivity_figure(ds: xr.Dataset) -> Figure:
    d = sensitivity_data(ds)
    xl = f"{d.readable}{d.bin_units}"
    yl = f"mean lidar − reference difference{d.difference_units}"
    units = d.slope_units
    rows, titles = [], {}
    for one in d.heights:
        titles[f"{fmt(one.height)} m"] = (f"{fmt(one.height)} m: m = {fmt(one.slope)} ± "
                                          f"{fmt(one.slope_standard_error)} {units}, "
                                          f"R = {fmt(one.correlation, 2)}")
        rows.append([fmt(one.height), f"{fmt(one.slope)} ± {fmt(one.slope_standard_error)}",
                     fmt(one.correlation, 2),
                     fmt(one.slope_times_std), fmt(one.slope_times_std_times_r),
                     str(one.bins_used), ", ".join(one.significant) or "no"])

    def build() -> Any:
        # one source of points and one of curves, holding every height's columns ("x|40 m" ...);
        # the menu copies the chosen height's into the drawn ones: 4 renderers, not 4 per height
        from bokeh.layouts import column
        from bokeh.models import ColumnDataSource, CustomJS, Select

        n_pts = max(1, max(one.x.size for one in d.heights))
        n_line = max([1] + [one.line[0].size for one in d.heights if one.line is not None])

        def pad(v: np.ndarray, n: int) -> np.ndarray:
            out = np.full(n, np.nan)
            out[: v.size] = v
            return out

        pts: dict[str, np.ndarray] = {}
        crv: dict[str, np.ndarray] = {}
        for label, one in zip(titles, d.heights, strict=True):
            x, y, s = one.x, one.y, one.sem
            pts.update({f"x|{label}": pad(x, n_pts), f"y|{label}": pad(y, n_pts),
                        f"y0|{label}": pad(y - s, n_pts), f"y1|{label}": pad(y + s, n_pts)})
            xf, fit, lo, hi = one.line if one.line is not None else (np.array([]),) * 4
            crv.update({f"xf|{label}": pad(xf, n_line), f"fit|{label}": pad(fit, n_line),
                        f"lo|{label}": pad(lo, n_line), f"hi|{label}": pad(hi, n_line)})
        shown = list(titles)[0]
        for data in (pts, crv):
            data.update({k.split("|")[0]: v for k, v in list(data.items()) if k.endswith(f"|{shown}")})
        points, curve = ColumnDataSource(pts), ColumnDataSource(crv)
        p = plot(titles[shown], xl, yl, width=_WIDTH - 80)
        p.varea("xf", "lo", "hi", source=curve, color="#1f77b4", alpha=0.25,
                legend_label="95 % confidence band")
        p.line("xf", "fit", source=curve, color="#1f77b4", line_width=2, legend_label="regression")
        p.segment("x", "y0", "x", "y1", source=points, color="black")
        p.scatter("x", "y", source=points, color="black", size=7, legend_label="bin mean ± s.e.")
        legend_outside(p)
        select = Select(title="Show:", value=shown, options=list(titles), width=220)
        select.js_on_change("value", CustomJS(
            args={"sources": [points, curve], "plot": p, "titles": dict(titles)},
            code="for (const src of sources) { const d = {...src.data};"
                 "  for (const k of Object.keys(d)) { const [base, h] = k.split('|');"
                 "    if (h === cb_obj.value) { d[base] = d[k]; } }"
                 "  src.data = d; }"
                 "plot.title.text = titles[cb_obj.value];"))
        return column(select, p)

    note = (
        "<p>Points: bin means of the difference with the standard error of the mean "
        "(standard deviation / √periods); bins with fewer periods than the minimum are left out of "
        "the regression and not drawn. Line: least-squares fit of the bin means on the bin centres; "
        "band: its 95 % confidence band (from the slope's standard error).</p>"
        + html_table(["height (m)", f"slope m ({units})", "R", "m·std (%)", "m·std·R (%)", "bins",
                      "significant"],
                     rows, f"Sensitivity to {d.readable} (3 significant digits; Eq. 12: |m·std| > 0.5 %, "
                           "Eq. 13: |m·std·R| > 0.1 %)")
    )
    return Figure(f"Sensitivity to {d.readable}", build, note=note)


def _sensitivity_plots(sens: Iterable[xr.Dataset]) -> dict[str, Figure]:
    sens = list(sens)
    out = {f"sensitivity_{read_attr(ds, 'environmental_variable', kind='sensitivity', default='variable')}":
           _sensitivity_figure(ds) for ds in sens}
    if out:
        def build() -> Any:
            from bokeh.models import Span

            d = significance_data(sens)
            p = plot("m · std of each variable per height; threshold ±0.5 %", "height (m)", "m · std (%)")
            for i, (name, h, y) in enumerate(d.variables):
                p.line(h, y, color=COLORS[i % 10], line_width=2, legend_label=name)
                p.scatter(h, y, color=COLORS[i % 10], size=7, legend_label=name)
            for s in (0.5, -0.5):
                p.add_layout(Span(location=s, dimension="width", line_color="grey", line_dash="dashed"))
            p.y_range.start, p.y_range.end = -d.limit, d.limit
            legend_outside(p)
            return p

        out["sensitivity_slopes"] = Figure("Significance of the sensitivities (Eq. 12)", build)
    return out


def _cube_plots(cube: xr.Dataset, drawn_cnr: tuple[float, float] | None = None) -> dict[str, Figure]:
    """CNR x programmed velocity heatmaps of each line of sight (menu: the LOS), one colour scale for all.

    The colour scale spans the bins the simulation draws from (``drawn_cnr``, dB), else all bins.
    One plot shows the chosen line of sight: five plots would be five times the models to write
    (axes, grids, ranges, tools), for the same pictures the PDF shows side by side.
    """
    out = {}
    for name, heading, palette in (
        ("los_bias", "Bench: mean LOS velocity error (measured − programmed)", "RdBu11"),
        ("los_std", "Bench: standard deviation of the measured LOS velocity", "Viridis256"),
    ):
        if name not in cube:
            continue
        d = cube_data(cube, name, drawn_cnr)

        def build(d=d, palette=palette, heading=heading) -> Any:
            from bokeh.models import ColorBar, LinearColorMapper
            from bokeh.palettes import Viridis256, all_palettes

            # bokeh's RdBu runs blue (low) to red (high), as matplotlib's RdBu_r in the PDF
            colors = Viridis256 if palette == "Viridis256" else list(all_palettes["RdBu"][11])
            mapper = LinearColorMapper(palette=colors, low=d.limits[0], high=d.limits[1],
                                       nan_color=(0, 0, 0, 0))
            x0, x1, y0, y1 = d.extent
            labels = [f"{label} (vertical beam)" if v else label
                      for label, v in zip(d.los_labels, d.vertical, strict=True)]
            p = plot(labels[0], f"programmed radial velocity{d.velocity_units}", f"CNR{d.cnr_units}",
                     width=620, height=420)
            for values, text in zip(d.values, labels, strict=True):
                p.image(image=[values], x=x0, y=y0, dw=x1 - x0, dh=y1 - y0, color_mapper=mapper, name=text)
            p.add_layout(ColorBar(color_mapper=mapper, title=d.label), "right")
            return _menu(p, _by_name(p), labels[0], {text: f"{heading}: {text}" for text in labels})

        scale = (f"99th percentile of the CNR bins the simulation draws from, {fmt(drawn_cnr[0])} to "
                 f"{fmt(drawn_cnr[1])} dB" if drawn_cnr else "99th percentile of all bins")
        out[f"cube_{name}"] = Figure(
            f"{heading}, per line of sight", build,
            note=f"<p>Colour: {html.escape(d.label)}; blank cells had no bench samples. The menu chooses the "
                 "line of sight; the colour scale is the same for every one "
                 f"({fmt(d.limits[0])} to {fmt(d.limits[1])}, {scale}).</p>",
        )
    return out


def _rwf_plots(rwf: xr.Dataset) -> dict[str, Figure]:
    d = rwf_data(rwf)
    xl = "range offset from gate centre (m)"

    def shape() -> Any:
        p = plot(f"Pulse, apodization and RWF (normalised), Zd = {fmt(d.zero_distance)} m", xl,
                 "normalised amplitude")
        for i, (name, y) in enumerate(d.shapes.items()):
            p.line(d.x, y, color=COLORS[i], line_width=2, legend_label=name)
        legend_outside(p)
        return p

    def gradients() -> Any:
        p = plot("RWF for several CNR gradients (Eq. 2)", xl, f"RWF{d.rwf_units}")
        for k, (label, y) in enumerate(d.gradients):
            p.line(d.x, y, color=COLORS[k % 10], line_width=2, legend_label=label)
        legend_outside(p)
        return p

    return {"rwf_shape": Figure("Range-weighting function", shape),
            "rwf_gradients": Figure("Range-weighting function for several CNR gradients", gradients)}


def report_figures(
    *,
    budget: xr.Dataset | None = None,
    sensitivities: Iterable[xr.Dataset] | Mapping[str, xr.Dataset] = (),
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
    drawn_cnr: tuple[float, float] | None = None,
) -> dict[str, Figure]:
    """Build the report's :class:`Figure` for every component given, by figure name, in page order.

    The budget comes first (what an engineer reads first), then the sensitivities, the bench
    cube and the range-weighting function.
    """
    sens = list(sensitivities.values()) if isinstance(sensitivities, Mapping) else list(sensitivities)
    figs: dict[str, Figure] = {}
    if budget is not None:
        figs.update({"budget": _budget_figure(budget), "budget_contributors": _contributors_figure(budget)})
    if sens:
        figs.update(_sensitivity_plots(sens))
    if cube is not None:
        figs.update(_cube_plots(cube, drawn_cnr))
    if rwf is not None:
        figs.update(_rwf_plots(rwf))
    if not figs:
        raise InputError("nothing to report: give a certificate, a budget, sensitivities, a cube or an RWF")
    return figs
