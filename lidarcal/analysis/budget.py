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
    ``statistical`` — σ_diff / √N.
``iec`` (field calibration against a mast)
    ``reference_sensor`` — √(u_abs² + (u_rel·Ū)²) from the anemometer calibration;
    ``mean_difference``; ``statistical`` — σ_diff / √N; ``mounting``, ``separation`` and
    ``flow_inhomogeneity`` — relative terms × Ū (default 0).

They are combined in quadrature into ``uncertainty`` (m s-1); ``relative_uncertainty`` (%)
is relative to the bin's mean reference wind speed Ū; ``expanded_uncertainty`` is
k × ``uncertainty`` (k = 2 by default).  Bins with fewer than ``min_samples`` periods are
flagged in ``bin_flag`` (not dropped); σ_diff needs two periods, so single-period bins have a
NaN combined uncertainty.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis import kernels
from lidarcal.analysis._records import checked, select_heights, source_name
from lidarcal.analysis.terms import PAPER_INPUTS, uncertainty_terms
from lidarcal.cf import Param, declared_attrs, with_bounds
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.provenance import stamp
from lidarcal.units import Q_, convert_values, to_magnitude

__all__ = ["budget", "CONTRIBUTORS", "DEFAULT_MIN_SAMPLES", "TERMS_TOTAL_NAMES"]

#: Contributors of each approach, in the order of the ``contributor`` dimension.
CONTRIBUTORS = {
    "monte_carlo": ("virtual_reference", "mean_difference", "std_difference", "statistical"),
    "iec": ("reference_sensor", "mean_difference", "statistical", "mounting", "separation",
            "flow_inhomogeneity"),
}

_CONTRIBUTOR_NAMES = {
    "virtual_reference": "virtual reference uncertainty (Table 4 total, Eqs. 6-11)",
    "mean_difference": "absolute mean lidar minus reference difference",
    "std_difference": "standard deviation of the lidar minus reference difference",
    "statistical": "standard uncertainty of the mean difference, sigma_diff / sqrt(N)",
    "reference_sensor": "reference anemometer standard uncertainty",
    "mounting": "lidar mounting",
    "separation": "separation between lidar and reference mast",
    "flow_inhomogeneity": "flow inhomogeneity across the lidar measurement volume",
}

#: Bins with fewer periods are flagged ``thin`` (IEC practice: at least 3 per bin).
DEFAULT_MIN_SAMPLES = 3

#: Names under which an ``uncertainty_terms`` artefact may store the Table 4 total (m s-1).
TERMS_TOTAL_NAMES = ("total", "total_uncertainty", "combined_uncertainty", "uncertainty")


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
        for i, h in enumerate(heights):
            inputs = {**PAPER_INPUTS, "height": f"{h} m", "noise_terms": noise_terms}
            out[i, positive] = uncertainty_terms(Q_(centres[positive], "m s-1"), **inputs).total.values
        how = "" if noise_terms == "printed" else f", noise_terms={noise_terms!r}"
        return out, f"lidarcal.analysis.terms.uncertainty_terms(**PAPER_INPUTS{how}) at each budget height"
    if noise_terms != "printed" and terms.attrs.get("noise_terms", "printed") != noise_terms:
        raise InputError(f"{source_name(terms, '<terms>')}: the terms artefact has noise_terms="
                         f"{terms.attrs.get('noise_terms', 'printed')!r}; asked for {noise_terms!r} "
                         "(recompute it with lidarcal terms --noise-terms)")
    src = source_name(terms, "<terms>")
    name = next((n for n in TERMS_TOTAL_NAMES if n in terms.data_vars), None)
    if name is None:
        raise MissingVariableError(
            f"{src}: no Table 4 total variable; expected one of {list(TERMS_TOTAL_NAMES)}, "
            f"found {sorted(map(str, terms.data_vars))}"
        )
    total = terms[name]
    if "wind_speed" not in total.dims:
        raise InputError(
            f"{src}: variable {name!r} has dims {tuple(total.dims)}; expected a 'wind_speed' dim")
    where = f"{src}: variable {name!r}"
    values = convert_values(total.values, total.attrs.get("units"), "m s-1", where=where)
    total = total.copy(data=values)
    ws = np.asarray(terms["wind_speed"].values, dtype=float)
    lo, hi = float(ws.min()), float(ws.max())
    need = centres[positive] if positive.any() else centres
    if need.min() < lo - 1e-9 or need.max() > hi + 1e-9:
        raise InputError(
            f"{src}: variable {name!r} covers wind speeds {lo:g}-{hi:g} m s-1; the budget needs "
            f"{need.min():g}-{need.max():g} m s-1 (no extrapolation); recompute the terms over "
            "that range"
        )
    out = total.interp(wind_speed=np.where(positive, centres, np.nan))
    if "height" in out.dims:
        th = np.asarray(terms["height"].values, dtype=float)
        if heights.min() < th.min() - 1e-6 or heights.max() > th.max() + 1e-6:
            raise InputError(f"{src}: terms cover heights {th.min():g}-{th.max():g} m; budget needs "
                             f"{heights.min():g}-{heights.max():g} m")
        out = out.interp(height=heights).transpose("height", "wind_speed")
        arr = out.values
    else:
        extra = [d for d in out.dims if d != "wind_speed"]
        if extra:
            raise InputError(f"{src}: variable {name!r} has unexpected dims {extra}")
        arr = np.broadcast_to(out.values, (len(heights), len(centres)))
    origin = src
    if "height" in terms.coords and terms["height"].ndim == 0:
        origin += f" (evaluated at z = {float(terms['height']):g} m, used for every height)"
    return np.asarray(arr, dtype=float), origin


#: Declared CF attributes of every output variable (applied by :func:`_assemble`).  Templates:
#: ``{k}`` the coverage factor as text, ``{min_samples}``; ``Param("k")`` the factor as a number.
OUTPUT_ATTRS: dict[str, dict[str, Any]] = {
    "uncertainty": dict(
        long_name="combined standard uncertainty of the lidar wind speed (quadrature sum of contributors)",
        units="m s-1", ancillary_variables="sample_count bin_flag",
        standard_name="wind_speed standard_error"),
    "relative_uncertainty": dict(
        long_name="combined standard uncertainty relative to the bin mean reference wind speed", units="%"),
    "expanded_uncertainty": dict(long_name="expanded uncertainty (k = {k})", units="m s-1",
                                 coverage_factor=Param("coverage_factor")),
    "relative_expanded_uncertainty": dict(
        long_name="expanded uncertainty (k = {k}) relative to the bin mean reference wind speed", units="%",
        coverage_factor=Param("coverage_factor")),
    # CF standard-name modifiers (Appendix C): each contribution is a standard uncertainty of
    # the wind speed; relative and expanded uncertainties have no CF name (docs/certificate.md)
    "contribution": dict(long_name="standard uncertainty contribution", units="m s-1",
                         standard_name="wind_speed standard_error"),
    "relative_contribution": dict(
        long_name="standard uncertainty contribution relative to the bin mean reference wind speed",
        units="%"),
    "sample_count": dict(long_name="number of 10-minute periods in bin", units="1",
                         coverage_content_type="auxiliaryInformation",
                         standard_name="wind_speed number_of_observations"),
    "mean_reference_wind_speed": dict(long_name="mean reference wind speed in bin", units="m s-1",
                                      standard_name="wind_speed"),
    "mean_lidar_wind_speed": dict(long_name="mean lidar wind speed in bin", units="m s-1",
                                  standard_name="wind_speed"),
    "mean_difference": dict(long_name="mean lidar minus reference wind speed", units="m s-1"),
    "std_difference": dict(long_name="standard deviation of lidar minus reference wind speed (ddof=1)",
                           units="m s-1"),
    "bin_flag": dict(long_name="bin sample flag", units="1", coverage_content_type="qualityInformation",
                     flag_values=np.array([0, 1, 2], dtype=np.int8), flag_meanings="ok thin empty",
                     comment="thin: fewer than {min_samples} periods; empty: no period"),
    "wind_speed": dict(long_name="centre of reference wind speed bin", units="m s-1",
                       standard_name="wind_speed", coverage_content_type="coordinate"),
}

#: Relative (fraction of the bin mean reference speed) inputs of the IEC approach.
_IEC_FRACTIONS = ("reference_relative_uncertainty", "mounting", "separation", "flow_inhomogeneity")


def budget(
    records: xr.Dataset,
    *,
    terms: xr.Dataset | None = None,
    approach: str = "monte_carlo",
    bin_width: Any = "0.5 m s-1",
    min_samples: int = DEFAULT_MIN_SAMPLES,
    heights: Iterable[float] | None = None,
    coverage_factor: float = 2.0,
    reference_uncertainty: Any = None,
    reference_relative_uncertainty: Any = 0.0,
    mounting: Any = 0.0,
    separation: Any = 0.0,
    flow_inhomogeneity: Any = 0.0,
    noise_terms: str = "printed",
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
    min_samples : int
        Bins with fewer periods are flagged ``thin`` (default 3).
    heights : sequence of float, optional
        Heights (m) to include; a height not in the records is an error.
    coverage_factor : float
        k of the expanded uncertainty (default 2).
    reference_uncertainty : quantity or str
        IEC approach: absolute standard uncertainty of the calibrated anemometer, e.g. "0.1 m s-1".
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
    if int(min_samples) < 1:
        raise InputError(f"min_samples must be >= 1; got {min_samples}")
    width = float(to_magnitude(bin_width, "m s-1", name="bin_width"))
    if not width > 0:
        raise InputError(f"bin_width must be positive; got {bin_width!r}")
    k = float(coverage_factor)
    records = select_heights(records, heights, source=source)
    edges, binned = _binned(records, width, source)
    centres = 0.5 * (edges[:-1] + edges[1:])
    config: dict[str, Any] = {"approach": approach, "bin_width_m_s-1": width, "min_samples": int(min_samples),
                              "coverage_factor": k, "binned_by": "reference_wind_speed",
                              "relative_to": "mean reference wind speed in the bin"}
    if approach == "monte_carlo":
        vref, config["virtual_reference_terms"] = _terms_total(
            terms, centres, np.asarray(records["height"].values, dtype=float), noise_terms)
        parts = _monte_carlo_parts(binned, vref)
    else:
        u_abs, rel = _iec_inputs(terms, reference_uncertainty, dict(zip(_IEC_FRACTIONS, (
            reference_relative_uncertainty, mounting, separation, flow_inhomogeneity), strict=True)))
        config.update({"reference_uncertainty_m_s-1": u_abs, **{f"{a}_fraction": b for a, b in rel.items()}})
        parts = _iec_parts(binned, u_abs, rel)
    contribution = np.stack([np.broadcast_to(parts[c], binned["n"].shape) for c in CONTRIBUTORS[approach]],
                            axis=-1)
    return _assemble(records, terms, approach, edges, binned, contribution, int(min_samples), k, config, call)


def _binned(records: xr.Dataset, width: float, source: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Bin edges centred on multiples of ``width`` and the per-(height, bin) statistics."""
    lidar = checked(records, "lidar_wind_speed", source=source)
    ref = checked(records, "reference_wind_speed", source=source)
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
        n, md, sd, mref = kernels.bin_statistics(x, y, edges)
        _, mlid, _, _ = kernels.bin_statistics(x, z, edges)
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
    return edges, {"n": n, "mean_difference": mean_diff, "std_difference": std_diff,
                   "mean_reference": mean_ref, "mean_lidar": mean_lidar, "statistical": statistical}


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


def _assemble(records: xr.Dataset, terms: xr.Dataset | None, approach: str, edges: np.ndarray,
              binned: Mapping[str, np.ndarray], contribution: np.ndarray, min_samples: int, k: float,
              config: dict[str, Any], call: str | None) -> xr.Dataset:
    """Build the ``uncertainty_budget`` artefact with the attributes of :data:`OUTPUT_ATTRS`, stamped."""
    n, names = binned["n"], CONTRIBUTORS[approach]
    combined = kernels.quadrature(contribution, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        pct = 100.0 / binned["mean_reference"]
    hw, hwc = ("height", "wind_speed"), ("height", "wind_speed", "contributor")
    values = {
        "uncertainty": (hw, combined), "relative_uncertainty": (hw, combined * pct),
        "expanded_uncertainty": (hw, k * combined), "relative_expanded_uncertainty": (hw, k * combined * pct),
        "contribution": (hwc, contribution), "relative_contribution": (hwc, contribution * pct[..., None]),
        "sample_count": (hw, n.astype(np.int32)),
        "mean_reference_wind_speed": (hw, binned["mean_reference"]),
        "mean_lidar_wind_speed": (hw, binned["mean_lidar"]),
        "mean_difference": (hw, binned["mean_difference"]),
        "std_difference": (hw, binned["std_difference"]),
        "bin_flag": (hw, np.where(n >= min_samples, 0, np.where(n > 0, 1, 2)).astype(np.int8)),
    }
    context = {"k": f"{k:g}", "coverage_factor": k, "min_samples": min_samples}
    ds = xr.Dataset(
        {name: (dims, data, declared_attrs(OUTPUT_ATTRS, name, **context))
         for name, (dims, data) in values.items()},
        coords={
            "height": records["height"].variable.copy(),
            "wind_speed": ("wind_speed", 0.5 * (edges[:-1] + edges[1:]),
                           declared_attrs(OUTPUT_ATTRS, "wind_speed", **context)),
            "contributor": ("contributor", np.array(names, dtype=object), {
                "long_name": "uncertainty contributor",
                "description": "; ".join(f"{c}: {_CONTRIBUTOR_NAMES[c]}" for c in names)}),
        },
    )
    ds["height"].attrs = dict(records["height"].attrs)
    ds = with_bounds(ds, "wind_speed", edges)
    ds.attrs = {"approach": approach, "coverage_factor": k, "min_samples": min_samples,
                "records_kind": str(records.attrs.get("lidarcal_artefact", "unknown"))}
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
