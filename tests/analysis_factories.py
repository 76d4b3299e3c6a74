"""Seeded record datasets (``simulated_rtd``-like) for the analysis, certificate and report tests."""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.cf import height_coord, time_coord

CONDITION_UNITS = {
    "wind_speed": "m s-1",
    "wind_from_direction": "degree",
    "turbulence_intensity": "1",
    "wind_shear_exponent": "1",
    "cnr": "dB",
    "cnr_gradient": "dB m-1",
}


def var_attrs(long_name: str, units: str, standard_name: str | None = None) -> dict[str, str]:
    """Attributes of a hand-made input variable: ``long_name``, ``units``, ACDD content type (and CF name)."""
    attrs = {"long_name": long_name, "units": units, "coverage_content_type": "modelResult"}
    return {**attrs, "standard_name": standard_name} if standard_name else attrs


def make_records(
    n=600,
    heights=(80.0, 120.0),
    seed=1,
    *,
    shear_slope=(2.0, -1.0),
    ti_slope=0.0,
    noise=0.5,
    bias=0.0,
    lidar_serial="WLS7-TEST",
    replicas=1,
):
    """Records whose relative difference (%) is ``bias + slope * (alpha - 0.15) + N(0, noise)``.

    ``shear_slope`` is the true sensitivity to the shear exponent per height (% per unit alpha).
    With ``replicas`` > 1 the records carry Monte Carlo replicas of every period as the adaptive
    Monte Carlo stores them (``period_key`` and the ``trial_*`` variables): the same conditions,
    a fresh N(0, noise) draw each (from a stream of their own, so replica 0 is the same as
    without replicas).
    """
    rng = np.random.default_rng(np.random.SeedSequence([seed, 2024]))
    nh = len(heights)
    shape = (n, nh)
    ws = rng.uniform(4.5, 15.5, shape)
    alpha = rng.uniform(0.0, 0.3, shape)
    ti = rng.uniform(0.04, 0.20, shape)
    rel = (
        bias
        + np.resize(np.asarray(shear_slope, dtype=float), nh)[None, :] * (alpha - 0.15)
        + ti_slope * (ti - 0.1)
        + rng.normal(0.0, noise, shape)
    )
    ref = ws
    lidar = ref * (1 + rel / 100.0)
    data = {
        "wind_speed": ws,
        "wind_from_direction": rng.uniform(0, 360, shape),
        "turbulence_intensity": ti,
        "wind_shear_exponent": alpha,
        "cnr": rng.uniform(-25, -10, shape),
        "cnr_gradient": rng.uniform(-0.05, 0.05, shape),
    }
    ds = xr.Dataset(
        {
            k: (("time", "height"), v, var_attrs(k.replace("_", " "), CONDITION_UNITS[k]))
            for k, v in data.items()
        },
        coords={
            "time": time_coord(np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")),
            "height": height_coord(heights),
        },
    )
    ds["wind_speed"].attrs["standard_name"] = "wind_speed"
    ds["lidar_wind_speed"] = (("time", "height"), lidar, var_attrs("lidar wind speed", "m s-1", "wind_speed"))
    ds["reference_wind_speed"] = (
        ("time", "height"),
        ref,
        var_attrs("reference wind speed", "m s-1", "wind_speed"),
    )
    ds.attrs = {"lidarcal_artefact": "simulated_rtd", "lidar_serial": lidar_serial}
    if replicas > 1:
        from lidarcal.campaign.adaptive import with_trials
        from lidarcal.schema import output_attrs

        ds["period_key"] = ("time", 1_704_067_200 + 600 * np.arange(n, dtype=np.int64),
                            output_attrs("simulated_rtd", "period_key"))
        more = np.random.default_rng(np.random.SeedSequence([seed, 2024, 1]))
        deterministic = rel - (rel - bias - np.resize(np.asarray(shear_slope, dtype=float), nh)[None, :]
                               * (alpha - 0.15) - ti_slope * (ti - 0.1))
        trials = []
        for r in range(1, replicas):
            rel_r = deterministic + more.normal(0.0, noise, shape)
            period, height = np.nonzero(np.ones(shape, dtype=bool))
            trials.append({"replica": r, "period": period, "height": np.asarray(heights, dtype=float)[height],
                           "lidar_wind_speed": (ref * (1 + rel_r / 100.0))[period, height],
                           "reference_wind_speed": ref[period, height]})
        ds = with_trials(ds, trials)
    return ds
