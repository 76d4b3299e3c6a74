"""A small sealed certificate and campaign files for the ``lidarcal smc`` tests, built in seconds.

The certificate bundles a budget and sensitivities computed from seeded hand-made records (no
simulation), a simulated bench cube (20 s per bin) and the sample pulse's RWF, and records the
lidar model those describe, so the Monte Carlo route can run on it.  Its numbers are what the
records say, not a calibration: the tests read them back from the file and compute what
``lidarcal smc`` must give from them by hand.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr
from analysis_factories import make_records

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

SERIAL = "WLS866-0195"  # the sample bench unit
HEIGHTS = (80.0, 120.0)
#: true sensitivities of the records (% per unit): TI at both heights, shear at 80 m only
TI_SLOPE = -8.0
SHEAR_SLOPE = (3.0, 0.0)


def small_certificate(
    d: Path,
    *,
    name: str = "cert.nc",
    flags=None,
    with_model: bool = True,
    signing_key=None,
    sensitivities: bool = True,
) -> Path:
    """Write and seal a small certificate in ``d``; ``flags(budget) -> budget`` may edit its bin flags."""
    d.mkdir(parents=True, exist_ok=True)
    rec = make_records(
        n=700,
        heights=HEIGHTS,
        seed=5,
        shear_slope=SHEAR_SLOPE,
        ti_slope=TI_SLOPE,
        noise=0.6,
        lidar_serial=SERIAL,
        replicas=6,  # JCGM 101 7.9: a value settles only with replicas (h >= 2)
    )
    run = simulate_run(seed=3, accumulation_time="20 s", lidar_serial=SERIAL)
    cube, _ = build_cube(run.rtd, run.control)
    cube = write_artefact(
        stamp(cube, "bench_cube", title="cube", summary="test cube", call="test"),
        d / "cube.nc",
        overwrite=True,
    )
    rwf = write_artefact(
        range_weighting_function(pulse_file=sample_file("rwf/pulse_example.csv")),
        d / "rwf.nc",
        overwrite=True,
    )
    cube, rwf = open_artefact(cube), open_artefact(rwf)
    if with_model:
        rec.attrs["lidarcal_lidar_model"] = LidarModel.from_artefacts(cube=cube, rwf=rwf).to_json()
        rec.attrs["lidarcal_base_seed"] = 20240101
    write_artefact_records = d / "records.nc"
    rec.to_netcdf(write_artefact_records)
    records = open_artefact(write_artefact_records)
    terms = uncertainty_terms(
        Q_(np.arange(0.25, 40.01, 0.25), "m/s"), **{**PAPER_INPUTS, "height": Q_(np.asarray(HEIGHTS), "m")}
    )
    terms = open_artefact(write_artefact(terms, d / "terms.nc", overwrite=True))
    # one significant digit: with 6 replicas of 700 periods every bin settles to it (to 2, none does)
    bud = budget(records, terms=terms, rule=CertificationRule(significant_digits=1))
    if flags is not None:
        bud = flags(bud)
    sens = [sensitivity(records, v) for v in ("turbulence_intensity", "wind_shear_exponent", "cnr_gradient")]
    sens = sens if sensitivities else []
    parts = {"cube": cube, "rwf": rwf} if with_model else {}
    cert = make_certificate(
        budget=bud, sensitivities=sens, terms=terms, records=records, demonstration=True, **parts
    )
    return write_certificate(cert, d / name, overwrite=True, signing_key=signing_key)


def add_model_form(bud: xr.Dataset, percent: float = 0.8) -> xr.Dataset:
    """The budget with a ``model_form`` contributor of ``percent`` of each bin's mean reference speed.

    As a calibration with the model-form runs states it (``lidarcal.analysis.model_form``); the
    totals are recombined here with numpy, in quadrature over every contributor.
    """
    b = bud.transpose("height", "wind_speed", "contributor", ...)
    mref = b["mean_reference_wind_speed"].values
    contribution = np.concatenate([b["contribution"].values, percent / 100.0 * mref[..., None]], axis=-1)
    combined = np.sqrt((contribution**2).sum(axis=-1))
    k = float(b.attrs["coverage_factor"])
    out = b.drop_vars(["contribution", "relative_contribution"]).drop_dims("contributor")
    names = [*map(str, b["contributor"].values), "model_form"]
    out = out.assign_coords(contributor=("contributor", np.array(names, dtype=object),
                                         b["contributor"].attrs))
    hwc = ("height", "wind_speed", "contributor")
    out["contribution"] = (hwc, contribution, b["contribution"].attrs)
    out["relative_contribution"] = (hwc, 100 * contribution / mref[..., None],
                                    b["relative_contribution"].attrs)
    for name, value in (("uncertainty", combined), ("relative_uncertainty", 100 * combined / mref),
                        ("expanded_uncertainty", k * combined),
                        ("relative_expanded_uncertainty", 100 * k * combined / mref)):
        out[name] = (("height", "wind_speed"), value, b[name].attrs)
    return out


def conditions_file(
    path: Path,
    values: dict[str, np.ndarray],
    heights,
    *,
    serial: str = SERIAL,
    cone_angle: float | None = 28.0,
    start: str = "2024-06-01T00:00",
) -> Path:
    """A ``conditions`` file of the given (time, height) values, written with plain xarray."""
    n = next(iter(values.values())).shape[0]
    units = {
        "wind_speed": "m s-1",
        "wind_from_direction": "degree",
        "turbulence_intensity": "1",
        "wind_shear_exponent": "1",
        "cnr": "dB",
        "cnr_gradient": "dB m-1",
    }
    ds = xr.Dataset(
        {
            k: (
                ("time", "height"),
                np.asarray(v, float),
                {"units": units[k], "long_name": k.replace("_", " ")},
            )
            for k, v in values.items()
        },
        coords={
            "time": time_coord(np.datetime64(start, "ns") + np.arange(n) * np.timedelta64(600, "s")),
            "height": height_coord(heights),
        },
    )
    ds.attrs["lidar_serial"] = serial  # tests/test_smc_montecarlo.py writes the old name, lidar_serial_number
    if cone_angle is not None:
        ds.attrs["lidar_cone_angle"] = cone_angle
    ds.to_netcdf(path)
    return path


def campaign_values(n: int, heights, seed: int = 11, *, ti=None) -> dict[str, np.ndarray]:
    """Seeded campaign conditions on (time, height): speeds 4-15 m/s, TI, shear, CNR, CNR gradient."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5AC]))
    shape = (n, len(heights))
    return {
        "wind_speed": rng.uniform(4.2, 15.0, shape),
        "wind_from_direction": rng.uniform(0, 360, shape),
        "turbulence_intensity": rng.uniform(0.05, 0.22, shape) if ti is None else np.full(shape, ti),
        "wind_shear_exponent": rng.uniform(0.0, 0.35, shape),
        "cnr": rng.uniform(-20, -8, shape),
        "cnr_gradient": rng.uniform(-0.04, 0.04, shape),
    }
