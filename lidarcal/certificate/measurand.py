"""What U is: the measurand a certified value belongs to, and the simulation's model-form term in words.

:data:`MEASURAND` is the sentence the certificate (global attribute ``measurand``), the PDF, the
HTML report and the DCC state about every certified value (``docs/certificate.md``).
:func:`model_form_values` reads the budget's ``model_form`` contributor and its standard error
relative to the bin's mean reference wind speed, and :func:`model_form_summary` says in one
sentence what it is, how large it is over the certified bins and how much it raises U (the
recipe: :mod:`lidarcal.analysis.model_form`, ``docs/method.md``).  Each takes a certificate or an
``uncertainty_budget``.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.certificate.results import _budget_of, certified_mask
from lidarcal.readback import read_attr

__all__ = ["MEASURAND", "model_form_values", "model_form_summary"]

#: The measurand of a certified value, and what must not be done with the values (docs/certificate.md).
MEASURAND = (
    "U is the expanded uncertainty of a single 10-minute mean of the lidar's horizontal wind speed at that "
    "height in that reference wind-speed bin. The Table 4 terms (beam angle, zero distance, bench) are fully "
    "correlated across bins and heights: whoever aggregates bins must not average them down."
)


def model_form_values(obj: xr.Dataset) -> dict[str, np.ndarray] | None:
    """Relative ``model_form`` contribution and its standard error (%, k = 1) on (wind_speed, height).

    Also ``certified`` (the headline's bins) and ``raise`` (how many percentage points the term adds
    to U).  None when the budget has no ``model_form`` contributor.
    """
    budget = _budget_of(obj)
    if "model_form" not in [str(c) for c in budget["contributor"].values]:
        return None
    b = budget.transpose("wind_speed", "height", ...)
    rel = b["relative_contribution"].sel(contributor="model_form").values
    with np.errstate(invalid="ignore", divide="ignore"):
        se = (100.0 * b["model_form_standard_error"] / b["mean_reference_wind_speed"]).values \
            if "model_form_standard_error" in b else np.full(rel.shape, np.nan)
        k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
        total = b["relative_uncertainty"].values
        raised = k * (total - np.sqrt(np.maximum(total**2 - rel**2, 0.0)))
    return {"value": rel, "standard_error": se, "raise": raised,
            "certified": certified_mask(budget).transpose("wind_speed", "height").values}


def model_form_summary(obj: xr.Dataset) -> str | None:
    """One sentence on the ``model_form`` contributor over the certified bins; None without it."""
    values = model_form_values(obj)
    if values is None:
        return None
    budget = _budget_of(obj)
    alternatives = ([str(a) for a in budget["model_form_alternative"].values]
                    if "model_form_alternative" in budget.coords else [])
    text = ("The uncertainty includes the simulation's model form (contributor model_form): the spread of "
            f"the combined uncertainty across {len(alternatives)} defensible alternative model(s)"
            + (f" ({', '.join(alternatives)})" if alternatives else "")
            + ", simulated with the nominal run's random numbers")
    ok = values["certified"] & np.isfinite(values["value"])
    if not ok.any():
        return text + "; no certified bin."
    se = values["standard_error"][ok]
    return (text + f"; over the certified bins {np.nanmin(values['value'][ok]):.2f} % to "
            f"{np.nanmax(values['value'][ok]):.2f} % of the wind speed (k = 1"
            + (f", standard error up to {np.nanmax(se):.2f} %" if np.isfinite(se).any() else "")
            + f"), raising U by {np.nanmin(values['raise'][ok]):.2f} to {np.nanmax(values['raise'][ok]):.2f} "
            "percentage points.")
