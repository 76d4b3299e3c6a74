"""The JCGM 101 figures of a default run, as docs/validation.md quotes them.

``python benchmarks/jcgm_figures.py RUN`` reads ``RUN/budget.nc`` and prints, in the words of
the bullet "Monte Carlo (JCGM 101)" of docs/validation.md's "The default run beside Figures 8
and 9", the figures ``tests/test_pipeline.py::test_sample_lidar_reproduces_the_papers_findings``
checks there: replicas and trials, how many of the bins certified but for the Monte Carlo did
not settle (per height), how many settled certified bins remain, in how many the coverage
interval is certified instead of ±U, the probability ±U holds, the smallest ν_eff and the
relative standard uncertainty of the certified bins per band of heights.
"""

import sys

import xarray as xr


def figures(run: str) -> list[str]:
    b = xr.open_dataset(f"{run}/budget.nc")
    ok, missed = b.bin_flag == 0, b.bin_flag == 4
    assessed = int((b.numerical_flag <= 1).sum())
    per_height = ", ".join(f"{int(missed.sel(height=h).sum())} at {h:g} m" for h in b.height.values
                           if int(missed.sel(height=h).sum()))
    cover = b.expanded_uncertainty_coverage.where(ok)
    rel = b.relative_uncertainty.where(ok).sel(wind_speed=slice(4, 16))
    groups = ((slice(None, 140), "40–140 m"), (160.0, "160 m"), (200.0, "200 m"))
    bands = "; ".join(f"{float(rel.sel(height=h).min()):.2f}–{float(rel.sel(height=h).max()):.2f} % "
                      f"at {label}" for h, label in groups)
    return [
        f"{int(b.attrs['monte_carlo_replicas'])} replicas, {int(b.attrs['monte_carlo_trials']):,} trials",
        f"{int(missed.sum())} of the {assessed} bins certified but for the Monte Carlo ({per_height})",
        f"over the {int(ok.sum())} settled certified bins",
        f"the coverage interval is certified instead of ±U in {int(b.attrs['certified_coverage_intervals'])} "
        "of them",
        f"±U holds {float(cover.min()):.1f}–{float(cover.max()):.1f} % of the distribution",
        f"ν_eff is at least {int(b.effective_degrees_of_freedom.where(ok).min())}",
        f"relative standard uncertainty {bands}",
    ]


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    print("\n".join(figures(sys.argv[1])))
