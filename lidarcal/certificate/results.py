"""What a certificate certifies, read from its budget: the headline and the result table.

The certified bins are those the budget's ``bin_flag`` calls ``certified`` (centre in the
certified wind-speed range, enough distinct periods and, for the Monte Carlo, every value
settled; :func:`lidarcal.analysis.certification.certified_bins`); :func:`certified_mask` reads
that flag, for every reader here and in the documents and the DCC.  A certificate written before
the flag had the meaning ``not_settled`` marked such values only in ``numerical_flag``; they are
read as not settled, and not certified, all the same.  :func:`headline_range` and
:func:`headline_sentence` give the range of the k = 2 relative expanded uncertainty quoted on the
certificate (settled certified values only; the one builder of the headline, which every document
shows after :data:`HEADLINE_LABEL`: :func:`headline_text`), :func:`not_settled` and
:func:`not_settled_rows` the values the Monte Carlo did not settle (listed apart, with their
tolerances; :func:`not_settled_sentence` and :func:`not_settled_items` the one wording of them), and
:func:`result_table` (``lidarcal table``) one row per height and wind-speed bin, with why a bin
is not certified, what it certifies (±U or the Monte Carlo coverage interval), its main
contributors and the significant sensitivities.  Each takes a certificate or an
``uncertainty_budget``.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lidarcal.analysis.certification import digits_text
from lidarcal.certificate.layout import components, extract_component
from lidarcal.certificate.seal import require_valid_seal
from lidarcal.errors import InputError
from lidarcal.io import source_name
from lidarcal.readback import read_attr

__all__ = [
    "certified_mask",
    "certified_rule",
    "not_settled",
    "not_settled_rows",
    "headline_range",
    "headline_sentence",
    "headline_text",
    "HEADLINE_LABEL",
    "not_settled_sentence",
    "not_settled_items",
    "coverage_interval_bins",
    "result_table",
]


def _budget_of(obj: xr.Dataset | xr.DataTree) -> xr.Dataset:
    if isinstance(obj, xr.DataTree):  # as lidarcal.open_certificate gives it: one group per component
        if "budget" not in obj.children:
            raise InputError(f"{source_name(obj.to_dataset())}: certificate tree has no 'budget' group; it "
                             f"has {sorted(obj.children)}")
        return obj["budget"].to_dataset()
    if read_attr(obj, "lidarcal_artefact") == "certificate" or "lidarcal_components" in obj.attrs:
        return extract_component(obj, "budget")
    if "relative_expanded_uncertainty" not in obj:
        kind = read_attr(obj, "lidarcal_artefact")
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


def _not_settled_mask(budget: xr.Dataset) -> xr.DataArray:
    """Return the bins whose Monte Carlo values did not settle.

    ``bin_flag`` ``not_settled``, or (a certificate written before that meaning) ``certified``
    with ``numerical_flag`` ``not_settled``.
    """
    names = {m: v for v, m in _flag_names(budget["bin_flag"]).items()}
    if "not_settled" in names:
        return budget["bin_flag"] == names["not_settled"]
    if "numerical_flag" in budget and "certified" in names:
        numerical = {m: v for v, m in _flag_names(budget["numerical_flag"]).items()}
        unsettled = budget["numerical_flag"] == numerical.get("not_settled", 1)
        return (budget["bin_flag"] == names["certified"]) & unsettled
    return xr.zeros_like(budget["bin_flag"], dtype=bool)


def certified_mask(obj: xr.Dataset) -> xr.DataArray:
    """Bins the certificate certifies: ``bin_flag`` ``certified``, settled, with a finite value.

    The one reader of the certification rule (:func:`lidarcal.analysis.certification.certified_bins`)
    for the headline, the table, the documents and the DCC.
    """
    budget = _budget_of(obj)
    certified = budget["bin_flag"] == _certified_value(budget)
    return certified & ~_not_settled_mask(budget) & np.isfinite(budget["relative_expanded_uncertainty"])


def certified_rule(obj: xr.Dataset) -> str:
    """Return the budget's certification rule in words, e.g. ``centres 4 to 16 m/s, >= 10 periods``.

    With a Monte Carlo numerical state, ``, settled to N significant digits`` follows.
    """
    budget = _budget_of(obj)
    lo, hi = read_attr(budget, "certified_range_m_s", kind="uncertainty_budget")
    fewest = read_attr(budget, "min_periods", kind="uncertainty_budget")
    text = f"centres {lo:g} to {hi:g} m/s, >= {fewest} periods"
    digits = read_attr(budget, "monte_carlo_significant_digits", kind="uncertainty_budget")
    if "numerical_flag" in budget and digits is not None:
        text += f", settled to {digits_text(digits)}"
    return text


def not_settled(obj: xr.Dataset) -> list[tuple[float, float]]:
    """(height m, bin centre m/s) of the bins not certified because their values did not settle."""
    budget = _budget_of(obj)
    flag = _not_settled_mask(budget).transpose("height", "wind_speed").values
    return [(float(budget["height"].values[i]), float(budget["wind_speed"].values[j]))
            for i, j in zip(*np.nonzero(flag), strict=True)]


#: The tolerances a not-settled value is listed with, and the columns they go to.
_TOLERANCES = {"numerical_tolerance": "tolerance_expanded_pct",
               "numerical_tolerance_mean_difference": "tolerance_mean_difference_pct",
               "numerical_tolerance_error_standard_uncertainty": "tolerance_standard_uncertainty_pct",
               "numerical_tolerance_coverage_interval_lower": "tolerance_interval_lower_pct",
               "numerical_tolerance_coverage_interval_upper": "tolerance_interval_upper_pct"}


def not_settled_rows(obj: xr.Dataset) -> list[dict[str, float]]:
    """Return the values not certified because they did not settle, apart, with their tolerances.

    One dict per bin: ``height_m``, ``wind_speed_m_s``, the relative expanded uncertainty
    ``expanded_uncertainty_pct`` (k as the budget's), the tolerance each value reached
    (``tolerance_expanded_pct``, ``tolerance_mean_difference_pct``, ... where the budget has
    them) and the replicas that estimated it.
    """
    budget = _budget_of(obj).transpose("height", "wind_speed", ...)
    out = []
    for z, u in not_settled(budget):
        cell = budget.sel(height=z, wind_speed=u)
        row = {"height_m": z, "wind_speed_m_s": u,
               "expanded_uncertainty_pct": float(cell["relative_expanded_uncertainty"])}
        row.update({col: float(cell[name]) for name, col in _TOLERANCES.items() if name in budget})
        if "replicas_needed" in budget:
            row["replicas_needed"] = int(cell["replicas_needed"])
        out.append(row)
    return out


def headline_range(obj: xr.Dataset, *, wind_speeds: tuple[float, float] | None = None
                   ) -> tuple[float, float] | None:
    """Smallest and largest k = 2 relative expanded uncertainty (%) quoted on the certificate.

    Only certified bins count (``bin_flag`` ``certified``: centre in the certified range and
    enough distinct periods; :func:`lidarcal.analysis.budget.certified_bins`); ``wind_speeds``
    (m/s, inclusive) may narrow them further.  ``obj`` is a certificate or an
    ``uncertainty_budget``; None when no bin qualifies.
    """
    budget = _budget_of(obj)
    mask = certified_mask(budget)
    if wind_speeds is not None:
        mask = mask & (budget["wind_speed"] >= wind_speeds[0]) & (budget["wind_speed"] <= wind_speeds[1])
    rel = budget["relative_expanded_uncertainty"].where(mask)
    if not bool(np.isfinite(rel).any()):
        return None
    return float(rel.min()), float(rel.max())


#: The label every document puts before :func:`headline_sentence` (the DCC, the PDF, the HTML report
#: and ``lidarcal table``; :func:`headline_text`).
HEADLINE_LABEL = "Expanded uncertainty"


def _settle_limits(budget: xr.Dataset) -> str:
    """How far the Monte Carlo went: ``to 1 significant digit within 8 Monte Carlo replicas``."""
    digits = read_attr(budget, "monte_carlo_significant_digits", kind="uncertainty_budget")
    replicas = read_attr(budget, "monte_carlo_replicas", kind="uncertainty_budget")
    return f"to {digits_text(digits)} within {replicas} Monte Carlo replicas"


def not_settled_sentence(obj: xr.Dataset) -> str:
    """Return how many bins did not settle and so are not certified, as one clause ("" if none).

    The one wording of it (JCGM 101 7.9: the Monte Carlo stopped at ``--max-replicas`` before
    these values settled), in the headline of every document and in the budget's summary.
    """
    budget = _budget_of(obj)
    missed = not_settled(budget)
    if not missed:
        return ""
    return (f"{len(missed)} bin(s) did not settle {_settle_limits(budget)} "
            "and are not certified (listed apart)")


def not_settled_items(obj: xr.Dataset) -> list[str]:
    """Return each bin left out because it did not settle, as text: its U and largest tolerance.

    ``40 m 5.5 m/s (U 1.23 %, tolerance 0.05 %)``: the one wording of a row of
    :func:`not_settled_rows`, in the certificate (``monte_carlo_not_settled``), the documents and
    ``lidarcal table``.  The tolerance is the largest finite one of the bin's values.
    """
    out = []
    for r in not_settled_rows(obj):
        tol = [v for c, v in r.items() if c.startswith("tolerance_") and np.isfinite(v)]
        out.append(f"{r['height_m']:g} m {r['wind_speed_m_s']:g} m/s (U {r['expanded_uncertainty_pct']:.2f} %"
                   + (f", tolerance {max(tol):.2g} %)" if tol else ")"))
    return out


def headline_sentence(obj: xr.Dataset) -> str | None:
    """Return the certificate's headline: the certified range, what is certified, what did not settle.

    The one builder of the headline (sealed into the certificate as ``expanded_uncertainty_headline``;
    every document shows it after :data:`HEADLINE_LABEL`, :func:`headline_text`); None when no bin
    is certified.
    """
    budget = _budget_of(obj)
    rng = headline_range(budget)
    if rng is None:
        return None
    k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
    text = (f"{rng[0]:.2f} % to {rng[1]:.2f} % (k = {k:g}; "
            f"certified bins: {certified_rule(budget)}; lidarcal table lists every bin)")
    intervals = coverage_interval_bins(budget)
    if intervals:
        lows = [lo for lo, _ in intervals.values()]
        highs = [hi for _, hi in intervals.values()]
        text += (f"; in {len(intervals)} of them the Monte Carlo 95 % coverage interval of the error is "
                 "certified instead of +-U (they differ materially; ends "
                 f"{min(lows):+.2f} % to {max(highs):+.2f} %)")
    if missed := not_settled_sentence(budget):
        text += f"; {missed}"
    return text


def headline_text(obj: xr.Dataset) -> str:
    """Return the headline as every document shows it: :data:`HEADLINE_LABEL`, then the sentence.

    With no certified bin: the label, ``nothing is certified``, the rule and what did not settle.
    """
    budget = _budget_of(obj)
    sentence = headline_sentence(budget)
    if sentence is None:
        k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
        sentence = (f"nothing is certified (k = {k:g}; "
                    f"certified bins: {certified_rule(budget)}; lidarcal table lists every bin)")
        if missed := not_settled_sentence(budget):
            sentence += f"; {missed}"
    return f"{HEADLINE_LABEL}: {sentence}"


def coverage_interval_bins(obj: xr.Dataset) -> dict[tuple[float, float], tuple[float, float]]:
    """Return the certified bins that certify the Monte Carlo interval: (height, centre) -> (low, high) %."""
    budget = _budget_of(obj)
    if "certified_statement" not in budget:
        return {}
    names = {m: v for v, m in _flag_names(budget["certified_statement"]).items()}
    pick = (certified_mask(budget) & (budget["certified_statement"] == names.get("coverage_interval", 1)))
    pick = pick.transpose("height", "wind_speed").values
    lo = budget["relative_coverage_interval_lower"].transpose("height", "wind_speed").values
    hi = budget["relative_coverage_interval_upper"].transpose("height", "wind_speed").values
    return {(float(budget["height"].values[i]), float(budget["wind_speed"].values[j])): (float(lo[i, j]),
                                                                                          float(hi[i, j]))
            for i, j in zip(*np.nonzero(pick), strict=True)}


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
        var = read_attr(sens, "environmental_variable", kind="sensitivity",
                        default=name[len("sensitivity_"):])
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
    lo, hi = read_attr(budget, "certified_range_m_s", kind="uncertainty_budget")
    return {"certified": "",
            "too_few_periods": (f"{periods} periods (fewer than "
                                f"{read_attr(budget, 'min_periods', kind='uncertainty_budget')})"),
            "empty": "no period",
            "outside_certified_range": f"centre outside {lo:g} to {hi:g} m/s",
            "not_settled": f"not settled {_settle_limits(budget)}",
            }.get(flag, flag)


def _value(budget: xr.Dataset, name: str, i: int, j: int) -> float:
    return float(budget[name].values[i, j]) if name in budget else np.nan


#: The Monte Carlo columns of the result table: column -> budget variable (JCGM 101).
_MONTE_CARLO_COLUMNS = {
    "mean_difference_pct": "relative_mean_difference",
    "standard_uncertainty_pct": "relative_error_standard_uncertainty",
    "coverage_interval_lower_pct": "relative_coverage_interval_lower",
    "coverage_interval_upper_pct": "relative_coverage_interval_upper",
    "expanded_uncertainty_coverage_pct": "expanded_uncertainty_coverage",
    "effective_degrees_of_freedom": "effective_degrees_of_freedom",
}


def result_table(cert: xr.Dataset | xr.DataTree, *, contributors: int = 3, allow_invalid: bool = False):
    """IEC-style result table of a certificate: one row per height and wind-speed bin.

    Columns: ``height_m``, ``wind_speed_m_s`` (bin centre) and its bounds, ``sample_count``
    (Monte Carlo trials), ``period_count`` (distinct 10-minute periods), ``bin_flag`` (the
    budget's flag meaning: ``certified``, ``too_few_periods``, ``empty``,
    ``outside_certified_range``, ``not_settled``), ``certified`` (counted in
    :func:`headline_range`), ``not_certified_reason``, ``certified_statement`` (``expanded_uncertainty``:
    ±U; ``coverage_interval``: the Monte Carlo interval; empty when not certified), the k = 2
    expanded uncertainty in m/s and in % of the bin's mean reference wind speed,
    ``numerical_tolerance_pct`` (the Monte Carlo's tolerance on that %, JCGM 101 7.9) and
    ``numerically_settled``; the Monte Carlo distribution of the error of one 10-minute mean
    (``mean_difference_pct``, ``standard_uncertainty_pct``, ``coverage_interval_lower_pct`` and
    ``_upper_pct``, each with its ``tolerance_*`` column, ``expanded_uncertainty_coverage_pct``
    and ``effective_degrees_of_freedom``); ``model_form_pct`` (the simulation's model-form
    contributor, k = 1, in %; NaN without it), ``main_contributors`` (the largest ``contributors``
    standard-uncertainty contributions, in %) and ``significant_sensitivities`` (per height, Eqs.
    12-13).  Numbers are the certificate's own values, not rounded.  The table's attributes
    carry the headline range, the rule, ``headline`` (:func:`headline_text`), ``not_settled_rows``
    (:func:`not_settled_rows`) and ``not_settled_items`` (:func:`not_settled_items`).

    ``cert`` is a certificate Dataset (or a budget), or the tree :func:`lidarcal.open_certificate`
    returns.  A certificate read from a file has its seal checked first
    (:func:`lidarcal.certificate.seal.require_valid_seal`, on the file the Dataset or tree was read from):
    an altered one raises :class:`~lidarcal.errors.SealError` unless ``allow_invalid`` (the
    caller then shows :func:`lidarcal.certificate.seal.invalid_seal_banner` with the table).

    Returns
    -------
    pandas.DataFrame
    """
    import pandas as pd

    is_certificate = "lidarcal_components" in cert.attrs
    if not allow_invalid and is_certificate:
        require_valid_seal(cert.to_dataset() if isinstance(cert, xr.DataTree) else cert)

    budget = _budget_of(cert).load()
    k = read_attr(budget, "coverage_factor", kind="uncertainty_budget")
    flags = _flag_names(budget["bin_flag"])
    statements = _flag_names(budget["certified_statement"]) if "certified_statement" in budget else {}
    # rows run over (height, wind speed): index by those names, whatever the stored order
    headline = certified_mask(budget).transpose("height", "wind_speed")
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
            tol = _value(budget, "numerical_tolerance", i, j)
            nflag = int(budget["numerical_flag"].values[i, j]) if "numerical_flag" in budget else 2
            certified = bool(headline.values[i, j])
            label = flags.get(flag, str(flag))
            if label == "certified" and not certified and nflag == 1:
                label = "not_settled"  # a certificate written before bin_flag had that meaning
            row = {
                "height_m": float(z),
                "wind_speed_m_s": float(u),
                "wind_speed_min_m_s": float(bounds[j, 0]) if bounds is not None else np.nan,
                "wind_speed_max_m_s": float(bounds[j, 1]) if bounds is not None else np.nan,
                "sample_count": int(budget["sample_count"].values[i, j]),
                "period_count": periods,
                "bin_flag": label,
                "certified": certified,
                "not_certified_reason": _reason(label, periods, budget),
                "certified_statement": (statements.get(int(budget["certified_statement"].values[i, j]), "")
                                        if certified and "certified_statement" in budget else
                                        ("expanded_uncertainty" if certified else "")),
                f"expanded_uncertainty_k{k:g}_m_s": float(budget["expanded_uncertainty"].values[i, j]),
                f"expanded_uncertainty_k{k:g}_pct": float(
                    budget["relative_expanded_uncertainty"].values[i, j]),
                "numerical_tolerance_pct": tol,
                "numerically_settled": {0: "yes", 1: "no"}.get(nflag, ""),
            }
            for col, name in _MONTE_CARLO_COLUMNS.items():
                row[col] = _value(budget, name, i, j)
            for name, col in _TOLERANCES.items():
                if name != "numerical_tolerance":
                    row[col] = _value(budget, name, i, j)
            row["model_form_pct"] = float(rel_c[mf]) if mf is not None else np.nan
            row["main_contributors"] = main
            row["significant_sensitivities"] = sens.get(float(z), "")
            rows.append(row)
    table = pd.DataFrame(rows)
    table.attrs["coverage_factor"] = k
    table.attrs["certified_rule"] = certified_rule(budget)
    table.attrs["headline_range_pct"] = headline_range(budget)
    table.attrs["not_settled"] = not_settled(budget)
    table.attrs["not_settled_rows"] = not_settled_rows(budget)
    table.attrs["not_settled_items"] = not_settled_items(budget)
    table.attrs["headline"] = headline_text(budget)
    table.attrs["coverage_interval_bins"] = len(coverage_interval_bins(budget))
    table.attrs["significant_digits"] = read_attr(budget, "monte_carlo_significant_digits",
                                                  kind="uncertainty_budget")
    return table

