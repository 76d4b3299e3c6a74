"""The ``smc`` artefact: per period and per bin, with its schema's metadata and its provenance.

:func:`smc_dataset` assembles what :func:`lidarcal.smc.core.smc` computed into the ``smc``
artefact (``schemas/smc.yaml``); :func:`binned` gives its per-bin part as a Dataset with a
``wind_speed`` dimension, so ``binned(ds).sel(height=120, wind_speed=8)`` works as on a budget
(the per-period ``wind_speed`` variable holds that name in the file itself);
:func:`binned_table` is the IEC-style table ``lidarcal table smc.nc`` prints.
"""

from __future__ import annotations

import functools
import json
import os

import dask
import dask.array as da
import numpy as np
import xarray as xr

from lidarcal.analysis.sensitivity import per_unit
from lidarcal.certificate.admin import DEMONSTRATION
from lidarcal.cf import with_bounds
from lidarcal.conditions.variables import CONDITION_NAMES
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, source_name
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs
from lidarcal.smc.certified import flag_meanings
from lidarcal.smc.core import BLOCK_PERIODS, Campaign
from lidarcal.smc.expected import REGRESSORS
from lidarcal.smc.periods import CONTRIBUTORS, BinSums, blocks, contributor_names, period_block
from lidarcal.smc.routes import ENVELOPE, QUANTILES, calibration_quantiles

__all__ = ["smc_dataset", "binned", "binned_table", "CONTRIBUTORS", "ROUTES", "MEASURAND"]

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


def _binned_values(c: Campaign, edges: np.ndarray) -> dict:
    """Return the (bin, height) variables of the certificate and of the Monte Carlo route, side by side."""
    nb, nh = len(edges) - 1, c.height_index.size
    centres = 0.5 * (edges[:-1] + edges[1:])
    out = {}
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


def smc_dataset(c: Campaign, *, call: str | None = None, block: int = BLOCK_PERIODS) -> xr.Dataset:
    """Assemble the stamped ``smc`` artefact of a :class:`~lidarcal.smc.core.Campaign`.

    The per-bin tables are summed over the campaign block by block of ``block`` periods
    (:class:`~lidarcal.smc.periods.BinSums`); the per-period variables are dask arrays with one
    chunk per block, each computed from its periods when it is read or written
    (:func:`~lidarcal.smc.periods.period_block`), so writing the artefact holds one block at a time.
    """
    cert, cond = c.cert, c.conditions.transpose("time", "height", ...)
    names = contributor_names(c)
    route = "monte_carlo" if c.monte_carlo is not None else "iec"
    edges = c.edges
    nt, nh = cond.sizes["time"], cond.sizes["height"]
    sums = BinSums(edges, names, nh, "environmental_iec" if route == "iec" else "environmental_monte_carlo")
    slices = list(blocks(nt, block))
    kinds: dict[str, np.dtype] = {}
    for sl in slices:
        one = period_block(c, sl)
        sums.add(one)
        kinds = kinds or {n: v.dtype for n, v in one.arrays().items()}
    k = read_attr(cert.budget, "coverage_factor", kind="uncertainty_budget")
    cflags = flag_meanings(cert.budget["bin_flag"])
    (low, high), env_names = c.envelope, ENVELOPE
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
        ds[name] = (dims, _in_blocks(cond[name].data, block), dict(cond[name].attrs))
    lazy = _lazy_periods(c, slices, kinds, len(names))
    for name, values in lazy.items():
        if name not in ("contribution", "outside_envelope"):
            ds[name] = (dims, values, output_attrs("smc", name, **context))
    ds["contribution"] = (
        ("contributor", *dims),
        lazy["contribution"],
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
    ds["outside_envelope"] = (dims, lazy["outside_envelope"],
                              output_attrs("smc", "outside_envelope", **context))
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
    tables = sums.tables()
    binned_values = {**{n: tables.pop(n) for n in _FROM_PERIODS}, **_binned_values(c, edges), **tables}
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
    return _stamped(ds, c, route, call, covered=sums.covered_periods, total=sums.periods_with_wind_speed)


#: The per-bin variables from the periods that come before the certificate's and the route's (file order).
_FROM_PERIODS = ("bin_mean_wind_speed", "bin_uncertainty", "bin_relative_uncertainty",
                 "bin_uncertainty_iec_route", "bin_uncertainty_monte_carlo_route", "bin_period_count",
                 "bin_covered_count", "bin_contribution")


def _lazy_periods(c: Campaign, slices: list[slice], kinds: dict[str, np.dtype],
                  n_contributors: int) -> dict[str, da.Array]:
    """Each per-period variable as a dask array, one chunk per block, computed from its block's periods.

    A block's values are computed once however many of its variables a computation reads
    (one task per block; each variable's chunk is an item of it).
    """
    nh = c.height_index.size
    compute = functools.partial(_block_arrays, c)
    pieces = [(dask.delayed(compute, pure=False)(sl), sl.stop - sl.start) for sl in slices]
    out = {}
    for name, kind in kinds.items():
        lead = (n_contributors,) if name == "contribution" else ()
        parts = [da.from_delayed(piece[name], shape=(*lead, n, nh), dtype=kind) for piece, n in pieces]
        out[name] = da.concatenate(parts, axis=len(lead))
    return out


def _in_blocks(values, block: int) -> da.Array:
    """(time, ...) values as a dask array of the per-period variables' blocks (written alike)."""
    chunks = (max(1, int(block)), *(-1,) * (values.ndim - 1))
    return values.rechunk(chunks) if isinstance(values, da.Array) else da.from_array(values, chunks=chunks)


def _block_arrays(c: Campaign, periods: slice) -> dict[str, np.ndarray]:
    return period_block(c, periods).arrays()


def _stamped(ds: xr.Dataset, c: Campaign, route: str, call: str | None, *, covered: int,
             total: int) -> xr.Dataset:
    cert, cond = c.cert, c.conditions
    demo = cert.demonstration
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
