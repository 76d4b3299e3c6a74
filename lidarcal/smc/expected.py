"""The Monte Carlo route's expected deviation of a period given its conditions, and its standard error.

:func:`fit_expected` fits, per simulated height, the trials' deviations (lidar − reference) to
the bin's mean deviation plus pooled within-bin least-squares slopes on the :data:`REGRESSORS`
(:func:`lidarcal.smc.kernels.within_bin_fit`), the trials grouped by their reference speed's
bin; :meth:`ExpectedFit.at` evaluates that fit, and its standard error, at any block of the
campaign's periods, each looked up by its own speed's bin (:mod:`lidarcal.smc.periods`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from lidarcal.smc.kernels import bin_index, expected_deviation, expected_deviation_se, within_bin_fit

__all__ = ["REGRESSORS", "ExpectedFit", "fit_expected"]

#: Conditions the expected deviation of a period is regressed on inside its wind-speed bin.
REGRESSORS = ("turbulence_intensity", "wind_shear_exponent", "cnr", "cnr_gradient")


@dataclass(frozen=True)
class ExpectedFit:
    """The trials' within-bin fit per simulated height, evaluated at any periods (:meth:`at`).

    Per height: the trials' deviations, conditions and reference-speed bins, and what
    :func:`~lidarcal.smc.kernels.within_bin_fit` made of them.  A period is looked up by its own
    speed's bin (``edges``).
    """

    heights: np.ndarray  #: (height,) m
    edges: np.ndarray  #: lookup bin edges, m s-1
    deviation: tuple[np.ndarray, ...]  #: per height, each trial's lidar − reference (m s-1)
    conditions: tuple[np.ndarray, ...]  #: per height, (trial, regressor) the trial's period's conditions
    bins: tuple[np.ndarray, ...]  #: per height, each trial's reference-speed bin
    fitted: tuple[tuple[np.ndarray, ...], ...]  #: per height, (count, mean_d, mean_x, beta)

    def at(self, conditions: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
        """Return the expected deviation and its standard error (time, height, m s-1) at these periods."""
        cond = conditions.sel(height=self.heights).transpose("time", "height", ...)
        x_all = np.stack([cond[n].values for n in REGRESSORS], axis=-1)  # (time, height, regressor)
        speed = cond["wind_speed"].values
        expected = np.full(speed.shape, np.nan)
        se = np.full(speed.shape, np.nan)
        for i in range(self.heights.size):
            n, mean_d, mean_x, beta = self.fitted[i]
            at = bin_index(speed[:, i], self.edges)
            expected[:, i] = expected_deviation(x_all[:, i], at, mean_d, mean_x, beta, n >= 2)
            se_i = expected_deviation_se(self.deviation[i], self.conditions[i], self.bins[i], x_all[:, i], at)
            se[:, i] = np.where(np.isfinite(expected[:, i]), se_i, np.nan)
        return expected, se


def fit_expected(
    trials: dict[str, np.ndarray], conditions: np.ndarray, heights: np.ndarray, edges: np.ndarray
) -> tuple[ExpectedFit, np.ndarray]:
    """Return the fit of the expected deviation and its slopes (height, regressor, m s-1 per unit).

    ``trials``: flat arrays ``period``, ``height`` (index), ``lidar`` and ``reference`` (m s-1) of
    every trial; ``conditions`` (period, height, regressor): the :data:`REGRESSORS` of the trials'
    periods; ``edges``: the wind-speed bins (m s-1) the trials are grouped in by reference speed.
    """
    heights = np.asarray(heights, dtype=float)
    nh, nb = heights.size, len(edges) - 1
    slopes = np.full((nh, len(REGRESSORS)), np.nan)
    parts: dict[str, list] = {"deviation": [], "conditions": [], "bins": [], "fitted": []}
    for i in range(nh):
        mine = trials["height"] == i
        d = trials["lidar"][mine] - trials["reference"][mine]
        b = bin_index(trials["reference"][mine], edges)
        xt = conditions[trials["period"][mine], i]
        n, mean_d, mean_x, beta = within_bin_fit(d, xt, b, nb)
        slopes[i] = beta
        for key, value in zip(parts, (d, xt, b, (n, mean_d, mean_x, beta)), strict=True):
            parts[key].append(value)
    fitted = ExpectedFit(heights=heights, edges=np.asarray(edges, dtype=float),
                         **{k: tuple(v) for k, v in parts.items()})
    return fitted, slopes
