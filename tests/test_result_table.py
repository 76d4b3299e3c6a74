"""The certificate read back: the IEC-style result table, the DataTree view and pint units."""

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from analysis_factories import make_records

import lidarcal
import lidarcal.cli.table
from lidarcal.analysis import budget, sensitivity
from lidarcal.analysis.rule import CertificationRule
from lidarcal.analysis.terms import PAPER_INPUTS, TABLE4_WIND_SPEEDS, uncertainty_terms
from lidarcal.certificate import headline_range, make_certificate, result_table
from lidarcal.certificate.seal import write_certificate
from lidarcal.cli import main
from lidarcal.io import write_artefact

SERIAL = "WLS7-TABLE"


@pytest.fixture(scope="module")
def cert_path(tmp_path_factory):
    """A sealed certificate whose budget has a thin, a slow and an unsettled bin with large values.

    The records span about 2-14 m/s, with eight Monte Carlo replicas of every period (the budget
    settles its values to one significant digit).  A budget written by other code may keep a
    value in a flagged bin, so the 8 m/s bin at 120 m is flagged too_few_periods with a finite
    50 %, the well-filled bin at 2 m/s and 80 m (outside the certified range) gets 40 % and the
    10 m/s bin at 80 m is flagged not_settled with 60 %: the headline must leave all three out.
    """
    d = tmp_path_factory.mktemp("table")
    records = make_records(n=500, heights=(80.0, 120.0), lidar_serial=SERIAL, shear_slope=(8.0, 0.0),
                           replicas=8)
    for name in ("wind_speed", "lidar_wind_speed", "reference_wind_speed", "trial_lidar_wind_speed",
                 "trial_reference_wind_speed"):
        records[name] = records[name] * (12 / 11) - 3.0  # about 1.9 to 13.9 m/s, same relative error
    bud = budget(records, rule=CertificationRule(significant_digits=1))
    rel = bud["relative_expanded_uncertainty"]
    j8 = int(np.argmin(abs(bud["wind_speed"].values - 8.0)))
    bud["bin_flag"][{"height": 1, "wind_speed": j8}] = 1
    rel[{"height": 1, "wind_speed": j8}] = 50.0
    j10 = int(np.argmin(abs(bud["wind_speed"].values - 10.0)))
    assert bud["bin_flag"].isel(height=0, wind_speed=j10) == 0  # certified until planted unsettled
    bud["bin_flag"][{"height": 0, "wind_speed": j10}] = 4
    bud["numerical_flag"][{"height": 0, "wind_speed": j10}] = 1
    rel[{"height": 0, "wind_speed": j10}] = 60.0
    j2 = int(np.argmin(abs(bud["wind_speed"].values - 2.0)))
    assert bud["bin_flag"].isel(height=0, wind_speed=j2) == 3 and bud["wind_speed"].values[j2] == 2.0
    assert bud["period_count"].isel(height=0, wind_speed=j2) >= 10  # not certified only by its speed
    rel[{"height": 0, "wind_speed": j2}] = 40.0
    sens = [sensitivity(records, v) for v in ("wind_shear_exponent", "turbulence_intensity")]
    terms = uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS)
    cert = make_certificate(budget=bud, sensitivities=sens, terms=terms, demonstration=True)
    path = write_certificate(cert, d / "cert.nc")
    write_artefact(bud, d / "budget.nc")
    return path


def _brute_headline(bud):
    """Loop over every bin: >= 10 periods, centre in [4, 16] m/s, finite value, settled, not planted thin."""
    vals = []
    bud = bud.transpose("height", "wind_speed", ...)  # the loops index (height, wind speed)
    for i in range(bud.sizes["height"]):
        for j, u in enumerate(bud["wind_speed"].values):
            v = float(bud["relative_expanded_uncertainty"].values[i, j])
            planted = int(bud["bin_flag"].values[i, j]) == 1 and bud["period_count"].values[i, j] >= 10
            settled = int(bud["numerical_flag"].values[i, j]) == 0
            if (bud["period_count"].values[i, j] >= 10 and 4.0 <= u <= 16.0 and np.isfinite(v) and not planted
                    and settled):
                vals.append(v)
    return min(vals), max(vals)


def test_table_numbers_are_the_certificate_values(cert_path):
    cert = xr.open_dataset(cert_path)
    table = result_table(cert)
    cert = cert.transpose("budget_height", "budget_wind_speed", ...)  # the loops index (height, wind speed)
    nh, nu = cert.sizes["budget_height"], cert.sizes["budget_wind_speed"]
    assert len(table) == nh * nu
    got = table.set_index(["height_m", "wind_speed_m_s"])
    for i, z in enumerate(cert["budget_height"].values):
        for j, u in enumerate(cert["budget_wind_speed"].values):
            row = got.loc[(z, u)]
            # the same float64 values, not recomputed: exact equality (NaN = NaN)
            np.testing.assert_array_equal(row["expanded_uncertainty_k2_m_s"],
                                          cert["budget_expanded_uncertainty"].values[i, j])
            np.testing.assert_array_equal(row["expanded_uncertainty_k2_pct"],
                                          cert["budget_relative_expanded_uncertainty"].values[i, j])
            assert row["sample_count"] == cert["budget_sample_count"].values[i, j]
            assert row["period_count"] == cert["budget_period_count"].values[i, j]
            flag = int(cert["budget_bin_flag"].values[i, j])
            meanings = ["certified", "too_few_periods", "empty", "outside_certified_range", "not_settled"]
            assert row["bin_flag"] == meanings[flag]
            assert row["certified"] == (flag == 0) and (row["not_certified_reason"] == "") == (flag == 0)
    # the contributors: the largest relative contributions of one well-filled bin, by name
    i, j = 0, int(np.argmax(cert["budget_sample_count"].values[0]))
    rc = cert["budget_relative_contribution"].values[i, j]
    names = [str(n) for n in cert["budget_contributor"].values]
    order = np.argsort(rc)[::-1][:3]
    expected = "; ".join(f"{names[n]} {rc[n]:.2f} %" for n in order)
    assert got.loc[(cert["budget_height"].values[i], cert["budget_wind_speed"].values[j]),
                   "main_contributors"] == expected


def test_headline_leaves_out_flagged_and_out_of_range_bins(cert_path):
    cert = xr.open_dataset(cert_path)
    bud = lidarcal.certificate.extract_component(cert, "budget")
    lo, hi = headline_range(cert)
    assert (lo, hi) == _brute_headline(bud)
    assert hi < 40.0  # neither the planted thin bin (50 %), the 2 m/s bin (40 %) nor the unsettled one (60 %)
    table = result_table(cert)
    assert not table.loc[table["bin_flag"] != "certified", "certified"].any()
    reasons = table.set_index(["height_m", "wind_speed_m_s"])["not_certified_reason"]
    assert reasons.loc[(80.0, 2.0)] == "centre outside 4 to 16 m/s"
    assert reasons.loc[(120.0, 8.0)].endswith("periods (fewer than 10)")
    assert reasons.loc[(80.0, 10.0)] == "not settled to 1 significant digit within 8 Monte Carlo replicas"
    inside = table[table["certified"]]
    pct = inside["expanded_uncertainty_k2_pct"]
    assert (pct.min(), pct.max()) == (lo, hi)
    assert cert.attrs["expanded_uncertainty_headline"].startswith(f"{lo:.2f} % to {hi:.2f} %")


def test_a_value_that_did_not_settle_is_listed_apart_never_certified(cert_path):
    """JCGM 101 7.9: the planted unsettled bin (80 m, 10 m/s, 60 %) is in no certified result."""
    cert = xr.open_dataset(cert_path)
    table = result_table(cert)
    row = table.set_index(["height_m", "wind_speed_m_s"]).loc[(80.0, 10.0)]
    assert row["bin_flag"] == "not_settled" and not row["certified"] and row["certified_statement"] == ""
    assert 60.0 not in table.loc[table["certified"], "expanded_uncertainty_k2_pct"].values
    apart = table.attrs["not_settled_rows"]
    assert [(r["height_m"], r["wind_speed_m_s"], r["expanded_uncertainty_pct"]) for r in apart] == [
        (80.0, 10.0, 60.0)]
    # with the tolerance each value reached, as the budget states it
    bud = lidarcal.certificate.extract_component(cert, "budget").sel(height=80.0, wind_speed=10.0)
    tol = float(bud["numerical_tolerance_coverage_interval_upper"])
    assert apart[0]["tolerance_interval_upper_pct"] == tol
    headline = cert.attrs["expanded_uncertainty_headline"]
    assert "60.00" not in headline and "1 bin(s) did not settle" in headline
    assert cert.attrs["monte_carlo_not_settled"].startswith("80 m 10 m/s (U 60.00 %")
    md = lidarcal.cli.table.render(table, "md")
    assert "## Not certified: Monte Carlo values not settled" in md
    assert "- 80 m 10 m/s (U 60.00 %" in md  # the certificate's own wording (monte_carlo_not_settled)


def test_significant_sensitivities_per_height(cert_path):
    cert = xr.open_dataset(cert_path)
    table = result_table(cert).drop_duplicates("height_m").set_index("height_m")
    for z in cert["sensitivity_wind_shear_exponent_height"].values:
        sig = int(cert["sensitivity_wind_shear_exponent_significant"].sel(
            sensitivity_wind_shear_exponent_height=z))
        text = table.loc[z, "significant_sensitivities"]
        assert ("wind_shear_exponent" in text) == bool(sig)
        if sig:
            m_std = float(cert["sensitivity_wind_shear_exponent_slope_times_std"].sel(
                sensitivity_wind_shear_exponent_height=z))
            assert f"m*std = {m_std:.2f} %" in text
    # the factory plants 8 % per unit alpha at 80 m and none at 120 m: Eq. 12/13 must see it
    assert "wind_shear_exponent" in table.loc[80.0, "significant_sensitivities"]


@pytest.mark.parametrize("fmt", ["csv", "md", "html"])
def test_table_cli_formats(cert_path, tmp_path, capsys, fmt):
    out = tmp_path / f"t.{fmt}"
    assert main(["table", str(cert_path), "-o", str(out)]) == 0
    text = out.read_text()
    lo, hi = headline_range(xr.open_dataset(cert_path))
    if fmt == "csv":
        back = pd.read_csv(out)
        assert len(back) == len(result_table(xr.open_dataset(cert_path)))
        # CSV keeps pandas' shortest round-trip repr of the float64: equal to the last bit
        assert back["expanded_uncertainty_k2_pct"].where(back["certified"]).max() == hi
    else:
        assert f"{lo:.2f} % to {hi:.2f} %" in text and "Significant sensitivities" in text
    assert main(["table", str(cert_path), "-o", str(out)]) == 2  # never replaced silently
    assert "exists" in capsys.readouterr().err
    assert main(["table", str(cert_path.parent / "budget.nc")]) == 2
    assert "expected a 'certificate' artefact" in capsys.readouterr().err


def test_open_certificate_tree(cert_path):
    tree = lidarcal.open_certificate(cert_path)
    assert isinstance(tree, xr.DataTree)
    assert set(tree.children) == {"budget", "terms", "sensitivity_wind_shear_exponent",
                                  "sensitivity_turbulence_intensity"}
    flat = xr.open_dataset(cert_path)
    one = tree["budget"].sel(height=120, wind_speed=8, method="nearest")
    i = int(np.argmin(abs(flat["budget_height"].values - 120)))
    j = int(np.argmin(abs(flat["budget_wind_speed"].values - 8)))
    expected = flat["budget_relative_expanded_uncertainty"].isel(budget_height=i, budget_wind_speed=j)
    assert float(one["relative_expanded_uncertainty"]) == expected
    assert tree["budget"].dataset["wind_speed"].attrs["bounds"] == "wind_speed_bounds"
    # the cf accessor finds one vertical axis per group (the flat file has one per component)
    assert tree["budget"].dataset.cf["Z"].name == "height"
    assert tree.attrs["lidar_serial"] == SERIAL
    # eager: a certificate is small, values are numpy arrays an analyst can .item()
    assert tree["budget"].dataset["uncertainty"].chunks is None
    cell = tree["budget"].ds.relative_expanded_uncertainty.sel(height=120, wind_speed=8, method="nearest")
    value = cell.item()
    assert value == expected.item()
    # lazy on request
    lazy = lidarcal.open_certificate(cert_path, chunks={})
    assert lazy["budget"].dataset["uncertainty"].chunks is not None


def test_open_certificate_refuses_other_artefacts(cert_path):
    with pytest.raises(lidarcal.errors.InputError, match="budget.nc: not a lidarcal certificate"):
        lidarcal.open_certificate(cert_path.parent / "budget.nc")


def test_certificate_written_before_not_settled_still_reads_and_verifies(tmp_path):
    """A budget of the earlier rule: bin_flag 0-3, an unsettled value certified with numerical_flag 1.

    Such a certificate opens and verifies; its unsettled value is read as not settled: out of the
    headline and the certified rows, listed apart.
    """
    from lidarcal.certificate.seal import verify_certificate

    records = make_records(n=400, heights=(80.0,), lidar_serial=SERIAL, replicas=8)
    bud = budget(records, rule=CertificationRule(significant_digits=1))
    j = int(np.argmin(abs(bud["wind_speed"].values - 9.0)))
    assert int(bud["bin_flag"].isel(height=0, wind_speed=j)) == 0
    # the earlier budget: no JCGM 101 distribution, four flag meanings, the value still flagged certified
    new = ("relative_coverage", "coverage_interval", "numerical_tolerance_", "certified_statement",
           "relative_mean", "relative_error", "error_", "effective_", "expanded_uncertainty_coverage",
           "replica")
    old = bud.drop_vars([v for v in bud.data_vars if v.startswith(new)])
    old["bin_flag"].attrs.update(flag_values=np.array([0, 1, 2, 3], dtype=np.int8),
                                 flag_meanings="certified too_few_periods empty outside_certified_range")
    old["numerical_flag"][{"height": 0, "wind_speed": j}] = 1
    old["relative_expanded_uncertainty"][{"height": 0, "wind_speed": j}] = 70.0
    cert = make_certificate(budget=old, sensitivities=[sensitivity(records, "wind_shear_exponent")],
                            demonstration=True)
    path = write_certificate(cert, tmp_path / "old.nc")
    assert verify_certificate(path).ok
    back = xr.open_dataset(path)
    lo, hi = headline_range(back)
    assert hi < 70.0
    table = result_table(back).set_index(["height_m", "wind_speed_m_s"])
    row = table.loc[(80.0, float(bud["wind_speed"].values[j]))]
    assert row["bin_flag"] == "not_settled" and not row["certified"]
    assert [r["wind_speed_m_s"] for r in result_table(back).attrs["not_settled_rows"]] == [
        float(bud["wind_speed"].values[j])]
