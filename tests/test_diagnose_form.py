"""Model-form shares derived from the engine's alternatives (diagnose/model_form.py, docs/diagnose.md)."""

import numpy as np
import pytest

from lidarcal.diagnose.effects import DERIVED_FORM_SOURCE, EFFECTS, model_form_share
from lidarcal.diagnose.model_form import combine_ratios, derived_shares, response_ratio


def test_a_response_scaled_by_an_alternative_gives_that_scale_and_the_rectangular_share():
    # hand computation: without drivers the smoothed response is the per-height (weighted) mean,
    # so an alternative whose change is exactly 1.2 x the nominal one gives k = 1.2, and a second
    # one at 0.9 gives u = sqrt((0.2^2 + 0.1^2) / 3), the budget's rectangular rule
    rng = np.random.default_rng(np.random.SeedSequence([26, 1]))
    base = rng.normal(0.01, 0.002, size=(200, 3))
    nominal = np.broadcast_to(base.mean(axis=0), base.shape).copy()  # already smooth: S(nominal) = nominal
    valid, weights = np.ones(base.shape, bool), np.ones(base.shape)
    k1, psi1 = response_ratio(1.2 * nominal, nominal, {}, (), valid, weights)
    k2, psi2 = response_ratio(0.9 * nominal, nominal, {}, (), valid, weights)
    assert k1 == pytest.approx(1.2, rel=1e-12) and k2 == pytest.approx(0.9, rel=1e-12)
    u, se = combine_ratios({"a": k1, "b": k2}, {"a": psi1, "b": psi2})
    assert u == pytest.approx(np.sqrt((0.2**2 + 0.1**2) / 3.0), rel=1e-12)
    assert se == pytest.approx(0.0, abs=1e-12)  # an exact scale has no scatter


def test_the_delta_method_error_is_the_spread_over_independent_draws():
    # the standard error of k (influence over periods) against the spread of k over 400 independent
    # noisy draws; with 400 draws the sample sd is within 3 x 1/sqrt(2 * 399) = 11 % of the truth
    rng = np.random.default_rng(np.random.SeedSequence([26, 2]))
    ti = rng.uniform(0.05, 0.25, size=(150, 2))
    nominal = 0.02 * ti**2 + rng.normal(0.0, 2e-4, ti.shape)
    conds, valid, weights = {"turbulence_intensity": ti}, np.ones(ti.shape, bool), np.ones(ti.shape)
    ks, ses = [], []
    for _ in range(400):
        alt = 0.8 * nominal + rng.normal(0.0, 3e-4, ti.shape)
        k, psi = response_ratio(alt, nominal, conds, ("turbulence_intensity",), valid, weights)
        ks.append(k)
        ses.append(np.sqrt(np.sum(psi**2)))
    assert np.mean(ks) == pytest.approx(0.8, abs=3 * np.std(ks) / np.sqrt(400))
    assert np.median(ses) == pytest.approx(np.std(ks, ddof=1), rel=0.11)


def test_the_recorded_shares_are_the_engines_on_other_conditions_and_seeds():
    # recompute hybrid_weight and reference_gain (both exact shortcuts: 4 simulations) on a small
    # turbulent campaign of other conditions and another seed than the recorded ones
    # (DERIVED_FORM_SOURCE); the hybrid weight's share must lie within 3 combined Monte Carlo
    # standard errors of the recorded one
    from lidarcal.diagnose.generate import hidden_effect_conditions

    assert "seed" in DERIVED_FORM_SOURCE
    cond = hidden_effect_conditions(40, (80.0, 160.0), seed=26, turbulence_reference=0.16)
    out = derived_shares(cond, effects=["hybrid_weight", "reference_gain"], base_seed=99,
                         execution={"scheduler": "synchronous"})
    recorded, recorded_se = EFFECTS["hybrid_weight"].derived_form
    got = out["hybrid_weight"]
    bound = 3.0 * np.hypot(got.standard_error, recorded_se)
    assert abs(got.share - recorded) <= bound, (got.share, got.standard_error, recorded, recorded_se)
    # a pure reference-side ratio does not depend on the turbulence model: ~0 (a result; its
    # few 1e-4 move with L/R, i.e. with the conditions, more than with the Monte Carlo noise)
    assert out["reference_gain"].share < 0.01 and EFFECTS["reference_gain"].derived_form[0] < 0.01
    # the hybrid weight's response is a turbulence statistic: Ed. 2's shorter coherence shrinks it
    assert out["hybrid_weight"].ratios["coherence"] < 1.0 - 3 * out["hybrid_weight"].ratio_errors["coherence"]


def test_the_share_used_is_the_largest_of_default_derived_and_fitted():
    hybrid, gain = EFFECTS["hybrid_weight"], EFFECTS["reference_gain"]
    assert model_form_share(hybrid, 0.075) == max(0.075, hybrid.derived_form[0], hybrid.model_form)
    assert model_form_share(gain, 0.075) == 0.075  # its derived share is far below the default
    assert model_form_share(gain, 0.5) == 0.5
    assert all(e.derived_form is not None for i, e in EFFECTS.items() if i != "none")


def test_the_catalogue_records_the_largest_stored_share_with_its_error():
    # Effect.derived_form is what benchmarks/diagnose_form_shares.py printed (its --json output is
    # stored): for each effect the largest share over the condition sets and lidars, 4 decimals
    import json
    from pathlib import Path

    from lidarcal.diagnose.effects import DERIVED_FORM

    path = Path(__file__).parent / "data" / "diagnose_form_shares.json"
    rows = json.loads(path.read_text(encoding="utf-8"))["rows"]
    assert set(DERIVED_FORM) == {e for e in EFFECTS if e != "none"} == {r["effect"] for r in rows}
    for eid, (share, se) in DERIVED_FORM.items():
        best = max((r for r in rows if r["effect"] == eid), key=lambda r: r["share"])
        assert (share, se) == (round(best["share"], 4), round(best["standard_error"], 4)), eid
        assert EFFECTS[eid].derived_form == DERIVED_FORM[eid]
