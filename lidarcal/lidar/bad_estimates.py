"""Bad estimates as a property of CNR: classification, the rate p_bad(CNR), its uncertainty, draws.

A pulsed Doppler lidar's velocity estimate is the peak of a noisy Doppler spectrum.  At low CNR
the peak is sometimes a noise peak anywhere in the lidar's velocity search band: a *bad
estimate*, unrelated to the true radial velocity.  How often that happens depends on the CNR
(and on the search band, which sets how many noise bins compete), not on the programmed
velocity or the beam.  A bench bin of 13 or 14 samples (the sample cube) cannot measure a rate
of 0.2 %; the bench as a whole, pooled at each CNR, can.  This module (pure numpy/scipy: SI
floats, no files, no xarray) does that:

* **Classification** (:func:`classify`).  Per CNR the residuals r (measured − programmed) of
  every bench bin are centred on their bin's median m; the good-estimate scale s_c is
  1.4826 · the median of |r − m| pooled over the CNR's beams and velocities (about 2,000
  values on the sample bench, so s_c is known to about 3 %; a bin's own 13 values would give
  it to 30 %, the reason the bench's per-bin MAD rule (``lidarcal.bench.kernels.reject_outliers``,
  k = 4) is not reused: it flags about 1 in 2,000 good estimates, the size of the rate to be
  measured at −18 dB).  A residual is a bad estimate when ``|r − m| > K · max(s_c, 0.005 m/s)``
  with ``K =`` :data:`CLASSIFY_K` = 6: a Gaussian good estimate lies beyond 6 s with
  probability 2e-9, and since bad estimates lie anywhere in a band of about ±30 m/s, few lie
  within 6 s of the truth (below 5 % of them at −24 dB and above).  Those few are corrected for
  rather than ignored: a bin's bad estimate is *detected* with probability
  ``q = 1 − |window ∩ band| / |band|``, the window being ``v + m ± K s_c`` in measured velocity.
  On the sample bench the detection-corrected rate at −28 dB is 0.395–0.397 for K = 5, 6 and 8
  (the classification does not depend on K there, docs/method.md).
* **The search band** (:func:`search_band`): the flagged estimates' *measured* velocities are
  uniform over the band (checked, :func:`uniformity_pvalue`); its ends are estimated by the
  minimum-variance unbiased estimators of a uniform's ends, ``min − (max − min)/(n − 1)`` and
  ``max + (max − min)/(n − 1)``.
* **The rate** (:func:`fit_rate`): ``p_bad(c) = expit(a + b (c − c_ref))``, fitted to every
  bench bin at or above the lowest CNR bin the filtered lidar can draw from, each bin's flagged
  count binomial with probability ``q · p_bad(c)``; maximum likelihood with Firth's penalty
  (½ log det I(θ), Jeffreys' prior: finite estimates when a CNR has no bad estimate at all,
  and the O(1/n) bias of a rare-event logistic fit removed; Firth, Biometrika 80 (1993) 27).
  The covariance of (a, b) is the inverse Fisher information at the estimate.
* **Propagation** (:meth:`BadEstimates.for_trial`): in Monte Carlo replica r >= 1 each
  period draws its curve's (a, b) from the bivariate normal N((â, b̂), Σ) of the fit (JCGM 101
  §6.4.8: every trial draws every input), from
  ``SeedSequence([base_seed, r, period_key], spawn_key=(BAD_RATE_STREAM,))``; replica 0
  simulates the best estimate (â, b̂).  A draw per trial, not one per replica: the distribution
  of one period's error is the same either way, and a curve shared by a whole replica would
  shift every period of a bin together, a shift the replicas must then average out.  The
  rate's uncertainty is nevertheless one lidar's: it is systematic across the periods of a
  campaign, and whoever averages many 10-minute means must not average it down
  (``docs/certificate.md``).

The virtual lidar then draws each line-of-sight estimate as bad with probability
``p_bad(CNR)`` at the period's CNR (its value uniform over the band, whatever the true
velocity), and otherwise as the true radial velocity plus a *good* residual resampled from the
bench bin (:func:`good_pools`: bins with fewer than :data:`MIN_GOOD` good residuals pool the
good residuals of their CNR neighbours).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from scipy import optimize, stats
from scipy.special import expit

__all__ = ["BadEstimates", "CLASSIFY_K", "MIN_SCALE", "MIN_GOOD", "BAD_RATE_STREAM", "classify",
           "search_band", "detection_probability", "fit_rate", "uniformity_pvalue", "good_pools",
           "fit_cnr_min", "padded"]

#: Bad estimate: |r − bin median| > CLASSIFY_K · the CNR's pooled robust scale.
CLASSIFY_K = 6.0
#: Floor (m s-1) of the robust scale, as the bench's MAD rule (``lidarcal.bench.kernels``).
MIN_SCALE = 0.005
#: Fewest good residuals a bin is resampled from: the standard deviation of n values has a
#: relative standard uncertainty of 1/sqrt(2 (n - 1)), 24 % at n = 10 (and the bin's mean one of
#: 0.32 sigma); a bin with fewer pools the good residuals of its CNR neighbours (:func:`good_pools`).
MIN_GOOD = 10
#: ``spawn_key`` of the trials' draws of the rate curve (never a period's or height's own stream).
BAD_RATE_STREAM = 0xBAD


def padded(count: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Return a ragged array (``count`` per bin, ``values`` concatenated in C order) NaN-padded.

    Returns shape ``count.shape + (max(count),)``.
    """
    count = np.asarray(count, dtype=np.int64)
    flat = count.ravel()
    width = max(int(flat.max(initial=0)), 1)
    out = np.full((flat.size, width), np.nan)
    rows = np.repeat(np.arange(flat.size), flat)
    start = np.concatenate([[0], np.cumsum(flat)[:-1]])
    cols = np.arange(flat.sum()) - np.repeat(start, flat)
    out[rows, cols] = values
    return out.reshape(*count.shape, width)


def classify(residuals: np.ndarray, k: float = CLASSIFY_K) -> dict[str, np.ndarray]:
    """Classify bench residuals into good and bad estimates (module docstring).

    ``residuals`` (m s-1) has shape ``(beam, cnr, velocity, sample)``, NaN-padded.  Returns
    ``centre`` (beam, cnr, velocity: each bin's median, NaN when empty), ``scale`` (cnr: the
    pooled robust scale s_c; a CNR without residuals takes the nearest CNR's), ``threshold`` (cnr:
    ``k · max(s_c, MIN_SCALE)``) and ``bad`` (the residuals' shape, False where NaN).
    """
    res = np.asarray(residuals, dtype=float)
    finite = np.isfinite(res)
    has = finite.any(axis=-1)
    centre = np.full(res.shape[:-1], np.nan)
    centre[has] = np.nanmedian(res[has], axis=-1)
    dev = np.abs(res - centre[..., None])
    scale = np.full(res.shape[1], np.nan)
    for c in range(res.shape[1]):
        d = dev[:, c][finite[:, c]]
        if d.size:
            scale[c] = 1.4826 * np.median(d)
    known = np.flatnonzero(np.isfinite(scale))
    if known.size == 0:
        raise ValueError("no residual at any CNR")
    # a CNR without residuals: the scale of the nearest CNR with some (the noise table fills its
    # empty bins from the nearest populated ones); ties go to the lower CNR index
    nearest = known[np.argmin(np.abs(np.arange(scale.size)[:, None] - known[None, :]), axis=1)]
    scale = scale[nearest]
    threshold = k * np.maximum(scale, MIN_SCALE)
    with np.errstate(invalid="ignore"):
        bad = finite & (dev > threshold[None, :, None, None])
    return {"centre": centre, "scale": scale, "threshold": threshold, "bad": bad}


def search_band(measured: np.ndarray) -> tuple[float, float]:
    """Return the ends (m s-1) of the band bad estimates are uniform over, from their measured velocities.

    The minimum-variance unbiased estimators of a uniform distribution's ends:
    ``min − (max − min)/(n − 1)`` and ``max + (max − min)/(n − 1)``; needs n >= 2 values.
    """
    x = np.asarray(measured, dtype=float)
    if x.size < 2:
        raise ValueError(f"the search band needs at least 2 bad estimates; found {x.size}")
    lo, hi = float(x.min()), float(x.max())
    pad = (hi - lo) / (x.size - 1)
    return lo - pad, hi + pad


def _overlap(lo: np.ndarray, hi: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    return np.clip(np.minimum(hi, band[1]) - np.maximum(lo, band[0]), 0.0, None)


def detection_probability(centre: np.ndarray, threshold: np.ndarray, band: tuple[float, float]) -> np.ndarray:
    """Probability that a bad estimate of a bin is classified bad: ``1 − |window ∩ band| / |band|``.

    ``centre`` is the bin's centre in *measured* velocity (programmed + median residual),
    ``threshold`` the half-width of its good window (broadcast with ``centre``).
    """
    centre, threshold = np.asarray(centre, dtype=float), np.asarray(threshold, dtype=float)
    width = band[1] - band[0]
    return 1.0 - _overlap(centre - threshold, centre + threshold, band) / width


def uniformity_pvalue(measured: np.ndarray, centre: np.ndarray, threshold: np.ndarray,
                      band: tuple[float, float]) -> float:
    """Kolmogorov–Smirnov p-value of "flagged estimates are uniform over the band".

    A flagged value x of a bin whose good window is ``centre ± threshold`` is, under the
    hypothesis, uniform over the band outside that window; its conditional distribution
    function (the band's length below x outside the window over the length outside it) maps it
    to a uniform on [0, 1], which is tested (``scipy.stats.kstest``).
    """
    x, c, t = (np.asarray(a, dtype=float) for a in (measured, centre, threshold))
    c, t = np.broadcast_to(c, x.shape), np.broadcast_to(t, x.shape)
    lo, hi = band
    inside = _overlap(c - t, c + t, band)
    below = (np.clip(x, lo, hi) - lo) - _overlap(c - t, np.minimum(c + t, x), band)
    u = below / ((hi - lo) - inside)
    return float(stats.kstest(np.clip(u, 0.0, 1.0), "uniform").pvalue)


def _information(theta: np.ndarray, x: np.ndarray, n: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Fisher information of (a, b) for flagged counts ~ Binomial(n, q · expit(a + b x))."""
    s = expit(theta[0] + theta[1] * x)
    p = q * s
    dp = q * s * (1.0 - s)
    w = n * dp * dp / (p * (1.0 - p))
    return np.array([[np.sum(w), np.sum(w * x)], [np.sum(w * x), np.sum(w * x * x)]])


def fit_rate(x: np.ndarray, n: np.ndarray, flagged: np.ndarray, q: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """Fit ``p(x) = expit(a + b x)`` to flagged counts ~ Binomial(n, q p(x)), Firth-penalised.

    ``x`` (the bins' CNR − c_ref, dB), ``n`` (candidates), ``flagged`` (bad estimates found) and
    ``q`` (detection probability) per bin.  Returns the estimate ``(a, b)`` and its covariance
    (the inverse Fisher information there).  Raises ``ValueError`` when it does not converge or
    the information is singular (all bins at one CNR).
    """
    x, n, k, q = (np.asarray(a, dtype=float).ravel() for a in (x, n, flagged, q))
    keep = n > 0
    x, n, k, q = x[keep], n[keep], k[keep], q[keep]
    if np.unique(x).size < 2:
        raise ValueError("the bad-estimate rate needs bench bins at two CNRs at least")

    def objective(theta: np.ndarray) -> float:
        p = q * expit(theta[0] + theta[1] * x)
        p = np.clip(p, 1e-300, 1.0 - 1e-16)
        loglik = np.sum(k * np.log(p) + (n - k) * np.log1p(-p))
        sign, logdet = np.linalg.slogdet(_information(theta, x, n, q))
        return np.inf if sign <= 0 else -(loglik + 0.5 * logdet)

    # start: a weighted straight line through the per-CNR empirical logits (half-count corrected)
    xs = np.unique(x)
    rate = np.array([(k[x == v].sum() + 0.5) / (np.sum(n[x == v] * q[x == v]) + 1.0) for v in xs])
    start = np.polyfit(xs, np.log(rate / (1.0 - rate)), 1)[::-1]
    best = optimize.minimize(objective, start, method="Nelder-Mead",
                             options={"xatol": 1e-9, "fatol": 1e-11, "maxiter": 20000, "maxfev": 40000})
    if not best.success or not np.all(np.isfinite(best.x)):
        raise ValueError(f"the bad-estimate rate fit did not converge: {best.message}")
    info = _information(best.x, x, n, q)
    if np.linalg.det(info) <= 0:
        raise ValueError("the bad-estimate rate fit has a singular information matrix")
    return np.asarray(best.x, dtype=float), np.linalg.inv(info)


def fit_cnr_min(cnr: np.ndarray, cnr_threshold: float | None) -> float:
    """Lowest bench CNR bin (dB) a lidar filtered at ``cnr_threshold`` draws from (all without one).

    A period at the threshold interpolates between the bins either side of it, so the lowest
    bin used is the highest bin centre at or below the threshold.
    """
    cnr = np.sort(np.asarray(cnr, dtype=float))
    if cnr_threshold is None or cnr_threshold <= cnr[0]:
        return float(cnr[0])
    return float(cnr[cnr <= cnr_threshold][-1])


def good_pools(count: np.ndarray, values: np.ndarray, threshold: np.ndarray,
               min_good: int = MIN_GOOD) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the good residuals each bin is resampled from, as a ragged array.

    ``count`` (beam, cnr, velocity) and ``values`` are a noise table's residuals (C order),
    ``threshold`` (cnr,) the classification's half-widths.  A residual is good when within
    ``threshold`` of its bin's median.  A bin with fewer than ``min_good`` good residuals adds
    the good residuals of the same beam and velocity at the CNR bins 1 step away (both sides
    together), then 2 steps, ... until it has ``min_good`` or the CNR axis is used up.  Returns
    ``(good_count, good_values, own_count)``: the pools (C order of the bins, each bin's own
    good residuals first, then its neighbours' in CNR-step order, lower CNR first) and each
    bin's own good count.  Raises ``ValueError`` when a beam and velocity have no good residual
    at any CNR.
    """
    res = padded(count, values)
    centre = np.nanmedian(res, axis=-1)
    with np.errstate(invalid="ignore"):
        near = np.abs(res - centre[..., None]) <= np.asarray(threshold)[None, :, None, None]
    good = np.isfinite(res) & near
    own = good.sum(axis=-1)
    n_beam, n_cnr, n_vel = own.shape
    counts = np.empty(own.shape, dtype=np.int64)
    chunks = []
    for b in range(n_beam):
        for c in range(n_cnr):
            for v in range(n_vel):
                pool = [res[b, c, v][good[b, c, v]]]
                size = int(own[b, c, v])
                step = 1
                while size < min_good and step < n_cnr:
                    for cc in (c - step, c + step):
                        if 0 <= cc < n_cnr:
                            pool.append(res[b, cc, v][good[b, cc, v]])
                            size += int(own[b, cc, v])
                    step += 1
                if size == 0:
                    raise ValueError(f"no good residual at any CNR for beam {b}, velocity bin {v}")
                counts[b, c, v] = size
                chunks.extend(pool)
    return counts, np.concatenate(chunks), own


@dataclasses.dataclass(frozen=True)
class BadEstimates:
    """A lidar's bad estimates: p_bad(CNR), its covariance and the search band (module docstring).

    Per bench CNR bin (``cnr``, dB): ``scale`` (the pooled robust scale s_c, m s-1),
    ``threshold`` (``k · max(s_c, MIN_SCALE)``, m s-1: the good window's half-width),
    ``total`` and ``flagged`` (candidates and bad estimates found, the model's beams) and
    ``detection`` (the mean detection probability q of its bad estimates).  ``band`` (m s-1):
    the search band's ends.  The fit: bins at or above ``fit_cnr_min`` (dB), ``p_bad(c) =
    expit(a + b (c − cnr_reference))`` with ``rate_parameters`` (a, b) and ``rate_covariance``;
    ``fit_chi2`` / ``fit_dof`` the Pearson chi-square of the per-CNR flagged counts against the
    fit; ``band_uniformity_p`` the p-value of :func:`uniformity_pvalue`.  ``k`` and
    ``min_good`` are the classification's multiple and the fewest good residuals a bin is
    resampled from.  ``drawn`` (a, b): the curve one Monte Carlo trial simulates
    (:meth:`for_trial`); ``None``: the best estimate.
    """

    cnr: tuple[float, ...]
    scale: tuple[float, ...]
    threshold: tuple[float, ...]
    total: tuple[int, ...]
    flagged: tuple[int, ...]
    detection: tuple[float, ...]
    band: tuple[float, float]
    fit_cnr_min: float
    cnr_reference: float
    rate_parameters: tuple[float, float]
    rate_covariance: tuple[tuple[float, float], tuple[float, float]]
    fit_chi2: float
    fit_dof: int
    band_uniformity_p: float
    k: float = CLASSIFY_K
    min_good: int = MIN_GOOD
    drawn: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            object.__setattr__(self, f.name, _tuplify(getattr(self, f.name)))
        for name in ("scale", "threshold", "detection"):  # JSON's null: a CNR without residuals
            values = tuple(np.nan if v is None else float(v) for v in getattr(self, name))
            object.__setattr__(self, name, values)
        object.__setattr__(self, "total", tuple(int(v) for v in self.total))
        object.__setattr__(self, "flagged", tuple(int(v) for v in self.flagged))
        n = len(self.cnr)
        problems = []
        if not all(len(getattr(self, name)) == n for name in ("scale", "threshold", "total", "flagged",
                                                              "detection")):
            problems.append(f"scale, threshold, total, flagged and detection need one value per CNR ({n})")
        if len(self.band) != 2 or not self.band[0] < self.band[1]:
            problems.append(f"band must be (low, high) with low < high; got {self.band}")
        cov = np.asarray(self.rate_covariance, dtype=float)
        if (len(self.rate_parameters) != 2 or cov.shape != (2, 2) or not np.all(np.isfinite(cov))
                or cov[0, 0] <= 0 or np.linalg.det(cov) <= 0 or cov[0, 1] != cov[1, 0]):
            problems.append("rate_parameters must be (a, b) and rate_covariance a symmetric positive "
                            "definite 2 x 2 matrix")
        if self.drawn is not None and len(self.drawn) != 2:
            problems.append(f"drawn must be (a, b) or None; got {self.drawn}")
        if not (self.k > 0 and int(self.min_good) >= 1):
            problems.append(f"k must be > 0 and min_good >= 1; got {self.k}, {self.min_good}")
        if problems:
            raise ValueError("bad_estimates: " + "; ".join(problems))

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def from_residuals(cls, residuals: np.ndarray, cnr: np.ndarray, velocity: np.ndarray, *,
                       cnr_threshold: float | None, k: float = CLASSIFY_K,
                       min_good: int = MIN_GOOD) -> BadEstimates:
        """Classify a bench's residuals, estimate the band and fit the rate.

        ``residuals`` (m s-1): ``(beam, cnr, velocity, sample)``, NaN-padded, the bench's own
        values (empty bins not filled: a filled bin would count its neighbour's values twice);
        ``cnr`` (dB) and ``velocity`` (m s-1) the bin centres; ``cnr_threshold`` (dB or None)
        the lidar's CNR filter, which sets the fitted CNR range (:func:`fit_cnr_min`).
        Raises ``ValueError`` naming what is missing when the bench holds too few bad estimates.
        """
        res = np.asarray(residuals, dtype=float)
        cnr, velocity = np.asarray(cnr, dtype=float), np.asarray(velocity, dtype=float)
        found = classify(res, k)
        bad, centre, threshold = found["bad"], found["centre"], found["threshold"]
        measured = (res + velocity[None, None, :, None])[bad]
        band = search_band(measured)
        n_bin = np.isfinite(res).sum(axis=-1)
        k_bin = bad.sum(axis=-1)
        centre_meas = centre + velocity[None, None, :]
        q_bin = detection_probability(centre_meas, threshold[None, :, None], band)
        lowest = fit_cnr_min(cnr, cnr_threshold)
        in_fit = np.broadcast_to((cnr >= lowest)[None, :, None], n_bin.shape) & (n_bin > 0)
        reference = float(np.mean(cnr[cnr >= lowest]))
        x = np.broadcast_to((cnr - reference)[None, :, None], n_bin.shape)
        theta, cov = fit_rate(x[in_fit], n_bin[in_fit], k_bin[in_fit], q_bin[in_fit])
        cov = 0.5 * (cov + cov.T)
        fitted = expit(theta[0] + theta[1] * x) * q_bin
        chi2, dof = _goodness_of_fit(fitted, n_bin, k_bin, in_fit, cnr >= lowest)
        total = n_bin.sum(axis=(0, 2))
        detection = np.array([np.sum(n_bin[:, c] * np.nan_to_num(q_bin[:, c])) / max(total[c], 1)
                              for c in range(cnr.size)])
        bad_bins = np.broadcast_to(np.arange(n_bin.size).reshape(n_bin.shape)[..., None], res.shape)[bad]
        window = np.broadcast_to(threshold[None, :, None], n_bin.shape).ravel()[bad_bins]
        uniform_p = uniformity_pvalue(measured, centre_meas.ravel()[bad_bins], window, band)
        return cls(cnr=cnr, scale=found["scale"], threshold=threshold, total=total,
                   flagged=k_bin.sum(axis=(0, 2)),
                   detection=detection, band=band, fit_cnr_min=lowest, cnr_reference=reference,
                   rate_parameters=theta, rate_covariance=cov, fit_chi2=float(chi2), fit_dof=int(max(dof, 0)),
                   band_uniformity_p=uniform_p, k=float(k), min_good=int(min_good))

    # -- use ------------------------------------------------------------------------------
    @property
    def parameters(self) -> tuple[float, float]:
        """The (a, b) this model simulates: :attr:`drawn` for a replica, the best estimate otherwise."""
        return self.drawn if self.drawn is not None else self.rate_parameters

    @property
    def fit_pvalue(self) -> float:
        """p-value of the fit's Pearson chi-square (1 without degrees of freedom)."""
        return float(stats.chi2.sf(self.fit_chi2, self.fit_dof)) if self.fit_dof > 0 else 1.0

    def rate(self, cnr: Any, parameters: Any = None) -> np.ndarray:
        """p_bad at ``cnr`` (dB) with ``parameters`` (a, b) (default :attr:`parameters`)."""
        a, b = self.parameters if parameters is None else parameters
        return expit(a + b * (np.asarray(cnr, dtype=float) - self.cnr_reference))

    def rate_standard_uncertainty(self, cnr: Any) -> np.ndarray:
        """Return the standard uncertainty of the best-estimate p_bad at ``cnr`` (dB) (delta method)."""
        c = np.asarray(cnr, dtype=float)
        p = self.rate(c, self.rate_parameters)
        x = c - self.cnr_reference
        cov = np.asarray(self.rate_covariance)
        var_eta = cov[0, 0] + 2 * x * cov[0, 1] + x * x * cov[1, 1]
        return p * (1.0 - p) * np.sqrt(var_eta)

    def for_trial(self, base_seed: int, replica: int, key: int) -> BadEstimates:
        """Return the curve one Monte Carlo trial simulates: period ``key`` in replica ``replica``.

        Replica 0: the best estimate (``self`` without a draw).  Replica r >= 1: (a, b) =
        (â, b̂) + L z, L the Cholesky factor of the covariance (written out for 2 x 2, so the
        draw is the same on any BLAS) and z two standard normals from
        ``SeedSequence([base_seed, r, key mod 2**64], spawn_key=(BAD_RATE_STREAM,))``: every
        (period, replica) its own curve, the same at all heights of the period (module docstring).
        """
        if int(replica) == 0:
            return dataclasses.replace(self, drawn=None)
        seq = np.random.SeedSequence([int(base_seed), int(replica), int(key) % 2**64],
                                     spawn_key=(BAD_RATE_STREAM,))
        z = np.random.default_rng(seq).standard_normal(2)
        (s00, s01), (_, s11) = self.rate_covariance
        l00 = np.sqrt(s00)
        l10 = s01 / l00
        l11 = np.sqrt(max(s11 - l10 * l10, 0.0))
        a, b = self.rate_parameters
        return dataclasses.replace(self, drawn=(float(a + l00 * z[0]), float(b + l10 * z[0] + l11 * z[1])))

    def apply(self, los: np.ndarray, cnr: float, uniforms: np.ndarray) -> np.ndarray:
        """Make estimates bad: where ``uniforms[0] < p_bad(cnr)`` the value is uniform over the band.

        ``los`` (m s-1) are the good estimates (true radial velocity + good residual), ``uniforms``
        ``(2, n)`` uniform numbers in [0, 1): row 0 decides, row 1 places the bad value.
        """
        lo, hi = self.band
        bad = uniforms[0] < float(self.rate(cnr))
        return np.where(bad, lo + (hi - lo) * uniforms[1], los)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form (lists and numbers); :class:`BadEstimates` ``(**d)`` reads it back."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name == "drawn" and value is None:
                continue
            out[f.name] = _listify(value)
        return out


def _goodness_of_fit(p: np.ndarray, n: np.ndarray, k: np.ndarray, in_fit: np.ndarray,
                     fitted_cnr: np.ndarray) -> tuple[float, int]:
    """Pearson chi-square of the flagged counts per CNR against the fit, and its degrees of freedom.

    ``p`` (the fitted detection-weighted rate), ``n`` and ``k`` per bin (beam, cnr, velocity).
    CNRs are grouped from the highest down until a group expects at least 5 bad estimates
    (Cochran's rule: the chi-square approximation needs it; at high CNR one CNR expects 0.01);
    the remainder joins the last group.  Degrees of freedom: groups − 2 (at least 0).
    """
    groups: list[list[float]] = []
    current = [0.0, 0.0, 0.0]  # observed, expected, variance
    for c in np.flatnonzero(fitted_cnr)[::-1]:
        sel = in_fit[:, c]
        current[0] += float(k[:, c][sel].sum())
        current[1] += float(np.sum(n[:, c][sel] * p[:, c][sel]))
        current[2] += float(np.sum(n[:, c][sel] * p[:, c][sel] * (1.0 - p[:, c][sel])))
        if current[1] >= 5.0:
            groups.append(current)
            current = [0.0, 0.0, 0.0]
    if current[1] > 0 or not groups:
        if groups:
            groups[-1] = [a + b for a, b in zip(groups[-1], current, strict=True)]
        else:
            groups.append(current)
    chi2 = sum((o - e) ** 2 / v for o, e, v in groups if v > 0)
    return float(chi2), max(len(groups) - 2, 0)


def _tuplify(value: Any) -> Any:
    """Arrays and lists as nested tuples of Python numbers (a hashable, comparable record)."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, list | tuple):
        return tuple(_tuplify(v) for v in value)
    return value.item() if isinstance(value, np.generic) else value


def _listify(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return [_listify(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None  # JSON has no NaN: a CNR without residuals has no scale
    return value
