"""``lidarcal smc``: the 50-2 route and the calibration contributor against hand computations, bad input.

The certificate is a small one made in seconds (:mod:`smc_factories`); the expected values are
computed here from the numbers stored in its file (read with netCDF4) and the campaign's own
values, with numpy only.  The Monte Carlo route's statistical checks are slow tests
(``test_smc_montecarlo.py``).
"""

import json
import math
import shutil

import netCDF4
import numpy as np
import pytest
from smc_factories import HEIGHTS, SERIAL, campaign_values, conditions_file, small_certificate
from test_sta import ends, make_values, write_newer, write_older

import lidarcal
from lidarcal.certificate.signing import generate_keypair
from lidarcal.cli import main
from lidarcal.data import sample_file
from lidarcal.errors import InputError
from lidarcal.smc import binned, binned_table, smc, smc_dataset
from lidarcal.smc.kernels import group_of, within_bin_fit

COVERAGE = [
    "covered",
    "no_wind_speed",
    "height_not_certified",
    "outside_certified_range",
    "bin_not_certified",
    "environmental_term_missing",
]


@pytest.fixture(scope="session")
def cert(tmp_path_factory):
    return small_certificate(tmp_path_factory.mktemp("smc-cert"))


def stored(path, name):
    """A variable of the certificate as stored (netCDF4, no lidarcal), in the file's dimension order."""
    with netCDF4.Dataset(path) as nc:
        var = nc.variables[name]
        return np.asarray(var[:].filled(np.nan) if np.ma.isMaskedArray(var[:]) else var[:]), var.dimensions


def flag_value(path, name, meaning):
    with netCDF4.Dataset(path) as nc:
        var = nc.variables[name]
        return dict(zip(var.flag_meanings.split(), np.atleast_1d(var.flag_values).tolist(), strict=True))[
            meaning
        ]


def run_smc(tmp_path, cert, *args, out="smc.nc"):
    code = main(["smc", str(cert), *map(str, args), "-o", str(tmp_path / out), "--no-progress"])
    return code, tmp_path / out


def test_iec_route_and_calibration_against_hand_computation(tmp_path, cert):
    heights = (60.0, *HEIGHTS)  # 60 m is not certified
    v = campaign_values(60, heights)
    path = conditions_file(tmp_path / "c.nc", v, heights)
    code, out = run_smc(tmp_path, cert, "--conditions", path, "--no-monte-carlo")
    assert code == 0
    ds = lidarcal.open_artefact(out)
    # --- by hand, from the certificate's stored numbers ---
    rel, dims = stored(cert, "budget_relative_uncertainty")
    rel = rel if dims == ("budget_wind_speed", "budget_height") else rel.T  # (bin, height)
    flag, _ = stored(cert, "budget_bin_flag")
    flag = flag if dims == ("budget_wind_speed", "budget_height") else flag.T
    centres, _ = stored(cert, "budget_wind_speed")
    certified = flag_value(cert, "budget_bin_flag", "certified")
    u = v["wind_speed"]
    expected_cal = np.full(u.shape, np.nan)
    expected_env = np.zeros(u.shape)
    expected_dev = np.zeros(u.shape)
    for j, z in enumerate(heights):
        if z not in HEIGHTS:
            continue
        i = HEIGHTS.index(z)
        for t in range(u.shape[0]):
            b = int(np.argmin(np.abs(centres - u[t, j])))  # 0.5 m/s bins centred on the centres
            if abs(centres[b] - u[t, j]) <= 0.25 and flag[b, i] == certified:
                expected_cal[t, j] = rel[b, i] * u[t, j] / 100.0
        squares = 0.0
        for var in ("turbulence_intensity", "wind_shear_exponent", "cnr_gradient"):
            sig, _ = stored(cert, f"sensitivity_{var}_significant")
            if not sig[i]:
                continue
            slope, _ = stored(cert, f"sensitivity_{var}_slope")
            n, ndims = stored(cert, f"sensitivity_{var}_sample_count")
            xm, _ = stored(cert, f"sensitivity_{var}_variable_mean")
            used, _ = stored(cert, f"sensitivity_{var}_bin_flag")
            if ndims[0].endswith("height"):
                n, xm, used = n.T, xm.T, used.T
            keep = used[:, i] == flag_value(cert, f"sensitivity_{var}_bin_flag", "used")
            mean = (n[keep, i] * xm[keep, i]).sum() / n[keep, i].sum()
            dev = slope[i] / 100.0 * (v[var][:, j] - mean) * u[:, j]
            squares = squares + dev**2
            expected_dev[:, j] += dev
        expected_env[:, j] = np.sqrt(squares)
    got = ds.contribution.sel(contributor="calibration").transpose("time", "height").values
    np.testing.assert_allclose(got, expected_cal, rtol=1e-12, equal_nan=True)
    env = ds.contribution.sel(contributor="environmental_iec").transpose("time", "height").values
    cols = [1, 2]  # the certified heights
    np.testing.assert_allclose(env[:, cols], expected_env[:, cols], rtol=1e-12)
    np.testing.assert_allclose(
        ds.environmental_deviation_iec.values[:, cols], expected_dev[:, cols], rtol=1e-12
    )
    # at least one slope was applied at each certified height, so the route is not trivially zero
    assert (expected_env[:, cols] > 1e-4).any(axis=0).all()
    total = ds.uncertainty.transpose("time", "height").values
    np.testing.assert_allclose(total[:, cols], np.hypot(expected_cal, expected_env)[:, cols], rtol=1e-12)
    assert ds.uncertainty.attrs["units"] == "m s-1" and ds.relative_uncertainty.attrs["units"] == "%"
    np.testing.assert_allclose(ds.relative_uncertainty.values, 100 * total / u, rtol=1e-12)
    # coverage: 60 m not certified, every other period covered or outside/uncertified, never a made-up number
    flags = ds.coverage_flag.transpose("time", "height").values
    assert (flags[:, 0] == COVERAGE.index("height_not_certified")).all()
    assert np.isnan(total[flags != 0]).all() and np.isfinite(total[flags == 0]).all()
    assert ds.attrs["environmental_route"] == "iec" and json.loads(ds.attrs["heights_not_covered_m"]) == [
        60.0
    ]
    assert ds.combined.sel(contributor="environmental_monte_carlo").item() == 0
    # a certificate whose budget has no model_form contributor: said, with its measurand
    assert ds.attrs["certificate_model_form"].startswith("not stated")
    assert "fully correlated" in ds.attrs["certificate_measurand"]


def test_only_bins_whose_flag_means_certified_count(tmp_path):
    """A flag meaning added later (here not_settled, value 4) and meanings listed in another order."""

    def edit(bud):
        bud = bud.copy()
        assert int(bud["bin_flag"].max()) <= 2  # no bin outside the certified range: value 3 is free
        flag = bud["bin_flag"].where(~((bud["wind_speed"] == 8.0) & (bud["bin_flag"] == 0)), 3)  # not settled
        # renumber: certified becomes 2, empty 0 (the meanings say which is which)
        renumber = {0: 2, 2: 0, 1: 1, 3: 3}
        bud["bin_flag"] = flag.copy(data=np.vectorize(renumber.get)(flag.values).astype(np.int8))
        bud["bin_flag"].attrs.update(
            flag_values=np.array([0, 1, 2, 3], dtype=np.int8),
            flag_meanings="empty too_few_periods certified not_settled",
        )
        return bud

    cert = small_certificate(tmp_path / "c", flags=edit)
    speeds = np.array([[8.0, 8.1], [9.0, 9.1], [8.1, 3.0]])
    v = {**{k: a[:3] for k, a in campaign_values(3, HEIGHTS).items()}, "wind_speed": speeds}
    c = smc(cert, conditions=conditions_file(tmp_path / "c.nc", v, HEIGHTS), monte_carlo=False)
    ds = smc_dataset(c)
    assert ds.coverage_flag.transpose("time", "height").values.tolist() == [[4, 4], [0, 0], [4, 3]]
    cal = ds.contribution.sel(contributor="calibration").transpose("time", "height").values
    assert np.isnan(cal[[0, 0, 2], [0, 1, 0]]).all() and np.isfinite(cal[1]).all()


def test_sample_firmware2_sta_takes_the_certificate_cone_angle(tmp_path, cert):
    code, out = run_smc(tmp_path, cert, sample_file("sta/example_firmware2.sta"), "--no-monte-carlo")
    assert code == 0
    ds = lidarcal.open_artefact(out)
    assert ds.attrs["lidar_cone_angle"] == 28.0
    assert (
        "certificate" in ds.attrs["lidar_cone_angle_source"] and "NA" in ds.attrs["lidar_cone_angle_source"]
    )
    assert ds.attrs["lidar_serial"] == SERIAL and ds.sizes["height"] == 9
    sha = json.loads(ds.attrs["lidarcal_inputs"])
    roles = {r["role"]: r for r in sha}
    assert {"certificate", "sta_1"} <= set(roles) and len(roles["sta_1"]["sha256"]) == 64
    # the analyst's view: per bin, with a wind_speed dimension
    b = binned(lidarcal.open_artefact(out))
    one = b.sel(height=120, wind_speed=8, method="nearest")
    assert one.uncertainty.attrs["units"] == "m s-1" and math.isfinite(float(one.uncertainty))
    assert set(b.contribution.dims) == {"wind_speed", "contributor", "height"}


def test_demonstration_is_said_everywhere(tmp_path, cert, capsys):
    code, out = run_smc(tmp_path, cert, sample_file("sta/example_firmware2.sta"), "--no-monte-carlo")
    assert code == 0
    assert "DEMONSTRATION" in capsys.readouterr().out
    ds = lidarcal.open_artefact(out)
    assert ds.attrs["calibration_status"] == "demonstration"
    assert "DEMONSTRATION" in ds.attrs["title"] and ds.attrs["summary"].startswith("DEMONSTRATION")
    assert main(["table", str(out), "--format", "md"]) == 0
    assert "DEMONSTRATION" in capsys.readouterr().out.splitlines()[0]
    table = binned_table(out)
    assert table.attrs["demonstration"] and {"height_m", "wind_speed_m_s", "uncertainty_m_s"} <= set(
        table.columns
    )


def test_user_terms(tmp_path, cert):
    terms = tmp_path / "terms.yaml"
    terms.write_text(
        "terms:\n"
        "  - {name: flow_inhomogeneity, value: 0.6, unit: '%', distribution: rectangular,\n"
        "     source: 'CFD study, report 12'}\n"
        "  - {name: mounting, value: 0.02, unit: m s-1, distribution: normal, source: tripod}\n"
    )
    v = campaign_values(20, HEIGHTS)
    code, out = run_smc(
        tmp_path,
        cert,
        "--conditions",
        conditions_file(tmp_path / "c.nc", v, HEIGHTS),
        "--no-monte-carlo",
        "--user-terms",
        terms,
    )
    assert code == 0
    ds = lidarcal.open_artefact(out)
    flow = ds.contribution.sel(contributor="flow_inhomogeneity").transpose("time", "height").values
    np.testing.assert_allclose(flow, 0.006 * v["wind_speed"] / math.sqrt(3), rtol=1e-12)  # GUM 4.3.7
    np.testing.assert_allclose(ds.contribution.sel(contributor="mounting").values, 0.02)
    parts = ds.contribution.transpose("contributor", "time", "height").values
    combined = ds.combined.values.astype(bool)
    ok = ds.coverage_flag.values == 0
    np.testing.assert_allclose(
        ds.uncertainty.values[ok], np.sqrt((parts[combined] ** 2).sum(axis=0))[ok], rtol=1e-12
    )
    assert json.loads(ds.attrs["user_terms"])[0]["source"] == "CFD study, report 12"


@pytest.mark.parametrize(
    "text, words",
    [
        (
            "terms: [{name: calibration, value: 1, unit: '%', distribution: normal, source: x}]",
            ["name", "built-in"],
        ),
        ("terms: [{name: a, value: -1, unit: '%', distribution: normal, source: x}]", ["value", "-1"]),
        ("terms: [{name: a, value: 1, unit: degree, distribution: normal, source: x}]", ["unit", "degree"]),
        (
            "terms: [{name: a, value: 1, unit: '%', distribution: gamma, source: x}]",
            ["distribution", "gamma"],
        ),
        ("terms: [{name: a, value: 1, unit: '%', distribution: normal}]", ["source", "missing"]),
    ],
)
def test_bad_user_terms(tmp_path, cert, capsys, text, words):
    terms = tmp_path / "terms.yaml"
    terms.write_text(text)
    code, out = run_smc(
        tmp_path, cert, sample_file("sta/example_firmware2.sta"), "--no-monte-carlo", "--user-terms", terms
    )
    err = capsys.readouterr().err
    assert code == 2 and "terms.yaml" in err and all(w in err for w in words) and not out.exists()


def _sta(tmp_path, name="c.sta", *, n=6, serial=SERIAL, z=(60.0, 80.0, 100.0, 120.0), dialect="newer"):
    v = make_values(n, z, seed=4)
    writer = write_newer if dialect == "newer" else write_older
    return writer(tmp_path / name, ends(n), np.asarray(z), v, serial=serial)


def _edit(path, old: bytes, new: bytes):
    raw = path.read_bytes()
    assert old in raw
    path.write_bytes(raw.replace(old, new))
    return path


@pytest.mark.parametrize(
    "case, words",
    [
        ("other_unit", ["ID System=WLS7-164", "WLS866-0195", "another unit"]),
        ("cone_angle", ["ScanAngle", "30", "28", "certificate"]),
        ("heights", ["height", "50", "70", "certified"]),
        ("one_period", ["time", "at least 2", "found 1"]),
        ("empty", ["no data rows"]),
        ("km_h", ["Wind Speed (km/h)", "m/s", "km/h"]),
    ],
)
def test_bad_campaign_files(tmp_path, cert, capsys, case, words):
    if case == "other_unit":
        path = _sta(tmp_path, serial="WLS7-164", dialect="older")
    elif case == "cone_angle":
        path = _edit(_sta(tmp_path), b"ScanAngle (\xb0)=28.000", b"ScanAngle (\xb0)=30.000")
    elif case == "heights":
        path = _sta(tmp_path, z=(50.0, 70.0))
    elif case == "one_period":
        path = _sta(tmp_path, n=1)
    elif case == "empty":
        path = _sta(tmp_path)
        lines = path.read_bytes().split(b"\n")
        path.write_bytes(b"\n".join(lines[:12]) + b"\n")  # header and column names only
    else:
        path = _edit(_sta(tmp_path), b"80m Wind Speed (m/s)", b"80m Wind Speed (km/h)")
    code, out = run_smc(tmp_path, cert, path, "--no-monte-carlo")
    err = capsys.readouterr().err
    assert code == 2, err
    assert str(path.name) in err and all(w in err for w in words), err
    assert not out.exists() and not list(tmp_path.glob(".*.part"))


def test_tampered_unsigned_and_unsealed_certificates_are_refused(tmp_path, cert, capsys):
    sta = sample_file("sta/example_firmware2.sta")
    tampered = shutil.copy(cert, tmp_path / "tampered.nc")
    with netCDF4.Dataset(tampered, "a") as nc:
        nc.variables["budget_relative_uncertainty"][0, 0] = 0.01
    code, out = run_smc(tmp_path, tampered, sta, "--no-monte-carlo")
    err = capsys.readouterr().err
    assert code == 2 and "tampered.nc" in err and "seal" in err and not out.exists()
    key = tmp_path / "key"
    generate_keypair(key)
    code, out = run_smc(tmp_path, cert, sta, "--no-monte-carlo", "--public-key", f"{key}.pub")
    err = capsys.readouterr().err
    assert code == 2 and "sign" in err and not out.exists()
    # a sealed and signed certificate passes with its key
    signed = small_certificate(tmp_path / "signed", signing_key=key)
    code, out = run_smc(tmp_path, signed, sta, "--no-monte-carlo", "--public-key", f"{key}.pub")
    assert code == 0 and lidarcal.open_artefact(out).attrs["certificate_seal"] == "signed and sealed"


def test_what_an_old_certificate_cannot_give_is_named(tmp_path, capsys):
    old = small_certificate(tmp_path / "old", with_model=False)  # no cube, no RWF, no lidar model
    sta = sample_file("sta/example_firmware2.sta")
    code, out = run_smc(tmp_path, old, sta)
    err = capsys.readouterr().err
    # the Monte Carlo route is named as not computed, with what the certificate lacks; 50-2 quoted
    assert code == 0 and "lidarcal_lidar_model" in err and "Monte Carlo route" in err
    ds = lidarcal.open_artefact(out)
    assert (
        ds.attrs["environmental_route"] == "iec" and "lidarcal_lidar_model" in ds.attrs["monte_carlo_route"]
    )
    assert np.isnan(ds.contribution.sel(contributor="environmental_monte_carlo")).all()
    assert (ds.coverage_flag == 0).sum() > 0 and np.isfinite(
        ds.uncertainty.where(ds.coverage_flag == 0)
    ).any()
    # the cone angle is the Table 4 terms' (the certificate says so)
    assert "Table 4 terms" in ds.attrs["lidar_cone_angle_source"]
    # without the Monte Carlo route and without sensitivities nothing can be quoted: refused
    bare = small_certificate(tmp_path / "bare", with_model=False, sensitivities=False)
    code, out = run_smc(tmp_path, bare, sta, out="bare.nc")
    err = capsys.readouterr().err
    assert code == 2 and "neither environmental route" in err and "sensitivity" in err and not out.exists()


def test_conditions_file_needs_unit_and_cone_angle(tmp_path, cert, capsys):
    v = campaign_values(10, HEIGHTS)
    for kwargs, words in (
        ({"serial": "WLS7-9982"}, ["lidar_serial", "WLS7-9982", SERIAL]),
        ({"cone_angle": None}, ["lidar_cone_angle", "missing"]),
        ({"cone_angle": 30.0}, ["lidar_cone_angle", "30", "28"]),
    ):
        path = conditions_file(tmp_path / "c.nc", v, HEIGHTS, **kwargs)
        code, out = run_smc(tmp_path, cert, "--conditions", path, "--no-monte-carlo")
        err = capsys.readouterr().err
        assert code == 2 and "c.nc" in err and all(w in err for w in words), err
        path.unlink()


def test_monte_carlo_route_runs_on_a_tiny_campaign(tmp_path, cert):
    v = campaign_values(6, HEIGHTS[1:])
    c = smc(
        cert,
        conditions=conditions_file(tmp_path / "c.nc", v, HEIGHTS[1:]),
        max_replicas=2,
        execution={"scheduler": "synchronous"},
    )
    mc = c.monte_carlo
    assert mc.replicas == 2 and mc.records.sizes["time"] == 6
    # every period was simulated; the not-settled bins' periods got their second replica
    ds = smc_dataset(c)
    trials = ds.monte_carlo_trials.transpose("time", "height").values
    assert (trials[:, 0] >= 1).all() and (trials[:, 0] <= 2).all()
    assert np.isfinite(ds.monte_carlo_expected_deviation.values).sum() >= 1


def test_within_bin_fit_recovers_known_slopes():
    rng = np.random.default_rng(np.random.SeedSequence([3, 1]))
    n = 4000
    bins = rng.integers(0, 5, n)
    x = rng.normal(size=(n, 2))
    d = np.array([0.1, -0.2, 0.3, 0.0, 0.5])[bins] + 0.04 * x[:, 0] - 0.02 * x[:, 1] + rng.normal(0, 0.01, n)
    count, mean_d, mean_x, beta = within_bin_fit(d, x, bins, 5)
    # least squares with 4000 rows and residual 0.01: slope standard error 0.01/sqrt(4000) = 1.6e-4
    np.testing.assert_allclose(beta, [0.04, -0.02], atol=8e-4)
    assert count.sum() == n
    keys = np.arange(0, 600 * 8, 600)
    assert np.bincount(group_of(keys, np.zeros(8, int))).tolist() == [2, 2, 2, 2]


def test_smc_refuses_both_or_neither_input(tmp_path, cert):
    with pytest.raises(InputError, match="one of the two"):
        smc(cert, monte_carlo=False)
    path = conditions_file(tmp_path / "c.nc", campaign_values(4, HEIGHTS), HEIGHTS)
    with pytest.raises(InputError, match="one of the two"):
        smc(cert, [sample_file("sta/example_firmware2.sta")], conditions=path, monte_carlo=False)


def test_report_without_the_monte_carlo_route(tmp_path, cert):
    code, out = run_smc(
        tmp_path,
        cert,
        sample_file("sta/example_firmware2.sta"),
        "--no-monte-carlo",
        "--report",
        tmp_path / "smc.html",
    )
    assert code == 0
    page = (tmp_path / "smc.html").read_text(encoding="utf-8")
    assert page.count("data:image/png;base64,") == 3 and "DEMONSTRATION result" in page
    assert "<th>Quoted route</th><td>iec (Monte Carlo route: not run" in page
    assert "<th>What u is</th>" in page and "must not divide them by the square root" in page
    pdf = (tmp_path / "smc.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and len(pdf) > 20_000  # a text page and three figures (pages: slow test)
