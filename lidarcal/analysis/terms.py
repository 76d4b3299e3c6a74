"""Uncertainty terms not modelled by the Monte Carlo simulation (paper §2.4, Eqs. 6–11, Table 4).

Five standard uncertainties of the horizontal wind speed U, added in quadrature to the
Monte Carlo budget.  ``phi`` is the cone (opening) angle of the oblique beams from the
vertical (28° for a WindCube; Table 1's "polar 62°" is the elevation, 90° - 28°).

=============================  =====  ============================================================
contributor                    Eq.    standard uncertainty of U
=============================  =====  ============================================================
``bench_std_repeatability``    6      ``s_s / (sqrt(2) sin phi)``
``bench_bias_repeatability``   7      ``s_delta / (sqrt(2) sqrt(N) sin phi)``
``bench_uncertainty``          8      ``(dv_SAFO / k) / (sqrt(2) sqrt(N_los) sin phi)``
``beam_angle``                 9      ``U cot(phi) dphi`` (or ``c U`` with a given coefficient c)
``zero_distance``              11     ``alpha U dz cos(phi) / z`` (power-law shear, Eq. 10)
=============================  =====  ============================================================

What the paper's printed numbers imply (and what lidarcal therefore does)
-------------------------------------------------------------------------
*N in Eq. 7.*  The text says N is the number of repeated bench runs (4 kept runs), which
gives 0.021 / (sqrt(2) sqrt(4) sin 28°) = 0.0158 m/s.  Table 4 prints 0.0026 m/s, which is
Eq. 7 with the N = 150 LOS samples per 10 minutes of Eq. 8 (0.00258).  The default,
``bias_repeatability_n="los_samples"``, reproduces Table 4; ``"runs"`` follows the text.

*Coverage factor of dv_SAFO.*  The bench uncertainty 0.0145 m/s is stated at k = 2, yet
Table 4's 0.0018 m/s is Eq. 8 with 0.0145 used as a standard uncertainty (0.00178); with
k = 2 removed it is 0.00089 m/s.  lidarcal divides by the stated k = 2 by default
(``bench_coverage_factor=2``): a standard uncertainty enters a quadrature sum.
``paper_table4=True`` restores the printed use (k = 1).

*Beam angle, 0.00248 vs 0.00286.*  Eq. 9 with dphi = 0.087° = 1.518e-3 rad and phi = 28°
gives cot(28°) × 1.518e-3 = 0.00286 U, not the printed 0.00248 U (that coefficient would
need dphi = 0.0756°, or phi = 31.5° with 0.087°).  Table 4's beam-angle row uses 0.00248 U.
By default lidarcal evaluates the formula (0.00286 U); pass ``beam_angle_coefficient=0.00248``
to reproduce the table as printed.

*Rounding of the printed total.*  Table 4's Total rows are the quadrature sum of the rows
*as printed* (in particular Eq. 6 rounded to 0.041 m/s from 0.04067), and the % row is that
rounded total divided by U.  lidarcal sums the unrounded terms, which gives totals up to
0.0003 m/s (0.07 percentage points at 4 m/s) below the printed ones; ``tests/test_terms.py``
shows both.

*Eqs. 6–7: where the √N belongs* (``noise_terms``).  The printed forms divide the bias
repeatability (Eq. 7) by √N and not the std repeatability (Eq. 6).  Propagating each error
through the 10-minute DBS average gives the opposite (``docs/noise_terms.md``):

* an error δσ in the LOS noise std changes the 10-minute speed only through the noise of
  the mean of N samples per beam, ``δσ / (√2 √N sin φ)``, and the change of the scalar
  average's noise bias ``p σ δσ / (2 sin²φ U)`` (added in quadrature: the first has zero
  mean): with s_s = 0.027 m/s, N = 150, σ = 0.1 m/s, p = 2/3: 0.0033 m/s ⊕ 0.0010 (4 m/s)
  … 0.0003 (16 m/s) m/s = 0.0035 … 0.0033 m/s;
* an error δμ in a bin's mean bias does not average away: a 10-minute period keeps sampling
  the same few (CNR, velocity) bins of each beam, so ``s_δ / (√2 sin φ)`` = 0.032 m/s.

``noise_terms="printed"`` (default) keeps Eqs. 6–7 as printed, so Table 4 is reproduced;
``noise_terms="derived"`` uses the propagated forms.  ``tests/test_terms.py`` checks both
against a Monte Carlo run of the virtual lidar with the bench cube perturbed by s_s and s_δ.

*Zd uncertainty along the beam.*  Eq. 11 uses the 0.45 m range uncertainty as a height
uncertainty; the height error of an oblique beam is dz cos(phi) (0.397 m at 28°).  lidarcal
uses dz cos(phi) by default; ``paper_table4=True`` restores Eq. 11 as printed (dz).

*One switch for the printed table.*  ``paper_table4=True`` (``lidarcal terms --table4 printed``)
restores both printed choices (dv_SAFO used as a standard uncertainty, the range error used as
a height error); with ``beam_angle_coefficient=0.00248`` and the default Eqs. 6-7 it reproduces
Table 4 to its printed digits (``tests/test_terms.py``).  An explicit ``bench_coverage_factor``
overrides the one the switch picks.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any, Literal, NamedTuple

import numpy as np
import xarray as xr

from lidarcal.errors import InputError
from lidarcal.io import open_artefact
from lidarcal.provenance import stamp
from lidarcal.schema import with_output_attrs
from lidarcal.units import Q_, convert_variable, to_magnitude

__all__ = [
    "CONTRIBUTORS",
    "PAPER_INPUTS",
    "TABLE4_WIND_SPEEDS",
    "NOISE_TERMS",
    "table4_kernel",
    "uncertainty_terms",
    "table4_total",
    "repeatability_inputs",
    "format_table",
]

#: Contributor id -> (equation, description), in Table 4's row order.
CONTRIBUTORS: dict[str, tuple[str, str]] = {
    "bench_std_repeatability": ("6", "repeatability of the SAFO-MV LOS standard deviation"),
    "bench_bias_repeatability": ("7", "repeatability of the SAFO-MV LOS mean bias"),
    "bench_uncertainty": ("8", "standard uncertainty of the SAFO-MV bench"),
    "beam_angle": ("9", "lidar beam (cone) angle uncertainty"),
    "zero_distance": ("11", "zero-distance (Zd) calibration uncertainty under shear"),
}

#: Inputs of Table 4 as given in the paper (§2.4); ``uncertainty_terms(ws, **PAPER_INPUTS)``.
PAPER_INPUTS: dict[str, Any] = {
    "mean_between_run_std_std": Q_(0.027, "m/s"),
    "mean_between_run_std_bias": Q_(0.021, "m/s"),
    "n_runs": 4,
    "n_los_samples": 150,
    "bench_uncertainty": Q_(0.0145, "m/s"),
    "beam_angle_uncertainty": Q_(0.087, "degree"),
    "zero_distance_uncertainty": Q_(0.45, "m"),
    "shear_exponent": 0.2,
    "height": Q_(100.0, "m"),
    "cone_angle": Q_(28.0, "degree"),
}
#: Forms of Eqs. 6-7 (see module docstring and ``docs/noise_terms.md``).
NOISE_TERMS = ("printed", "derived")
#: LOS noise std and hybrid weight used by the derived Eq. 6's noise-bias part when none is given:
#: the ideal lidar's defaults (:class:`lidarcal.lidar.LidarModel`).
DERIVED_DEFAULTS: dict[str, Any] = {"los_noise_std": Q_(0.1, "m/s"), "hybrid_weight": 2.0 / 3.0}
#: Wind speeds of Table 4's columns.
TABLE4_WIND_SPEEDS = Q_(np.arange(4.0, 17.0, 2.0), "m/s")


def table4_kernel(
    wind_speed: np.ndarray,
    *,
    std_repeatability: float,
    bias_repeatability: float,
    n_bias: float,
    n_los_samples: float,
    bench_uncertainty: float,
    beam_angle_uncertainty: float,
    zero_distance_uncertainty: float,
    shear_exponent: float,
    height: float,
    cone_angle: float,
    beam_angle_coefficient: float | None = None,
    noise_terms: str = "printed",
    los_noise_std: float = 0.1,
    hybrid_weight: float = 2.0 / 3.0,
    zero_distance_projection: float = 1.0,
) -> np.ndarray:
    """Eqs. 6–9 and 11 on SI floats; returns shape (len(wind_speed), 5) in m s-1.

    Angles are in radians; ``n_bias`` is the N of Eq. 7; ``bench_uncertainty`` is already a
    standard uncertainty; Eq. 11's height uncertainty is ``zero_distance_projection`` times
    ``zero_distance_uncertainty`` (cos phi for the range error of an oblique beam, 1 as Table 4
    prints it).  Columns follow :data:`CONTRIBUTORS`.  ``noise_terms="derived"``
    replaces Eqs. 6–7 by ``s_s / (√2 √N_los sin φ) ⊕ p σ s_s / (2 sin²φ U)`` and
    ``s_δ / (√2 sin φ)`` (``los_noise_std`` σ and ``hybrid_weight`` p enter only there).
    """
    u = np.asarray(wind_speed, dtype=float)
    denom = np.sqrt(2.0) * np.sin(cone_angle)
    if noise_terms == "printed":
        eq6 = std_repeatability / denom
        eq7 = bias_repeatability / (denom * np.sqrt(n_bias))
    elif noise_terms == "derived":
        # the mean of N noisy samples per beam (a zero-mean error, delta-sigma times the mean of
        # N unit normals) and the scalar average's noise bias p sigma_u^2 / (2 U), sigma_u =
        # sigma / (sqrt(2) sin phi), differentiated in sigma (a shift): uncorrelated, so in quadrature
        noise_bias = hybrid_weight * los_noise_std * std_repeatability / (2.0 * np.sin(cone_angle) ** 2 * u)
        eq6 = np.hypot(std_repeatability / (denom * np.sqrt(n_los_samples)), noise_bias)
        eq7 = bias_repeatability / denom  # a period keeps sampling the same bins: no 1/sqrt(N)
    else:
        raise ValueError(f"noise_terms must be one of {NOISE_TERMS}; got {noise_terms!r}")
    eq8 = bench_uncertainty / (denom * np.sqrt(n_los_samples))
    if beam_angle_coefficient is None:
        eq9 = u * beam_angle_uncertainty / np.tan(cone_angle)
    else:
        eq9 = beam_angle_coefficient * u
    eq11 = shear_exponent * u * zero_distance_projection * zero_distance_uncertainty / height
    ones = np.ones_like(u)
    return np.stack([eq6 * ones, eq7 * ones, eq8 * ones, eq9, eq11], axis=-1)


def _positive(value: float, name: str, unit: str, *, allow_zero: bool = True) -> float:
    value = float(value)
    if not np.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
        need = "a non-negative" if allow_zero else "a positive"
        raise InputError(f"argument {name!r}: expected {need} finite value; found {value:g} {unit}".rstrip())
    return value


#: The inputs stored as scalar variables (one per height when stacked), in output order; their
#: units and long names are declared in ``schemas/uncertainty_terms.yaml``.
INPUT_NAMES = ("mean_between_run_std_std", "mean_between_run_std_bias", "n_runs", "n_los_samples",
               "bench_uncertainty", "bench_coverage_factor", "beam_angle_uncertainty",
               "zero_distance_uncertainty", "zero_distance_projection", "shear_exponent", "cone_angle",
               "beam_angle_coefficient", "los_noise_std", "hybrid_weight")


class _Table4(NamedTuple):
    """Table 4 computed for checked inputs: the terms of each height, before any artefact."""

    ws: np.ndarray
    heights: Any
    alphas: list[float]
    inputs: dict[str, Any]
    per_height: list[np.ndarray]
    n_bias: Any
    beam_angle_coefficient: float | None
    paper_table4: bool


def _table4(
    wind_speed: Any,
    *,
    mean_between_run_std_std: Any,
    mean_between_run_std_bias: Any,
    n_runs: int,
    n_los_samples: int,
    bench_uncertainty: Any,
    beam_angle_uncertainty: Any,
    zero_distance_uncertainty: Any,
    shear_exponent: float,
    height: Any,
    cone_angle: Any,
    beam_angle_coefficient: float | None = None,
    bias_repeatability_n: Literal["los_samples", "runs"] = "los_samples",
    bench_coverage_factor: float | None = None,
    noise_terms: Literal["printed", "derived"] = "printed",
    paper_table4: bool = False,
    los_noise_std: Any = None,
    hybrid_weight: float | None = None,
) -> _Table4:
    """Check the inputs of :func:`uncertainty_terms` and evaluate Table 4 at each height."""
    ws = _checked_wind_speeds(wind_speed)
    heights, alphas = _checked_heights(height, shear_exponent)
    paper_table4 = bool(paper_table4)
    if bench_coverage_factor is None:
        bench_coverage_factor = 1.0 if paper_table4 else 2.0
    inputs = _checked_inputs(
        mean_between_run_std_std=mean_between_run_std_std,
        mean_between_run_std_bias=mean_between_run_std_bias,
        n_runs=n_runs, n_los_samples=n_los_samples, bench_uncertainty=bench_uncertainty,
        bench_coverage_factor=bench_coverage_factor, beam_angle_uncertainty=beam_angle_uncertainty,
        zero_distance_uncertainty=zero_distance_uncertainty, cone_angle=cone_angle)
    # Eq. 11: the range error of Zd moves an oblique beam's gate by dz cos(phi) in height
    cos_phi = float(np.cos(np.deg2rad(inputs["cone_angle"])))
    inputs["zero_distance_projection"] = 1.0 if paper_table4 else cos_phi
    if bias_repeatability_n not in ("los_samples", "runs"):
        raise InputError(f"argument 'bias_repeatability_n': expected 'los_samples' or 'runs'; "
                         f"found {bias_repeatability_n!r}")
    if beam_angle_coefficient is not None:
        beam_angle_coefficient = _positive(beam_angle_coefficient, "beam_angle_coefficient", "")
        inputs["beam_angle_coefficient"] = beam_angle_coefficient
    derived = _derived_inputs(noise_terms, los_noise_std, hybrid_weight)
    inputs.update(derived)
    n_bias = inputs["n_los_samples"] if bias_repeatability_n == "los_samples" else inputs["n_runs"]
    per_height = [table4_kernel(
        ws, std_repeatability=inputs["mean_between_run_std_std"],
        bias_repeatability=inputs["mean_between_run_std_bias"], n_bias=n_bias,
        n_los_samples=inputs["n_los_samples"],
        bench_uncertainty=inputs["bench_uncertainty"] / inputs["bench_coverage_factor"],
        beam_angle_uncertainty=np.deg2rad(inputs["beam_angle_uncertainty"]),
        zero_distance_uncertainty=inputs["zero_distance_uncertainty"],
        shear_exponent=alpha, height=z, cone_angle=np.deg2rad(inputs["cone_angle"]),
        beam_angle_coefficient=beam_angle_coefficient, noise_terms=noise_terms,
        zero_distance_projection=inputs["zero_distance_projection"], **derived,
    ) for z, alpha in zip(np.atleast_1d(heights), alphas, strict=True)]
    inputs = {name: (alphas if name == "shear_exponent" else inputs[name]) for name in INPUT_NAMES
              if name in inputs or name == "shear_exponent"}
    return _Table4(ws, heights, alphas, inputs, per_height, n_bias, beam_angle_coefficient, paper_table4)


def _total(terms: np.ndarray) -> np.ndarray:
    """Quadrature sum of the contributors (the last axis but the wind speeds')."""
    return np.sqrt(np.sum(terms**2, axis=1))


def table4_total(wind_speed: Any, **inputs: Any) -> np.ndarray:
    """Return Table 4's total (m s-1) on (height, wind speed), without building the artefact.

    ``inputs`` as for :func:`uncertainty_terms` (``height`` 1-D); the values are its ``total``
    variable's.  What :func:`lidarcal.analysis.budget.budget` needs when given no terms.
    """
    return np.stack([_total(terms) for terms in _table4(wind_speed, **inputs).per_height])


def uncertainty_terms(
    wind_speed: Any,
    *,
    mean_between_run_std_std: Any,
    mean_between_run_std_bias: Any,
    n_runs: int,
    n_los_samples: int,
    bench_uncertainty: Any,
    beam_angle_uncertainty: Any,
    zero_distance_uncertainty: Any,
    shear_exponent: float,
    height: Any,
    cone_angle: Any,
    beam_angle_coefficient: float | None = None,
    bias_repeatability_n: Literal["los_samples", "runs"] = "los_samples",
    bench_coverage_factor: float | None = None,
    noise_terms: Literal["printed", "derived"] = "printed",
    paper_table4: bool = False,
    los_noise_std: Any = None,
    hybrid_weight: float | None = None,
    repeatability: xr.Dataset | None = None,
    call: str = "lidarcal.analysis.terms.uncertainty_terms",
) -> xr.Dataset:
    """Build the ``uncertainty_terms`` artefact: Table 4 for any inputs and wind speeds.

    Parameters
    ----------
    wind_speed : pint.Quantity
        Horizontal wind speeds (1-D, > 0), e.g. :data:`TABLE4_WIND_SPEEDS`.
    mean_between_run_std_std, mean_between_run_std_bias : pint.Quantity (speed)
        s-bar_s and s-bar_delta of the repeatability analysis (0.027 and 0.021 m/s).
    n_runs : int
        Number of bench runs in the repeatability analysis (the N of Eq. 7 per the text).
    n_los_samples : int
        Radial velocities per LOS in a 10-minute period (150; the N of Eq. 8).
    bench_uncertainty : pint.Quantity (speed)
        dv_SAFO (0.0145 m/s, stated at k = 2; see ``bench_coverage_factor``).
    beam_angle_uncertainty : pint.Quantity (angle)
        dphi, standard uncertainty of the cone angle (0.087°).
    zero_distance_uncertainty : pint.Quantity (length)
        dz, standard uncertainty of the zero distance (0.45 m).
    shear_exponent : float or sequence of float
        Power-law alpha of Eq. 10 (0.2); one per height when ``height`` is 1-D.
    height : pint.Quantity (length)
        Measurement height z (100 m), or a 1-D array of heights: the terms of each height then
        stack along a ``height`` dimension (Eq. 11 scales with 1/z).
    cone_angle : pint.Quantity (angle)
        phi, beam angle from vertical (28°).
    beam_angle_coefficient : float, optional
        If given, Eq. 9 is ``coefficient * U`` (Table 4 uses 0.00248) instead of
        ``U cot(phi) dphi`` (0.00286 U with the paper's inputs).
    bias_repeatability_n : {"los_samples", "runs"}
        Which N divides Eq. 7: ``n_los_samples`` (reproduces Table 4) or ``n_runs`` (the text).
    bench_coverage_factor : float, optional
        k dividing ``bench_uncertainty``: default 2 (dv_SAFO is stated at k = 2), 1 with
        ``paper_table4`` (Table 4's use); a value given here overrides both.
    noise_terms : {"printed", "derived"}
        Eqs. 6–7 as printed (reproduces Table 4) or as propagated through the 10-minute
        average (module docstring, ``docs/noise_terms.md``).
    paper_table4 : bool
        Restore Table 4's printed choices: dv_SAFO used as a standard uncertainty (k = 1) and
        Eq. 11 with the range error of Zd as a height error (no cos phi).  Default False: ÷ k = 2
        and ``dz cos(phi)`` (module docstring).
    los_noise_std, hybrid_weight : optional
        σ (speed) and p of the derived Eq. 6's noise-bias part (default 0.1 m/s and 2/3);
        only with ``noise_terms="derived"``.
    repeatability : xarray.Dataset, optional
        The repeatability artefact the inputs came from (recorded in provenance).
    call : str
        Recorded in ``history``.

    Returns
    -------
    xarray.Dataset
        Dims ``(wind_speed, contributor)``: ``uncertainty`` (m s-1) and
        ``relative_uncertainty`` (%) per contributor, ``total`` and ``total_relative`` (the
        quadrature sums), the inputs as scalar variables and ``height`` as a scalar coordinate;
        with several heights, every variable has a trailing ``height`` dimension.
        Select with ``ds.uncertainty.sel(wind_speed=8, contributor="beam_angle")``.

    Examples
    --------
    >>> ds = uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS, beam_angle_coefficient=0.00248,
    ...                        paper_table4=True)
    >>> round(float(ds.uncertainty.sel(wind_speed=10, contributor="beam_angle")), 4)
    0.0248
    >>> at = uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "height": Q_([50.0, 100.0], "m")})
    >>> at.total.dims, round(float(at.uncertainty.sel(wind_speed=10, height=50)[-1]), 4)
    (('wind_speed', 'height'), 0.0159)
    """
    t = _table4(wind_speed, mean_between_run_std_std=mean_between_run_std_std,
                mean_between_run_std_bias=mean_between_run_std_bias, n_runs=n_runs,
                n_los_samples=n_los_samples, bench_uncertainty=bench_uncertainty,
                beam_angle_uncertainty=beam_angle_uncertainty,
                zero_distance_uncertainty=zero_distance_uncertainty,
                shear_exponent=shear_exponent, height=height, cone_angle=cone_angle,
                beam_angle_coefficient=beam_angle_coefficient, bias_repeatability_n=bias_repeatability_n,
                bench_coverage_factor=bench_coverage_factor, noise_terms=noise_terms,
                paper_table4=paper_table4, los_noise_std=los_noise_std, hybrid_weight=hybrid_weight)
    ws, heights, alphas, inputs, per_height = t.ws, t.heights, t.alphas, t.inputs, t.per_height
    n_bias = t.n_bias
    beam_angle_coefficient, paper_table4 = t.beam_angle_coefficient, t.paper_table4
    ds = _to_dataset(ws, per_height, heights, inputs)
    stacked = np.ndim(heights) == 1
    config = {**{k: (v if stacked else v[0]) if k == "shear_exponent" else v for k, v in inputs.items()},
              "height": heights.tolist() if stacked else heights, "wind_speed": ws,
              "bias_repeatability_n": bias_repeatability_n, "beam_angle_coefficient": beam_angle_coefficient,
              "noise_terms": noise_terms, "paper_table4": paper_table4}
    ds.attrs.update({
        "bias_repeatability_n": bias_repeatability_n,
        "eq7_sample_count": np.int32(n_bias) if noise_terms == "printed" else np.int32(1),
        "noise_terms": noise_terms,
        "beam_angle_method": "coefficient" if beam_angle_coefficient is not None else "cot(phi) dphi (Eq. 9)",
    })
    if stacked:
        where = (f"at each height z = {', '.join(f'{z:g}' for z in heights)} m, with that height's shear "
                 f"exponent (variable shear_exponent, {min(alphas):.4g} to {max(alphas):.4g}), ")
    else:
        where = f"at z = {heights:g} m, alpha = {alphas[0]:g}, phi = {inputs['cone_angle']:g} degree "
    summary = (
        f"Uncertainty terms of the horizontal wind speed not modelled by Monte Carlo (paper Eqs. 6-11, "
        f"Table 4) {where}for {ws.size} wind speeds; "
        f"total {float(ds.total.min()):.4f} to {float(ds.total.max()):.4f} m/s."
    )
    return stamp(ds, "uncertainty_terms", title="Non-simulated calibration uncertainty terms (Table 4)",
                 summary=summary, call=call,
                 input_datasets={"repeatability": repeatability} if repeatability is not None else None,
                 config=config, keywords="Doppler lidar, calibration, uncertainty budget, wind speed")


def _derived_inputs(noise_terms: str, los_noise_std: Any, hybrid_weight: Any) -> dict[str, float]:
    """Check ``noise_terms``; return σ (m s-1) and p of the derived Eq. 6 (empty for the printed form)."""
    if noise_terms not in NOISE_TERMS:
        raise InputError(f"argument 'noise_terms': expected one of {list(NOISE_TERMS)}; "
                         f"found {noise_terms!r}")
    if noise_terms == "printed":
        if los_noise_std is not None or hybrid_weight is not None:
            raise InputError("arguments 'los_noise_std' and 'hybrid_weight' only apply with "
                             "noise_terms='derived'")
        return {}
    sigma = DERIVED_DEFAULTS["los_noise_std"] if los_noise_std is None else los_noise_std
    p = DERIVED_DEFAULTS["hybrid_weight"] if hybrid_weight is None else hybrid_weight
    sigma = to_magnitude(sigma, "m s-1", name="los_noise_std")
    derived = {"los_noise_std": _positive(sigma, "los_noise_std", "m s-1"), "hybrid_weight": float(p)}
    if not 0.0 <= derived["hybrid_weight"] <= 1.0:
        raise InputError(f"argument 'hybrid_weight': expected a value in [0, 1]; found {p}")
    return derived


def _checked_wind_speeds(wind_speed: Any) -> np.ndarray:
    """Wind speeds in m s-1 as a 1-D array of distinct positive finite values."""
    ws = np.atleast_1d(np.asarray(to_magnitude(wind_speed, "m s-1", name="wind_speed"), dtype=float))
    if ws.ndim != 1 or ws.size == 0 or not np.all(np.isfinite(ws)) or np.any(ws <= 0):
        raise InputError(f"argument 'wind_speed': expected a 1-D array of positive finite speeds; found {ws}")
    if len(np.unique(ws)) != ws.size:
        raise InputError(f"argument 'wind_speed': expected distinct speeds; found duplicates in {ws}")
    return ws


def _checked_heights(height: Any, shear_exponent: Any) -> tuple[Any, list[float]]:
    """Height(s) z in m (a float, or a 1-D array of distinct heights) and the shear exponent of each.

    ``shear_exponent`` is one exponent for every height or one per height.
    """
    z = np.asarray(to_magnitude(height, "m", name="height"), dtype=float)
    if z.ndim > 1 or z.size == 0:
        raise InputError(f"argument 'height': expected a height or a 1-D array of heights; found {z}")
    for value in np.atleast_1d(z):
        _positive(value, "height", "m", allow_zero=False)
    if z.ndim == 1 and len(np.unique(z)) != z.size:
        raise InputError(f"argument 'height': expected distinct heights; found duplicates in {z}")
    alpha = np.asarray(to_magnitude(shear_exponent, "1", name="shear_exponent"), dtype=float)
    if alpha.ndim == 0:
        alpha = np.full(z.size, float(alpha))
    if alpha.shape != (z.size,):
        raise InputError(f"argument 'shear_exponent': expected one exponent or one per height ({z.size}); "
                         f"found {alpha.tolist()}")
    if not np.all(np.isfinite(alpha)):
        raise InputError(f"argument 'shear_exponent': expected a finite exponent; found {alpha.tolist()}")
    return (z if z.ndim == 1 else float(z)), [float(a) for a in alpha]


def _checked_inputs(**given: Any) -> dict[str, Any]:
    """Check Table 4's inputs other than height and shear; return them as floats (counts as ``int``)."""
    out: dict[str, Any] = {}
    for name, unit in (("mean_between_run_std_std", "m s-1"), ("mean_between_run_std_bias", "m s-1"),
                       ("bench_uncertainty", "m s-1"), ("beam_angle_uncertainty", "degree"),
                       ("zero_distance_uncertainty", "m")):
        out[name] = _positive(to_magnitude(given[name], unit, name=name), name, unit)
    phi = float(to_magnitude(given["cone_angle"], "degree", name="cone_angle"))
    if not 0 < phi < 90:
        raise InputError(
            f"argument 'cone_angle': expected an angle from vertical in (0, 90) degree; found {phi:g}")
    out["cone_angle"] = phi
    out["bench_coverage_factor"] = _positive(given["bench_coverage_factor"], "bench_coverage_factor", "",
                                             allow_zero=False)
    for name in ("n_runs", "n_los_samples"):
        value = given[name]
        if not float(value) >= 1 or float(value) != int(value):
            raise InputError(f"argument {name!r}: expected a whole number >= 1; found {value}")
        out[name] = int(value)
    return out


def _to_dataset(ws: np.ndarray, per_height: list[np.ndarray], heights: Any,
                inputs: Mapping[str, Any]) -> xr.Dataset:
    """Assemble the terms of each height and the inputs, with the attributes of their schema.

    With 1-D ``heights`` every variable stacks the heights on a trailing ``height`` dim.
    """
    stacked = np.ndim(heights) == 1
    values: dict[str, list[np.ndarray]] = {"uncertainty": [], "relative_uncertainty": [], "total": [],
                                           "total_relative": []}
    for terms in per_height:
        total = _total(terms)
        values["uncertainty"].append(terms)
        values["relative_uncertainty"].append(100.0 * terms / ws[:, None])
        values["total"].append(total)
        values["total_relative"].append(100.0 * total / ws)
    wc, tail = ("wind_speed", "contributor"), ("height",) if stacked else ()
    dims = {"uncertainty": wc, "relative_uncertainty": wc, "total": wc[:1], "total_relative": wc[:1]}
    data = {name: (dims[name] + tail, np.stack(parts, axis=-1) if stacked else parts[0])
            for name, parts in values.items()}
    for name, value in inputs.items():
        dtype = np.int32 if name in ("n_runs", "n_los_samples") else float
        per = value if name == "shear_exponent" else [value] * len(per_height)
        data[name] = (tail, np.asarray(per if stacked else per[0], dtype=dtype))
    rows = list(CONTRIBUTORS)
    ds = xr.Dataset(data, coords={
        "wind_speed": ("wind_speed", ws),
        "contributor": ("contributor", np.array(rows, dtype=object)),
        "equation": ("contributor", np.array([CONTRIBUTORS[n][0] for n in rows], dtype=object)),
        "contributor_description": ("contributor",
                                    np.array([CONTRIBUTORS[n][1] for n in rows], dtype=object)),
        "height": (tail, heights),
    })
    return with_output_attrs(ds, "uncertainty_terms")


def repeatability_inputs(source: str | os.PathLike | xr.Dataset) -> tuple[dict[str, Any], xr.Dataset]:
    """Read s-bar_s, s-bar_delta and the run count from a ``repeatability`` artefact.

    Returns the keyword arguments (pint quantities / int) for :func:`uncertainty_terms` and
    the opened dataset (for provenance).
    """
    ds = source if isinstance(source, xr.Dataset) else open_artefact(source, "repeatability")
    where = "<repeatability dataset>" if isinstance(source, xr.Dataset) else str(source)
    out: dict[str, Any] = {}
    for name in ("mean_between_run_std_std", "mean_between_run_std_bias"):
        da = convert_variable(ds, name, "m s-1", source=where)
        if da.ndim != 0:
            raise InputError(f"{where}: variable {name!r} has dims {da.dims}; expected a scalar")
        out[name] = Q_(float(da), "m/s")
    n = convert_variable(ds, "n_runs", "1", source=where)
    if n.ndim != 0 or not float(n) >= 1:
        raise InputError(f"{where}: variable 'n_runs' is {n.values!r}; expected a scalar count >= 1")
    out["n_runs"] = int(n)
    return out, ds


def format_table(ds: xr.Dataset, digits: int = 4) -> str:
    """Human-readable Table 4 (rows: contributors and totals; columns: wind speeds)."""
    ws = ds.wind_speed.values
    head = f"{'term':<26}{'Eq.':>4}  " + "".join(f"{f'U={u:g}':>9}" for u in ws)
    lines = [
        f"Non-simulated uncertainty terms (m/s) at z = {float(ds.height):g} m, "
        f"alpha = {float(ds.shear_exponent):g}, phi = {float(ds.cone_angle):g} degree",
        f"Eq. 8: dv_SAFO / {float(ds.bench_coverage_factor):g}; Eq. 11: height error "
        f"{float(ds.get('zero_distance_projection', 1.0)):.4g} x dz",
        head, "-" * len(head),
    ]
    for name in ds.contributor.values:
        row = ds.uncertainty.sel(contributor=name).values
        eq = str(ds.equation.sel(contributor=name).values)
        lines.append(f"{name:<26}{eq:>4}  " + "".join(f"{v:>9.{digits}f}" for v in row))
    lines.append("-" * len(head))
    lines.append(f"{'Total (m/s)':<30}" + "".join(f"{v:>9.{digits}f}" for v in ds.total.values))
    lines.append(f"{'Total (%)':<30}" + "".join(f"{v:>8.2f}%" for v in ds.total_relative.values))
    return "\n".join(lines)
