"""The certified values of two default runs side by side, bin by bin (docs/validation.md).

``python benchmarks/certified_table.py BEFORE AFTER [--heights 160 200] [--update PAGE]``
reads each run directory's ``budget.nc`` and ``simulated.nc`` and prints, per height and
wind-speed bin certified in either run, the relative expanded uncertainty (k = 2, %) with its
Monte Carlo numerical tolerance (``numerical_tolerance``, JCGM 101 §7.9; "not settled" when
``numerical_flag`` says so) and the excess kurtosis (``scipy.stats.kurtosis``, Fisher, biased)
of the bin's trials' (L − R)/R (replica 0 and every further replica, binned by each trial's
own reference speed, as the budget bins them); then each run's headline range, its number of
values that did not settle (``monte_carlo_not_settled``), replicas and trials, and the range of
the excess kurtosis over the certified bins of each height; then, per height and band of the
period's CNR, the number of trials and the mean and standard deviation of their (L − R)/R.
``--update PAGE`` writes the output between the page's ``<!-- certified-table:begin -->`` and
``<!-- certified-table:end -->`` lines instead, so the table in the documentation is this
script's output and nothing else.
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import xarray as xr
from scipy import stats

BEGIN, END = "<!-- certified-table:begin -->", "<!-- certified-table:end -->"


#: CNR bands (dB) of the second table: the filter's neighbourhood in 1-dB steps, then wider.
CNR_BANDS = ((-23, -22), (-22, -21), (-21, -20), (-20, -19), (-19, -18), (-18, -16), (-16, -10), (-10, 0))


def trials(sim: xr.Dataset, height: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lidar and reference speed (m/s) and period CNR (dB) of every trial at ``height`` (replica 0 first)."""
    lid = sim["lidar_wind_speed"].sel(height=height).values
    ref = sim["reference_wind_speed"].sel(height=height).values
    cnr = sim["cnr"].sel(height=height).values
    if "trial_height" in sim.variables:
        at = sim["trial_height"].values == height
        of_key = dict(zip(sim["period_key"].values.tolist(), cnr.tolist(), strict=True))
        lid = np.concatenate([lid, sim["trial_lidar_wind_speed"].values[at]])
        ref = np.concatenate([ref, sim["trial_reference_wind_speed"].values[at]])
        cnr = np.concatenate([cnr, [of_key[k] for k in sim["trial_period_key"].values[at].tolist()]])
    ok = np.isfinite(lid) & np.isfinite(ref)
    return lid[ok], ref[ok], cnr[ok]


def trial_deviations(sim: xr.Dataset, height: float, edges: np.ndarray) -> list[np.ndarray]:
    """(L − R)/R (%) of every trial at ``height``, per wind-speed bin of ``edges`` (reference speed)."""
    lid, ref, _ = trials(sim, height)
    idx = np.searchsorted(edges, ref, side="right") - 1
    idx[ref == edges[-1]] = edges.size - 2
    return [100.0 * (lid[idx == b] / ref[idx == b] - 1.0) for b in range(edges.size - 1)]


def by_cnr(sim: xr.Dataset, height: float) -> list[tuple[int, float, float]]:
    """Per CNR band: trials, mean and standard deviation of (L − R)/R (%) at ``height``."""
    lid, ref, cnr = trials(sim, height)
    dev = 100.0 * (lid / ref - 1.0)
    out = []
    for lo, hi in CNR_BANDS:
        sel = (cnr >= lo) & (cnr < hi)
        out.append((int(sel.sum()), float(dev[sel].mean()) if sel.any() else np.nan,
                    float(dev[sel].std()) if sel.any() else np.nan))
    return out


def run_summary(path: Path, heights: list[float]) -> dict:
    budget = xr.open_dataset(path / "budget.nc")
    sim = xr.open_dataset(path / "simulated.nc")
    bounds = budget["wind_speed_bounds"].values
    edges = np.append(bounds[:, 0], bounds[-1, 1])
    certified = budget["bin_flag"] == 0
    rel = budget["relative_expanded_uncertainty"].where(certified)
    out = {"headline": (float(rel.min()), float(rel.max())),
           "not_settled": int(budget.attrs.get("monte_carlo_not_settled", 0)),
           "replicas": int(budget.attrs.get("monte_carlo_replicas", 1)),
           "trials": int(budget.attrs.get("monte_carlo_trials", 0)), "bins": {},
           "cnr": {z: by_cnr(sim, z) for z in heights}}
    for z in heights:
        devs = trial_deviations(sim, z, edges)
        for j, u in enumerate(budget["wind_speed"].values):
            if not bool(certified.sel(height=z).values[j]):
                continue
            one = budget.sel(height=z, wind_speed=u)
            out["bins"][(z, float(u))] = {
                "value": float(one["relative_expanded_uncertainty"]),
                "tolerance": float(one["numerical_tolerance"]) if "numerical_tolerance" in one else np.nan,
                "settled": int(one["numerical_flag"]) != 1 if "numerical_flag" in one else True,
                "kurtosis": float(stats.kurtosis(devs[j])) if devs[j].size > 3 else np.nan,
            }
    return out


def _cell(entry: dict | None) -> tuple[str, str]:
    if entry is None:
        return "—", "—"
    text = f"{entry['value']:.2f} ± {entry['tolerance']:.2f}"
    if not entry["settled"]:
        text += " not settled"
    return text, f"{entry['kurtosis']:.1f}"


def table(before: dict, after: dict, heights: list[float]) -> str:
    lines = ["| height (m) | bin (m/s) | before: U ± δ (%) | before: kurtosis | after: U ± δ (%) "
             "| after: kurtosis |", "|---|---|---|---|---|---|"]
    keys = sorted(set(before["bins"]) | set(after["bins"]))
    for z, u in keys:
        b, a = _cell(before["bins"].get((z, u))), _cell(after["bins"].get((z, u)))
        lines.append(f"| {z:g} | {u:g} | {b[0]} | {b[1]} | {a[0]} | {a[1]} |")
    lines.append("")
    for name, run in (("before", before), ("after", after)):
        kurt = {z: [e["kurtosis"] for (h, _), e in run["bins"].items() if h == z] for z in heights}
        spread = "; ".join(f"{z:g} m {min(k):.1f} to {max(k):.1f}" for z, k in kurt.items() if k)
        lines.append(f"- **{name}:** headline {run['headline'][0]:.2f} % to {run['headline'][1]:.2f} % "
                     f"(k = 2); {run['not_settled']} certified value(s) not settled; {run['replicas']} "
                     f"replicas, {run['trials']:,} trials; excess kurtosis of the certified bins {spread}")
    lines += ["", "| height (m) | period CNR (dB) | before: trials | before: mean, sd of (L − R)/R (%) "
              "| after: trials | after: mean, sd of (L − R)/R (%) |", "|---|---|---|---|---|---|"]
    for z in heights:
        for (lo, hi), b, a in zip(CNR_BANDS, before["cnr"][z], after["cnr"][z], strict=True):
            if b[0] == a[0] == 0:
                continue
            lines.append(f"| {z:g} | [{lo}, {hi}) | {b[0]:,} | {b[1]:+.2f}, {b[2]:.2f} | {a[0]:,} "
                         f"| {a[1]:+.2f}, {a[2]:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    parser.add_argument("--heights", type=float, nargs="+", default=[160.0, 200.0])
    parser.add_argument("--update", type=Path, metavar="PAGE",
                        help=f"write the table between the page's {BEGIN} and {END} lines")
    args = parser.parse_args(argv)
    text = table(run_summary(args.before, args.heights), run_summary(args.after, args.heights), args.heights)
    if args.update is None:
        sys.stdout.write(text)
        return 0
    page = args.update.read_text(encoding="utf-8")
    if page.count(BEGIN) != 1 or page.count(END) != 1:
        sys.stderr.write(f"{args.update}: expected one {BEGIN} and one {END} line\n")
        return 2
    head, rest = page.split(BEGIN)
    _, tail = rest.split(END)
    args.update.write_text(f"{head}{BEGIN}\n{text}{END}{tail}", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
