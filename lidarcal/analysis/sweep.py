"""Analysis of a classification-style sweep (paper §4, Discussion a and b).

The virtual lidar is simulated on the full-factorial grid of
:func:`lidarcal.conditions.grid.sweep_conditions` (the orchestration is
:func:`lidarcal.pipeline.sweep`); :func:`analyse_sweep` reads the simulated records back
onto the grid:

- ``deviation`` — the mean relative lidar−reference deviation (%) at every grid point and
  height (averaged over ``repeats`` Monte Carlo replicates with different seeds);
- ``max_abs_deviation`` — its maximum magnitude over the grid per height (the class-style
  figure of Discussion a) and the conditions where it occurs;
- sensitivity slopes of the deviation to every swept variable (Discussion b), from
  :func:`lidarcal.analysis.sensitivity.sensitivity_fit` with one bin per grid value: in a
  full-factorial design a bin mean is the marginal effect of that variable.

The attributes of every variable are declared in ``schemas/sweep.yaml``.

Grid period *i* is simulated with seed ``(base_seed, i)`` as in any campaign, with the
replicates of one grid point consecutive: period = grid_index × repeats + replicate.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.sensitivity import per_unit, sensitivity_fit
from lidarcal.conditions.grid import SWEEP_VARIABLES, grid_values
from lidarcal.conditions.variables import CANONICAL_UNITS, STANDARD_NAMES
from lidarcal.errors import InputError
from lidarcal.provenance import stamp
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs

__all__ = ["analyse_sweep"]


def _edges(values: np.ndarray) -> np.ndarray:
    mid = 0.5 * (values[1:] + values[:-1])
    return np.concatenate([[values[0] - (mid[0] - values[0])], mid, [values[-1] + (values[-1] - mid[-1])]])


def analyse_sweep(
    records: xr.Dataset,
    grid: Mapping[str, Any] | None,
    *,
    repeats: int = 1,
    call: str | None = None,
    inputs: Mapping[str, Any] | None = None,
) -> xr.Dataset:
    """Turn simulated records of :func:`~lidarcal.conditions.grid.sweep_conditions` into a ``sweep`` artefact.

    Parameters
    ----------
    records : xarray.Dataset
        ``simulated_rtd`` records of the grid, in grid order.  The lidar model and base seed
        recorded on them (``lidarcal_lidar_model``, ``lidarcal_base_seed``) go into the
        artefact's provenance.
    grid : mapping or None
        The grid the conditions were built from (as for
        :func:`~lidarcal.conditions.grid.grid_values`).
    repeats : int
        Monte Carlo replicates per grid point.
    call : str, optional
        What produced it, for the ``history`` attribute.
    inputs : mapping of role to path, optional
        Input files, recorded with their SHA-256.
    """
    values = grid_values(grid)
    shape = tuple(len(values[n]) for n in SWEEP_VARIABLES)
    n_grid = int(np.prod(shape))
    nt = records.sizes["time"]
    if nt != n_grid * repeats:
        raise InputError(f"records have {nt} periods; the grid has {n_grid} points x {repeats} repeats")
    lidar = records["lidar_wind_speed"].transpose("time", "height").values
    ref = records["reference_wind_speed"].transpose("time", "height").values
    heights = records["height"].values
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = 100.0 * (lidar - ref) / ref
    rel = rel.reshape(n_grid, repeats, len(heights))
    with np.errstate(invalid="ignore"):
        dev = np.nanmean(rel, axis=1) if repeats > 1 else rel[:, 0]
        spread = np.nanstd(rel, axis=1, ddof=1) if repeats > 1 else np.full_like(dev, np.nan)
    if not np.isfinite(dev).any():
        raise InputError("no grid point has a finite simulated deviation (all periods skipped?)")
    dev_grid = np.moveaxis(dev.reshape(*shape, len(heights)), -1, 0)
    spread_grid = np.moveaxis(spread.reshape(*shape, len(heights)), -1, 0)
    absdev = np.where(np.isfinite(dev), np.abs(dev), -np.inf)
    where = np.argmax(absdev, axis=0)  # per height, flat grid index of the largest |deviation|
    at = np.array(np.unravel_index(where, shape))  # (variable, height)

    def attrs(name: str, variable: str | None = None) -> dict[str, Any]:
        context = {} if variable is None else {
            "xname": variable.replace("_", " "), "standard_name": STANDARD_NAMES.get(variable, ""),
            "slope_units": per_unit("%", CANONICAL_UNITS[variable])}
        return output_attrs("sweep", name, repeats=repeats, **context)

    gdims = ("height", *SWEEP_VARIABLES)
    data = {
        "deviation": (gdims, dev_grid),
        "deviation_replicate_std": (gdims, spread_grid),
        "max_abs_deviation": ("height", np.take_along_axis(np.abs(dev), where[None, :], 0)[0]),
        "max_deviation": ("height", np.take_along_axis(dev, where[None, :], 0)[0]),
        "mean_deviation": ("height", np.nanmean(dev, axis=0)),
    }
    data = {name: (*spec, attrs(name)) for name, spec in data.items()}
    for i, name in enumerate(SWEEP_VARIABLES):
        key = f"max_deviation_{name}"
        data[key] = ("height", values[name][at[i]], attrs(key, name))
    swept = [n for n in SWEEP_VARIABLES if len(values[n]) > 1]
    stats = {k: np.full((len(swept), len(heights)), np.nan)
             for k in ("slope_times_std", "slope_times_std_times_r", "correlation")}
    flags = np.zeros((len(swept), len(heights)), dtype=np.int8)
    for j, name in enumerate(swept):
        # a deterministic grid: one value per bin, no sampling error to weight by
        fit = sensitivity_fit(records, name, _edges(values[name]), min_periods=1, reference_range=None,
                              regression="unweighted")
        for k in stats:
            stats[k][j] = fit[k]
        flags[j] = fit["significant"]
        data[f"slope_{name}"] = ("height", fit["slope"], attrs(f"slope_{name}", name))
    coords = {"height": records["height"].variable.copy(),
              **{name: (name, values[name], attrs(name, name)) for name in SWEEP_VARIABLES}}
    if swept:
        vd = ("variable", "height")
        data.update({k: (vd, v, attrs(k)) for k, v in stats.items()})
        data["significant"] = (vd, flags, attrs("significant"))
        coords["variable"] = ("variable", np.array(swept, dtype=object), attrs("variable"))
    ds = xr.Dataset(data, coords=coords)
    ds["height"].attrs = dict(records["height"].attrs)
    ds.attrs = {
        "sweep_grid": json.dumps({k: v.tolist() for k, v in values.items()}),
        "sweep_repeats": int(repeats),
        "sweep_points": n_grid,
        "deviation_definition": "100 % * (lidar_wind_speed - reference_wind_speed) / reference_wind_speed",
    }
    for key in ("lidarcal_lidar_model", "lidarcal_base_seed"):
        if key in records.attrs:
            ds.attrs[key] = records.attrs[key]
    return _stamp(ds, records, values, repeats=int(repeats), call=call, inputs=inputs)


def _stamp(ds, records, values, *, repeats, call, inputs) -> xr.Dataset:
    """Provenance of the ``sweep`` artefact, from the grid and what the records say of their run."""
    n = int(np.prod([len(v) for v in values.values()]))
    run = json.loads(records.attrs.get("lidarcal_config", "{}"))
    config = {
        "grid": {k: v.tolist() for k, v in values.items()},
        "heights": [float(h) for h in records["height"].values],
        "repeats": repeats,
    }
    if "chunk" in run:
        config["chunk"] = run["chunk"]
    if (model := read_attr(records, "lidarcal_lidar_model", kind="simulated_rtd")) is not None:
        config["lidar_model"] = model
    seeds = {"scheme": "SeedSequence([base_seed, period_key, round(height_m * 1000)]), period_key = seconds "
                       "since 1970 of the synthetic time 2000-01-01T00:00 + 600 s * (grid_index * repeats "
                       "+ replicate)"}
    if (seed := read_attr(records, "lidarcal_base_seed", kind="simulated_rtd")) is not None:
        seeds = {"base_seed": seed, **seeds}
    return stamp(
        ds,
        "sweep",
        title="Classification-style sweep of the virtual lidar over a full grid of conditions",
        summary=(
            f"Virtual lidar simulated on a full-factorial grid of {n} condition points x {repeats} "
            "replicate(s): mean relative deviation from the virtual reference at every point, its maximum "
            "magnitude over the grid, and sensitivity slopes (paper Discussion a-b)."
        ),
        call=call or "lidarcal.analysis.sweep.analyse_sweep",
        inputs=dict(inputs or {}),
        config=config,
        seeds=seeds,
    )
