"""The virtual DBS lidar's configuration: :class:`LidarModel`.

A :class:`LidarModel` is a frozen, JSON-serialisable dataclass holding everything the virtual
lidar needs: the beam geometry, the beam period, the hybrid weight, the RWF as K quadrature
nodes, the LOS noise (ideal Gaussian, or a bench ``ℓcv`` table: good residuals resampled with
bad estimates at the CNR's fitted rate, every residual resampled, or Gaussian from its bias and
std, ``los_noise_model``), the CNR filter, the availability, and the
effects the ``diagnose`` stage can switch on (``zero_distance_offset``, ``beam_angle_offset``,
``cnr_weighting_scale``, ``hybrid_weight``, ``reference_overspeeding``, ``reference_gain``,
``reference_flow_distortion_*``).

Conventions
-----------
* Azimuths are clockwise from the lidar's north mark (degree); the cone angle is measured
  from the vertical (degree, 28° for a WindCube: elevation 62°).
* Radial velocities are positive *away from* the lidar (as the bench cube's ``velocity`` and
  the RWF's ``range_offset``).
* ``hybrid_weight`` p multiplies the *scalar* average: V = p V_scalar + (1 - p) V_vector
  (WindCube v2.1: p = 2/3; WindCube XP: p = 1/2; see :mod:`lidarcal.lidar.wfr`).  Eq. 5 does
  not say which average p belongs to; ``hybrid_convention = "vector"`` records the other
  reading, V = p V_vector + (1 - p) V_scalar (about 0.3 % lower at TI 0.2 for p = 2/3).
"""

from __future__ import annotations

import dataclasses
import json
import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import source_name
from lidarcal.lidar.attributes import LIDAR_ATTRIBUTES, LIDAR_DEFAULTS, lidar_attributes, lidar_cnr_threshold
from lidarcal.lidar.bad_estimates import BadEstimates
from lidarcal.lidar.noise import (
    LOS_NOISE_MODELS,
    NoiseTable,
    cube_residuals,
    fit_bad_estimates,
    listify,
    noise_table_from_cube,
    residuals_digest,
    tuplify,
)
from lidarcal.lidar.quadrature import gauss_hermite_rwf
from lidarcal.lidar.rwf_profile import RwfProfileDigest, rwf_nodes, rwf_profile_digest
from lidarcal.lidar.synthesis import REFERENCE_TURBULENCE
from lidarcal.turbulence.kernels import COHERENCE_DECAY, L_C, LAMBDA_1, SIGMA_RATIOS

__all__ = ["LidarModel", "DEFAULT_CNR_THRESHOLD", "flow_distortion_factor", "direction_spread",
           "RwfProfileDigest",
           "rwf_profile_digest", "REFERENCE_TURBULENCE", "fit_bad_estimates", "lidar_cnr_threshold",
           "LIDAR_ATTRIBUTES", "lidar_attributes"]

log = logging.getLogger(__name__)

#: Records written before ``reference_turbulence`` existed carried ``turbulence_amplitudes``: its
#: words, read as the one vocabulary (:data:`lidarcal.lidar.synthesis.REFERENCE_TURBULENCE`) here only.
_LEGACY_AMPLITUDES = {"deterministic": "pinned_uvw", "rayleigh": "free"}

#: Readings of Eq. 5's p: the average it multiplies (see :func:`lidarcal.lidar.wfr.hybrid_speed`).
HYBRID_CONVENTIONS = ("scalar", "vector")

#: Full width at half maximum (m) of the ideal lidar's Gaussian RWF (``schemas/conditions.yaml``).
DEFAULT_RWF_FWHM = LIDAR_DEFAULTS["lidar_rwf_fwhm"]
#: Gauss quadrature nodes per beam.
DEFAULT_RWF_NODES = 5

#: CNR filter (dB) of a bench-calibrated lidar: WindCube-type profilers discard LOS estimates
#: below about -23 dB by default.
DEFAULT_CNR_THRESHOLD = -23.0


@dataclasses.dataclass(frozen=True)
class LidarModel:
    """Configuration of the virtual DBS lidar (see module docstring for conventions)."""

    #: nominal cone angle from vertical (degree); this and the other ``lidar_*`` defaults are declared
    #: in ``schemas/conditions.yaml`` (:data:`~lidarcal.lidar.attributes.LIDAR_DEFAULTS`)
    cone_angle: float = LIDAR_DEFAULTS["lidar_cone_angle"]
    azimuths: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)  #: beam azimuths (degree)
    beam_period: float = LIDAR_DEFAULTS["lidar_beam_period"]  #: seconds per LOS (vertical beam ignored)
    hybrid_weight: float = LIDAR_DEFAULTS["lidar_hybrid_weight"]  #: p: V = p V_scalar + (1 - p) V_vector
    hybrid_convention: str = "scalar"  #: which Eq. 5 average p multiplies: "scalar" or "vector"
    rwf_offsets: tuple[float, ...] = tuple(gauss_hermite_rwf(DEFAULT_RWF_FWHM, DEFAULT_RWF_NODES)[0].tolist())
    rwf_weights: tuple[float, ...] = tuple(gauss_hermite_rwf(DEFAULT_RWF_FWHM, DEFAULT_RWF_NODES)[1].tolist())
    #: ideal Gaussian LOS noise (m s-1), used when no table
    los_noise_std: float = LIDAR_DEFAULTS["lidar_los_noise_std"]
    noise_table: NoiseTable | None = None  #: bench cube (overrides ``los_noise_std``)
    availability: float = 1.0  #: probability that a LOS sample is kept
    cnr_threshold: float | None = None  #: CNR filter (dB): periods below it are unavailable
    zero_distance_offset: float = 0.0  #: gates sit this far (m) beyond nominal along the beam
    beam_angle_offset: float = 0.0  #: true cone = cone_angle + offset (degree)
    cnr_weighting_scale: float = 0.0  #: 0 = no CNR weighting, 1 = Eq. 2 as written
    reference_overspeeding: float = 0.0  #: reference over-reading per unit TI
    reference_gain: float = 0.0  #: the reference reads (1 + gain) x the true speed
    reference_flow_distortion_centre: float = 0.0  #: centre of the mast-shadow sector (degree, from)
    reference_flow_distortion_width: float = 0.0  #: full width of that sector (degree; 0 = no shadow)
    reference_flow_distortion_deficit: float = 0.0  #: the reference under-reads by this fraction inside it
    #: what the virtual reference's turbulence is conditioned on (``docs/validation.md``):
    #: ``"pinned_u"`` its realised 10-min σ_u is the period's TI·U (the measured value), everything
    #: else follows PyConTurb's point-level convention through the continuous RWF (Gaussian LOS
    #: coefficients); ``"pinned_uvw"`` the engine before this field existed (σ_u and σ_v pinned, six
    #: fixed-amplitude signals; records without this field mean it); ``"free"`` a Gaussian process;
    #: ``"inferred_level"`` σ_u pinned as well, but the field's level is unknown given it (scales with it)
    reference_turbulence: str = "pinned_u"
    #: LOS error of a bench-calibrated lidar: ``"mixture"`` a bad estimate with probability
    #: p_bad(CNR) (``bad_estimates``), otherwise one of the bench bin's good residuals;
    #: ``"residuals"`` resamples every residual of the bin (bad estimates included: the model of runs
    #: before the mixture existed); ``"gaussian"`` draws N(los_bias, los_std) (MAD-trimmed);
    #: :meth:`from_artefacts` picks ``"mixture"`` when the cube has residuals.  The ideal lidar is
    #: Gaussian (``los_noise_std``) whatever this says.
    los_noise_model: str = "gaussian"
    #: the ``"mixture"`` model's bad estimates: p_bad(CNR), its covariance, the search band
    #: (:class:`~lidarcal.lidar.bad_estimates.BadEstimates`); other noise models carry none
    bad_estimates: BadEstimates | None = None
    #: the continuous RWF ``(offsets (m), values)`` that filters turbulence; ``None``: the Gaussian with
    #: the quadrature nodes' mean and variance (exact for the ideal lidar)
    rwf_profile: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    #: the turbulence model's form (``lidarcal.turbulence.kernels``; defaults IEC 61400-1 Ed. 3 as
    #: PyConTurb): decay a and u coherence length L_c (m) of exp(-a r sqrt((f/U)² + (0.12/L_c)²)),
    #: and the Kaimal Lambda_1 (m), Lambda(z) = min(0.7 z, Lambda_1)
    coherence_decay: float = COHERENCE_DECAY
    coherence_length: float = L_C
    turbulence_length_scale: float = LAMBDA_1
    description: str = "ideal"  #: free text: where the configuration came from

    def __post_init__(self) -> None:
        object.__setattr__(self, "azimuths", tuplify(self.azimuths))
        object.__setattr__(self, "rwf_offsets", tuplify(self.rwf_offsets))
        object.__setattr__(self, "rwf_weights", tuplify(self.rwf_weights))
        if isinstance(self.rwf_profile, Mapping):  # the attribute form: {"sha256": ..., "count": ...}
            object.__setattr__(self, "rwf_profile", RwfProfileDigest(**self.rwf_profile))
        elif self.rwf_profile is not None and not isinstance(self.rwf_profile, RwfProfileDigest):
            object.__setattr__(self, "rwf_profile", tuplify(self.rwf_profile))
        if isinstance(self.noise_table, Mapping):
            object.__setattr__(self, "noise_table", NoiseTable(**self.noise_table))
        if isinstance(self.bad_estimates, Mapping):
            try:
                object.__setattr__(self, "bad_estimates", BadEstimates(**self.bad_estimates))
            except (TypeError, ValueError) as exc:
                raise InputError(f"LidarModel: {exc}") from None
        if self.los_noise_model != "mixture":  # the fit belongs to the mixture (replace() drops it)
            object.__setattr__(self, "bad_estimates", None)
        problems = []
        if len(self.azimuths) != 4:
            problems.append(f"azimuths must list 4 oblique beams; got {self.azimuths}")
        else:
            az = np.mod(np.asarray(self.azimuths) - self.azimuths[0], 360.0)
            if not np.allclose(az, [0.0, 90.0, 180.0, 270.0], atol=1e-9):
                problems.append(f"azimuths must be 90° apart in clockwise order; got {self.azimuths}")
        if not 0.0 < self.cone_angle < 90.0:
            problems.append(f"cone_angle must be in (0, 90) degree; got {self.cone_angle}")
        if not 0.0 < self.cone_angle + self.beam_angle_offset < 90.0:
            problems.append(f"cone_angle + beam_angle_offset must be in (0, 90) degree; got "
                            f"{self.cone_angle + self.beam_angle_offset}")
        if self.hybrid_convention not in HYBRID_CONVENTIONS:
            problems.append(f"hybrid_convention must be one of {list(HYBRID_CONVENTIONS)}; "
                            f"got {self.hybrid_convention!r}")
        if not self.beam_period > 0:
            problems.append(f"beam_period must be > 0 s; got {self.beam_period}")
        if len(self.rwf_offsets) != len(self.rwf_weights) or not self.rwf_offsets:
            problems.append("rwf_offsets and rwf_weights must be non-empty and of equal length")
        elif abs(sum(self.rwf_weights) - 1.0) > 1e-9 or min(self.rwf_weights) < 0:
            problems.append(f"rwf_weights must be >= 0 and sum to 1; sum is {sum(self.rwf_weights)}")
        if not self.los_noise_std >= 0:
            problems.append(f"los_noise_std must be >= 0 m s-1; got {self.los_noise_std}")
        if not 0.0 < self.availability <= 1.0:
            problems.append(f"availability must be in (0, 1]; got {self.availability}")
        if self.cnr_threshold is not None and not np.isfinite(self.cnr_threshold):
            problems.append(f"cnr_threshold must be a finite CNR in dB or None; got {self.cnr_threshold}")
        table = self.noise_table
        if table is not None and table.bias is not None and len(table.bias) != 4:
            problems.append(f"noise_table must have 4 beams; has {len(self.noise_table.bias)}")
        if self.los_noise_model not in LOS_NOISE_MODELS:
            problems.append(f"los_noise_model must be one of {list(LOS_NOISE_MODELS)}; got "
                            f"{self.los_noise_model!r}")
        elif self.los_noise_model == "residuals" and not (self.noise_table is not None and (
                self.noise_table.has_residuals or self.noise_table.needs_residuals)):
            problems.append("los_noise_model 'residuals' needs a bench noise table with measured residuals "
                            "(a bench cube with 'los_residual'); use 'gaussian'")
        elif self.los_noise_model == "mixture":
            table = self.noise_table
            if not (table is not None and (table.has_residuals or table.needs_residuals)):
                problems.append("los_noise_model 'mixture' needs a bench noise table with measured residuals "
                                "(a bench cube with 'los_residual'); use 'gaussian'")
            elif self.bad_estimates is None:
                problems.append("los_noise_model 'mixture' needs bad_estimates (the fitted rate "
                                "LidarModel.from_artefacts or with_los_noise('mixture', cube) gives)")
            elif tuple(self.bad_estimates.cnr) != tuple(table.cnr):
                problems.append(f"bad_estimates' CNR bins {list(self.bad_estimates.cnr)} dB are not the "
                                "noise "
                                f"table's {list(table.cnr)} dB")
        for name in ("coherence_decay", "coherence_length", "turbulence_length_scale"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                problems.append(f"{name} must be a finite number > 0; got {value!r}")
        if self.reference_turbulence not in REFERENCE_TURBULENCE:
            problems.append(f"reference_turbulence must be one of {list(REFERENCE_TURBULENCE)}; got "
                            f"{self.reference_turbulence!r}")
        if isinstance(self.rwf_profile, RwfProfileDigest):
            if not (isinstance(self.rwf_profile.sha256, str) and len(self.rwf_profile.sha256) == 64):
                problems.append(f"rwf_profile's sha256 must be 64 hexadecimal digits; got "
                                f"{self.rwf_profile.sha256!r}")
        elif self.rwf_profile is not None:
            prof = np.asarray(self.rwf_profile, dtype=float)
            if (prof.ndim != 2 or prof.shape[0] != 2 or prof.shape[1] < 8 or np.any(np.diff(prof[0]) <= 0)
                    or not np.all(np.isfinite(prof)) or prof[1].max() <= 0):
                problems.append("rwf_profile must be (offsets, values): >= 8 increasing offsets (m) and "
                                "finite values with a positive maximum")
        if problems:
            raise InputError("LidarModel: " + "; ".join(problems))

    # -- construction -------------------------------------------------------------------
    @classmethod
    def ideal(cls, cone_angle: float | None = None, hybrid_weight: float | None = None,
              rwf_fwhm: float = DEFAULT_RWF_FWHM, los_noise_std: float | None = None,
              beam_period: float | None = None, *, n_nodes: int = DEFAULT_RWF_NODES,
              **overrides: Any) -> LidarModel:
        """Build the ideal lidar: zero bias, Gaussian noise, Gaussian RWF of ``rwf_fwhm`` (m).

        Arguments left ``None`` take the field defaults of :class:`LidarModel` (28°, p = 2/3,
        0.1 m s-1, 1 s per LOS); see ``docs/contracts.md``.
        """
        given = {"cone_angle": cone_angle, "hybrid_weight": hybrid_weight, "los_noise_std": los_noise_std,
                 "beam_period": beam_period}
        kw = {name: float(value) for name, value in given.items() if value is not None}
        offsets, weights = gauss_hermite_rwf(rwf_fwhm, n_nodes)
        return cls(rwf_offsets=offsets, rwf_weights=weights,
                   description=f"ideal: Gaussian RWF FWHM {float(rwf_fwhm):g} m, {n_nodes} nodes",
                   **kw, **overrides)

    @classmethod
    def from_attrs(cls, ds: xr.Dataset, *, cube: xr.Dataset | None = None, rwf: xr.Dataset | None = None,
                   source: str | None = None, los_noise_model: str | None = None) -> LidarModel:
        """Build the nominal lidar a ``conditions`` / ``field_campaign`` dataset describes.

        Its optional ``lidar_*`` global attributes (:data:`LIDAR_ATTRIBUTES`) give the
        configuration; missing ones take the defaults.  With ``cube`` and/or ``rwf`` the lidar is
        configured from those artefacts (:meth:`from_artefacts`) and the attributes fill in the
        rest (cone, p, beam period; RWF width without ``rwf``; LOS noise without ``cube``; with
        ``cube``, the CNR filter ``lidar_cnr_threshold`` when the file gives one, the ``.sta``
        header's ``CNRThreshold``: :func:`lidar_cnr_threshold`).
        ``los_noise_model`` is passed on to :meth:`from_artefacts` (without a cube only
        ``None`` or ``"gaussian"`` make sense: the ideal lidar's noise is Gaussian).
        """
        p = lidar_attributes(ds, source=source)
        if cube is None and los_noise_model in ("residuals", "mixture"):
            raise InputError(f"{source or source_name(ds)}: los_noise_model {los_noise_model!r} needs a "
                             "bench "
                             "cube (--cube) with measured residuals; without one the LOS noise is Gaussian")
        if cube is None and rwf is None:
            return cls.ideal(cone_angle=p["lidar_cone_angle"], hybrid_weight=p["lidar_hybrid_weight"],
                             rwf_fwhm=p["lidar_rwf_fwhm"], los_noise_std=p["lidar_los_noise_std"],
                             beam_period=p["lidar_beam_period"])
        overrides = {"cone_angle": p["lidar_cone_angle"], "hybrid_weight": p["lidar_hybrid_weight"],
                     "beam_period": p["lidar_beam_period"]}
        if rwf is None:
            overrides["rwf_fwhm"] = p["lidar_rwf_fwhm"]
        if cube is None:
            overrides["los_noise_std"] = p["lidar_los_noise_std"]
        else:
            threshold = lidar_cnr_threshold(ds, source=source)
            if threshold is not None:
                overrides["cnr_threshold"] = threshold
        return cls.from_artefacts(cube=cube, rwf=rwf, los_noise_model=los_noise_model, **overrides)

    @classmethod
    def from_artefacts(cls, cube: xr.Dataset | None = None, rwf: xr.Dataset | None = None, *,
                       n_nodes: int = DEFAULT_RWF_NODES, los_noise_model: str | None = None,
                       **overrides: Any) -> LidarModel:
        """Configure the lidar from a ``bench_cube`` and/or ``rwf`` artefact (CONTRIBUTING.md).

        Without an RWF the ideal Gaussian RWF (``rwf_fwhm`` override, default 30 m) is used.
        With an RWF, its ``cnr_gradient = 0`` column (re-centred on the recorded
        zero distance, which the lidar applies) is reduced to ``n_nodes`` Gauss nodes and
        ``cnr_weighting_scale`` defaults to 1 (Eq. 2 applied by the simulator, as in the paper's
        simulation); pass ``cnr_weighting_scale=0`` to switch it off.  Without a cube the ideal
        Gaussian noise (``los_noise_std``) is used.  With a cube the lidar's CNR filter
        ``cnr_threshold`` defaults to :data:`DEFAULT_CNR_THRESHOLD`: below it a real profiler
        discards its estimates (bench bins there are dominated by bad estimates), so those
        periods are unavailable rather than simulated with metres-per-second noise; pass
        ``cnr_threshold=None`` to simulate every period.

        ``los_noise_model`` (:data:`LOS_NOISE_MODELS`): ``None`` picks ``"mixture"`` when the cube
        has ``los_residual`` (good residuals resampled, bad estimates at the rate
        :func:`fit_bad_estimates` fits, ``docs/method.md``) and ``"gaussian"`` (N(``los_bias``,
        ``los_std``)) otherwise; a cube whose residuals hold fewer than two bad estimates (so no
        search band can be estimated) falls back to ``"residuals"`` with a warning.  Asking for
        ``"mixture"`` or ``"residuals"`` with a cube without residuals is a
        :class:`~lidarcal.errors.MissingVariableError` naming the file; ``"mixture"`` with too
        few bad estimates an :class:`~lidarcal.errors.InputError` saying why.  Without a cube the
        noise is the ideal Gaussian.  Remaining ``overrides`` set fields (a ``cnr_threshold``
        override also sets the CNR range the rate is fitted over).
        """
        if los_noise_model is not None and los_noise_model not in LOS_NOISE_MODELS:
            raise InputError(f"los_noise_model must be one of {list(LOS_NOISE_MODELS)}; "
                             f"got {los_noise_model!r}")
        rwf_fwhm = float(overrides.pop("rwf_fwhm", DEFAULT_RWF_FWHM))
        offsets, weights = gauss_hermite_rwf(rwf_fwhm, n_nodes)
        kw: dict[str, Any] = {"rwf_offsets": offsets, "rwf_weights": weights}
        described = []
        if rwf is not None:
            offsets, weights, profile = rwf_nodes(rwf, n_nodes)
            kw.update(rwf_offsets=offsets, rwf_weights=weights, cnr_weighting_scale=1.0, rwf_profile=profile)
            described.append(f"RWF {source_name(rwf)} ({n_nodes} nodes)")
        else:
            described.append(f"ideal Gaussian RWF FWHM {rwf_fwhm:g} m ({n_nodes} nodes)")
        if cube is not None:
            has = "los_residual" in cube.variables
            if los_noise_model in ("residuals", "mixture") and not has:
                raise MissingVariableError(
                    f"{source_name(cube)}: los_noise_model {los_noise_model!r} needs the bench cube variable "
                    "'los_residual' (each bin's measured residuals, written by lidarcal bench ingest since "
                    "it keeps them); this cube has none - re-ingest the bench run or use 'gaussian'")
            azimuths = tuple(overrides.get("azimuths", cls.azimuths))
            threshold = overrides.get("cnr_threshold", DEFAULT_CNR_THRESHOLD)
            model = los_noise_model or ("mixture" if has else "gaussian")
            if model == "mixture":
                try:
                    kw["bad_estimates"] = fit_bad_estimates(cube, azimuths, threshold)
                except InputError as exc:
                    if los_noise_model is not None:
                        raise
                    log.warning("%s; resampling every residual of each bin (los_noise_model "
                                "'residuals')", exc)
                    model = "residuals"
            kw["noise_table"] = noise_table_from_cube(cube, azimuths, residuals=model != "gaussian")
            kw["los_noise_model"] = model
            kw["cnr_threshold"] = DEFAULT_CNR_THRESHOLD
            noise = {"mixture": "good residuals resampled, bad estimates at the fitted CNR rate",
                     "residuals": "measured residuals resampled", "gaussian": "Gaussian LOS noise"}[model]
            described.append(f"bench cube {source_name(cube)} ({noise}), CNR filter "
                             f"{'none' if threshold is None else format(threshold, 'g') + ' dB'}")
        else:
            described.append("ideal Gaussian LOS noise")
        kw["description"] = "; ".join(described)
        kw.update(overrides)
        return cls(**kw)

    def with_los_noise(self, name: str, cube: xr.Dataset | None = None) -> LidarModel:
        """Return the model with ``los_noise_model = name`` (``"mixture"`` fitted from ``cube`` if needed).

        A model that has no ``bad_estimates`` needs the bench cube it was built from to switch to
        ``"mixture"`` (the rate is fitted over the CNR range its ``cnr_threshold`` draws from).
        """
        if name not in LOS_NOISE_MODELS:
            raise InputError(f"los_noise_model must be one of {list(LOS_NOISE_MODELS)}; got {name!r}")
        if name != "mixture" or self.bad_estimates is not None:
            return self.replace(los_noise_model=name)
        if cube is None:
            raise InputError("los_noise_model 'mixture' needs the bench cube the model was built from "
                             "(--cube) to fit its bad-estimate rate")
        bad = fit_bad_estimates(cube, self.azimuths, self.cnr_threshold)
        model = self.replace(los_noise_model=name, bad_estimates=bad)
        if model.noise_table is not None and model.noise_table.needs_values:
            model = model.with_residuals(cube)
        return model

    def for_trial(self, base_seed: int, replica: int, key: int) -> LidarModel:
        """Return the model period ``key`` simulates in Monte Carlo replica ``replica`` (docs/seeds.md).

        With the ``"mixture"`` noise model, in replica r >= 1 each period simulates its own
        p_bad(CNR) curve drawn from the fit's distribution (:meth:`BadEstimates.for_trial
        <lidarcal.lidar.bad_estimates.BadEstimates.for_trial>`, keyed by ``(base_seed, r, key)``),
        replica 0 the best estimate; every other model is the same for all trials.
        """
        if self.bad_estimates is None:
            return self
        return self.replace(bad_estimates=self.bad_estimates.for_trial(base_seed, replica, key))

    # -- serialisation ------------------------------------------------------------------
    def to_dict(self, *, residuals: bool = False) -> dict[str, Any]:
        """Return a JSON-safe dictionary (lists and floats only); inverse of :meth:`from_dict`.

        By default this is the *attribute form* written into artefacts: bench data the model's
        input artefacts already hold appear only by digest, a few hundred bytes instead of tens of
        kB (so that every attribute reads as one short line of ``ncdump -h``).  A noise table keeps
        its bin centres, ``table_sha256`` for its bias and std (the cube's ``los_bias`` and
        ``los_std``) and ``residuals_sha256``/``residuals_total`` for its measured residuals; the
        RWF profile is ``{"sha256": ..., "count": ...}`` (:class:`RwfProfileDigest`).
        :meth:`from_dict` needs the bench cube and the RWF to restore them.  ``residuals=True``
        gives the full form for in-process and worker transport (every value, so a worker draws
        bit for bit); it raises :class:`~lidarcal.errors.InputError` when the model knows some of
        them only by digest.
        """
        table = self.noise_table
        if residuals:
            resampled = self.los_noise_model in ("residuals", "mixture")
            if table is not None and table.needs_residuals and resampled:
                raise InputError(table.missing_residuals_message())
            if table is not None and table.needs_table:
                raise InputError(table.missing_table_message())
            if isinstance(self.rwf_profile, RwfProfileDigest):
                raise InputError(self.missing_rwf_message())
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, NoiseTable):
                value = value if residuals else value.attribute_form()
                value = {g.name: listify(getattr(value, g.name)) for g in dataclasses.fields(value)
                         if g.name != "origin"}
                for name in ("residual_count", "residuals", "bias", "std"):
                    if value[name] is None:
                        del value[name]
                if value["residuals_sha256"] is None:  # a Gaussian table: no residuals to identify
                    del value["residuals_sha256"], value["residuals_total"]
            elif f.name == "rwf_profile" and value is not None and not residuals:
                if not isinstance(value, RwfProfileDigest):
                    value = RwfProfileDigest(rwf_profile_digest(value), len(value[0]))
                value = value.to_dict()
            elif isinstance(value, RwfProfileDigest):
                value = value.to_dict()
            elif isinstance(value, BadEstimates):
                value = value.to_dict()
            elif f.name == "bad_estimates":  # None: left out, so other models' records read as before
                continue
            out[f.name] = listify(value)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | str, *, cube: xr.Dataset | None = None,
                  rwf: xr.Dataset | None = None, source: str | None = None) -> LidarModel:
        """Rebuild a model from :meth:`to_dict` output (or its JSON text).

        An attribute-form record knows the bench noise table and residuals and the RWF profile
        only by digest: without ``cube``/``rwf`` the model is rebuilt (its settings, its bin
        centres, the digests) but refuses to draw or travel to a worker until
        :meth:`with_residuals` / :meth:`with_rwf` restore them; with ``cube`` (the bench cube the
        model was built from) and ``rwf`` (its RWF artefact) they are restored and checked against
        the digests.  Records written before the digests existed (every value inline) are read
        as they are.  ``source`` names the record in error messages (e.g. ``"x.nc: global
        attribute 'lidarcal_lidar_model'"``).
        """
        if isinstance(data, str):
            data = json.loads(data)
        data = dict(data)
        if "reference_turbulence" not in data:  # a record from before the field: its engine's convention
            legacy = data.pop("turbulence_amplitudes", "deterministic")
            if legacy not in _LEGACY_AMPLITUDES:
                raise InputError(f"LidarModel.from_dict: turbulence_amplitudes must be one of "
                                 f"{list(_LEGACY_AMPLITUDES)}; got {legacy!r}")
            data["reference_turbulence"] = _LEGACY_AMPLITUDES[legacy]
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise InputError(f"LidarModel.from_dict: unknown field(s) {sorted(unknown)}; "
                             f"known {sorted(known)}")
        if source:  # the noise table and the RWF digest name the record in their messages
            for key in ("noise_table", "rwf_profile"):
                if isinstance(data.get(key), Mapping):
                    data[key] = {**data[key], "origin": source}
        model = cls(**data)
        if cube is not None:
            model = model.with_residuals(cube, source=source)
        if rwf is not None:
            model = model.with_rwf(rwf, source=source)
        return model

    def with_residuals(self, cube: xr.Dataset, *, source: str | None = None) -> LidarModel:
        """Restore a digest-only noise table (bias, std, residuals) from the bench cube ``cube``.

        The values are gathered exactly as :meth:`from_artefacts` gathers them (the model's
        beams, empty bins from the nearest populated one) and must have the recorded SHA-256s;
        otherwise :class:`~lidarcal.errors.InputError` names the record (``source``), the cube
        and both digests.  A model without such a table is returned unchanged.
        """
        table = self.noise_table
        if table is None or not table.needs_values:
            return self
        origin = source or table.origin
        restored = table
        if table.needs_table:
            built = noise_table_from_cube(cube, self.azimuths)
            if built.cnr != table.cnr or built.velocity != table.velocity:
                raise InputError(
                    f"{origin}: the bench cube {source_name(cube)} is not the one the model was built from: "
                    f"its bins are cnr {list(built.cnr)} dB, velocity {list(built.velocity)} m s-1; expected "
                    f"cnr {list(table.cnr)} dB, velocity {list(table.velocity)} m s-1")
            if built.table_sha256 != table.table_sha256:
                raise InputError(
                    f"{origin}: the bench cube {source_name(cube)} is not the one the model was built from: "
                    f"its noise table (los_bias, los_std) has sha256 {built.table_sha256}; expected sha256 "
                    f"{table.table_sha256}")
            restored = dataclasses.replace(restored, bias=built.bias, std=built.std)
        if table.needs_residuals:
            count, values = cube_residuals(cube, self.azimuths)
            found = residuals_digest(count, values)
            if found != table.residuals_sha256:
                raise InputError(
                    f"{origin}: the bench cube {source_name(cube)} is not the one the model was built from: "
                    f"its residuals ({values.size} values) have sha256 {found}; expected sha256 "
                    f"{table.residuals_sha256} ({table.residuals_total} values)")
            restored = dataclasses.replace(restored, residual_count=count, residuals=values)
        return dataclasses.replace(self, noise_table=restored)

    def with_rwf(self, rwf: xr.Dataset, *, source: str | None = None) -> LidarModel:
        """Restore an RWF profile known only by digest from the ``rwf`` artefact the model was built from.

        The profile is computed exactly as :meth:`from_artefacts` computes it and must have the
        recorded SHA-256; otherwise :class:`~lidarcal.errors.InputError` names the record, the RWF
        file and both digests.  A model with its profile (or none) is returned unchanged.
        """
        pending = self.rwf_profile
        if not isinstance(pending, RwfProfileDigest):
            return self
        _, _, profile = rwf_nodes(rwf, len(self.rwf_offsets))
        found = rwf_profile_digest(profile)
        if found != pending.sha256:
            origin = source or pending.origin
            raise InputError(
                f"{origin}: the RWF {source_name(rwf)} is not the "
                f"one the model was built from: its profile ({len(profile[0])} points) has sha256 {found}; "
                f"expected sha256 {pending.sha256} ({pending.count} points)")
        return dataclasses.replace(self, rwf_profile=profile)

    def missing_rwf_message(self) -> str:
        """Why a model whose RWF profile is known only by digest cannot simulate, and how to restore it."""
        pending = self.rwf_profile
        return (f"{pending.origin} records the RWF profile only by digest: no RWF "
                f"given; pass the RWF artefact the model was built from (--rwf), its profile has sha256 "
                f"{pending.sha256} ({pending.count} points)")

    def to_json(self) -> str:
        """Compact JSON text of the attribute form of :meth:`to_dict` (``lidarcal_lidar_model``)."""
        return json.dumps(self.to_dict(), sort_keys=True)

    def reference_scale(self, direction: Any, turbulence_intensity: Any) -> Any:
        """Factor by which the virtual reference over-reads the cup's true 10-minute mean speed.

        ``(1 + reference_overspeeding · TI) · (1 + reference_gain) · flow-distortion factor`` for
        the period's mean ``direction`` (degree, from) and turbulence intensity; the sector's
        edge is smoothed by the spread of the instantaneous direction, σ_θ = σ_v / U =
        0.8 · TI rad (:func:`flow_distortion_factor`).  Exactly 1 for the nominal model (every
        factor is then 1.0, so the records stay bit-identical).
        """
        spread = direction_spread(turbulence_intensity)
        return ((1.0 + self.reference_overspeeding * turbulence_intensity) * (1.0 + self.reference_gain)
                * flow_distortion_factor(direction, self.reference_flow_distortion_centre,
                                         self.reference_flow_distortion_width,
                                         self.reference_flow_distortion_deficit, spread))

    def replace(self, **changes: Any) -> LidarModel:
        """Return a copy with some fields changed (``dataclasses.replace``)."""
        return dataclasses.replace(self, **changes)


def direction_spread(turbulence_intensity: Any) -> Any:
    """Return the standard deviation (degree) of the instantaneous direction: σ_v / U = 0.8 · TI rad."""
    return np.degrees(SIGMA_RATIOS[1] * np.asarray(turbulence_intensity, dtype=float))


def flow_distortion_factor(direction: Any, centre: float, width: float, deficit: float,
                           spread: Any = 0.0) -> Any:
    """Mast-shadow factor of a 10-minute mean reference: ``1 − deficit · P(in sector)``.

    The sector holds the directions (degree, from) within ``width / 2`` of ``centre`` on the
    circle.  The cup is shadowed sample by sample, so for a period of mean ``direction`` whose
    instantaneous direction is Gaussian with standard deviation ``spread`` (degree) the factor
    is ``1 − deficit · [Φ((w/2 − Δ)/spread) − Φ((−w/2 − Δ)/spread)]``, Δ the signed offset from
    ``centre``: a smooth edge about ``spread`` wide.  ``spread = 0`` is a hard edge (edges
    included).  ``width = 0`` or ``deficit = 0`` is no shadow (factor exactly 1.0).
    """
    if width <= 0.0 or deficit == 0.0:
        return np.ones_like(np.asarray(direction, dtype=float)) if np.ndim(direction) else 1.0
    from scipy.special import ndtr

    delta = (np.asarray(direction, dtype=float) - centre + 180.0) % 360.0 - 180.0
    spread = np.asarray(spread, dtype=float)
    hard = np.where(np.abs(delta) <= 0.5 * width, 1.0, 0.0)
    s = np.where(spread > 0, spread, 1.0)
    smooth = ndtr((0.5 * width - delta) / s) - ndtr((-0.5 * width - delta) / s)
    return 1.0 - deficit * np.where(spread > 0, smooth, hard)
