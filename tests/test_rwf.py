"""Tests of the range-weighting function, CNR weighting and zero distance (paper §2.2)."""

import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarcal.cli import main
from lidarcal.compliance import check_compliance
from lidarcal.data import sample_file
from lidarcal.errors import InputError, MissingVariableError, UnitError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.rwf import RwfConfig, compute_rwf, range_weighting_function, read_pulse_csv
from lidarcal.rwf import kernels as k
from lidarcal.schema import validate_dataset
from lidarcal.units import Q_

DR = k.range_sample_spacing(250e6)  # 0.5996 m per sample at 250 MHz


def analytic_variance(pulse_fwhm, fraction, fft_size=64):
    """sigma^2 of Gaussian pulse ⊗ Gaussian window^2: sigma_p^2 + sigma_a^2 / 2."""
    sigma_p = pulse_fwhm / k.FWHM_PER_SIGMA
    sigma_a = fraction * fft_size * DR
    return sigma_p**2 + sigma_a**2 / 2


def test_sample_spacing_and_window_span():
    # c / (2 * 250 MHz) = 0.5996 m; 64 samples span 38.37 m, 128 span 76.75 m
    assert DR == pytest.approx(0.599584916, abs=1e-9)
    z = k.range_grid(60.0, 0.1)
    w64 = k.gaussian_window(z, 64, DR, 0.2)
    support = z[w64 > 0]
    assert support[-1] - support[0] == pytest.approx(64 * DR, abs=0.2)  # grid step 0.1 at both ends
    assert z.size % 2 == 1 and z[z.size // 2] == 0.0


def test_symmetric_gaussian_rwf():
    # window std 0.1 x 64 samples = 3.84 m: the 38.4 m window truncates its square at 7 sigma,
    # so the RWF is Gaussian with sigma^2 = sigma_p^2 + sigma_a^2 / 2 to ~1e-11
    out = compute_rwf(RwfConfig(pulse_length=25.0, window_std_fraction=0.1, cnr_gradient=(0.0,)))
    rwf = out["rwf"][:, 0]
    assert abs(out["zero_distance"]) < 1e-9
    np.testing.assert_allclose(rwf, rwf[::-1], rtol=0, atol=1e-12 * rwf.max())  # mirror symmetric
    assert rwf.sum() * 0.1 == pytest.approx(1.0, abs=1e-12)  # unit integral, m-1
    expected = k.FWHM_PER_SIGMA * np.sqrt(analytic_variance(25.0, 0.1))  # 25.80 m
    assert out["rwf_fwhm"] == pytest.approx(expected, abs=0.1)  # grid resolution 0.1 m
    assert expected == pytest.approx(25.8036, abs=1e-4)


@pytest.mark.parametrize("g", [-0.1, -0.03, 0.05, 0.1])
def test_cnr_gradient_shifts_barycenter_as_gaussian_theory(g):
    # Gaussian of variance s2 times exp(k z), k = g ln10 / 20, moves its mean by k s2 exactly;
    # discretisation on a 0.1 m grid of an 11 m-wide Gaussian is accurate to ~1e-11 m
    out = compute_rwf(RwfConfig(window_std_fraction=0.1, cnr_gradient=(g,)))
    i = int(np.flatnonzero(out["cnr_gradient"] == g)[0])
    kk = g * np.log(10) / 20
    assert out["barycenter"][i] == pytest.approx(kk * analytic_variance(25.0, 0.1), abs=1e-8)
    # every column stays a unit-integral weighting function
    np.testing.assert_allclose(out["rwf"].sum(axis=0) * 0.1, 1.0, atol=1e-12)


def test_zero_gradient_always_present_and_sorted():
    out = compute_rwf(RwfConfig(cnr_gradient=(0.05, -0.02)))
    np.testing.assert_array_equal(out["cnr_gradient"], [-0.02, 0.0, 0.05])


@pytest.mark.parametrize("asymmetry", [0.3, -0.2])
def test_asymmetric_pulse_shifts_zero_distance(asymmetry):
    out = compute_rwf(RwfConfig(asymmetry=asymmetry, cnr_gradient=(0.0,)))
    z, pulse = out["range_offset"], out["pulse"]
    direct = np.sum(z * pulse) / np.sum(pulse)  # direct first moment of the pulse
    near, far = k.two_sided_sigmas(25.0, asymmetry)
    theory = np.sqrt(2 / np.pi) * (far - near)  # mean of a two-sided Gaussian; 5.08 m at 0.3
    # the symmetric window^2 does not move the barycenter; the kink at the peak costs ~1e-10 m
    assert out["zero_distance"] == pytest.approx(direct, abs=1e-9)
    assert out["zero_distance"] == pytest.approx(theory, abs=1e-8)
    assert np.sign(out["zero_distance"]) == np.sign(asymmetry)
    assert abs(out["zero_distance"]) > 3.0  # far from zero: an asymmetric pulse biases the range
    # FWHM of the pulse itself is kept at 25 m whatever the asymmetry (grid 0.1 m)
    assert k.full_width_half_maximum(pulse, z) == pytest.approx(25.0, abs=0.1)


@settings(max_examples=15, deadline=None)
@given(fwhm=st.floats(10.0, 40.0), asymmetry=st.floats(-0.6, 0.6), fft=st.sampled_from([64, 128]),
       fraction=st.floats(0.1, 0.3))
def test_properties_of_any_synthetic_rwf(fwhm, asymmetry, fft, fraction):
    grads = (-0.1, -0.02, 0.03, 0.1)
    out = compute_rwf(RwfConfig(pulse_length=fwhm, asymmetry=asymmetry, fft_size=fft,
                                window_std_fraction=fraction, cnr_gradient=grads))
    z, pulse = out["range_offset"], out["pulse"]
    # the symmetric window^2 never moves the barycenter: Zd = first moment of the pulse
    assert out["zero_distance"] == pytest.approx(np.sum(z * pulse) / np.sum(pulse), abs=1e-8)
    # a CNR increasing away from the lidar pulls the barycenter outwards, monotonically
    assert np.all(np.diff(out["barycenter"]) > 0)
    np.testing.assert_allclose(out["rwf"].sum(axis=0) * 0.1, 1.0, atol=1e-12)
    assert np.all(out["rwf"] >= 0)


def test_pulse_offset_moves_zero_distance_by_the_offset():
    out = compute_rwf(RwfConfig(pulse_offset=1.5, cnr_gradient=(0.0,)))
    assert out["zero_distance"] == pytest.approx(1.5, abs=1e-9)


def test_fft_128_gives_a_wider_rwf_than_64():
    w64 = compute_rwf(RwfConfig(fft_size=64, cnr_gradient=(0.0,)))["rwf_fwhm"]
    w128 = compute_rwf(RwfConfig(fft_size=128, cnr_gradient=(0.0,)))["rwf_fwhm"]
    # std fraction 0.2: window sigma 7.7 m vs 15.3 m; 28.07 m vs 35.75 m measured
    assert w128 > w64 + 5.0
    assert w64 == pytest.approx(28.07, abs=0.02) and w128 == pytest.approx(35.75, abs=0.02)


def test_steep_gradient_refused_instead_of_truncated():
    with pytest.raises(InputError, match=r"cnr_gradient.*edge"):
        compute_rwf(RwfConfig(cnr_gradient=(5.0,)))  # would move the barycenter ~80 m, off the grid


def write_csv(path, text):
    path.write_text(text)
    return path


def test_measured_gaussian_in_time_matches_synthetic(tmp_path):
    # a Gaussian of 25 m FWHM is 166.8 ns FWHM in time; sampled every 4 ns (250 MHz)
    tau = 25.0 / (k.SPEED_OF_LIGHT / 2) * 1e9
    t = np.arange(-600, 604, 4.0)
    y = np.exp(-0.5 * (t / (tau / k.FWHM_PER_SIGMA)) ** 2)
    lines = "\n".join(f"{a:.1f},{b:.8f}" for a, b in zip(t, y, strict=True))
    path = write_csv(tmp_path / "p.csv", "# comment\ntime_ns,intensity\n" + lines + "\n")
    ds = range_weighting_function(pulse_file=path, cnr_gradient=Q_([0.0, 0.1], "dB m-1"))
    ref = range_weighting_function(pulse_length=Q_(25, "m"), cnr_gradient=Q_([0.0, 0.1], "dB m-1"))
    # linear interpolation of 0.6 m samples of an 11 m-sigma Gaussian: width error < 2 mm
    assert float(ds.rwf_fwhm) == pytest.approx(float(ref.rwf_fwhm), abs=0.05)
    assert abs(float(ds.zero_distance)) < 1e-6  # symmetric samples around t = 0
    np.testing.assert_allclose(ds.barycenter, ref.barycenter.values, atol=0.005)
    assert ds.attrs["pulse_shape"] == "measured" and ds.attrs["pulse_file"] == "p.csv"


def test_noise_floor_of_a_measured_pulse_is_removed(tmp_path):
    # 0.3 % detector noise clipped at zero leaves a +0.12 % pedestal over the whole recording;
    # kept, it would put RWF weight 80 m from the gate (and Gauss nodes below ground at 40 m)
    t = np.arange(-800, 804, 4.0)
    clean = np.exp(-0.5 * (t / 70.0) ** 2)
    noisy = np.clip(clean + np.random.default_rng(3).normal(0, 0.003, t.size), 0, None)
    cleaned = k.remove_noise_floor(t, noisy)
    assert np.all(cleaned[np.abs(t) > 300] == 0.0)  # beyond 4.3 sigma the pulse is below the noise
    lines = "\n".join(f"{a:.1f},{b:.8f}" for a, b in zip(t, noisy, strict=True))
    ds = range_weighting_function(pulse_file=write_csv(tmp_path / "n.csv", "time_ns,intensity\n" + lines))
    rwf = ds.rwf.sel(cnr_gradient=0.0)
    assert float(rwf.where(np.abs(ds.range_offset) > 60).max()) == 0.0
    assert abs(float(ds.zero_distance)) < 0.05  # symmetric pulse; noise moves the barycentre < 5 cm
    np.testing.assert_allclose(k.remove_noise_floor(t, clean), clean, rtol=0, atol=1e-12)  # noise-free


def test_time_is_mapped_to_range_with_reversal(tmp_path):
    # a pulse emitted late (t > 0) samples ranges nearer the lidar: z = -c t / 2
    path = write_csv(tmp_path / "late.csv", "time_ns,intensity\n90,0\n100,1\n110,0\n")
    pulse = read_pulse_csv(path)
    np.testing.assert_allclose(pulse.range_offset, -k.SPEED_OF_LIGHT / 2 * np.array([90, 100, 110]) * 1e-9)
    out = compute_rwf(RwfConfig(pulse_shape="measured", cnr_gradient=(0.0,)), pulse)
    # -14.99 m; the 3 m-wide triangle's vertices fall between 0.1 m grid nodes: error < 1 mm
    assert out["zero_distance"] == pytest.approx(-k.SPEED_OF_LIGHT / 2 * 100e-9, abs=1e-3)


def test_sample_pulse_file():
    # make_pulse.py: two-sided Gaussian in time, rise 70 ns, decay 80 ns, peak at +5 ns; its mean
    # is 5 + sqrt(2/pi) * 10 = 12.98 ns -> z = -1.946 m; with the noise floor removed what is
    # left is 4 ns (0.6 m) sampling and the 3-sigma cut of the lobe's outer edges: < 2 cm
    ds = range_weighting_function(pulse_file=sample_file("rwf/pulse_example.csv"), fft_size=128)
    assert float(ds.zero_distance) == pytest.approx(-1.946, abs=0.02)
    assert float(ds.barycenter.sel(cnr_gradient=0.1)) > float(ds.zero_distance)


@pytest.mark.parametrize(
    ("text", "error", "pattern"),
    [
        ("time_ns,intensity\n0,1\n4,-0.5\n8,0.2\n", InputError,
         r"bad.csv: line 3, column 'intensity': expected a non-negative intensity; found '-0.5'"),
        ("time_ns,power\n0,1\n4,0.5\n8,0.2\n", MissingVariableError, r"bad.csv: line 1: column 'intensity'"),
        ("intensity\n1\n0.5\n0.2\n", MissingVariableError, r"bad.csv.*range_offset_<unit>"),
        ("", InputError, r"bad.csv: pulse file is empty"),
        ("# only a comment\n", InputError, r"bad.csv: pulse file is empty"),
        ("range_offset_m,intensity\n", InputError, r"bad.csv: expected at least 3 pulse samples.*found 0"),
        ("range_offset_m,intensity\n0,1\nx,1\n2,1\n", InputError,
         r"line 3, column 'range_offset_m': expected a number"),
        ("range_offset_K,intensity\n0,1\n1,1\n2,1\n", UnitError, r"column 'range_offset_K' has units 'K'"),
        ("range_offset_m,intensity\n0,1\n0,1\n2,1\n", InputError, r"distinct"),
        ("range_offset_m,intensity\n0,0\n1,0\n2,0\n", InputError, r"positive maximum"),
    ],
)
def test_bad_pulse_files_are_refused(tmp_path, text, error, pattern):
    path = write_csv(tmp_path / "bad.csv", text)
    with pytest.raises(error, match=pattern):
        read_pulse_csv(path)


def test_cli_bad_pulse_file_writes_nothing(tmp_path, capsys):
    path = write_csv(tmp_path / "bad.csv", "time_ns,intensity\n0,1\n4,-0.5\n8,0.2\n")
    out = tmp_path / "rwf.nc"
    assert main(["rwf", "--pulse-file", str(path), "-o", str(out)]) == 2
    assert "bad.csv: line 3, column 'intensity'" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv"]  # no output, no temp file


def test_units_are_checked_at_the_boundary():
    with pytest.raises(UnitError, match="argument 'pulse_length'"):
        range_weighting_function(pulse_length=25.0)
    with pytest.raises(UnitError, match="argument 'cnr_gradient' has units 'm s-1'"):
        range_weighting_function(cnr_gradient=Q_([0.1], "m/s"))
    with pytest.raises(InputError, match="synthetic pulses only"):
        range_weighting_function(pulse_file=sample_file("rwf/pulse_example.csv"), asymmetry=0.2)
    with pytest.raises(InputError, match="fft_size.*64 or 128.*found 100"):
        range_weighting_function(fft_size=100)
    # 1 km of pulse length is fine as long as the units convert
    ds = range_weighting_function(pulse_length=Q_(0.025, "km"), cnr_gradient=Q_([0.0], "dB m-1"))
    assert ds.attrs["pulse_length_fwhm_m"] == pytest.approx(25.0)


def test_artefact_follows_the_interface_and_passes_validate(tmp_path, capsys):
    out = tmp_path / "rwf.nc"
    argv = ["rwf", "--pulse-length", "25", "--asymmetry", "0.1", "--fft-size", "128", "-o", str(out)]
    assert main(argv) == 0
    assert "zero distance Zd" in capsys.readouterr().out
    ds = open_artefact(out, "rwf")
    assert ds.rwf.dims == ("range_offset", "cnr_gradient") and ds.rwf.attrs["units"] == "m-1"
    assert ds.barycenter.dims == ("cnr_gradient",) and ds.zero_distance.dims == ()
    assert ds.cnr_gradient.attrs["units"] == "dB m-1" and ds.range_offset.attrs["units"] == "m"
    assert ds.attrs["fft_size"] == 128 and ds.attrs["sampling_frequency_hz"] == 250e6
    assert float(ds.zero_distance) == pytest.approx(float(ds.barycenter.sel(cnr_gradient=0.0)))
    assert validate_dataset(ds, "rwf") == []
    for name, var in ds.data_vars.items():
        assert {"units", "long_name", "coverage_content_type"} <= set(var.attrs), name
    report = check_compliance(out)
    assert report.passed, report.failures
    assert sum("UDUNITS" in e for e in report.exceptions) == 1  # the dB m-1 of cnr_gradient only
    assert main(["rwf", "-o", str(out)]) == 2  # refuses to overwrite
    assert main(["rwf", "-o", str(out), "--overwrite", "--cnr-gradient", "0.02"]) == 0
    np.testing.assert_array_equal(xr.open_dataset(out).cnr_gradient, [0.0, 0.02])


def test_write_artefact_roundtrip(tmp_path):
    ds = range_weighting_function(cnr_gradient=Q_([-0.05, 0.0, 0.05], "dB m-1"))
    path = write_artefact(ds, tmp_path / "r.nc")
    back = open_artefact(path, "rwf")
    xr.testing.assert_allclose(back.rwf, ds.rwf)
    assert back.attrs["lidarcal_config"] == ds.attrs["lidarcal_config"]
