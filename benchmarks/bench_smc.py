"""Benchmark: ``lidarcal smc`` on a one-year campaign (52,560 periods x 12 heights), both routes.

Targets (docs/performance.md): the 50-2 route in seconds, the Monte Carlo route <= 15 min on 2
cores, memory flat in the campaign's length.

Usage::

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_smc.py [--periods 52560] [--heights 12]
        [--mc-periods 1008 4032] [--full-monte-carlo] [--workers 2] [--scheduler processes]
        [--certificate CERT.nc]

The certificate is a small one certifying the campaign's heights (budget and sensitivities of
seeded hand-made records, the simulated bench cube and the sample pulse's RWF: the route's cost
does not depend on its numbers), unless ``--certificate`` gives one (then the campaign takes its
heights).  The campaign is synthetic stochastic conditions (:func:`lidarcal.conditions.synthetic_conditions`).

Printed: the 50-2 route over the whole campaign (time and peak memory of this process); the
Monte Carlo route on each of ``--mc-periods`` (time, cells simulated with the replicas, time per
cell and height, peak memory of this process) and the one-year time projected from the longest
(cells per period and time per cell measured); with ``--full-monte-carlo`` the whole year too.
"""

import argparse
import os
import resource
import tempfile
import time
import tracemalloc
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
    from lidarcal.analysis.terms import PAPER_INPUTS, uncertainty_terms
    from lidarcal.bench import build_cube, simulate_run
    from lidarcal.certificate import make_certificate
    from lidarcal.cf import height_coord, time_coord
    from lidarcal.data import sample_file
    from lidarcal.io import open_artefact, write_artefact
    from lidarcal.lidar import LidarModel
    from lidarcal.provenance import stamp
    from lidarcal.rwf import range_weighting_function
    from lidarcal.seal import write_certificate
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
        budget=budget(records, terms=terms),
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
    """Peak resident memory of this process so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cpu_seconds() -> float:
    """CPU time (user + system) of this process and of its finished children (the pool's workers)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run(
    cert: Path, cond: Path, out: Path, *, monte_carlo: bool, opts: dict
) -> tuple[float, object, float, float]:
    """Time ``smc`` + the artefact + its file; return (seconds, campaign, traced peak MB, CPU seconds)."""
    from lidarcal.io import write_artefact
    from lidarcal.smc import smc, smc_dataset

    tracemalloc.start()
    t0, c0 = time.perf_counter(), cpu_seconds()
    c = smc(cert, conditions=cond, monte_carlo=monte_carlo, execution=opts)
    write_artefact(smc_dataset(c), out, overwrite=True)
    elapsed, cpu = time.perf_counter() - t0, cpu_seconds() - c0
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return elapsed, c, peak / 2**20, cpu


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
        nargs="+",
        default=[1008, 4032],
        help="campaign lengths the Monte Carlo route is timed on (default: one and four weeks)",
    )
    p.add_argument(
        "--full-monte-carlo", action="store_true", help="also run the Monte Carlo route on the whole year"
    )
    p.add_argument("--certificate", help="use this certificate (the campaign takes its heights)")
    p.add_argument("--scheduler", default="processes")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args()
    warnings.simplefilter("ignore")
    logging.getLogger("pint").setLevel(logging.ERROR)
    opts = {"scheduler": args.scheduler, "workers": args.workers, "chunk": 64}
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
        print(
            f"load: {os.getloadavg()[0]:.1f} (1 min), {os.cpu_count()} CPUs; scheduler {args.scheduler} x "
            f"{args.workers}; heights {heights}"
        )
        year = campaign(d, args.periods, heights, "year")
        t, c, traced, cpu = run(cert, year, d / "smc-year-iec.nc", monte_carlo=False, opts=opts)
        cells = args.periods * len(heights)
        print(
            f"50-2 route, {args.periods} periods x {len(heights)} heights: {t:7.1f} s wall, {cpu:7.1f} s CPU "
            f"(target: seconds); traced peak {traced:.0f} MB, process peak RSS {peak_rss_mb():.0f} MB; "
            f"{int((c.coverage == 0).sum())} of {cells} period-heights covered"
        )
        last = None
        for n in sorted(args.mc_periods):
            cond = campaign(d, n, heights, f"mc{n}")
            t, c, traced, cpu = run(cert, cond, d / f"smc-mc{n}.nc", monte_carlo=True, opts=opts)
            simulated = int(c.monte_carlo.trials.sum())
            last = (n, t, cpu, simulated)
            print(
                f"Monte Carlo route, {n} periods x {len(heights)} heights: {t:7.1f} s wall, "
                f"{cpu:7.1f} s CPU, {c.monte_carlo.replicas} replica(s), {simulated} cells simulated "
                f"({simulated / (n * len(heights)):.2f} per period-height), "
                f"{1000 * cpu / simulated:.2f} ms CPU per cell; traced peak {traced:.0f} MB, "
                f"process peak RSS {peak_rss_mb():.0f} MB"
            )
        if last is not None:
            n, t, cpu, simulated = last
            # the year's cells: replica 0 of every period-height, plus replicas at the longest run's
            # rate (an upper bound: a longer campaign fills its bins better and needs fewer)
            year_cells = cells * simulated / (n * len(heights))
            by_cpu = cpu / simulated * year_cells / args.workers
            by_wall = t / simulated * year_cells
            print(
                f"Monte Carlo route, {args.periods} periods projected from the {n}-period run: "
                f"{by_cpu / 60:6.1f} min on {args.workers} idle cores (CPU time / {args.workers}), "
                f"{by_wall / 60:6.1f} min at this run's wall rate (load {os.getloadavg()[0]:.1f}); "
                "target <= 15 min on 2 cores"
            )
        if args.full_monte_carlo:
            t, c, traced, cpu = run(cert, year, d / "smc-year-mc.nc", monte_carlo=True, opts=opts)
            print(
                f"Monte Carlo route, {args.periods} periods x {len(heights)} heights: "
                f"{t / 60:6.1f} min wall, "
                f"{cpu / 60:6.1f} min CPU, {c.monte_carlo.replicas} replica(s), "
                f"{int(c.monte_carlo.trials.sum())} cells; traced peak {traced:.0f} MB, process peak RSS "
                f"{peak_rss_mb():.0f} MB"
            )


if __name__ == "__main__":
    main()
