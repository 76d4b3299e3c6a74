"""What the certificate's documents state: page 1's facts, the headline, the certified grid, number formats.

The PDF (:mod:`lidarcal.certificate.document.pages`) and the HTML report
(:mod:`lidarcal.certificate.report`) print the same words and numbers, taken from here:
:func:`certificate_facts` turns the certificate's global attributes into page 1's sections (an
attribute it does not carry is shown as :data:`NOT_STATED`), :func:`signature_status` says what its
seal attributes state (the headline is :func:`lidarcal.certificate.results.headline_text`, the same
in every document), :func:`certified_grid` the certified statement per wind-speed bin and height
(±U, or the Monte Carlo coverage interval where the two differ materially), :func:`not_settled_text`
the values left out because they did not settle, listed apart with their tolerances,
:func:`model_form_grid` the simulation's model-form contributor on the same grid, and :func:`fmt`,
:func:`units_suffix` and :data:`VARIABLE_NAMES` the one way numbers, units and variables are
written.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import DEFAULT_CERTIFIED_RANGE
from lidarcal.certificate.measurand import model_form_values
from lidarcal.certificate.results import (
    certified_mask,
    not_settled,
    not_settled_items,
)
from lidarcal.certificate.seal import INTEGRITY_ATTR, SIGNATURE_ATTR, SIGNATURE_KEY_ATTR
from lidarcal.readback import read_attr

__all__ = [
    "NOT_STATED",
    "VARIABLE_NAMES",
    "fmt",
    "units_suffix",
    "stated",
    "seal_statement",
    "signature_status",
    "certificate_facts",
    "certificate_id",
    "certified_grid",
    "certified_rows",
    "extent_text",
    "not_settled_text",
    "grid_cell",
    "model_form_grid",
]

NOT_STATED = "not stated"
VARIABLE_NAMES = {  # readable names of the environmental variables
    "wind_shear_exponent": "wind shear exponent",
    "turbulence_intensity": "turbulence intensity",
    "cnr_gradient": "CNR gradient",
    "cnr": "CNR",
}


def fmt(value: Any, digits: int = 3) -> str:
    """``value`` with ``digits`` significant digits (``-1.93``, ``0.000123``, ``1230``, ``3.09e-16``)."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not np.isfinite(x):
        return "–" if np.isnan(x) else str(x)
    if x == int(x) and abs(x) < 10**digits:
        return f"{int(x):d}"
    if abs(x) < 1e-4 or abs(x) >= 1e6:
        return f"{x:.{digits - 1}e}"
    return np.format_float_positional(x, precision=digits, unique=False, fractional=False, trim="-")


def units_suffix(da: xr.DataArray) -> str:
    """`` (unit)`` for a label, nothing for a dimensionless variable."""
    u = da.attrs.get("units", "")
    return f" ({u})" if u and u != "1" else ""


def stated(attrs: Mapping[str, Any], *names: str) -> str:
    """Return the first of the attributes ``names`` that is set and not blank, else :data:`NOT_STATED`."""
    for name in names:
        value = attrs.get(name)
        if value is not None and str(value).strip():
            return str(value)
    return NOT_STATED


def seal_statement(signed_by: str | None, certificate: str | None = None,
                   public_key: str | None = None) -> str:
    """Describe the seal of a certificate signed by key ``signed_by`` (fingerprint), or unsigned.

    ``certificate`` (the file's name) and ``public_key`` (the key file) make the command that
    checks it; unknown, the sentence says which file to give instead of a placeholder.
    """
    check = f"check with lidarcal verify {certificate}" if certificate else \
        "check its file with lidarcal verify"
    if signed_by:
        key = f" --public-key {public_key}" if public_key else \
            " and --public-key with the signer's public key"
        return f"signed (Ed25519) by key {signed_by}; {check}{key}"
    return (
        "sealed, unsigned: SHA-256 integrity record only (whoever can rewrite the file can "
        f"re-seal it); {check}"
    )


def signature_status(attrs: Mapping[str, Any], seal: str | None = None) -> str:
    """Say what the certificate's seal and signature attributes say (not a verification).

    ``seal`` (:func:`seal_statement`) stands for a certificate not yet written, whose seal
    and signature are added when it is.  A certificate read from a file is named by it.
    """
    name = read_attr(attrs, "lidarcal_source_file")
    if SIGNATURE_ATTR in attrs:
        return seal_statement(str(attrs.get(SIGNATURE_KEY_ATTR, NOT_STATED)), name)
    if INTEGRITY_ATTR in attrs:
        return seal_statement(None, name)
    return seal or "not sealed (this document was made from a certificate not yet written)"


def certificate_facts(
    attrs: Mapping[str, Any], seal: str | None = None
) -> list[tuple[str, list[tuple[str, str]]]]:
    """Page 1's administrative data as (section, [(label, value)]) from the global attributes."""
    persons = stated(attrs, "responsible_persons")
    bench_start = stated(attrs, "bench_run_start", "bench_time_coverage_start")
    bench_end = stated(attrs, "bench_run_end", "bench_time_coverage_end")
    bench = bench_start if bench_end in (NOT_STATED, bench_start) else f"{bench_start} to\n{bench_end}"
    version = attrs.get("lidarcal_version")
    return [
        (
            "Status",
            [
                ("Calibration status", stated(attrs, "calibration_status")),
                *(
                    [("Why", reason)]
                    if (reason := read_attr(attrs, "calibration_status_reason", kind="certificate"))
                    else []
                ),
                ("Certificate id", certificate_id(attrs)),
                ("Date of issue", stated(attrs, "date_issued", "date_created")),
            ],
        ),
        (
            "Issuer",
            [
                ("Laboratory", stated(attrs, "laboratory_name", "institution")),
                ("Address", stated(attrs, "laboratory_address")),
                ("Responsible", persons.replace("; ", "\n") if persons != NOT_STATED else persons),
                ("Created by", stated(attrs, "creator_name")),
            ],
        ),
        (
            "Customer",
            [("Name", stated(attrs, "customer_name")), ("Address", stated(attrs, "customer_address"))],
        ),
        (
            "Calibrated item",
            [
                ("Manufacturer", stated(attrs, "item_manufacturer")),
                ("Model", stated(attrs, "item_model")),
                ("Serial number", stated(attrs, "item_serial_number", "lidar_serial")),
                ("Firmware", stated(attrs, "item_firmware")),
            ],
        ),
        (
            "Dates and place",
            [
                ("Bench run", bench),
                ("Simulation", stated(attrs, "simulation_date")),
                ("Place", stated(attrs, "calibration_location")),
            ],
        ),
        (
            "Method",
            [
                ("Method", stated(attrs, "method_reference", "references")),
                ("Software", f"lidarcal {version}" if version else NOT_STATED),
                ("Approach", stated(attrs, "budget_approach")),
            ],
        ),
        (
            "Traceability of the bench",
            [
                ("Bench", stated(attrs, "bench_id")),
                ("Bench run", stated(attrs, "bench_run_id")),
                ("Operator", stated(attrs, "bench_operator")),
                ("RF driver cal.", stated(attrs, "rf_driver_calibration_reference")),
            ],
        ),
        ("Signature", [("Seal", signature_status(attrs, seal))]),
    ]


def certificate_id(attrs: Mapping[str, Any]) -> str:
    """Return the certificate id (``certificate_id``, else the ACDD ``id``)."""
    return stated(attrs, "certificate_id", "id")


def not_settled_text(budget: xr.Dataset) -> str:
    """Return the values left out because they did not settle, with their tolerances ("" if none)."""
    items = not_settled_items(budget)
    if not items:
        return ""
    k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
    return (f"Not certified, not settled (U for k = {k:g}, with the largest numerical tolerance of the bin's "
            "values): " + "; ".join(items) + ".")


def grid_cell(g: dict[str, Any], i: int, j: int, *, tolerance: bool = True) -> str:
    """Return the text of one bin of :func:`certified_grid`: "U ± tol", or "low…high" for an interval."""
    if g["statement"] is not None and g["certified"][i, j] and int(g["statement"][i, j]) == 1:
        return f"{g['lower'][i, j]:+.2f}…{g['upper'][i, j]:+.2f}"
    v = g["value"][i, j]
    if not np.isfinite(v):
        return "–"
    text = f"{v:.2f}"
    if tolerance and g["tolerance"] is not None and np.isfinite(g["tolerance"][i, j]):
        text += f" ± {g['tolerance'][i, j]:.2g}"
    return text


def certified_rows(g: Mapping[str, Any]) -> np.ndarray:
    """Return the wind-speed bins (indices) the certified result lists.

    The certified range, cut to the bins certified at some height (empty when nothing is).
    """
    rows = np.flatnonzero(g["inside"])
    some = np.flatnonzero(g["certified"][rows].any(axis=1))
    return rows[some[0]:some[-1] + 1] if some.size else rows[:0]


def extent_text(budget: xr.Dataset, g: Mapping[str, Any] | None = None) -> str | None:
    """Say where the certified values stop inside the certified range, and why; None when they fill it.

    The range is the budget's own (``certified_range_m_s``): bin centres beyond the budget's
    wind-speed axis had no period at all.
    """
    g = certified_grid(budget) if g is None else g
    shown = certified_rows(g)
    if not shown.size:
        return None
    lo, hi = read_attr(budget, "certified_range_m_s", kind="uncertainty_budget")
    ws = g["wind_speed"]
    step = float(np.median(np.diff(ws))) if ws.size > 1 else 0.0
    first, last = float(ws[shown[0]]), float(ws[shown[-1]])
    below, above = first - step / 2 > lo, last + step / 2 < hi  # a whole bin of the range left out
    if not (below or above):
        return None
    meanings = dict(zip(np.atleast_1d(budget["bin_flag"].attrs.get("flag_values", [])).tolist(),
                        str(budget["bin_flag"].attrs.get("flag_meanings", "")).split(), strict=False))
    beyond = np.setdiff1d(np.flatnonzero(g["inside"]), shown)
    found = {meanings.get(int(f)) for f in np.asarray(g["flag"])[beyond].ravel()}
    thin = found <= {"too_few_periods", "empty"}
    sides = " and ".join([f"below {fmt(first)} m/s"] * below + [f"above {fmt(last)} m/s"] * above)
    why = (f"no bin has the {read_attr(budget, 'min_periods', kind='uncertainty_budget')} distinct periods "
           "a certified bin needs, at "
           "any height" if thin and "min_periods" in budget.attrs else "no bin is certified at any height")
    return (f"The certified values span {fmt(first)} to {fmt(last)} m/s of the {fmt(lo)} to {fmt(hi)} m/s "
            f"range: {sides} {why}.")


def certified_grid(
    budget: xr.Dataset, wind_speeds: tuple[float, float] = DEFAULT_CERTIFIED_RANGE
) -> dict[str, Any]:
    """Return the certified result: per (wind speed, height) bin the relative U (k = 2) and its tolerance.

    ``certified`` marks the bins of the headline (flag ok, centre in ``wind_speeds``), or the
    bins the certificate certifies (:func:`lidarcal.certificate.results.certified_mask`) when the
    budget's ``flag_meanings`` have the meaning ``certified``; ``tolerance`` is the budget's
    ``numerical_tolerance`` (same units) or None; ``statement`` the budget's
    ``certified_statement`` (1: the coverage interval ``lower``…``upper``, %) or None;
    ``not_settled`` the bins left out because their values did not settle.
    """
    b = budget.transpose("wind_speed", "height", ...)
    rel = b["relative_expanded_uncertainty"].values
    inside = (b["wind_speed"].values >= wind_speeds[0]) & (b["wind_speed"].values <= wind_speeds[1])
    flag = b["bin_flag"]
    meanings = dict(
        zip(
            str(flag.attrs.get("flag_meanings", "")).split(),
            np.atleast_1d(flag.attrs.get("flag_values", [])).tolist(),
            strict=False,
        )
    )
    good = (
        certified_mask(b).transpose("wind_speed", "height").values
        if "certified" in meanings
        else (flag.values == 0) & inside[:, None]
    )
    certified = good & np.isfinite(rel)
    missed = np.zeros(rel.shape, dtype=bool)
    for z, u in not_settled(b) if "certified" in meanings else []:
        i, j = np.flatnonzero(b["wind_speed"].values == u)[0], np.flatnonzero(b["height"].values == z)[0]
        missed[i, j] = True

    def optional(name: str) -> np.ndarray | None:
        return b[name].transpose("wind_speed", "height").values if name in b else None

    return {
        "wind_speed": b["wind_speed"].values,
        "height": b["height"].values,
        "value": rel,
        "tolerance": optional("numerical_tolerance"),
        "certified": certified,
        "inside": inside,
        "flag": b["bin_flag"].values,
        "statement": optional("certified_statement"),
        "lower": optional("relative_coverage_interval_lower"),
        "upper": optional("relative_coverage_interval_upper"),
        "not_settled": missed,
    }


def model_form_grid(budget: xr.Dataset) -> dict[str, Any] | None:
    """Return the ``model_form`` contributor (%, k = 1) and its standard error, as :func:`certified_grid`.

    None when the budget has no model-form contributor.
    """
    values = model_form_values(budget)
    if values is None:
        return None
    return {**certified_grid(budget), "value": values["value"], "tolerance": values["standard_error"]}
