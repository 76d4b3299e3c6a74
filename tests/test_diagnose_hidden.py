"""Diagnose campaigns with a hidden effect: name it, recover it, close the gap (the confusion matrix).

Fast versions (150 periods x 3 heights, the effect-free campaign and a hidden reference
over-speeding; a hidden Zd error runs through the CLI in test_diagnose.py) run by default;
the full catalogue on 600 periods x 4 heights is ``@pytest.mark.slow``.
Acceptance (docs/diagnose.md): the hidden effect is named alone (diagonal of the confusion matrix),
the truth lies in its 95 % interval, and the gap at least halves; the effect-free campaign gives
``none``.  The same tests on an independent simulator are in ``test_diagnose_independent.py``.
"""

import numpy as np
import pytest

from lidarcal.diagnose import (
    EFFECTS,
    REALISTIC_STRENGTHS,
    diagnose,
    generate_field_campaign,
    hidden_effect_conditions,
    summary,
    to_dataset,
)
from lidarcal.schema import validate_dataset


def check_recovery(result, effect, params):
    js = summary(result)
    # one line per campaign (shown with `pytest -s`): the confusion-matrix row
    print(f"\n[diagnose] hidden {effect} {params} -> {js['effect']} {js['parameters']} "
          f"+- {js['uncertainties']}; "
          f"gap {js['gap_before']:.3f} -> {js['gap_after']:.3f} % (floor {js['gap_noise_floor']:.3f} %); "
          + ", ".join(f"{c['effect']} {c['score']:.1f}" for c in js["candidates"]))
    assert js["effect"] == effect, (js["candidates"], js["note"])
    if effect == "none":
        assert js["parameters"] == {} and js["drivers"] == [] and js["effects"] == []
        assert js["gap_after"] == js["gap_before"]
        return js
    assert [e["effect"] for e in js["effects"]] == [effect]  # one hidden effect: nothing else named
    for name, truth in params.items():
        lo, hi = js["intervals"][name]
        assert lo <= truth <= hi, f"{effect}.{name}: {js['parameters'][name]:.4g} in [{lo:.4g}, {hi:.4g}], " \
                                  f"truth {truth}"
    assert js["gap_after"] <= 0.5 * js["gap_before"], (js["gap_before"], js["gap_after"])
    assert js["drivers"] and set(js["drivers"][0]) == {"variable", "range", "units", "z"}
    return js


@pytest.fixture(scope="module")
def small_conditions():
    return hidden_effect_conditions(150, (40.0, 80.0, 160.0), seed=21)


@pytest.mark.parametrize("effect", ["none", "reference_overspeeding"])
def test_hidden_effect_small_campaign(small_conditions, effect):
    sim = {"scheduler": "synchronous"}
    field = generate_field_campaign(small_conditions, effect, execution=sim)
    result = diagnose(field, execution=sim)
    js = check_recovery(result, effect, REALISTIC_STRENGTHS[effect])
    if effect == "none":
        # no false alarm: no height/variable bin disagrees after the Holm correction
        assert not js["significant"]
        assert result.settings["simulations"] == 4  # nominal + 3 geometric probes; nothing refined
    ds = to_dataset(result)
    assert validate_dataset(ds) == []


@pytest.mark.slow
@pytest.mark.parametrize("effect", list(EFFECTS))
def test_confusion_matrix_full_catalogue(effect):
    # 600 periods x 4 heights (40-160 m, across the 110 m CNR-gradient zero crossing); the
    # hybrid-weight campaign is more turbulent (I_ref 0.16): p only matters through TI^2.
    iref = 0.16 if effect == "hybrid_weight" else 0.10
    cond = hidden_effect_conditions(600, (40.0, 80.0, 120.0, 160.0), seed=33, turbulence_reference=iref)
    field = generate_field_campaign(cond, effect)
    result = diagnose(field)
    check_recovery(result, effect, REALISTIC_STRENGTHS[effect])
    assert np.isfinite(result.gap_before[0])
