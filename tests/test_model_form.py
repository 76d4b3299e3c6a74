"""The simulation's model-form term (issue 24 §3): alternatives, common random numbers, the contributor.

Independent references: the alternatives' cross-spectra against a brute-force double sum written
here (IEC Ed. 2 coherence and Kaimal length scale, as ``tests/test_lidar_spectral.py`` does for
Ed. 3); the Gaussian-RWF alternative against the ideal lidar; the contributor against a hand
computation; its delta-method standard error against the scatter of repeated subsamples.
"""

import json
import subprocess

import numpy as np
import pytest
import xarray as xr
from analysis_factories import make_records

from lidarcal.analysis.budget import budget
from lidarcal.analysis.model_form import model_form_term
from lidarcal.analysis.rule import CertificationRule
from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.adaptive import with_trials
from lidarcal.campaign.model_form import model_form_runs, select_periods, with_model_form
from lidarcal.campaign.run import simulate_replicas
from lidarcal.campaign.settings import Execution
from lidarcal.certificate import MEASURAND, make_certificate, result_table
from lidarcal.certificate.dcc.export import dcc_tree
from lidarcal.certificate.document import write_document
from lidarcal.conditions import synthetic_conditions
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.lidar import LidarModel, simulate_period
from lidarcal.lidar.model_form import ALTERNATIVES, IEC_ED2, alternative_models, gaussian_rwf_of, rwf_fwhm
from lidarcal.lidar.spectral import cross_spectral_matrix
from lidarcal.rwf import range_weighting_function

PHI = np.radians(28.0)
NT, T = 600, 600.0
F_ALL = np.arange(NT // 2 + 1) / T


# -- the registry ------------------------------------------------------------------------------------

def test_each_alternative_changes_only_its_own_choice():
    nominal = LidarModel.ideal()
    alts = alternative_models(nominal)
    assert list(alts) == ["reference_level", "coherence", "length_scale"]  # no measured RWF: no rwf_shape
    base = nominal.to_dict()
    changed = {name: {k for k, v in m.to_dict().items() if v != base[k] and k != "description"}
               for name, m in alts.items()}
    assert changed == {"reference_level": {"reference_turbulence"},
                       "coherence": {"coherence_decay", "coherence_length"},
                       "length_scale": {"turbulence_length_scale"}}
    assert alts["reference_level"].reference_turbulence == "inferred_level"
    assert (alts["coherence"].coherence_decay, alts["coherence"].coherence_length) == (8.8, 73.5)
    assert alts["length_scale"].turbulence_length_scale == 21.0
    # a nominal at the other end of a range gets the nominal default: the same range either way
    ed2 = nominal.replace(**IEC_ED2, reference_turbulence="inferred_level")
    back = alternative_models(ed2)
    assert back["coherence"].coherence_decay == 12.0 and back["coherence"].coherence_length == 340.2
    assert back["length_scale"].turbulence_length_scale == 42.0
    assert back["reference_level"].reference_turbulence == "pinned_u"
    assert [a.name for a in ALTERNATIVES] == ["reference_level", "coherence", "length_scale", "rwf_shape"]
    with pytest.raises(InputError, match="coherence_length must be a finite number > 0"):
        LidarModel.ideal(coherence_length=0.0)


def test_gaussian_rwf_alternative_of_a_gaussian_profile_is_the_ideal_lidar():
    """A 'measured' RWF that is a 30-m Gaussian: its alternative is the ideal lidar, period for period."""
    s = np.arange(-80.0, 80.01, 0.5)
    sigma = 30.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    measured = LidarModel.ideal(rwf_profile=(tuple(s), tuple(np.exp(-0.5 * (s / sigma) ** 2))))
    assert rwf_fwhm(measured) == pytest.approx(30.0, abs=0.01)  # half-maximum crossings interpolated on 0.5 m
    alt = gaussian_rwf_of(measured)
    ideal = LidarModel.ideal()
    assert alt.rwf_profile is None
    np.testing.assert_allclose(alt.rwf_offsets, ideal.rwf_offsets, atol=2e-3)
    kw = dict(heights=[60.0, 140.0], wind_speed=9.0, wind_from_direction=75.0, turbulence_intensity=0.12,
              wind_shear_exponent=0.15, cnr=-12.0, cnr_gradient=0.0, seed=(5, 77))
    a, b = simulate_period(alt, **kw), simulate_period(ideal, **kw)
    # same seeds, RWFs equal within 1e-4 of their width: the speeds agree to far below the LOS noise
    np.testing.assert_allclose(a["lidar_wind_speed"], b["lidar_wind_speed"], atol=2e-4)
    np.testing.assert_allclose(a["reference_wind_speed"], b["reference_wind_speed"], rtol=1e-12)
    # the sample pulse's RWF: the Gaussian has the FWHM the rwf artefact itself records
    rwf = range_weighting_function()
    model = LidarModel.from_artefacts(rwf=rwf)
    gauss = alternative_models(model)["rwf_shape"]
    assert rwf_fwhm(gauss) == pytest.approx(float(rwf["rwf_fwhm"]), abs=0.5)  # 0.5-m profile grid
    assert gauss.rwf_profile is None and model.rwf_profile is not None


# -- the alternatives' cross-spectra against a brute-force double sum ---------------------------------

def _brute(height, U, direction, ti, fidx, hgrid, *, decay, lc_u, lam):
    """Double sum over RWF nodes (spacing ``hgrid``) of the IEC coherence and Kaimal spectra."""
    sr = 30.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    s = np.arange(-6.0 * sr, 6.0 * sr + 1e-9, hgrid)
    R = height / np.cos(PHI)
    w = np.exp(-0.5 * (s / sr) ** 2)
    w /= w.sum()
    th = np.radians(direction)
    down = np.array([-np.sin(th), -np.cos(th)])
    left = np.array([-down[1], down[0]])
    az = np.radians([0.0, 90.0, 180.0, 270.0])
    n = np.stack([np.sin(PHI) * np.sin(az), np.sin(PHI) * np.cos(az), np.full(4, np.cos(PHI))], axis=-1)
    a = np.stack([n[:, :2] @ down, n[:, :2] @ left, n[:, 2]], axis=-1)
    sig = ti * U * np.array([1.0, 0.8, 0.5])
    factors = np.array([8.1, 2.7, 0.66])
    mags = []
    for c in range(3):  # PyConTurb's spc_to_mag with Lambda = min(0.7 z, lam): z > 30 m here, so lam
        tau = lam * factors[c] / U
        m = np.sqrt(4.0 * tau / (1.0 + 6.0 * tau * F_ALL) ** (5.0 / 3.0) / T / 2.0)
        m[0] = 0.0
        mags.append(m * sig[c] / np.sqrt(NT / (NT - 1) * (2.0 * np.sum(m**2) - m[-1] ** 2)))
    lc = lc_u * factors / factors[0]
    pts = [(R + s)[:, None] * a[b] for b in range(4)]
    out = np.zeros((len(fidx), 4, 4), dtype=complex)
    for i in range(4):
        for j in range(i, 4):
            r = np.hypot(pts[i][:, None, 1] - pts[j][None, :, 1], pts[i][:, None, 2] - pts[j][None, :, 2])
            dx = pts[i][:, None, 0] - pts[j][None, :, 0]
            for k, nf in enumerate(fidx):
                f = F_ALL[nf]
                ph = np.exp(-2j * np.pi * f * dx / U)
                tot = sum(a[i, c] * a[j, c] * mags[c][nf] ** 2
                          * (w @ (np.exp(-decay * r * np.sqrt((f / U) ** 2 + (0.12 / lc[c]) ** 2)) * ph) @ w)
                          for c in range(3))
                out[k, i, j], out[k, j, i] = tot, np.conj(tot)
    return out


@pytest.mark.parametrize("name", ["coherence", "length_scale"])
def test_the_turbulence_alternatives_match_a_brute_force_double_sum(name):
    """The engine with the Ed. 2 coherence / length scale against the double sum of the same model.

    Four LOS signals at 100 m, 8 m/s, wind from 20°, at frequencies the engine computes and ones it
    interpolates.  Tolerance as tests/test_lidar_spectral.py: every element within 2 % of
    sqrt(C_ii C_jj) (the double sum's cusp error removed by Richardson extrapolation of 0.5 and
    0.25 m grids); and the alternative moves some element by more than that, so the check sees it.
    """
    nominal = LidarModel.ideal()
    alt = alternative_models(nominal)[name]
    fidx = [1, 3, 10, 30, 120, 300]
    pars = dict(decay=alt.coherence_decay, lc_u=alt.coherence_length, lam=alt.turbulence_length_scale)
    ref = (4.0 * _brute(100.0, 8.0, 20.0, 0.15, fidx, 0.25, **pars)
           - _brute(100.0, 8.0, 20.0, 0.15, fidx, 0.5, **pars)) / 3.0
    sigma = 0.15 * 8.0 * np.array([1.0, 0.8, 0.5])
    C = cross_spectral_matrix(alt, 100.0, 8.0, 20.0, sigma, 0.0, T)[np.array(fidx) - 1][:, 2:, 2:]
    C0 = cross_spectral_matrix(nominal, 100.0, 8.0, 20.0, sigma, 0.0, T)[np.array(fidx) - 1][:, 2:, 2:]
    d = np.sqrt(np.real(np.einsum("fii->fi", ref)))
    scale = d[:, :, None] * d[:, None, :]
    assert (np.abs(C - ref) / scale).max() < 0.02
    assert (np.abs(C0 - ref) / scale).max() > 0.05  # the nominal model is not this one


# -- common random numbers ---------------------------------------------------------------------------

def test_common_random_numbers_make_the_difference_far_less_noisy():
    """Alternative minus nominal with the nominal's seeds against with independent seeds, 40 periods.

    Measured variance ratios (independent / common): reference_level ≈ 9, coherence ≈ 120,
    length_scale ≈ 54.  With 39 degrees of freedom each, a variance ratio estimate lies within a
    factor 1.9 of its true value 95 % of the time: the thresholds 3 and 15 leave that margin.
    """
    nominal = LidarModel.ideal()
    kw = dict(heights=[100.0], wind_speed=10.0, wind_from_direction=30.0, turbulence_intensity=0.15,
              wind_shear_exponent=0.1, cnr=-10.0, cnr_gradient=0.0)

    def error(model, seed):
        out = simulate_period(model, seed=seed, **kw)
        return out["lidar_wind_speed"][0] - out["reference_wind_speed"][0]

    e0 = np.array([error(nominal, (3, k)) for k in range(40)])
    ratios = {}
    for name, alt in alternative_models(nominal).items():
        common = np.array([error(alt, (3, k)) for k in range(40)]) - e0
        independent = np.array([error(alt, (4, k)) for k in range(40)]) - e0
        ratios[name] = independent.var(ddof=1) / common.var(ddof=1)
    assert ratios["reference_level"] > 3.0, ratios
    assert ratios["coherence"] > 15.0 and ratios["length_scale"] > 15.0, ratios


# -- the contributor ---------------------------------------------------------------------------------

def _one_bin_records(n=60, seed=3):
    """Records at 100 m whose reference speeds all fall in the 8 m/s bin, with period keys."""
    rec = make_records(n=n, heights=(100.0,), seed=seed, noise=1.0)
    rng = np.random.default_rng(seed)
    ref = 8.0 + rng.uniform(-0.2, 0.2, (n, 1))
    rel = rec["lidar_wind_speed"].values / rec["reference_wind_speed"].values
    rec["reference_wind_speed"].values[:] = ref
    rec["lidar_wind_speed"].values[:] = ref * rel
    rec["period_key"] = ("time", rec["time"].values.astype("datetime64[s]").astype(np.int64))
    return rec


def _with_runs(rec, shifts):
    """``rec`` with model-form runs: per alternative, lidar speeds from a function of the nominal ones."""
    lid, ref = rec["lidar_wind_speed"].values[:, 0], rec["reference_wind_speed"].values[:, 0]
    idx = np.arange(rec.sizes["time"])
    runs = {name: {"period": idx, "height": np.full(idx.size, 100.0), "lidar_wind_speed": fn(lid, ref),
                   "reference_wind_speed": ref.copy()} for name, fn in shifts.items()}
    models = dict(zip(shifts, [LidarModel.ideal()] * len(shifts), strict=True))
    return with_model_form(rec, models, runs, per_bin=len(idx))


def test_the_contributor_counts_periods_not_trials():
    """With replicas the contributor's N is the bin's distinct periods, as the statistical term's.

    Replicas 1-3 repeat replica 0's errors: the trials quadruple, the periods do not.  By hand from
    the budget's own pooled μ, σ, N = ``period_count`` and v, with the +0.02 m/s alternative:
    u = sqrt(v² + μ² + σ²(1 + 1/N)), u_mf = |δu| / √3, model_form = sqrt((u + u_mf)² − u²).
    """
    rec = _one_bin_records()
    runs = _with_runs(rec, {"reference_level": lambda lid, ref: lid + 0.02})
    lid, ref = rec["lidar_wind_speed"].values[:, 0], rec["reference_wind_speed"].values[:, 0]
    idx = np.arange(rec.sizes["time"])
    more = with_trials(runs, [{"replica": r, "period": idx, "height": np.full(idx.size, 100.0),
                               "lidar_wind_speed": lid, "reference_wind_speed": ref} for r in (1, 2, 3)])
    cell = budget(more, rule=CertificationRule(min_periods=3)).sel(height=100.0, wind_speed=8.0)
    n, trials = int(cell.period_count), int(cell.sample_count)
    assert (n, trials) == (60, 240)
    v = float(cell.contribution.sel(contributor="virtual_reference"))
    mu, sigma = float(cell.mean_difference), float(cell.std_difference)
    def u_of(m, periods):
        return np.sqrt(v**2 + m**2 + sigma**2 * (1 + 1 / periods))
    for periods in (n, trials):
        u_mf = abs(u_of(mu + 0.02, periods) - u_of(mu, periods)) / np.sqrt(3)
        expected = np.sqrt((u_of(mu, periods) + u_mf) ** 2 - u_of(mu, periods) ** 2)
        close = float(cell.contribution.sel(contributor="model_form")) == pytest.approx(expected, rel=1e-9)
        assert close == (periods == n), periods  # N = periods matches to rounding; N = trials does not


def test_the_contributor_by_hand():
    """One bin, two made-up alternatives: the mean error + 0.02 m/s; the spread x 1.3.

    By hand: u = sqrt(v² + μ² + σ²(1 + 1/n)); under the first μ → μ + 0.02, under the second σ → 1.3 σ;
    u_mf = sqrt((δu_1² + δu_2²) / 3); model_form = sqrt((u + u_mf)² − u²).
    """
    rec = _one_bin_records()
    def spread(lid, ref):
        e = lid - ref
        return ref + e.mean() + 1.3 * (e - e.mean())

    both = _with_runs(rec, {"reference_level": lambda lid, ref: lid + 0.02, "coherence": spread})
    b = budget(both, rule=CertificationRule(min_periods=3))
    assert list(b.contributor.values)[-1] == "model_form"
    three = CertificationRule(min_periods=3)
    assert "model_form" not in budget(rec, rule=three).contributor.values  # no runs: no contributor
    assert "model_form" not in budget(both, rule=three, model_form=False).contributor.values
    cell = b.sel(height=100.0, wind_speed=8.0)
    e = (rec["lidar_wind_speed"] - rec["reference_wind_speed"]).values[:, 0]
    n, mu, sigma = e.size, e.mean(), e.std(ddof=1)
    v = float(cell.contribution.sel(contributor="virtual_reference"))
    u = np.sqrt(v**2 + mu**2 + sigma**2 * (1 + 1 / n))
    du1 = np.sqrt(v**2 + (mu + 0.02) ** 2 + sigma**2 * (1 + 1 / n)) - u
    du2 = np.sqrt(v**2 + mu**2 + (1.3 * sigma) ** 2 * (1 + 1 / n)) - u
    u_mf = np.sqrt((du1**2 + du2**2) / 3)
    expected = np.sqrt((u + u_mf) ** 2 - u**2)
    assert float(cell.contribution.sel(contributor="model_form")) == pytest.approx(expected, rel=1e-9)
    assert float(cell.uncertainty) == pytest.approx(u + u_mf, rel=1e-9)  # the combined is u + u_mf
    assert cell.contribution.attrs["units"] == "m s-1" and b.model_form_shift.attrs["units"] == "%"
    shift = cell.model_form_shift.sel(model_form_alternative="coherence")
    assert float(shift) == pytest.approx(2 * du2 * 100 / float(cell.mean_reference_wind_speed), rel=1e-9)
    assert int(cell.model_form_sample_count) == n
    # standard error by hand (delta method): the mean shift is the same on every period (no error);
    # the spread alternative moves period j by 0.3 (e_j - ē) (influence on δμ) and its std by 0.3 s
    # (influence 0.3 ((e_j - ē)² - s² (n-1)/n) / 2s on δσ)
    dev = e - mu
    psi_u2 = (mu * 0.3 * dev + 1.3 * sigma * (1 + 1 / n) * 0.3 * (dev**2 - sigma**2 * (n - 1) / n)
              / (2 * sigma)) / (u + du2)
    se_mf = np.sqrt(np.sum((du2 * psi_u2 / (3 * u_mf)) ** 2)) / n
    se = (u + u_mf) / expected * se_mf
    assert float(cell.model_form_standard_error) == pytest.approx(se, rel=1e-9)


def test_standard_error_matches_the_scatter_of_repeated_subsamples():
    """Delta-method standard error of model_form against 400 independent subsamples of 16 periods.

    Alternatives with period-to-period noise (as common random numbers leave): the mean error +
    0.01 ± 0.01 m/s and the spread x 1.15 ± 0.01 m/s.  The standard deviation of 400 values is
    known to 3.5 %; the delta method at 16 periods agrees with it within 25 % (measured: 5-10 %).
    """
    rng = np.random.default_rng(11)
    m, trials = 16, 400
    binned = {"n": np.array([[200]]), "mean_difference": np.array([[0.05]]),
              "std_difference": np.array([[0.1]]), "mean_reference": np.array([[8.0]])}
    vref = np.array([[0.04]])
    edges = np.array([7.75, 8.25])
    values, errors = [], []
    for _ in range(trials):
        ref = 8.0 + rng.uniform(-0.2, 0.2, m)
        e0 = rng.normal(0.05, 0.1, m)
        ea = e0 + rng.normal(0.01, 0.01, m)
        eb = 0.05 + 1.15 * (e0 - 0.05) + rng.normal(0.0, 0.01, m)
        rec = xr.Dataset(
            {"lidar_wind_speed": (("time", "height"), (ref + e0)[:, None], {"units": "m s-1"}),
             "reference_wind_speed": (("time", "height"), ref[:, None], {"units": "m s-1"}),
             "period_key": ("time", np.arange(m)),
             "model_form_period_key": ("model_form_sample", np.arange(m)),
             "model_form_height": ("model_form_sample", np.full(m, 100.0), {"units": "m"}),
             "model_form_lidar_wind_speed": (("model_form_alternative", "model_form_sample"),
                                             np.stack([ref + ea, ref + eb]), {"units": "m s-1"}),
             "model_form_reference_wind_speed": (("model_form_alternative", "model_form_sample"),
                                                 np.stack([ref, ref]), {"units": "m s-1"})},
            coords={"height": [100.0], "model_form_alternative": ["a", "b"]})
        out = model_form_term(rec, edges, binned, vref, 2.0, source="test")
        values.append(out["contribution"][0, 0])
        errors.append(out["standard_error"][0, 0])
    ratio = np.median(errors) / np.std(values, ddof=1)
    assert 0.75 < ratio < 1.25, ratio


def test_select_periods_takes_at_most_per_bin_evenly_in_time():
    rec = make_records(n=300, heights=(80.0, 120.0), seed=4)
    cells = select_periods(rec, per_bin=5)
    ref = rec["reference_wind_speed"].values
    for i in range(2):
        bins = np.floor(ref[:, i] / 0.5 + 0.5)
        for b in np.unique(bins):
            mine = np.flatnonzero(bins == b)
            chosen = np.flatnonzero(cells[:, i] & (bins == b))
            assert chosen.size == min(5, mine.size)
            if mine.size > 5:  # the first and the last period of the bin, the rest between
                assert chosen[0] == mine[0] and chosen[-1] == mine[-1]
    inside = select_periods(rec, per_bin=5, wind_speeds=(6.0, 9.0))  # only bins centred in 6-9 m/s
    centres = np.floor(ref / 0.5 + 0.5) * 0.5
    assert np.array_equal(inside, cells & (centres >= 6.0) & (centres <= 9.0))
    with pytest.raises(InputError, match="per_bin must be >= 2"):
        select_periods(rec, per_bin=1)


# -- the contributor in every document -------------------------------------------------------------

@pytest.fixture(scope="module")
def small_chain(tmp_path_factory):
    """30 two-minute periods at 100 m, a measured RWF, the four alternatives; budget to certificate."""
    d = tmp_path_factory.mktemp("model_form")
    cond = synthetic_conditions(30, (60.0, 100.0), seed=7)
    rwf = range_weighting_function()
    model = LidarModel.from_artefacts(rwf=rwf)
    records = simulate_campaign(cond, model, heights=[100.0],
                                execution=Execution(scheduler="synchronous"), duration=120.0)
    records = model_form_runs(records, cond, model,
                              execution=Execution(scheduler="synchronous"), duration=120.0, per_bin=6)
    # 15 Monte Carlo replicas of every period: a value certifies only once it has settled (JCGM 101
    # 7.9) from the replicas and from all trials; with 3-6 periods a bin, 16 replicas settle every bin
    # of 3 periods or more to one significant digit (4 replicas settle one of six)
    done = simulate_replicas(cond, model, np.ones((30, 1), dtype=bool), list(range(1, 16)), heights=[100.0],
                             execution=Execution(scheduler="synchronous"), duration=120.0)
    records = with_trials(records, [{"replica": r, **{k: done[r][k] for k in ("period", "height",
                                     "lidar_wind_speed", "reference_wind_speed")}} for r in sorted(done)])
    rec_path = write_artefact(records, d / "simulated.nc")
    records = open_artefact(rec_path, "simulated_rtd")
    b = budget(records, rule=CertificationRule(min_periods=3, significant_digits=1))
    cert = make_certificate(budget=b, sensitivities=[], rwf=rwf, records=records, demonstration=True)
    return d, records, b, cert, rwf


def test_runs_reuse_the_nominal_seeds(small_chain):
    _, records, _, _, rwf = small_chain
    assert list(records.model_form_alternative.values) == ["reference_level", "coherence", "length_scale",
                                                           "rwf_shape"]
    assert records.model_form_lidar_wind_speed.attrs["units"] == "m s-1"
    # an alternative sample re-run by hand: simulate_period with the alternative and replica 0's seed
    model = LidarModel.from_dict(json.loads(str(records.model_form_model.values[1])), rwf=rwf)
    assert model.coherence_decay == 8.8
    j = 0
    key, z = int(records.model_form_period_key[j]), float(records.model_form_height[j])
    t = int(np.flatnonzero(records.period_key.values == key)[0])
    cond = {v: float(records[v].isel(time=t).sel(height=z)) for v in
            ("wind_speed", "wind_from_direction", "turbulence_intensity", "wind_shear_exponent", "cnr",
             "cnr_gradient")}
    out = simulate_period(model, heights=[z], seed=(int(records.attrs["lidarcal_base_seed"]), key),
                          duration=120.0, **cond)
    assert float(records.model_form_lidar_wind_speed[1, j]) == out["lidar_wind_speed"][0]


def test_the_contributor_is_in_the_budget_certificate_table_pdf_and_dcc(small_chain, poppler, tmp_path):
    d, _, b, cert, _ = small_chain
    assert "model_form" in b.contributor.values and b.contribution.attrs["units"] == "m s-1"
    certified = b.relative_contribution.sel(contributor="model_form").where(b.bin_flag == 0)
    assert np.isfinite(certified).any() and float(certified.max()) > 0
    # the certificate: the budget component, its summary and the measurand
    assert "model_form" in [str(c) for c in cert.budget_contributor.values]
    assert cert.budget_model_form_standard_error.attrs["units"] == "m s-1"
    assert cert.attrs["measurand"] == MEASURAND and "single 10-minute mean" in MEASURAND
    assert "model form" in cert.attrs["model_form"] and "percentage points" in cert.attrs["model_form"]
    table = result_table(cert)
    assert table[table.certified]["model_form_pct"].max() == pytest.approx(float(certified.max()), rel=1e-12)
    # the PDF: the measurand on page 1, a page of the model-form contributor per bin in %
    pdf = write_document(tmp_path / "cert.pdf", cert)["pdf"]
    text = subprocess.run([poppler[1], "-raw", str(pdf), "-"], capture_output=True, text=True,
                          check=True).stdout
    flat = " ".join(text.split())
    assert "U is the expanded uncertainty of a single 10-minute mean" in flat
    assert "must not average them down" in flat
    assert "Model form of the simulation: contributor model_form (%, k = 1)" in flat
    best = float(certified.max())
    assert f"{best:.2f} ±" in flat  # the largest certified value, as printed in the grid
    # the DCC: per height, the model-form list in percent
    tree = dcc_tree(cert, certificate_sha256="0" * 64)
    ns = {"dcc": "https://ptb.de/dcc", "si": "https://ptb.de/si"}
    lists = tree.findall(".//dcc:quantity[@refType='lidarcal_modelFormUncertainty']", ns)
    assert len(lists) == 1
    assert lists[0].find(".//si:unitXMLList", ns).text == r"\percent"
    values = [float(x) for x in lists[0].find(".//si:valueXMLList", ns).text.split()]
    listed = b.relative_contribution.sel(contributor="model_form").where(b.bin_flag != 4)  # 4: listed apart
    assert max(values) == pytest.approx(float(listed.max()), rel=1e-6)
    statement = tree.find(".//dcc:statement[@refType='lidarcal_measurand']", ns)
    assert "single 10-minute mean" in "".join(statement.itertext())
