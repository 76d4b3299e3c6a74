"""A campaign block by block: each period's values, and the per-bin sums the artefact's tables need.

Every value ``lidarcal smc`` gives a 10-minute period depends on that period's own conditions
and on what the certificate and the Monte Carlo route hold per height and bin, never on another
period.  :func:`period_block` computes them for any run of consecutive periods; :class:`BinSums`
adds up, block after block, what the per-bin tables are made of (counts, sums, sums of squares).
So :func:`lidarcal.smc.dataset.smc_dataset` holds one block of the campaign's per-period values
at a time, and writes them to ``smc.nc`` block by block (a dask array per variable, one chunk per
block), and a conditions file is read block by block too (``load_conditions(block=...)``): the
memory the command needs does not grow with the campaign's length (``docs/smc.md``, "Long
campaigns: speed and memory").

A block is :data:`lidarcal.smc.core.BLOCK_PERIODS` periods (30 days).  Per-period values do not
depend on it; the per-bin tables' sums are added block after block, so a table value may differ
in its last bit between two block sizes (never between two runs, schedulers or machines: the
size is fixed).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from lidarcal.binning import bin_index
from lidarcal.smc.core import BLOCK_PERIODS, Campaign
from lidarcal.smc.kernels import binned_mean_finish, binned_mean_sums, quadrature
from lidarcal.smc.routes import COVERAGE, budget_edges, calibration_part, outside_envelope

__all__ = ["CONTRIBUTORS", "Block", "BinSums", "blocks", "contributor_names", "period_block"]

#: The contributors lidarcal computes, in order; the user's terms follow.
CONTRIBUTORS = ("calibration", "environmental_iec", "environmental_monte_carlo")
#: Per-period uncertainties whose root mean square over a bin's covered periods the tables give.
RMS_OF = {
    "bin_uncertainty": "uncertainty",
    "bin_relative_uncertainty": "relative_uncertainty",
    "bin_uncertainty_iec_route": "uncertainty_iec_route",
    "bin_uncertainty_monte_carlo_route": "uncertainty_monte_carlo_route",
}


def blocks(n_periods: int, size: int = BLOCK_PERIODS) -> Iterator[slice]:
    """Yield the campaign's blocks of consecutive periods, in time order."""
    size = max(1, int(size))
    for start in range(0, int(n_periods), size):
        yield slice(start, min(start + size, int(n_periods)))


def contributor_names(c: Campaign) -> list[str]:
    """Return the campaign's contributors: :data:`CONTRIBUTORS`, then the user's terms."""
    return [*CONTRIBUTORS, *(t.name for t in c.user_terms)]


@dataclass(frozen=True)
class Block:
    """Every per-period value of one block of periods (time, height)."""

    start: int  #: the block's first period (time index in the campaign)
    speed: np.ndarray  #: (time, height) the lidar's wind speed, m s-1
    values: dict[str, np.ndarray]  #: the artefact's per-period variables, in their order
    contribution: np.ndarray  #: (contributor, time, height) each contributor, m s-1
    split: dict[str, tuple[np.ndarray, np.ndarray]]  #: contributor -> (correlated, independent) parts, m s-1

    def arrays(self) -> dict[str, np.ndarray]:
        """Return the per-period variables and ``contribution``, by their names in the artefact."""
        return {**self.values, "contribution": self.contribution}


def period_block(c: Campaign, periods: slice) -> Block:
    """Compute every per-period value of the campaign's ``periods`` (a slice of its time axis).

    The contributors (``docs/smc.md``): the certificate's certified value (``calibration``), the
    50-2 route, the Monte Carlo route (the bin's expected shift from the calibration's mean
    deviation and the campaign's spread beyond the calibration's) and the user's terms; their
    combinations per route; the coverage and envelope flags; and each contributor's split into a
    part fully correlated across periods and a part independent between them.
    """
    # the block's conditions in one computation (a lazily read campaign's: one read of the block)
    cond = c.conditions.isel(time=periods).transpose("time", "height", ...).compute()
    start = int(periods.start or 0)
    speed = cond["wind_speed"].values
    nt, nh = speed.shape
    calibration, coverage, _ = calibration_part(c.cert, speed, c.height_index)
    iec_contribution, iec_deviation = c.iec.apply(cond)
    mc_env, mc_dev, mc_expected, mc_expected_se, mc_excess = (np.full((nt, nh), np.nan) for _ in range(5))
    trials = np.zeros((nt, nh), dtype=np.int32)
    cols = np.flatnonzero(c.height_index >= 0)
    if c.monte_carlo is not None:
        mc = c.monte_carlo
        expected, expected_se, count = mc.at(cond.isel(height=cols), start=start)
        edges = budget_edges(c.cert.budget)
        cert_md = c.cert.budget["mean_difference"].transpose("height", "wind_speed").values
        cert_sd = c.cert.budget["std_difference"].transpose("height", "wind_speed").values
        sim = mc.budget.transpose("height", "wind_speed", ...)
        sim_edges = budget_edges(sim)
        for k, j in enumerate(cols):
            i = c.height_index[j]
            b = bin_index(speed[:, j], edges)
            ok = b >= 0
            shift = expected[:, k] - np.where(ok, cert_md[i, np.maximum(b, 0)], np.nan)
            # the campaign's spread beyond the calibration's in the bin (the lidar's random deviation)
            sb = bin_index(speed[:, j], sim_edges)
            s_sim = np.where(sb >= 0, sim["std_difference"].values[k, np.maximum(sb, 0)], np.nan)
            s_cal = np.where(ok, cert_sd[i, np.maximum(b, 0)], np.nan)
            excess = np.sqrt(np.maximum(s_sim**2 - s_cal**2, 0.0))
            mc_dev[:, j], mc_expected[:, j] = shift, expected[:, k]
            mc_expected_se[:, j], mc_excess[:, j] = expected_se[:, k], excess
            mc_env[:, j] = quadrature(shift, excess)
            trials[:, j] = count[:, k]
    user = [t.at(speed) for t in c.user_terms]
    contribution = np.stack([calibration, iec_contribution, mc_env, *user])
    cal_user = quadrature(calibration, *user)
    u_iec = quadrature(cal_user, iec_contribution)
    u_mc = quadrature(cal_user, mc_env)
    quoted = u_mc if c.monte_carlo is not None else u_iec
    coverage[(coverage == 0) & ~np.isfinite(quoted)] = COVERAGE.index("environmental_term_missing")
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = 100.0 * quoted / speed
    outside = outside_envelope(*c.envelope, cond)
    values = {
        "uncertainty": quoted,
        "relative_uncertainty": rel,
        "uncertainty_iec_route": u_iec,
        "uncertainty_monte_carlo_route": u_mc,
        "environmental_deviation_iec": iec_deviation,
        "environmental_deviation_monte_carlo": mc_dev,
        "monte_carlo_expected_deviation": mc_expected,
        "monte_carlo_expected_deviation_standard_error": mc_expected_se,
        "monte_carlo_trials": trials,
        "monte_carlo_simulated": (trials > 0).astype(np.int8),
        "coverage_flag": coverage,
        "outside_envelope": outside,
    }
    # each contributor's part fully correlated across periods and its part independent between them
    # (the uncertainty of a bin's mean, docs/smc.md): calibration = its certified terms (correlated)
    # and the calibration's single-period spread std_difference (independent); the Monte Carlo
    # route = its expected shift (correlated) and its excess spread (independent); the 50-2 route
    # and the user terms wholly correlated
    cal_random = _calibration_random(c, speed, calibration)
    zero = np.zeros((nt, nh))
    split = {
        "calibration": (np.sqrt(np.maximum(calibration**2 - cal_random**2, 0.0)), cal_random),
        "environmental_iec": (iec_contribution, zero),
        "environmental_monte_carlo": (np.abs(mc_dev), mc_excess),
        **{t.name: (u, zero) for t, u in zip(c.user_terms, user, strict=True)},
    }
    return Block(start=start, speed=speed, values=values, contribution=contribution, split=split)


def _calibration_random(c: Campaign, speed: np.ndarray, calibration: np.ndarray) -> np.ndarray:
    """(time, height) the calibration contributor's independent part: the certified bin's std_difference.

    Its relative contribution (%) times the period's speed; 0 where the certificate's budget has no
    such contributor (then the whole contributor counts as correlated), NaN where not certified.
    """
    bud = c.cert.budget.transpose("height", "wind_speed", "contributor", ...)
    out = np.where(np.isfinite(calibration), 0.0, np.nan)
    if "std_difference" not in [str(n) for n in bud["contributor"].values]:
        return out
    rel = bud["relative_contribution"].sel(contributor="std_difference").values  # (height, bin), %
    edges = budget_edges(bud)
    for j, i in enumerate(c.height_index):
        if i >= 0:
            b = bin_index(speed[:, j], edges)
            part = np.where(b >= 0, rel[i, np.maximum(b, 0)] * speed[:, j] / 100.0, np.nan)
            out[:, j] = np.where(np.isfinite(calibration[:, j]), part, np.nan)
    return out


class BinSums:
    """The campaign's per-bin sums on the table's bins (``edges``), added block after block.

    :meth:`add` takes a :class:`Block`; :meth:`tables` turns the sums into the artefact's per-bin
    variables that come from the periods (counts, mean speed, root mean squares of the
    uncertainties and contributors over the covered periods, and the uncertainty of each bin's
    mean speed, ``docs/smc.md``).
    """

    def __init__(self, edges: np.ndarray, names: list[str], n_heights: int, quoted_route: str) -> None:
        nb, nc, nh = len(edges) - 1, len(names), n_heights
        self.edges, self.names = np.asarray(edges, dtype=float), list(names)
        self.quoted = [k for k, n in enumerate(names)
                       if not n.startswith("environmental_") or n == quoted_route]
        self.period_count = np.zeros((nb, nh), dtype=np.int64)
        self.covered_count = np.zeros((nb, nh), dtype=np.int64)
        self.speed_sum = np.zeros((nb, nh))
        self.covered_speed_sum = np.zeros((nb, nh))
        self.rms_n = {k: np.zeros((nb, nh), dtype=np.int64) for k in RMS_OF}
        self.rms_s2 = {k: np.zeros((nb, nh)) for k in RMS_OF}
        self.contribution_n = np.zeros((nb, nc, nh), dtype=np.int64)
        self.contribution_s2 = np.zeros((nb, nc, nh))
        self.mean_n = np.zeros((nb, nc, nh), dtype=np.int64)
        self.mean_s1 = np.zeros((nb, nc, nh))
        self.mean_s2 = np.zeros((nb, nc, nh))
        self.covered_periods = 0  #: period-heights covered by the certificate
        self.periods_with_wind_speed = 0  #: period-heights with a wind speed

    def add(self, block: Block) -> None:
        """Add one block's periods."""
        nb = len(self.edges) - 1
        covered = block.values["coverage_flag"] == 0
        self.covered_periods += int(covered.sum())
        self.periods_with_wind_speed += int(np.isfinite(block.speed).sum())
        for j in range(block.speed.shape[1]):
            s = block.speed[:, j]
            b = bin_index(s, self.edges)
            self.period_count[:, j] += np.bincount(b[b >= 0], minlength=nb)
            self.speed_sum[:, j] += np.bincount(b[b >= 0], weights=s[b >= 0], minlength=nb)
            bc = np.where(covered[:, j], b, -1)
            self.covered_count[:, j] += np.bincount(bc[bc >= 0], minlength=nb)
            self.covered_speed_sum[:, j] += np.bincount(bc[bc >= 0], weights=s[bc >= 0], minlength=nb)
            for name, src in RMS_OF.items():
                n, s2 = _squares(block.values[src][:, j], bc, nb)
                self.rms_n[name][:, j] += n
                self.rms_s2[name][:, j] += s2
            for k, name in enumerate(self.names):
                n, s2 = _squares(block.contribution[k, :, j], bc, nb)
                self.contribution_n[:, k, j] += n
                self.contribution_s2[:, k, j] += s2
                corr, rand = block.split[name]
                n, s1, s2 = binned_mean_sums(corr[None, :, j], rand[None, :, j], bc, nb)
                self.mean_n[:, k, j] += n
                self.mean_s1[:, k, j] += s1[0]
                self.mean_s2[:, k, j] += s2[0]

    def tables(self) -> dict[str, np.ndarray]:
        """Return the per-bin variables the periods give: (bin, height), or (bin, contributor, height)."""
        n = self.period_count
        with np.errstate(invalid="ignore", divide="ignore"):
            out = {"bin_mean_wind_speed": np.where(n > 0, self.speed_sum / np.maximum(n, 1), np.nan)}
            out.update({k: _root_mean(self.rms_n[k], self.rms_s2[k]) for k in RMS_OF})
            out["bin_period_count"] = n.astype(np.int32)
            out["bin_covered_count"] = self.covered_count.astype(np.int32)
            out["bin_contribution"] = _root_mean(self.contribution_n, self.contribution_s2)
            mean = binned_mean_finish(self.mean_n, self.mean_s1, self.mean_s2)  # (bin, contributor, height)
            n_cov = self.covered_count
            u = np.sqrt(np.sum(mean[:, self.quoted, :] ** 2, axis=1))
            mean_speed = self.covered_speed_sum / n_cov
            out["bin_mean_contribution"] = mean
            out["bin_mean_uncertainty"] = np.where(n_cov > 0, u, np.nan)
            out["bin_mean_relative_uncertainty"] = np.where(n_cov > 0, 100.0 * u / mean_speed, np.nan)
        return out


def _squares(values: np.ndarray, bins: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """Per bin: how many of ``values`` are finite, and the sum of their squares (bins -1: left out)."""
    ok = (bins >= 0) & np.isfinite(values)
    return np.bincount(bins[ok], minlength=nb), np.bincount(bins[ok], weights=values[ok] ** 2, minlength=nb)


def _root_mean(n: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """Root mean square from its count and sum of squares; NaN where the count is 0."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.sqrt(s2 / np.maximum(n, 1)), np.nan)
