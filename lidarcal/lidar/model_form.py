"""The simulation's model form: the defensible alternatives to a nominal virtual lidar, declared once.

The Monte Carlo budget rests on choices the measurements do not fix.  Each :class:`Alternative`
names one such choice and says how to derive, from the nominal :class:`~lidarcal.lidar.LidarModel`,
the model that makes the other defensible choice; :func:`alternative_models` applies every one
to a nominal model.  The model-form term of the budget (``docs/method.md``) is the spread of the
result across these alternatives, each simulated with the nominal model's seeds (common random
numbers: :mod:`lidarcal.campaign.model_form`); ``diagnose`` can reuse the same registry.

=====================  ====================================================================
alternative            the other defensible choice
=====================  ====================================================================
``reference_level``    ``reference_turbulence = "inferred_level"``: the field's turbulence
                       level unknown given the reference's measured 10-minute σ_u (the
                       nominal ``"pinned_u"`` takes the field at the measured TI;
                       ``docs/validation.md``)
``coherence``          IEC 61400-1 Ed. 2's coherence, decay a = 8.8 and L_c = 3.5 Λ_1 =
                       73.5 m (Λ_1 = 21 m), instead of Ed. 3's a = 12, L_c = 8.1 · 42 m
``length_scale``       IEC 61400-1 Ed. 2's Kaimal length scale Λ_1 = 21 m (0.7 z below 30 m)
                       instead of Ed. 3's 42 m (0.7 z below 60 m)
``rwf_shape``          a Gaussian RWF of the measured RWF's FWHM instead of the measured shape
                       (only for a model with a measured RWF profile)
=====================  ====================================================================

The two IEC editions bound the literature range the engine's turbulence model is taken from
(PyConTurb implements Ed. 3; NREL's TurbSim implements both).  A nominal model that already
makes the alternative's choice gets the nominal default instead (Ed. 3, ``pinned_u``), so every
alternative spans the same range whichever end the nominal sits at.  ``pinned_uvw`` and ``free``
are not defensible alternatives: the first pins more than the point-level convention it reads
(``docs/validation.md``), the second contradicts the measured TI (the reference's realised σ_u is
what a conditions file records).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from lidarcal.lidar.model import DEFAULT_RWF_NODES, LidarModel, RwfProfileDigest
from lidarcal.lidar.quadrature import gauss_hermite_rwf
from lidarcal.rwf.kernels import full_width_half_maximum
from lidarcal.turbulence.kernels import COHERENCE_DECAY, L_C, LAMBDA_1

__all__ = ["Alternative", "ALTERNATIVES", "IEC_ED2", "alternative_models", "gaussian_rwf_of", "rwf_fwhm"]

#: IEC 61400-1 Ed. 2 (1999) turbulence parameters above 30 m: coherence decay a, coherence length
#: L_c = 3.5 Λ_1 (m), Kaimal Λ_1 (m).  Ed. 3 (2005), the nominal: 12, 8.1 · 42 = 340.2 m, 42 m.
IEC_ED2 = {"coherence_decay": 8.8, "coherence_length": 73.5, "turbulence_length_scale": 21.0}
_IEC_ED3 = {"coherence_decay": COHERENCE_DECAY, "coherence_length": L_C, "turbulence_length_scale": LAMBDA_1}


@dataclasses.dataclass(frozen=True)
class Alternative:
    """One defensible alternative to a nominal model: its name, what it changes, how to derive it."""

    name: str  #: identifier (the ``model_form_alternative`` coordinate of the records and the budget)
    aspect: str  #: which modelling choice it spans
    description: str  #: what the alternative model does differently (for the certificate and report)
    derive: Callable[[LidarModel], LidarModel | None]  #: nominal -> alternative (None: not applicable)


def _reference_level(model: LidarModel) -> LidarModel:
    other = "pinned_u" if model.reference_turbulence == "inferred_level" else "inferred_level"
    return model.replace(reference_turbulence=other)


def _edition(model: LidarModel, names: tuple[str, ...]) -> LidarModel:
    now = {n: getattr(model, n) for n in names}
    other = _IEC_ED3 if now == {n: IEC_ED2[n] for n in names} else IEC_ED2
    return model.replace(**{n: other[n] for n in names})


def rwf_fwhm(model: LidarModel) -> float:
    """Full width at half maximum (m) of the model's RWF: its measured profile, else its Gaussian nodes."""
    profile = model.rwf_profile
    if profile is not None and not isinstance(profile, RwfProfileDigest):
        offsets, values = (np.asarray(a, dtype=float) for a in profile)
        return full_width_half_maximum(values, offsets)
    x, w = np.asarray(model.rwf_offsets), np.asarray(model.rwf_weights)
    sd = float(np.sqrt(np.sum(w * (x - np.sum(w * x)) ** 2)))
    return sd * 2.0 * np.sqrt(2.0 * np.log(2.0))


def gaussian_rwf_of(model: LidarModel) -> LidarModel | None:
    """Return the model with a Gaussian RWF of its measured RWF's FWHM (None: no measured profile).

    The Gaussian is centred where the lidar puts its gate (the measured RWF's barycentre, offset 0:
    :meth:`LidarModel.from_artefacts` re-centres the nodes on it) and has as many quadrature nodes.
    """
    if model.rwf_profile is None:
        return None
    if isinstance(model.rwf_profile, RwfProfileDigest):
        from lidarcal.errors import InputError  # deferred: only on this error path

        raise InputError(model.missing_rwf_message())
    offsets, weights = gauss_hermite_rwf(rwf_fwhm(model), len(model.rwf_offsets) or DEFAULT_RWF_NODES)
    return model.replace(rwf_profile=None, rwf_offsets=tuple(offsets.tolist()),
                         rwf_weights=tuple(weights.tolist()))


#: The alternatives, in the order of the ``model_form_alternative`` coordinate.
ALTERNATIVES: tuple[Alternative, ...] = (
    Alternative("reference_level", "reference turbulence convention",
                "reference_turbulence inferred_level: the field's turbulence level inferred from the "
                "reference's measured 10-minute sigma_u (nominal pinned_u: the field at the measured TI)",
                _reference_level),
    Alternative("coherence", "IEC coherence decay",
                "IEC 61400-1 Ed. 2 coherence: decay 8.8, coherence length 73.5 m (nominal Ed. 3: 12, "
                "340.2 m)",
                lambda m: _edition(m, ("coherence_decay", "coherence_length"))),
    Alternative("length_scale", "Kaimal length scale",
                "IEC 61400-1 Ed. 2 Kaimal length scale Lambda_1 = 21 m (nominal Ed. 3: 42 m)",
                lambda m: _edition(m, ("turbulence_length_scale",))),
    Alternative("rwf_shape", "range-weighting function shape",
                "a Gaussian RWF of the measured RWF's full width at half maximum (nominal: the measured "
                "shape)",
                gaussian_rwf_of),
)


def alternative_models(model: LidarModel) -> dict[str, LidarModel]:
    """Return ``{name: alternative model}`` for every alternative that applies to ``model``, in order.

    An alternative that does not apply (``rwf_shape`` for a model without a measured RWF) or
    that gives the nominal model back is left out.

    >>> sorted(alternative_models(LidarModel.ideal()))
    ['coherence', 'length_scale', 'reference_level']
    >>> alternative_models(LidarModel.ideal())["coherence"].coherence_length
    73.5
    """
    out = {}
    for alt in ALTERNATIVES:
        derived = alt.derive(model)
        if derived is not None and derived != model:
            out[alt.name] = derived.replace(description=f"{model.description}; model-form alternative "
                                                        f"{alt.name}: {alt.description}")
    return out
