"""Adaptive Monte Carlo (JCGM 101 §7.9): replicas until every certified value has settled.

Replica 0 is the campaign as :func:`~lidarcal.campaign.simulate_campaign` simulates it.  A
replica ``r`` >= 1 re-simulates periods with the independent seed entropy
``(base_seed, r, period_key)`` (docs/seeds.md).  After each batch of replicas the budget
(:func:`lidarcal.analysis.budget.budget`) gives, for every certified value (relative expanded
uncertainty per height and wind-speed bin), its numerical tolerance from the h replica
estimates: δ reached = the smallest ½·10^ℓ at least 2·s/√h (JCGM 101 §7.9.4).  Batches
continue until every certified value has settled to ``significant_digits`` significant digits
or ``max_replicas`` replicas (replica 0 included) are done.  Only the cells that have not
settled get new trials: a batch re-simulates, at each height, only the periods whose replica-0
reference wind speed falls in an unsettled bin.

Batches hold 3, 4, 8, 8, ... replicas (a fixed schedule: the replicas run do not depend on the
machine), each batch's replicas submitted together as Dask tasks.  The first check comes at
h = 4 rather than JCGM 101's h = 2: a standard deviation of two estimates has one degree of
freedom, and on small bins it let values stop with a tolerance far smaller than their real
spread.  Everything depends only
on the inputs and seeds, so the result is the same for any workers, scheduler or chunk size,
and with ``workdir`` an interrupted run resumes from its finished chunks.  The trials are
returned as ``trial_*`` variables (dim ``trial``) of the ``simulated_rtd`` records, which the
budget pools with replica 0.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import (
    DEFAULT_CERTIFIED_RANGE,
    DEFAULT_MIN_PERIODS,
    DEFAULT_SIGNIFICANT_DIGITS,
    TRIAL_VARIABLES,
    budget,
)
from lidarcal.binning import bin_index
from lidarcal.campaign.progress import Progress
from lidarcal.campaign.run import DEFAULT_BASE_SEED, simulate_replicas
from lidarcal.errors import InputError
from lidarcal.schema import output_attrs

__all__ = ["adaptive_replicas", "with_trials", "DEFAULT_MAX_REPLICAS", "BATCH_SCHEDULE"]

log = logging.getLogger(__name__)

#: Most replicas (replica 0 included) by default.
DEFAULT_MAX_REPLICAS = 30
#: Replicas per batch, in order; the last repeats (the first check at h = 4 replicas).
BATCH_SCHEDULE = (3, 4, 8)


def with_trials(records: xr.Dataset, trials: Sequence[dict[str, np.ndarray]]) -> xr.Dataset:
    """Return ``records`` with the replica ``trials`` as ``trial_*`` variables on a ``trial`` dim."""
    out = records.drop_vars([n for n in TRIAL_VARIABLES if n in records.variables])
    if not trials:
        return out
    keys = np.asarray(records["period_key"].values, dtype=np.int64)
    cols = {
        "trial_replica": np.concatenate([np.full(t["period"].size, t["replica"], dtype=np.int32)
                                         for t in trials]),
        "trial_period_key": np.concatenate([keys[t["period"]] for t in trials]),
        "trial_height": np.concatenate([t["height"] for t in trials]).astype(float),
        "trial_lidar_wind_speed": np.concatenate([t["lidar_wind_speed"] for t in trials]),
        "trial_reference_wind_speed": np.concatenate([t["reference_wind_speed"] for t in trials]),
    }
    for name, values in cols.items():
        out[name] = ("trial", values, output_attrs("simulated_rtd", name))
    return out


def _batches(max_replicas: int) -> list[list[int]]:
    """Replica numbers of each batch: 1-3, 4-7, 8-15, 16-23, ... up to ``max_replicas - 1``."""
    out, r, i = [], 1, 0
    while r < max_replicas:
        size = min(BATCH_SCHEDULE[min(i, len(BATCH_SCHEDULE) - 1)], max_replicas - r)
        out.append(list(range(r, r + size)))
        r, i = r + size, i + 1
    return out


def _cells(records: xr.Dataset, bud: xr.Dataset) -> np.ndarray:
    """(time, height) periods whose replica-0 reference falls in a certified value that has not settled."""
    flag = bud["numerical_flag"].transpose("height", "wind_speed").values
    bounds = bud["wind_speed_bounds"].values
    edges = np.append(bounds[:, 0], bounds[-1, 1])
    ref = records["reference_wind_speed"].transpose("time", "height").values
    out = np.zeros(ref.shape, dtype=bool)
    for i in range(ref.shape[1]):
        b = bin_index(ref[:, i], edges)
        out[:, i] = (b >= 0) & (flag[i, np.maximum(b, 0)] == 1)
    return out


def adaptive_replicas(
    records: xr.Dataset,
    conditions: str | os.PathLike | xr.Dataset,
    model,
    *,
    terms: xr.Dataset | None = None,
    significant_digits: int = DEFAULT_SIGNIFICANT_DIGITS,
    max_replicas: int = DEFAULT_MAX_REPLICAS,
    min_periods: int = DEFAULT_MIN_PERIODS,
    certified_range: tuple[float, float] = DEFAULT_CERTIFIED_RANGE,
    bin_width: Any = "0.5 m s-1",
    coverage_factor: float = 2.0,
    base_seed: int = DEFAULT_BASE_SEED,
    chunk: int = 64,
    scheduler: Any = None,
    workers: int | None = None,
    workdir: str | os.PathLike | None = None,
    progress: Any = False,
    duration: float = 600.0,
) -> tuple[xr.Dataset, xr.Dataset]:
    """Add Monte Carlo replicas to ``records`` until every certified value has settled.

    Parameters
    ----------
    records : xarray.Dataset
        Replica 0: the ``simulated_rtd`` records of ``conditions`` simulated with ``model`` and
        ``base_seed`` (at the records' heights).
    conditions, model, base_seed, chunk, scheduler, workers, workdir, progress, duration
        As for :func:`~lidarcal.campaign.simulate_campaign` (the same conditions, model, seed and
        duration as replica 0).
    terms, min_periods, certified_range, bin_width, coverage_factor, significant_digits
        As for :func:`lidarcal.analysis.budget.budget`: what is certified and the values settled.
    max_replicas : int
        Most replicas, replica 0 included (1: none added).

    Returns
    -------
    (records, budget)
        The records with the trials of every replica (``trial_*`` variables; none when all had
        settled, or ``max_replicas`` is 1) and the budget of all trials.
    """
    if int(max_replicas) < 1:
        raise InputError(f"max_replicas must be >= 1; got {max_replicas}")
    if int(records.attrs.get("lidarcal_base_seed", base_seed)) != int(base_seed):
        raise InputError(f"records were simulated with base seed {records.attrs['lidarcal_base_seed']}; "
                         f"replicas asked with {base_seed}")
    opts = dict(terms=terms, min_periods=min_periods, certified_range=certified_range, bin_width=bin_width,
                coverage_factor=coverage_factor, significant_digits=significant_digits)
    heights = [float(z) for z in records["height"].values]
    progress = Progress.of(progress)
    trials: list[dict[str, np.ndarray]] = []
    current = with_trials(records, trials)
    bud = budget(current, **opts)
    for batch in _batches(int(max_replicas)):
        cells = _cells(records, bud)
        if not cells.any():
            break
        log.info("Monte Carlo replicas %s: %d certified value(s) not settled to %d digits; re-simulating %d "
                 "(period, height) cells", f"{batch[0]}-{batch[-1]}" if len(batch) > 1 else batch[0],
                 int((bud["numerical_flag"] == 1).sum()), int(significant_digits), int(cells.sum()))
        label = (f"replicas {batch[0]}-{batch[-1]}" if len(batch) > 1 else f"replica {batch[0]}")
        done = simulate_replicas(conditions, model, cells, batch, heights=heights, base_seed=base_seed,
                                 chunk=chunk, scheduler=scheduler, workers=workers, workdir=workdir,
                                 progress=progress.labelled(f"{label} (of at most {int(max_replicas)})"),
                                 duration=duration)
        trials += [{"replica": r, **done[r]} for r in batch]
        current = with_trials(records, trials)
        bud = budget(current, **opts)
    return current, bud
