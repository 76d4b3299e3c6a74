r"""Calibration uncertainty budget per height and 0.5 m s-1 wind-speed bin (paper §3.4).

The records (``simulated_rtd`` or ``field_campaign``) are binned by the **reference** wind
speed, as IEC 61400-50-2 does, in bins centred on integer multiples of the bin width
(0.5 m s-1: the 8 m s-1 bin is [7.75, 8.25)).  Per (height, bin) the standard-uncertainty
contributors are, for the two approaches of Figure 9:

``monte_carlo`` (SAFO-MV + virtual lidar)
    ``virtual_reference`` — Table 4 total (Eqs. 6–11) at the bin centre, from an
    ``uncertainty_terms`` artefact (interpolated) or computed with :mod:`lidarcal.analysis.terms`;
    ``mean_difference`` — \\|mean(lidar − reference)\\|;
    ``std_difference`` — standard deviation σ_diff of lidar − reference (ddof = 1);
    ``statistical`` — σ_diff / √N;
    ``model_form`` — the simulation's model form, when the records carry the model-form runs
    (:mod:`lidarcal.analysis.model_form`): raises the combined standard uncertainty by the
    spread of its value across the defensible alternative models.
``iec`` (field calibration against a mast)
    ``reference_sensor`` — √(u_abs² + (u_rel·Ū)²) from the anemometer calibration;
    ``mean_difference``; ``statistical`` — σ_diff / √N; ``mounting``, ``separation`` and
    ``flow_inhomogeneity`` — relative terms × Ū (default 0).

They are combined in quadrature into ``uncertainty`` (m s-1); ``relative_uncertainty`` (%)
is relative to the bin's mean reference wind speed Ū; ``expanded_uncertainty`` is
k × ``uncertainty`` (k = 2 by default).

**What is certified** — one rule, :func:`certified_bins`, used by the budget, the certificate,
``lidarcal table``, the report and the headline: a bin is certified when its centre lies in the
certified wind-speed range (:data:`DEFAULT_CERTIFIED_RANGE`, 4 to 16 m s-1) and it holds at
least ``min_periods`` distinct 10-minute periods of the conditions record
(:data:`DEFAULT_MIN_PERIODS` = 10).  ``bin_flag`` says which bins are (``certified``) and why
the others are not (``too_few_periods``, ``empty``, ``outside_certified_range``); no bin is
dropped.

**Monte Carlo replicas** (JCGM 101 §7.9) — ``simulated_rtd`` records may carry further trials
of the same periods with independent seed streams (variables ``trial_*`` on a ``trial`` dim,
written by :mod:`lidarcal.campaign.adaptive`).  Every trial enters the bin statistics:
``sample_count`` counts trials, ``period_count`` distinct periods.  Each replica's own estimate
of a certified bin's relative expanded uncertainty gives the numerical tolerance of the value,
``numerical_tolerance`` = the smallest ½·10^ℓ at least 2·s/√h (s: standard deviation of the h
replica estimates, JCGM 101 §7.9.4), and ``numerical_flag`` says whether it settled to
``significant_digits`` significant digits (:func:`numerical_state`).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis import kernels
from lidarcal.analysis._records import checked, select_heights
from lidarcal.analysis.model_form import model_form_term
from lidarcal.analysis.terms import PAPER_INPUTS, uncertainty_terms
from lidarcal.binning import bin_index, binned_statistics
from lidarcal.cf import with_bounds
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import source_name
from lidarcal.provenance import stamp
from lidarcal.schema import with_output_attrs
from lidarcal.units import Q_, convert_values, to_magnitude

__all__ = ["budget", "certified_bins", "numerical_state", "tolerance_exponent", "CONTRIBUTORS",
           "DEFAULT_CERTIFIED_RANGE", "DEFAULT_MIN_PERIODS", "DEFAULT_SIGNIFICANT_DIGITS", "TRIAL_VARIABLES"]

#: Contributors of each approach, in the order of the ``contributor`` dimension.
CONTRIBUTORS = {
    "monte_carlo": ("virtual_reference", "mean_difference", "std_difference", "statistical", "model_form"),
    "iec": ("reference_sensor", "mean_difference", "statistical", "mounting", "separation",
            "flow_inhomogeneity"),
}

_CONTRIBUTOR_NAMES = {
    "virtual_reference": "virtual reference uncertainty (Table 4 total, Eqs. 6-11)",
    "mean_difference": "absolute mean lidar minus reference difference",
    "std_difference": "standard deviation of the lidar minus reference difference",
    "statistical": "standard uncertainty of the mean difference, sigma_diff / sqrt(N)",
    "model_form": "simulation model form, the spread of the combined uncertainty across the defensible "
                  "alternative models (common random numbers)",
    "reference_sensor": "reference anemometer standard uncertainty",
    "mounting": "lidar mounting",
    "separation": "separation between lidar and reference mast",
    "flow_inhomogeneity": "flow inhomogeneity across the lidar measurement volume",
}

#: Certified wind-speed range: bin centres (m s-1, inclusive) a certified bin may have.
DEFAULT_CERTIFIED_RANGE = (4.0, 16.0)
#: Fewest distinct 10-minute periods of the conditions record in a certified bin, and in a bin
#: entering a sensitivity regression (:mod:`lidarcal.analysis.sensitivity`): one rule for a bin
#: that counts.  IEC 61400-50-2 drops bins "that do not contain sufficient sample number" without
#: a number in any text available here, so this is lidarcal's documented choice: 10 periods give
#: the bin variance 9 degrees of freedom, enough for its inverse (the weight n / s²) to have a
#: finite mean (inflated 9/7) and variance, and for the bin mean to be close to normal
#: (docs/sensitivity.md).
DEFAULT_MIN_PERIODS = 10
#: Significant digits the Monte Carlo settles every certified value to (JCGM 101 §7.9).
DEFAULT_SIGNIFICANT_DIGITS = 2
#: Variables (dim ``trial``) of the further Monte Carlo replicas in ``simulated_rtd`` records.
TRIAL_VARIABLES = ("trial_replica", "trial_period_key", "trial_height", "trial_lidar_wind_speed",
                   "trial_reference_wind_speed")


def _fraction(value: Any, name: str) -> float:
    out = float(to_magnitude(value, "1", name=name))
    if not 0 <= out < 1:
        raise InputError(f"argument {name!r}: expected a fraction in [0, 1) (e.g. '0.5 %'); got {value!r}")
    return out


def _terms_total(
    terms: xr.Dataset | None, centres: np.ndarray, heights: np.ndarray, noise_terms: str = "printed"
) -> tuple[np.ndarray, str]:
    """Table 4 total (m s-1) on (height, bin centre) and a description of where it came from.

    Without ``terms`` the paper's inputs (:data:`lidarcal.analysis.terms.PAPER_INPUTS`) are used with
    the measurement height of each budget height (Eq. 11 scales with 1/z).  Bin centres at
    or below 0 m s-1 get NaN (Table 4 is defined for U > 0).
    """
    positive = centres > 0
    if terms is None:
        out = np.full((len(heights), len(centres)), np.nan)
        at = uncertainty_terms(Q_(centres[positive], "m s-1"), **{**PAPER_INPUTS, "height": Q_(heights, "m")},
                               noise_terms=noise_terms)
        out[:, positive] = at.total.transpose("height", "wind_speed").values
        how = "" if noise_terms == "printed" else f", noise_terms={noise_terms!r}"
        return out, f"lidarcal.analysis.terms.uncertainty_terms(**PAPER_INPUTS{how}) at each budget height"
    if noise_terms != "printed" and terms.attrs.get("noise_terms", "printed") != noise_terms:
        raise InputError(f"{source_name(terms, '<terms>')}: the terms artefact has noise_terms="
                         f"{terms.attrs.get('noise_terms', 'printed')!r}; asked for {noise_terms!r} "
                         "(recompute it with lidarcal terms --noise-terms)")
    src = source_name(terms, "<terms>")
    if "total" not in terms.data_vars:
        raise MissingVariableError(f"{src}: no Table 4 total variable 'total'; found "
                                   f"{sorted(map(str, terms.data_vars))}")
    total = terms["total"]
    if "wind_speed" not in total.dims:
        raise InputError(f"{src}: variable 'total' has dims {tuple(total.dims)}; expected a 'wind_speed' dim")
    values = convert_values(total.values, total.attrs.get("units"), "m s-1", where=f"{src}: variable 'total'")
    total = total.copy(data=values)
    ws = np.asarray(terms["wind_speed"].values, dtype=float)
    lo, hi = float(ws.min()), float(ws.max())
    need = centres[positive] if positive.any() else centres
    if need.min() < lo - 1e-9 or need.max() > hi + 1e-9:
        raise InputError(
            f"{src}: variable 'total' covers wind speeds {lo:g}-{hi:g} m s-1; the budget needs "
            f"{need.min():g}-{need.max():g} m s-1 (no extrapolation); recompute the terms over "
            "that range"
        )
    out = total.interp(wind_speed=np.where(positive, centres, np.nan))
    if "height" in out.dims:
        th = np.asarray(terms["height"].values, dtype=float)
        if heights.min() < th.min() - 1e-6 or heights.max() > th.max() + 1e-6:
            raise InputError(f"{src}: terms cover heights {th.min():g}-{th.max():g} m; budget needs "
                             f"{heights.min():g}-{heights.max():g} m")
        out = out.interp(height=heights) if th.size > 1 else out.isel(height=[0] * len(heights))
        arr = out.transpose("height", "wind_speed").values
    else:
        extra = [d for d in out.dims if d != "wind_speed"]
        if extra:
            raise InputError(f"{src}: variable 'total' has unexpected dims {extra}")
        arr = np.broadcast_to(out.values, (len(heights), len(centres)))
    origin = src
    if "height" in terms.coords and terms["height"].ndim == 0:
        origin += f" (evaluated at z = {float(terms['height']):g} m, used for every height)"
    return np.asarray(arr, dtype=float), origin


def certified_bins(centres: np.ndarray, period_count: np.ndarray, *,
                   certified_range: tuple[float, float] = DEFAULT_CERTIFIED_RANGE,
                   min_periods: int = DEFAULT_MIN_PERIODS) -> np.ndarray:
    """Return the ``bin_flag`` of every bin (int8, ``(..., bin)``): the one rule for what is certified.

    0 ``certified`` (centre in ``certified_range`` m s-1, inclusive, and at least ``min_periods``
    distinct periods), 1 ``too_few_periods``, 2 ``empty`` (no period), 3
    ``outside_certified_range`` (a non-empty bin whose centre is outside the range).

    >>> certified_bins(np.array([2.0, 8.0, 8.5, 9.0]), np.array([50, 12, 9, 0])).tolist()
    [3, 0, 1, 2]
    """
    lo, hi = (float(v) for v in certified_range)
    centres = np.asarray(centres, dtype=float)
    n = np.asarray(period_count)
    inside = (centres >= lo - 1e-9) & (centres <= hi + 1e-9)
    flag = np.where(n >= int(min_periods), 0, 1)
    flag = np.where(inside, flag, 3)
    return np.where(n > 0, flag, 2).astype(np.int8)


def tolerance_exponent(spread: np.ndarray) -> np.ndarray:
    """Smallest integer ℓ with ½·10^ℓ ≥ ``spread`` (= 2 s/√h); NaN where ``spread`` is NaN.

    >>> tolerance_exponent(np.array([0.04, 0.05, 0.051, 0.3])).astype(int).tolist()
    [-1, -1, 0, 0]
    """
    spread = np.asarray(spread, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        ell = np.ceil(np.log10(2.0 * spread) - 1e-12)
    return np.where(spread > 0, ell, np.where(spread == 0, -np.inf, np.nan))


def numerical_state(value: np.ndarray, estimates: np.ndarray, certified: np.ndarray,
                    significant_digits: int = DEFAULT_SIGNIFICANT_DIGITS
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Numerical tolerance of each value from its replica estimates (JCGM 101 §7.9.4).

    ``estimates`` (..., replica) holds every replica's own estimate of ``value`` (...) (NaN where
    a replica did not estimate it).  With h ≥ 2 estimates and s their standard deviation, the
    value reached the tolerance δ = ½·10^ℓ, ℓ the smallest integer with δ ≥ 2 s/√h; it has
    settled to ``significant_digits`` digits when δ ≤ ½·10^(e − N + 1), e the decimal exponent of
    ``value`` (JCGM 101 §7.9.2).  Returns (tolerance, flag, h): flag 0 ``settled``, 1
    ``not_settled``, 2 ``not_certified`` (``certified`` False: not assessed).
    """
    est = np.asarray(estimates, dtype=float)
    h = np.isfinite(est).sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN cells: NaN, no warning
        s = np.nanstd(est, axis=-1, ddof=1)
        spread = np.where(h >= 2, 2.0 * s / np.sqrt(np.maximum(h, 1)), np.nan)
        ell = tolerance_exponent(spread)
        tol = np.where(np.isfinite(ell) | (ell == -np.inf), 0.5 * 10.0 ** ell, np.nan)
        v = np.abs(np.asarray(value, dtype=float))
        target = np.floor(np.log10(np.where(v > 0, v, np.nan))) - int(significant_digits) + 1
    settled = np.isfinite(tol) & np.isfinite(target) & (ell <= target)
    flag = np.where(np.asarray(certified, dtype=bool), np.where(settled, 0, 1), 2).astype(np.int8)
    return tol, flag, h


#: Relative (fraction of the bin mean reference speed) inputs of the IEC approach.
_IEC_FRACTIONS = ("reference_relative_uncertainty", "mounting", "separation", "flow_inhomogeneity")


def budget(
    records: xr.Dataset,
    *,
    terms: xr.Dataset | None = None,
    approach: str = "monte_carlo",
    bin_width: Any = "0.5 m s-1",
    min_periods: int = DEFAULT_MIN_PERIODS,
    certified_range: tuple[float, float] = DEFAULT_CERTIFIED_RANGE,
    significant_digits: int = DEFAULT_SIGNIFICANT_DIGITS,
    heights: Iterable[float] | None = None,
    coverage_factor: float = 2.0,
    reference_uncertainty: Any = None,
    reference_relative_uncertainty: Any = 0.0,
    mounting: Any = 0.0,
    separation: Any = 0.0,
    flow_inhomogeneity: Any = 0.0,
    noise_terms: str = "printed",
    model_form: bool = True,
    source: str | None = None,
    call: str | None = None,
) -> xr.Dataset:
    """Uncertainty budget per height and reference wind-speed bin.

    Parameters
    ----------
    records : xarray.Dataset
        ``simulated_rtd`` (``approach="monte_carlo"``) or ``field_campaign`` (``"iec"``)
        records with ``lidar_wind_speed`` and ``reference_wind_speed`` on (time, height).
    terms : xarray.Dataset, optional
        ``uncertainty_terms`` artefact (Table 4 total on a ``wind_speed`` dim, optionally also
        ``height``); Monte Carlo approach only.  Default: :mod:`lidarcal.analysis.terms` defaults.
    noise_terms : {"printed", "derived"}
        Form of Eqs. 6-7 when the terms are computed here (no ``terms`` given); see
        :mod:`lidarcal.analysis.terms`.  With ``terms`` the artefact's own form is used.
    approach : {"monte_carlo", "iec"}
    bin_width : quantity or str
        Wind-speed bin width (default 0.5 m s-1).
    min_periods : int
        Fewest distinct 10-minute periods a certified bin holds (default 10; :func:`certified_bins`).
    certified_range : (float, float)
        Bin centres (m s-1, inclusive) a certified bin may have (default 4 to 16).
    significant_digits : int
        Digits the Monte Carlo must settle every certified value to (``numerical_flag``;
        default 2).  Needs records with replicas (``trial_*`` variables) to be assessed.
    heights : sequence of float, optional
        Heights (m) to include; a height not in the records is an error.
    coverage_factor : float
        k of the expanded uncertainty (default 2).
    reference_uncertainty : quantity or str
        IEC approach: absolute standard uncertainty of the calibrated anemometer, e.g. "0.1 m s-1".
    model_form : bool
        Monte Carlo approach: add the ``model_form`` contributor when the records carry the
        model-form runs (``model_form_*`` variables, :mod:`lidarcal.campaign.model_form`); without
        them (or with False) the contributor is left out.
    reference_relative_uncertainty, mounting, separation, flow_inhomogeneity : fraction or str
        IEC approach: relative standard uncertainties ("0.5 %" or 0.005), multiplied by the
        bin's mean reference wind speed.
    source, call : str, optional
        File name for messages and the command recorded in ``history``.

    Returns
    -------
    xarray.Dataset
        An ``uncertainty_budget`` artefact on (height, wind_speed[, contributor]).
    """
    source = source or source_name(records)
    if approach not in CONTRIBUTORS:
        raise InputError(f"approach must be one of {sorted(CONTRIBUTORS)}; got {approach!r}")
    if int(min_periods) < 2:
        raise InputError(f"min_periods must be >= 2 (a standard deviation needs two periods); "
                         f"got {min_periods}")
    certified_range = _certified_range(certified_range)
    if int(significant_digits) < 1:
        raise InputError(f"significant_digits must be >= 1; got {significant_digits}")
    width = float(to_magnitude(bin_width, "m s-1", name="bin_width"))
    if not width > 0:
        raise InputError(f"bin_width must be positive; got {bin_width!r}")
    k = float(coverage_factor)
    records = select_heights(records, heights, source=source)
    edges, binned = _binned(records, width, source)
    centres = 0.5 * (edges[:-1] + edges[1:])
    config: dict[str, Any] = {"approach": approach, "bin_width_m_s-1": width, "min_periods": int(min_periods),
                              "certified_range_m_s-1": list(certified_range),
                              "significant_digits": int(significant_digits),
                              "coverage_factor": k, "binned_by": "reference_wind_speed",
                              "relative_to": "mean reference wind speed in the bin"}
    if approach == "monte_carlo":
        vref, config["virtual_reference_terms"] = _terms_total(
            terms, centres, np.asarray(records["height"].values, dtype=float), noise_terms)
        parts = _monte_carlo_parts(binned, vref)
        mf = model_form_term(records, edges, binned, vref, k, source=source) if model_form else None
        if mf is not None:
            parts["model_form"], config["model_form"] = mf["contribution"], mf["config"]
        binned["estimates"] = _replica_estimates(binned, vref, k, parts.get("model_form"))
    else:
        u_abs, rel = _iec_inputs(terms, reference_uncertainty, dict(zip(_IEC_FRACTIONS, (
            reference_relative_uncertainty, mounting, separation, flow_inhomogeneity), strict=True)))
        config.update({"reference_uncertainty_m_s-1": u_abs, **{f"{a}_fraction": b for a, b in rel.items()}})
        parts = _iec_parts(binned, u_abs, rel)
        mf = None
    names = tuple(c for c in CONTRIBUTORS[approach] if c in parts)
    contribution = np.stack([np.broadcast_to(parts[c], binned["n"].shape) for c in names], axis=-1)
    rule = {"min_periods": int(min_periods), "certified_range": certified_range,
            "significant_digits": int(significant_digits)}
    return _assemble(records, terms, names, edges, binned, contribution, rule, k, config, call, mf)


def _certified_range(value: Any) -> tuple[float, float]:
    def speed(v: Any) -> float:  # bare numbers are m s-1 here (the range is documented in m s-1)
        return float(v) if isinstance(v, int | float | np.number) else float(
            to_magnitude(v, "m s-1", name="certified_range"))

    try:
        lo, hi = (speed(v) for v in value)
    except (TypeError, ValueError):
        raise InputError(f"certified_range must be two wind speeds (m s-1), low and high; "
                         f"got {value!r}") from None
    if not 0 <= lo <= hi:
        raise InputError(f"certified_range must satisfy 0 <= low <= high; got {lo:g} to {hi:g} m s-1")
    return lo, hi


def _binned(records: xr.Dataset, width: float, source: str) -> tuple[np.ndarray, dict[str, Any]]:
    """Bin edges centred on multiples of ``width`` and the per-(height, bin) statistics.

    Without replicas (no ``trial_*`` variables) the records are binned lazily (Dask-friendly);
    with them every trial of every replica enters the statistics, and each replica's own
    statistics are kept for its estimates (:func:`_replica_estimates`).
    """
    lidar = checked(records, "lidar_wind_speed", source=source)
    ref = checked(records, "reference_wind_speed", source=source)
    if "trial_replica" in records.variables:
        return _binned_replicas(records, lidar, ref, width, source)
    ok = np.isfinite(lidar) & np.isfinite(ref)
    diff = (lidar - ref).where(ok)
    refv = ref.where(ok)
    lo, hi = float(refv.min().compute()), float(refv.max().compute())
    if not np.isfinite(lo):
        raise InputError(f"{source}: no period has both lidar_wind_speed and reference_wind_speed; "
                         "nothing to put in a budget")
    edges = kernels.centred_edges(lo, hi, width)
    nb = len(edges) - 1

    def _stats(x, y, z):
        n, md, sd, mref = binned_statistics(x, y, edges)
        _, mlid, _, _ = binned_statistics(x, z, edges)
        return n, md, sd, mref, mlid

    outs = xr.apply_ufunc(
        _stats, refv, diff, lidar.where(ok), input_core_dims=[["time"]] * 3,
        output_core_dims=[["wind_speed"]] * 5, dask="parallelized",
        output_dtypes=[np.int64, float, float, float, float],
        dask_gufunc_kwargs={"output_sizes": {"wind_speed": nb}, "allow_rechunk": True},
    )
    n, mean_diff, std_diff, mean_ref, mean_lidar = (np.asarray(o.compute().values) for o in outs)
    with np.errstate(invalid="ignore", divide="ignore"):
        statistical = std_diff / np.sqrt(n)
    # one record per period and height: the trials are the periods
    return edges, {"n": n, "mean_difference": mean_diff, "std_difference": std_diff,
                   "mean_reference": mean_ref, "mean_lidar": mean_lidar, "statistical": statistical,
                   "period_count": n, "replicas": [{"n": n, "mean_difference": mean_diff,
                                                     "std_difference": std_diff, "mean_reference": mean_ref,
                                                     "targeted": n > 0}]}


def _trial_arrays(records: xr.Dataset, heights: np.ndarray, source: str) -> dict[str, np.ndarray]:
    """Return the ``trial_*`` variables as arrays, each trial's height as an index into ``heights``."""
    missing = [n for n in TRIAL_VARIABLES if n not in records.variables]
    if missing:
        raise MissingVariableError(f"{source}: replica trials need the variables {list(TRIAL_VARIABLES)}; "
                                   f"missing {missing}")
    out = {}
    for name in ("trial_lidar_wind_speed", "trial_reference_wind_speed"):
        var = records[name]
        out[name] = convert_values(np.asarray(var.values, dtype=float), var.attrs.get("units"), "m s-1",
                                   where=f"{source}: variable {name!r}")
    th = convert_values(np.asarray(records["trial_height"].values, dtype=float),
                        records["trial_height"].attrs.get("units"), "m",
                        where=f"{source}: variable 'trial_height'")
    hidx = np.full(th.shape, -1)
    for i, z in enumerate(heights):
        hidx[np.abs(th - z) < 1e-3] = i
    out["height_index"] = hidx
    out["replica"] = np.asarray(records["trial_replica"].values, dtype=np.int64)
    out["period_key"] = np.asarray(records["trial_period_key"].values, dtype=np.int64)
    return out


def _binned_replicas(records: xr.Dataset, lidar: xr.DataArray, ref: xr.DataArray, width: float,
                     source: str) -> tuple[np.ndarray, dict[str, Any]]:
    """:func:`_binned` over replica 0 (the (time, height) records) and every further trial."""
    heights = np.asarray(records["height"].values, dtype=float)
    lid0, ref0 = np.asarray(lidar.values), np.asarray(ref.values)  # (time, height)
    if "period_key" not in records.variables:
        raise MissingVariableError(f"{source}: replica trials need the variable 'period_key' of replica 0")
    key0 = np.asarray(records["period_key"].values, dtype=np.int64)
    tr = _trial_arrays(records, heights, source)
    t_ok = (tr["height_index"] >= 0) & np.isfinite(tr["trial_lidar_wind_speed"]) & np.isfinite(
        tr["trial_reference_wind_speed"])
    ok0 = np.isfinite(lid0) & np.isfinite(ref0)
    allref = np.concatenate([ref0[ok0], tr["trial_reference_wind_speed"][t_ok]])
    if not allref.size:
        raise InputError(f"{source}: no period has both lidar_wind_speed and reference_wind_speed; "
                         "nothing to put in a budget")
    edges = kernels.centred_edges(float(allref.min()), float(allref.max()), width)
    nh, nb = len(heights), len(edges) - 1
    replicas = sorted({0, *(int(r) for r in np.unique(tr["replica"]))})
    shape = (nh, nb)
    pooled = {k: np.full(shape, np.nan) for k in ("mean_difference", "std_difference", "mean_reference",
                                                  "mean_lidar")}
    pooled["n"] = np.zeros(shape, dtype=np.int64)
    pooled["period_count"] = np.zeros(shape, dtype=np.int64)
    per = [{"n": np.zeros(shape, dtype=np.int64), "mean_difference": np.full(shape, np.nan),
            "std_difference": np.full(shape, np.nan), "mean_reference": np.full(shape, np.nan),
            "targeted": np.zeros(shape, dtype=bool)} for _ in replicas]
    pos = {r: j for j, r in enumerate(replicas)}
    for i in range(nh):
        sel = t_ok & (tr["height_index"] == i)
        x = np.concatenate([ref0[ok0[:, i], i], tr["trial_reference_wind_speed"][sel]])
        lid = np.concatenate([lid0[ok0[:, i], i], tr["trial_lidar_wind_speed"][sel]])
        keys = np.concatenate([key0[ok0[:, i]], tr["period_key"][sel]])
        rep = np.concatenate([np.zeros(int(ok0[:, i].sum()), dtype=np.int64), tr["replica"][sel]])
        n, md, sd, mref = binned_statistics(x, lid - x, edges)
        _, mlid, _, _ = binned_statistics(x, lid, edges)
        pooled["n"][i], pooled["mean_difference"][i], pooled["std_difference"][i] = n, md, sd
        pooled["mean_reference"][i], pooled["mean_lidar"][i] = mref, mlid
        b = bin_index(x, edges)
        pairs = np.unique(np.stack([b[b >= 0], keys[b >= 0]]), axis=1)
        pooled["period_count"][i] = np.bincount(pairs[0], minlength=nb)
        # the replica-0 bin of every period with a reference value: the cells a replica targets
        has_ref0 = np.isfinite(ref0[:, i])
        b0 = bin_index(ref0[has_ref0, i], edges)
        k0 = key0[has_ref0]
        for r in replicas:
            mine = rep == r
            rn, rmd, rsd, rmref = binned_statistics(x[mine], (lid - x)[mine], edges)
            d = per[pos[r]]
            d["n"][i], d["mean_difference"][i] = rn, rmd
            d["std_difference"][i], d["mean_reference"][i] = rsd, rmref
            if r == 0:
                d["targeted"][i] = rn > 0
                continue
            # replica r estimates a cell only if it re-simulated every period replica 0 put in it
            done = np.isin(k0, tr["period_key"][(tr["replica"] == r) & (tr["height_index"] == i)])
            missed = np.bincount(b0[(b0 >= 0) & ~done], minlength=nb)
            present = np.bincount(b0[b0 >= 0], minlength=nb)
            d["targeted"][i] = (present > 0) & (missed == 0) & (rn > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        pooled["statistical"] = pooled["std_difference"] / np.sqrt(pooled["n"])
    pooled["replicas"] = per
    return edges, pooled


def _replica_estimates(binned: Mapping[str, Any], vref: np.ndarray, k: float,
                       model_form: np.ndarray | None = None) -> np.ndarray:
    """Each replica's own relative expanded uncertainty (%) per (height, bin, replica); NaN where none.

    ``model_form`` (the pooled contributor, one value per bin) enters every replica's estimate alike.
    """
    out = []
    for d in binned["replicas"]:
        with np.errstate(invalid="ignore", divide="ignore"):
            parts = _monte_carlo_parts({**d, "statistical": d["std_difference"] / np.sqrt(d["n"])}, vref)
            if model_form is not None:
                parts["model_form"] = model_form
            combined = kernels.quadrature(*(np.broadcast_to(parts[c], d["n"].shape)
                                            for c in CONTRIBUTORS["monte_carlo"] if c in parts))
            value = k * combined * 100.0 / d["mean_reference"]
        out.append(np.where(d["targeted"], value, np.nan))
    return np.stack(out, axis=-1)


def _monte_carlo_parts(binned: Mapping[str, np.ndarray], vref: np.ndarray) -> dict[str, np.ndarray]:
    """Contributors of the SAFO-MV + virtual lidar approach (m s-1)."""
    return {"virtual_reference": vref, "mean_difference": np.abs(binned["mean_difference"]),
            "std_difference": binned["std_difference"], "statistical": binned["statistical"]}


def _iec_inputs(terms: xr.Dataset | None, reference_uncertainty: Any,
                fractions: Mapping[str, Any]) -> tuple[float, dict[str, float]]:
    """Check the IEC approach's inputs; return u_abs (m s-1) and the relative terms (fractions)."""
    if terms is not None:
        raise InputError("terms apply to the Monte Carlo approach only; the IEC approach uses "
                         "reference_uncertainty")
    if reference_uncertainty is None:
        raise InputError("the IEC approach needs the reference anemometer's standard uncertainty: "
                         "reference_uncertainty='0.1 m s-1' (--reference-uncertainty)")
    u_abs = float(to_magnitude(reference_uncertainty, "m s-1", name="reference_uncertainty"))
    return u_abs, {name: _fraction(v, name) for name, v in fractions.items()}


def _iec_parts(binned: Mapping[str, np.ndarray], u_abs: float,
               rel: Mapping[str, float]) -> dict[str, np.ndarray]:
    """Contributors of the IEC field approach (m s-1); relative terms scale with the bin mean reference."""
    mean_ref = binned["mean_reference"]
    return {
        "reference_sensor": np.sqrt(u_abs**2 + (rel["reference_relative_uncertainty"] * mean_ref) ** 2),
        "mean_difference": np.abs(binned["mean_difference"]), "statistical": binned["statistical"],
        "mounting": rel["mounting"] * mean_ref, "separation": rel["separation"] * mean_ref,
        "flow_inhomogeneity": rel["flow_inhomogeneity"] * mean_ref,
    }


def _assemble(records: xr.Dataset, terms: xr.Dataset | None, names: tuple[str, ...], edges: np.ndarray,
              binned: Mapping[str, Any], contribution: np.ndarray, rule: Mapping[str, Any], k: float,
              config: dict[str, Any], call: str | None, mf: Mapping[str, Any] | None = None) -> xr.Dataset:
    """Build the ``uncertainty_budget`` artefact with the attributes of its schema, stamped."""
    n, approach = binned["n"], config["approach"]
    combined = kernels.quadrature(contribution, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        pct = 100.0 / binned["mean_reference"]
    hw, hwc = ("height", "wind_speed"), ("height", "wind_speed", "contributor")
    values = {
        "uncertainty": (hw, combined), "relative_uncertainty": (hw, combined * pct),
        "expanded_uncertainty": (hw, k * combined), "relative_expanded_uncertainty": (hw, k * combined * pct),
        "contribution": (hwc, contribution), "relative_contribution": (hwc, contribution * pct[..., None]),
        "sample_count": (hw, n.astype(np.int32)),
        "period_count": (hw, np.asarray(binned["period_count"]).astype(np.int32)),
        "mean_reference_wind_speed": (hw, binned["mean_reference"]),
        "mean_lidar_wind_speed": (hw, binned["mean_lidar"]),
        "mean_difference": (hw, binned["mean_difference"]),
        "std_difference": (hw, binned["std_difference"]),
        "bin_flag": (hw, certified_bins(0.5 * (edges[:-1] + edges[1:]), binned["period_count"],
                                        certified_range=rule["certified_range"],
                                        min_periods=rule["min_periods"])),
    }
    if mf is not None:  # the model-form contributor's companions (lidarcal.analysis.model_form)
        values["model_form_standard_error"] = (hw, mf["standard_error"])
        values["model_form_sample_count"] = (hw, mf["sample_count"].astype(np.int32))
        values["model_form_shift"] = (hw + ("model_form_alternative",), mf["shift"])
    mc: dict[str, Any] = {}
    if "estimates" in binned:  # the Monte Carlo approach: how far its own numbers have settled
        tol, nflag, h = numerical_state(values["relative_expanded_uncertainty"][1], binned["estimates"],
                                        values["bin_flag"][1] == 0, rule["significant_digits"])
        values["numerical_tolerance"] = (hw, tol)
        values["numerical_flag"] = (hw, nflag)
        mc = {"monte_carlo_replicas": int(binned["estimates"].shape[-1]), "monte_carlo_trials": int(n.sum()),
              "monte_carlo_significant_digits": int(rule["significant_digits"]),
              "monte_carlo_settled": int((nflag == 0).sum()),
              "monte_carlo_not_settled": int((nflag == 1).sum())}
    lo, hi = rule["certified_range"]
    context = {"k": f"{k:g}", "coverage_factor": k, "min_periods": rule["min_periods"], "lo": lo, "hi": hi,
               "digits": rule["significant_digits"],
               "contributor_description": "; ".join(f"{c}: {_CONTRIBUTOR_NAMES[c]}" for c in names)}
    ds = xr.Dataset(
        {name: (dims, data) for name, (dims, data) in values.items()},
        coords={"height": records["height"].variable.copy(),
                "wind_speed": ("wind_speed", 0.5 * (edges[:-1] + edges[1:])),
                "contributor": ("contributor", np.array(names, dtype=object)),
                **({"model_form_alternative": ("model_form_alternative",
                                               np.array(mf["alternatives"], dtype=object))} if mf else {})},
    )
    ds = with_output_attrs(ds, "uncertainty_budget", **context)
    ds["height"].attrs = dict(records["height"].attrs)
    ds = with_bounds(ds, "wind_speed", edges)
    ds.attrs = {"approach": approach, "coverage_factor": k, "min_periods": rule["min_periods"],
                "certified_range_m_s": np.array([lo, hi]),
                "records_kind": str(records.attrs.get("lidarcal_artefact", "unknown")), **mc}
    serial = records.attrs.get("lidar_serial") or records.attrs.get("lidar_serial_number")  # .sta: _number
    if serial:
        ds.attrs["lidar_serial"] = serial
    title = {"monte_carlo": "SAFO-MV and Monte Carlo", "iec": "IEC 61400-50-2 field"}[approach]
    return stamp(
        ds, "uncertainty_budget",
        title=f"Lidar calibration uncertainty budget ({title} approach)",
        summary=("Standard uncertainty contributors per height and 0.5 m/s reference wind speed bin, "
                 "combined in quadrature, in m/s and %, with the expanded uncertainty (paper section 3.4)."),
        call=call or f"lidarcal.analysis.budget(records, approach={approach!r})",
        input_datasets={"records": records, **({"terms": terms} if terms is not None else {})}, config=config,
    )
