"""What a certificate certifies, read from its budget: the headline and the result table.

The certified bins are those the budget's ``bin_flag`` calls ``certified`` (centre in the
certified wind-speed range and enough distinct periods, :func:`lidarcal.analysis.budget.certified_bins`).
:func:`headline_range` and :func:`headline_sentence` give the range of their k = 2 relative
expanded uncertainty quoted on the certificate, :func:`not_settled` the values the Monte Carlo
did not settle, and :func:`result_table` (``lidarcal table``) one row per height and wind-speed
bin, with why a bin is not certified, its main contributors and the significant sensitivities.
Each takes a certificate or an ``uncertainty_budget``.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import DEFAULT_CERTIFIED_RANGE
from lidarcal.certificate.layout import components, extract_component
from lidarcal.errors import InputError
from lidarcal.io import source_name
from lidarcal.seal import require_valid_seal

__all__ = [
    "certified_rule",
    "not_settled",
    "headline_range",
    "headline_sentence",
    "result_table",
]


def _budget_of(obj: xr.Dataset | xr.DataTree) -> xr.Dataset:
    if isinstance(obj, xr.DataTree):  # as lidarcal.open_certificate gives it: one group per component
        if "budget" not in obj.children:
            raise InputError(f"{source_name(obj.to_dataset())}: certificate tree has no 'budget' group; it "
                             f"has {sorted(obj.children)}")
        return obj["budget"].to_dataset()
    if obj.attrs.get("lidarcal_artefact") == "certificate" or "lidarcal_components" in obj.attrs:
        return extract_component(obj, "budget")
    if "relative_expanded_uncertainty" not in obj:
        kind = obj.attrs.get("lidarcal_artefact")
        what = f"a {kind!r} artefact" if kind else "a file with no lidarcal_artefact attribute"
        raise InputError(f"{source_name(obj)}: expected a certificate or an uncertainty_budget; found {what} "
                         f"and no variable 'relative_expanded_uncertainty' (variables "
                         f"{sorted(map(str, obj.data_vars))})")
    return obj


def _certified_value(budget: xr.Dataset) -> int:
    """Return the ``bin_flag`` value meaning ``certified`` (the budget declares its own meanings)."""
    names = {m: v for v, m in _flag_names(budget["bin_flag"]).items()}
    if "certified" not in names:
        raise InputError(f"{source_name(budget)}: the budget's bin_flag has no meaning 'certified' (found "
                         f"{budget['bin_flag'].attrs.get('flag_meanings')!r}); it predates the certification "
                         "rule: recompute it with lidarcal budget")
    return names["certified"]


def _headline_mask(budget: xr.Dataset) -> xr.DataArray:
    certified = budget["bin_flag"] == _certified_value(budget)
    return certified & np.isfinite(budget["relative_expanded_uncertainty"])


def certified_rule(obj: xr.Dataset) -> str:
    """Return the budget's certification rule in words, e.g. ``centres 4 to 16 m/s, >= 10 periods``."""
    budget = _budget_of(obj)
    lo, hi = np.asarray(budget.attrs.get("certified_range_m_s", DEFAULT_CERTIFIED_RANGE), dtype=float)
    return f"centres {lo:g} to {hi:g} m/s, >= {int(budget.attrs.get('min_periods', 0))} periods"


def not_settled(obj: xr.Dataset) -> list[tuple[float, float]]:
    """(height m, bin centre m/s) of the certified values the Monte Carlo did not settle."""
    budget = _budget_of(obj)
    if "numerical_flag" not in budget:
        return []
    flag = budget["numerical_flag"].transpose("height", "wind_speed").values
    return [(float(budget["height"].values[i]), float(budget["wind_speed"].values[j]))
            for i, j in zip(*np.nonzero(flag == 1), strict=True)]


def headline_range(obj: xr.Dataset, *, wind_speeds: tuple[float, float] | None = None
                   ) -> tuple[float, float] | None:
    """Smallest and largest k = 2 relative expanded uncertainty (%) quoted on the certificate.

    Only certified bins count (``bin_flag`` ``certified``: centre in the certified range and
    enough distinct periods; :func:`lidarcal.analysis.budget.certified_bins`); ``wind_speeds``
    (m/s, inclusive) may narrow them further.  ``obj`` is a certificate or an
    ``uncertainty_budget``; None when no bin qualifies.
    """
    budget = _budget_of(obj)
    mask = _headline_mask(budget)
    if wind_speeds is not None:
        mask = mask & (budget["wind_speed"] >= wind_speeds[0]) & (budget["wind_speed"] <= wind_speeds[1])
    rel = budget["relative_expanded_uncertainty"].where(mask)
    if not bool(np.isfinite(rel).any()):
        return None
    return float(rel.min()), float(rel.max())


def headline_sentence(obj: xr.Dataset) -> str | None:
    """Return the certificate's headline: the certified range and any values that did not settle."""
    budget = _budget_of(obj)
    rng = headline_range(budget)
    if rng is None:
        return None
    text = (f"{rng[0]:.2f} % to {rng[1]:.2f} % (k = {float(budget.attrs.get('coverage_factor', 2)):g}; "
            f"certified bins: {certified_rule(budget)}; lidarcal table lists every bin)")
    missed = not_settled(budget)
    if missed:
        text += (f"; {len(missed)} certified value(s) did not settle to "
                 f"{int(budget.attrs['monte_carlo_significant_digits'])} significant digits within "
                 f"{int(budget.attrs['monte_carlo_replicas'])} Monte Carlo replicas "
                 "(monte_carlo_not_settled)")
    return text


def _flag_names(var: xr.DataArray) -> dict[int, str]:
    values = np.atleast_1d(var.attrs.get("flag_values", []))
    meanings = str(var.attrs.get("flag_meanings", "")).split()
    return {int(v): m for v, m in zip(values, meanings, strict=False)}


def _sensitivities(cert: xr.Dataset | xr.DataTree) -> dict[str, xr.Dataset]:
    """Return the sensitivity components (``sensitivity_<variable>``) of a flat certificate or a tree."""
    if isinstance(cert, xr.DataTree):
        return {str(name): node.to_dataset() for name, node in cert.children.items()
                if str(name).startswith("sensitivity_")}
    return {comp["name"]: extract_component(cert, comp["name"]) for comp in components(cert)
            if comp["name"].startswith("sensitivity_")}


def _significant_sensitivities(cert: xr.Dataset | xr.DataTree) -> dict[float, str]:
    """Per height, the sensitivities significant by Eq. 12 or 13, as readable text."""
    out: dict[float, list[str]] = {}
    for name, sens in _sensitivities(cert).items():
        var = sens.attrs.get("environmental_variable", name[len("sensitivity_"):])
        for z in np.atleast_1d(sens["height"].values):
            one = sens.sel(height=z)
            if not int(one["significant"]):
                continue
            eqs = [eq for eq, name in (("Eq. 12", "significant_eq12"), ("Eq. 13", "significant_eq13"))
                   if int(one[name])]
            out.setdefault(float(z), []).append(
                f"{var}: m*std = {float(one['slope_times_std']):.2f} %, "
                f"m*std*R = {float(one['slope_times_std_times_r']):.2f} % ({', '.join(eqs)})"
            )
    return {z: "; ".join(v) for z, v in out.items()}


def _reason(flag: str, periods: int, budget: xr.Dataset) -> str:
    """Why a bin is not certified, in words ("" when it is)."""
    lo, hi = np.asarray(budget.attrs.get("certified_range_m_s", DEFAULT_CERTIFIED_RANGE), dtype=float)
    return {"certified": "",
            "too_few_periods": f"{periods} periods (fewer than {int(budget.attrs.get('min_periods', 0))})",
            "empty": "no period",
            "outside_certified_range": f"centre outside {lo:g} to {hi:g} m/s"}.get(flag, flag)


def result_table(cert: xr.Dataset | xr.DataTree, *, contributors: int = 3, allow_invalid: bool = False):
    """IEC-style result table of a certificate: one row per height and wind-speed bin.

    Columns: ``height_m``, ``wind_speed_m_s`` (bin centre) and its bounds, ``sample_count``
    (Monte Carlo trials), ``period_count`` (distinct 10-minute periods), ``bin_flag`` (the
    budget's flag meaning: ``certified``, ``too_few_periods``, ``empty``,
    ``outside_certified_range``), ``certified`` (counted in :func:`headline_range`),
    ``not_certified_reason``, the k = 2 expanded uncertainty in m/s and in % of the bin's mean
    reference wind speed, ``numerical_tolerance_pct`` (the Monte Carlo's tolerance on that %,
    JCGM 101 7.9) and ``numerically_settled``, ``model_form_pct`` (the simulation's model-form
    contributor, k = 1, in %; NaN without it), ``main_contributors`` (the largest
    ``contributors`` standard-uncertainty contributions, in %) and ``significant_sensitivities``
    (per height, Eqs. 12-13).  Numbers are the certificate's own values, not rounded.

    ``cert`` is a certificate Dataset (or a budget), or the tree :func:`lidarcal.open_certificate`
    returns.  A certificate read from a file has its seal checked first
    (:func:`lidarcal.seal.require_valid_seal`, on the file the Dataset or tree was read from):
    an altered one raises :class:`~lidarcal.errors.SealError` unless ``allow_invalid`` (the
    caller then shows :func:`lidarcal.seal.invalid_seal_banner` with the table).

    Returns
    -------
    pandas.DataFrame
    """
    import pandas as pd

    is_certificate = "lidarcal_components" in cert.attrs
    if not allow_invalid and is_certificate:
        require_valid_seal(cert.to_dataset() if isinstance(cert, xr.DataTree) else cert)

    budget = _budget_of(cert).load()
    k = float(budget.attrs.get("coverage_factor", 2.0))
    flags = _flag_names(budget["bin_flag"])
    # rows run over (height, wind speed): index by those names, whatever the stored order
    headline = _headline_mask(budget).transpose("height", "wind_speed")
    budget = budget.transpose("height", "wind_speed", ...)
    sens = _significant_sensitivities(cert) if is_certificate else {}
    names = [str(c) for c in budget["contributor"].values]
    mf = names.index("model_form") if "model_form" in names else None
    bounds = budget["wind_speed_bounds"].values if "wind_speed_bounds" in budget else None
    rows = []
    for i, z in enumerate(budget["height"].values):
        for j, u in enumerate(budget["wind_speed"].values):
            rel_c = budget["relative_contribution"].values[i, j]
            order = [n for n in np.argsort(-np.nan_to_num(rel_c, nan=-np.inf)) if np.isfinite(rel_c[n])]
            main = "; ".join(f"{names[n]} {rel_c[n]:.2f} %" for n in order[:contributors])
            flag = int(budget["bin_flag"].values[i, j])
            periods = int(budget["period_count"].values[i, j]) if "period_count" in budget else -1
            tol = (float(budget["numerical_tolerance"].values[i, j]) if "numerical_tolerance" in budget
                   else np.nan)
            nflag = int(budget["numerical_flag"].values[i, j]) if "numerical_flag" in budget else 2
            rows.append({
                "height_m": float(z),
                "wind_speed_m_s": float(u),
                "wind_speed_min_m_s": float(bounds[j, 0]) if bounds is not None else np.nan,
                "wind_speed_max_m_s": float(bounds[j, 1]) if bounds is not None else np.nan,
                "sample_count": int(budget["sample_count"].values[i, j]),
                "period_count": periods,
                "bin_flag": flags.get(flag, str(flag)),
                "certified": bool(headline.values[i, j]),
                "not_certified_reason": _reason(flags.get(flag, str(flag)), periods, budget),
                f"expanded_uncertainty_k{k:g}_m_s": float(budget["expanded_uncertainty"].values[i, j]),
                f"expanded_uncertainty_k{k:g}_pct": float(
                    budget["relative_expanded_uncertainty"].values[i, j]),
                "numerical_tolerance_pct": tol,
                "numerically_settled": {0: "yes", 1: "no"}.get(nflag, ""),
                "model_form_pct": float(rel_c[mf]) if mf is not None else np.nan,
                "main_contributors": main,
                "significant_sensitivities": sens.get(float(z), ""),
            })
    table = pd.DataFrame(rows)
    table.attrs["coverage_factor"] = k
    table.attrs["certified_rule"] = certified_rule(budget)
    table.attrs["headline_range_pct"] = headline_range(budget)
    table.attrs["not_settled"] = not_settled(budget)
    table.attrs["significant_digits"] = budget.attrs.get("monte_carlo_significant_digits")
    return table

