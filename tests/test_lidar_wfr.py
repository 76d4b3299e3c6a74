"""Unit tests of the pure WFR functions (Eqs. 3-5) and the RWF quadrature."""

import numpy as np
import pytest

from lidarcal.errors import InputError
from lidarcal.lidar import LidarModel
from lidarcal.lidar.quadrature import cnr_weights, gauss_hermite_rwf, gauss_rwf_nodes
from lidarcal.lidar.wfr import hold_latest, hybrid_speed, reconstruct, sliding_components
from lidarcal.rwf.kernels import cnr_weighted_rwf

PHI = 28.0
S = np.sin(np.radians(PHI))
AZ = np.radians([0.0, 90.0, 180.0, 270.0])


def radial(u, v, w, beam):
    """Radial velocity (positive away) of beam index ``beam`` for wind toward 0 deg (u) and 90 deg (v)."""
    th = AZ[beam]
    return S * (u * np.cos(th) + v * np.sin(th)) + np.cos(np.radians(PHI)) * w


def test_hold_latest_keeps_previous_value_of_each_beam():
    los = np.array([1.0, 2.0, 3.0, 4.0, 5.0, np.nan, 7.0, 8.0])
    beam = np.arange(8) % 4
    held = hold_latest(los, beam)
    np.testing.assert_array_equal(held[:, 5], [5.0, 2.0, 3.0, 4.0])  # beam 1 dropped at t=5: keeps 2
    assert np.isnan(held[3, 2]) and held[3, 3] == 4.0  # beam 3 unseen before t=3


def test_components_exact_and_vertical_cancels():
    rng = np.random.default_rng(0)
    beam = np.arange(600) % 4
    # a steady vertical wind cancels in S1 - S3 and S2 - S4 (a varying one does not: opposite
    # beams are sampled 2 s apart)
    los = radial(3.0, 4.0, rng.normal(0, 0.5, 600), beam)
    los_c = radial(3.0, 4.0, 0.7, beam)
    u, v = sliding_components(los_c, beam, PHI)
    np.testing.assert_allclose(u[3:], 3.0, atol=1e-12)
    np.testing.assert_allclose(v[3:], 4.0, atol=1e-12)
    assert np.isnan(u[:2]).all() and np.isnan(v[:3]).all()  # u needs beams 0 and 2, v beams 1 and 3
    out = reconstruct(los_c, beam, PHI, 2 / 3)
    assert out["n_reconstructions"] == 597  # from the 4th LOS on: 600 - 3
    for name in ("scalar", "vector", "hybrid"):
        assert out[name] == pytest.approx(5.0, abs=1e-12)
    assert np.isfinite(reconstruct(los, beam, PHI, 0.5)["scalar"])


def test_scalar_vector_hybrid_and_eq4_as_printed():
    rng = np.random.default_rng(1)
    beam = np.arange(600) % 4
    ang = np.radians(30 * np.sin(np.arange(600) / 40) + rng.normal(0, 10, 600))  # meandering wind
    speed = 8 + rng.normal(0, 1, 600)
    los = radial(speed * np.cos(ang), speed * np.sin(ang), 0.0, beam)
    out = reconstruct(los, beam, PHI, 2 / 3)
    u, v = sliding_components(los, beam, PHI)
    u, v = u[3:], v[3:]
    assert out["scalar"] == pytest.approx(np.mean(np.hypot(u, v)), rel=1e-14)  # Eq. 3
    assert out["vector"] == pytest.approx(np.hypot(u.mean(), v.mean()), rel=1e-14)  # average-then-reconstruct
    rms = np.sqrt(np.mean(u**2) + np.mean(v**2))  # Eq. 4 as printed: an RMS speed
    assert out["vector"] < out["scalar"] < rms  # ordering; the printed Eq. 4 would exceed the scalar mean
    assert out["hybrid"] == pytest.approx(2 / 3 * out["scalar"] + 1 / 3 * out["vector"], rel=1e-14)
    assert reconstruct(los, beam, PHI, 1.0)["hybrid"] == out["scalar"]  # p multiplies the scalar mean
    assert reconstruct(los, beam, PHI, 0.0)["hybrid"] == out["vector"]


def test_no_reconstruction_gives_nan():
    beam = np.arange(8) % 4
    los = np.where(beam == 2, np.nan, 1.0)  # beam 2 never delivers
    out = reconstruct(los, beam, PHI, 0.5)
    assert out["n_reconstructions"] == 0 and np.isnan(out["hybrid"])


def asymmetric_rwf():
    s = np.linspace(-150.0, 150.0, 6001)
    g = np.where(s < 0, np.exp(-0.5 * (s / 10.0) ** 2), np.exp(-0.5 * (s / 17.0) ** 2))
    return s, g


@pytest.mark.parametrize("n_nodes", [3, 5, 7])
def test_gauss_nodes_integrate_polynomials_exactly(n_nodes):
    s, g = asymmetric_rwf()
    nodes, weights = gauss_rwf_nodes(s, g, n_nodes)
    assert weights.sum() == pytest.approx(1.0, abs=1e-14) and np.all(weights > 0)
    norm = np.trapezoid(g, s)
    for deg in range(2 * n_nodes):  # exact up to degree 2K - 1 against the trapezoid measure
        exact = np.trapezoid(g * (s / 50) ** deg, s) / norm
        assert np.dot(weights, (nodes / 50) ** deg) == pytest.approx(exact, rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("height", [40.0, 60.0, 100.0, 200.0])
@pytest.mark.parametrize("alpha", [0.0, 0.1, 0.2, 0.3])
@pytest.mark.parametrize("gradient", [-0.1, 0.0, 0.1])
def test_five_nodes_average_power_law_to_1mm_s(height, alpha, gradient):
    # RWF-average of U (z/h)^alpha along a 28 deg beam, with Eq. 2's CNR weighting, by 5 Gauss
    # nodes versus the trapezoid rule on the 0.05 m table: agreement < 1 mm/s at U = 10 m/s
    s, g = asymmetric_rwf()
    nodes, weights = gauss_rwf_nodes(s, g, 5)
    r = height / np.cos(np.radians(PHI))
    keep = r + s > 0.5  # the table stops above the ground
    profile = lambda x: 10.0 * ((r + x) / r) ** alpha  # noqa: E731
    gw = g[keep] * 10 ** (gradient * s[keep] / 20)
    exact = np.trapezoid(gw * profile(s[keep]), s[keep]) / np.trapezoid(gw, s[keep])
    approx = np.dot(cnr_weights(nodes, weights, gradient), profile(nodes))
    assert approx == pytest.approx(exact, abs=1e-3)


def test_quadratic_profile_exact_and_gauss_hermite():
    nodes, weights = gauss_hermite_rwf(30.0, 5)
    sigma = 30.0 / (2 * np.sqrt(2 * np.log(2)))
    # E[a + b s + c s^2] = a + c sigma^2 for a Gaussian RWF: exact to rounding
    expected = 1 + 1e-4 * sigma**2
    assert np.dot(weights, 1 + 0.01 * nodes + 1e-4 * nodes**2) == pytest.approx(expected, abs=1e-14)
    np.testing.assert_allclose(cnr_weights(nodes, weights, 0.0), weights, rtol=1e-15)
    with pytest.raises(ValueError, match="increasing"):
        gauss_rwf_nodes(nodes[::-1], weights, 3)


def test_eq2_kernel_is_shared_guarded_and_as_written_for_moderate_gradients():
    nodes, weights = gauss_hermite_rwf(30.0, 5)
    g = np.linspace(-0.2, 0.2, 41)
    # moderate gradients: exactly Eq. 2 as written (the overflow guard is not engaged)
    direct = weights * 10.0 ** (g[:, None] * nodes / 20.0)
    np.testing.assert_array_equal(cnr_weights(nodes, weights, g), direct / direct.sum(axis=-1, keepdims=True))
    # the RWF table (axis 0, unit integral) and the nodes (axis -1, unit sum) use the same factor
    table = cnr_weighted_rwf(weights, nodes, g, dz=2.0, axis=0)
    np.testing.assert_allclose(2.0 * table.T, cnr_weights(nodes, weights, g), rtol=1e-15)
    # 1000 dB m-1 over +-36 m is 10^(+-1800): the unguarded form overflows, the guarded one
    # puts all weight on the far node (the others < 1e-40), computed here from logs by hand
    steep = cnr_weights(nodes, weights, [1000.0, -1000.0])
    assert np.all(np.isfinite(steep))
    logw = np.log10(weights) + 1000.0 * nodes / 20.0
    expected = 10.0 ** (logw - logw.max())
    np.testing.assert_allclose(steep[0], expected / expected.sum(), rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(steep[1], (expected / expected.sum())[::-1], rtol=1e-12, atol=1e-300)


def test_hybrid_conventions_p_on_scalar_or_on_vector():
    # Eq. 5's "p and (1 - p)": p on the scalar average (default) or on the vector average.
    # Isotropic Gaussian fluctuations, TI 0.2 (sigma 1.6 m/s on 8 m/s) in u and v, independent
    # samples: the scalar mean exceeds the vector mean by ~sigma_v^2 / (2 U) = 2 % of U, so the
    # two readings differ by (2p - 1) x 2 % = 0.67 % for p = 2/3 (sampling error ~0.1 %).
    rng = np.random.default_rng(4)
    beam = np.arange(6000) % 4
    u = 8.0 + rng.normal(0, 1.6, 6000)
    v = rng.normal(0, 1.6, 6000)
    los = radial(u, v, 0.0, beam)
    a = reconstruct(los, beam, PHI, 2 / 3)
    b = reconstruct(los, beam, PHI, 2 / 3, convention="vector")
    assert a["hybrid"] == pytest.approx(2 / 3 * a["scalar"] + 1 / 3 * a["vector"], rel=1e-14)
    assert b["hybrid"] == pytest.approx(2 / 3 * b["vector"] + 1 / 3 * b["scalar"], rel=1e-14)
    assert a["hybrid"] - b["hybrid"] == pytest.approx((a["scalar"] - a["vector"]) / 3, rel=1e-12)
    assert 0.2 < 100 * (a["hybrid"] - b["hybrid"]) / a["vector"] < 1.5
    # p = 1/2 (WindCube XP): the two readings coincide
    assert hybrid_speed(10.3, 10.0, 0.5, "vector") == hybrid_speed(10.3, 10.0, 0.5, "scalar")
    with pytest.raises(ValueError, match="'scalar' or 'vector'"):
        hybrid_speed(1.0, 1.0, 0.5, "mean")
    # the convention is a recorded, serialised field of the lidar model; today's reading is the default
    assert LidarModel().hybrid_convention == "scalar"
    m = LidarModel(hybrid_convention="vector")
    assert LidarModel.from_dict(m.to_json()) == m and '"hybrid_convention": "vector"' in m.to_json()
    with pytest.raises(InputError, match="hybrid_convention"):
        LidarModel(hybrid_convention="rms")
