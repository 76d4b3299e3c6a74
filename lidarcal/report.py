"""Offline HTML report of a calibration: interactive hvplot/bokeh plots plus static PNGs.

The page embeds BokehJS inline (``resources=INLINE``), so it opens without network access,
and shows, as available:

- the bench cube (paper Figure 5): LOS bias and standard deviation vs programmed velocity,
  one line per CNR, averaged over the lines of sight;
- the range-weighting function (Figure 6): pulse, apodization and RWF, and the RWF for a few
  CNR gradients, with the zero distance Zd;
- the sensitivities (Figure 7): bin means of the difference vs the environmental variable
  per height with the regression lines, and (Figure 8) the Eq. 12 statistic m·std per
  height for every variable against the ±0.5 % threshold;
- the uncertainty budget (Figure 9): relative standard uncertainty vs wind speed per height,
  and the contributors at one height.

Every plot is also written as a PNG through HoloViews' matplotlib backend, next to the page
(``<stem>_<figure>.png``).
"""

from __future__ import annotations

import html
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate import HEADLINE_WIND_SPEEDS, components, extract_component, headline_range
from lidarcal.errors import InputError
from lidarcal.io import atomic_path, check_writable

__all__ = ["report_figures", "write_report", "offline_html", "write_text"]

_WIDTH, _HEIGHT = 640, 340


def _hv():
    import holoviews as hv
    import holoviews.plotting.mpl  # noqa: F401  (matplotlib backend for the PNGs)
    import hvplot.xarray  # noqa: F401  (registers .hvplot)

    hv.Store.set_current_backend("bokeh")
    return hv


def _units(da: xr.DataArray) -> str:
    u = da.attrs.get("units", "")
    return f" ({u})" if u and u != "1" else ""


def _fig(obj: Any, title: str, xlabel: str, ylabel: str) -> Any:
    """Apply the same labels for both backends (bokeh page, matplotlib PNG)."""
    obj = obj.opts(title=title, xlabel=xlabel, ylabel=ylabel, width=_WIDTH, height=_HEIGHT, backend="bokeh")
    return obj.opts(title=title, xlabel=xlabel, ylabel=ylabel, aspect=2.0, fig_size=250, backend="matplotlib")


def _cube_plots(cube: xr.Dataset) -> dict[str, Any]:
    out = {}
    for name, title in (
        ("los_bias", "Bench: mean LOS error (measured - programmed)"),
        ("los_std", "Bench: standard deviation of the LOS velocity"),
    ):
        if name not in cube:
            continue
        da = cube[name].mean("los", skipna=True, keep_attrs=True)
        da = da.assign_coords(cnr=[f"{c:g} dB" for c in cube.cnr.values]).rename(name)
        out[f"cube_{name}"] = _fig(
            da.hvplot.line(x="velocity", by="cnr"),
            f"{title}, mean over lines of sight",
            f"programmed radial velocity{_units(cube.velocity)}",
            f"{name.replace('_', ' ')}{_units(cube[name])}",
        )
    return out


def _rwf_plots(rwf: xr.Dataset) -> dict[str, Any]:
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
    out["rwf_shape"] = _fig(
        norm.hvplot.line(x="range_offset", y=list(curves)),
        f"Pulse, apodization and RWF (normalised), Zd = {zd:.2f} m",
        xl,
        "normalised amplitude",
    )
    g = rwf["cnr_gradient"].values
    pick = sorted(set(np.linspace(0, len(g) - 1, min(5, len(g))).round().astype(int).tolist()))
    sub = rwf["rwf"].isel(cnr_gradient=pick, range_offset=sl)
    sub = sub.assign_coords(cnr_gradient=[f"{v:g} dB/m" for v in g[pick]])
    out["rwf_gradients"] = _fig(
        sub.hvplot.line(x="range_offset", by="cnr_gradient"),
        "RWF for several CNR gradients (Eq. 2)",
        xl,
        f"RWF{_units(rwf['rwf'])}",
    )
    return out


def _sensitivity_plots(sens: Iterable[xr.Dataset]) -> dict[str, Any]:
    hv = _hv()
    out = {}
    stats = []
    for ds in sens:
        var = str(ds.attrs.get("environmental_variable", "variable"))
        heights = [f"{h:g} m" for h in ds.height.values]
        means = ds["mean_difference"].assign_coords(height=heights)
        fit = (ds["intercept"] + ds["slope"] * ds["bin"]).where(ds["bin_flag"] == 0)
        fit = fit.assign_coords(height=heights).rename("regression")
        out[f"sensitivity_{var}"] = _fig(
            means.hvplot.scatter(x="bin", by="height", size=40) * fit.hvplot.line(x="bin", by="height"),
            f"Sensitivity to {var.replace('_', ' ')}: bin means and regression lines",
            f"{var.replace('_', ' ')}{_units(ds['bin'])}",
            f"mean lidar - reference difference{_units(ds['mean_difference'])}",
        )
        stats.append(ds["slope_times_std"].expand_dims(variable=[var]).reset_coords(drop=True))
    if stats:
        all_stats = xr.concat(stats, dim="variable", join="outer").rename("slope_times_std")
        limit = hv.HLine(0.5) * hv.HLine(-0.5)
        limit = limit.opts(
            hv.opts.HLine(color="grey", line_dash="dashed", backend="bokeh"),
            hv.opts.HLine(color="grey", linestyle="--", backend="matplotlib"),
        )
        out["sensitivity_slopes"] = _fig(
            all_stats.hvplot.line(x="height", by="variable") * limit,
            "Slope x std of the variable per height (Eq. 12 threshold +-0.5 %)",
            "height (m)",
            "m * std (%)",
        )
    return out


def _budget_plots(budget: xr.Dataset) -> dict[str, Any]:
    out = {}
    xl, yl = "reference wind speed bin (m s-1)", "relative standard uncertainty (%)"
    rel = budget["relative_uncertainty"].assign_coords(height=[f"{h:g} m" for h in budget.height.values])
    out["budget"] = _fig(
        rel.hvplot.line(x="wind_speed", by="height"),
        f"Combined standard uncertainty ({budget.attrs.get('approach')} approach)",
        xl,
        yl,
    )
    h = float(budget.height.sel(height=120.0, method="nearest"))
    contrib = budget["relative_contribution"].sel(height=h)
    total = budget["relative_uncertainty"].sel(height=h).expand_dims(contributor=["combined"])
    both = xr.concat([contrib, total], dim="contributor").rename("relative_contribution")
    out["budget_contributors"] = _fig(
        both.hvplot.line(x="wind_speed", by="contributor"), f"Uncertainty contributors at {h:g} m", xl, yl
    )
    return out


def report_figures(
    *,
    budget: xr.Dataset | None = None,
    sensitivities: Iterable[xr.Dataset] | Mapping[str, xr.Dataset] = (),
    cube: xr.Dataset | None = None,
    rwf: xr.Dataset | None = None,
) -> dict[str, Any]:
    """HoloViews objects (hvplot, bokeh-renderable) for every component given, by figure name."""
    _hv()
    sens = list(sensitivities.values()) if isinstance(sensitivities, Mapping) else list(sensitivities)
    figs: dict[str, Any] = {}
    if cube is not None:
        figs.update(_cube_plots(cube))
    if rwf is not None:
        figs.update(_rwf_plots(rwf))
    if sens:
        figs.update(_sensitivity_plots(sens))
    if budget is not None:
        figs.update(_budget_plots(budget))
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
                rows.append((label, str(meta.attrs[key])))
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
) -> dict[str, Any]:
    """Write the offline HTML report (and PNGs next to it).

    With ``certificate`` the components are taken from it; explicit arguments override them.

    Returns
    -------
    dict
        ``{"html": Path, "figures": [names], "png": [Paths]}``.
    """
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
    models = {name: hv.render(fig, backend="bokeh") for name, fig in figs.items()}
    links = {name: f'<p class="png"><a href="{p.name}">static PNG</a></p>' for name, p in pngs.items()}
    page = offline_html(models, title=title, header=f"<table>\n{table}\n</table>", after=links)
    written = []
    if png:
        renderer = hv.renderer("matplotlib")
        for name, fig in figs.items():
            with atomic_path(pngs[name], overwrite=overwrite) as tmp:
                renderer.save(fig, str(tmp.with_suffix("")), fmt="png")
                tmp.with_suffix(".png").replace(tmp)
            written.append(pngs[name])
    write_text(path, page, overwrite=overwrite)
    return {"html": path, "figures": list(figs), "png": written}


def offline_html(models: Mapping[str, Any], *, title: str, header: str = "",
                 after: Mapping[str, str] | None = None, headings: bool = True) -> str:
    """One self-contained HTML page of bokeh ``models``: BokehJS inline, nothing from the network.

    Each model gets a ``<section>`` (with an ``<h2>`` of its name if ``headings``, then
    ``after[name]`` if given) below the ``<h1>`` title and the ``header`` HTML.  Only the
    BokehJS bundles the models need are embedded.  Importing hvplot imports panel, which adds
    URL-loaded files (its ES-module shims) to every bokeh Resources object; the plots here are
    plain bokeh models, so those URLs are dropped, and a model from outside bokeh (which would
    need them) is refused.
    """
    from bokeh.embed import components as bokeh_components
    from bokeh.embed.bundle import Bundle, bundle_for_objs_and_resources
    from bokeh.resources import INLINE

    models = dict(models)
    after = after or {}
    foreign = sorted(
        {
            type(x).__module__
            for m in models.values()
            for x in m.references()
            if not type(x).__module__.startswith("bokeh.")
        }
    )
    if foreign:
        raise InputError(f"report plots use non-bokeh models from {foreign}; cannot embed them offline")
    script, divs = bokeh_components(list(models.values()))
    bundle = bundle_for_objs_and_resources(list(models.values()), INLINE)
    resources = "".join(Bundle(js_raw=bundle.js_raw, css_raw=bundle.css_raw, hashes=bundle.hashes))
    sections = "\n".join(
        f'<section id="{html.escape(name)}">'
        + (f"<h2>{html.escape(name.replace('_', ' '))}</h2>" if headings else "")
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
</style>
{resources}
{script}
</head>
<body>
<h1>{html.escape(title)}</h1>
{header}
{sections}
<footer><p>Generated by lidarcal; self-contained (BokehJS inline, no network needed).</p></footer>
</body>
</html>
"""


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = False) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; refuses an existing file unless ``overwrite``."""
    path = Path(path)
    with atomic_path(path, overwrite=overwrite) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
