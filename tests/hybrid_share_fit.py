"""The fit set of the hybrid weight's model-form share (a test helper; run as a script it writes the data).

``lidarcal diagnose`` adds a model-form (GUM Type B) standard uncertainty u × |θ̂ − θ₀| to a
fitted parameter's block-bootstrap one (``docs/diagnose.md``, "Model-form share").  Whether the
hybrid weight needs a larger u than the default is measured here, on campaigns of the converged
independent simulator (``tests/independent_campaign.py``) that no test asserts on: the FIT SET.

* seeds 101 and 102: 300 periods at 40/100/160 m, the simulator's TI distribution;
* seed 103: 300 periods at 60/100/140 m, every TI × 1.3 (a more turbulent site);
* each with a hybrid weight p = 0 and p = 1 hidden against a nominal 0.5 (the same turbulence
  for both: paired), diagnosed with the hybrid weight as the only candidate and no model-form
  share (``model_uncertainty=0``), so that the uncertainty recorded is the bootstrap's alone.

For each: the unconstrained fit p̂ (what the data ask for, also beyond [0, 1]) and its bootstrap
standard error, and the share of the weighted residual sum of squares that the hybrid weight and
its look-alike (an over-speeding cup, whose response grows with TI rather than TI²) each explain
alone.  Two things are fitted from these (``docs/diagnose.md`` computes both from the stored
file): the error of the fitted change, e = (p̂ − p)/(p − p₀), beyond its bootstrap part
s = se/|p − p₀| (method of moments, mean(e²) − mean(s²)); and how much better the look-alike can
fit a hybrid weight's residual than the hybrid weight's own response, q = (RSS_hybrid −
RSS_cup)/(RSS_none − RSS_cup), which the tie rule allows a runner-up with share u up to
(1.96 u)².

The ASSERT SET is disjoint (seed 3, heights 40/80/160 m and 40/80/120/160 m, the plain TI
distribution): ``tests/test_diagnose_edges.py`` and the slow matrix of
``tests/test_diagnose_independent.py``.

``python tests/hybrid_share_fit.py`` rewrites ``tests/data/hybrid_share_fit.json`` (about 8 CPU
minutes).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

DATA = Path(__file__).parent / "data" / "hybrid_share_fit.json"
NOMINAL = 0.5
#: (seed, heights, turbulence_scale) of the fit set; 300 periods each.
FIT_SET = [(101, (40.0, 100.0, 160.0), 1.0), (102, (40.0, 100.0, 160.0), 1.0),
           (103, (60.0, 100.0, 140.0), 1.3)]
N_PERIODS = 300


def fit_one(seed: int, heights, turbulence_scale: float, p_true: float) -> dict:
    """Diagnose one fit-set campaign with each candidate alone; return what the share is fitted on.

    The hybrid weight's unconstrained p̂ and bootstrap standard error, and the share of the
    weighted residual sum of squares explained by the hybrid weight and by its look-alike, an
    over-speeding cup, each fitted alone to the same residual (same seeds).
    """
    from independent_campaign import make_field_campaign

    from lidarcal.diagnose import diagnose

    field = make_field_campaign({"hybrid_weight": {"p": p_true}}, n_periods=N_PERIODS, heights=heights,
                                seed=seed, hybrid_weight=NOMINAL, turbulence_scale=turbulence_scale)
    fits = {}
    for effect in ("hybrid_weight", "reference_overspeeding"):
        result = diagnose(field, candidates=[effect], model_uncertainty=0.0,
                          execution={"scheduler": "synchronous"})
        # named (refined on the secant) or, if out of its range, as fitted alone: the same object
        fits[effect] = (result, next(c for c in result.candidates if c.effect.id == effect))
    result, hybrid = fits["hybrid_weight"]
    return {"seed": seed, "heights": list(heights), "turbulence_scale": turbulence_scale,
            "n_periods": N_PERIODS, "nominal": NOMINAL, "p_true": p_true, "p_free": hybrid.free["p"],
            "se": hybrid.stderr["p"], "answer": result.effect_id, "explained": hybrid.explained,
            "explained_by_overspeeding": fits["reference_overspeeding"][1].explained}


def main() -> None:
    sys.path.insert(0, str(Path(__file__).parent))
    rows = []
    for seed, heights, scale in FIT_SET:
        for p_true in (0.0, 1.0):
            t = time.process_time()
            rows.append(fit_one(seed, heights, scale, p_true))
            print(rows[-1], f"{time.process_time() - t:.0f} s", flush=True)
    DATA.write_text(json.dumps({"about": "tests/hybrid_share_fit.py", "campaigns": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
