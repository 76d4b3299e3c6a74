"""Tests of the turbulence kernels: PyConTurb's models reproduced, and the fast generator's statistics."""

import numpy as np
import pandas as pd
import pytest

from lidarcal.turbulence.kernels import (
    cell_size,
    generate_points,
    iec3d_coherence,
    kaimal_psd,
    sigma_components,
    spectral_magnitudes,
)

U, TI, Z = 8.0, 0.12, 100.0
SIGMA = sigma_components(TI, U)
NT, DF = 600, 1 / 600
F = np.arange(NT // 2 + 1) * DF


def spat_df(y, z):
    cols, rows = [], []
    for k in range(3):
        for p, (yy, zz) in enumerate(zip(y, z, strict=True)):
            cols.append(f"{'uvw'[k]}_p{p}")
            rows.append([k, 0.0, yy, zz])
    return pd.DataFrame(np.array(rows, float).T, index=["k", "x", "y", "z"], columns=cols)


def independent_points(n, z=Z):
    """n points 5 km apart across the wind: coherence exp(-12*5000*0.12/340) ~ 1e-9, independent."""
    return np.zeros(n), 5000.0 * np.arange(n), np.full(n, z)


def test_sigma_ratios_table2():
    np.testing.assert_allclose(sigma_components(0.1, 8.0), [0.8, 0.64, 0.4], rtol=1e-15)


def test_models_identical_to_pyconturb():
    from pyconturb.coherence import get_iec3d_cor_mat
    from pyconturb.magnitudes import spc_to_mag
    from pyconturb.sig_models import constant_sig
    from pyconturb.spectral_models import kaimal_spectrum

    y, z = np.array([0.0, 7.0, -20.0]), np.array([40.0, 75.0, 130.0])  # below and above 60 m
    df = spat_df(y, z)
    ref = kaimal_spectrum(F, df, u_ref=U)
    ours = np.concatenate([kaimal_psd(F, z, U, k) for k in range(3)], axis=1)
    np.testing.assert_allclose(ours, ref, rtol=1e-14)
    ref_mag = spc_to_mag(df, ref, constant_sig, sig_vals=list(SIGMA), comps=[0, 1, 2], T=600.0, nt=NT)
    ours_mag = spectral_magnitudes(F, z, U, SIGMA, NT)
    np.testing.assert_allclose(np.concatenate(list(ours_mag), axis=1), ref_mag, rtol=1e-12)
    cor = get_iec3d_cor_mat(F[1:4], df, u_ref=U, l_c=340.2)
    r = np.hypot(y[0] - y[2], z[0] - z[2])
    for k in range(3):
        np.testing.assert_allclose(cor[:, 3 * k, 3 * k + 2], iec3d_coherence(F[1:4], r, U, k), rtol=1e-14)
    assert np.all(cor[:, 0, 3:] == 0)  # no cross-component coherence: independent blocks


def test_cell_size_rule_numbers():
    a, b, longitudinal = cell_size(80.0, 28.0, 4.0, 4.0)
    assert a == pytest.approx(2 * 80 * np.tan(np.radians(28)), rel=1e-14)  # opposite beams, 2 h tan phi
    assert b == pytest.approx(np.sqrt(2) * 80 * np.tan(np.radians(28)), rel=1e-14)  # adjacent beams
    assert (round(a, 1), round(b, 1)) == (85.1, 60.2)  # the paper's numbers
    assert longitudinal == pytest.approx(16.0)  # 4 m/s x 4 s


def exact_variance_se(n_real):
    """Standard error of the mean ddof=1 variance over n_real independent Rayleigh realisations.

    The sample variance is (nt/(nt-1)) sum_k c_k |xi_k|^2 with c_k = 2 m_k^2 (m_N^2 at Nyquist);
    |xi|^2 ~ Exp(1) (variance 1) and xi_N^2 ~ chi2_1 (variance 2), so the variance is exact.
    """
    mags = spectral_magnitudes(F, [Z], U, SIGMA, NT)[:, :, 0]
    c = 2 * mags**2
    c[:, -1] = mags[:, -1] ** 2
    var = np.sum(c[:, :-1] ** 2, axis=1) + 2 * c[:, -1] ** 2
    return NT / (NT - 1) * np.sqrt(var / n_real)


def ensemble(n_points, n_seeds, amplitude="rayleigh", base=0):
    x, y, z = independent_points(n_points)
    runs = [generate_points(x, y, z, wind_speed=U, sigma=SIGMA, amplitude=amplitude,
                            rng=np.random.default_rng(np.random.SeedSequence([base, s])))
            for s in range(n_seeds)]
    return np.concatenate(runs, axis=1)  # (3, n_points * n_seeds, nt)


SLOW = pytest.mark.slow


@pytest.mark.parametrize(("n_points", "n_seeds"), [(60, 3), pytest.param(200, 10, marks=SLOW)])
def test_std_matches_sigma(n_points, n_seeds):
    series = ensemble(n_points, n_seeds)
    var = series.var(axis=-1, ddof=1).mean(axis=1)
    se = exact_variance_se(series.shape[1])
    # 4 standard errors of the sampling distribution of the variance (derived, see helper)
    np.testing.assert_array_less(np.abs(var - SIGMA**2), 4 * se)
    assert np.all(4 * se / SIGMA**2 < 0.08)  # the test can fail: 8 % resolution (u is red: few dof)
    # PyConTurb's fixed-amplitude draws carry exactly sigma in every isolated realisation
    fixed = generate_points([0.0], [0.0], [Z], wind_speed=U, sigma=SIGMA, rng=np.random.default_rng(1),
                            amplitude="fixed")
    # (rtol: the 1e-10 diagonal jitter of the factorisation adds 5e-11 to the std)
    np.testing.assert_allclose(fixed.std(axis=-1, ddof=1)[:, 0], SIGMA, rtol=1e-9)


def log_bins(n_f):
    edges = np.unique(np.r_[1, np.round(np.geomspace(2, n_f, 9)).astype(int)])
    return [np.arange(lo, hi) for lo, hi in zip(edges[:-1], edges[1:], strict=True) if hi - lo >= 2]


@pytest.mark.parametrize(("n_points", "n_seeds"), [(100, 4), pytest.param(200, 20, marks=SLOW)])
def test_periodogram_matches_kaimal(n_points, n_seeds):
    series = ensemble(n_points, n_seeds, base=1)  # 400 (slow: 4000) independent realisations
    coef = np.fft.rfft(series, axis=-1) / NT
    psd = 2 * np.mean(np.abs(coef) ** 2, axis=1) / DF  # one-sided periodogram (3, nf)
    for k in range(3):
        shape = kaimal_psd(F, [Z], U, k)[:, 0]
        expected = SIGMA[k] ** 2 * shape / np.sum(shape[1:] * DF)  # Kaimal carrying sigma^2
        for idx in log_bins(F.size - 1):
            ratio = psd[k, idx].mean() / expected[idx].mean()
            # |xi|^2 ~ Exp(1): relative SE 1/sqrt(n_freq * n_real); 4 SE <= 14 %
            tol = 4 / np.sqrt(idx.size * series.shape[1])
            assert tol <= 0.15
            assert ratio == pytest.approx(1.0, abs=tol), (k, idx[0], ratio)


def binned_coherence(a, b, weights_f):
    """Pooled co-coherence Re<X1 X2*> / sqrt(<|X1|^2><|X2|^2>) per log bin, with its expected value."""
    xa, xb = np.fft.rfft(a, axis=-1), np.fft.rfft(b, axis=-1)
    out = []
    for idx in log_bins(xa.shape[-1] - 1):
        cross = np.real(xa[:, idx] * np.conj(xb[:, idx])).sum()
        est = cross / np.sqrt((np.abs(xa[:, idx]) ** 2).sum() * (np.abs(xb[:, idx]) ** 2).sum())
        out.append((idx, est))
    return out


@pytest.mark.parametrize(("sep", "n_pairs", "n_seeds"),
                         [(12.0, 40, 5), pytest.param(12.0, 100, 20, marks=SLOW),
                          pytest.param(40.0, 100, 20, marks=SLOW)])
def test_coherence_matches_iec3d(sep, n_pairs, n_seeds):
    y = np.repeat(5000.0 * np.arange(n_pairs), 2) + np.tile([0.0, sep], n_pairs)
    x, z = np.zeros_like(y), np.full_like(y, Z)
    runs = [generate_points(x, y, z, wind_speed=U, sigma=SIGMA, rng=np.random.default_rng([9, s]))
            for s in range(n_seeds)]
    series = np.concatenate(runs, axis=1)
    n_real = series.shape[1] // 2
    mags = spectral_magnitudes(F, [Z], U, SIGMA, NT)[:, :, 0]
    for k in range(3):
        gamma = iec3d_coherence(F, sep, U, k)
        for idx, est in binned_coherence(series[k, 0::2], series[k, 1::2], mags[k]):
            w = mags[k, idx] ** 2
            expected = np.sum(w * gamma[idx]) / w.sum()  # power-weighted like the pooled estimator
            n_eff = n_real * w.sum() ** 2 / np.sum(w**2)
            # SE of a coherence estimate ~ (1 - gamma^2) / sqrt(N_eff); 4 SE plus 0.01 for the
            # ratio-estimator bias (O(1/N))
            tol = 4 * (1 - expected**2) / np.sqrt(n_eff) + 0.01
            assert est == pytest.approx(expected, abs=tol), (k, idx[0], est, expected)
    # the u coherence is far from both 0 and 1 at some frequency: the test discriminates
    assert 0.2 < iec3d_coherence(0.02 * 12 / sep, sep, U, 0) < 0.8


def test_frozen_turbulence_shift_is_exact():
    # a point 3 s downstream (x = 3 U) sees the x = 0 signal 3 s later: u(x, t) = u(0, t - x/U)
    out = generate_points([0.0, 3 * U, 0.0], [0.0, 0.0, 15.0], [Z, Z, Z], wind_speed=U, sigma=SIGMA,
                          rng=np.random.default_rng(3))
    np.testing.assert_allclose(out[:, 1], np.roll(out[:, 0], 3, axis=-1), atol=1e-12)
    assert not np.allclose(out[:, 2], out[:, 0], atol=0.05)


def test_near_duplicates_and_zero_sigma():
    # 1e-4 m apart: not merged, the near-singular matrix is handled (jitter / eigen fallback)
    out = generate_points([0.0, 0.0], [0.0, 1e-4], [Z, Z], wind_speed=U, sigma=SIGMA,
                          rng=np.random.default_rng(0))
    assert np.all(np.isfinite(out))
    # IEC coherence falls linearly at small r: 1 - corr ~ 12 r <a> <= 12e-4 * 0.07 ~ 1e-5
    corr = [np.corrcoef(out[k, 0], out[k, 1])[0, 1] for k in range(3)]
    assert min(corr) > 1 - 1e-4
    zero = generate_points([0.0], [0.0], [Z], wind_speed=U, sigma=[0.0, 0.0, 0.0],
                           rng=np.random.default_rng(0))
    assert zero.shape == (3, 1, NT) and not zero.any()


def test_own_generator_only_and_reproducible():
    state = np.random.get_state()
    a = generate_points([0.0], [0.0], [Z], wind_speed=U, sigma=SIGMA, rng=np.random.default_rng([1, 2]))
    b = generate_points([0.0], [0.0], [Z], wind_speed=U, sigma=SIGMA, rng=np.random.default_rng([1, 2]))
    np.testing.assert_array_equal(a, b)
    after = np.random.get_state()
    assert state[0] == after[0] and np.array_equal(state[1], after[1])  # global RNG untouched


def test_bad_points_rejected():
    with pytest.raises(ValueError, match="z > 0"):
        generate_points([0.0], [0.0], [0.0], wind_speed=U, sigma=SIGMA, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="wind_speed"):
        generate_points([0.0], [0.0], [Z], wind_speed=0.0, sigma=SIGMA, rng=np.random.default_rng(0))
    with pytest.raises(ValueError, match="whole number"):
        generate_points([0.0], [0.0], [Z], wind_speed=U, sigma=SIGMA, rng=np.random.default_rng(0), dt=7.0)
