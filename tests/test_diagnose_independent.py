"""``lidarcal diagnose`` on field campaigns it did not generate (``tests/independent_campaign.py``).

The campaigns come from an independent simulator: its own turbulence boxes (PyConTurb's spectra
and coherence, one box for all heights), a fine RWF quadrature, a cup whose TI, shear and
direction are computed from its own 1 Hz series, and the conditions taken from those measured
values, as on a real mast.  A structural mismatch with lidarcal's engine is expected; the
answers must stay honest anyway (``docs/diagnose.md``):

* each catalogue effect alone is named alone (the diagonal of the confusion matrix; a constant
  reference gain and a beam-angle offset, or a hybrid weight and an over-speeding cup, may be
  reported as tied — no other tie), its true parameters lie in the reported 95 % intervals and
  the gap at least halves;
* two effects at once are both named;
* an effect outside the catalogue (a lidar error in one direction sector) is ``unexplained`` and
  ``drivers`` points at that sector;
* effect-free campaigns of different sizes give ``none``;
* over all hidden-effect campaigns the 95 % intervals hold the truth in at least 90 % of cases.

Fast versions (150 periods × 3 heights) run by default; the full matrix is ``@pytest.mark.slow``.
"""

import numpy as np
import pytest
from diagnose_checks import assert_note_matches_answer
from independent_campaign import make_field_campaign

from lidarcal.diagnose import REALISTIC_STRENGTHS, diagnose, summary

SIM = {"scheduler": "synchronous"}
#: Catalogue effects at a realistic strength that is material (changes (L - R)/R by more than the
#: 0.1 % tolerance) on this simulator's campaigns: the engine tests' strengths, except that its
#: CNR profiles (lapse 0.01 +- 0.03 dB/m) make Eq. 2 as written (scale 1) move (L - R)/R by under
#: 0.1 % — correctly answered `none` — so scale 3 is used, and the hybrid weight is that of vector
#: averaging (p = 0 against the nominal 2/3; p = 0.5 changes it by ~0.1 % at TI 0.12).
CATALOGUE = {k: v for k, v in REALISTIC_STRENGTHS.items() if k != "none"}
CATALOGUE["cnr_gradient_weighting"] = {"scale": 3.0}
CATALOGUE["hybrid_weight"] = {"p": 0.0}
#: Look-alike groups: effects that may be reported as tied with each other.  A constant reference gain
#: and a beam-angle offset scale every height alike; a hybrid weight and an over-speeding cup both
#: grow with TI, and on this simulator's campaigns (the cup's measured TI, not the TI the lidar's
#: turbulence was made with) their fits differ by less than the model-form allowance (400 x 4:
#: 27.2 % against 27.6 % of the weighted residual).  A tie outside these groups fails the test.
LOOK_ALIKE = [{"reference_gain", "beam_angle_offset"}, {"hybrid_weight", "reference_overspeeding"}]


def run(effects, n_periods, heights=(40.0, 80.0, 120.0, 160.0), seed=3, candidates=None, **campaign):
    field = make_field_campaign(effects, n_periods=n_periods, heights=heights, seed=seed, **campaign)
    js = summary(diagnose(field, candidates=candidates, execution=SIM))
    # one line per campaign (shown with `pytest -s`): the confusion-matrix row
    print(f"\n[independent] {effects} {campaign} -> {js['effect']} "
          + "; ".join(f"{e['effect']} {e['parameters']} in {e['intervals']}" for e in js["effects"])
          + f"; drivers {js['drivers']}; gap {js['gap_before']:.3f} -> {js['gap_after']:.3f} % "
          f"(floor {js['gap_noise_floor']:.3f} %); {js['note']}")
    assert_note_matches_answer(js)  # on every campaign: the note names exactly the answer's effects
    return js


def named(js):
    """Catalogue ids named, with ties: each named effect as the set of ids it cannot be told from."""
    return [{e["effect"], *e["tied"]} for e in js["effects"]]


def covered(js, effects):
    """(inside, total) over the true parameters of the hidden effects that were named."""
    inside = total = 0
    for e in js["effects"]:
        if e["effect"] not in effects:
            continue
        for name, truth in effects[e["effect"]].items():
            lo, hi = e["intervals"][name]
            total += 1
            if name == "centre":  # a direction: compare on the circle
                truth = lo + np.mod(truth - lo, 360.0)
            inside += bool(lo <= truth <= hi)
    return inside, total


def check_single(js, effect, params):
    """The effect is named alone (or tied with its look-alike) and the gap at least halves."""
    assert len(js["effects"]) == 1 and effect in named(js)[0], (js["effect"], js["note"])
    allowed = set().union({effect}, *(g for g in LOOK_ALIKE if effect in g))
    assert named(js)[0] <= allowed, (named(js), js["note"])  # ties only within a look-alike group
    # the gap metric sees the effect: it at least halves once the effect is added
    assert js["gap_after"] <= 0.5 * js["gap_before"], (js["gap_before"], js["gap_after"])
    return covered(js, {effect: params})


# -- fast versions (default suite) ----------------------------------------------------------------

def test_effect_free_campaign_is_none():
    js = run({}, 150, heights=(40.0, 80.0, 160.0))
    assert js["effect"] == "none" and js["effects"] == [] and js["drivers"] == [], js["note"]
    assert js["gap_after"] == js["gap_before"]


TWO = {"reference_overspeeding": {"coefficient": 0.08},
       "reference_flow_distortion": {"centre": 120.0, "width": 40.0, "deficit": 0.04}}


def test_two_effects_at_once_are_both_named():
    # an over-speeding cup (0.08 x TI: ~1 %) and a mast shadow (4 % in a 40-degree sector)
    js = run(TWO, 150, heights=(40.0, 80.0, 160.0))
    assert sorted(e["effect"] for e in js["effects"]) == sorted(TWO), js["note"]
    inside, total = covered(js, TWO)
    assert total == 4 and inside >= 3, js["effects"]  # 95 % intervals: at most one miss in four
    assert js["gap_after"] <= 0.5 * js["gap_before"]


# -- the full matrix (slow) -------------------------------------------------------------------------

N_SLOW = 400
#: Two effects at once (slow): a lidar and a reference defect; a geometric one and a mast shadow.
PAIRS = [
    {"zero_distance_offset": {"offset": 4.0}, "reference_overspeeding": {"coefficient": 0.08}},
    {"cnr_gradient_weighting": {"scale": 1.0},
     "reference_flow_distortion": {"centre": 250.0, "width": 60.0, "deficit": 0.04}},
]


@pytest.fixture(scope="module")
def matrix():
    """Every catalogue effect alone and every pair, diagnosed once (shared by the slow tests).

    Nine 400 x 4 campaigns and diagnoses: about 9.5 min on a loaded 2-core machine.
    """
    cases = [{k: v} for k, v in CATALOGUE.items()] + PAIRS
    return [(effects, run(effects, N_SLOW)) for effects in cases]


@pytest.mark.slow
def test_confusion_matrix_is_diagonal_and_the_gap_halves(matrix):
    for effects, js in matrix[: len(CATALOGUE)]:
        (effect, params), = effects.items()
        check_single(js, effect, params)


@pytest.mark.slow
def test_two_effects_at_once_are_both_named_full(matrix):
    for effects, js in matrix[len(CATALOGUE):]:
        assert sorted(e["effect"] for e in js["effects"]) == sorted(effects), js["note"]


@pytest.mark.slow
def test_intervals_cover_the_truth_in_90_percent_of_cases(matrix):
    inside = total = 0
    for effects, js in matrix:
        i, t = covered(js, effects)
        inside, total = inside + i, total + t
    # 7 single effects (9 parameters) and 2 pairs (5 parameters): 14 true values; >= 90 % inside
    assert total >= 12 and inside / total >= 0.9, (inside, total)


@pytest.mark.slow
def test_an_effect_outside_the_catalogue_is_unexplained_and_located():
    # The lidar over-reads by 3 % for winds from 280-320 degree.  On (L - R)/R that is the
    # signature of a mast shadow on the cup (a 3 % deficit in the same sector): no data on the
    # lidar/cup pair alone can tell them apart, so with the full catalogue the honest answer is
    # reference_flow_distortion.  The effect is "outside the catalogue" for a catalogue without
    # the mast shadow: every other entry is tried and none may be named.
    candidates = [e for e in CATALOGUE if e != "reference_flow_distortion"]
    js = run({"lidar_sector_error": {"centre": 300.0, "width": 40.0, "error": 0.03}}, N_SLOW,
             candidates=candidates)
    assert js["effect"] == "unexplained", js["note"]
    top = js["drivers"][0]
    assert top["variable"] == "wind_from_direction" and top["units"] == "degree"
    lo, hi = top["range"]
    # the sector, not the whole rose: 30-degree sectors with |z| >= 2 around the peak (the vane's
    # measured direction and the 10-minute scatter spread a 40-degree error over 3-4 sectors)
    assert lo <= 300.0 <= hi and hi - lo <= 180.0, top


@pytest.mark.slow
@pytest.mark.parametrize("n_periods", [200, 600])
def test_effect_free_campaigns_of_different_size_are_none(n_periods):
    js = run({}, n_periods, seed=11)
    assert js["effect"] == "none" and js["effects"] == [], js["note"]


# -- issue 26's campaigns (slow) --------------------------------------------------------------------
# Long campaigns of the kind issue 26 reported, on this simulator with seed 26 (no constant of the
# diagnosis was set from it; the hybrid weight's fitted model-form share comes from seeds 101-103,
# the share it uses from the engine's alternatives).  The
# issue's second effect was Eq. 2 CNR weighting of scale 1 changing (L - R)/R by 0.2 %; on this
# simulator's CNR profiles scale 1 changes it by under the tolerance (CATALOGUE above), so scale 3
# makes it a decisive, material second effect here.

@pytest.mark.slow
@pytest.mark.campaign  # ~8-25 min each: outside CI's time budget, run with -m campaign
def test_issue_26_a_long_effect_free_campaign_is_never_a_catalogue_effect():
    js = run({}, 1200, seed=26)
    assert js["effect"] in ("none", "unexplained") and js["effects"] == [], js["note"]
    if js["gap_before"] <= 0.1:  # within the tolerance: none, whatever the significance
        assert js["effect"] == "none", js["note"]


@pytest.mark.slow
@pytest.mark.campaign  # ~8-25 min each: outside CI's time budget, run with -m campaign
def test_issue_26_a_decisive_second_effect_is_named():
    hidden = {"beam_angle_offset": {"offset": -0.3}, "cnr_gradient_weighting": {"scale": 3.0}}
    js = run(hidden, 2400, seed=26)
    sets = named(js)
    assert len(sets) == 2, js["note"]
    for effect in hidden:  # each hidden effect named, or tied within its look-alike group
        group = set().union({effect}, *(g for g in LOOK_ALIKE if effect in g))
        assert any(effect in s and s <= group for s in sets), (effect, sets, js["note"])
    assert js["gap_after"] <= 0.5 * js["gap_before"]
