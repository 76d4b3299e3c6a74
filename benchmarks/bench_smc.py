"""Benchmark: ``lidarcal smc`` on a one-year campaign (52,560 periods x 12 heights), both routes.

Targets (docs/performance.md): the 50-2 route in seconds, the Monte Carlo route <= 15 min on 2
cores, memory flat in the campaign's length.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_smc.py [--periods 52560] [--heights 12]
        [--mc-periods 1008] [--repeat 3] [--mc-periods-per-bin N|all] [--no-year-monte-carlo]
        [--workers 2] [--scheduler processes] [--certificate CERT.nc]

The certificate is a small one certifying the campaign's heights (budget and sensitivities of
seeded hand-made records, the simulated bench cube and the sample pulse's RWF: the route's cost
does not depend on its numbers), unless ``--certificate`` gives one (then the campaign takes its
heights).  The campaign is synthetic stochastic conditions (:func:`lidarcal.conditions.synthetic_conditions`).

Printed (each Monte Carlo run in a fresh process, so that its peak RSS is its own):

1. the 50-2 route over the whole campaign (wall, CPU, peak memory);
2. the baseline: the Monte Carlo route simulating **every** period (``--mc-periods-per-bin all``)
   of a ``--mc-periods`` campaign, ``--repeat`` times: median wall, CPU and CPU per simulated
   cell, and the whole campaign projected from it (its cells per period-height and CPU per cell);
3. the Monte Carlo route with the stratified subsample (``--mc-periods-per-bin``, default the
   package's) on a quarter and on the whole campaign: wall, CPU, cells simulated, peak RSS of the
   main process and of the largest worker, and the ratio of the whole campaign's CPU to the
   projected full simulation's (same run, same machine).
"""

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

SERIAL = "WLS866-0195"
#: A WindCube's usual twelve heights (m): 10 m steps to 100 m, then 20 m steps to 200 m.
TYPICAL_HEIGHTS = (40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0, 120.0, 140.0, 160.0, 180.0, 200.0)


def certificate(d: Path, heights) -> Path:
    """A sealed certificate of ``heights`` from seeded hand-made records (no simulation)."""
    import numpy as np
    import xarray as xr

    from lidarcal.analysis import budget, sensitivity
    from lidarcal.analysis.rule import CertificationRule
    from lidarcal.analysis.terms import PAPER_INPUTS, uncertainty_terms
    from lidarcal.bench import build_cube, simulate_run
    from lidarcal.certificate import make_certificate
    from lidarcal.certificate.seal import write_certificate
    from lidarcal.cf import height_coord, time_coord
    from lidarcal.data import sample_file
    from lidarcal.io import open_artefact, write_artefact
    from lidarcal.lidar import LidarModel
    from lidarcal.provenance import stamp
    from lidarcal.rwf import range_weighting_function
    from lidarcal.units import Q_

    rng = np.random.default_rng(np.random.SeedSequence([2025, 1]))
    n, z = 1500, np.asarray(heights, dtype=float)
    shape = (n, z.size)
    ws, ti = rng.uniform(3.0, 17.0, shape), rng.uniform(0.04, 0.25, shape)
    ref = ws
    lid = ref * (1 + (-6.0 * (ti - 0.1) + rng.normal(0, 0.8, shape)) / 100)
    units = {
        "wind_speed": "m s-1",
        "wind_from_direction": "degree",
        "turbulence_intensity": "1",
        "wind_shear_exponent": "1",
        "cnr": "dB",
        "cnr_gradient": "dB m-1",
    }
    data = {
        "wind_speed": ws,
        "wind_from_direction": rng.uniform(0, 360, shape),
        "turbulence_intensity": ti,
        "wind_shear_exponent": rng.uniform(-0.1, 0.5, shape),
        "cnr": rng.uniform(-24, -6, shape),
        "cnr_gradient": rng.uniform(-0.08, 0.08, shape),
        "lidar_wind_speed": lid,
        "reference_wind_speed": ref,
    }
    rec = xr.Dataset(
        {
            k: (("time", "height"), v, {"units": units.get(k, "m s-1"), "long_name": k})
            for k, v in data.items()
        },
        coords={
            "time": time_coord(np.datetime64("2023-01-01") + np.arange(n) * np.timedelta64(600, "s")),
            "height": height_coord(z),
        },
    )
    run = simulate_run(seed=3, accumulation_time="20 s", lidar_serial=SERIAL)
    cube, _ = build_cube(run.rtd, run.control)
    cube = open_artefact(
        write_artefact(
            stamp(cube, "bench_cube", title="cube", summary="bench cube", call="bench_smc"), d / "cube.nc"
        )
    )
    rwf = open_artefact(
        write_artefact(
            range_weighting_function(pulse_file=sample_file("rwf/pulse_example.csv")), d / "rwf.nc"
        )
    )
    rec.attrs = {
        "lidarcal_artefact": "simulated_rtd",
        "lidar_serial": SERIAL,
        "lidarcal_base_seed": 20240101,
        "lidarcal_lidar_model": LidarModel.from_artefacts(cube=cube, rwf=rwf).to_json(),
    }
    # three further replicas of every period (fresh noise, the same conditions), as the adaptive Monte
    # Carlo stores them: JCGM 101 7.9 settles a bin only with replicas, and a certificate without
    # settled bins certifies none (the campaign's Monte Carlo route would then have no bin to settle)
    from lidarcal.campaign.adaptive import with_trials
    from lidarcal.schema import output_attrs

    rec["period_key"] = ("time", 1_672_531_200 + 600 * np.arange(n, dtype=np.int64),
                         output_attrs("simulated_rtd", "period_key"))
    period, height = np.nonzero(np.ones(shape, dtype=bool))
    def replica() -> np.ndarray:
        return (ref * (1 + (-6.0 * (ti - 0.1) + rng.normal(0, 0.8, shape)) / 100))[period, height]

    trials = [{"replica": r, "period": period, "height": z[height], "lidar_wind_speed": replica(),
               "reference_wind_speed": ref[period, height]} for r in range(1, 4)]
    rec = with_trials(rec, trials)
    rec.to_netcdf(d / "records.nc")
    records = open_artefact(d / "records.nc")
    terms = open_artefact(
        write_artefact(
            uncertainty_terms(
                Q_(np.arange(0.25, 40.01, 0.25), "m/s"), **{**PAPER_INPUTS, "height": Q_(z, "m")}
            ),
            d / "terms.nc",
        )
    )
    sens = [sensitivity(records, v) for v in ("turbulence_intensity", "wind_shear_exponent", "cnr_gradient")]
    cert = make_certificate(
        budget=budget(records, terms=terms, rule=CertificationRule(significant_digits=1)),
        sensitivities=sens,
        cube=cube,
        rwf=rwf,
        terms=terms,
        records=records,
        demonstration=True,
    )
    return write_certificate(cert, d / "certificate.nc")


def campaign(d: Path, n: int, heights, name: str) -> Path:
    """A synthetic campaign of ``n`` periods at ``heights``, as the lidar's conditions file."""
    from lidarcal.conditions import synthetic_conditions

    ds = synthetic_conditions(n, heights, seed=7, start="2024-01-01T00:00")
    ds.attrs.update(lidar_serial=SERIAL, lidar_cone_angle=28.0)
    path = d / f"{name}.nc"
    ds.to_netcdf(path)
    return path


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MB).

    ``VmHWM`` of /proc/self/status where there is one: getrusage's ``ru_maxrss`` survives fork and
    exec, so in a child it is never below its parent's peak at the fork.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _covered(path: Path) -> int:
    """Period-heights the certificate covers, as the written ``smc`` artefact says."""
    from lidarcal.io import open_artefact

    return int(open_artefact(path, load=False).attrs["covered_periods"])


def cpu_seconds() -> float:
    """CPU time (user + system) of this process and of its finished children (the pool's workers)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run(
    cert: Path, cond: Path, out: Path, *, monte_carlo: bool, opts: dict, periods_per_bin=None
) -> tuple[float, object, float]:
    """Time ``smc`` + the artefact + its file; return (seconds, campaign, CPU seconds).

    Untraced: tracemalloc would slow the Python-level work (a block's reads, its xarray objects)
    several times over; memory is the process's peak RSS, each Monte Carlo run in a fresh process.
    """
    from lidarcal.io import write_artefact
    from lidarcal.smc import smc, smc_dataset

    t0, c0 = time.perf_counter(), cpu_seconds()
    c = smc(cert, conditions=cond, monte_carlo=monte_carlo, execution=opts,
            periods_per_bin=periods_per_bin)
    write_artefact(smc_dataset(c), out, overwrite=True)
    elapsed, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    return elapsed, c, cpu


def case(args) -> None:
    """One Monte Carlo run in this (fresh) process; print its figures as one JSON line."""
    import json
    import warnings

    warnings.simplefilter("ignore")
    opts = {"scheduler": args.scheduler, "workers": args.workers, "chunk": 64}
    ppb = None if args.mc_periods_per_bin in ("all", "none") else int(args.mc_periods_per_bin)
    mc_on = args.mc_periods_per_bin != "none"  # none: the 50-2 route alone
    t, c, cpu = run(Path(args.certificate), Path(args.case), Path(args.case).with_suffix(".smc.nc"),
                    monte_carlo=mc_on, opts=opts, periods_per_bin=ppb)
    if not mc_on:
        print(json.dumps({"wall": t, "cpu": cpu, "rss": peak_rss_mb(), "load": os.getloadavg()[0]}))
        return
    mc = c.monte_carlo
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    print(json.dumps({
        "wall": t, "cpu": cpu, "cells": int(mc.count.sum()), "simulated": mc.simulated,
        "period_heights": int(c.conditions["wind_speed"].count()), "replicas": mc.replicas,
        "rss": peak_rss_mb(), "worker_rss": kids,
        "load": os.getloadavg()[0],
    }))


def child(script_args: list[str]) -> dict:
    """Run :func:`case` in a fresh Python process; return its figures."""
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, __file__, *script_args], check=True, stdout=subprocess.PIPE,
                         text=True)  # the child's log and any traceback go to this process's stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    """Run the benchmark and print its figures."""
    import logging
    import warnings

    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--periods", type=int, default=52560, help="periods of the campaign (default: one year)")
    p.add_argument(
        "--heights",
        type=int,
        default=12,
        help="heights of the campaign (default 12: 40 to 100 m every 10 m, then to 200 m every 20 m)",
    )
    p.add_argument(
        "--mc-periods",
        type=int,
        default=1008,
        help="length of the baseline campaign simulated in full (default: one week)",
    )
    p.add_argument("--repeat", type=int, default=3, help="baseline runs (medians; default 3)")
    p.add_argument("--mc-periods-per-bin", default=None,
                   help="periods per height and bin of the subsampled route (default: the package's)")
    p.add_argument("--parts", default="iec,baseline,memory,year",
                   help="what to run, comma-separated (default all): iec (the 50-2 route), baseline, memory "
                        "(quarter and whole campaign at --memory-periods-per-bin), year (the whole campaign "
                        "at --mc-periods-per-bin)")
    p.add_argument("--memory-periods-per-bin", default="10",
                   help="periods per bin of the quarter / whole-campaign memory pair (default 10: memory "
                        "depends on it, not on the campaign's length)")
    p.add_argument("--certificate", help="use this certificate (the campaign takes its heights)")
    p.add_argument("--scheduler", default="processes")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--case", help=argparse.SUPPRESS)  # internal: one run in a fresh process
    args = p.parse_args()
    if args.case:
        case(args)
        return
    from lidarcal.smc.subsample import DEFAULT_PERIODS_PER_BIN

    ppb = str(args.mc_periods_per_bin or DEFAULT_PERIODS_PER_BIN)
    warnings.simplefilter("ignore")
    logging.getLogger("pint").setLevel(logging.ERROR)
    opts = {"scheduler": args.scheduler, "workers": args.workers, "chunk": 64}
    common = ["--scheduler", args.scheduler, "--workers", str(args.workers)]
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        if args.certificate:
            import lidarcal

            cert = Path(args.certificate)
            heights = [float(h) for h in lidarcal.open_artefact(cert)["budget_height"].values]
        else:
            heights = (
                list(TYPICAL_HEIGHTS[: args.heights])
                if args.heights <= len(TYPICAL_HEIGHTS)
                else [40.0 + 20.0 * k for k in range(args.heights)]
            )
            cert = certificate(d, heights)
        from lidarcal.smc.certified import read_certified

        bud = read_certified(cert).budget
        certified = int((bud["bin_flag"] == read_certified(cert).certified_flag).sum())
        print(
            f"load: {os.getloadavg()[0]:.1f} (1 min), {os.cpu_count()} CPUs; scheduler {args.scheduler} x "
            f"{args.workers}; heights {heights}; the certificate certifies {certified} of "
            f"{bud['bin_flag'].size} (height, wind-speed bin): the Monte Carlo route settles those"
        )
        parts = set(args.parts.split(","))
        year = campaign(d, args.periods, heights, "year")
        cells = args.periods * len(heights)
        per_cell = float("nan")
        if "iec" in parts:
            t, c, cpu = run(cert, year, d / "smc-year-iec.nc", monte_carlo=False, opts=opts)
            print(
                f"50-2 route, {args.periods} periods x {len(heights)} heights: {t:7.1f} s wall, {cpu:7.1f} s "
                f"CPU (target: seconds); "
                f"{_covered(d / 'smc-year-iec.nc')} of {cells} period-heights covered", flush=True
            )
        if "baseline" in parts:
            per_cell = baseline(args, d, cert, heights, common, cells)
        runs = []
        if "memory" in parts:
            for label, m in (("quarter", max(2, args.periods // 4)), ("whole campaign", args.periods)):
                path = year if m == args.periods else campaign(d, m, heights, f"q{m}")
                r = child(["--case", str(path), "--certificate", str(cert), "--mc-periods-per-bin", "none",
                           *common])
                print(f"50-2 route alone, {label}: {m} periods x {len(heights)} heights: {r['wall']:.1f} s "
                      f"wall, {r['cpu']:.1f} s CPU; peak RSS {r['rss']:.0f} MB (fresh process)", flush=True)
            runs += [("quarter", max(2, args.periods // 4), args.memory_periods_per_bin),
                     ("whole campaign", args.periods, args.memory_periods_per_bin)]
        if "year" in parts:
            runs.append(("whole campaign", args.periods, ppb))
        rss: dict[tuple[str, str], dict] = {}
        for label, m, k in runs:
            path = year if m == args.periods else campaign(d, m, heights, f"q{m}")
            r = child(["--case", str(path), "--certificate", str(cert), "--mc-periods-per-bin", k, *common])
            rss[label, k] = r
            full = per_cell * m * len(heights)  # the baseline's CPU for replica 0 of this campaign
            print(
                f"Monte Carlo route, {label}: {m} periods x {len(heights)} heights, at most {k} periods "
                f"per height and bin: {r['wall'] / 60:6.2f} min wall, {r['cpu'] / 60:6.2f} min CPU "
                f"({r['cpu'] / args.workers / 60:.2f} min on {args.workers} idle cores), {r['replicas']} "
                f"replica(s), {r['simulated']} of {r['period_heights']} period-heights simulated, "
                f"{r['cells']} cells ({1000 * r['cpu'] / r['cells']:.2f} ms CPU per cell, all included); "
                f"peak RSS {r['rss']:.0f} MB main (VmHWM), largest worker {r['worker_rss']:.0f} MB "
                f"(ru_maxrss: not below the main process's at its start); load "
                f"{r['load']:.1f}; CPU / baseline's replica-0 projection {r['cpu'] / full:.3f}", flush=True
            )
        k = args.memory_periods_per_bin
        if ("quarter", k) in rss and ("whole campaign", k) in rss:  # memory flat in the campaign's length
            q, w = rss["quarter", k], rss["whole campaign", k]
            print(f"memory, whole campaign / quarter at {k} periods per bin: peak RSS main {w['rss']:.0f} / "
                  f"{q['rss']:.0f} MB = {w['rss'] / q['rss']:.2f}, largest worker {w['worker_rss']:.0f} / "
                  f"{q['worker_rss']:.0f} MB = {w['worker_rss'] / q['worker_rss']:.2f} (campaign 4x longer)",
                  flush=True)


def baseline(args, d: Path, cert: Path, heights, common: list[str], cells: int) -> float:
    """The full-simulation baseline (every period) ``--repeat`` times; print medians, return CPU per cell."""
    import statistics

    n = args.mc_periods
    week = campaign(d, n, heights, f"mc{n}")
    whole = ["--case", str(week), "--certificate", str(cert), "--mc-periods-per-bin", "all", *common]
    base = [child(whole) for _ in range(max(1, args.repeat))]
    med = {k: statistics.median(r[k] for r in base)
           for k in ("wall", "cpu", "cells", "rss", "worker_rss")}
    loads = ", ".join(f"{r['load']:.1f}" for r in base)
    per_cell = med["cpu"] / med["cells"]
    rate = med["cells"] / (n * len(heights))  # cells per period-height, replicas included
    projected = per_cell * cells  # replica 0 of every period-height alone: a lower bound
    print(
        f"baseline, Monte Carlo route simulating every period of {n} periods x {len(heights)} heights, "
        f"median of {len(base)}: {med['wall']:7.1f} s wall, {med['cpu']:7.1f} s CPU, "
        f"{med['cells']:.0f} cells ({rate:.2f} per period-height), {1000 * per_cell:.2f} ms CPU per "
        f"cell; peak RSS {med['rss']:.0f} MB (worker {med['worker_rss']:.0f} MB); loads {loads}"
    )
    print(
        f"baseline projected to {args.periods} periods simulated in full, replica 0 alone (a lower "
        f"bound): {projected / 60:6.1f} min CPU, {projected / args.workers / 60:6.1f} min on "
        f"{args.workers} idle cores; at the baseline's {rate:.2f} cells per period-height "
        f"{rate * projected / 60:6.1f} min CPU"
    )
    return per_cell


if __name__ == "__main__":
    main()
