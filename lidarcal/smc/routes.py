"""The certificate applied to a campaign's periods: the calibration contributor and the 50-2 route.

:func:`calibration_part` looks every period up in the certificate's budget at its height and
wind-speed bin: a bin whose ``bin_flag`` means ``certified`` gives its certified relative
standard uncertainty times the period's speed; any other bin, a speed outside the budget's bins
or a height that is not certified gives NaN and a coverage flag saying why, never a number.

:func:`iec_route` is the IEC 61400-50-2 way of carrying a calibration to a campaign (the
paper's §4: "sensitivity slopes and the actual difference in conditions between calibration
and SMC"): at each height, every sensitivity the certificate found significant (Eq. 12 or
Eq. 13) predicts the deviation ``m_j (x_j − x̄_j,cal)`` of a period whose condition ``x_j``
differs from the calibration's mean ``x̄_j,cal`` (the mean over the periods its regression used,
from the sensitivity's bin table); the route's contribution is the root-sum-square of those
deviations in m s-1, and their sum is kept as the signed deviation.  ``docs/smc.md`` gives the
formula, its sources and what the route leaves out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from lidarcal.analysis.kernels import centred_edges
from lidarcal.errors import InputError
from lidarcal.readback import read_attr
from lidarcal.smc.certified import Certified, flag_meanings
from lidarcal.smc.kernels import bin_index, binned_quantiles, iec_deviations, quadrature

__all__ = [
    "COVERAGE",
    "ENVELOPE",
    "IecRoute",
    "calibration_part",
    "iec_route",
    "calibration_means",
    "budget_edges",
    "envelope",
    "envelope_bounds",
    "outside_envelope",
    "table_edges",
    "calibration_quantiles",
    "QUANTILES",
    "SLOPE_VARIABLES",
]

#: ``coverage_flag`` meanings, in value order (0 ... 5).
COVERAGE = (
    "covered",
    "no_wind_speed",
    "height_not_certified",
    "outside_certified_range",
    "bin_not_certified",
    "environmental_term_missing",
)
#: Variables whose sensitivity the 50-2 route applies: the wind speed has its own bins (the budget
#: is per wind-speed bin already) and a slope against the direction, a circular variable, has no meaning.
SLOPE_VARIABLES = ("turbulence_intensity", "wind_shear_exponent", "cnr", "cnr_gradient")


def budget_edges(budget: xr.Dataset) -> np.ndarray:
    """Return the budget's wind-speed bin edges (m s-1), from its bounds."""
    b = np.asarray(budget["wind_speed_bounds"].values, dtype=float)
    return np.append(b[:, 0], b[-1, 1])


def table_edges(budget: xr.Dataset, speed: np.ndarray) -> np.ndarray:
    """Return the edges of the campaign's wind-speed bins.

    The budget's width, centred on its multiples, spanning the budget's bins and every campaign
    speed (so a period outside the certificate's bins has a row).
    """
    edges = budget_edges(budget)
    width = float(np.min(np.diff(edges)))
    finite = np.asarray(speed, dtype=float)[np.isfinite(speed)]
    lo = min(float(edges[0]) + width / 2, float(finite.min()) if finite.size else np.inf)
    hi = max(float(edges[-1]) - width / 2, float(finite.max()) if finite.size else -np.inf)
    return centred_edges(lo, hi, width)


def calibration_part(
    cert: Certified, speed: np.ndarray, height_index: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the calibration contributor (m s-1), the coverage code and the budget bin of every period.

    ``speed`` (time, height) the campaign's wind speeds (m s-1), ``height_index`` (height,) the
    certified height each campaign height is (-1: not certified).  Codes are :data:`COVERAGE`'s
    0 ... 4 (code 5 is set once the environmental term is known).
    """
    bud = cert.budget.transpose("height", "wind_speed", ...)
    rel = bud["relative_uncertainty"].values  # (certified height, bin), %
    flags = flag_meanings(bud["bin_flag"])
    meaning = np.vectorize(lambda v: flags.get(int(v), str(v)))(bud["bin_flag"].values)
    edges = budget_edges(bud)
    nt, nh = speed.shape
    u = np.full((nt, nh), np.nan)
    code = np.zeros((nt, nh), dtype=np.int8)
    bins = np.full((nt, nh), -1)
    for j in range(nh):
        s = speed[:, j]
        if height_index[j] < 0:
            code[:, j] = np.where(np.isfinite(s), 2, 1)
            continue
        b = bin_index(s, edges)
        bins[:, j] = b
        m = np.where(b >= 0, meaning[height_index[j], np.maximum(b, 0)], "outside")
        certified = (b >= 0) & (m == "certified")
        u[:, j] = np.where(certified, rel[height_index[j], np.maximum(b, 0)] * s / 100.0, np.nan)
        code[:, j] = np.select(
            [~np.isfinite(s), (b < 0) | (m == "outside_certified_range"), ~certified], [1, 3, 4], 0
        )
    return u, code, bins


def calibration_means(sens: xr.Dataset) -> np.ndarray:
    """Return the calibration's mean of a sensitivity's variable per height (periods of its regression).

    ``Σ n_b x̄_b / Σ n_b`` over the bins ``bin_flag`` calls ``used`` (the sensitivity's bin table).
    """
    s = sens.transpose("height", "bin", ...)
    used = (
        np.vectorize(lambda v: flag_meanings(s["bin_flag"]).get(int(v), ""))(s["bin_flag"].values) == "used"
    )
    n = np.where(used, s["sample_count"].values, 0).astype(float)
    x = np.where(used, s["variable_mean"].values, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (n * x).sum(axis=1) / n.sum(axis=1)


@dataclass(frozen=True)
class IecRoute:
    """What the 50-2 route applies per height; :meth:`apply` gives its result on any block of periods."""

    variables: tuple[str, ...]  #: the sensitivity variables of the certificate it considered
    slope: np.ndarray  #: (variable, height) slope applied (NaN where not significant), % per unit
    calibration_mean: np.ndarray  #: (variable, height) the calibration's mean of the variable
    units: tuple[str, ...]  #: each variable's units
    slope_units: tuple[str, ...]  #: each slope's units
    significant: np.ndarray  #: (variable, height) 1 where the slope is applied
    note: str = "computed"  #: or why not

    def apply(self, conditions: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
        """Return the route's contribution (root-sum-square of the slopes' deviations) and their signed sum.

        Both (time, height) in m s-1 at ``conditions``' periods (the campaign's, canonical units,
        on the route's heights); NaN where the wind speed is missing, or where a condition is
        missing whose slope is applied, or everywhere when the route could not be computed.
        """
        speed = conditions["wind_speed"].transpose("time", "height").values
        nt, nh = speed.shape
        if self.note != "computed":
            nan = np.full((nt, nh), np.nan)
            return nan, nan.copy()
        if not self.variables:
            zero = np.where(np.isfinite(speed), 0.0, np.nan)
            return zero, zero.copy()
        x = np.stack([conditions[v].transpose("time", "height").values for v in self.variables])
        applied = np.where(self.significant == 1, self.slope, 0.0)  # a slope not significant adds nothing
        dev_pct = iec_deviations(x, applied[:, None, :], self.calibration_mean[:, None, :])  # %
        # a missing condition matters only where its slope is applied
        dev_pct = np.where(self.significant[:, None, :] == 1, dev_pct, 0.0)
        dev = dev_pct * speed[None] / 100.0
        contribution = np.where(np.isfinite(speed), quadrature(dev, axis=0), np.nan)
        deviation = np.where(np.isfinite(speed), dev.sum(axis=0), np.nan)
        return contribution, deviation


def iec_route(cert: Certified, conditions: xr.Dataset, height_index: np.ndarray) -> IecRoute:
    """Set up the 50-2 route (module docstring): the slopes and calibration means it applies per height.

    ``conditions`` are the campaign's (time, height) in canonical units (only their units are
    read), ``height_index`` as for :func:`calibration_part`; :meth:`IecRoute.apply` computes the
    route on the periods.
    """
    nh = conditions.sizes["height"]
    if "sensitivities" in cert.missing:  # an older certificate: the route cannot be computed, no number
        return IecRoute(variables=(), slope=np.zeros((0, nh)),
                        calibration_mean=np.zeros((0, nh)), units=(), slope_units=(),
                        significant=np.zeros((0, nh), dtype=np.int8),
                        note=f"not computed: {cert.missing['sensitivities']}")
    variables = tuple(v for v in SLOPE_VARIABLES if v in cert.sensitivities)
    slope = np.full((len(variables), nh), np.nan)
    mean = np.full((len(variables), nh), np.nan)
    sig = np.zeros((len(variables), nh), dtype=np.int8)
    units, slope_units = [], []
    for k, v in enumerate(variables):
        sens = cert.sensitivities[v].transpose("height", ...)
        found = read_attr(sens, "environmental_variable_units", kind="sensitivity",
                          default=sens["bin"].attrs.get("units"))
        want = conditions[v].attrs.get("units")
        if found != want:
            raise InputError(
                f"{cert.path}: component sensitivity_{v}: variable units {found!r}; the campaign's "
                f"{v!r} is in {want!r} (expected the same units)"
            )
        if not str(sens["slope"].attrs.get("units", "")).startswith("%"):
            raise InputError(
                f"{cert.path}: component sensitivity_{v}: slope units "
                f"{sens['slope'].attrs.get('units')!r}; expected a relative slope (% per unit)"
            )
        units.append(str(want))
        slope_units.append(str(sens["slope"].attrs["units"]))
        means = calibration_means(sens)
        for j in range(nh):
            if height_index[j] < 0:
                continue
            i = height_index[j]
            mean[k, j] = means[i]
            if int(sens["significant"].values[i]) == 1 and np.isfinite(sens["slope"].values[i]):
                slope[k, j] = float(sens["slope"].values[i])
                sig[k, j] = 1
    return IecRoute(
        variables=variables,
        slope=slope,
        calibration_mean=mean,
        units=tuple(units),
        slope_units=tuple(slope_units),
        significant=sig,
    )


#: Variables whose calibrated envelope is checked, in the order of ``outside_envelope``'s bits (1, 2, 4, 8).
ENVELOPE = ("turbulence_intensity", "wind_shear_exponent", "cnr", "cnr_gradient")


def envelope(
    cert: Certified, conditions: xr.Dataset, height_index: np.ndarray
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray, tuple[str, ...]]:
    """Return the calibrated envelope per variable and height, and each period's bits outside it.

    A variable's envelope at a height is the range of the populated bins of its sensitivity
    (the calibration's periods of that regression); the CNR's, without a CNR sensitivity, is the
    range the calibration simulated (``lidarcal_records_summary``).  Where the certificate says
    nothing the envelope is NaN and no period is flagged.  Returns (low per variable (height,),
    high per variable (height,), bits (time, height) int8, :data:`ENVELOPE`).
    """
    lows, highs = envelope_bounds(cert, height_index)
    return lows, highs, outside_envelope(lows, highs, conditions), ENVELOPE


def envelope_bounds(cert: Certified, height_index: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Return the calibrated envelope of each :data:`ENVELOPE` variable: (lows, highs), each (height,)."""
    nh = np.asarray(height_index).size
    lows, highs = [], []
    for v in ENVELOPE:
        lo, hi = np.full(nh, np.nan), np.full(nh, np.nan)
        sens = cert.sensitivities.get(v)
        for j in range(nh):
            i = height_index[j]
            if i < 0:
                continue
            if sens is not None:
                s = sens.transpose("height", "bin", ...)
                bounds = np.asarray(s["bin_bounds"].values, dtype=float)
                filled = np.asarray(s["sample_count"].values[i]) > 0
                if filled.any():
                    lo[j], hi[j] = bounds[filled, 0].min(), bounds[filled, 1].max()
            elif v == "cnr" and cert.summary and "cnr_min_db" in cert.summary:
                lo[j], hi[j] = float(cert.summary["cnr_min_db"]), float(cert.summary["cnr_max_db"])
        lows.append(lo)
        highs.append(hi)
    return lows, highs


def outside_envelope(lows: list[np.ndarray], highs: list[np.ndarray], conditions: xr.Dataset) -> np.ndarray:
    """(time, height) int8: bit k set where :data:`ENVELOPE`'s k-th variable is outside its envelope."""
    bits = np.zeros((conditions.sizes["time"], conditions.sizes["height"]), dtype=np.int8)
    for k, (v, lo, hi) in enumerate(zip(ENVELOPE, lows, highs, strict=True)):
        x = conditions[v].transpose("time", "height").values
        with np.errstate(invalid="ignore"):
            out = np.isfinite(x) & ((x < lo[None, :]) | (x > hi[None, :]))
        bits |= (out.astype(np.int8) << k).astype(np.int8)
    return bits


#: Quantile levels of the calibration's distribution of each variable kept in the ``smc`` artefact.
QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


def calibration_quantiles(cert: Certified, height_index: np.ndarray) -> dict[str, np.ndarray]:
    """Return the calibration's distribution of each :data:`ENVELOPE` variable: :data:`QUANTILES` per height.

    From the bin table of the variable's sensitivity (its regression's periods; linear inside a
    bin, :func:`lidarcal.smc.kernels.binned_quantiles`); (quantile, height), NaN where the
    certificate has no such sensitivity or the height is not certified.
    """
    out = {}
    for v in ENVELOPE:
        q = np.full((len(QUANTILES), height_index.size), np.nan)
        sens = cert.sensitivities.get(v)
        if sens is not None:
            s = sens.transpose("height", "bin", ...)
            bounds = np.asarray(s["bin_bounds"].values, dtype=float)
            for j, i in enumerate(height_index):
                if i >= 0:
                    counts = np.asarray(s["sample_count"].values[i])
                    q[:, j] = binned_quantiles(bounds, counts, np.array(QUANTILES))
        out[v] = q
    return out
