"""The model-form runs: every defensible alternative model on a subsample of periods, common random numbers.

The budget's ``model_form`` contributor (:mod:`lidarcal.analysis.model_form`, ``docs/method.md``)
is the spread of the certified value across the alternatives of
:data:`lidarcal.lidar.model_form.ALTERNATIVES`.  To measure the *change* a model choice makes,
each alternative re-simulates periods of the campaign with the nominal run's own random streams
(replica 0's seed entropy ``(base_seed, period_key)``, docs/seeds.md): the same Fourier draws, noise
draws and availability draws, filtered through the alternative model.  The difference from the
nominal run is then free of most of the sampling noise a fresh draw would add.

Which periods: at each height, the replica-0 periods are binned by their reference wind speed on
the budget's lattice (bins of ``bin_width`` centred on its multiples); a bin's periods are all
taken when it holds at most ``per_bin`` of them, otherwise ``per_bin`` of them evenly spaced in
time.  With ``wind_speeds`` only the bins whose centre lies in that range (the certified range)
are re-simulated; the budget gives the others the term of the nearest bin at their height.  The
runs are added to the ``simulated_rtd`` records as ``model_form_*`` variables (dims
``model_form_alternative``, ``model_form_sample``), beside the Monte Carlo replicas' ``trial_*``.
Everything depends only on the records, the model and the seeds: any workers, scheduler or chunk
size give the same numbers.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.kernels import centred_edges
from lidarcal.binning import bin_index
from lidarcal.campaign.run import DEFAULT_BASE_SEED, simulate_replicas
from lidarcal.campaign.settings import Execution
from lidarcal.errors import InputError
from lidarcal.lidar.model_form import ALTERNATIVES, alternative_models
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs
from lidarcal.units import to_magnitude

__all__ = ["DEFAULT_PER_BIN", "MODEL_FORM_VARIABLES", "model_form_runs", "select_periods", "with_model_form"]

log = logging.getLogger(__name__)

#: Most periods per (height, reference wind-speed bin) each alternative re-simulates.
DEFAULT_PER_BIN = 16
#: Variables the runs add to the ``simulated_rtd`` records.
MODEL_FORM_VARIABLES = ("model_form_alternative", "model_form_description", "model_form_model",
                        "model_form_period_key", "model_form_height", "model_form_lidar_wind_speed",
                        "model_form_reference_wind_speed")


def select_periods(records: xr.Dataset, per_bin: int = DEFAULT_PER_BIN, bin_width: Any = "0.5 m s-1",
                   wind_speeds: tuple[float, float] | None = None) -> np.ndarray:
    """(time, height) bool: the replica-0 periods the alternatives re-simulate.

    Per height and reference wind-speed bin (``bin_width`` wide, centred on its multiples, as the
    budget bins), every period with a finite lidar and reference speed when the bin holds at most
    ``per_bin``, otherwise ``per_bin`` of them evenly spaced in time order; with ``wind_speeds``
    (m s-1, inclusive) only the bins whose centre lies in that range.
    """
    per_bin = int(per_bin)
    if per_bin < 2:
        raise InputError(f"per_bin must be >= 2 periods (a standard deviation needs two); got {per_bin}")
    width = float(to_magnitude(bin_width, "m s-1", name="bin_width"))
    ref = records["reference_wind_speed"].transpose("time", "height").values
    lid = records["lidar_wind_speed"].transpose("time", "height").values
    ok = np.isfinite(ref) & np.isfinite(lid)
    out = np.zeros(ref.shape, dtype=bool)
    if not ok.any():
        return out
    edges = centred_edges(float(ref[ok].min()), float(ref[ok].max()), width)
    centres = 0.5 * (edges[:-1] + edges[1:])
    wanted = np.ones(centres.size, dtype=bool) if wind_speeds is None else (
        (centres >= float(wind_speeds[0]) - 1e-9) & (centres <= float(wind_speeds[1]) + 1e-9))
    for i in range(ref.shape[1]):
        rows = np.flatnonzero(ok[:, i])
        b = bin_index(ref[rows, i], edges)
        for cell in np.unique(b[b >= 0]):
            if not wanted[cell]:
                continue
            mine = rows[b == cell]  # in time order
            if mine.size > per_bin:
                mine = mine[np.unique(np.round(np.linspace(0, mine.size - 1, per_bin)).astype(int))]
            out[mine, i] = True
    return out


def model_form_runs(
    records: xr.Dataset,
    conditions: str | os.PathLike | xr.Dataset,
    model,
    *,
    per_bin: int = DEFAULT_PER_BIN,
    bin_width: Any = "0.5 m s-1",
    wind_speeds: tuple[float, float] | None = None,
    base_seed: int = DEFAULT_BASE_SEED,
    duration: float = 600.0,
    execution: Execution | Mapping[str, Any] | None = None,
) -> xr.Dataset:
    """Simulate every alternative of ``model`` on the selected periods; return ``records`` with the runs.

    Parameters
    ----------
    records : xarray.Dataset
        Replica 0: the ``simulated_rtd`` records of ``conditions`` simulated with ``model`` and
        ``base_seed`` (the runs reuse its seeds: common random numbers).
    conditions, model, base_seed, duration, execution
        As for :func:`~lidarcal.campaign.simulate_campaign`; each alternative keeps its chunks in its
        own ``model-form-<name>`` folder of ``execution.workdir``.
    per_bin, bin_width, wind_speeds
        At most ``per_bin`` periods per (height, reference wind-speed bin), only the bins with
        centres in ``wind_speeds`` when given (:func:`select_periods`).

    Returns
    -------
    xarray.Dataset
        ``records`` with the ``model_form_*`` variables (:data:`MODEL_FORM_VARIABLES`); unchanged
        (and without them) when no alternative applies.
    """
    seed = read_attr(records, "lidarcal_base_seed", kind="simulated_rtd", default=int(base_seed))
    if seed != int(base_seed):
        raise InputError(f"records were simulated with base seed {seed}; "
                         f"the model-form runs asked with {base_seed} (common random numbers need the same)")
    models = alternative_models(model)
    if not models:
        return records
    cells = select_periods(records, per_bin, bin_width, wind_speeds)
    heights = [float(z) for z in records["height"].values]
    log.info("model form: %d alternative(s) (%s) on %d (period, height) cells, at most %d per bin, with the "
             "nominal run's seeds", len(models), ", ".join(models), int(cells.sum()), int(per_bin))
    run = Execution.of(execution)
    runs = {}
    for i, (name, alt) in enumerate(models.items(), 1):
        where = None if run.workdir is None else os.path.join(os.fspath(run.workdir), f"model-form-{name}")
        said = run.labelled(f"model form {name} ({i} of {len(models)})").replace(workdir=where)
        runs[name] = simulate_replicas(conditions, alt, cells, [0], heights=heights, base_seed=base_seed,
                                       duration=duration, execution=said)[0]
    return with_model_form(records, models, runs, per_bin=int(per_bin))


def with_model_form(records: xr.Dataset, models: dict, runs: dict[str, dict[str, np.ndarray]], *,
                    per_bin: int) -> xr.Dataset:
    """Return ``records`` with the alternatives' ``runs`` (per name, as :func:`simulate_replicas` gives)."""
    out = records.drop_vars([n for n in MODEL_FORM_VARIABLES if n in records.variables])
    names = list(runs)
    if not names:
        return out
    first = runs[names[0]]
    for name in names[1:]:  # every alternative ran on the same cells, in the same order
        if not (np.array_equal(runs[name]["period"], first["period"])
                and np.array_equal(runs[name]["height"], first["height"])):
            raise InputError(f"model-form run {name!r} covers other cells than {names[0]!r}")
    keys = np.asarray(records["period_key"].values, dtype=np.int64)
    described = {a.name: a.description for a in ALTERNATIVES}
    context = {"per_bin": per_bin}
    alt_dims, sample, both = ("model_form_alternative",), ("model_form_sample",), (
        "model_form_alternative", "model_form_sample")
    out = out.assign_coords(model_form_alternative=(alt_dims, np.array(names, dtype=object),
                                                    output_attrs("simulated_rtd", "model_form_alternative")))
    values = {
        "model_form_description": (alt_dims, np.array([described[n] for n in names], dtype=object)),
        "model_form_model": (alt_dims, np.array([models[n].to_json() for n in names], dtype=object)),
        "model_form_period_key": (sample, keys[first["period"]]),
        "model_form_height": (sample, np.asarray(first["height"], dtype=float)),
        "model_form_lidar_wind_speed": (both, np.stack([runs[n]["lidar_wind_speed"] for n in names])),
        "model_form_reference_wind_speed": (both, np.stack([runs[n]["reference_wind_speed"] for n in names])),
    }
    for name, (dims, data) in values.items():
        out[name] = (dims, data, output_attrs("simulated_rtd", name, **context))
    return out
