"""Adaptive Monte Carlo (JCGM 101 §7.9): replicas until every certified value has settled.

Replica 0 is the campaign as :func:`~lidarcal.campaign.simulate_campaign` simulates it.  A
replica ``r`` >= 1 re-simulates periods with the independent seed entropy
``(base_seed, r, period_key)`` (docs/seeds.md).  After each batch of replicas the budget
(:func:`lidarcal.analysis.budget.budget`) assesses every bin certified but for its numerical
state: its five values (estimate, standard uncertainty, both coverage-interval endpoints and the
k = 2 expanded uncertainty) must each reach the tolerance δ of ``significant_digits``
significant digits of U, their half-width being the larger of t₀.₉₇₅(h − 1)·s/√h over the h
replicas and 1.96 times the delta-method standard deviation from all trials
(:func:`lidarcal.analysis.certification.numerical_state`).  Batches continue until every such
bin has settled or ``max_replicas`` replicas (replica 0 included) are done; a bin still
unsettled is flagged ``not_settled`` and not certified.

Batches hold 1, 2, 4, 8, 8, ... replicas (:data:`BATCH_SCHEDULE`, a fixed schedule: the
replicas run do not depend on the machine), so the first check comes at h = 2, as soon as a
replica scatter exists (the Student factor, 12.7 at h = 2, makes an early stop honest).  Within
a batch, the periods re-simulated at each height are those whose replica-0 reference wind speed
falls in a bin that has not settled and is expected to need more replicas than it has had (the
budget's ``replicas_needed``, the smallest h at which both half-widths, extrapolated from the
replicas so far, reach δ — Stein's two-stage idea as in Wübbeler, Harris, Cox and Elster,
Metrologia 47 (2010) 317, refreshed after every batch — against its ``replica_count``): a bin
needing n more takes part in the first n replicas of the batch, and one expected (from h = 4
on) to need more than ``max_replicas`` even if its replica spread were over-stated as much as it
is once in a hundred times takes part in none: it would end not settled anyway, and its replicas
would only cost time.  Each batch's replicas are
submitted together as Dask tasks.  Everything depends only on the inputs and seeds, so the
result is the same for any workers, scheduler or chunk size, and with ``workdir`` an
interrupted run resumes from its finished chunks.  The trials are returned as ``trial_*``
variables (dim ``trial``) of the ``simulated_rtd`` records, which the budget pools with replica 0.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import xarray as xr
from scipy import stats

from lidarcal.analysis.budget import TRIAL_VARIABLES, budget
from lidarcal.analysis.certification import digits_text
from lidarcal.analysis.rule import CertificationRule
from lidarcal.binning import bin_index
from lidarcal.campaign.run import DEFAULT_BASE_SEED, simulate_replicas
from lidarcal.campaign.settings import Execution
from lidarcal.errors import InputError
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs

__all__ = ["adaptive_replicas", "with_trials", "DEFAULT_MAX_REPLICAS", "BATCH_SCHEDULE"]

log = logging.getLogger(__name__)

#: Most replicas (replica 0 included) by default.
DEFAULT_MAX_REPLICAS = 30
#: What is kept of each replica's trials (the other engine outputs are dropped as they arrive).
_KEPT = ("period", "height", "lidar_wind_speed", "reference_wind_speed")
#: Replicas (of a bin) from which a bin expected to need far more than the most replicas is given
#: up (:func:`_futile`): its replica spread then rests on 3 degrees of freedom at least.
FUTILE_AFTER = 4
#: Replicas per batch, in order; the last repeats (checks at h = 2, 4, 8, 16, 24, ...).
BATCH_SCHEDULE = (1, 2, 4, 8)


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
    """Replica numbers of each batch: 1, 2-3, 4-7, 8-15, 16-23, ... up to ``max_replicas - 1``."""
    out, r, i = [], 1, 0
    while r < max_replicas:
        size = min(BATCH_SCHEDULE[min(i, len(BATCH_SCHEDULE) - 1)], max_replicas - r)
        out.append(list(range(r, r + size)))
        r, i = r + size, i + 1
    return out


def _futile(needed: np.ndarray, count: np.ndarray, max_replicas: int) -> np.ndarray:
    """Bins expected to need more than ``max_replicas`` replicas however their spread was over-stated.

    ``needed`` grows with the square of the replica spread s, estimated on h − 1 degrees of
    freedom (h = ``count``); s² over-states σ² by more than χ²₀.₉₉(h − 1)/(h − 1) once in a hundred
    times (3.8 at h = 4, 2.6 at h = 8, 2.0 at h = 16).  A bin whose ``needed`` exceeds that many
    times ``max_replicas`` would end not settled anyway.  Only from h = :data:`FUTILE_AFTER` on.

    >>> _futile(np.array([100, 120, 60]), np.array([4, 4, 8]), 30).tolist()
    [False, True, False]
    """
    h = np.asarray(count, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        dof = np.maximum(h - 1, 1)
        factor = np.where(h >= FUTILE_AFTER, stats.chi2.ppf(0.99, dof) / dof, np.inf)
    return np.asarray(needed, dtype=float) > factor * int(max_replicas)


def _cells(records: xr.Dataset, bud: xr.Dataset, batch: Sequence[int],
           max_replicas: int) -> dict[int, np.ndarray]:
    """Per replica of ``batch``, the (time, height) periods it re-simulates.

    A period is re-simulated by the first n replicas of the batch when its replica-0 reference
    falls in a bin that is certified but for its numerical state and has not settled, n being the
    replicas the bin still needs (``replicas_needed`` − ``replica_count``).  A bin is given up
    (:func:`_futile`) when it would need more than ``max_replicas`` even if its replica spread
    were over-stated as much as it is once in a hundred times.
    """
    flag = bud["numerical_flag"].transpose("height", "wind_speed").values
    needed = bud["replicas_needed"].transpose("height", "wind_speed").values
    count = bud["replica_count"].transpose("height", "wind_speed").values
    futile = _futile(needed, count, int(max_replicas))
    need = np.where(futile, 0, needed - count)
    bounds = bud["wind_speed_bounds"].values
    edges = np.append(bounds[:, 0], bounds[-1, 1])
    ref = records["reference_wind_speed"].transpose("time", "height").values
    bins = np.stack([bin_index(ref[:, i], edges) for i in range(ref.shape[1])], axis=1)
    heights = np.broadcast_to(np.arange(ref.shape[1])[None, :], ref.shape)
    open_ = (bins >= 0) & (flag[heights, np.maximum(bins, 0)] == 1)
    wanted = np.where(open_, need[heights, np.maximum(bins, 0)], 0)
    return {r: wanted > j for j, r in enumerate(batch)}


def adaptive_replicas(
    records: xr.Dataset,
    conditions: str | os.PathLike | xr.Dataset,
    model,
    *,
    terms: xr.Dataset | None = None,
    rule: CertificationRule | Mapping[str, Any] | None = None,
    max_replicas: int = DEFAULT_MAX_REPLICAS,
    bin_width: Any = "0.5 m s-1",
    base_seed: int = DEFAULT_BASE_SEED,
    duration: float = 600.0,
    execution: Execution | Mapping[str, Any] | None = None,
) -> tuple[xr.Dataset, xr.Dataset]:
    """Add Monte Carlo replicas to ``records`` until every certified value has settled.

    Parameters
    ----------
    records : xarray.Dataset
        Replica 0: the ``simulated_rtd`` records of ``conditions`` simulated with ``model`` and
        ``base_seed`` (at the records' heights).
    conditions, model, base_seed, duration, execution
        As for :func:`~lidarcal.campaign.simulate_campaign` (the same conditions, model, seed and
        duration as replica 0).
    terms, rule, bin_width
        As for :func:`lidarcal.analysis.budget.budget`: what is certified and the values settled
        (:class:`~lidarcal.analysis.rule.CertificationRule`).
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
    seed = read_attr(records, "lidarcal_base_seed", kind="simulated_rtd", default=int(base_seed))
    if seed != int(base_seed):
        raise InputError(f"records were simulated with base seed {seed}; "
                         f"replicas asked with {base_seed}")
    rule = CertificationRule.of(rule)
    opts = dict(terms=terms, rule=rule, bin_width=bin_width)
    heights = [float(z) for z in records["height"].values]
    run = Execution.of(execution)
    trials: list[dict[str, np.ndarray]] = []
    current = with_trials(records, trials)
    bud = budget(current, **opts)
    for batch in _batches(int(max_replicas)):
        cells = _cells(records, bud, batch, int(max_replicas))
        cells = {r: c for r, c in cells.items() if c.any()}
        if not cells:
            break
        first, last = min(cells), max(cells)
        log.info("Monte Carlo replicas %s: %d certified bin(s) not settled to %s; re-simulating %d "
                 "(period, height) cells", f"{first}-{last}" if last > first else first,
                 int((bud["numerical_flag"] == 1).sum()), digits_text(rule.significant_digits),
                 int(sum(c.sum() for c in cells.values())))
        label = f"replicas {first}-{last}" if last > first else f"replica {first}"
        done = simulate_replicas(conditions, model, cells, list(cells), heights=heights, base_seed=base_seed,
                                 duration=duration,
                                 execution=run.labelled(f"{label} (of at most {int(max_replicas)})"))
        # keep only what the budget and the records need: memory grows by four numbers a trial
        trials += [{"replica": r, **{k: done[r][k] for k in _KEPT}} for r in sorted(done)]
        current = with_trials(records, trials)
        bud = budget(current, **opts)
    return current, bud
