"""LOS time series of selected periods as ``simulated_rtd`` variables (``--los-periods``)."""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.schema import output_attrs

__all__ = ["los_variables"]


def los_variables(los_data: dict[int, dict[str, np.ndarray]], heights: np.ndarray) -> xr.Dataset:
    """``los_radial_velocity`` and its coordinates (dims (los_period, los_time, height) once stamped).

    ``los_data`` maps a period index to the engine's ``return_los`` output for the heights
    that were simulated in that period (``columns``); other heights are NaN.
    """
    periods = sorted(los_data)
    first = los_data[periods[0]]
    n_times = int(np.asarray(first["los_time"]).size)
    values = np.full((len(periods), heights.size, n_times), np.nan)
    for i, p in enumerate(periods):
        values[i, np.asarray(los_data[p]["columns"], dtype=int)] = los_data[p]["los"]
    return xr.Dataset(
        {
            "los_radial_velocity": (
                ("los_period", "height", "los_time"),
                values,
                output_attrs("simulated_rtd", "los_radial_velocity"),
            )
        },
        coords={
            "los_period": (
                "los_period",
                np.asarray(periods, dtype=np.int64),
                output_attrs("simulated_rtd", "los_period"),
            ),
            "los_time": (
                "los_time",
                np.asarray(first["los_time"], dtype=float),
                output_attrs("simulated_rtd", "los_time"),
            ),
            "los_beam": (
                "los_time",
                np.asarray(first["los_beam"], dtype=np.int8),
                output_attrs("simulated_rtd", "los_beam"),
            ),
        },
    )
