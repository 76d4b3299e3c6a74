"""The calibration's figures as data: one function per figure, drawn by the PDF and by the HTML page.

Each function takes the certificate's components (budget, sensitivity, cube, RWF) and returns
a small frozen record of plain numpy arrays and words: what is drawn, never how.  The PDF and
PNG drawings (:mod:`lidarcal.certificate.document.figures`, matplotlib) and the HTML report's interactive
figures (:mod:`lidarcal.certificate.report.plots`, bokeh) both draw from them, so a figure's numbers are
prepared once:

- :func:`budget_data` — U (k = 2) per (wind speed, height) bin and which bins are certified,
  thin, not settled or apart (paper Figure 9);
- :func:`contributors_data` — each contributor's relative standard uncertainty and their
  combination, certified bins only;
- :func:`sensitivity_data` — per height the kept bin means with their standard errors, the
  regression line with its 95 % confidence band (:func:`confidence_band`) and the Eqs. 12-13
  statistics (Figure 7);
- :func:`significance_data` — the Eq. 12 statistic m·std per height of every variable (Figure 8);
- :func:`cube_data` — a bench cube heatmap per line of sight with its colour limits
  (:func:`cube_colour_limits`, from the CNR bins the simulation draws from, :func:`drawn_cnr_range`);
- :func:`rwf_data` — the pulse, apodization and RWF around the peak, and the RWF for a few CNR
  gradients (:func:`rwf_window`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import DEFAULT_CERTIFIED_RANGE
from lidarcal.certificate.document.facts import (
    VARIABLE_NAMES,
    certified_grid,
    certified_rows,
    fmt,
    units_suffix,
)
from lidarcal.readback import read_attr

__all__ = [
    "BudgetData",
    "ContributorsData",
    "SensitivityData",
    "SensitivityHeight",
    "SignificanceData",
    "CubeData",
    "RwfData",
    "budget_data",
    "contributors_data",
    "sensitivity_data",
    "significance_data",
    "cube_data",
    "rwf_data",
    "bin_means",
    "confidence_band",
    "cube_colour_limits",
    "drawn_cnr_range",
    "rwf_window",
]

#: Points at which a sensitivity's regression line and confidence band are drawn.
LINE_POINTS = 60


def _step(ws: np.ndarray) -> float:
    return float(np.median(np.diff(ws))) if ws.size > 1 else 1.0


def _variable_name(ds: xr.Dataset) -> tuple[str, str]:
    var = read_attr(ds, "environmental_variable", kind="sensitivity", default="variable")
    return var, VARIABLE_NAMES.get(var, var.replace("_", " "))


@dataclass(frozen=True)
class BudgetData:
    """The budget's U (k = 2) per (wind speed, height) bin (``value``, %, all bins) and the bins' state.

    Masks (wind speed x height): ``kept`` the bins with enough periods (``bin_flag`` 0),
    ``certified`` the certificate's bins (:func:`~lidarcal.certificate.document.facts.certified_grid`),
    ``thin`` bins with too few periods and a value, ``not_settled`` those whose Monte Carlo
    values did not settle, ``apart`` every finite value that is not certified.  ``tolerance``:
    the numerical tolerance (same units) or None.  ``range_limits``: the certified wind-speed
    range, half a bin beyond; ``held``: the first and last bin centres that hold certified
    values (the range when none).
    """

    k: float
    approach: str
    wind_speed: np.ndarray
    height: np.ndarray
    step: float
    value: np.ndarray
    kept: np.ndarray
    certified: np.ndarray
    thin: np.ndarray
    not_settled: np.ndarray
    apart: np.ndarray
    tolerance: np.ndarray | None
    wind_speeds: tuple[float, float]
    range_limits: tuple[float, float]
    held: tuple[float, float]
    wind_speed_units: str


def _held(g: Mapping[str, Any], wind_speeds: tuple[float, float]) -> tuple[float, float]:
    """Return the first and last bin centres holding certified values (``wind_speeds`` when none)."""
    rows = certified_rows(g)
    lo, hi = (g["wind_speed"][rows[0]], g["wind_speed"][rows[-1]]) if rows.size else wind_speeds
    return float(lo), float(hi)


def budget_data(budget: xr.Dataset, wind_speeds: tuple[float, float] = DEFAULT_CERTIFIED_RANGE) -> BudgetData:
    """Return :class:`BudgetData` of ``budget``, certified on ``wind_speeds`` (m/s, bin centres)."""
    g = certified_grid(budget, wind_speeds)
    flag = budget["bin_flag"].transpose("wind_speed", "height").values
    ws, val = g["wind_speed"], g["value"]
    finite = np.isfinite(val)
    step = _step(ws)
    return BudgetData(
        k=read_attr(budget, "coverage_factor", kind="uncertainty_budget"),
        approach=read_attr(budget, "approach", kind="uncertainty_budget", default=""),
        wind_speed=ws,
        height=g["height"],
        step=step,
        value=val,
        kept=flag == 0,
        certified=g["certified"],
        thin=(flag == 1) & finite,
        not_settled=g["not_settled"] & finite,
        apart=~g["certified"] & finite,
        tolerance=g["tolerance"],
        wind_speeds=wind_speeds,
        range_limits=(wind_speeds[0] - step / 2, wind_speeds[1] + step / 2),
        held=_held(g, wind_speeds),
        wind_speed_units=units_suffix(budget.wind_speed),
    )


@dataclass(frozen=True)
class ContributorsData:
    """Each contributor's relative standard uncertainty (%, k = 1) and their combination, per bin.

    ``values`` is (wind speed, height, name) over ``names`` (the contributors, then
    ``"combined"``); ``certified`` (wind speed, height) marks the bins drawn; ``held`` the first
    and last bin centres holding certified values; ``range_limits`` the certified wind-speed
    range, half a bin beyond.
    """

    wind_speed: np.ndarray
    height: np.ndarray
    step: float
    names: list[str]
    values: np.ndarray
    certified: np.ndarray
    held: tuple[float, float]
    range_limits: tuple[float, float]
    wind_speed_units: str


def contributors_data(
    budget: xr.Dataset, wind_speeds: tuple[float, float] = DEFAULT_CERTIFIED_RANGE
) -> ContributorsData:
    """Return :class:`ContributorsData` of ``budget``, certified on ``wind_speeds``."""
    g = certified_grid(budget, wind_speeds)
    contrib = budget["relative_contribution"].transpose("wind_speed", "height", "contributor").values
    combined = budget["relative_uncertainty"].transpose("wind_speed", "height").values
    step = _step(g["wind_speed"])
    return ContributorsData(
        wind_speed=g["wind_speed"],
        height=g["height"],
        step=step,
        names=[str(c).replace("_", " ") for c in budget.contributor.values] + ["combined"],
        values=np.concatenate([contrib, combined[:, :, None]], axis=2),
        certified=g["certified"],
        held=_held(g, wind_speeds),
        range_limits=(wind_speeds[0] - step / 2, wind_speeds[1] + step / 2),
        wind_speed_units=units_suffix(budget.wind_speed),
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


def bin_means(one: xr.Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return one height's kept bins (``bin_flag`` 0, finite mean): centres, mean differences, s.e.

    The standard error of a bin mean is its standard deviation over the square root of its periods.
    """
    used = (one["bin_flag"] == 0).values & np.isfinite(one["mean_difference"].values)
    sem = one["std_difference"].values / np.sqrt(np.maximum(one["sample_count"].values, 1))
    return one["bin"].values[used], one["mean_difference"].values[used], sem[used]


@dataclass(frozen=True)
class SensitivityHeight:
    """One height of a sensitivity: kept bin means ``x``, ``y`` ± ``sem``; the regression and its statistics.

    ``line`` is ``(x, fit, lower, upper)`` of the regression and its 95 % band at
    :data:`LINE_POINTS` points, or None (fewer than two bins, or no slope); ``significant``
    names the criteria met (``"Eq. 12"``, ``"Eq. 13"``); absent statistics are NaN.
    """

    height: float
    x: np.ndarray
    y: np.ndarray
    sem: np.ndarray
    line: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None
    slope: float
    slope_standard_error: float
    correlation: float
    slope_times_std: float
    slope_times_std_times_r: float
    bins_used: int
    significant: list[str]


@dataclass(frozen=True)
class SensitivityData:
    """A sensitivity artefact's figure: the variable (``name``, ``readable``), units, one entry per height."""

    name: str
    readable: str
    slope_units: str
    bin_units: str
    difference_units: str
    heights: list[SensitivityHeight]


def sensitivity_data(ds: xr.Dataset) -> SensitivityData:
    """Return :class:`SensitivityData` of one ``sensitivity`` artefact."""
    var, readable = _variable_name(ds)

    def stat(one: xr.Dataset, key: str) -> float:
        return float(one[key]) if key in one else np.nan

    heights = []
    for h in np.atleast_1d(ds.height.values):
        one = ds.sel(height=h)
        xb, yb, sem = bin_means(one)
        slope = stat(one, "slope")
        line = None
        if xb.size >= 2 and np.isfinite(slope):
            x = np.linspace(xb.min(), xb.max(), LINE_POINTS)
            line = (x, *confidence_band(ds, h, x))
        heights.append(SensitivityHeight(
            height=float(h), x=xb, y=yb, sem=sem, line=line, slope=slope,
            slope_standard_error=stat(one, "slope_standard_error"), correlation=stat(one, "correlation"),
            slope_times_std=stat(one, "slope_times_std"),
            slope_times_std_times_r=stat(one, "slope_times_std_times_r"),
            bins_used=int(one["bins_used"]) if "bins_used" in one else int(xb.size),
            significant=[name for name, key in (("Eq. 12", "significant_eq12"),
                                                ("Eq. 13", "significant_eq13"))
                         if key in one and int(one[key]) == 1],
        ))
    return SensitivityData(name=var, readable=readable, slope_units=ds["slope"].attrs.get("units", ""),
                           bin_units=units_suffix(ds["bin"]),
                           difference_units=units_suffix(ds["mean_difference"]), heights=heights)


@dataclass(frozen=True)
class SignificanceData:
    """The Eq. 12 statistic m·std (%) per height, one ``(readable name, heights, values)`` per variable.

    ``limit``: the symmetric y limit, at least 0.6 % and 10 % beyond the largest |m·std|.
    """

    variables: list[tuple[str, np.ndarray, np.ndarray]]
    limit: float


def significance_data(sens: Iterable[xr.Dataset]) -> SignificanceData:
    """Return :class:`SignificanceData` of the sensitivity artefacts ``sens``."""
    variables = [(_variable_name(ds)[1], np.atleast_1d(ds.height.values),
                  np.atleast_1d(ds["slope_times_std"].values)) for ds in sens]
    finite = np.concatenate([y for *_, y in variables]) if variables else np.array([])
    finite = finite[np.isfinite(finite)]
    return SignificanceData(variables, max(0.6, 1.1 * float(np.abs(finite).max())) if finite.size else 0.6)


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


@dataclass(frozen=True)
class CubeData:
    """A bench cube variable (``los_bias`` or ``los_std``) as heatmaps, one per line of sight.

    ``values`` is (los, cnr, velocity) on ascending ``cnr`` and ``velocity``; ``regular`` says
    whether both axes are evenly spaced (``extent`` then bounds the cells: velocity low, high,
    CNR low, high); ``los_labels`` name each line of sight (with its azimuth, but for the
    vertical beam, ``vertical``); ``limits`` the colour scale (:func:`cube_colour_limits`);
    ``label`` the colour bar's text.
    """

    name: str
    symmetric: bool
    values: np.ndarray
    velocity: np.ndarray
    cnr: np.ndarray
    regular: bool
    extent: tuple[float, float, float, float]
    los_labels: list[str]
    vertical: list[bool]
    limits: tuple[float, float]
    drawn: tuple[float, float] | None
    label: str
    velocity_units: str
    cnr_units: str


def cube_data(cube: xr.Dataset, name: str, drawn: tuple[float, float] | None = None) -> CubeData:
    """Return :class:`CubeData` of ``cube[name]``, coloured by the CNR bins ``drawn`` from (dB; None: all)."""
    symmetric = name == "los_bias"
    da = cube[name].transpose("los", "cnr", "velocity")
    limits = cube_colour_limits(da, drawn, symmetric)
    da = da.sortby("cnr").sortby("velocity")
    v, c = da["velocity"].values.astype(float), da["cnr"].values.astype(float)
    dv, dc = (np.diff(v) if v.size > 1 else np.ones(1)), (np.diff(c) if c.size > 1 else np.ones(1))
    labels, vertical = [], []
    for one in da.los.values:
        label = f"LOS {one}"
        vertical.append(str(one).upper() == "V")
        if "los_azimuth" in cube.coords and not vertical[-1]:
            label += f" (azimuth {fmt(cube.los_azimuth.sel(los=one).item())}°)"
        labels.append(label)
    return CubeData(
        name=name, symmetric=symmetric, values=da.values, velocity=v, cnr=c,
        regular=bool(np.allclose(dv, dv[0]) and np.allclose(dc, dc[0])),
        extent=(v[0] - dv[0] / 2, v[-1] + dv[0] / 2, c[0] - dc[0] / 2, c[-1] + dc[0] / 2),
        los_labels=labels, vertical=vertical, limits=limits, drawn=drawn,
        label=f"{name.replace('_', ' ')}{units_suffix(da)}",
        velocity_units=units_suffix(cube.velocity), cnr_units=units_suffix(cube.cnr),
    )


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


@dataclass(frozen=True)
class RwfData:
    """The RWF figure: the range offsets ``x`` (m) around the peak and what is drawn on them.

    ``shapes``: the normalised RWF, pulse and apodization, by name; ``gradients``: the RWF at a
    few CNR gradients, ``(label, values)``; ``zero_distance``: Zd (m).
    """

    x: np.ndarray
    shapes: dict[str, np.ndarray]
    gradients: list[tuple[str, np.ndarray]]
    zero_distance: float
    rwf_units: str


def rwf_data(rwf: xr.Dataset) -> RwfData:
    """Return :class:`RwfData` of an ``rwf`` artefact."""
    norm, sl, pick = rwf_window(rwf)
    shapes = {"RWF": norm[sl]}
    for name in ("pulse", "apodization"):
        if name in rwf:
            shapes[name] = (rwf[name] / float(rwf[name].max())).values[sl]
    g = rwf["cnr_gradient"].values
    return RwfData(
        x=rwf["range_offset"].values[sl], shapes=shapes,
        gradients=[(f"{fmt(g[i])} dB/m", rwf["rwf"].isel(cnr_gradient=i).values[sl]) for i in pick],
        zero_distance=float(rwf["zero_distance"]) if "zero_distance" in rwf else float("nan"),
        rwf_units=units_suffix(rwf["rwf"]),
    )
