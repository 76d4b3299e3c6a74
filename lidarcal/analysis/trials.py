"""The Monte Carlo trials of a budget, binned: pooled statistics, each replica's own, the trials themselves.

``simulated_rtd`` records hold replica 0 on (time, height) and may carry further replicas of
the same periods with independent seed streams (variables :data:`TRIAL_VARIABLES` on a
``trial`` dim, written by :mod:`lidarcal.campaign.adaptive`).  :func:`binned` bins every trial
by its reference wind speed (bins centred on multiples of the width) and returns, per
(height, bin):

- the pooled statistics of all trials (``n`` trials, ``period_count`` distinct periods, mean and
  standard deviation of lidar − reference, mean reference and lidar speeds);
- each replica's own statistics and whether the replica estimates the bin (``targeted``: it
  re-simulated every period replica 0 put there);
- the trials: lidar − reference (m s-1), their cell (height × bins + bin), replica and period, from
  which :mod:`lidarcal.analysis.distribution` builds each bin's output distribution.

Records without replicas are binned lazily (Dask-friendly); their trials are the records.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis import kernels
from lidarcal.analysis._records import checked
from lidarcal.binning import bin_index, binned_statistics
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.units import convert_values

__all__ = ["TRIAL_VARIABLES", "binned"]

#: Variables (dim ``trial``) of the further Monte Carlo replicas in ``simulated_rtd`` records.
TRIAL_VARIABLES = ("trial_replica", "trial_period_key", "trial_height", "trial_lidar_wind_speed",
                   "trial_reference_wind_speed")


def binned(records: xr.Dataset, width: float, source: str) -> tuple[np.ndarray, dict[str, Any]]:
    """Bin edges centred on multiples of ``width`` and the per-(height, bin) statistics and trials."""
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
    # one record per period and height: the trials are the periods, all of replica 0
    x = np.asarray(refv.transpose("time", "height").values, dtype=float)
    d = np.asarray(diff.transpose("time", "height").values, dtype=float)
    b = bin_index(x, edges)
    cell = np.where(b >= 0, np.arange(x.shape[1])[None, :] * nb + b, -1)
    keep = (cell >= 0) & np.isfinite(d)
    # no period key without replicas: each record is its own period
    period = np.broadcast_to(np.arange(x.shape[0])[:, None], x.shape)
    trials = {"diff": d[keep], "cell": cell[keep], "replica": np.zeros(int(keep.sum()), dtype=np.int64),
              "period": period[keep].astype(np.int64)}
    return edges, {"n": n, "mean_difference": mean_diff, "std_difference": std_diff,
                   "mean_reference": mean_ref, "mean_lidar": mean_lidar, "period_count": n,
                   "replicas": [{"n": n, "mean_difference": mean_diff, "std_difference": std_diff,
                                 "mean_reference": mean_ref, "targeted": n > 0}],
                   "replica_numbers": [0], "trials": trials}


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
    """:func:`binned` over replica 0 (the (time, height) records) and every further trial."""
    heights = np.asarray(records["height"].values, dtype=float)
    lid0 = np.asarray(lidar.transpose("time", "height").values)
    ref0 = np.asarray(ref.transpose("time", "height").values)
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
    trials: dict[str, list[np.ndarray]] = {"diff": [], "cell": [], "replica": [], "period": []}
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
        inbin = b >= 0
        trials["diff"].append((lid - x)[inbin])
        trials["cell"].append(i * nb + b[inbin])
        trials["replica"].append(rep[inbin])
        trials["period"].append(keys[inbin])
        pairs = np.unique(np.stack([b[inbin], keys[inbin]]), axis=1)
        pooled["period_count"][i] = np.bincount(pairs[0], minlength=nb)
        # the replica-0 bin of every period with a reference value: the cells a replica targets
        has_ref0 = np.isfinite(ref0[:, i])
        b0 = bin_index(ref0[has_ref0, i], edges)
        k0 = key0[has_ref0]
        present = np.bincount(b0[b0 >= 0], minlength=nb)
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
            d["targeted"][i] = (present > 0) & (missed == 0) & (rn > 0)
    pooled["replicas"] = per
    pooled["replica_numbers"] = replicas
    pooled["trials"] = {k: np.concatenate(v) for k, v in trials.items()}
    return edges, pooled
