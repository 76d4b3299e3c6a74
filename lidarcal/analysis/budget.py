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
    ``statistical`` — σ_diff / √N, N the distinct 10-minute periods in the bin (``period_count``:
    replicas add trials, not periods of the atmosphere);
    ``model_form`` — the simulation's model form, when the records carry the model-form runs
    (:mod:`lidarcal.analysis.model_form`): raises the combined standard uncertainty by the
    spread of its value across the defensible alternative models.
``iec`` (field calibration against a mast)
    ``reference_sensor`` — √(u_abs² + (u_rel·Ū)²) from the anemometer calibration;
    ``mean_difference``; ``statistical`` — σ_diff / √N; ``mounting``, ``separation`` and
    ``flow_inhomogeneity`` — relative terms × Ū (default 0).

They are combined in quadrature into ``uncertainty`` (m s-1); ``relative_uncertainty`` (%)
is relative to the bin's mean reference wind speed Ū; ``expanded_uncertainty`` is
k × ``uncertainty`` (k = 2 by default): the value of the IEC-style tables.

**The Monte Carlo distribution** (JCGM 101, Monte Carlo approach): the measurand of a bin is the
error of one 10-minute mean of the lidar at that height and bin.  The trials represent the
contributors of :data:`EMPIRICAL_CONTRIBUTORS` (the mean and spread of lidar − reference); every
other contributor of the approach (the Table 4 terms, the statistical term, and any contributor
added to :data:`CONTRIBUTORS`) enters as one normal of their quadrature sum, convolved with the
trials (:mod:`lidarcal.analysis.distribution`).  Per bin the budget records the estimate
(``mean_difference``), its standard uncertainty (``error_standard_uncertainty``), the 95 %
coverage interval (``coverage_interval_lower``/``_upper``, probabilistically symmetric or
``shortest``), the effective degrees of freedom that widen it in thin bins, the probability
the distribution gives to ±U (``expanded_uncertainty_coverage``) and which statement the bin
certifies (``certified_statement``: ±U, or the interval where they differ materially).

**What is certified** — one rule, :func:`lidarcal.analysis.certification.certified_bins`,
applied here and read by the certificate, ``lidarcal table``, the documents and the DCC: a bin
is certified when its centre lies in the certified wind-speed range
(:data:`DEFAULT_CERTIFIED_RANGE`, 4 to 16 m s-1), it holds at least ``min_periods`` distinct
10-minute periods (:data:`DEFAULT_MIN_PERIODS` = 10) and, for the Monte Carlo approach, each of
its values has settled (JCGM 101 §7.9, :func:`lidarcal.analysis.certification.numerical_state`:
the estimate, u, both endpoints and U, to ``significant_digits`` significant digits of U, from
the replicas with a Student factor and from all trials by the delta method).  ``bin_flag``
says which bins are (``certified``) and why the others are not (``too_few_periods``,
``empty``, ``outside_certified_range``, ``not_settled``); no bin is dropped.

Replicas (``trial_*`` variables on a ``trial`` dim, :mod:`lidarcal.analysis.trials`) enter
every statistic; ``sample_count`` counts trials, ``period_count`` distinct periods.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis import kernels
from lidarcal.analysis._records import select_heights
from lidarcal.analysis.certification import (
    DEFAULT_CERTIFIED_RANGE,
    DEFAULT_MIN_PERIODS,
    DEFAULT_SIGNIFICANT_DIGITS,
    SETTLED_VALUES,
    certified_bins,
    certified_statement,
    effective_dof,
    numerical_state,
    settle_target,
)
from lidarcal.analysis.distribution import bin_values, delta_sds, grouped
from lidarcal.analysis.model_form import model_form_term
from lidarcal.analysis.montecarlo import COVERAGE_PROBABILITY, tolerance_exponent
from lidarcal.analysis.rule import COVERAGE_INTERVALS, CertificationRule
from lidarcal.analysis.terms import PAPER_INPUTS, table4_total
from lidarcal.analysis.trials import TRIAL_VARIABLES
from lidarcal.analysis.trials import binned as binned_trials
from lidarcal.cf import with_bounds
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import source_name
from lidarcal.provenance import lidar_serial, stamp
from lidarcal.readback import read_attr
from lidarcal.schema import with_output_attrs
from lidarcal.units import Q_, convert_values, to_magnitude

__all__ = ["budget", "certified_bins", "numerical_state", "tolerance_exponent", "CONTRIBUTORS",
           "EMPIRICAL_CONTRIBUTORS", "COVERAGE_INTERVALS", "DEFAULT_CERTIFIED_RANGE", "DEFAULT_MIN_PERIODS",
           "DEFAULT_SIGNIFICANT_DIGITS", "TRIAL_VARIABLES", "CertificationRule"]

#: Contributors of each approach, in the order of the ``contributor`` dimension.
CONTRIBUTORS = {
    "monte_carlo": ("virtual_reference", "mean_difference", "std_difference", "statistical", "model_form"),
    "iec": ("reference_sensor", "mean_difference", "statistical", "mounting", "separation",
            "flow_inhomogeneity"),
}
#: Monte Carlo contributors the trials themselves represent (their mean and spread); every other
#: contributor of the approach is convolved with the trials as a normal.
EMPIRICAL_CONTRIBUTORS = ("mean_difference", "std_difference")
#: Contributors estimated from the bin's N distinct periods: N − 1 degrees of freedom each
#: (Welch–Satterthwaite); the others are Type B, with infinitely many.
PERIOD_CONTRIBUTORS = ("std_difference", "statistical")
#: Kinds of coverage interval (JCGM 101 §7.7).
#: The values of a bin JCGM 101 7.9 settles.
SETTLED = tuple(SETTLED_VALUES)
#: Replicas beyond which no bin's need is predicted (``replicas_needed``).
_NEED_CAP = 1000

_CONTRIBUTOR_NAMES = {
    "virtual_reference": "virtual reference uncertainty (Table 4 total, Eqs. 6-11)",
    "mean_difference": "absolute mean lidar minus reference difference",
    "std_difference": "standard deviation of the lidar minus reference difference",
    "statistical": "standard uncertainty of the mean difference, sigma_diff / sqrt(N), N distinct periods",
    "model_form": "simulation model form, the spread of the combined uncertainty across the defensible "
                  "alternative models (common random numbers)",
    "reference_sensor": "reference anemometer standard uncertainty",
    "mounting": "lidar mounting",
    "separation": "separation between lidar and reference mast",
    "flow_inhomogeneity": "flow inhomogeneity across the lidar measurement volume",
}


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
        inputs = {**PAPER_INPUTS, "height": Q_(heights, "m")}
        out[:, positive] = table4_total(Q_(centres[positive], "m s-1"), **inputs, noise_terms=noise_terms)
        how = "" if noise_terms == "printed" else f", noise_terms={noise_terms!r}"
        return out, f"lidarcal.analysis.terms.uncertainty_terms(**PAPER_INPUTS{how}) at each budget height"
    found = read_attr(terms, "noise_terms", kind="uncertainty_terms")
    if noise_terms != "printed" and found != noise_terms:
        raise InputError(f"{source_name(terms, '<terms>')}: the terms artefact has noise_terms="
                         f"{found!r}; asked for {noise_terms!r} "
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


#: Relative (fraction of the bin mean reference speed) inputs of the IEC approach.
_IEC_FRACTIONS = ("reference_relative_uncertainty", "mounting", "separation", "flow_inhomogeneity")


def budget(
    records: xr.Dataset,
    *,
    terms: xr.Dataset | None = None,
    approach: str = "monte_carlo",
    bin_width: Any = "0.5 m s-1",
    rule: CertificationRule | Mapping[str, Any] | None = None,
    heights: Iterable[float] | None = None,
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
    rule : CertificationRule or mapping, optional
        What is certified and how (:class:`~lidarcal.analysis.rule.CertificationRule`, or a
        mapping of its fields; default its defaults): ``min_periods`` (10; :func:`certified_bins`),
        ``certified_range`` (bin centres 4 to 16 m s-1), ``significant_digits`` of each bin's U
        that the Monte Carlo must settle the bin's values to (``numerical_flag``; 2: a value
        settles only with at least two replicas, ``trial_*`` variables, and a certified bin whose
        values have not settled is flagged ``not_settled`` and not certified), ``coverage_factor``
        (k = 2) and ``coverage_interval`` (JCGM 101 §7.7: ``"symmetric"`` or ``"shortest"``).
    heights : sequence of float, optional
        Heights (m) to include; a height not in the records is an error.
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
    rule = CertificationRule.of(rule)
    width = float(to_magnitude(bin_width, "m s-1", name="bin_width"))
    if not width > 0:
        raise InputError(f"bin_width must be positive; got {bin_width!r}")
    k = rule.coverage_factor
    records = select_heights(records, heights, source=source)
    edges, binned = binned_trials(records, width, source)
    centres = 0.5 * (edges[:-1] + edges[1:])
    with np.errstate(invalid="ignore", divide="ignore"):
        binned["statistical"] = binned["std_difference"] / np.sqrt(binned["period_count"])
    config: dict[str, Any] = {"approach": approach, "bin_width_m_s-1": width,
                              **rule.record(monte_carlo=approach == "monte_carlo"),
                              "binned_by": "reference_wind_speed",
                              "relative_to": "mean reference wind speed in the bin"}
    mc = None
    if approach == "monte_carlo":
        vref, config["virtual_reference_terms"] = _terms_total(
            terms, centres, np.asarray(records["height"].values, dtype=float), noise_terms)
        parts = _monte_carlo_parts(binned, vref)
        config["coverage_probability"] = COVERAGE_PROBABILITY
        mf = model_form_term(records, edges, binned, vref, k, source=source) if model_form else None
        if mf is not None:
            parts["model_form"], config["model_form"] = mf["contribution"], mf["config"]
        mc = _monte_carlo_values(binned, parts, vref, k, centres, rule)
    else:
        u_abs, rel = _iec_inputs(terms, reference_uncertainty, dict(zip(_IEC_FRACTIONS, (
            reference_relative_uncertainty, mounting, separation, flow_inhomogeneity), strict=True)))
        config.update({"reference_uncertainty_m_s-1": u_abs, **{f"{a}_fraction": b for a, b in rel.items()}})
        parts = _iec_parts(binned, u_abs, rel)
        mf = None
    names = tuple(c for c in CONTRIBUTORS[approach] if c in parts)
    contribution = np.stack([np.broadcast_to(parts[c], binned["n"].shape) for c in names], axis=-1)
    return _assemble(records, terms, names, edges, binned, contribution, rule, k, config, call, mc, mf)


def _quadrature(parts: Mapping[str, np.ndarray], names: Iterable[str], shape: tuple[int, ...]) -> np.ndarray:
    return kernels.quadrature(*(np.broadcast_to(parts[c], shape) for c in names))


def _distribution_inputs(stats: Mapping[str, Any], parts: Mapping[str, np.ndarray], k: float
                         ) -> dict[str, np.ndarray]:
    """Per (height, bin), in % of the bin mean reference: σ of the terms not simulated, U, ν_eff, scale."""
    shape = stats["n"].shape
    names = [c for c in CONTRIBUTORS["monte_carlo"] if c in parts]
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = 100.0 / stats["mean_reference"]
        periods = np.asarray(stats["period_count"], dtype=float)
        nu = effective_dof({c: np.broadcast_to(parts[c], shape) for c in names if c != "mean_difference"},
                           {c: periods - 1 for c in PERIOD_CONTRIBUTORS})
    return {"scale": scale, "sigma": _quadrature(parts, [c for c in names if c not in EMPIRICAL_CONTRIBUTORS],
                                                  shape) * scale,
            "combined": _quadrature(parts, names, shape) * scale,
            "expanded": k * _quadrature(parts, names, shape) * scale, "nu": nu}


def _monte_carlo_values(binned: Mapping[str, Any], parts: Mapping[str, np.ndarray], vref: np.ndarray,
                        k: float, centres: np.ndarray, rule: CertificationRule) -> dict[str, Any]:
    """Return the Monte Carlo distribution of every bin and the numerical state of the certified ones.

    Pooled values from all trials (in % of the bin mean reference speed); each replica's own
    values for the bins it estimates; JCGM 101 §7.9 on the bins certified but for their
    numerical state (:func:`lidarcal.analysis.certification.numerical_state`).
    """
    shape = binned["n"].shape
    ncell = int(np.prod(shape))
    shortest = rule.coverage_interval == "shortest"
    pooled_in = _distribution_inputs(binned, parts, k)
    tr = binned["trials"]
    samples = grouped(tr["diff"] * pooled_in["scale"].ravel()[tr["cell"]], tr["cell"], ncell)
    flat = {name: v.ravel() for name, v in pooled_in.items()}
    values = bin_values(samples, flat["sigma"], flat["expanded"], flat["nu"], shortest=shortest)
    values["expanded_uncertainty"] = flat["expanded"]
    period_count = np.asarray(binned["period_count"]).ravel()
    strata = grouped(tr["period"], tr["cell"], ncell, fill=-1)
    sds = delta_sds(samples, strata, flat["sigma"], values, period_count, flat["combined"], k)
    # JCGM 101 7.9 on the bins that are certified but for their numerical state
    cand = certified_bins(centres, binned["period_count"], certified_range=rule.certified_range,
                          min_periods=rule.min_periods).ravel() == 0
    idx = np.flatnonzero(cand)
    reps = binned["replicas"]
    per = {name: np.full((idx.size, len(reps)), np.nan) for name in SETTLED}
    if idx.size:
        pos = np.full(ncell, -1)
        pos[idx] = np.arange(idx.size)
        for j, d in enumerate(reps):
            mine = (tr["replica"] == binned["replica_numbers"][j]) & (pos[tr["cell"]] >= 0)
            with np.errstate(invalid="ignore", divide="ignore"):
                stats = {**d, "period_count": d["n"], "statistical": d["std_difference"] / np.sqrt(d["n"])}
            rparts = _monte_carlo_parts(stats, vref)
            if "model_form" in parts:  # the same in every replica (its error: model_form_standard_error)
                rparts["model_form"] = parts["model_form"]
            rin = {name: v.ravel()[idx] for name, v in _distribution_inputs(stats, rparts, k).items()}
            cells = tr["cell"][mine]
            rs = grouped(tr["diff"][mine] * rin["scale"][pos[cells]], pos[cells], idx.size)
            rv = bin_values(rs, rin["sigma"], rin["expanded"], rin["nu"], shortest=shortest)
            rv["expanded_uncertainty"] = rin["expanded"]
            targeted = d["targeted"].ravel()[idx]
            for name in SETTLED:
                per[name][:, j] = np.where(targeted, rv[name], np.nan)
    state = numerical_state({name: values[name][idx] for name in SETTLED}, per,
                            {name: sds[name][idx] for name in SETTLED},
                            settle_target(flat["expanded"][idx], rule.significant_digits),
                            np.ones(idx.size, dtype=bool), max_replicas=_NEED_CAP)
    settled = np.ones(ncell, dtype=bool)
    settled[idx] = state["settled"]
    out: dict[str, Any] = {"values": {n: v.reshape(shape) for n, v in values.items()},
                           "nu": pooled_in["nu"], "settled": settled.reshape(shape),
                           "replicas": int(max(binned["replica_numbers"])) + 1}
    full = {"flag": np.full(ncell, 2, dtype=np.int8), "needed": np.zeros(ncell, dtype=np.int64),
            "h": np.zeros(ncell, dtype=np.int64)}
    full["flag"][idx], full["needed"][idx], full["h"][idx] = state["flag"], state["needed"], state["h"]
    for name in SETTLED:
        t = np.full(ncell, np.nan)
        t[idx] = state[f"tolerance_{name}"]
        full[f"tolerance_{name}"] = t
    out["state"] = {n: v.reshape(shape) for n, v in full.items()}
    return out


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
              binned: Mapping[str, Any], contribution: np.ndarray, rule: CertificationRule, k: float,
              config: dict[str, Any], call: str | None, mc: Mapping[str, Any] | None,
              mf: Mapping[str, Any] | None = None) -> xr.Dataset:
    """Build the ``uncertainty_budget`` artefact with the attributes of its schema, stamped."""
    n, approach = binned["n"], config["approach"]
    combined = kernels.quadrature(contribution, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        pct = 100.0 / binned["mean_reference"]
    hw, hwc = ("height", "wind_speed"), ("height", "wind_speed", "contributor")
    flag = certified_bins(0.5 * (edges[:-1] + edges[1:]), binned["period_count"],
                          certified_range=rule.certified_range, min_periods=rule.min_periods,
                          settled=None if mc is None else mc["settled"])
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
        "bin_flag": (hw, flag),
    }
    extra: dict[str, Any] = {}
    if mc is not None:  # the Monte Carlo distribution of each bin, and how far its values settled
        v, st = mc["values"], mc["state"]
        with np.errstate(invalid="ignore", divide="ignore"):
            ref = binned["mean_reference"] / 100.0  # % of the bin mean reference -> m s-1
        values.update({
            "relative_mean_difference": (hw, v["mean_difference"]),
            "error_standard_uncertainty": (hw, v["error_standard_uncertainty"] * ref),
            "relative_error_standard_uncertainty": (hw, v["error_standard_uncertainty"]),
            "coverage_interval_lower": (hw, v["coverage_interval_lower"] * ref),
            "coverage_interval_upper": (hw, v["coverage_interval_upper"] * ref),
            "relative_coverage_interval_lower": (hw, v["coverage_interval_lower"]),
            "relative_coverage_interval_upper": (hw, v["coverage_interval_upper"]),
            "effective_degrees_of_freedom": (hw, np.where(np.isfinite(mc["nu"]), mc["nu"], np.nan)),
            "expanded_uncertainty_coverage": (hw, 100.0 * v["coverage"]),
            "certified_statement": (hw, certified_statement(v["coverage"], flag == 0)),
            "numerical_flag": (hw, st["flag"]),
            "replicas_needed": (hw, st["needed"].astype(np.int32)),
            "replica_count": (hw, st["h"].astype(np.int32)),
        })
        for name, var in SETTLED_VALUES.items():
            values["numerical_tolerance" + (f"_{var}" if var else "")] = (hw, st[f"tolerance_{name}"])
        statement = values["certified_statement"][1]
        extra = {"monte_carlo_replicas": int(mc["replicas"]), "monte_carlo_trials": int(n.sum()),
                 "monte_carlo_significant_digits": int(rule.significant_digits),
                 "monte_carlo_settled": int((st["flag"] == 0).sum()),
                 "monte_carlo_not_settled": int((st["flag"] == 1).sum()),
                 "coverage_probability": COVERAGE_PROBABILITY,
                 "coverage_interval": rule.coverage_interval,
                 "certified_coverage_intervals": int((statement == 1).sum())}
    if mf is not None:  # the model-form contributor's companions (lidarcal.analysis.model_form)
        values["model_form_standard_error"] = (hw, mf["standard_error"])
        values["model_form_sample_count"] = (hw, mf["sample_count"].astype(np.int32))
        values["model_form_shift"] = (hw + ("model_form_alternative",), mf["shift"])
    lo, hi = rule.certified_range
    context = {"k": f"{k:g}", "coverage_factor": k, "min_periods": rule.min_periods, "lo": lo, "hi": hi,
               "digits": rule.significant_digits, "coverage_probability": COVERAGE_PROBABILITY,
               "interval": {"symmetric": "probabilistically symmetric",
                            "shortest": "shortest"}[rule.coverage_interval],
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
    ds.attrs = {"approach": approach, "coverage_factor": k, "min_periods": rule.min_periods,
                "certified_range_m_s": np.array([lo, hi]),
                "records_kind": read_attr(records, "lidarcal_artefact", default="unknown"), **extra}
    serial = lidar_serial(records.attrs)  # old .sta records: lidar_serial_number
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
