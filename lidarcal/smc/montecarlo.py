"""The Monte Carlo route (paper §4 c): the calibrated virtual lidar simulated in the campaign's conditions.

:func:`monte_carlo_route` simulates every period of the campaign at its certified heights with
the certificate's own lidar model (bench cube, RWF and every setting of the calibration,
:meth:`lidarcal.smc.certified.Certified.lidar_model`), each period at its own wind speed,
direction, TI, shear, CNR and CNR gradient, on Dask (:func:`lidarcal.campaign.simulate_campaign`),
and then:

* **per wind-speed bin** the campaign's budget as the certificate computes its own
  (:func:`lidarcal.analysis.budget.budget` with the certificate's Table 4 terms, coverage factor
  and certified range): mean deviation (lidar − reference), its spread, trials, and the
  relative expanded uncertainty, so that a campaign in the calibration's own conditions gives
  the certificate's budget back.  A contributor the campaign's trials cannot give (the
  simulation's ``model_form``, which needs the alternative models' runs) is carried over from
  the certificate: its relative value at the same height and bin (the nearest certified-range
  bin outside it, as the budget fills its own) times the campaign bin's mean reference speed
  (:func:`with_carried`);
* **per period** the deviation expected of the virtual lidar given its conditions: the bin's
  mean deviation plus pooled within-bin least-squares slopes on TI, shear, CNR and CNR gradient
  (:mod:`lidarcal.smc.expected`), so one period's turbulence draw does not pass for an
  environmental effect.

**Numerical tolerance, adaptively** (JCGM 101 §7.9): the trials of a bin are split into h = 4
sequences (:func:`lidarcal.smc.kernels.group_of`: trial (period p, replica r) goes to sequence
(p + r) mod 4); each sequence's estimate of the bin's relative expanded uncertainty gives the
tolerance t₀.₉₇₅(h − 1)·s/√h rounded up to ½·10^ℓ (the Student factor, since s rests on h − 1
degrees of freedom: :func:`lidarcal.analysis.montecarlo.replica_half_width`), and a bin has
settled when that is within the certificate's significant digits
(:func:`lidarcal.analysis.certification.settle_target`).  A bin
the campaign fills with many periods settles from its own periods; only the periods of bins
that have not settled are re-simulated as further replicas (:func:`lidarcal.campaign.run.simulate_replicas`,
seed entropy ``(base_seed, r, period_key)``), in batches of 3, 4, 8, 8 … replicas up to
``max_replicas``.  (``lidarcal calibrate`` re-runs whole replicas: a calibration campaign is
short, so its bins hold few periods; a campaign of a year holds thousands per bin.)  Only bins
whose centre is certified at that height are assessed: the others are not covered anyway.
Everything depends on the inputs and seeds only: bit-identical for any scheduler, workers or chunk.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import budget
from lidarcal.analysis.certification import settle_target
from lidarcal.analysis.montecarlo import replica_half_width, tolerance_exponent
from lidarcal.analysis.rule import CertificationRule
from lidarcal.binning import binned_statistics
from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.adaptive import BATCH_SCHEDULE, with_trials
from lidarcal.campaign.chunks import period_keys
from lidarcal.campaign.run import simulate_replicas
from lidarcal.campaign.settings import Execution
from lidarcal.cf import height_coord, time_coord
from lidarcal.readback import read_attr
from lidarcal.schema import output_attrs
from lidarcal.smc import subsample
from lidarcal.smc.expected import REGRESSORS, ExpectedFit, fit_expected
from lidarcal.smc.kernels import SEQUENCES, bin_index, group_of

__all__ = ["MonteCarloRoute", "monte_carlo_route", "with_carried"]

log = logging.getLogger(__name__)

#: Monte Carlo budget contributors computed from the trials (recomputed per JCGM 101 sequence).
_FROM_TRIALS = ("mean_difference", "std_difference", "statistical")


@dataclass(frozen=True)
class MonteCarloRoute:
    """What the Monte Carlo route computed (see the module docstring)."""

    records: xr.Dataset  #: simulated records, replica 0 on (time, height) and further trials
    budget: xr.Dataset  #: the campaign's Monte Carlo budget per (height, reference wind-speed bin)
    tolerance: np.ndarray  #: (height, budget bin) numerical tolerance of its relative expanded U (%)
    settled: np.ndarray  #: (height, budget bin) 0 settled, 1 not settled, 2 not assessed
    fit: ExpectedFit  #: the within-bin fit giving each period's expected deviation (:meth:`at`)
    slopes: np.ndarray  #: (height, regressor) within-bin slopes of the deviation (m s-1 per unit)
    rows: np.ndarray  #: (record period,) the campaign period (time index) of each simulated period
    count: np.ndarray  #: (record period, height) trials simulated of each of them
    replicas: int  #: replicas run, replica 0 included
    periods_per_bin: int | None  #: most periods simulated per (height, bin); None: every period
    periods_simulated: np.ndarray  #: (height, budget bin) distinct periods among the bin's trials
    population: np.ndarray  #: (height, budget bin) the campaign's periods in the bin (their own speed)
    mean_difference_se: np.ndarray  #: (height, budget bin) SE of the mean deviation from subsampling, m s-1
    std_difference_se: np.ndarray  #: (height, budget bin) SE of the spread from subsampling, m s-1

    def at(self, conditions: xr.Dataset, start: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return (expected deviation, its standard error, trials) of a block of the campaign's periods.

        ``conditions`` are the campaign's periods ``start``, ``start + 1`` … at the simulated heights,
        (time, height) arrays on them: the route holds no per-period array of the campaign, so a
        campaign of any length is taken block by block (:mod:`lidarcal.smc.periods`).
        """
        expected, se = self.fit.at(conditions)
        trials = np.zeros(expected.shape, dtype=np.int64)
        mine = (self.rows >= start) & (self.rows < start + expected.shape[0])
        trials[self.rows[mine] - start] = self.count[mine]
        return expected, se, trials

    @property
    def simulated(self) -> int:
        """Period-heights simulated at least once."""
        return int((self.count > 0).sum())


def with_carried(bud: xr.Dataset, carried: xr.Dataset | None) -> xr.Dataset:
    """Add to a budget the contributors ``carried`` holds that it lacks; recombine its totals.

    ``carried`` holds relative contributions (%) on (height, wind_speed, contributor) at the
    budget's heights and the certificate's bin centres; each budget bin takes the nearest centre's
    value times its own mean reference wind speed.  The combined, expanded and relative
    uncertainties are recomputed in quadrature over every contributor, as the budget combines them.
    """
    if carried is None:
        return bud
    have = [str(c) for c in bud["contributor"].values]
    extra = [str(c) for c in carried["contributor"].values if str(c) not in have]
    if not extra:
        return bud
    b = bud.transpose("height", "wind_speed", "contributor", ...)
    centres = np.asarray(carried["wind_speed"].values, dtype=float)
    at = np.asarray(b["wind_speed"].values, dtype=float)
    nearest = np.abs(at[:, None] - centres[None, :]).argmin(axis=1)
    rel = carried.transpose("height", "wind_speed", "contributor")["relative_contribution"].sel(
        contributor=extra).values[:, nearest, :]  # (height, budget bin, extra), %
    mean_ref = b["mean_reference_wind_speed"].values
    contribution = np.concatenate([b["contribution"].values, rel * mean_ref[..., None] / 100.0], axis=-1)
    combined = np.sqrt(np.sum(contribution**2, axis=-1))
    k = read_attr(b, "coverage_factor", kind="uncertainty_budget")
    with np.errstate(invalid="ignore", divide="ignore"):
        pct = 100.0 / mean_ref
    out = b.drop_vars(["contribution", "relative_contribution"]).drop_dims("contributor")
    hwc = ("height", "wind_speed", "contributor")
    out = out.assign_coords(contributor=("contributor", np.array(have + extra, dtype=object),
                                         dict(b["contributor"].attrs)))
    out["contribution"] = (hwc, contribution, dict(b["contribution"].attrs))
    out["relative_contribution"] = (hwc, contribution * pct[..., None],
                                    dict(b["relative_contribution"].attrs))
    for name, value in (("uncertainty", combined), ("relative_uncertainty", combined * pct),
                        ("expanded_uncertainty", k * combined),
                        ("relative_expanded_uncertainty", k * combined * pct)):
        out[name] = (("height", "wind_speed"), value, dict(b[name].attrs))
    out.attrs["carried_from_certificate"] = ", ".join(extra)
    return out


def _batches(max_replicas: int) -> list[list[int]]:
    """Replica numbers of each batch (the schedule of :mod:`lidarcal.campaign.adaptive`)."""
    out, r, i = [], 1, 0
    while r < max_replicas:
        size = min(BATCH_SCHEDULE[min(i, len(BATCH_SCHEDULE) - 1)], max_replicas - r)
        out.append(list(range(r, r + size)))
        r, i = r + size, i + 1
    return out


def _trials(records: xr.Dataset, heights: np.ndarray) -> dict[str, np.ndarray]:
    """Every trial as flat arrays: period index, height index, replica, lidar and reference speeds."""
    lid = records["lidar_wind_speed"].transpose("time", "height").values
    ref = records["reference_wind_speed"].transpose("time", "height").values
    nt, nh = lid.shape
    t, h = np.meshgrid(np.arange(nt), np.arange(nh), indexing="ij")
    out = {
        "period": t.ravel(),
        "height": h.ravel(),
        "replica": np.zeros(lid.size, dtype=np.int64),
        "lidar": lid.ravel(),
        "reference": ref.ravel(),
    }
    if "trial_replica" in records.variables:
        keys = np.asarray(records["period_key"].values, dtype=np.int64)  # increasing with time
        period = np.searchsorted(keys, np.asarray(records["trial_period_key"].values, dtype=np.int64))
        th = np.asarray(records["trial_height"].values, dtype=float)
        hidx = np.abs(th[:, None] - heights[None, :]).argmin(axis=1)
        out = {
            "period": np.concatenate([out["period"], period]).astype(np.int64),
            "height": np.concatenate([out["height"], hidx]),
            "replica": np.concatenate([out["replica"], records["trial_replica"].values.astype(np.int64)]),
            "lidar": np.concatenate([out["lidar"], records["trial_lidar_wind_speed"].values]),
            "reference": np.concatenate([out["reference"], records["trial_reference_wind_speed"].values]),
        }
    ok = np.isfinite(out["lidar"]) & np.isfinite(out["reference"])
    return {k: v[ok] for k, v in out.items()}


def _sequence_estimates(
    trials: dict[str, np.ndarray], keys: np.ndarray, bud: xr.Dataset, k: float
) -> np.ndarray:
    """Each sequence's estimate of every bin's relative expanded uncertainty (%): (height, bin, sequence).

    The budget's Monte Carlo combination (``lidarcal.analysis.budget``) with the parts the trials
    give recomputed from each sequence's trials (|mean difference|, its spread, spread/√n) and
    every other contributor (the virtual reference's Table 4 terms, and any a later budget adds)
    taken from the pooled budget: k·√(fixed² + mean_diff² + std_diff² + std_diff²/n) / mean
    reference · 100.
    """
    bounds = bud["wind_speed_bounds"].values
    edges = np.append(bounds[:, 0], bounds[-1, 1])
    names = [str(c) for c in bud["contributor"].values]
    parts = bud["contribution"].transpose("height", "wind_speed", "contributor").values
    fixed = [j for j, n in enumerate(names) if n not in _FROM_TRIALS]
    vref = np.sqrt(np.sum(parts[:, :, fixed] ** 2, axis=-1))  # NaN where a fixed part is
    nh, nb = vref.shape
    group = group_of(keys[trials["period"]], trials["replica"])
    out = np.full((nh, nb, SEQUENCES), np.nan)
    for i in range(nh):
        mine = trials["height"] == i
        for g in range(SEQUENCES):
            sel = mine & (group == g)
            x, y = trials["reference"][sel], trials["lidar"][sel] - trials["reference"][sel]
            n, md, sd, mref = binned_statistics(x, y, edges)
            with np.errstate(invalid="ignore", divide="ignore"):
                u = np.sqrt(vref[i] ** 2 + md**2 + sd**2 + sd**2 / n)
                out[i, :, g] = np.where(n >= 2, k * u * 100.0 / mref, np.nan)
    return out


def _assess(
    records: xr.Dataset, bud: xr.Dataset, targets: np.ndarray, digits: int, k: float
) -> tuple[np.ndarray, np.ndarray]:
    """(tolerance, flag) of every budget bin from its sequences; flag 2 where not a target."""
    heights = np.asarray(records["height"].values, dtype=float)
    keys = np.asarray(records["period_key"].values, dtype=np.int64)
    est = _sequence_estimates(_trials(records, heights), keys, bud, k)
    value = bud["relative_expanded_uncertainty"].transpose("height", "wind_speed").values
    # JCGM 101 7.9 on the sequences' estimates, with the Student factor of h - 1 degrees of freedom
    half, _ = replica_half_width(est)
    ell = tolerance_exponent(half)
    with np.errstate(over="ignore"):
        tol = np.where(targets & (np.isfinite(ell) | (ell == -np.inf)), 0.5 * 10.0**ell, np.nan)
    settled = np.isfinite(tol) & (tol <= settle_target(value, digits) * (1 + 1e-9))
    flag = np.where(targets, np.where(settled, 0, 1), 2).astype(np.int8)
    return tol, flag


def _targets(bud: xr.Dataset, covered: np.ndarray) -> np.ndarray:
    """(height, budget bin) bins to settle: those whose centre the certificate certifies at that height.

    ``covered(height_index, centres) -> bool array`` says which centres are certified.
    """
    centres = np.asarray(bud["wind_speed"].values, dtype=float)
    n = bud["sample_count"].transpose("height", "wind_speed").values
    return np.stack([covered(i, centres) for i in range(bud.sizes["height"])]) & (n > 0)


def _cells(records: xr.Dataset, bud: xr.Dataset, flag: np.ndarray) -> np.ndarray:
    """(time, height) periods whose replica-0 reference speed is in a bin that has not settled."""
    bounds = bud["wind_speed_bounds"].values
    edges = np.append(bounds[:, 0], bounds[-1, 1])
    ref = records["reference_wind_speed"].transpose("time", "height").values
    out = np.zeros(ref.shape, dtype=bool)
    for i in range(ref.shape[1]):
        b = bin_index(ref[:, i], edges)
        out[:, i] = (b >= 0) & (flag[i, np.maximum(b, 0)] == 1)
    return out


#: The budget's wind-speed bin width (m s-1; lidarcal.analysis.budget's default).
_BIN_WIDTH = 0.5


def _terms_span(terms: xr.Dataset | None) -> tuple[float, float]:
    """Speeds (m s-1) a trial's reference may have for its bin to lie inside the terms' wind speeds."""
    if terms is None or "wind_speed" not in terms.coords:
        return -np.inf, np.inf
    ws = np.asarray(terms["wind_speed"].values, dtype=float)
    return float(ws.min()) + _BIN_WIDTH, float(ws.max()) - _BIN_WIDTH


def _within(records: xr.Dataset, span: tuple[float, float]) -> xr.Dataset:
    """Return ``records`` with every cell whose reference speed is outside ``span`` set missing."""
    ref = records["reference_wind_speed"]
    out = (ref < span[0]) | (ref > span[1])
    if not bool(out.any()):
        return records
    records = records.copy()
    for name in ("lidar_wind_speed", "reference_wind_speed"):
        records[name] = records[name].where(~out)
    return records


def _trial_within(trial: dict[str, np.ndarray], span: tuple[float, float]) -> dict[str, np.ndarray]:
    """Return a replica's trials with those whose reference speed is outside ``span`` set missing."""
    ref = np.asarray(trial["reference_wind_speed"], dtype=float)
    out = (ref < span[0]) | (ref > span[1])
    if not out.any():
        return trial
    names = ("lidar_wind_speed", "reference_wind_speed")
    return {**trial, **{k: np.where(out, np.nan, trial[k]) for k in names}}


def _subsample_records(
    conditions: xr.Dataset, model, chosen: np.ndarray, *, base_seed: int, execution: Execution
) -> tuple[xr.Dataset, xr.Dataset]:
    """Simulate the ``chosen`` (time, height) cells only; return (their periods' conditions, records).

    The records hold replica 0 of the periods with any chosen cell, NaN at the cells not chosen:
    the same numbers a full campaign gives at those cells (the seed is the period's, docs/seeds.md).
    """
    rows = np.flatnonzero(chosen.any(axis=1))
    sub = conditions.isel(time=rows).compute()  # a bounded number of periods, however long the campaign
    heights = np.asarray(sub["height"].values, dtype=float)
    done = simulate_replicas(sub, model, chosen[rows], [0], heights=heights.tolist(),
                             base_seed=int(base_seed), execution=execution)[0]
    col = np.abs(np.asarray(done["height"], dtype=float)[:, None] - heights[None, :]).argmin(axis=1)
    dims = ("time", "height")
    rec = xr.Dataset(coords={"time": time_coord(sub["time"].values), "height": height_coord(heights)})
    for name in ("lidar_wind_speed", "reference_wind_speed"):
        grid = np.full((rows.size, heights.size), np.nan)
        grid[done["period"], col] = done[name]
        rec[name] = (dims, grid, output_attrs("simulated_rtd", name))
    rec["period_key"] = ("time", period_keys(sub["time"].values), output_attrs("simulated_rtd", "period_key"))
    rec.attrs["lidarcal_base_seed"] = int(base_seed)
    return sub, rec


def _height_column(conditions: xr.Dataset, i: int) -> xr.Dataset:
    """Return the campaign's conditions at its ``i``-th height, in memory, read block after block.

    A lazily read campaign (dask arrays, one chunk per block of periods) is read in its blocks'
    order, each block once; one in memory is taken as it is.
    """
    chunks = conditions["wind_speed"].chunks
    if chunks is None:
        return conditions.isel(height=i)
    edges = np.cumsum((0, *chunks[conditions["wind_speed"].dims.index("time")]))
    parts = [conditions.isel(height=i, time=slice(int(a), int(b))).compute()
             for a, b in zip(edges[:-1], edges[1:], strict=True)]
    return xr.concat(parts, dim="time", data_vars="all", coords="minimal", compat="override")


def monte_carlo_route(
    conditions: xr.Dataset,
    model,
    *,
    terms: xr.Dataset,
    covered,
    lookup_edges: np.ndarray,
    rule: CertificationRule | Mapping[str, Any] | None = None,
    max_replicas: int = 30,
    base_seed: int,
    periods_per_bin: int | None = subsample.DEFAULT_PERIODS_PER_BIN,
    execution: Execution | Mapping[str, Any] | None = None,
    carried: xr.Dataset | None = None,
) -> MonteCarloRoute:
    """Simulate the campaign with the calibrated lidar; per bin its budget, per period its expected deviation.

    Parameters
    ----------
    conditions : xarray.Dataset
        The campaign's conditions at its certified heights (a ``conditions`` input; the wind
        speed is the lidar's own 10-minute speed).
    model : lidarcal.lidar.LidarModel
        The certificate's lidar.
    terms : xarray.Dataset
        The certificate's Table 4 terms (virtual reference uncertainty).
    covered : callable
        ``covered(height_index, bin_centres) -> bool array``: centres the certificate certifies.
    lookup_edges : array
        Wind-speed bin edges (m s-1) the periods are looked up in (their own speed).
    rule : CertificationRule or mapping, optional
        The certificate's certification rule (:class:`~lidarcal.analysis.rule.CertificationRule`):
        its certified range, coverage factor and interval, and the significant digits the bins
        settle to.  Its ``min_periods`` is not used: the campaign's budget states every bin of two
        periods or more (the certificate says which it certifies, ``covered``).  None: the rule's
        defaults.
    max_replicas : int
        Most replicas, replica 0 included.
    base_seed : int
        Base seed (docs/seeds.md).
    periods_per_bin : int or None
        Most periods simulated per height and ``lookup_edges`` bin, a stratified subsample
        (:mod:`lidarcal.smc.subsample`); None: every period.
    execution : Execution or mapping, optional
        Where and how the simulations run (:class:`~lidarcal.campaign.settings.Execution`).
    carried : xarray.Dataset, optional
        The certificate's relative contributions (%) of the contributors the trials cannot give,
        on (height, wind_speed, contributor) at the simulated heights (:func:`with_carried`).
    """
    execution = Execution.of(execution)
    rule = CertificationRule.of(rule).replace(min_periods=2)
    digits, k = rule.significant_digits, rule.coverage_factor
    heights = np.asarray(conditions["height"].values, dtype=float)
    cond = conditions.transpose("time", "height", ...)
    keys = period_keys(cond["time"].values)
    lookup_edges = np.asarray(lookup_edges, dtype=float)
    nt, nh, nb = cond.sizes["time"], heights.size, len(lookup_edges) - 1
    # the budget never extrapolates the certificate's Table 4 terms: a period beyond their speeds
    # (less one bin for the reference's own drift) cannot be budgeted, so it is not simulated
    span = _terms_span(terms)
    chosen, inside = np.zeros((nt, nh), dtype=bool), np.zeros((nt, nh), dtype=bool)
    population, got = np.zeros((nh, nb), dtype=np.int64), np.zeros((nh, nb), dtype=np.int64)
    for i in range(nh):  # one height's conditions at a time (a long campaign's are read lazily)
        col = _height_column(cond, i)
        speed = col["wind_speed"].values
        within = (speed >= span[0]) & (speed <= span[1])
        strata = ("turbulence_intensity", "wind_shear_exponent", "cnr")
        chosen[:, i] = within & subsample.select_height(
            speed,
            np.stack([col[n].values for n in strata], axis=-1),
            col["wind_from_direction"].values,
            keys,
            heights[i],
            lookup_edges,
            None if periods_per_bin is None else int(periods_per_bin),
            int(base_seed),
        )
        inside[:, i] = np.isfinite(speed) & (speed >= lookup_edges[0]) & (speed < lookup_edges[-1]) & within
        # each simulated cell stands for N / n campaign periods of its own-speed bin (N periods, n simulated)
        lookup = bin_index(speed, lookup_edges)
        population[i] = np.bincount(lookup[lookup >= 0], minlength=nb)
        got[i] = np.bincount(lookup[(lookup >= 0) & chosen[:, i]], minlength=nb)
    if (chosen == inside).all():  # every period: the campaign as a whole
        sim_cond = conditions.compute()
        records = simulate_campaign(
            sim_cond,
            model,
            base_seed=int(base_seed),
            execution=execution,
            call="lidarcal smc (Monte Carlo route)",
        ).transpose("time", "height", ...)
        rows = np.arange(nt)
    else:
        log.info(
            "Monte Carlo route: simulating %d of %d (period, height) cells, at most %d periods per height "
            "and wind-speed bin (stratified subsample, lidarcal.smc.subsample)",
            int(chosen.sum()), int(inside.sum()), int(periods_per_bin),
        )
        sim_cond, records = _subsample_records(cond, model, chosen, base_seed=base_seed, execution=execution)
        rows = np.flatnonzero(chosen.any(axis=1))
    records = _within(records, span)
    trials: list[dict[str, np.ndarray]] = []
    current = records
    bud = with_carried(budget(current, terms=terms, rule=rule), carried)
    targets = _targets(bud, covered)
    tol, flag = _assess(current, bud, targets, digits, k)
    replicas = 1
    for batch in _batches(int(max_replicas)):
        cells = _cells(records, bud, flag)
        if not cells.any():
            break
        log.info(
            "Monte Carlo replicas %s: %d bin(s) not settled to %d digits; re-simulating %d (period, "
            "height) cells",
            f"{batch[0]}-{batch[-1]}" if len(batch) > 1 else batch[0],
            int((flag == 1).sum()),
            digits,
            int(cells.sum()),
        )
        done = simulate_replicas(
            sim_cond,
            model,
            cells,
            batch,
            heights=records["height"].values.tolist(),
            base_seed=int(base_seed),
            execution=execution,
        )
        trials += [{"replica": r, **_trial_within(done[r], span)} for r in batch]
        replicas = batch[-1] + 1
        current = with_trials(records, trials)
        bud = with_carried(budget(current, terms=terms, rule=rule), carried)
        targets = _targets(bud, covered)
        tol, flag = _assess(current, bud, targets, digits, k)
    fit, slopes, count = _expected(current, sim_cond, lookup_edges)
    sim_speed = sim_cond.transpose("time", "height", ...)["wind_speed"].values  # the simulated periods'
    weight = np.zeros((rows.size, nh))
    for i in range(nh):
        at = bin_index(sim_speed[:, i], lookup_edges)
        with np.errstate(invalid="ignore", divide="ignore"):
            weight[:, i] = np.where(at >= 0, (population[i] / np.maximum(got[i], 1))[np.maximum(at, 0)], 0.0)
    m, se_mean, se_sd, population = _subsample_errors(current, bud, weight)
    return MonteCarloRoute(
        records=current,
        budget=bud,
        tolerance=tol,
        settled=flag,
        fit=fit,
        slopes=slopes,
        rows=rows,
        count=count,
        replicas=replicas,
        periods_per_bin=None if periods_per_bin is None else int(periods_per_bin),
        periods_simulated=m,
        population=population,
        mean_difference_se=se_mean,
        std_difference_se=se_sd,
    )


def _subsample_errors(
    records: xr.Dataset, bud: xr.Dataset, weight: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(periods simulated, SE of the mean deviation, SE of the spread, campaign periods) per budget bin.

    :func:`lidarcal.smc.subsample.standard_errors` over each bin's trials (binned by the reference
    speed, as the budget bins them).  The bin's campaign periods N are estimated from its simulated
    ones: each weighs ``weight`` (records' (time, height): N / n of its own-speed bin), so N is
    exact where every period was simulated.
    """
    heights = np.asarray(records["height"].values, dtype=float)
    tr = _trials(records, heights)
    bounds = bud["wind_speed_bounds"].values
    edges = np.append(bounds[:, 0], bounds[-1, 1])
    nh, nb = heights.size, len(edges) - 1
    out = [np.zeros((nh, nb), dtype=np.int64), np.full((nh, nb), np.nan), np.full((nh, nb), np.nan),
           np.zeros((nh, nb), dtype=np.int64)]
    for i in range(nh):
        mine = tr["height"] == i
        first = mine & (tr["replica"] == 0)  # one weight per period
        bf = bin_index(tr["reference"][first], edges)
        pop = np.rint(np.bincount(bf[bf >= 0], weights=weight[tr["period"][first][bf >= 0], i], minlength=nb))
        m, se_mean, se_sd = subsample.standard_errors(
            tr["lidar"][mine] - tr["reference"][mine],
            tr["period"][mine],
            bin_index(tr["reference"][mine], edges),
            nb,
            pop,
        )
        for k, v in enumerate((m, se_mean, se_sd, pop)):
            out[k][i] = v
    return tuple(out)


def _expected(
    records: xr.Dataset, fit_conditions: xr.Dataset, edges: np.ndarray
) -> tuple[ExpectedFit, np.ndarray, np.ndarray]:
    """Return the fit of the expected deviation, the slopes (height, regressor) and the trials per period.

    The fit (:func:`lidarcal.smc.expected.fit_expected`) is on the trials, their conditions from
    ``fit_conditions`` (the records' periods).  Trials are counted on the records' periods
    (record period, height).
    """
    heights = np.asarray(records["height"].values, dtype=float)
    tr = _trials(records, heights)
    fit = fit_conditions.sel(height=records["height"].values).transpose("time", "height", ...)
    x_fit = np.stack([fit[n].values for n in REGRESSORS], axis=-1)  # (record time, height, regressor)
    count = np.zeros((records.sizes["time"], heights.size), dtype=np.int64)
    np.add.at(count, (tr["period"], tr["height"]), 1)
    fitted, slopes = fit_expected(tr, x_fit, heights, edges)
    return fitted, slopes, count
