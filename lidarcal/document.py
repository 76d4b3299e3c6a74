"""The certificate document: a paginated A4 PDF of a calibration certificate (matplotlib only).

:func:`write_document` writes ``report.pdf``: page 1 is the certificate itself (status,
certificate id, issuer, customer, calibrated item, dates and place, method, traceability of
the bench, signature status and the certified result: per height and wind-speed bin the
relative expanded uncertainty for k = 2, with its numerical tolerance where the budget has
one, under the headline sentence).  The following pages hold the figures, scaled to the
certified wind-speed range (bins outside it are drawn apart, in their own panel, and never set
the axes), every bin of the budget, and the inputs with their SHA-256.  Every page carries the
certificate id, the status and "page x of y" in its footer.

The figures are drawn by small functions on a matplotlib :class:`~matplotlib.figure.Figure`
(:data:`DRAWERS`), so the HTML report's static PNGs are the same drawings.  Administrative
attributes a certificate does not carry are shown as "not stated".
"""

from __future__ import annotations

import json
import os
import textwrap
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.certificate import (
    HEADLINE_WIND_SPEEDS,
    certified_rule,
    components,
    extract_component,
    headline_range,
    not_settled,
)
from lidarcal.io import atomic_path, check_writable
from lidarcal.seal import INTEGRITY_ATTR, SIGNATURE_ATTR, SIGNATURE_KEY_ATTR

__all__ = [
    "A4",
    "confidence_band",
    "NOT_STATED",
    "DRAWERS",
    "certificate_facts",
    "signature_status",
    "seal_statement",
    "certified_grid",
    "drawn_cnr_range",
    "STYLE",
    "headline_sentence",
    "write_document",
    "fmt",
    "units_suffix",
    "VARIABLE_NAMES",
]

A4 = (8.27, 11.69)  # inches, portrait
NOT_STATED = "not stated"
_FONT = 8.0
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
VARIABLE_NAMES = {  # readable names of the environmental variables
    "wind_shear_exponent": "wind shear exponent",
    "turbulence_intensity": "turbulence intensity",
    "cnr_gradient": "CNR gradient",
    "cnr": "CNR",
}


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


def units_suffix(da: xr.DataArray) -> str:
    """`` (unit)`` for a label, nothing for a dimensionless variable."""
    u = da.attrs.get("units", "")
    return f" ({u})" if u and u != "1" else ""


# ------------------------------------------------------------------ what page 1 states


def _attr(attrs: Mapping[str, Any], *names: str) -> str:
    for name in names:
        value = attrs.get(name)
        if value is not None and str(value).strip():
            return str(value)
    return NOT_STATED


def seal_statement(signed_by: str | None) -> str:
    """Describe the seal of a certificate signed by key ``signed_by`` (fingerprint), or unsigned."""
    if signed_by:
        return f"signed (Ed25519) by key {signed_by}; check with lidarcal verify CERT.nc --public-key KEY.pub"
    return (
        "sealed, unsigned: SHA-256 integrity record only (whoever can rewrite the file can "
        "re-seal it); check with lidarcal verify CERT.nc"
    )


def signature_status(attrs: Mapping[str, Any], seal: str | None = None) -> str:
    """Say what the certificate's seal and signature attributes say (not a verification).

    ``seal`` (:func:`seal_statement`) stands for a certificate not yet written, whose seal
    and signature are added when it is.
    """
    if SIGNATURE_ATTR in attrs:
        return seal_statement(str(attrs.get(SIGNATURE_KEY_ATTR, NOT_STATED)))
    if INTEGRITY_ATTR in attrs:
        return seal_statement(None)
    return seal or "not sealed (this document was made from a certificate not yet written)"


def certificate_facts(
    attrs: Mapping[str, Any], seal: str | None = None
) -> list[tuple[str, list[tuple[str, str]]]]:
    """Page 1's administrative data as (section, [(label, value)]) from the global attributes."""
    persons = _attr(attrs, "responsible_persons")
    bench_start = _attr(attrs, "bench_run_start", "bench_time_coverage_start")
    bench_end = _attr(attrs, "bench_run_end", "bench_time_coverage_end")
    bench = bench_start if bench_end in (NOT_STATED, bench_start) else f"{bench_start} to\n{bench_end}"
    version = attrs.get("lidarcal_version")
    return [
        (
            "Status",
            [
                ("Calibration status", _attr(attrs, "calibration_status")),
                *(
                    [("Why", str(attrs["calibration_status_reason"]))]
                    if attrs.get("calibration_status_reason")
                    else []
                ),
                ("Certificate id", certificate_id(attrs)),
                ("Date of issue", _attr(attrs, "date_issued", "date_created")),
            ],
        ),
        (
            "Issuer",
            [
                ("Laboratory", _attr(attrs, "laboratory_name", "institution")),
                ("Address", _attr(attrs, "laboratory_address")),
                ("Responsible", persons.replace("; ", "\n") if persons != NOT_STATED else persons),
                ("Created by", _attr(attrs, "creator_name")),
            ],
        ),
        (
            "Customer",
            [("Name", _attr(attrs, "customer_name")), ("Address", _attr(attrs, "customer_address"))],
        ),
        (
            "Calibrated item",
            [
                ("Manufacturer", _attr(attrs, "item_manufacturer")),
                ("Model", _attr(attrs, "item_model")),
                ("Serial number", _attr(attrs, "item_serial_number", "lidar_serial")),
                ("Firmware", _attr(attrs, "item_firmware")),
            ],
        ),
        (
            "Dates and place",
            [
                ("Bench run", bench),
                ("Simulation", _attr(attrs, "simulation_date")),
                ("Place", _attr(attrs, "calibration_location")),
            ],
        ),
        (
            "Method",
            [
                ("Method", _attr(attrs, "method_reference", "references")),
                ("Software", f"lidarcal {version}" if version else NOT_STATED),
                ("Approach", _attr(attrs, "budget_approach")),
            ],
        ),
        (
            "Traceability of the bench",
            [
                ("Bench", _attr(attrs, "bench_id")),
                ("Bench run", _attr(attrs, "bench_run_id")),
                ("Operator", _attr(attrs, "bench_operator")),
                ("RF driver cal.", _attr(attrs, "rf_driver_calibration_reference")),
            ],
        ),
        ("Signature", [("Seal", signature_status(attrs, seal))]),
    ]


def certificate_id(attrs: Mapping[str, Any]) -> str:
    """Return the certificate id (``certificate_id``, else the ACDD ``id``)."""
    return _attr(attrs, "certificate_id", "id")


def headline_sentence(budget: xr.Dataset, wind_speeds: tuple[float, float] = HEADLINE_WIND_SPEEDS) -> str:
    """Return the headline: the range of the certified relative expanded uncertainty (k = 2)."""
    k = float(budget.attrs.get("coverage_factor", 2.0))
    lo, hi = wind_speeds
    where = f"bins flagged ok with centres {lo:g} to {hi:g} m/s"
    if "certified" in str(budget["bin_flag"].attrs.get("flag_meanings", "")).split():
        where, wind_speeds = f"certified bins ({certified_rule(budget)})", None  # the budget's own rule
    rng = headline_range(budget, wind_speeds=wind_speeds)
    if rng is None:
        return f"Relative expanded uncertainty (k = {k:g}): no {where}, nothing is certified."
    text = (
        f"Relative expanded uncertainty (k = {k:g}) of the lidar's horizontal wind speed, {where}: "
        f"{rng[0]:.2f} % to {rng[1]:.2f} %."
    )
    missed = not_settled(budget)
    if missed:  # JCGM 101 7.9: the Monte Carlo stopped at --max-replicas before these settled
        text += (f" {len(missed)} certified value(s) did not settle to "
                 f"{int(budget.attrs['monte_carlo_significant_digits'])} significant digits within "
                 f"{int(budget.attrs['monte_carlo_replicas'])} Monte Carlo replicas.")
    return text


def certified_grid(
    budget: xr.Dataset, wind_speeds: tuple[float, float] = HEADLINE_WIND_SPEEDS
) -> dict[str, Any]:
    """Return the certified result: per (wind speed, height) bin the relative U (k = 2) and its tolerance.

    ``certified`` marks the bins of the headline (flag ok, centre in ``wind_speeds``), or the
    bins the budget's ``bin_flag`` itself calls ``certified`` when its ``flag_meanings`` have
    that meaning; ``tolerance`` is the budget's ``numerical_tolerance`` (same units) or None.
    """
    b = budget.transpose("wind_speed", "height", ...)
    rel = b["relative_expanded_uncertainty"].values
    inside = (b["wind_speed"].values >= wind_speeds[0]) & (b["wind_speed"].values <= wind_speeds[1])
    flag = b["bin_flag"]
    meanings = dict(
        zip(
            str(flag.attrs.get("flag_meanings", "")).split(),
            np.atleast_1d(flag.attrs.get("flag_values", [])).tolist(),
            strict=False,
        )
    )
    good = (
        flag.values == meanings["certified"]
        if "certified" in meanings
        else (flag.values == 0) & inside[:, None]
    )
    certified = good & np.isfinite(rel)
    tol = (
        b["numerical_tolerance"].transpose("wind_speed", "height").values
        if "numerical_tolerance" in b
        else None
    )
    return {
        "wind_speed": b["wind_speed"].values,
        "height": b["height"].values,
        "value": rel,
        "tolerance": tol,
        "certified": certified,
        "inside": inside,
        "flag": b["bin_flag"].values,
    }


# ------------------------------------------------------------------ figures


def _axes(
    fig,
    nrows: int,
    ncols: int,
    *,
    top: float = 0.9,
    bottom: float = 0.08,
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
#: (type 42) so that the PDF's text can be searched and extracted.
STYLE = {
    "pdf.fonttype": 42,
    "font.size": _FONT,
    "axes.titlesize": _FONT + 1,
    "axes.labelsize": _FONT,
    "xtick.labelsize": _FONT - 1,
    "ytick.labelsize": _FONT - 1,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "legend.fontsize": _FONT - 1,
}


def _small(ax, title: str, xlabel: str, ylabel: str) -> None:
    ax.set_title(title)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    from matplotlib.ticker import MaxNLocator

    for axis in (ax.xaxis, ax.yaxis):  # fewer ticks: each tick label is a text to lay out
        if isinstance(axis.get_major_locator(), MaxNLocator):
            axis.get_major_locator().set_params(nbins=6)


def draw_budget(fig, budget: xr.Dataset, wind_speeds: tuple[float, float] = HEADLINE_WIND_SPEEDS) -> None:
    """U (k = 2) per height on the certified range; bins outside it, or thin, in a panel of their own."""
    g = certified_grid(budget, wind_speeds)
    k = float(budget.attrs.get("coverage_factor", 2.0))
    ws, val, cert = g["wind_speed"], g["value"], g["certified"]
    top, bottom = _axes(fig, 2, 1, height_ratios=[2.2, 1], top=0.9, bottom=0.07, hspace=0.45, right=0.8)
    step = float(np.median(np.diff(ws))) if ws.size > 1 else 1.0
    for j, h in enumerate(g["height"]):
        c = _COLORS[j % len(_COLORS)]
        top.plot(
            ws, np.where(cert[:, j], val[:, j], np.nan), "-o", color=c, ms=3, lw=1.5, label=f"{fmt(h)} m"
        )
        apart = ~cert[:, j] & np.isfinite(val[:, j])
        bottom.plot(ws[apart], val[apart, j], "x" if True else "o", color=c, ms=4, label=f"{fmt(h)} m")
    certified_values = val[cert]
    ymax = float(certified_values.max()) * 1.15 if certified_values.size else 1.0
    top.set_xlim(wind_speeds[0] - step / 2, wind_speeds[1] + step / 2)
    top.set_ylim(0, ymax)
    _small(
        top,
        f"Relative expanded uncertainty (k = {k:g}), certified bins "
        f"({wind_speeds[0]:g} to {wind_speeds[1]:g} m/s, enough periods)",
        f"reference wind speed bin{units_suffix(budget.wind_speed)}",
        f"U, k = {k:g} (%)",
    )
    top.legend(
        fontsize=_FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1), title="height", title_fontsize=_FONT
    )
    if bottom.lines and any(line.get_xdata().size for line in bottom.lines):
        bottom.set_yscale("log")
    bottom.axvspan(wind_speeds[0] - step / 2, wind_speeds[1] + step / 2, color="0.9", zorder=0)
    _small(
        bottom,
        "Not certified: bins outside that range or with too few periods (own scale)",
        f"reference wind speed bin{units_suffix(budget.wind_speed)}",
        f"U, k = {k:g} (%)",
    )


def draw_contributors(
    fig, budget: xr.Dataset, wind_speeds: tuple[float, float] = HEADLINE_WIND_SPEEDS
) -> None:
    """Standard-uncertainty contributors per height as grouped bars, certified bins only."""
    g = certified_grid(budget, wind_speeds)
    b = budget.transpose("wind_speed", "height", ...)
    names = [str(c).replace("_", " ") for c in b.contributor.values] + ["combined"]
    heights = g["height"]
    ncol = 2
    axes = _axes(fig, int(np.ceil(len(heights) / ncol)), ncol, sharey=True, top=0.88, bottom=0.06, hspace=0.6)
    ws = g["wind_speed"]
    step = float(np.median(np.diff(ws))) if ws.size > 1 else 1.0
    width = 0.85 * step / len(names)
    contrib = b["relative_contribution"].transpose("wind_speed", "height", "contributor").values
    combined = b["relative_uncertainty"].values
    for j, (ax, h) in enumerate(zip(axes, heights, strict=False)):
        ok = g["certified"][:, j]
        values = np.concatenate([contrib[ok, j, :].T, combined[ok, j][None, :]])
        span = (wind_speeds[1] - wind_speeds[0]) + 2 * step  # the x limits below
        points = ax.get_position().width * fig.get_figwidth() * 72 / span  # points per m/s
        for i, (name, v) in enumerate(zip(names, values, strict=True)):
            # bars as one line collection each (butt caps, width in points): ~1,000 rectangles are slow
            ax.vlines(
                ws[ok] + (i - (len(names) - 1) / 2) * width,
                0,
                v,
                label=name,
                color=_COLORS[i % 10],
                linewidth=points * width,
                capstyle="butt",
            )
        ax.set_xlim(wind_speeds[0] - step, wind_speeds[1] + step)
        _small(ax, f"{fmt(h)} m", f"wind speed bin{units_suffix(budget.wind_speed)}", "u (%)")
    for ax in axes[len(heights) :]:
        ax.set_visible(False)
    axes[0].legend(fontsize=_FONT - 1, ncol=min(len(names), 4), loc="lower left", bbox_to_anchor=(0, 1.25))
    fig.suptitle(
        "Relative standard uncertainty (k = 1) of each contributor, certified bins", fontsize=_FONT + 3
    )


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


def draw_sensitivity(fig, ds: xr.Dataset) -> None:
    """Bin means (± s.e.), the regression and its 95 % band, one panel per height."""
    var = str(ds.attrs.get("environmental_variable", "variable"))
    readable = VARIABLE_NAMES.get(var, var.replace("_", " "))
    units = ds["slope"].attrs.get("units", "")
    heights = np.atleast_1d(ds.height.values)
    axes = _axes(fig, int(np.ceil(len(heights) / 2)), 2, top=0.9, bottom=0.06, hspace=0.7)
    for ax, h in zip(axes, heights, strict=False):
        one = ds.sel(height=h)
        used = (one["bin_flag"] == 0).values & np.isfinite(one["mean_difference"].values)
        xb, yb = one["bin"].values[used], one["mean_difference"].values[used]
        sem = (one["std_difference"].values / np.sqrt(np.maximum(one["sample_count"].values, 1)))[used]
        ax.errorbar(xb, yb, yerr=sem, fmt="o", color="black", ms=3, lw=0.8, label="bin mean ± s.e.")
        if used.sum() >= 2 and np.isfinite(float(one["slope"])):
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
            f"lidar − ref.{units_suffix(ds['mean_difference'])}",
        )
    for ax in axes[len(heights) :]:
        ax.set_visible(False)
    axes[0].legend(fontsize=_FONT - 1)
    fig.suptitle(f"Sensitivity to {readable}", fontsize=_FONT + 3)


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
    ax.legend(fontsize=_FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1))
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
    axes = _axes(fig, int(np.ceil(len(los) / 2)), 2, top=0.87, bottom=0.06, right=0.86, hspace=0.6)
    mesh = None
    for ax, one in zip(axes, los, strict=False):
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
            f"{name.replace('_', ' ')}{units_suffix(da)}", fontsize=_FONT
        )
    what = (
        "mean LOS velocity error (measured − programmed)"
        if symmetric
        else "standard deviation of the measured LOS velocity"
    )
    scale = (
        f"colour scale: 99th percentile of the CNR bins the simulation draws from ({fmt(drawn[0])} to "
        f"{fmt(drawn[1])} dB, dotted lines)"
        if drawn
        else "colour scale: 99th percentile of all bins"
    )
    fig.suptitle(f"Bench: {what}\n{scale}\nblank cells had no bench samples", fontsize=_FONT + 2)


def draw_rwf(fig, rwf: xr.Dataset) -> None:
    """Pulse, apodization and RWF (normalised) with Zd; the RWF for a few CNR gradients."""
    zd = float(rwf["zero_distance"]) if "zero_distance" in rwf else float("nan")
    column = rwf["rwf"].sel(cnr_gradient=0.0, method="nearest")
    norm = column.values / float(column.max())
    support = np.flatnonzero(norm > 1e-3)
    n = rwf.sizes["range_offset"]
    lo, hi = (support.min(), support.max()) if support.size else (0, n - 1)
    pad = max(5, (hi - lo) // 4)
    sl = slice(max(lo - pad, 0), min(hi + pad, n - 1) + 1)
    x = rwf["range_offset"].values[sl]
    a, b = _axes(fig, 2, 1, top=0.92, bottom=0.07, right=0.78, hspace=0.35)
    a.plot(x, norm[sl], label="RWF")
    for name in ("pulse", "apodization"):
        if name in rwf:
            a.plot(x, (rwf[name] / float(rwf[name].max())).values[sl], label=name)
    a.legend(fontsize=_FONT - 1, loc="upper left", bbox_to_anchor=(1.01, 1))
    _small(
        a,
        f"Pulse, apodization and RWF (normalised), Zd = {fmt(zd)} m",
        "range offset from gate centre (m)",
        "normalised amplitude",
    )
    g = rwf["cnr_gradient"].values
    pick = sorted(set(np.linspace(0, len(g) - 1, min(5, len(g))).round().astype(int).tolist()))
    for i in pick:
        b.plot(x, rwf["rwf"].isel(cnr_gradient=i).values[sl], label=f"{fmt(g[i])} dB/m")
    b.legend(
        fontsize=_FONT - 1,
        loc="upper left",
        bbox_to_anchor=(1.01, 1),
        title="CNR gradient",
        title_fontsize=_FONT,
    )
    _small(
        b,
        "RWF for several CNR gradients (Eq. 2)",
        "range offset from gate centre (m)",
        f"RWF{units_suffix(rwf['rwf'])}",
    )


#: Figure name -> (what it needs, drawer(fig, parts)); names match the HTML report's sections.
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


# ------------------------------------------------------------------ pages


def _text_page(
    fig, y: float, lines: list[tuple[str, str, dict]], *, x0: float = 0.07, x1: float = 0.33, width: int = 80
) -> float:
    """Write (label, value, style) rows from ``y`` (figure fraction) down; return the next free y."""
    line = _FONT * 1.45 / 72 / A4[1]
    for label, value, style in lines:
        if style.get("section"):
            y -= 0.4 * line
            fig.text(x0, y, label, fontsize=_FONT + 1.5, weight="bold", va="top")
            y -= 1.25 * line
            continue
        wrapped = [
            w
            for part in str(value).split("\n")
            for w in (textwrap.wrap(part, width, break_on_hyphens=False) or [""])
        ]
        fig.text(x0 + 0.015, y, label, fontsize=_FONT, va="top", color="0.25")
        fig.text(
            x1,
            y,
            "\n".join(wrapped),
            fontsize=_FONT,
            va="top",
            linespacing=1.3,
            color=style.get("color", "black"),
            weight=style.get("weight", "normal"),
        )
        y -= line * len(wrapped)
    return y


def _grid_table(
    fig, y: float, g: dict[str, Any], rows: np.ndarray, *, only_certified: bool, bottom: float = 0.05
) -> float:
    """Write a wind speed × height table of U (k = 2, %) from ``y`` down; returns the next free y.

    The font shrinks (to 5.5 pt at least) when the rows would not fit above ``bottom``.
    """
    heights, ws = g["height"], g["wind_speed"]
    x0, first, x1 = 0.07, 0.19, 0.95
    cols = np.linspace(first, x1, len(heights) + 1)[1:]
    size = _FONT - 0.5 if g["tolerance"] is not None else _FONT
    fits = (y - bottom) / (len(rows) + 2.8) * 72 * A4[1] / 1.4  # the font size whose rows fit
    size = max(5.5, min(size, fits))
    line = size * 1.4 / 72 / A4[1]
    fig.text(x0, y, "wind speed\nbin (m/s)", fontsize=size, va="top", weight="bold", linespacing=1.1)
    for c, h in zip(cols, heights, strict=True):
        fig.text(c, y, f"{fmt(h)} m", fontsize=size, va="top", ha="right", weight="bold")
    y -= 2.3 * line
    fig.add_artist(_rule(y + 0.4 * line))
    # one text per column and colour (not per cell): hundreds of text artists are what costs
    rows = list(rows)
    style = dict(fontsize=size, va="top", linespacing=1.4)
    fig.text(x0 + 0.02, y, "\n".join(fmt(ws[i]) for i in rows), **style)
    for j, c in enumerate(cols):
        black, grey = [], []
        for i in rows:
            v, ok = g["value"][i, j], g["certified"][i, j]
            if only_certified and not ok:
                text = "–"
            else:
                text = f"{v:.2f}" if np.isfinite(v) else "–"
                if g["tolerance"] is not None and np.isfinite(g["tolerance"][i, j]) and np.isfinite(v):
                    text += f" ± {g['tolerance'][i, j]:.2g}"
                if not ok and np.isfinite(v):
                    text += " t" if int(g["flag"][i, j]) == 1 else " o"
            (black if ok else grey).append(text)
            (grey if ok else black).append(" ")
        fig.text(c, y, "\n".join(black), ha="right", multialignment="right", color="black", **style)
        fig.text(c, y, "\n".join(grey), ha="right", multialignment="right", color="0.45", **style)
    return y - line * len(rows) - 0.5 * line


def _rule(y: float):
    from matplotlib.lines import Line2D

    return Line2D([0.07, 0.95], [y, y], lw=0.5, color="0.3")


def _title(fig, text: str, sub: str = "") -> None:
    fig.text(0.07, 0.965, text, fontsize=_FONT + 6, weight="bold", va="top")
    if sub:
        fig.text(0.07, 0.94, sub, fontsize=_FONT, va="top", color="0.3")


def _page_one(fig, cert: xr.Dataset, budget: xr.Dataset | None, seal: str | None = None) -> None:
    attrs = cert.attrs
    status = _attr(attrs, "calibration_status")
    _title(fig, "Calibration certificate: pulsed Doppler wind lidar", _attr(attrs, "title"))
    reason = attrs.get("calibration_status_reason")
    banner = {
        "demonstration": (
            "DEMONSTRATION: not a calibration of a real instrument"
            + ("" if reason else " (made from simulated or sample data)"),
            "#b22222",
        ),
        "issued": ("ISSUED calibration certificate", "#1a6b1a"),
    }.get(status, (f"Calibration status: {status}", "#8a5a00"))
    text = textwrap.fill(banner[0], 95)
    fig.text(0.07, 0.915, text, fontsize=_FONT + 2, weight="bold", color=banner[1], va="top")
    shift = 0.016 * text.count("\n")  # a long reason takes more lines: the columns start lower
    # the status block (status, id, date of issue) across the page, the other sections in two columns
    blocks: list[list[tuple[str, str, dict]]] = [[], [], []]
    facts = certificate_facts(attrs, seal)
    for n, (section, items) in enumerate(facts):
        rows = blocks[0 if n == 0 else 1 if n <= len(facts) // 2 else 2]
        rows.append((section, "", {"section": True}))
        for label, value in items:
            style = {"color": "#b22222", "weight": "bold"} if label == "Calibration status" else {}
            if value == NOT_STATED:
                style = {"color": "0.5"}
            rows.append((label, value, style))
    y = _text_page(fig, 0.9 - shift, blocks[0], x0=0.07, x1=0.22, width=100)
    y = min(
        _text_page(fig, y, blocks[1], x0=0.07, x1=0.22, width=44),
        _text_page(fig, y, blocks[2], x0=0.52, x1=0.67, width=40),
    )
    if budget is None:
        fig.text(
            0.07, y - 0.02, "This certificate carries no uncertainty budget.", fontsize=_FONT + 1, va="top"
        )
        return
    k = float(budget.attrs.get("coverage_factor", 2.0))
    y -= 0.012
    fig.text(
        0.07,
        y,
        f"Certified result: relative expanded uncertainty U (%), k = {k:g}",
        fontsize=_FONT + 1.5,
        weight="bold",
        va="top",
    )
    y -= 0.018
    headline = textwrap.fill(headline_sentence(budget), 105)
    fig.text(0.07, y, headline, fontsize=_FONT + 0.5, va="top", weight="bold")
    y -= (headline.count("\n") + 1) * (_FONT + 0.5) * 1.25 / 72 / A4[1] + 0.006  # however many lines it takes
    g = certified_grid(budget)
    tol = "; ± its numerical tolerance (Monte Carlo)" if g["tolerance"] is not None else ""
    fig.text(
        0.07,
        y,
        f"Per height and wind-speed bin (bin centre){tol}; – : bin not certified (too few periods "
        "or no data).",
        fontsize=_FONT - 0.5,
        va="top",
        color="0.3",
    )
    _grid_table(fig, y - 0.016, g, np.flatnonzero(g["inside"]), only_certified=True)


def _all_bins_page(fig, budget: xr.Dataset) -> None:
    k = float(budget.attrs.get("coverage_factor", 2.0))
    _title(
        fig,
        f"Every bin of the budget: U (%), k = {k:g}",
        "Grey: not certified (t: too few periods; o: outside the certified wind-speed range); "
        "– : no data. Only the black values are certified.",
    )
    g = certified_grid(budget)
    _grid_table(fig, 0.91, g, np.arange(g["wind_speed"].size), only_certified=False)


def _provenance_page(fig, cert: xr.Dataset) -> None:
    _title(
        fig,
        "Inputs and provenance",
        "Each input file of the certificate with its SHA-256; the full chain, "
        "configuration and seeds are in the certificate's lidarcal_* attributes.",
    )
    rows: list[tuple[str, str, dict]] = [("Inputs", "", {"section": True})]
    chain = cert.attrs.get("lidarcal_provenance_chain")
    for item in json.loads(chain) if chain else []:
        rows.append(
            (
                f"{item.get('role')}",
                f"{item.get('file')} ({item.get('kind', '')}), SHA-256:\n{item.get('sha256')}",
                {},
            )
        )
    rows.append(("Certificate", "", {"section": True}))
    for key in ("certificate_components", "lidarcal_version", "date_created", "history"):
        if key in cert.attrs:
            rows.append((key, str(cert.attrs[key]), {}))
    _text_page(fig, 0.9, rows, x1=0.4, width=85)


def write_document(
    path: str | os.PathLike,
    cert: xr.Dataset,
    *,
    overwrite: bool = False,
    parts: Mapping[str, Any] | None = None,
    seal: str | None = None,
    warning: str | None = None,
) -> dict[str, Any]:
    """Write the certificate document ``path`` (A4 PDF) of certificate ``cert``.

    ``parts`` (from :func:`parts_of`) saves extracting the components again; ``seal``
    (:func:`seal_statement`) states the seal of a certificate written after its document;
    ``warning`` (an invalid seal) is printed in red on page 1 and in every page's footer.

    Returns
    -------
    dict
        ``{"pdf": Path, "pages": int}``.
    """
    import matplotlib
    from matplotlib.backends.backend_pdf import PdfPages
    from matplotlib.figure import Figure

    path = Path(path)
    check_writable(path, overwrite=overwrite)
    parts = parts_of(cert) if parts is None else parts
    budget = parts.get("budget")
    pages: list[Figure] = []

    def page() -> Figure:
        fig = Figure(figsize=A4)
        pages.append(fig)
        return fig

    with matplotlib.rc_context(STYLE):
        first = page()
        _page_one(first, cert, budget, seal)
        if warning:  # over the title block, in red: the numbers below are not certified
            first.text(
                0.07,
                0.99,
                textwrap.fill(warning, 110),
                fontsize=_FONT,
                color="#b22222",
                weight="bold",
                va="top",
            )
        for name in figure_names(parts):
            fig = page()
            draw(fig, name, parts)
        if budget is not None:
            _all_bins_page(page(), budget)
        _provenance_page(page(), cert)
        cid, status = certificate_id(cert.attrs), _attr(cert.attrs, "calibration_status")
        for i, fig in enumerate(pages, 1):
            fig.add_artist(_rule(0.035))
            invalid = " · INVALID SEAL: these numbers are NOT certified" if warning else ""
            fig.text(
                0.07,
                0.025,
                f"Certificate {cid} · status: {status}{invalid}",
                fontsize=_FONT - 1,
                va="top",
                color="#b22222" if warning else "black",
            )
            fig.text(0.95, 0.025, f"page {i} of {len(pages)}", fontsize=_FONT - 1, va="top", ha="right")
        with atomic_path(path, overwrite=overwrite) as tmp:
            with PdfPages(
                tmp,
                metadata={
                    "Title": f"Calibration certificate {cid}",
                    "Creator": "lidarcal",
                    "Subject": f"status: {status}",
                },
            ) as pdf:
                for fig in pages:
                    pdf.savefig(fig)
    return {"pdf": path, "pages": len(pages)}
