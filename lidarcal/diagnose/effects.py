"""The catalogue of model effects that ``lidarcal diagnose`` can name, fit and add.

The catalogue is data: :data:`EFFECTS` maps each catalogue id of ``docs/diagnose.md`` to a small
frozen :class:`Effect` that states

- its parameters (name, unit, physical bounds, the ``LidarModel`` field each one sets, and the
  probe step used to measure the model's response to it),
- the environmental drivers it acts through (``conditions`` variables; the per-height response
  is smoothed on these, see :mod:`lidarcal.diagnose.fit`),
- how it modifies a model, ``effect.apply(model, params)`` → a new ``LidarModel`` made with
  :func:`dataclasses.replace` (models are frozen), and
- optionally an *exact shortcut*: when an effect acts only after the turbulence has been
  sampled (the hybrid weight p only re-weights the scalar and vector reconstructions the
  simulator already returns; the reference over-speeding only scales the virtual reference),
  the records of the modified model follow exactly from the baseline records, so no
  re-simulation is needed.  ``tests/test_diagnose.py``
  (``test_exact_shortcuts_equal_a_full_resimulation``) checks each shortcut against a full
  re-simulation.

Each entry states its expected first-order signature (``Effect.signature``, cone angle φ from
vertical, relative to the reference); ``docs/diagnose.md``'s catalogue table is
:func:`catalogue_table` (``tests/test_diagnose.py`` checks that the page shows it), and the
``fit_*`` variables of ``schemas/diagnosis.yaml`` are expanded from :func:`schema_rows`, which
this module registers with the schema loader: a new effect is one entry here (and its model
field and physics), nothing else.

**Grid parameters.** Some parameters enter non-linearly and the response is not smooth in them
(the sector's ``centre`` and ``width``).  Such a parameter declares a ``grid`` of candidate
values: a fitter scans :meth:`Effect.grid_points` and, at each point, fits the remaining
(*linear*) parameters from a probe :meth:`Effect.probe` ``(model, at=point)``; the best point is
the estimate, and the penalty of the BIC counts every parameter, grid ones included.  Without
``at``, :meth:`Effect.probe` keeps grid parameters at their nominal values (for the mast
shadow: width 0, i.e. no response), so a fitter that knows nothing of grids sees no signal
rather than a wrong one.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lidarcal.errors import InputError
from lidarcal.lidar.model import direction_spread, flow_distortion_factor
from lidarcal.schema import register_catalogue

__all__ = ["Parameter", "Effect", "EFFECTS", "DERIVED_FORM", "DERIVED_FORM_SOURCE", "get_effect",
           "model_form_share", "realistic_strengths", "schema_rows", "catalogue_table"]

#: Records are dicts of arrays over (time, height) with the simulated_rtd names.
Records = Mapping[str, np.ndarray]


@dataclass(frozen=True)
class Parameter:
    """One fitted parameter of an effect.

    Attributes
    ----------
    name : str
        Name in the ``--json`` output (``docs/diagnose.md``), e.g. ``"offset"``.
    units : str
        UDUNITS spelling (``m``, ``degree``, ``1``).
    bounds : tuple of float
        The parameter's *physical range*, declared once here: the values the physics (or the
        instrument's definition) allows.  Where physics gives the parameter a sign, the range
        says so (a cup over-speeds in turbulence: its coefficient is ≥ 0).  The fitted values
        of ``schemas/diagnosis.yaml`` carry this range (expanded from :func:`schema_rows`).  A
        fit at a bound within its uncertainty is named at the bound; one that wants to go beyond
        it by more than its uncertainty is out of range (``docs/diagnose.md``).
    model_field : str
        The ``LidarModel`` field this parameter sets (absolute value, not an increment).
    step : float
        Probe step: the response is measured at ``nominal + step`` (``nominal − step`` if that
        leaves the bounds).
    long_name : str
        Human-readable description.
    grid : tuple of float, optional
        Candidate values of a non-linear parameter (see module docstring); ``None`` for a
        parameter fitted by linearisation.
    basis : str
        Why the physical range is what it is (quoted in the diagnosis note when a fit reaches a
        bound or wants to go beyond it).
    realistic : float
        A realistic strength, within the bounds: the value ``lidarcal diagnose-generate`` hides
        by default (:func:`realistic_strengths`).
    """

    name: str
    units: str
    bounds: tuple[float, float]
    model_field: str
    step: float
    long_name: str
    grid: tuple[float, ...] | None = None
    basis: str = ""
    realistic: float | None = None

    @property
    def sign(self) -> int:
        """+1 (−1) when the physical range admits only non-negative (non-positive) values, else 0."""
        lo, hi = self.bounds
        return 1 if lo >= 0.0 else (-1 if hi <= 0.0 else 0)

    def describe_range(self) -> str:
        """Return the physical range in words, e.g. ``"[0, 0.5] (a cup over-speeds in turbulence ...)"``."""
        lo, hi = self.bounds
        unit = "" if self.units == "1" else f" {self.units}"
        return f"[{lo:g}, {hi:g}]{unit}" + (f" ({self.basis})" if self.basis else "")


def _hybrid_shortcut(records: Records, conditions: Records, nominal: Mapping[str, float],
                     params: Mapping[str, float]) -> dict[str, np.ndarray]:
    """Return the records with hybrid weight p: V = p·V_scalar + (1 − p)·V_vector (same turbulence)."""
    p = float(params["p"])
    lidar = p * records["lidar_wind_speed_scalar"] + (1.0 - p) * records["lidar_wind_speed_vector"]
    return {"lidar_wind_speed": lidar, "reference_wind_speed": records["reference_wind_speed"]}


def _overspeeding_shortcut(records: Records, conditions: Records, nominal: Mapping[str, float],
                           params: Mapping[str, float]) -> dict[str, np.ndarray]:
    """Return the records with reference over-speeding c: reference × (1 + c·TI) / (1 + c₀·TI)."""
    ti = np.asarray(conditions["turbulence_intensity"], dtype=float)
    scale = (1.0 + float(params["coefficient"]) * ti) / (1.0 + float(nominal["coefficient"]) * ti)
    return {"lidar_wind_speed": records["lidar_wind_speed"],
            "reference_wind_speed": records["reference_wind_speed"] * scale}


def _ratio_shortcut(factor: Callable[..., np.ndarray | float]):
    """Shortcut of a reference effect: reference × factor(params) / factor(nominal) (exact)."""

    def shortcut(records: Records, conditions: Records, nominal: Mapping[str, float],
                 params: Mapping[str, float]) -> dict[str, np.ndarray]:
        scale = factor(conditions, params) / factor(conditions, nominal)
        return {"lidar_wind_speed": records["lidar_wind_speed"],
                "reference_wind_speed": records["reference_wind_speed"] * scale}

    return shortcut


def _gain_factor(conditions: Records, params: Mapping[str, float]) -> float:
    return 1.0 + float(params["gain"])


def _shadow_factor(conditions: Records, params: Mapping[str, float]) -> np.ndarray:
    return flow_distortion_factor(np.asarray(conditions["wind_from_direction"], dtype=float),
                                  float(params["centre"]), float(params["width"]), float(params["deficit"]),
                                  direction_spread(conditions["turbulence_intensity"]))


@dataclass(frozen=True)
class Effect:
    """A catalogue entry: a way the nominal model can be wrong, with its parameters."""

    id: str
    description: str
    parameters: tuple[Parameter, ...]
    drivers: tuple[str, ...]
    signature: str
    shortcut: Callable[[Records, Records, Mapping[str, float], Mapping[str, float]],
                       dict[str, np.ndarray]] | None = field(default=None, compare=False)
    #: Model-form standard uncertainty of the response, as a share of the fitted change, when it is
    #: known to be larger than the diagnosis' ``model_uncertainty`` (``None``: that one applies).
    #: Read only through :func:`model_form_share`.
    model_form: float | None = None
    #: (share, its Monte Carlo standard error) derived from the engine's model-form alternatives:
    #: the relative spread of the effect's change of (L − R)/R across them
    #: (:mod:`lidarcal.diagnose.model_form`, :data:`DERIVED_FORM_SOURCE`).  Read only through
    #: :func:`model_form_share`.
    derived_form: tuple[float, float] | None = None

    @property
    def n_parameters(self) -> int:
        """Number of fitted parameters (the BIC penalty counts these)."""
        return len(self.parameters)

    def nominal(self, model: Any) -> dict[str, float]:
        """Return the parameter values the nominal ``model`` already has (the null hypothesis)."""
        return {p.name: float(getattr(model, p.model_field)) for p in self.parameters}

    def apply(self, model: Any, params: Mapping[str, float]) -> Any:
        """Return a copy of the frozen ``model`` with this effect at ``params``.

        Raises
        ------
        InputError
            If a parameter is missing, unknown or outside its bounds.
        """
        names = {p.name for p in self.parameters}
        unknown = set(params) - names
        if unknown:
            raise InputError(f"effect {self.id!r}: unknown parameter(s) {sorted(unknown)}; "
                             f"expected {sorted(names)}")
        changes = {}
        for p in self.parameters:
            if p.name not in params:
                raise InputError(f"effect {self.id!r}: parameter {p.name!r} is missing")
            value = float(params[p.name])
            lo, hi = p.bounds
            if not lo <= value <= hi:
                raise InputError(f"effect {self.id!r}: parameter {p.name!r} = {value:g} {p.units} "
                                 f"is outside its bounds [{lo:g}, {hi:g}]"
                                 + (f", its physical range ({p.basis})" if p.basis else ""))
            changes[p.model_field] = value
        return dataclasses.replace(model, **changes) if changes else model

    @property
    def linear_parameters(self) -> tuple[Parameter, ...]:
        """Parameters fitted by linearisation (those without a ``grid``)."""
        return tuple(p for p in self.parameters if p.grid is None)

    @property
    def grid_parameters(self) -> tuple[Parameter, ...]:
        """Non-linear parameters scanned over their ``grid`` (see module docstring)."""
        return tuple(p for p in self.parameters if p.grid is not None)

    def grid_points(self) -> list[dict[str, float]]:
        """Every combination of the grid parameters' values (``[{}]`` for a fully linear effect)."""
        points: list[dict[str, float]] = [{}]
        for p in self.grid_parameters:
            points = [{**pt, p.name: float(v)} for pt in points for v in p.grid]
        return points

    def probe(self, model: Any, at: Mapping[str, float] | None = None) -> dict[str, float]:
        """Parameter values at which the model's response is measured.

        Linear parameters: nominal + step (nominal − step if that leaves the bounds).  Grid
        parameters: their value in ``at`` (a :meth:`grid_points` entry), else nominal.
        """
        at = dict(at or {})
        out = {}
        for p in self.parameters:
            base = float(getattr(model, p.model_field))
            if p.grid is not None:
                out[p.name] = float(at.get(p.name, base))
                continue
            value = base + p.step
            out[p.name] = value if p.bounds[0] <= value <= p.bounds[1] else base - p.step
        return out


_CONE = "cone angle φ from vertical"

#: Where ``Effect.derived_form`` comes from (quoted in ``docs/diagnose.md``).
DERIVED_FORM_SOURCE = (
    "benchmarks/diagnose_form_shares.py --periods 150: lidarcal.diagnose.model_form.derived_shares on "
    "hidden_effect_conditions(150, (40, 80, 120, 160 m), seed 501, I_ref 0.10) and (seed 502, I_ref 0.16), "
    "base seed 2611, each effect at its realistic strength, for the lidar of the field file's attributes "
    "(alternatives reference_level, coherence, length_scale) and the same with the bench RWF artefact "
    "(and rwf_shape); the largest share over the four, with its Monte Carlo standard error"
)
#: Each effect's model-form share derived from the alternatives and its Monte Carlo standard
#: error, as recorded from :data:`DERIVED_FORM_SOURCE` (``tests/data/diagnose_form_shares.json``).
DERIVED_FORM: dict[str, tuple[float, float]] = {
    "zero_distance_offset": (0.0024, 0.0003),
    "beam_angle_offset": (0.0007, 0.0001),
    "cnr_gradient_weighting": (0.0029, 0.0004),
    "hybrid_weight": (0.187, 0.0045),
    "reference_overspeeding": (0.0013, 0.0001),
    "reference_gain": (0.0009, 0.0),
    "reference_flow_distortion": (0.001, 0.0002),
}

EFFECTS: dict[str, Effect] = {
    "none": Effect(
        id="none",
        description="No significant disagreement between the nominal model and the field records.",
        parameters=(),
        drivers=(),
        signature="residual consistent with zero in every height and environmental bin",
    ),
    "zero_distance_offset": Effect(
        id="zero_distance_offset",
        description="Every range gate sits `offset` metres further out along its beam than nominal "
                    "(a zero-distance Zd error); the measurement height moves up by offset·cos φ.",
        parameters=(Parameter("offset", "m", (-30.0, 30.0), "zero_distance_offset", 4.0,
                              "range-gate offset along the beam (positive away from the lidar)",
                              basis="either sign; +-30 m bounds a plausible zero-distance error",
                              realistic=4.0),),  # m, a Zd error of 3-5 m
        drivers=("wind_shear_exponent",),
        signature=f"relative bias ≈ +α·offset·cos φ / h ({_CONE}): grows with shear, falls with height",
        derived_form=DERIVED_FORM["zero_distance_offset"],
    ),
    "beam_angle_offset": Effect(
        id="beam_angle_offset",
        description="The oblique beams' true cone angle is nominal + `offset` degrees while the "
                    "reconstruction uses the nominal angle.",
        parameters=(Parameter("offset", "degree", (-3.0, 3.0), "beam_angle_offset", 0.5,
                              "true minus nominal cone angle of the oblique beams",
                              basis="either sign; +-3 degree bounds a plausible prism or mounting "
                                    "error", realistic=0.5),),
        drivers=("wind_shear_exponent",),
        signature=f"relative bias ≈ +cot φ·δφ − α·tan φ·δφ ({_CONE}, δφ in rad): nearly constant",
        derived_form=DERIVED_FORM["beam_angle_offset"],
    ),
    "cnr_gradient_weighting": Effect(
        id="cnr_gradient_weighting",
        description="The range-weighting function is CNR-weighted as in Eq. 2 "
                    "(`scale` = 1 is Eq. 2 as written, 0 is no weighting).",
        parameters=(Parameter("scale", "1", (0.0, 5.0), "cnr_weighting_scale", 1.0,
                              "multiplier of the CNR gradient in the Eq. 2 weighting",
                              basis="0 is no weighting; a negative scale would weight the RWF "
                                    "against the CNR", realistic=1.0),),  # Eq. 2 as written
        drivers=("wind_shear_exponent", "cnr_gradient"),
        signature="relative bias ≈ α·cos φ·σ_r²·(ln10/20)·scale·g / h: sign follows shear × CNR gradient",
        derived_form=DERIVED_FORM["cnr_gradient_weighting"],
    ),
    "hybrid_weight": Effect(
        id="hybrid_weight",
        description="The firmware's hybrid weight p (V = p·V_scalar + (1−p)·V_vector) differs from "
                    "the nominal one.",
        parameters=(Parameter("p", "1", (0.0, 1.0), "hybrid_weight", -1.0 / 6.0,
                              "weight of the scalar-averaged speed in the hybrid reconstruction",
                              basis="a weight: 0 is pure vector, 1 pure scalar averaging, both "
                                    "legitimate firmware settings",
                              realistic=0.5),),  # WindCube XP firmware vs nominal 2/3
        drivers=("turbulence_intensity",),
        signature="relative bias ≈ (p − p₀)·(V_scalar − V_vector)/V_ref, growing with TI²",
        shortcut=_hybrid_shortcut,
        # V_scalar − V_vector is a second-order statistic of the reconstructed wind: it follows
        # the turbulence level of the field, of which the cup's 10-minute TI is a noisy estimate,
        # so against the measured TI the true response is flatter than the engine's and a
        # TI-proportional over-speeding cup can fit it slightly better.  Fitted on the converged
        # independent simulator's fit set (tests/hybrid_share_fit.py, seeds 101-103; disjoint from
        # the campaigns the tests assert on): the error of the fitted change needs 6.9 % beyond
        # the bootstrap, the look-alike cup explains up to 3.6 % more of the residual, which a
        # share of 9.7 % covers at 95 % (docs/diagnose.md, "Model-form share of the hybrid
        # weight").  The 25 % this entry carried before had been set on the tests' own campaigns
        # of the 3-point test simulator, whose hybrid response was 20 % too large.  The share
        # derived from the engine's alternatives (DERIVED_FORM) is larger — IEC Ed. 2's shorter
        # coherence shrinks the response by about 29 %, a range the independent simulator (Ed. 3
        # coherence, like the nominal) cannot see — so it is the one model_form_share uses.
        model_form=0.10,
        derived_form=DERIVED_FORM["hybrid_weight"],
    ),
    "reference_overspeeding": Effect(
        id="reference_overspeeding",
        description="The reference cup over-reads in proportion to turbulence intensity.",
        parameters=(Parameter("coefficient", "1", (0.0, 0.5), "reference_overspeeding", 0.05,
                              "relative over-reading of the reference per unit turbulence intensity",
                              basis="a cup over-speeds in turbulence (it speeds up faster than it "
                                    "slows down), it never under-reads: coefficient >= 0",
                              realistic=0.08),),  # per unit TI
        drivers=("turbulence_intensity",),
        signature="relative bias ≈ −coefficient·TI",
        shortcut=_overspeeding_shortcut,
        derived_form=DERIVED_FORM["reference_overspeeding"],
    ),
    "reference_gain": Effect(
        id="reference_gain",
        description="The reference cup's calibration factor is off by a constant fraction: it reads "
                    "(1 + gain) × the true speed.",
        parameters=(Parameter("gain", "1", (-0.2, 0.2), "reference_gain", 0.01,
                              "relative error of the reference's calibration factor",
                              basis="either sign; +-20 % bounds a plausible calibration error",
                              realistic=0.01),),  # a cup calibration factor 1 % off
        drivers=(),
        signature="relative bias ≈ −gain/(1 + gain): constant over heights and conditions",
        shortcut=_ratio_shortcut(_gain_factor),
        derived_form=DERIVED_FORM["reference_gain"],
    ),
    "reference_flow_distortion": Effect(
        id="reference_flow_distortion",
        description="The mast shadows the reference cup for winds from a sector: every sample whose "
                    "direction lies within `width`/2 of `centre` reads (1 − `deficit`) × the true speed; "
                    "a period's mean is shadowed by the fraction of its samples in the sector (a "
                    "Gaussian spread of 0.8·TI rad about the mean direction: a smooth edge).",
        parameters=(
            Parameter("centre", "degree", (0.0, 360.0), "reference_flow_distortion_centre", 10.0,
                      "direction (from) at the centre of the shadowed sector",
                      grid=tuple(float(c) for c in range(0, 360, 10)),
                      basis="a direction: the whole compass", realistic=250.0),
            Parameter("width", "degree", (0.0, 180.0), "reference_flow_distortion_width", 10.0,
                      "full width of the shadowed sector", grid=(20.0, 40.0, 60.0, 90.0, 120.0),
                      basis="a mast shadows at most half the compass", realistic=60.0),
            Parameter("deficit", "1", (-0.5, 0.5), "reference_flow_distortion_deficit", 0.02,
                      "relative under-reading of the reference inside the sector",
                      basis="either sign: a mast's wake slows the flow (> 0), the flow around "
                            "its sides speeds up (< 0)", realistic=0.04),
        ),
        drivers=("wind_from_direction",),
        signature="relative bias ≈ +deficit/(1 − deficit) inside the sector centre ± width/2, 0 outside",
        shortcut=_ratio_shortcut(_shadow_factor),
        derived_form=DERIVED_FORM["reference_flow_distortion"],
    ),
}


def model_form_share(effect: Effect, default: float) -> float:
    """Model-form standard uncertainty of ``effect``'s fitted change, as a share of that change.

    The one place the share is obtained (the bootstrap's interval, the range verdict and the tie
    rule all read it from here): the largest of the diagnosis' ``default``
    (``--model-uncertainty``), the share derived from the engine's own model-form alternatives
    (``Effect.derived_form``) and the share fitted on independent campaigns where one exists
    (``Effect.model_form``, with its recorded fit/assert split).  They are three estimates of the
    same uncertainty from different evidence, not independent errors to add: an independent
    simulator's turbulence is itself one point of the range the alternatives span
    (``docs/diagnose.md``).
    """
    shares = [float(default)]
    if effect.derived_form is not None:
        shares.append(float(effect.derived_form[0]))
    if effect.model_form is not None:
        shares.append(float(effect.model_form))
    return max(shares)


def get_effect(effect_id: str) -> Effect:
    """Look up a catalogue entry, naming the valid ids when ``effect_id`` is unknown."""
    try:
        return EFFECTS[effect_id]
    except KeyError:
        raise InputError(f"unknown effect {effect_id!r}; catalogue ids: {', '.join(EFFECTS)}") from None


def realistic_strengths() -> dict[str, dict[str, float]]:
    """Realistic strength of every effect's parameters (``Parameter.realistic``), by catalogue id."""
    return {e.id: {p.name: float(p.realistic) for p in e.parameters} for e in EFFECTS.values()}


def schema_rows() -> list[dict[str, Any]]:
    """One row per parameter of every effect: what ``schemas/diagnosis.yaml`` expands its ``fit_*`` over.

    ``effect`` the catalogue id, ``name`` the parameter's name, ``parameter`` its long name,
    ``units`` its unit and ``range`` its physical range (``Parameter.bounds``).
    """
    return [{"effect": e.id, "name": p.name, "parameter": p.long_name, "units": p.units,
             "range": [float(p.bounds[0]), float(p.bounds[1])]}
            for e in EFFECTS.values() for p in e.parameters]


register_catalogue("diagnose_effect_parameters", schema_rows())


def _number(x: float) -> str:
    return f"{x:g}".replace("-", "−")


def _share_cell(e: Effect) -> str:
    """Return the model-form shares an effect records: derived (± its Monte Carlo error), fitted."""
    parts = []
    if e.derived_form is not None:
        parts.append(f"derived {e.derived_form[0]:.3f} ± {e.derived_form[1]:.3f}")
    if e.model_form is not None:
        parts.append(f"fitted {e.model_form:g}")
    return "; ".join(parts) or "—"


def catalogue_table() -> str:
    """Return the catalogue as the Markdown table of ``docs/diagnose.md`` (``none`` last).

    Columns: the id; each parameter's name, unit, physical range and the ``LidarModel`` field it
    sets; what is wrong (the description); the drivers and the expected signature; the
    model-form shares the effect records (``derived_form`` with its Monte Carlo standard error,
    ``model_form`` where fitted on independent campaigns; :func:`model_form_share` uses the
    largest of them and ``--model-uncertainty``).
    """
    def params(e: Effect) -> str:
        return ", ".join(f"`{p.name}` ({p.units}, [{_number(p.bounds[0])}, {_number(p.bounds[1])}]; "
                         f"sets `{p.model_field}`)" for p in e.parameters) or "—"

    rows = ["| id | parameters | what is wrong | acts through | model-form share |", "|---|---|---|---|---|"]
    for e in sorted(EFFECTS.values(), key=lambda e: e.id == "none"):
        drivers = ", ".join(f"`{d}`" for d in e.drivers) or "no driver"
        rows.append(f"| `{e.id}` | {params(e)} | {e.description} | {drivers}: {e.signature} "
                    f"| {_share_cell(e)} |")
    return "\n".join(rows)
