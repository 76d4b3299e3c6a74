r"""The budget's ``model_form`` contributor: the spread of the certified value across the model alternatives.

The records' model-form runs (:mod:`lidarcal.campaign.model_form`) simulate every defensible
alternative model (:data:`lidarcal.lidar.model_form.ALTERNATIVES`) on a subsample of each
(height, wind-speed bin) with the nominal run's seeds.  Per bin and alternative *a*, paired over
the subsample's periods (errors e = lidar − reference of the nominal run and of *a*):

* δμ_a = mean(e_a − e) — the shift of the mean difference;
* δσ_a = std(e_a) − std(e) — the shift of the standard deviation of the difference.

With the bin's own contributors (the μ and σ pooled over every trial, N its distinct 10-minute
periods as in the ``statistical`` term, and the virtual reference
v of Table 4) the combined standard uncertainty is u = √(v² + μ² + σ²(1 + 1/N)); under
alternative *a* it is u_a, the same with μ + δμ_a and σ + δσ_a, and δu_a = u_a − u (k·δu_a is
the shift of the certified value, ``model_form_shift`` in %).  Each alternative is one end of a
defensible range whose other end is the nominal model, so the true u lies anywhere between u and
u_a: a rectangular distribution, whose root-mean-square distance from u is |δu_a|/√3.  The
aspects are independent, so

    u_mf = √(Σ_a δu_a² / 3),

the model-form standard uncertainty of the combined standard uncertainty itself.  The budget
certifies the upper one-standard-uncertainty value u + u_mf: the contributor is
``model_form`` = √((u + u_mf)² − u²), so that the combined standard uncertainty with it is
exactly u + u_mf.  (Adding u_mf itself in quadrature would move u only at second order, by
u_mf²/2u: a 9 % shift of the certified value would show as 0.3 %.)

**Numerical accuracy.** δμ_a and δσ_a come from the subsample; their standard errors follow by
the delta method from each period's influence (ψ_μ = d − δμ_a; ψ_σ = ((e_a − ē_a)² − s_a²)/2s_a
− ((e − ē)² − s²)/2s), carried through u_a and u_mf to ``model_form`` over the periods of the
bin (``model_form_standard_error``).  A bin whose subsample holds fewer than
:data:`MIN_SAMPLES` periods takes the relative u_mf / Ū of the nearest bin at that height that
has one (``model_form_sample_count`` 0).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.binning import bin_index
from lidarcal.errors import InputError
from lidarcal.units import convert_values

__all__ = ["MIN_SAMPLES", "RECIPE", "model_form_term"]

#: Fewest subsample periods a bin's own model-form term needs (a standard deviation and its error).
MIN_SAMPLES = 3
#: One line for the provenance and the certificate: how the contributor is made.
RECIPE = ("model_form = sqrt((u + u_mf)^2 - u^2), u_mf = sqrt(sum_a du_a^2 / 3), du_a = the change of the "
          "combined standard uncertainty u when the bin's mean and standard deviation of lidar - reference "
          "move by their common-random-numbers shifts under alternative a (rectangular between the nominal "
          "model and a)")


def _values(records: xr.Dataset, name: str, unit: str, source: str) -> np.ndarray:
    var = records[name]
    return convert_values(np.asarray(var.values, dtype=float), var.attrs.get("units"), unit,
                          where=f"{source}: variable {name!r}")


def _nominal(records: xr.Dataset, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each model-form sample's height index, nominal lidar and reference speed (replica 0), and its keys."""
    heights = np.asarray(records["height"].values, dtype=float)
    keys = np.asarray(records["period_key"].values, dtype=np.int64)
    lid = records["lidar_wind_speed"].transpose("time", "height").values
    ref = records["reference_wind_speed"].transpose("time", "height").values
    s_keys = np.asarray(records["model_form_period_key"].values, dtype=np.int64)
    s_height = _values(records, "model_form_height", "m", source)
    hidx = np.full(s_keys.shape, -1)
    for i, z in enumerate(heights):
        hidx[np.abs(s_height - z) < 1e-3] = i
    order = np.argsort(keys, kind="stable")
    pos = np.searchsorted(keys[order], s_keys)
    found = (pos < keys.size) & (keys[order][np.minimum(pos, keys.size - 1)] == s_keys)
    if not found.all():
        raise InputError(f"{source}: {int((~found).sum())} model-form sample(s) have a period_key that is "
                         "not in the records (the runs belong to other records)")
    t = order[pos]
    keep = hidx >= 0  # a budget restricted to some heights drops the other samples
    n_lid = np.where(keep, lid[t, np.maximum(hidx, 0)], np.nan)
    n_ref = np.where(keep, ref[t, np.maximum(hidx, 0)], np.nan)
    return hidx, n_lid, n_ref, s_keys


def _bin_shifts(e0: np.ndarray, ea: np.ndarray, mu: float, sigma: float, n: float, vref: float
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """δu per alternative, its per-period influence (alternative, period) and u, for one bin.

    ``e0`` (m,) nominal errors; ``ea`` (alternative, m) the alternatives'; ``mu``, ``sigma``, ``n`` the
    bin's pooled mean, standard deviation and distinct-period count; ``vref`` its Table 4 total.
    """
    m = e0.size
    u0 = np.sqrt(vref**2 + mu**2 + sigma**2 * (1.0 + 1.0 / n))
    s0 = e0.std(ddof=1)
    sa = ea.std(axis=1, ddof=1)
    d_mu = (ea - e0).mean(axis=1)
    d_sigma = sa - s0
    mu_a, sigma_a = mu + d_mu, np.maximum(sigma + d_sigma, 0.0)
    ua = np.sqrt(vref**2 + mu_a**2 + sigma_a**2 * (1.0 + 1.0 / n))
    psi_mu = (ea - e0) - d_mu[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        dev = (ea - ea.mean(axis=1, keepdims=True)) ** 2
        psi_sa = (dev - sa[:, None] ** 2 * (m - 1) / m) / (2.0 * sa[:, None])
        psi_s0 = ((e0 - e0.mean()) ** 2 - s0**2 * (m - 1) / m) / (2.0 * s0)
        psi = (mu_a / ua)[:, None] * psi_mu + (sigma_a * (1.0 + 1.0 / n) / ua)[:, None] * (psi_sa - psi_s0)
    return ua - u0, np.nan_to_num(psi), float(u0)


def model_form_term(records: xr.Dataset, edges: np.ndarray, binned: Mapping[str, Any], vref: np.ndarray,
                    k: float, *, source: str) -> dict[str, Any] | None:
    """Return the ``model_form`` contributor (m s-1) per (height, bin) and its companions, or None.

    ``edges`` and ``binned`` are the budget's bins and pooled statistics (``n``, ``mean_difference``,
    ``std_difference``, ``mean_reference``), ``vref`` its Table 4 total on (height, bin) and ``k``
    its coverage factor.  Returns ``contribution``, ``standard_error`` (m s-1), ``sample_count``
    (height, bin), ``shift`` (%, height, bin, alternative), ``alternatives`` and ``config``.
    """
    if "model_form_lidar_wind_speed" not in records.variables:
        return None
    alts = [str(a) for a in records["model_form_alternative"].values]
    hidx, n_lid, n_ref, _ = _nominal(records, source)
    a_lid = _values(records, "model_form_lidar_wind_speed", "m s-1", source)
    a_ref = _values(records, "model_form_reference_wind_speed", "m s-1", source)
    ok = ((hidx >= 0) & np.isfinite(n_lid) & np.isfinite(n_ref)
          & np.all(np.isfinite(a_lid) & np.isfinite(a_ref), axis=0))
    b = np.where(ok, bin_index(np.where(ok, n_ref, np.nan), edges), -1)
    e0 = n_lid - n_ref
    ea = a_lid - a_ref
    shape = binned["n"].shape
    periods = np.asarray(binned.get("period_count", binned["n"]), dtype=float)  # N of sigma/sqrt(N)
    u_mf, u_mf_se = np.full(shape, np.nan), np.full(shape, np.nan)
    count = np.zeros(shape, dtype=np.int64)
    shift = np.full((*shape, len(alts)), np.nan)
    for i in range(shape[0]):
        for j in np.unique(b[(hidx == i) & (b >= 0)]):
            sel = (hidx == i) & (b == j)
            n = float(periods[i, j])
            count[i, j] = int(sel.sum())
            if count[i, j] < MIN_SAMPLES or not n > 0 or not np.isfinite(vref[i, j]):
                continue
            du, psi, _ = _bin_shifts(e0[sel], ea[:, sel], float(binned["mean_difference"][i, j]),
                                     float(binned["std_difference"][i, j]), n, float(vref[i, j]))
            u_mf[i, j] = np.sqrt(np.sum(du**2) / 3.0)
            shift[i, j] = k * du * 100.0 / binned["mean_reference"][i, j]
            if u_mf[i, j] > 0:
                infl = (du[:, None] * psi).sum(axis=0) / (3.0 * u_mf[i, j])
                u_mf_se[i, j] = np.sqrt(np.sum(infl**2)) / count[i, j]
    count[count < MIN_SAMPLES] = 0
    occupied = binned["n"] > 0
    u_mf, u_mf_se = _borrow(u_mf, u_mf_se, binned["mean_reference"], occupied, 0.5 * (edges[:-1] + edges[1:]))
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.sqrt(vref**2 + binned["mean_difference"] ** 2
                    + binned["std_difference"] ** 2 * (1.0 + 1.0 / np.where(occupied, periods, np.nan)))
        contribution = np.sqrt(np.maximum((u + u_mf) ** 2 - u**2, 0.0))
        # d(contribution)/d(u_mf) = (u + u_mf) / contribution
        se = np.where(contribution > 0, (u + u_mf) / contribution * u_mf_se, np.nan)
    contribution = np.where(occupied, contribution, np.nan)
    config = {"recipe": RECIPE, "alternatives": alts, "min_samples": MIN_SAMPLES, "samples": int(ok.sum()),
              "bins_borrowing": int(((count == 0) & np.isfinite(contribution)).sum())}
    return {"contribution": contribution, "standard_error": se, "sample_count": count, "shift": shift,
            "alternatives": alts, "config": config}


def _borrow(u_mf: np.ndarray, se: np.ndarray, mean_ref: np.ndarray, occupied: np.ndarray,
            centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fill an occupied bin without its own u_mf from the nearest bin at its height (relative u_mf / Ū)."""
    u_mf, se = u_mf.copy(), se.copy()
    with np.errstate(invalid="ignore", divide="ignore"):
        rel, rel_se = u_mf / mean_ref, se / mean_ref
    for i in range(u_mf.shape[0]):
        have = np.flatnonzero(np.isfinite(rel[i]))
        if not have.size:
            continue
        for j in np.flatnonzero(occupied[i] & ~np.isfinite(u_mf[i])):
            src = have[np.argmin(np.abs(centres[have] - centres[j]))]
            u_mf[i, j] = rel[i, src] * mean_ref[i, j]
            se[i, j] = rel_se[i, src] * mean_ref[i, j]
    return u_mf, se
