"""The ``smc`` artefact: per period and per bin, with its schema's metadata and its provenance.

:func:`smc_dataset` assembles what :func:`lidarcal.smc.core.smc` computed into the ``smc``
artefact (``schemas/smc.yaml``); :func:`binned` gives its per-bin part as a Dataset with a
``wind_speed`` dimension, so ``binned(ds).sel(height=120, wind_speed=8)`` works as on a budget
(the per-period ``wind_speed`` variable holds that name in the file itself);
:func:`binned_table` is the IEC-style table ``lidarcal table smc.nc`` prints.
"""

from __future__ import annotations

import json
import os

import numpy as np
import xarray as xr

from lidarcal.analysis.sensitivity import per_unit
from lidarcal.binning import bin_index
from lidarcal.certificate.admin import DEMONSTRATION
from lidarcal.cf import with_bounds
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, source_name
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs
from lidarcal.smc.certified import flag_meanings
from lidarcal.smc.core import Campaign
from lidarcal.smc.kernels import binned_mean_uncertainty, quadrature
from lidarcal.smc.montecarlo import REGRESSORS
from lidarcal.smc.routes import (
    COVERAGE,
    QUANTILES,
    budget_edges,
    calibration_quantiles,
    envelope,
    table_edges,
)

__all__ = ["smc_dataset", "binned", "binned_table", "CONTRIBUTORS", "ROUTES", "MEASURAND"]

#: The contributors lidarcal computes, in order; the user's terms follow.
CONTRIBUTORS = ("calibration", "environmental_iec", "environmental_monte_carlo")
ROUTES = ("monte_carlo", "iec")
#: What ``uncertainty`` and the bin values are (global attribute ``measurand``; docs/smc.md).
MEASURAND = (
    "uncertainty is the combined standard uncertainty (k = 1) of a single 10-minute mean of the lidar's "
    "horizontal wind speed at that height, the certificate's measurand applied period by period. The bin_* "
    "uncertainties are root mean squares of these single-period values, not the uncertainty of a bin's mean: "
    "the calibration contributor's Table 4 terms, mean difference and model form are fully correlated across "
    "periods, bins and heights, so whoever averages periods must not divide them by the square root of the "
    "number of periods. bin_mean_uncertainty is the uncertainty of the bin's mean speed: the correlated "
    "parts averaged linearly, only the independent single-period spreads divided down."
)
_DESCRIPTION = {
    "calibration": "the certificate's certified standard uncertainty at the period's height and speed bin",
    "environmental_iec": "IEC 61400-50-2 route: significant slopes times the difference from the "
    "calibration's "
    "conditions",
    "environmental_monte_carlo": "Monte Carlo route: the calibrated virtual lidar in the campaign's "
    "conditions",
}


def _rms(values: np.ndarray, bins: np.ndarray, nb: int) -> np.ndarray:
    """Root mean square of ``values`` (time,) per bin over its finite values; NaN for a bin with none."""
    ok = (bins >= 0) & np.isfinite(values)
    n = np.bincount(bins[ok], minlength=nb)
    s = np.bincount(bins[ok], weights=values[ok] ** 2, minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(s / np.maximum(n, 1)), np.nan)


def _by_centre(
    budget: xr.Dataset,
    name: str,
    centres: np.ndarray,
    height_index: np.ndarray,
    heights: np.ndarray | None = None,
) -> np.ndarray:
    """Return a budget variable (height, wind_speed) on the table's (bin, height); NaN where absent."""
    out = np.full((centres.size, height_index.size), np.nan)
    if name not in budget:
        return out
    b = budget[name].transpose("height", "wind_speed").values
    bc = np.asarray(budget["wind_speed"].values, dtype=float)
    j = np.abs(centres[:, None] - bc[None, :]).argmin(axis=1)
    match = np.abs(bc[j] - centres) < 1e-6
    rows = height_index if heights is None else heights
    for k, i in enumerate(rows):
        if i >= 0:
            out[:, k] = np.where(match, b[i, j], np.nan)
    return out


def _per_period(c: Campaign) -> tuple[dict, np.ndarray, list[str], dict]:
    """Per-period variables, contributions (contributor, time, height), contributor names, their split.

    The split: per contributor, its (correlated, independent) parts on (time, height), m s-1.
    """
    speed = c.conditions["wind_speed"].transpose("time", "height").values
    nt, nh = speed.shape
    names = [*CONTRIBUTORS, *(t.name for t in c.user_terms)]
    mc_env = np.full((nt, nh), np.nan)
    mc_dev = np.full((nt, nh), np.nan)
    mc_expected = np.full((nt, nh), np.nan)
    mc_expected_se = np.full((nt, nh), np.nan)
    mc_excess = np.full((nt, nh), np.nan)
    trials = np.zeros((nt, nh), dtype=np.int32)
    cols = np.flatnonzero(c.height_index >= 0)
    if c.monte_carlo is not None:
        mc = c.monte_carlo
        edges = budget_edges(c.cert.budget)
        cert_md = c.cert.budget["mean_difference"].transpose("height", "wind_speed").values
        cert_sd = c.cert.budget["std_difference"].transpose("height", "wind_speed").values
        sim = mc.budget.transpose("height", "wind_speed", ...)
        sim_edges = budget_edges(sim)
        for k, j in enumerate(cols):
            i = c.height_index[j]
            b = bin_index(speed[:, j], edges)
            ok = b >= 0
            shift = mc.expected[:, k] - np.where(ok, cert_md[i, np.maximum(b, 0)], np.nan)
            # the campaign's spread beyond the calibration's in the bin (the lidar's random deviation)
            sb = bin_index(speed[:, j], sim_edges)
            s_sim = np.where(sb >= 0, sim["std_difference"].values[k, np.maximum(sb, 0)], np.nan)
            s_cal = np.where(ok, cert_sd[i, np.maximum(b, 0)], np.nan)
            excess = np.sqrt(np.maximum(s_sim**2 - s_cal**2, 0.0))
            mc_dev[:, j], mc_expected[:, j] = shift, mc.expected[:, k]
            mc_expected_se[:, j], mc_excess[:, j] = mc.expected_se[:, k], excess
            mc_env[:, j] = quadrature(shift, excess)
            trials[:, j] = mc.trials[:, k]
    user = [t.at(speed) for t in c.user_terms]
    contribution = np.stack([c.calibration, c.iec.contribution, mc_env, *user])
    cal_user = quadrature(c.calibration, *user)
    u_iec = quadrature(cal_user, c.iec.contribution)
    u_mc = quadrature(cal_user, mc_env)
    quoted = u_mc if c.monte_carlo is not None else u_iec
    coverage = c.coverage.copy()
    coverage[(coverage == 0) & ~np.isfinite(quoted)] = COVERAGE.index("environmental_term_missing")
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = 100.0 * quoted / speed
    values = {
        "uncertainty": quoted,
        "relative_uncertainty": rel,
        "uncertainty_iec_route": u_iec,
        "uncertainty_monte_carlo_route": u_mc,
        "environmental_deviation_iec": c.iec.deviation,
        "environmental_deviation_monte_carlo": mc_dev,
        "monte_carlo_expected_deviation": mc_expected,
        "monte_carlo_expected_deviation_standard_error": mc_expected_se,
        "monte_carlo_trials": trials,
        "monte_carlo_simulated": (trials > 0).astype(np.int8),
        "coverage_flag": coverage,
    }
    # each contributor's part fully correlated across periods and its part independent between them
    # (the uncertainty of a bin's mean, docs/smc.md): calibration = its certified terms (correlated)
    # and the calibration's single-period spread std_difference (independent); the Monte Carlo
    # route = its expected shift (correlated) and its excess spread (independent); the 50-2 route
    # and the user terms wholly correlated
    cal_random = _calibration_random(c, speed)
    zero = np.zeros((nt, nh))
    split = {
        "calibration": (np.sqrt(np.maximum(c.calibration**2 - cal_random**2, 0.0)), cal_random),
        "environmental_iec": (c.iec.contribution, zero),
        "environmental_monte_carlo": (np.abs(mc_dev), mc_excess),
        **{t.name: (u, zero) for t, u in zip(c.user_terms, user, strict=True)},
    }
    return values, contribution, names, split


def _calibration_random(c: Campaign, speed: np.ndarray) -> np.ndarray:
    """(time, height) the calibration contributor's independent part: the certified bin's std_difference.

    Its relative contribution (%) times the period's speed; 0 where the certificate's budget has no
    such contributor (then the whole contributor counts as correlated), NaN where not certified.
    """
    bud = c.cert.budget.transpose("height", "wind_speed", "contributor", ...)
    out = np.where(np.isfinite(c.calibration), 0.0, np.nan)
    if "std_difference" not in [str(n) for n in bud["contributor"].values]:
        return out
    rel = bud["relative_contribution"].sel(contributor="std_difference").values  # (height, bin), %
    edges = budget_edges(bud)
    for j, i in enumerate(c.height_index):
        if i >= 0:
            b = bin_index(speed[:, j], edges)
            part = np.where(b >= 0, rel[i, np.maximum(b, 0)] * speed[:, j] / 100.0, np.nan)
            out[:, j] = np.where(np.isfinite(c.calibration[:, j]), part, np.nan)
    return out


def _bin_mean(c: Campaign, per: dict, split: dict, names: list[str], edges: np.ndarray) -> dict:
    """Return the (bin, [contributor,] height) uncertainty of each bin's mean speed over its covered periods.

    Per contributor :func:`lidarcal.smc.kernels.binned_mean_uncertainty` of its split (correlated
    parts add linearly, independent ones in quadrature; over the covered periods where it has a
    value); combined in quadrature over the contributors of the quoted route (docs/smc.md).
    """
    speed = c.conditions["wind_speed"].transpose("time", "height").values
    nb, nh = len(edges) - 1, speed.shape[1]
    covered = per["coverage_flag"] == 0
    route = "environmental_iec" if c.monte_carlo is None else "environmental_monte_carlo"
    quoted = [k for k, n in enumerate(names) if not n.startswith("environmental_") or n == route]
    out = {"bin_mean_contribution": np.full((nb, len(names), nh), np.nan),
           "bin_mean_uncertainty": np.full((nb, nh), np.nan),
           "bin_mean_relative_uncertainty": np.full((nb, nh), np.nan)}
    for j in range(nh):
        b = np.where(covered[:, j], bin_index(speed[:, j], edges), -1)
        for k, n in enumerate(names):
            corr, rand = split[n]
            u, _ = binned_mean_uncertainty(corr[None, :, j], rand[None, :, j], b, nb)
            out["bin_mean_contribution"][:, k, j] = u[0]
        n_cov = np.bincount(b[b >= 0], minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_speed = np.bincount(b[b >= 0], weights=speed[b >= 0, j], minlength=nb) / n_cov
        u = np.sqrt(np.sum(out["bin_mean_contribution"][:, quoted, j] ** 2, axis=1))
        out["bin_mean_uncertainty"][:, j] = np.where(n_cov > 0, u, np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            out["bin_mean_relative_uncertainty"][:, j] = np.where(n_cov > 0, 100.0 * u / mean_speed, np.nan)
    return out


def _binned_values(c: Campaign, per: dict, contribution: np.ndarray, edges: np.ndarray) -> dict:
    """Return the (bin, height) variables: counts, RMS of the uncertainties, the two budgets side by side."""
    speed = c.conditions["wind_speed"].transpose("time", "height").values
    nb, nh = len(edges) - 1, speed.shape[1]
    centres = 0.5 * (edges[:-1] + edges[1:])
    covered = per["coverage_flag"] == 0
    out = {
        k: np.full((nb, nh), np.nan)
        for k in (
            "bin_mean_wind_speed",
            "bin_uncertainty",
            "bin_relative_uncertainty",
            "bin_uncertainty_iec_route",
            "bin_uncertainty_monte_carlo_route",
        )
    }
    out["bin_period_count"] = np.zeros((nb, nh), dtype=np.int32)
    out["bin_covered_count"] = np.zeros((nb, nh), dtype=np.int32)
    out["bin_contribution"] = np.full((nb, contribution.shape[0], nh), np.nan)
    for j in range(nh):
        b = bin_index(speed[:, j], edges)
        out["bin_period_count"][:, j] = np.bincount(b[b >= 0], minlength=nb)
        bc = np.where(covered[:, j], b, -1)
        out["bin_covered_count"][:, j] = np.bincount(bc[bc >= 0], minlength=nb)
        n = np.bincount(b[b >= 0], minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            out["bin_mean_wind_speed"][:, j] = np.where(
                n > 0,
                np.bincount(b[b >= 0], weights=speed[b >= 0, j], minlength=nb) / np.maximum(n, 1),
                np.nan,
            )
        for name, src in (
            ("bin_uncertainty", "uncertainty"),
            ("bin_relative_uncertainty", "relative_uncertainty"),
            ("bin_uncertainty_iec_route", "uncertainty_iec_route"),
            ("bin_uncertainty_monte_carlo_route", "uncertainty_monte_carlo_route"),
        ):
            out[name][:, j] = _rms(per[src][:, j], bc, nb)
        for k in range(contribution.shape[0]):
            out["bin_contribution"][:, k, j] = _rms(contribution[k, :, j], bc, nb)
    cert = c.cert.budget
    hi = c.height_index
    out["bin_certificate_flag"] = np.nan_to_num(_by_centre(cert, "bin_flag", centres, hi), nan=-1).astype(
        np.int8
    )
    for name, src in (
        ("bin_certified_mean_difference", "mean_difference"),
        ("bin_certified_std_difference", "std_difference"),
        ("bin_certified_relative_expanded_uncertainty", "relative_expanded_uncertainty"),
        ("bin_certified_numerical_tolerance", "numerical_tolerance"),
    ):
        out[name] = _by_centre(cert, src, centres, hi)
    sim_rows = np.where(hi >= 0, np.cumsum(hi >= 0) - 1, -1)  # simulated heights are the certified ones
    mc = c.monte_carlo
    for name, src in (
        ("bin_simulated_mean_difference", "mean_difference"),
        ("bin_simulated_std_difference", "std_difference"),
        ("bin_simulated_sample_count", "sample_count"),
        ("bin_simulated_relative_expanded_uncertainty", "relative_expanded_uncertainty"),
    ):
        out[name] = (
            _by_centre(mc.budget, src, centres, hi, sim_rows) if mc is not None else np.full((nb, nh), np.nan)
        )
    out["bin_simulated_sample_count"] = np.nan_to_num(out["bin_simulated_sample_count"]).astype(np.int32)
    tol, flag = np.full((nb, nh), np.nan), np.full((nb, nh), 2, dtype=np.int8)
    extra = {
        "bin_simulated_mean_difference_standard_error": "mean_difference_se",
        "bin_simulated_std_difference_standard_error": "std_difference_se",
        "bin_simulated_period_count": "periods_simulated",
    }
    for name in extra:
        out[name] = np.full((nb, nh), np.nan)
    if mc is not None:
        hw = ("height", "wind_speed")
        sim = mc.budget.assign(
            tolerance=(hw, mc.tolerance),
            settled=(hw, mc.settled.astype(float)),
            **{src: (hw, np.asarray(getattr(mc, src), dtype=float)) for src in extra.values()},
        )
        tol = _by_centre(sim, "tolerance", centres, hi, sim_rows)
        flag = np.nan_to_num(_by_centre(sim, "settled", centres, hi, sim_rows), nan=2).astype(np.int8)
        for name, src in extra.items():
            out[name] = _by_centre(sim, src, centres, hi, sim_rows)
    out["bin_simulated_period_count"] = np.nan_to_num(out["bin_simulated_period_count"]).astype(np.int32)
    out["bin_simulated_numerical_tolerance"], out["bin_simulated_numerical_flag"] = tol, flag
    return out


def smc_dataset(c: Campaign, *, call: str | None = None) -> xr.Dataset:
    """Assemble the stamped ``smc`` artefact of a :class:`~lidarcal.smc.core.Campaign`."""
    cert, cond = c.cert, c.conditions.transpose("time", "height", ...)
    per, contribution, names, split = _per_period(c)
    route = "monte_carlo" if c.monte_carlo is not None else "iec"
    speed = cond["wind_speed"].values
    edges = table_edges(cert.budget, speed)
    k = read_attr(cert.budget, "coverage_factor", kind="uncertainty_budget")
    cflags = flag_meanings(cert.budget["bin_flag"])
    low, high, outside, env_names = envelope(cert, cond, c.height_index)
    sources = {**_DESCRIPTION, **{t.name: f"user term ({t.source})" for t in c.user_terms}}
    description = "; ".join(f"{n}: {sources[n]}" for n in names)
    context = {
        "route": route.replace("_", " "),
        "contributor_description": description,
        "k": f"{k:g}",
        "envelope_meanings": " ".join(f"{v}_outside" for v in env_names),
        "certificate_values": [-1, *cflags],
        "certificate_meanings": " ".join(["no_certificate_bin", *cflags.values()]),
    }
    dims = ("time", "height")
    ds = xr.Dataset(
        coords={
            "time": cond["time"].variable.copy(),
            "height": cond["height"].variable.copy(),
            "contributor": ("contributor", np.array(names, dtype=object)),
            "wind_speed_bin": ("wind_speed_bin", 0.5 * (edges[:-1] + edges[1:])),
            "quantile": ("quantile", np.asarray(QUANTILES)),
        }
    )
    for name in CONDITION_NAMES:
        ds[name] = (dims, cond[name].values, dict(cond[name].attrs))
    for name, values in per.items():
        ds[name] = (dims, values, output_attrs("smc", name, **context))
    ds["contribution"] = (
        ("contributor", *dims),
        contribution,
        output_attrs("smc", "contribution", **context),
    )
    combined = np.array(
        [
            n != ("environmental_iec" if route == "monte_carlo" else "environmental_monte_carlo")
            for n in names
        ],
        dtype=np.int8,
    )
    ds["combined"] = ("contributor", combined, output_attrs("smc", "combined", **context))
    ds["outside_envelope"] = (dims, outside, output_attrs("smc", "outside_envelope", **context))
    masks = ds["outside_envelope"].attrs["flag_masks"]
    ds["outside_envelope"].attrs["flag_masks"] = np.asarray(masks, np.int8)  # the variable's type (CF 3.5)
    quantiles = calibration_quantiles(cert, c.height_index)
    for v, lo_v, hi_v in zip(env_names, low, high, strict=True):
        ctx = {**context, "variable": v, "xname": v.replace("_", " "), "units": cond[v].attrs["units"]}
        ds[f"envelope_low_{v}"] = ("height", lo_v, output_attrs("smc", f"envelope_low_{v}", **ctx))
        ds[f"envelope_high_{v}"] = ("height", hi_v, output_attrs("smc", f"envelope_high_{v}", **ctx))
        ds[f"calibration_quantiles_{v}"] = (("quantile", "height"), quantiles[v],
                                            output_attrs("smc", f"calibration_quantiles_{v}", **ctx))
    for i, v in enumerate(c.iec.variables):
        ctx = {
            **context,
            "variable": v,
            "xname": v.replace("_", " "),
            "units": c.iec.units[i],
            "slope_units": c.iec.slope_units[i],
        }
        ds[f"iec_slope_{v}"] = ("height", c.iec.slope[i], output_attrs("smc", f"iec_slope_{v}", **ctx))
        ds[f"calibration_mean_{v}"] = (
            "height",
            c.iec.calibration_mean[i],
            output_attrs("smc", f"calibration_mean_{v}", **ctx),
        )
    if c.monte_carlo is not None:
        for i, v in enumerate(REGRESSORS):
            units = cond[v].attrs["units"]
            slope = np.full(cond.sizes["height"], np.nan)
            slope[c.height_index >= 0] = c.monte_carlo.slopes[:, i]
            ctx = {**context, "variable": v, "xname": v.replace("_", " ")}
            ctx["slope_units"] = per_unit("m s-1", units)
            ds[f"monte_carlo_slope_{v}"] = (
                "height",
                slope,
                output_attrs("smc", f"monte_carlo_slope_{v}", **ctx),
            )
    bdims = {n: ("wind_speed_bin", "contributor", "height")
             for n in ("bin_contribution", "bin_mean_contribution")}
    binned_values = {**_binned_values(c, per, contribution, edges), **_bin_mean(c, per, split, names, edges)}
    for name, values in binned_values.items():
        ds[name] = (
            bdims.get(name, ("wind_speed_bin", "height")),
            values,
            output_attrs("smc", name, **context),
        )
    for name in ("time", "height", "contributor", "wind_speed_bin", "quantile"):
        ds[name].attrs.update(output_attrs("smc", name, **context))
    ds["height"].attrs.update(dict(cond["height"].attrs))
    ds = with_bounds(ds, "wind_speed_bin", edges)
    if "time_bounds" in cond.coords:
        ds = ds.assign_coords(time_bounds=cond["time_bounds"].variable.copy())
        ds["time"].attrs["bounds"] = "time_bounds"
        ds["time"].encoding.update(
            {k: v for k, v in cond["time"].encoding.items() if k in ("units", "calendar")}
        )
    return _stamped(ds, c, route, call)


def _stamped(ds: xr.Dataset, c: Campaign, route: str, call: str | None) -> xr.Dataset:
    cert, cond = c.cert, c.conditions
    demo = cert.demonstration
    covered = int((ds["coverage_flag"].values == 0).sum())
    total = int(np.isfinite(ds["wind_speed"].values).sum())
    ds.attrs = {
        "calibration_status": cert.status,
        "calibration_status_reason": (
            f"the certificate is a demonstration ({cert.status_reason})"
            if demo
            else f"the certificate's status is {cert.status!r}"
        ),
        "certificate_file": cert.path.name,
        "certificate_sha256": read_attr(cert.attrs, "lidarcal_source_sha256", kind="certificate", default=""),
        "certificate_id": str(cert.attrs.get("certificate_id", cert.attrs.get("id", "not stated"))),
        "certificate_seal": cert.seal,
        "lidar_serial": str(cert.serial),
        "environmental_route": route,
        "monte_carlo_route": c.monte_carlo_note,
        "iec_route": c.iec.note,
        "lidar_cone_angle": read_attr(cond, "lidar_cone_angle", kind="conditions",
                                      default=float(cert.cone_angle)),
        "lidar_cone_angle_source": read_attr(cond, "lidar_cone_angle_source", kind="conditions"),
        "user_terms": json.dumps([t.describe() for t in c.user_terms]),
        "heights_not_covered_m": json.dumps(
            [float(z) for z, i in zip(ds["height"].values, c.height_index, strict=True) if i < 0]
        ),
        "covered_periods": covered,
        "periods_with_wind_speed": total,
        "campaign_files": cond.attrs.get(
            "sta_files", json.dumps([str(p.name) for r, p in c.inputs.items() if r != "certificate"])
        ),
        "lidar_site": read_attr(cond, "lidar_site", kind="conditions"),
        "lidarcal_smc_settings": json.dumps(c.settings, sort_keys=True),
        "monte_carlo_periods_per_bin": str(c.settings.get("monte_carlo_periods_per_bin", "all"))
        if c.monte_carlo is not None else "not run",
        "measurand": MEASURAND,
        "certificate_measurand": read_attr(cert.attrs, "measurand", kind="certificate",
                                           default="not stated (a certificate older than the "
                                                   "measurand statement)"),
        "certificate_model_form": read_attr(cert.attrs, "model_form", kind="certificate",
                                            default="not stated: the certificate's budget has no model_form "
                                                    "contributor"),
    }
    title = f"Campaign wind-speed uncertainty of lidar {cert.serial} from certificate {cert.path.name}"
    summary = (
        f"{cond.sizes['time']} ten-minute periods at {cond.sizes['height']} height(s) of the lidar "
        f"{cert.serial} ({c.source}): per period and height the wind speed and its combined standard "
        f"uncertainty (calibration, {route.replace('_', ' ')} environmental route"
        f"{', user terms' if c.user_terms else ''}); {covered} of {total} period-heights covered by the "
        "certificate."
    )
    if demo:
        title += " - DEMONSTRATION, from a demonstration certificate"
        summary = (
            "DEMONSTRATION result: the certificate is a demonstration, not a calibration of a real "
            "instrument. "
            + summary
        )
    return stamp(
        ds,
        "smc",
        title=title,
        summary=summary,
        call=call or "lidarcal.smc.smc(...)",
        inputs=c.inputs,
        config=c.settings,
        seeds={
            "base_seed": c.settings["base_seed"],
            "scheme": "numpy SeedSequence([base_seed, period_key, round(height_m * 1000)]); replica r: "
            "([base_seed, r, period_key]) (docs/seeds.md)",
        }
        if c.monte_carlo
        else None,
        keywords="Doppler lidar, wind speed, measurement uncertainty, specific measurement campaign",
    )


def binned(obj: xr.Dataset | str | os.PathLike) -> xr.Dataset:
    """Return the per-bin part of an ``smc`` artefact as a Dataset on (wind_speed, [contributor,] height).

    ``bin_*`` variables lose their prefix and ``wind_speed_bin`` becomes ``wind_speed``, so
    ``binned(ds).sel(height=120, wind_speed=8, method="nearest").uncertainty`` works as on a budget.
    ``obj`` is the artefact or its file.
    """
    ds = open_artefact(obj, "smc") if isinstance(obj, str | os.PathLike) else obj
    if read_attr(ds, "lidarcal_artefact") != "smc":
        raise InputError(
            f"{source_name(ds)}: expected an 'smc' artefact; found {read_attr(ds, 'lidarcal_artefact')!r}"
        )
    names = [n for n in ds.data_vars if str(n).startswith("bin_")]
    out = ds[names].drop_vars([v for v in ("time", "time_bounds") if v in ds[names].coords], errors="ignore")
    if "wind_speed_bin_bounds" in ds.variables:
        out = out.assign_coords(wind_speed_bin_bounds=ds["wind_speed_bin_bounds"])
    out = out.rename({n: str(n)[4:] for n in names})
    out = out.rename({"wind_speed_bin": "wind_speed", "wind_speed_bin_bounds": "wind_speed_bounds"})
    if "bounds" in out["wind_speed"].attrs:
        out["wind_speed"].attrs["bounds"] = "wind_speed_bounds"
    out.attrs = dict(ds.attrs)
    return out


def binned_table(obj: xr.Dataset | str | os.PathLike):
    """IEC-style table of an ``smc`` artefact: one row per height and wind-speed bin (``lidarcal table``).

    Columns: height, bin centre, periods and covered periods, mean wind speed, the certificate's
    flag meaning, the combined standard uncertainty (quoted route) in m/s and % (of a single
    period, the root mean square over the bin), both routes' combinations, the standard
    uncertainty of the bin's mean speed in m/s and %, each contributor (m/s), the certificate's
    and the campaign's simulated relative expanded uncertainty with their numerical tolerances,
    and the Monte Carlo route's periods simulated in the bin with its mean deviation and spread
    and their standard errors from the subsample.  Rows with no campaign period are left out.
    """
    import pandas as pd

    b = binned(obj).transpose("height", "wind_speed", "contributor", ...)
    meanings = flag_meanings(b["certificate_flag"])
    rows = []
    for i, z in enumerate(b["height"].values):
        for j, u in enumerate(b["wind_speed"].values):
            n = int(b["period_count"].values[i, j])
            if n == 0:
                continue
            row = {
                "height_m": float(z),
                "wind_speed_m_s": float(u),
                "periods": n,
                "covered_periods": int(b["covered_count"].values[i, j]),
                "mean_wind_speed_m_s": float(b["mean_wind_speed"].values[i, j]),
                "certificate_bin": meanings.get(int(b["certificate_flag"].values[i, j]), "?"),
                "uncertainty_m_s": float(b["uncertainty"].values[i, j]),
                "relative_uncertainty_pct": float(b["relative_uncertainty"].values[i, j]),
                "uncertainty_iec_route_m_s": float(b["uncertainty_iec_route"].values[i, j]),
                "uncertainty_monte_carlo_route_m_s": float(b["uncertainty_monte_carlo_route"].values[i, j]),
                "mean_uncertainty_m_s": float(b["mean_uncertainty"].values[i, j]),
                "mean_relative_uncertainty_pct": float(b["mean_relative_uncertainty"].values[i, j]),
            }
            for k, c in enumerate(b["contributor"].values):
                row[f"{c}_m_s"] = float(b["contribution"].values[i, j, k])
            for name in (
                "certified_relative_expanded_uncertainty",
                "certified_numerical_tolerance",
                "simulated_relative_expanded_uncertainty",
                "simulated_numerical_tolerance",
            ):
                row[f"{name}_pct"] = float(b[name].values[i, j])
            row["simulated_periods"] = int(b["simulated_period_count"].values[i, j])
            for name in ("simulated_mean_difference", "simulated_mean_difference_standard_error",
                         "simulated_std_difference", "simulated_std_difference_standard_error"):
                row[f"{name}_m_s"] = float(b[name].values[i, j])
            rows.append(row)
    table = pd.DataFrame(rows)
    table.attrs.update(
        {
            "status": str(read_attr(b, "calibration_status", kind="smc")),
            "demonstration": read_attr(b, "calibration_status", kind="smc") == DEMONSTRATION,
            "route": str(read_attr(b, "environmental_route", kind="smc")),
            "title": str(b.attrs.get("title", "")),
        }
    )
    return table
