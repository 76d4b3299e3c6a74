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
  (:func:`lidarcal.smc.kernels.within_bin_fit`), so one period's turbulence draw does not pass
  for an environmental effect.

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
from lidarcal.campaign.run import simulate_replicas
from lidarcal.campaign.settings import Execution
from lidarcal.smc.kernels import SEQUENCES, bin_index, expected_deviation, group_of, within_bin_fit

__all__ = ["MonteCarloRoute", "monte_carlo_route", "with_carried", "REGRESSORS"]

log = logging.getLogger(__name__)

#: Monte Carlo budget contributors computed from the trials (recomputed per JCGM 101 sequence).
_FROM_TRIALS = ("mean_difference", "std_difference", "statistical")
#: Conditions the expected deviation of a period is regressed on inside its wind-speed bin.
REGRESSORS = ("turbulence_intensity", "wind_shear_exponent", "cnr", "cnr_gradient")


@dataclass(frozen=True)
class MonteCarloRoute:
    """What the Monte Carlo route computed (see the module docstring)."""

    records: xr.Dataset  #: simulated records, replica 0 on (time, height) and further trials
    budget: xr.Dataset  #: the campaign's Monte Carlo budget per (height, reference wind-speed bin)
    tolerance: np.ndarray  #: (height, budget bin) numerical tolerance of its relative expanded U (%)
    settled: np.ndarray  #: (height, budget bin) 0 settled, 1 not settled, 2 not assessed
    expected: np.ndarray  #: (time, height) expected lidar − reference deviation (m s-1) given conditions
    slopes: np.ndarray  #: (height, regressor) within-bin slopes of the deviation (m s-1 per unit)
    trials: np.ndarray  #: (time, height) trials simulated of each period (0: not simulated)
    replicas: int  #: replicas run, replica 0 included


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
    k = float(b.attrs.get("coverage_factor", 2.0))
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


def monte_carlo_route(
    conditions: xr.Dataset,
    model,
    *,
    terms: xr.Dataset,
    covered,
    lookup_edges: np.ndarray,
    coverage_factor: float = 2.0,
    certified_range: tuple[float, float] = (4.0, 16.0),
    significant_digits: int = 2,
    max_replicas: int = 30,
    base_seed: int,
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
    coverage_factor, certified_range, significant_digits
        The certificate's (the budget's) settings.
    max_replicas : int
        Most replicas, replica 0 included.
    base_seed : int
        Base seed (docs/seeds.md).
    execution : Execution or mapping, optional
        Where and how the simulations run (:class:`~lidarcal.campaign.settings.Execution`).
    carried : xarray.Dataset, optional
        The certificate's relative contributions (%) of the contributors the trials cannot give,
        on (height, wind_speed, contributor) at the simulated heights (:func:`with_carried`).
    """
    execution = Execution.of(execution)
    records = simulate_campaign(
        conditions,
        model,
        base_seed=int(base_seed),
        execution=execution,
        call="lidarcal smc (Monte Carlo route)",
    )
    records = records.transpose("time", "height", ...)
    rule = dict(terms=terms, rule=CertificationRule(min_periods=2, certified_range=tuple(certified_range),
                                                    significant_digits=int(significant_digits),
                                                    coverage_factor=float(coverage_factor)))
    trials: list[dict[str, np.ndarray]] = []
    current = records
    bud = with_carried(budget(current, **rule), carried)
    targets = _targets(bud, covered)
    tol, flag = _assess(current, bud, targets, int(significant_digits), float(coverage_factor))
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
            int(significant_digits),
            int(cells.sum()),
        )
        done = simulate_replicas(
            conditions,
            model,
            cells,
            batch,
            heights=records["height"].values.tolist(),
            base_seed=int(base_seed),
            execution=execution,
        )
        trials += [{"replica": r, **done[r]} for r in batch]
        replicas = batch[-1] + 1
        current = with_trials(records, trials)
        bud = with_carried(budget(current, **rule), carried)
        targets = _targets(bud, covered)
        tol, flag = _assess(current, bud, targets, int(significant_digits), float(coverage_factor))
    expected, slopes, count = _expected(current, conditions, lookup_edges)
    return MonteCarloRoute(
        records=current,
        budget=bud,
        tolerance=tol,
        settled=flag,
        expected=expected,
        slopes=slopes,
        trials=count,
        replicas=replicas,
    )


def _expected(
    records: xr.Dataset, conditions: xr.Dataset, edges: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the expected deviation (time, height, m s-1), slopes (height, regressor), trials (time, height).

    Trials are grouped by their reference speed's bin, periods looked up by their own speed's bin.
    """
    heights = np.asarray(records["height"].values, dtype=float)
    tr = _trials(records, heights)
    cond = conditions.sel(height=records["height"].values).transpose("time", "height", ...)
    x_all = np.stack([cond[n].values for n in REGRESSORS], axis=-1)  # (time, height, regressor)
    speed = cond["wind_speed"].values
    nt, nh = speed.shape
    nb = len(edges) - 1
    expected = np.full((nt, nh), np.nan)
    slopes = np.full((nh, len(REGRESSORS)), np.nan)
    count = np.zeros((nt, nh), dtype=np.int64)
    np.add.at(count, (tr["period"], tr["height"]), 1)
    for i in range(nh):
        mine = tr["height"] == i
        d = tr["lidar"][mine] - tr["reference"][mine]
        b = bin_index(tr["reference"][mine], edges)
        n, mean_d, mean_x, beta = within_bin_fit(d, x_all[tr["period"][mine], i], b, nb)
        slopes[i] = beta
        expected[:, i] = expected_deviation(
            x_all[:, i], bin_index(speed[:, i], edges), mean_d, mean_x, beta, n >= 2
        )
    return expected, slopes, count
