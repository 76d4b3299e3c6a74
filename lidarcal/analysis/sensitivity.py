"""Environmental sensitivities of the lidar–reference difference (paper §3.3, IEC 61400-50-2).

For one environmental variable *X* and each height:

1. the records (10-minute periods) are binned by *X* (contiguous bins at integer multiples
   of the bin width, or user edges);
2. per bin, the mean, standard deviation and count of the difference
   ``d = 100 % · (lidar − reference) / reference`` (``relative=True``; relative to the
   **reference** wind speed of each period, then averaged) or ``d = lidar − reference`` in
   m s-1 (``relative=False``);
3. bins with fewer than ``min_periods`` periods (default 10, the budget's
   :data:`~lidarcal.analysis.budget.DEFAULT_MIN_PERIODS`: one rule for a bin that counts)
   are dropped (kept in the table with their count, flagged, mean set to NaN);
4. a **weighted** least-squares line of the remaining bin means against the mean of *X* in
   each bin, with weights ``1 / SE² = n / s²`` from each bin's count *n* and spread *s*
   (:func:`~lidarcal.analysis.kernels.bin_mean_weights`; a bin with ``s = 0`` or ``n < 2``
   takes the pooled within-bin variance): slope *m* (% per unit of *X*), intercept, weighted
   correlation *R*, the slope's standard error (inflated by the Birge ratio ``sqrt(χ²_ν)``
   when the bin means scatter more than their errors allow) and its 95 % confidence interval
   (Student t with ``bins − 2`` degrees of freedom);
5. ``std`` = sample standard deviation (ddof = 1) of *X* over all periods in the kept bins;
6. the significance tests ``|m·std| > 0.5 %`` (Eq. 12) and ``|m·std·R| > 0.1 %`` (Eq. 13).

Why weighted, and why 10 periods per bin: an unweighted fit of bin means gives a bin of 3
periods in the tail of the distribution (extrapolated shear reaches α ≈ 1.4 at 200 m) the
same say as a bin of 300 near the median, and its leverage is the largest; a few such bins
then decide the slope.  Weighting by ``n / s²`` is the maximum-likelihood line for bin means
with independent errors, and it makes the slope's standard error meaningful.  IEC
61400-50-2 (and the paper's §3.3) drop bins "that do not contain sufficient sample number"
without fixing the number in any text available to this project, so the count is a
documented choice: with ``n ≥ 10`` the bin's ``s²`` has 9 degrees of freedom, so its inverse
(the weight) has a finite mean and variance (``E[σ²/s²] = ν/(ν − 2) = 1.29``, relative
spread ≈ 0.6; with ``n = 3`` the mean of ``1/s²`` is infinite and one lucky bin can take
all the weight) and the bin mean of a skewed difference is close to normal.  The count is
a parameter (``min_periods``; ``--min-periods`` on the command line) and recorded in the
artefact (attribute ``min_samples``, the file's name for it).  ``docs/sensitivity.md`` has
the derivation.

One ``sensitivity`` artefact describes one variable, so every quantity has a single unit
(a slope in "% per m s-1" and one in "% per degree" cannot share a CF variable).  Several
variables → several artefacts (:func:`sensitivities`); simulated and measured results line up
with :func:`compare_slopes` (paper Figure 8).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr
from scipy import stats

from lidarcal.analysis import kernels
from lidarcal.analysis._records import checked, select_heights
from lidarcal.analysis.budget import DEFAULT_MIN_PERIODS
from lidarcal.binning import binned_statistics
from lidarcal.cf import with_bounds
from lidarcal.conditions.variables import STANDARD_NAMES
from lidarcal.errors import InputError
from lidarcal.io import source_name
from lidarcal.provenance import lidar_serial, stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs
from lidarcal.units import LOG_UNITS, to_magnitude

__all__ = ["sensitivity", "sensitivity_fit", "sensitivities", "compare_slopes", "per_unit",
           "DEFAULT_BIN_WIDTHS"]

#: Bin widths used when none is given, in the variable's canonical units.
DEFAULT_BIN_WIDTHS = {
    "wind_speed": 0.5,            # m s-1, the IEC wind-speed bin
    "wind_from_direction": 10.0,  # degree
    "turbulence_intensity": 0.01,  # 1 (one percentage point of TI)
    "wind_shear_exponent": 0.05,  # 1
    "cnr": 2.0,                   # dB, the bench's CNR step (Table 1)
    "cnr_gradient": 0.01,         # dB m-1
}

#: Confidence level of the slope's confidence interval.
CONFIDENCE = 0.95

#: Regression methods: name -> description recorded in the artefact.
REGRESSIONS = {
    "weighted": "weighted least squares of bin means (weights n/s2) on the mean of the variable in each bin",
    "unweighted": "unweighted ordinary least squares of bin means on bin centres (scipy.stats.linregress)",
}

#: Wind-speed range (m s-1, of the reference) used by default, the IEC classification range.
DEFAULT_REFERENCE_RANGE = (4.0, 16.0)

THRESHOLD_EQ12 = 0.5  # %
THRESHOLD_EQ13 = 0.1  # %


def per_unit(diff_units: str, x_units: str) -> str:
    """Return the units of a slope of ``diff_units`` per ``x_units``, in UDUNITS spelling.

    >>> per_unit("%", "m s-1"), per_unit("%", "dB m-1"), per_unit("m s-1", "1")
    ('% s m-1', '% m dB-1', 'm s-1')
    """
    if x_units in ("1", ""):
        return diff_units
    parts = x_units.split()
    inverse = []
    for p in parts:
        base = p.rstrip("-0123456789")
        exp = p[len(base):] or "1"
        e = -int(exp)
        inverse.append(base if e == 1 else f"{base}{e}")
    inverse.sort(key=lambda part: "-" in part)  # positive powers first: "% s m-1"
    return f"{diff_units} {' '.join(inverse)}"


def _width(variable: str, bin_width: Any, units: str) -> float:
    if bin_width is None:
        if variable not in DEFAULT_BIN_WIDTHS:
            raise InputError(f"no default bin width for variable {variable!r}; give bin_width= or bins=")
        return DEFAULT_BIN_WIDTHS[variable]
    if units in LOG_UNITS:
        if hasattr(bin_width, "magnitude"):
            return float(bin_width.magnitude)
        if isinstance(bin_width, str):
            value, _, unit = bin_width.partition(" ")
            if unit and unit.strip() not in LOG_UNITS[units]:
                raise InputError(f"bin width {bin_width!r} for {variable!r}: expected units {units!r}")
            return float(value)
        return float(bin_width)
    return float(to_magnitude(bin_width, units, name="bin_width"))


def _range(reference_range) -> tuple[float, float]:
    if reference_range is None:
        return 0.0, np.inf
    lo, hi = reference_range
    conv = [(-np.inf if i == 0 else np.inf) if v is None else
            float(v if isinstance(v, int | float) else to_magnitude(v, "m s-1", name="reference_range"))
            for i, v in enumerate((lo, hi))]
    return max(conv[0], 0.0), conv[1]


#: Comment on the Eq. 12-13 statistics of an absolute (m s-1) difference.
_ABSOLUTE_COMMENT = "the thresholds of Eqs. 12-13 are in %; they do not apply here"


def sensitivity(
    records: xr.Dataset,
    variable: str,
    *,
    bin_width: Any = None,
    bins: Any = None,
    min_periods: int = DEFAULT_MIN_PERIODS,
    relative: bool = True,
    regression: str = "weighted",
    heights: Iterable[float] | None = None,
    reference_range: tuple[Any, Any] | None = DEFAULT_REFERENCE_RANGE,
    source: str | None = None,
    call: str | None = None,
) -> xr.Dataset:
    """Sensitivity of the lidar–reference difference to one environmental variable.

    Parameters
    ----------
    records : xarray.Dataset
        ``simulated_rtd`` or ``field_campaign`` records on (time, height) with
        ``lidar_wind_speed``, ``reference_wind_speed`` and ``variable``.  May be Dask-backed;
        the result (a small table per height) is computed in one pass.
    variable : str
        Environmental variable to bin by, e.g. ``"wind_shear_exponent"``.
    bin_width : quantity, str or float, optional
        Bin width in the variable's units (``"0.5 m s-1"``; a bare float only for
        dimensionless variables and dB); default :data:`DEFAULT_BIN_WIDTHS`.
    bins : array, optional
        Explicit increasing bin edges (canonical units) instead of ``bin_width``.
    min_periods : int
        Bins with fewer periods are left out of the regression (default
        :data:`~lidarcal.analysis.budget.DEFAULT_MIN_PERIODS`, 10).
    relative : bool
        Difference in % of the reference (default) or in m s-1.
    regression : {"weighted", "unweighted"}
        ``"weighted"`` (default): least squares of the bin means on the bins' mean of the
        variable with weights ``n / s²``; ``"unweighted"``: ordinary least squares on the bin
        centres, as the paper describes the 50-2 procedure (``scipy.stats.linregress``).
    heights : sequence of float, optional
        Heights (m) to analyse; default all.  A height not in the records is an error.
    reference_range : (low, high), optional
        Reference wind-speed range of the periods used, in m s-1 (default 4–16 m s-1);
        ``None`` uses every period with a positive reference speed.
    source, call : str, optional
        File name for messages (default: the records' ``lidarcal_source_file``) and the
        command recorded in ``history``.

    Returns
    -------
    xarray.Dataset
        A ``sensitivity`` artefact (dims ``height``, ``bin``).
    """
    source = source or source_name(records)
    if bin_width is not None and bins is not None:
        raise InputError("give either bin_width or bins, not both")
    min_periods, regression = _min_periods(min_periods), _regression(regression)
    records = select_heights(records, heights, source=source)
    x = checked(records, variable, source=source)
    lo_ref, hi_ref = _range(reference_range)
    diff = _difference(records, x, relative, lo_ref, hi_ref, source)
    edges, width = _edges(x, diff, variable, bins, bin_width, source, (lo_ref, hi_ref))
    fit = _fit(records, x, diff, edges, variable, min_periods, source, regression)
    config = {
        "variable": variable, "variable_units": x.attrs["units"], "bin_width": width,
        "bin_edges": edges.tolist(), "min_samples": min_periods, "relative": relative,  # the file's name
        "reference_range_m_s-1": [lo_ref, None if np.isinf(hi_ref) else hi_ref],
        "regression": REGRESSIONS[regression],
        "confidence": CONFIDENCE,
        "thresholds_percent": {"eq12": THRESHOLD_EQ12, "eq13": THRESHOLD_EQ13},
    }
    return _assemble(records, variable, x.attrs["units"], relative, edges, fit, config, call)


def sensitivity_fit(
    records: xr.Dataset,
    variable: str,
    bins: Any,
    *,
    min_periods: int = DEFAULT_MIN_PERIODS,
    relative: bool = True,
    regression: str = "weighted",
    reference_range: tuple[Any, Any] | None = DEFAULT_REFERENCE_RANGE,
    source: str | None = None,
) -> dict[str, np.ndarray]:
    """Return the numbers of a :func:`sensitivity` on the bin edges ``bins``, without the artefact.

    The arrays of the bin table (height, bin) and of the regression and Eqs. 12-13 tests
    (height), named as the artefact's variables; the arguments are those of :func:`sensitivity`.
    For callers that need the slopes of many variables (:func:`lidarcal.analysis.sweep.analyse_sweep`).
    """
    source = source or source_name(records)
    x = checked(records, variable, source=source)
    lo_ref, hi_ref = _range(reference_range)
    diff = _difference(records, x, relative, lo_ref, hi_ref, source)
    edges, _ = _edges(x, diff, variable, bins, None, source, (lo_ref, hi_ref))
    return _fit(records, x, diff, edges, variable, _min_periods(min_periods), source, _regression(regression))


def _min_periods(value: int) -> int:
    if int(value) < 1:
        raise InputError(f"min_periods must be >= 1; got {value}")
    return int(value)


def _regression(value: str) -> str:
    if value not in REGRESSIONS:
        raise InputError(f"argument 'regression': expected one of {sorted(REGRESSIONS)}; found {value!r}")
    return value


def _difference(records: xr.Dataset, x: xr.DataArray, relative: bool, lo_ref: float, hi_ref: float,
                source: str) -> xr.DataArray:
    """Lidar − reference (in % of the reference or m s-1), NaN outside the usable periods."""
    lidar = checked(records, "lidar_wind_speed", source=source)
    ref = checked(records, "reference_wind_speed", source=source)
    use = (ref > lo_ref) & (ref <= hi_ref) & np.isfinite(lidar) & np.isfinite(x)
    diff = (100.0 * (lidar - ref) / ref) if relative else (lidar - ref)
    return diff.where(use)


def _edges(x: xr.DataArray, diff: xr.DataArray, variable: str, bins: Any, bin_width: Any, source: str,
           ref_range: tuple[float, float]) -> tuple[np.ndarray, float | None]:
    """Bin edges (user ``bins`` or multiples of the width over the data) and the width used."""
    if bins is not None:
        edges = np.asarray(bins, dtype=float)
        if edges.ndim != 1 or len(edges) < 2 or np.any(np.diff(edges) <= 0):
            raise InputError(f"bins must be at least two strictly increasing edges; got {edges.tolist()}")
        return edges, None
    width = _width(variable, bin_width, x.attrs["units"])
    xs = x.where(np.isfinite(diff))
    lo, hi = float(xs.min().compute()), float(xs.max().compute())
    if not np.isfinite(lo):
        raise InputError(
            f"{source}: no period has finite {variable!r}, lidar_wind_speed and reference_wind_speed "
            f"with the reference in [{ref_range[0]:g}, {ref_range[1]:g}] m s-1; nothing to bin"
        )
    return kernels.edges_from_width(lo, hi, width), width


def _fit(records: xr.Dataset, x: xr.DataArray, diff: xr.DataArray, edges: np.ndarray, variable: str,
         min_periods: int, source: str, regression: str = "weighted") -> dict[str, Any]:
    """Bin table, regression of the kept bin means, std of the variable and the Eqs. 12-13 tests."""
    nb = len(edges) - 1

    def _stats(xv, yv):
        return binned_statistics(xv, yv, edges)

    count, mean, std, mean_x = xr.apply_ufunc(
        _stats, x, diff, input_core_dims=[["time"], ["time"]], output_core_dims=[["bin"]] * 4,
        dask="parallelized", output_dtypes=[np.int64, float, float, float],
        dask_gufunc_kwargs={"output_sizes": {"bin": nb}, "allow_rechunk": True},
    )
    count, mean, std, mean_x = (a.compute() for a in (count, mean, std, mean_x))
    keep = count >= min_periods
    if not bool(keep.any()):
        raise InputError(
            f"{source}: variable {variable!r}: no bin has at least min_periods={min_periods} periods "
            f"(largest bin count {int(count.max())}, {int(count.sum())} usable periods in {nb} bins); "
            "lower --min-periods, widen the bins or supply more records"
        )
    centres = 0.5 * (edges[:-1] + edges[1:])
    mean_kept = mean.where(keep)
    if regression == "weighted":
        weight = np.where(keep.values, kernels.bin_mean_weights(count.values, std.values), 0.0)
        xfit = mean_x.values
    else:  # the unweighted fit on bin centres the paper describes for IEC 61400-50-2
        weight = np.where(keep.values, 1.0, 0.0)
        xfit = np.broadcast_to(centres, mean_kept.shape)
    reg = kernels.weighted_linear_regression(xfit, mean_kept.values, weight, confidence=CONFIDENCE)
    if regression == "unweighted":  # classical OLS standard error (no floor at the weights' scale)
        _, _, _, ols_se = kernels.linear_regression(xfit, mean_kept.values)
        tq = stats.t.ppf(0.5 + CONFIDENCE / 2.0, np.maximum(reg["n_points"] - 2, 1))
        reg.update(stderr=ols_se, ci_low=reg["slope"] - tq * ols_se, ci_high=reg["slope"] + tq * ols_se,
                   chi2_reduced=np.full_like(ols_se, np.nan))  # no error model: no chi-square
    slope, intercept, r, stderr = reg["slope"], reg["intercept"], reg["r"], reg["stderr"]
    if not np.isfinite(slope).any():
        raise InputError(
            f"{source}: variable {variable!r}: no height has two bins with at least "
            f"min_periods={min_periods} "
            f"periods, so no regression is possible (bins per height: "
            f"{dict(zip(map(float, records.height.values), keep.sum('bin').values.tolist(), strict=True))})"
        )
    xstd, n_used = xr.apply_ufunc(
        kernels.std_in_kept_bins, x, diff, keep, kwargs={"edges": edges},
        input_core_dims=[["time"], ["time"], ["bin"]],
        output_core_dims=[[], []], dask="parallelized", output_dtypes=[float, np.int64],
        dask_gufunc_kwargs={"allow_rechunk": True},
    )
    xstd, n_used = xstd.compute().values, n_used.compute().values
    m_std, m_std_r, sig12, sig13 = kernels.significance(
        slope, xstd, r, threshold_12=THRESHOLD_EQ12, threshold_13=THRESHOLD_EQ13)
    return {
        "mean_difference": mean_kept.values, "std_difference": std.values,
        "sample_count": count.values.astype(np.int32), "variable_mean": mean_x.values,
        "bin_flag": np.where(keep.values, 0, np.where(count.values > 0, 1, 2)).astype(np.int8),
        "slope": slope, "slope_standard_error": stderr, "slope_ci_low": reg["ci_low"],
        "slope_ci_high": reg["ci_high"], "reduced_chi_square": reg["chi2_reduced"],
        "regression_weight": weight, "intercept": intercept, "correlation": r,
        "variable_std": xstd, "periods_used": n_used.astype(np.int32),
        "bins_used": keep.sum("bin").values.astype(np.int32),
        "slope_times_std": m_std, "slope_times_std_times_r": m_std_r,
        "significant_eq12": sig12.astype(np.int8), "significant_eq13": sig13.astype(np.int8),
        "significant": (sig12 | sig13).astype(np.int8),
    }


def _assemble(records: xr.Dataset, variable: str, units: str, relative: bool, edges: np.ndarray,
              fit: Mapping[str, np.ndarray], config: dict[str, Any], call: str | None) -> xr.Dataset:
    """Build the ``sensitivity`` artefact: ``fit`` with the attributes of its schema, stamped."""
    xname = variable.replace("_", " ")
    diff_units = "%" if relative else "m s-1"
    context = dict(
        xname=xname, units=units, standard_name=STANDARD_NAMES.get(variable) or "", diff_units=diff_units,
        slope_units=per_unit(diff_units, units), relative="relative " if relative else "",
        mean_comment="relative to each period's reference wind speed, then averaged" if relative else "",
        statistic_comment="" if relative else _ABSOLUTE_COMMENT, threshold_eq12=THRESHOLD_EQ12,
        threshold_eq13=THRESHOLD_EQ13)
    centres = 0.5 * (edges[:-1] + edges[1:])
    ds = xr.Dataset(
        {name: (("height", "bin") if np.ndim(values) == 2 else ("height",), values,
                output_attrs("sensitivity", name, **context)) for name, values in fit.items()},
        coords={"height": records["height"].variable.copy(),
                "bin": ("bin", centres, output_attrs("sensitivity", "bin", **context))},
    )
    ds["height"].attrs = dict(records["height"].attrs)
    ds = with_bounds(ds, "bin", edges)
    ds.attrs = {
        "environmental_variable": variable,
        "environmental_variable_units": units,
        "difference_definition": ("100 % * (lidar_wind_speed - reference_wind_speed) / reference_wind_speed"
                                  if relative else "lidar_wind_speed - reference_wind_speed"),
        "regression_method": config["regression"],
        "min_samples": config["min_samples"],
        "records_kind": read_attr(records, "lidarcal_artefact", default="unknown"),
    }
    serial = lidar_serial(records.attrs)
    if serial:
        ds.attrs["lidar_serial"] = serial
    return stamp(
        ds, "sensitivity",
        title=f"Sensitivity of lidar wind speed to {xname}",
        summary=(f"IEC 61400-50-2 style sensitivity of the lidar-reference wind speed difference to {xname} "
                 f"per height: binned means, {config['regression']}, Eqs. 12-13 tests."),
        call=call or f"lidarcal.analysis.sensitivity(records, {variable!r})",
        input_datasets={"records": records}, config=config,
    )


def sensitivities(records: xr.Dataset, variables: Iterable[str], **kwargs: Any) -> dict[str, xr.Dataset]:
    """:func:`sensitivity` for several variables; ``bin_width`` may be a mapping per variable."""
    widths = kwargs.pop("bin_width", None)
    out = {}
    for v in variables:
        w = widths.get(v) if isinstance(widths, Mapping) else widths
        out[v] = sensitivity(records, v, bin_width=w, **kwargs)
    return out


def compare_slopes(results: Mapping[str, xr.Dataset]) -> xr.Dataset:
    """Line up slopes of several sensitivity artefacts of one variable (paper Figure 8).

    ``results`` maps a label (``"simulated"``, ``"classification #1"`` ...) to a sensitivity
    artefact; the output has a ``source`` dimension and the union of their heights (NaN
    where a source has no such height).
    """
    if not results:
        raise InputError("compare_slopes needs at least one sensitivity dataset")
    names = {read_attr(ds, "environmental_variable", kind="sensitivity") for ds in results.values()}
    if len(names) != 1:
        raise InputError(f"cannot compare slopes of different variables: {sorted(map(str, names))}")
    keep = ["slope", "intercept", "correlation", "variable_std", "slope_times_std",
            "slope_times_std_times_r", "significant"]
    parts = [ds[keep] for ds in results.values()]
    out = xr.concat(parts, dim=xr.DataArray(list(results), dims="source", name="source"), join="outer",
                    combine_attrs="drop_conflicts")
    out["source"].attrs = {"long_name": "origin of the sensitivity (simulation or field campaign)"}
    out.attrs = {"environmental_variable": names.pop()}
    return out
