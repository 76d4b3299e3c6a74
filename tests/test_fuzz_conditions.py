"""Property-based fuzz of conditions and field_campaign files through the CLI (issue 9).

Hypothesis builds valid netCDF files in random convertible units (km h-1, knot, rad, %) and
applies up to three mutations: NaN, infinities and out-of-range values, unconvertible or missing
units, time orders (shuffled, repeated, reversed), shapes (no periods, a missing variable,
transposed dims), ``positive: down`` heights and ``lidar_*`` global attributes (numbers in and
out of range, words).  Whatever the file:

* ``lidarcal conditions check`` exits 0 or 2 -- never a traceback (an exception escaping
  :func:`lidarcal.cli.main` fails the test) -- and on 2 prints one message naming the file;
* on 0 the loaded dataset passes the schema of its kind (what ``lidarcal validate`` checks), and
  ``lidarcal conditions synthetic --base FILE`` (kind conditions) either writes an artefact that
  ``lidarcal validate`` passes or exits 2 naming the base file (not the output);
* nothing but the input and a complete output is ever left in the directory (no ``.part``).

40 examples in the default run (each a few CLI calls in-process); set
``LIDARCAL_FUZZ_EXAMPLES=500`` for a deeper search.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import xarray as xr
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from lidarcal.cf import height_coord, time_coord
from lidarcal.cli import main
from lidarcal.conditions import load_conditions
from lidarcal.schema import validate_dataset

#: variable -> (canonical unit, other units it may be written in, unconvertible unit, typical range)
VARIABLES = {
    "wind_speed": ("m s-1", ["km h-1", "knot", "m/s"], "K", (0.0, 25.0)),
    "wind_from_direction": ("degree", ["rad", "degrees"], "m", (0.0, 360.0)),
    "turbulence_intensity": ("1", ["%", "percent"], "m s-1", (0.0, 0.4)),
    "wind_shear_exponent": ("1", ["dimensionless"], "K", (-0.3, 0.6)),
    "cnr": ("dB", ["decibel"], "m", (-30.0, -5.0)),
    "cnr_gradient": ("dB m-1", ["dB/m"], "K", (-0.1, 0.1)),
}
PAIR = ("lidar_wind_speed", "reference_wind_speed")
SPECIAL = [np.nan, np.inf, -np.inf, 1e30, -1e30, 1000.0, -1.0, 0.0]
LIDAR_ATTRS = {
    "lidar_cone_angle": st.one_of(st.floats(-10, 120), st.just("thirty"), st.just(np.nan)),
    "lidar_hybrid_weight": st.one_of(st.floats(-0.5, 1.5), st.just("two thirds")),
    "lidar_rwf_fwhm": st.one_of(st.floats(-5, 300), st.just(np.inf)),
    "lidar_los_noise_std": st.floats(-0.1, 1.0),
    "lidar_beam_period": st.floats(-1, 5),
}


def _scale(unit: str, canonical: str) -> float:
    """Factor converting a canonical value to ``unit`` (units the fuzz writes)."""
    return {"km h-1": 3.6, "knot": 1 / 0.514444, "rad": np.pi / 180, "%": 100.0, "percent": 100.0}.get(
        unit, 1.0) if unit != canonical else 1.0


MUTATIONS = ["nan", "nan", "special", "wrong_unit", "no_unit", "drop", "transpose", "reversed", "repeated",
             "shuffled", "no_periods", "positive_down", "low_height", "lidar_attribute", "lidar_attribute"]


@st.composite
def campaign_files(draw) -> tuple[xr.Dataset, str]:
    """A valid file in any convertible units, then up to three random mutations (most are not valid)."""
    kind = draw(st.sampled_from(["conditions", "field_campaign"]))
    mutations = draw(st.lists(st.sampled_from(MUTATIONS), max_size=3))
    # a field campaign needs diagnose's 6 bins x 10 periods per height to pass the check
    n = 0 if "no_periods" in mutations else draw(st.integers(1, 8) if kind == "conditions" else
                                                  st.integers(62, 70))
    heights = draw(st.lists(st.sampled_from([40.0, 60.0, 80.0, 120.0, 200.0]), min_size=1,
                            max_size=3, unique=True))
    rng = np.random.default_rng(draw(st.integers(0, 2**16)))
    t = np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")
    if "reversed" in mutations:
        t = t[::-1]
    if "repeated" in mutations and n > 1:
        t[-1] = t[0]
    if "shuffled" in mutations:
        t = rng.permutation(t)
    names = dict(VARIABLES)
    if kind == "field_campaign" or draw(st.booleans()):
        names.update({p: ("m s-1", ["km h-1", "knot"], "K", (4.0, 25.0)) for p in PAIR})
    data = {}
    for name, (canonical, others, _wrong, (lo, hi)) in names.items():
        unit = draw(st.sampled_from([canonical, *others]))
        values = rng.uniform(lo, hi, (n, len(heights))) * _scale(unit, canonical)
        data[name] = [("time", "height"), values, {"units": unit}]
    for m in mutations:
        name = draw(st.sampled_from(sorted(data)))
        dims, values, attrs = data[name]
        if m in ("nan", "special") and values.size:
            values.flat[rng.integers(values.size)] = np.nan if m == "nan" else draw(st.sampled_from(SPECIAL))
        elif m == "wrong_unit":
            attrs["units"] = names[name][2]
        elif m == "no_unit":
            attrs.pop("units", None)
        elif m == "drop":
            del data[name]
        elif m == "transpose":
            data[name] = [dims[::-1], values.T, attrs]
    if "low_height" in mutations:  # below what the default lidar's RWF can reach
        heights = [3.0, *heights[1:]]
    hcoord = height_coord(heights)
    if "positive_down" in mutations:
        hcoord.attrs["positive"] = "down"
    ds = xr.Dataset({k: tuple(v) for k, v in data.items()}, coords={"time": time_coord(t), "height": hcoord})
    for _ in range(mutations.count("lidar_attribute")):
        attr = draw(st.sampled_from(sorted(LIDAR_ATTRS)))
        ds.attrs[attr] = draw(LIDAR_ATTRS[attr])
    return ds, kind


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        rc = main(argv)
    except SystemExit as exc:
        rc = exc.code
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


@settings(max_examples=int(os.environ.get("LIDARCAL_FUZZ_EXAMPLES", 40)), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(case=campaign_files())
def test_check_exits_0_with_a_valid_result_or_2_with_a_message(case, capsys):
    ds, kind = case
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        src = d / "in.nc"
        ds.to_netcdf(src)
        rc, out, err = _run(["conditions", "check", str(src), "--kind", kind], capsys)
        assert rc in (0, 2), err
        assert "Traceback" not in err
        event(f"conditions check exit {rc}")
        if rc == 2:
            lines = [line for line in err.splitlines() if line.startswith("lidarcal conditions: error:")]
            assert len(lines) == 1 and "in.nc" in lines[0], err
        else:
            assert f"{kind} ok" in out
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                loaded = load_conditions(src, kind=kind)
            assert validate_dataset(loaded, kind, source=str(src)) == []
            # directions folded into [0, 360), never wrapped from out-of-range values
            wd = loaded.wind_from_direction.values
            assert np.all((wd[np.isfinite(wd)] >= 0) & (wd[np.isfinite(wd)] < 360))
            assert not np.isinf(np.stack([loaded[v].values for v in VARIABLES])).any()
            assert np.all(np.diff(loaded.time.values) > np.timedelta64(0, "ns"))
            if kind == "conditions":
                new = d / "synthetic.nc"
                rc2, _, err2 = _run(["conditions", "synthetic", "--base", str(src), "--heights", "40", "80",
                                     "-o", str(new)], capsys)
                assert rc2 in (0, 2) and "Traceback" not in err2, err2
                event(f"conditions synthetic exit {rc2}")
                if rc2 == 0:
                    rc3, out3, _ = _run(["validate", "--no-compliance", str(new)], capsys)
                    assert rc3 == 0, out3
                else:  # the culprit is the base file, never the output that was not written
                    assert "in.nc" in err2 and "synthetic.nc" not in err2, err2
        assert sorted(p.name for p in d.iterdir()) in (["in.nc"], ["in.nc", "synthetic.nc"])
