"""Tests of the non-simulated uncertainty terms (paper §2.4, Eqs. 6–11, Table 4)."""

import json
from decimal import ROUND_HALF_UP, Decimal

import numpy as np
import pytest
import xarray as xr
from analysis_factories import var_attrs

from lidarcal.analysis.terms import (
    CONTRIBUTORS,
    NOISE_TERMS,
    PAPER_INPUTS,
    TABLE4_WIND_SPEEDS,
    format_table,
    repeatability_inputs,
    table4_kernel,
    uncertainty_terms,
)
from lidarcal.bench.ingest import ingest
from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.settings import Execution
from lidarcal.cf import height_coord, time_coord
from lidarcal.cli import main
from lidarcal.compliance import check_compliance
from lidarcal.data import sample_file
from lidarcal.errors import InputError, MissingVariableError, UnitError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.lidar import LidarModel, NoiseTable
from lidarcal.schema import validate_dataset
from lidarcal.units import Q_

# Table 4 of the paper, exactly as printed (U = 4, 6, ..., 16 m/s)
TABLE4 = {
    "bench_std_repeatability": ["0.041"] * 7,
    "bench_bias_repeatability": ["0.0026"] * 7,
    "bench_uncertainty": ["0.0018"] * 7,
    "beam_angle": ["0.0099", "0.0149", "0.0198", "0.0248", "0.0298", "0.0347", "0.0397"],
    "zero_distance": ["0.0036", "0.0054", "0.0072", "0.009", "0.0108", "0.0126", "0.0144"],
}
TOTAL_MS = ["0.0424", "0.0441", "0.0462", "0.0489", "0.0519", "0.0553", "0.0589"]
TOTAL_PCT = ["1.06", "0.74", "0.58", "0.49", "0.43", "0.40", "0.37"]


def to_printed(value, printed):
    """Round ``value`` half-up to as many decimals as the printed string has."""
    exp = Decimal(printed).as_tuple().exponent
    return Decimal(repr(float(value))).quantize(Decimal(1).scaleb(exp), rounding=ROUND_HALF_UP)


@pytest.fixture(scope="module")
def table4():
    # the one switch for the printed choices (dv_SAFO at k = 1, Eq. 11 without cos phi), Eq. 9's coefficient
    return uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS, beam_angle_coefficient=0.00248,
                             paper_table4=True)


def test_table4_rows_reproduced_to_printed_digits(table4):
    assert list(table4.contributor.values) == list(TABLE4)
    for name, row in TABLE4.items():
        values = table4.uncertainty.sel(contributor=name).values
        got = [to_printed(v, p) for v, p in zip(values, row, strict=True)]
        assert got == [Decimal(p) for p in row], name


def test_table4_totals_reproduced_to_printed_digits(table4):
    # The paper's totals are the quadrature sum of the rows *as printed* (Eq. 6 rounded to 0.041)
    # and its % row is that rounded total / U, rounded half-up: apply exactly that arithmetic to
    # lidarcal's rows and every printed total comes out.
    for j, u in enumerate(table4.wind_speed.values):
        rows = [to_printed(table4.uncertainty.sel(contributor=n).values[j], TABLE4[n][j]) for n in TABLE4]
        total = Decimal(sum(float(r) ** 2 for r in rows) ** 0.5)
        total = total.quantize(Decimal("0.0001"), rounding=ROUND_HALF_UP)
        assert total == Decimal(TOTAL_MS[j]), u
        pct = (total / Decimal(str(float(u))) * 100).quantize(Decimal("0.01"), rounding=ROUND_HALF_UP)
        assert pct == Decimal(TOTAL_PCT[j]), u
    # lidarcal's own total sums the unrounded terms: lower by at most 0.0003 m/s (documented)
    diff = np.array([float(t) for t in TOTAL_MS]) - table4.total.values
    assert np.all((diff > 0) & (diff < 0.0004)), diff
    pct_diff = np.array([float(t) for t in TOTAL_PCT]) - table4.total_relative.values
    assert np.all(np.abs(pct_diff) < 0.011), pct_diff  # 1.053 % vs printed 1.06 % at 4 m/s


def test_quadrature_total_and_relative_values(table4):
    np.testing.assert_allclose(table4.total, np.sqrt((table4.uncertainty**2).sum("contributor")), rtol=1e-14)
    np.testing.assert_allclose(table4.relative_uncertainty, 100 * table4.uncertainty / table4.wind_speed,
                               rtol=1e-14)
    assert table4.relative_uncertainty.attrs["units"] == "%" and table4.total.attrs["units"] == "m s-1"
    # analysts select a term by name and wind speed
    assert float(table4.uncertainty.sel(wind_speed=8, contributor="zero_distance")) == pytest.approx(0.0072)
    # exact Eq. 6: 0.027 / (sqrt(2) sin 28 deg) = 0.040667 m/s (printed 0.041)
    assert float(table4.uncertainty.sel(wind_speed=4, contributor="bench_std_repeatability")) == \
        pytest.approx(0.027 / (np.sqrt(2) * np.sin(np.radians(28))), rel=1e-12)


def test_eq9_formula_gives_0_00286_not_0_00248():
    ds = uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS)
    coeff = ds.uncertainty.sel(contributor="beam_angle") / ds.wind_speed
    expected = np.radians(0.087) / np.tan(np.radians(28))  # cot 28 deg x 0.087 deg in rad
    np.testing.assert_allclose(coeff, expected, rtol=1e-12)
    assert round(expected, 5) == 0.00286
    # the printed 0.00248 would need dphi = 0.0755 deg with phi = 28 deg
    assert np.degrees(0.00248 * np.tan(np.radians(28))) == pytest.approx(0.07555, abs=1e-5)
    assert ds.attrs["beam_angle_method"].startswith("cot") and "beam_angle_coefficient" not in ds


def test_which_n_in_eq7_and_coverage_factor_in_eq8():
    def term(name, **kw):
        ds = uncertainty_terms(Q_([8.0], "m/s"), **PAPER_INPUTS, **kw)
        return float(ds.uncertainty.sel(wind_speed=8.0, contributor=name)), ds.attrs

    # N = 150 LOS samples: 0.021 / (sqrt 2 sqrt 150 sin 28) = 0.00258 -> printed 0.0026
    printed, attrs = term("bench_bias_repeatability")
    assert printed == pytest.approx(0.0025826, abs=1e-7) and attrs["eq7_sample_count"] == 150
    # N = 4 runs, as the text says: 0.0158 m/s, six times the printed value
    runs, attrs = term("bench_bias_repeatability", bias_repeatability_n="runs")
    assert runs == pytest.approx(0.0158148, abs=1e-7) and attrs["eq7_sample_count"] == 4
    # 0.0145 used as printed gives 0.00178 (Table 4's 0.0018); removing k = 2 (the default) halves it
    assert term("bench_uncertainty", paper_table4=True)[0] == pytest.approx(0.0017832, abs=1e-7)
    assert term("bench_uncertainty")[0] == pytest.approx(0.0008916, abs=1e-7)
    assert term("bench_uncertainty", bench_coverage_factor=1.0)[0] == pytest.approx(0.0017832, abs=1e-7)


def test_default_terms_against_the_printed_ones_by_hand():
    """Default: dv_SAFO / 2 in Eq. 8 and the height error dz cos(28°) in Eq. 11; Table 4 prints neither.

    By hand, at 8 m/s, 100 m, alpha 0.2: Eq. 8 printed 0.0145 / (sqrt 2 sqrt 150 sin 28°) =
    0.0145 / 8.13157 = 0.0017832 m/s, default half of it 0.0008916; Eq. 11 printed
    0.2 x 8 x 0.45 / 100 = 0.0072 m/s, default x cos 28° = 0.88295 -> 0.0063572 m/s.
    """
    default = uncertainty_terms(Q_([8.0], "m/s"), **PAPER_INPUTS)
    printed = uncertainty_terms(Q_([8.0], "m/s"), **PAPER_INPUTS, paper_table4=True)

    def row(ds, name):
        return float(ds.uncertainty.sel(wind_speed=8.0, contributor=name))

    assert row(printed, "bench_uncertainty") == pytest.approx(0.0017832, abs=1e-7)
    assert row(default, "bench_uncertainty") == pytest.approx(0.0008916, abs=1e-7)
    assert row(printed, "zero_distance") == pytest.approx(0.0072, abs=1e-10)
    assert row(default, "zero_distance") == pytest.approx(0.0063572, abs=1e-7)
    # the other three rows do not depend on the switch
    for name in ("bench_std_repeatability", "bench_bias_repeatability", "beam_angle"):
        assert row(default, name) == row(printed, name)
    assert float(default.bench_coverage_factor) == 2.0 and float(printed.bench_coverage_factor) == 1.0
    assert float(default.zero_distance_projection) == pytest.approx(0.8829476, abs=1e-7)
    assert float(printed.zero_distance_projection) == 1.0
    assert json.loads(default.attrs["lidarcal_config"])["paper_table4"] is False


def test_kernel_scaling():
    base = dict(std_repeatability=0.027, bias_repeatability=0.021, n_bias=150, n_los_samples=150,
                bench_uncertainty=0.0145, beam_angle_uncertainty=np.radians(0.087),
                zero_distance_uncertainty=0.45, shear_exponent=0.2, height=100.0, cone_angle=np.radians(28))
    a = table4_kernel(np.array([10.0]), **base)
    b = table4_kernel(np.array([10.0]), **{**base, "height": 200.0, "shear_exponent": 0.4})
    assert a.shape == (1, len(CONTRIBUTORS))
    assert a[0, 4] == pytest.approx(0.2 * 10 * 0.45 / 100)  # Eq. 11 as printed: 0.009 m/s
    c = table4_kernel(np.array([10.0]), **base, zero_distance_projection=np.cos(np.radians(28)))
    assert c[0, 4] == pytest.approx(0.009 * 0.8829476, rel=1e-7)  # the height error dz cos(phi)
    assert b[0, 4] == pytest.approx(a[0, 4])  # alpha / z unchanged
    np.testing.assert_array_equal(a[0, :4], b[0, :4])


def test_terms_at_several_heights_stack_the_single_height_artefacts():
    heights, alphas = [60.0, 120.0, 200.0], [0.1, 0.15, 0.3]
    stacked = uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "height": Q_(heights, "m"),
                                                      "shear_exponent": alphas})
    assert validate_dataset(stacked) == []
    assert stacked.uncertainty.dims == ("wind_speed", "contributor", "height")
    assert stacked.n_runs.dims == ("height",) and stacked.n_runs.dtype == np.int32
    config = json.loads(stacked.attrs["lidarcal_config"])
    assert config["height"] == heights and config["shear_exponent"] == alphas
    for z, alpha in zip(heights, alphas, strict=True):
        one = uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "height": Q_(z, "m"),
                                                      "shear_exponent": alpha})
        at = stacked.sel(height=z)
        for name in ("uncertainty", "relative_uncertainty", "total", "total_relative", "shear_exponent"):
            np.testing.assert_array_equal(at[name].values, one[name].values)  # bit-identical
            assert at[name].attrs == one[name].attrs
    with pytest.raises(InputError, match="one exponent or one per height"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "height": Q_(heights, "m"),
                                                 "shear_exponent": [0.1, 0.2]})
    with pytest.raises(InputError, match="distinct heights"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "height": Q_([80.0, 80.0], "m")})


def test_units_and_bad_values_refused():
    with pytest.raises(UnitError, match="argument 'height'"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "height": 100.0})
    with pytest.raises(UnitError, match="argument 'bench_uncertainty'.*'m'"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "bench_uncertainty": Q_(1, "m")})
    with pytest.raises(UnitError, match="argument 'wind_speed'"):
        uncertainty_terms([4.0, 8.0], **PAPER_INPUTS)
    with pytest.raises(InputError, match="argument 'zero_distance_uncertainty'.*found -0.1 m"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "zero_distance_uncertainty": Q_(-0.1, "m")})
    with pytest.raises(InputError, match="argument 'n_runs'.*found 0"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "n_runs": 0})
    with pytest.raises(InputError, match="argument 'cone_angle'.*found 95"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **{**PAPER_INPUTS, "cone_angle": Q_(95, "degree")})
    with pytest.raises(InputError, match="argument 'wind_speed'.*positive"):
        uncertainty_terms(Q_([0.0, 4.0], "m/s"), **PAPER_INPUTS)
    # convertible units are converted: 14.4 km/h = 4 m/s, 1.566 mrad ~ 0.0897 deg
    kmh = uncertainty_terms(Q_([14.4], "km/h"), **PAPER_INPUTS)
    ms = uncertainty_terms(Q_([4.0], "m/s"), **PAPER_INPUTS)
    np.testing.assert_allclose(kmh.uncertainty.values, ms.uncertainty.values, rtol=1e-12)


def make_repeatability(path, s_bias=0.03, s_std=0.05, n_runs=3, drop=None):
    ds = xr.Dataset({
        "mean_between_run_std_bias": ((), s_bias, var_attrs("s-bar_delta", "m s-1")),
        "mean_between_run_std_std": ((), s_std * 100, var_attrs("s-bar_s", "cm s-1")),  # converted on read
        "n_runs": ((), np.int32(n_runs), var_attrs("runs", "1")),
    }, attrs={"lidarcal_artefact": "repeatability", "history": "[2025-03-10T00:00:00Z] bench"})
    if drop:
        ds = ds.drop_vars(drop)
    ds.to_netcdf(path)
    return path


def test_repeatability_inputs_are_read_and_converted(tmp_path):
    path = make_repeatability(tmp_path / "rep.nc")
    kwargs, ds = repeatability_inputs(path)
    assert kwargs["mean_between_run_std_std"].to("m/s").magnitude == pytest.approx(0.05)
    assert kwargs["mean_between_run_std_bias"].magnitude == pytest.approx(0.03) and kwargs["n_runs"] == 3
    bad = make_repeatability(tmp_path / "bad.nc", drop="n_runs")
    with pytest.raises(MissingVariableError, match=r"bad.nc: required variable 'n_runs' is missing"):
        repeatability_inputs(bad)


def test_cli_terms_with_repeatability(tmp_path, capsys):
    rep = make_repeatability(tmp_path / "rep.nc")
    out = tmp_path / "terms.nc"
    argv = ["terms", "--repeatability", str(rep), "--n-runs", "5", "--height", "120", "--eq7-n", "runs",
            "--wind-speed", "5", "10", "-o", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "Total (m/s)" in printed and "z = 120 m" in printed
    ds = open_artefact(out, "uncertainty_terms")
    assert float(ds.mean_between_run_std_std) == pytest.approx(0.05)  # from the file (given in cm s-1)
    assert int(ds.n_runs) == 5  # explicit option overrides the file's 3
    # Eq. 7 with N = 5 runs: 0.03 / (sqrt 2 sqrt 5 sin 28)
    expected = 0.03 / (np.sqrt(2) * np.sqrt(5) * np.sin(np.radians(28)))
    got = ds.uncertainty.sel(contributor="bench_bias_repeatability")
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    assert float(ds.height) == 120.0 and ds.height.attrs["standard_name"] == "height"
    inputs = json.loads(ds.attrs["lidarcal_inputs"])
    assert inputs[0]["role"] == "repeatability" and inputs[0]["file"] == "rep.nc"
    assert ds.attrs["history"].startswith("[2025-03-10T00:00:00Z] bench")
    assert validate_dataset(ds, "uncertainty_terms") == []
    report = check_compliance(out)
    assert report.passed, report.failures
    assert main(argv) == 2  # no silent overwrite


def test_cli_bad_repeatability_writes_nothing(tmp_path, capsys):
    rep = make_repeatability(tmp_path / "rep.nc", drop="mean_between_run_std_bias")
    out = tmp_path / "terms.nc"
    assert main(["terms", "--repeatability", str(rep), "-o", str(out)]) == 2
    assert "rep.nc: required variable 'mean_between_run_std_bias' is missing" in capsys.readouterr().err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["rep.nc"]


def test_table_text_and_roundtrip(tmp_path, table4):
    text = format_table(table4)
    assert "0.0248" in text and "1.05%" in text  # exact-sum total at 4 m/s (printed table: 1.06 %)
    path = write_artefact(table4, tmp_path / "t4.nc")
    back = open_artefact(path, "uncertainty_terms")
    xr.testing.assert_allclose(back.uncertainty, table4.uncertainty)
    assert list(back.contributor.values) == list(CONTRIBUTORS)
    assert float(back.beam_angle_coefficient) == 0.00248


# -- Eqs. 6-7: printed vs derived -----------------------------------------------------------------
# Paper inputs: s_s = 0.027 m/s, s_delta = 0.021 m/s, phi = 28 deg, N = 150 LOS samples per
# 10 minutes.  sqrt(2) sin 28 deg = 1.4142136 x 0.4694716 = 0.6639364.
SIN = 0.4694716
DENOM = 1.4142136 * SIN
PRINTED_EQ6 = 0.027 / DENOM  # 0.04067 (Table 4: 0.041)
PRINTED_EQ7 = 0.021 / (DENOM * np.sqrt(150))  # 0.00258 (Table 4: 0.0026)
DERIVED_EQ6_NOISE = 0.027 / (DENOM * np.sqrt(150))  # 0.00332: the mean of N samples per beam
DERIVED_EQ7 = 0.021 / DENOM  # 0.03163: a bin's bias error does not average away


def test_derived_noise_terms_hand_computed():
    ds = uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS, noise_terms="derived")
    u = TABLE4_WIND_SPEEDS.magnitude
    # noise bias of the scalar average, p sigma s_s / (2 sin^2 phi U), sigma = 0.1 m/s, p = 2/3:
    # 0.0018 / (0.4408 U) = 0.00102 m/s at 4 m/s; in quadrature with the sqrt(N) part
    bias_part = (2 / 3) * 0.1 * 0.027 / (2 * SIN**2 * u)
    np.testing.assert_allclose(ds.uncertainty.sel(contributor="bench_std_repeatability"),
                               np.sqrt(DERIVED_EQ6_NOISE**2 + bias_part**2), rtol=1e-6)
    np.testing.assert_allclose(ds.uncertainty.sel(contributor="bench_bias_repeatability"), DERIVED_EQ7,
                               rtol=1e-6)
    assert round(float(ds.uncertainty.sel(wind_speed=4, contributor="bench_std_repeatability")), 4) == 0.0035
    assert round(float(ds.uncertainty.sel(wind_speed=16, contributor="bench_std_repeatability")), 4) == 0.0033
    assert round(DERIVED_EQ7, 3) == 0.032
    assert ds.attrs["noise_terms"] == "derived" and float(ds.los_noise_std) == 0.1
    # the default stays the printed forms (Table 4 reproduced, see the tests above)
    printed = uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS)
    assert printed.attrs["noise_terms"] == "printed" and "los_noise_std" not in printed
    np.testing.assert_allclose(printed.uncertainty.sel(contributor="bench_std_repeatability"), PRINTED_EQ6,
                               rtol=1e-6)
    np.testing.assert_allclose(printed.uncertainty.sel(contributor="bench_bias_repeatability"), PRINTED_EQ7,
                               rtol=1e-6)
    assert NOISE_TERMS == ("printed", "derived")
    with pytest.raises(InputError, match="noise_terms"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS, noise_terms="both")
    with pytest.raises(InputError, match="only apply with noise_terms='derived'"):
        uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS, los_noise_std=Q_(0.2, "m/s"))


def test_cli_terms_noise_terms_derived(tmp_path, capsys):
    out = tmp_path / "t.nc"
    assert main(["terms", "--noise-terms", "derived", "--los-noise-std", "0.2", "-o", str(out)]) == 0
    ds = open_artefact(out, "uncertainty_terms")
    assert ds.attrs["noise_terms"] == "derived" and float(ds.los_noise_std) == 0.2
    np.testing.assert_allclose(ds.uncertainty.sel(contributor="bench_bias_repeatability"), DERIVED_EQ7,
                               rtol=1e-6)
    assert "0.0316" in capsys.readouterr().out


def _tiny_dbs_speed(samples, p=2 / 3):
    """Hybrid 10-minute speed from (period, 4 beams at 0/90/180/270 deg, N) radial samples."""
    phi = np.radians(28.0)
    u = (samples[:, 0] - samples[:, 2]) / (2 * np.sin(phi))
    v = (samples[:, 1] - samples[:, 3]) / (2 * np.sin(phi))
    return p * np.hypot(u, v).mean(-1) + (1 - p) * np.hypot(u.mean(-1), v.mean(-1))


def test_tiny_independent_simulation_decides_where_sqrt_n_belongs():
    # Written here, independent of lidarcal: 4000 periods of 150 samples per beam of a steady
    # 8 m/s wind from a random direction, Gaussian LOS noise (sigma 0.1 m/s) plus each beam's
    # bin bias.  A rerun of the bench changes each bin's sigma by N(0, s_s) and its bias by
    # N(0, s_delta); a period samples one bin per beam.  The same noise draws are reused, so
    # the change of the 10-minute speed is due to the perturbation alone.
    rng = np.random.default_rng(0)
    m, n, phi = 4000, 150, np.radians(28.0)
    az = np.radians([0.0, 90.0, 180.0, 270.0])
    radial = 8.0 * np.sin(phi) * np.cos(rng.uniform(0, 2 * np.pi, m)[:, None] - az[None, :])
    z = rng.standard_normal((m, 4, n))
    mu = rng.normal(0.0, 0.02, (m, 4))[..., None]
    base = _tiny_dbs_speed(radial[..., None] + mu + 0.1 * z)
    d_sigma = rng.normal(0.0, 0.027, (m, 4))[..., None]
    d_mu = rng.normal(0.0, 0.021, (m, 4))[..., None]
    sigma_run = _tiny_dbs_speed(radial[..., None] + mu + (0.1 + d_sigma) * z)
    mu_run = _tiny_dbs_speed(radial[..., None] + mu + d_mu + 0.1 * z)
    moved_sigma = np.sqrt(np.mean((sigma_run - base) ** 2))
    moved_mu = np.sqrt(np.mean((mu_run - base) ** 2))
    # sampling error of an RMS over 4000 periods: ~1/sqrt(2 x 4000) = 1.1 %; allow 5 %
    assert moved_sigma == pytest.approx(DERIVED_EQ6_NOISE, rel=0.05)  # 0.0033, not 0.041
    assert moved_mu == pytest.approx(DERIVED_EQ7, rel=0.05)  # 0.032, not 0.0026
    assert moved_sigma < PRINTED_EQ6 / 10 and moved_mu > 10 * PRINTED_EQ7


def _steady_conditions(n, seed=0, cnr=-15.0):
    rng = np.random.default_rng(np.random.SeedSequence([seed, 5]))
    shape = (n, 1)
    data = {"wind_speed": ("m s-1", rng.uniform(4.0, 16.0, shape)),
            "wind_from_direction": ("degree", rng.uniform(0.0, 360.0, shape)),
            "turbulence_intensity": ("1", np.full(shape, 0.1)),
            "wind_shear_exponent": ("1", np.full(shape, 0.2)),
            "cnr": ("dB", np.full(shape, cnr)), "cnr_gradient": ("dB m-1", np.zeros(shape))}
    return xr.Dataset(
        {k: (("time", "height"), v, var_attrs(k.replace("_", " "), u)) for k, (u, v) in data.items()},
        coords={"time": time_coord(np.datetime64("2024-01-01") + np.arange(n) * np.timedelta64(600, "s")),
                "height": height_coord([100.0])},
    )


def _perturbed(model, seed, d_std=0.0, d_bias=0.0):
    """The model with every (beam, CNR, velocity) bin's std and bias moved by N(0, d_std), N(0, d_bias)."""
    t = model.noise_table
    rng = np.random.default_rng(seed)
    bias, std = np.asarray(t.bias), np.asarray(t.std)
    return model.replace(noise_table=NoiseTable(
        t.cnr, t.velocity, bias + d_bias * rng.standard_normal(bias.shape),
        np.abs(std + d_std * rng.standard_normal(std.shape))))


def _virtual_lidar_moves(n_periods, draws):
    cube = ingest(sample_file("bench/rtd.csv.gz"), sample_file("bench/control_log.csv"))
    # Eqs. 6-7 are about the Gaussian table's sigma and mu, which resampled residuals do not use
    model = LidarModel.from_artefacts(cube=cube, los_noise_model="gaussian")
    cond = _steady_conditions(n_periods)
    one_process = Execution(scheduler="synchronous")
    run = lambda m: simulate_campaign(cond, m, execution=one_process).lidar_wind_speed.values[:, 0]  # noqa: E731
    base = run(model)
    rms = lambda a: float(np.sqrt(np.nanmean((a - base) ** 2)))  # noqa: E731
    sigma = [rms(run(_perturbed(model, s, d_std=0.027))) for s in draws]
    mu = [rms(run(_perturbed(model, s, d_bias=0.021))) for s in draws]
    return sigma, mu


def _check_virtual_lidar(sigma, mu):
    # The virtual lidar interpolates the cube bilinearly in CNR and radial velocity, so a
    # period at -15 dB averages two CNR bins' independent errors (1/sqrt 2) and its turbulent
    # radial velocities spread over a few velocity bins: the moves are below the one-bin
    # values of the derived forms (measured 0.5-0.65 x for sigma, 0.3-0.6 x for mu with 1000
    # periods and 4 draws), and far from the printed forms on the other side.
    for s in sigma:
        assert 0.25 * DERIVED_EQ6_NOISE < s < 1.2 * DERIVED_EQ6_NOISE  # ~0.002 m/s
        assert s < PRINTED_EQ6 / 10  # the printed Eq. 6 (0.041) overstates it > 10 x
    for m in mu:
        assert 0.15 * DERIVED_EQ7 < m < 1.2 * DERIVED_EQ7  # ~0.01-0.02 m/s
        assert m > 3 * PRINTED_EQ7  # the printed Eq. 7 (0.0026) understates it > 3 x


def test_virtual_lidar_monte_carlo_decides_where_sqrt_n_belongs():
    # the sample bench cube, 200 periods at 100 m, one perturbation draw each (~10 s)
    _check_virtual_lidar(*_virtual_lidar_moves(200, draws=(1,)))


@pytest.mark.slow
def test_virtual_lidar_monte_carlo_decides_where_sqrt_n_belongs_large():
    _check_virtual_lidar(*_virtual_lidar_moves(1000, draws=(1, 2, 3, 4)))
