"""Derive every catalogue effect's model-form share from the engine's alternatives (docs/diagnose.md).

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/diagnose_form_shares.py [--periods 300] [--json OUT]

For each condition set of :data:`SETS` (``hidden_effect_conditions``: 4 heights, its seed and
I_ref) and each nominal lidar — the field file's attributes (Gaussian RWF: alternatives
``reference_level``, ``coherence``, ``length_scale``) and the same with the bench RWF artefact
(``--rwf``: a measured RWF, CNR-weighted, adding ``rwf_shape``) — every effect at its realistic
strength is simulated under the nominal model and each alternative with the same seeds
(:func:`lidarcal.diagnose.model_form.derived_shares`).  Prints each effect's share u with its
Monte Carlo standard error and the per-alternative ratios k_a; the share recorded in the
catalogue (``Effect.derived_form``) is the largest u over the sets and lidars, with its error.
"""

import argparse
import json
import os
import time

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

#: (conditions seed, turbulence_reference I_ref): the synthetic generator's default TI and a
#: turbulent one (TI ~0.13-0.3 at 80 m, where the hybrid weight matters).
SETS = ((501, 0.10), (502, 0.16))
HEIGHTS = (40.0, 80.0, 120.0, 160.0)
BASE_SEED = 2611


def main() -> None:
    from lidarcal.diagnose.generate import generate_field_campaign, hidden_effect_conditions
    from lidarcal.diagnose.model_form import derived_shares
    from lidarcal.lidar import LidarModel
    from lidarcal.rwf import range_weighting_function

    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--periods", type=int, default=300)
    p.add_argument("--json", help="write every result here")
    args = p.parse_args()
    run = {"scheduler": "synchronous"}
    rows: list[dict] = []
    for seed, iref in SETS:
        cond = hidden_effect_conditions(args.periods, HEIGHTS, seed=seed, turbulence_reference=iref)
        attrs = generate_field_campaign(cond.isel(time=slice(0, 2)), execution=run)  # the lidar_* attributes
        lidars = {"field attributes": LidarModel.from_attrs(attrs),
                  "measured RWF": LidarModel.from_attrs(attrs, rwf=range_weighting_function())}
        for lidar, model in lidars.items():
            t0 = time.process_time()
            out = derived_shares(cond, model, base_seed=BASE_SEED, execution=run)
            cpu = time.process_time() - t0
            print(f"\n== conditions seed {seed}, I_ref {iref:g}, {args.periods} periods x {len(HEIGHTS)} "
                  f"heights, {lidar} ({cpu:.0f} s CPU)")
            for e, d in out.items():
                ks = ", ".join(f"{a} {k:.4f}+-{d.ratio_errors[a]:.4f}" for a, k in d.ratios.items())
                print(f"{e:28s} u = {d.share:.4f} +- {d.standard_error:.4f}  change {d.change:.3f} % rms  "
                      f"[{ks}]")
                rows.append({"seed": seed, "turbulence_reference": iref, "lidar": lidar, "effect": e,
                             "share": d.share, "standard_error": d.standard_error, "ratios": d.ratios,
                             "ratio_errors": d.ratio_errors, "change": d.change, "cells": d.cells,
                             "parameters": d.parameters, "cpu_s": cpu})
    print("\n== recorded: the largest share over the sets and lidars (Effect.derived_form)")
    for e in dict.fromkeys(r["effect"] for r in rows):
        best = max((r for r in rows if r["effect"] == e), key=lambda r: r["share"])
        print(f"{e:28s} ({best['share']:.3f}, {best['standard_error']:.3f})  seed {best['seed']}, "
              f"{best['lidar']}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"sets": SETS, "heights": HEIGHTS, "base_seed": BASE_SEED, "periods": args.periods,
                       "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
