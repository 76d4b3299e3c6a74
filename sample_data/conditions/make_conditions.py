"""Build ``conditions.nc`` — a real ``conditions`` input from brightwind's demo met-mast record.

Usage (deterministic; rerunning gives the same data)::

    python sample_data/conditions/make_conditions.py [--csv demo_data.csv] [-o conditions.nc] [--overwrite]

Without ``--csv`` the script runs ``pip download brightwind==2.7.0 --no-deps`` into a
temporary directory and reads ``brightwind/demo_datasets/demo_data.csv`` from the wheel
(brightwind is *not* a lidarcal dependency).  Source: brightwind 2.7.0, © 2024 Stephen
Holleran, MIT licence (https://github.com/brightwind-dev/brightwind); 95,629 ten-minute
rows, 2016-01-09 … 2017-11-23, cup anemometers on north (N) and south (S) booms at 40, 60,
80 m and vanes at 38, 58, 78 m.

What the script does (rows 2016-06-01 00:00 … 2016-08-31 23:50, 13,248 periods):

* **boom choice** — per period and height the upwind boom is used to avoid mast shadow:
  the S boom when the wind comes from the southern half (90° ≤ dir < 270°, vane nearest in
  height), otherwise the N boom;
* **direction** — the vanes at 38, 58 and 78 m are assigned to the nearest speed heights
  40, 60 and 80 m (2 m apart; the vane height is kept in the variable's comment);
* **turbulence intensity** = boom std / boom mean (the record's std of the 10-min samples);
* **shear exponent** from neighbouring heights with Eq. 10 (paper §3.3): at 60 m from 40 and
  80 m, at 40 m from 40/60 m, at 80 m from 60/80 m;
* **CNR** is not measured by a mast: it is filled by lidarcal's documented CNR model
  (``lidarcal.conditions.kernels.cnr_model``: −13 dB base level, 3 dB diurnal cycle peaking at
  14 h, −0.01 dB/m mean decay with height, a 5 dB telescope-focus bump at 110 m, AR(1)
  synoptic variability), seeded with ``SeedSequence([20160601, 0x5C0D])``; the **CNR gradient**
  follows from neighbouring heights as in the paper, converted to a rate along the 28° beam
  (dCNR/ds = dCNR/dz · cos 28°);
* **quality control, never invention** — a height is set missing (NaN, flagged in
  ``quality_flag``) where the chosen cup reads calm (< 1 m/s: cups stall, and TI and shear are
  meaningless), where its std is exactly 0 with a non-calm mean (stuck or iced cup), or where
  the vane's std is exactly 0 (stuck vane); the few light-wind values with TI > 1 or a shear
  exponent beyond ±2 (outside the contract's physical range) are set missing and flagged too.
  Missing values propagate to the shear exponent and CNR gradient that need them; lidarcal
  skips those (period, height) pairs and reports them.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from lidarcal.conditions import cnr_model, conditions_dataset, shear_exponent
from lidarcal.conditions.kernels import cnr_gradient_along_beam
from lidarcal.io import write_artefact
from lidarcal.lidar import LidarModel
from lidarcal.provenance import sha256, stamp

HEIGHTS = np.array([40.0, 60.0, 80.0])
VANES = {40.0: 38, 60.0: 58, 80.0: 78}
START, STOP = "2016-06-01 00:00", "2016-08-31 23:50"
CALM = 1.0  # m/s
SEED = 20160601
BRIGHTWIND = "brightwind==2.7.0"
MEMBER = "brightwind/demo_datasets/demo_data.csv"


def fetch_csv(tmp: Path) -> Path:
    """Download the brightwind wheel (no dependencies) and extract the demo CSV."""
    subprocess.run(
        [sys.executable, "-m", "pip", "download", BRIGHTWIND, "--no-deps", "-q", "-d", str(tmp)], check=True
    )
    wheel = next(tmp.glob("brightwind-*.whl"))
    with zipfile.ZipFile(wheel) as zf:
        zf.extract(MEMBER, tmp)
    return tmp / MEMBER


def build(csv: Path) -> xr.Dataset:
    """Convert the demo CSV into a ``conditions`` Dataset (see module docstring)."""
    df = pd.read_csv(csv, encoding="utf-8-sig", parse_dates=["Timestamp"]).set_index("Timestamp")
    all_rows = len(df)
    first_row = int(np.searchsorted(df.index.values, np.datetime64(START)))
    df = df.loc[START:STOP]
    n = len(df)
    expected = pd.date_range(START, STOP, freq="10min")
    if not df.index.equals(expected):
        raise SystemExit(f"{csv}: rows {START}..{STOP} are not a gap-free 10-minute series")
    speed = np.empty((n, HEIGHTS.size))
    std = np.empty_like(speed)
    direction = np.empty_like(speed)
    flags = np.zeros((n, HEIGHTS.size), dtype=np.int8)
    for j, h in enumerate(HEIGHTS):
        vane = VANES[h]
        d = df[f"Dir{vane}mS"].to_numpy(float)
        south = (d >= 90.0) & (d < 270.0)
        for boom, use in (("N", ~south), ("S", south)):
            speed[use, j] = df[f"Spd{int(h)}m{boom}"].to_numpy(float)[use]
            std[use, j] = df[f"Spd{int(h)}m{boom}Std"].to_numpy(float)[use]
        direction[:, j] = d
        calm = speed[:, j] < CALM
        stuck_cup = (std[:, j] == 0) & ~calm
        stuck_vane = df[f"Dir{vane}mSStd"].to_numpy(float) == 0
        flags[:, j] = calm * 1 + stuck_cup * 2 + stuck_vane * 4
    speed[flags & 1 > 0] = np.nan
    std[flags & 3 > 0] = np.nan
    direction[flags & 4 > 0] = np.nan
    ti = std / speed
    alpha = shear_exponent(speed, HEIGHTS)
    # a handful of light-wind periods give TI > 1 or |alpha| > 2: outside the contract's
    # physical range, so they are set missing and flagged rather than clipped
    wild = (ti > 1.0) | (np.abs(alpha) > 2.0)
    flags[wild] |= 8
    ti[wild] = np.nan
    alpha[wild] = np.nan
    hours = (df.index.hour + df.index.minute / 60.0).to_numpy(float)
    rng = np.random.default_rng(np.random.SeedSequence([SEED, 0x5C0D]))
    cnr = cnr_model(hours, HEIGHTS, rng)
    # along the beam (the contract's meaning): dCNR/ds = dCNR/dz cos(phi), phi = 28 deg
    cnr_grad = cnr_gradient_along_beam(cnr, HEIGHTS, LidarModel.cone_angle)
    values = {
        "wind_speed": speed,
        "wind_from_direction": direction,
        "turbulence_intensity": ti,
        "wind_shear_exponent": alpha,
        "cnr": cnr,
        "cnr_gradient": cnr_grad,
    }
    attribution = (
        f"Met-mast data from brightwind 2.7.0 (https://github.com/brightwind-dev/brightwind), "
        f"file {MEMBER}, Copyright (c) 2024 Stephen Holleran, MIT License"
    )
    ds = conditions_dataset(
        df.index.values,
        HEIGHTS,
        values,
        {
            "source_data": attribution,
            "source_license": "MIT",
            "source_file": MEMBER,
            "source_file_sha256": sha256(csv),
            "source_rows": (
                f"data rows {first_row + 1}..{first_row + n} of {all_rows} "
                f"(timestamps {START} .. {STOP}, 1-based, header excluded)"
            ),
            "license": "MIT (derived from brightwind demo data, MIT licence); lidarcal additions CC-BY-4.0",
            "acknowledgment": "brightwind developers for publishing the demo met-mast record",
            "comment": (
                "Speeds from the upwind boom (S for 90-270 deg, else N); vanes at 38/58/78 m assigned to "
                "40/60/80 m; TI = std/mean; shear exponent (Eq. 10) and CNR gradient from neighbouring "
                "heights (CNR gradient along a 28 deg beam: dCNR/dz * cos 28 deg); "
                "CNR modelled (lidarcal.conditions.kernels.cnr_model, seed "
                f"SeedSequence([{SEED}, 0x5C0D])), not measured; calm (<{CALM} m/s), stuck cups and "
                "stuck vanes, TI > 1 and |shear| > 2 set to NaN and flagged in quality_flag. Built by "
                "sample_data/conditions/make_conditions.py."
            ),
            "lidarcal_cnr_model_seed": SEED,
        },
    )
    ds["wind_from_direction"].attrs["comment"] = "vanes at 38, 58, 78 m assigned to 40, 60, 80 m"
    ds["cnr"].attrs["comment"] = "modelled, not measured (lidarcal.conditions.kernels.cnr_model)"
    ds["cnr"].attrs["coverage_content_type"] = "modelResult"
    for name in ("wind_speed", "wind_from_direction", "turbulence_intensity", "wind_shear_exponent"):
        ds[name].attrs["coverage_content_type"] = "physicalMeasurement"
    ds["quality_flag"] = (
        ("time", "height"),
        flags,
        {
            "long_name": "quality control flags of the mast record",
            "flag_masks": np.array([1, 2, 4, 8], dtype=np.int8),
            "flag_values": np.array([1, 2, 4, 8], dtype=np.int8),
            "flag_meanings": "calm_below_1_m_s cup_std_zero vane_std_zero ti_above_1_or_shear_beyond_2",
            "coverage_content_type": "qualityInformation",
        },
    )
    return ds


def main(argv=None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--csv", type=Path, help="demo_data.csv (default: pip download brightwind 2.7.0)")
    ap.add_argument("-o", "--output", type=Path, default=Path(__file__).with_name("conditions.nc"))
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        csv = args.csv or fetch_csv(Path(tmp))
        ds = build(csv)
        ds = stamp(
            ds,
            "conditions",
            title="Real 10-minute conditions from the brightwind demo met mast, June-August 2016, 40/60/80 m",
            summary="Three summer months of 10-minute wind speed, direction, turbulence intensity and "
            "shear exponent from a real met mast (brightwind demo data, MIT), with modelled "
            "CNR, as a lidarcal conditions input.",
            call="python sample_data/conditions/make_conditions.py",
            inputs={"brightwind_demo_data": csv},
            seeds={"cnr_model": SEED},
        )
        ds.attrs["license"] = "MIT (derived from brightwind demo data); lidarcal additions CC-BY-4.0"
        write_artefact(ds, args.output, overwrite=args.overwrite)
    print(f"wrote {args.output} ({args.output.stat().st_size / 1e6:.2f} MB, {ds.sizes['time']} periods)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
