"""LOS noise resampled from the bench bins' measured residuals (issue 12 §6).

References are independent of the resampler: residual sets written here with a known mixture
(Gaussian core + uniform bad estimates), the noise-free radial velocity of a period without
turbulence (TI 0, no shear) computed by hand from the beam geometry, brute-force loops over the
bench RTD, and SHA-256 digests of the Gaussian noise as the code produced it before residual
resampling existed.
"""

import hashlib
import json

import numpy as np
import pytest
import xarray as xr
from scipy.stats import norm

from lidarcal.bench.kernels import pad_groups
from lidarcal.bench.simulator import simulate_run
from lidarcal.campaign import simulate_campaign
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import synthetic_conditions
from lidarcal.diagnose import corrected_model
from lidarcal.errors import InputError, MissingVariableError
from lidarcal.io import open_artefact, write_artefact
from lidarcal.lidar import LidarModel, NoiseTable, simulate_period
from lidarcal.schema import validate_dataset
from lidarcal.units import ureg

CNR = np.arange(-28.0, -4.0, 2.0)
VEL = np.arange(-18.0, 19.0, 1.0)
SHAPE = (5, CNR.size, VEL.size)
CONE = np.radians(28.0)


def hand_cube(residuals=None):
    """A bench_cube with smooth bias/std; ``residuals`` (5, 12, 37, n) NaN-padded, or None (old cube)."""
    _, c, v = np.meshgrid(np.arange(5), CNR, VEL, indexing="ij")
    bias = 0.01 * v / 18.0 + 0.002 * (c + 17.0) + 0.003
    std = 0.05 + 0.02 * (-6.0 - c) / 2.0 + 0.001 * np.abs(v)
    dims = ("los", "cnr", "velocity")
    ds = xr.Dataset(
        {"los_bias": (dims, bias, {"units": "m s-1"}), "los_std": (dims, std, {"units": "m s-1"}),
         "sample_count": (dims, np.full(SHAPE, 150, np.int32), {"units": "1"})},
        coords={"los": ["0", "90", "180", "270", "V"],
                "los_azimuth": ("los", [0.0, 90.0, 180.0, 270.0, 0.0], {"units": "degree"}),
                "los_elevation": ("los", [62.0, 62.0, 62.0, 62.0, 90.0], {"units": "degree"}),
                "cnr": ("cnr", CNR, {"units": "dB"}), "velocity": ("velocity", VEL, {"units": "m s-1"})},
        attrs={"lidarcal_artefact": "bench_cube", "lidarcal_source_file": "hand_cube.nc"})
    if residuals is not None:
        ds["los_residual"] = ((*dims, "sample"), np.asarray(residuals, float), {"units": "m s-1"})
    return ds


def mixture():
    """200 residuals: 180 Gaussian-core quantiles N(0.05, 0.1) + 20 bad estimates evenly in ±30 m/s."""
    core = 0.05 + 0.1 * norm.ppf((np.arange(180) + 0.5) / 180)
    bad = -30.0 + 60.0 * (np.arange(20) + 0.5) / 20
    return np.concatenate([core, bad])


def los_without_noise(U, n_times):
    """Noise-free LOS of a period without turbulence or shear, wind from north: -U sin φ cos(azimuth)."""
    beam = np.arange(n_times) % 4
    return -U * np.sin(CONE) * np.cos(np.radians(90.0 * beam)), beam


def run_los(model, *, cnr=-20.0, U=8.0, periods=10, ti=0.0, alpha=0.0, gradient=0.0, height=100.0):
    out = []
    for k in range(periods):
        r = simulate_period(model, heights=[height], wind_speed=U, wind_from_direction=0.0, cnr=cnr,
                            turbulence_intensity=ti, wind_shear_exponent=alpha, cnr_gradient=gradient,
                            seed=(7, k), return_los=True)
        out.append(r["los"][0])
    return np.concatenate(out), r


def test_resampled_errors_reproduce_the_measured_mixture():
    values = mixture()
    model = LidarModel.from_artefacts(cube=hand_cube(np.broadcast_to(values, (*SHAPE, values.size))),
                                      los_noise_model="residuals")
    assert model.los_noise_model == "residuals" and model.noise_table.has_residuals
    los, _ = run_los(model, periods=10)
    truth, _ = los_without_noise(8.0, 600)
    err = los - np.tile(truth, 10)
    n = err.size
    # every error is one of the bench residuals (up to rounding of los_true + r - los_true)
    assert np.abs(err[:, None] - values[None, :]).min(axis=1).max() < 1e-9
    # bad-estimate fraction: exactly 10 % in the set; binomial standard deviation sqrt(0.09 / n) = 0.0039
    # for n = 6000, 5 of them (false alarm 6e-7)
    assert abs(np.mean(np.abs(err) > 1.0) - 0.1) < 5 * np.sqrt(0.09 / n)
    # the whole distribution (Dvoretzky-Kiefer-Wolfowitz, any distribution, discrete included):
    # P(sup |F_n - F| > eps) <= 2 exp(-2 n eps^2) = 1e-6 for eps = 0.035
    grid = np.linspace(-31, 31, 2001)
    exact = (values[None, :] <= grid[:, None]).mean(axis=1)
    empirical = (err[None, :] <= grid[:, None]).mean(axis=1)
    assert np.abs(empirical - exact).max() < np.sqrt(np.log(2 / 1e-6) / (2 * n))
    # the Gaussian option from the same cube never produces a bad estimate (sigma <= 0.35 m/s)
    gauss, _ = run_los(LidarModel.from_artefacts(cube=hand_cube(np.broadcast_to(values, (*SHAPE, 200))),
                                                 los_noise_model="gaussian"), periods=2)
    assert np.abs(gauss - np.tile(truth, 2)).max() < 2.0


def test_bin_is_chosen_with_its_bilinear_weight():
    # one residual per bin encoding the bin: 100 * LOS row + CNR index + 0.01 * velocity index
    row, ci, vi = np.meshgrid(np.arange(5), np.arange(CNR.size), np.arange(VEL.size), indexing="ij")
    code = (100.0 * row + ci + 0.01 * vi)[..., None]
    model = LidarModel.from_artefacts(cube=hand_cube(code), los_noise_model="residuals")
    los, _ = run_los(model, cnr=-21.5, periods=20)
    truth, beam = los_without_noise(8.0, 600)
    err = los - np.tile(truth, 20)
    beam = np.tile(beam, 20)
    got_row = np.floor(err / 100.0 + 1e-9)
    got_ci = np.floor(err - 100.0 * got_row + 1e-9)
    got_vi = np.round((err - 100.0 * got_row - got_ci) / 0.01)
    np.testing.assert_array_equal(got_row, beam)  # the beam at azimuth 90 b draws from cube row b
    # CNR -21.5 dB lies a quarter of the way from the -22 dB bin (index 3) to the -20 dB bin (index 4)
    assert set(np.unique(got_ci)) == {3.0, 4.0}
    n = err.size  # 12000; binomial sd sqrt(0.25 * 0.75 / n) = 0.004, 5 sd
    assert abs(np.mean(got_ci == 4) - 0.25) < 5 * np.sqrt(0.1875 / n)
    # velocity: -8 sin 28° = -3.7558 m/s sits 0.2442 of the way from -4 m/s (index 14) to -3 (15);
    # +3.7558 sits 0.7558 from 3 (21) to 4 (22); the cross beams (0 m/s) are exactly on index 18
    s = 8.0 * np.sin(CONE)
    for b, lo, frac in ((0, 14, 4.0 - s), (2, 21, s - 3.0)):
        sel = got_vi[beam == b]
        assert set(np.unique(sel)) == {lo, lo + 1}
        assert abs(np.mean(sel == lo + 1) - frac) < 5 * np.sqrt(0.25 / sel.size)
    assert set(np.unique(got_vi[(beam == 1) | (beam == 3)])) == {18.0}


def test_velocity_outside_the_table_takes_the_edge_bin():
    row, ci, vi = np.meshgrid(np.arange(5), np.arange(CNR.size), np.arange(VEL.size), indexing="ij")
    model = LidarModel.from_artefacts(cube=hand_cube((ci + 0.01 * vi)[..., None]),
                                      los_noise_model="residuals")
    los, _ = run_los(model, U=45.0, cnr=-10.0, periods=1)  # 45 sin 28° = 21.1 m/s > 18.5
    truth, beam = los_without_noise(45.0, 600)
    err = los - truth
    np.testing.assert_allclose(err[beam == 0], 9 + 0.0, atol=1e-9)      # -21.1 m/s: bin -18 (index 0)
    np.testing.assert_allclose(err[beam == 2], 9 + 0.36, atol=1e-9)     # +21.1 m/s: bin 18 (index 36)


# Before residual resampling existed, the Gaussian noise of this hand cube gave these digests
# (SHA-256 of the float64 LOS array and of the three speeds; computed with commit 3bfbc6f).
GAUSSIAN_BEFORE = {
    (-20.0, 0.0, 0.0): (
        "d729a7deb478d4b41b7930e6a262bf50745d20deed682411c265dc59ff854bf6",
        "33ad8c5eb6fcb8ee4287645303db1e11e23c59ec2342ac6714336fd9d10a3f32"),
    (-17.3, 0.2, 0.01): (
        "d09bc9055cca3aa99a9b55152f4fc2605adc61d647b2d89ec50ebb036de3183b",
        "63b6d3e9c09f4af04cc8082e36ec3a7d151bcaccee1943c41547072af7a1dbef"),
}


def _digest(r):
    los = hashlib.sha256(np.ascontiguousarray(r["los"], dtype=np.float64).tobytes()).hexdigest()
    speeds = np.array([r[k][0] for k in ("lidar_wind_speed", "lidar_wind_speed_scalar",
                                         "lidar_wind_speed_vector")], dtype=np.float64)
    return los, hashlib.sha256(speeds.tobytes()).hexdigest()


@pytest.mark.parametrize("case", sorted(GAUSSIAN_BEFORE))
def test_gaussian_option_is_unchanged_bit_for_bit(case):
    cnr, alpha, gradient = case
    values = np.broadcast_to(mixture(), (*SHAPE, 200))
    new = LidarModel.from_artefacts(cube=hand_cube(values), los_noise_model="gaussian")
    old = LidarModel.from_artefacts(cube=hand_cube())  # a cube without residuals: Gaussian
    assert new.los_noise_model == old.los_noise_model == "gaussian"
    period = {"heights": [100.0], "wind_speed": 8.0, "wind_from_direction": 30.0, "turbulence_intensity": 0.0,
              "wind_shear_exponent": alpha, "cnr": cnr, "cnr_gradient": gradient,
              "seed": (20240101, 1_500_000_000), "return_los": True}
    for model in (new, old):
        assert _digest(simulate_period(model, **period)) == GAUSSIAN_BEFORE[case]
    assert _digest(simulate_period(LidarModel.ideal(), **period)) == IDEAL_BEFORE[case]


IDEAL_BEFORE = {
    (-20.0, 0.0, 0.0): (
        "9859c77d46b87e85d50ac4c9a176b935ad2d8a0f6109770579a6c6e09a468b06",
        "01b9bf4b28897dcc35860d263174d2f1f2f09e881c61faf4e0c2a8e905290e20"),
    (-17.3, 0.2, 0.01): (
        "44f5abf9bac76504fcc746f18d069606693c0a9f7f678cb25de175562ef5cf52",
        "818e0b0885af8c3b08b52cab40df3f422a489c520f040ce9bfda6067df09d3e4"),
}


def test_model_with_residuals_round_trips_through_json():
    row, ci, vi = np.meshgrid(np.arange(5), np.arange(CNR.size), np.arange(VEL.size), indexing="ij")
    values = np.full((*SHAPE, 3), np.nan)
    values[..., 0] = ci * 0.01
    values[::2, ..., 1] = -vi[::2] * 0.001  # bins with 1 and with 2 residuals
    cube = hand_cube(values)
    model = LidarModel.from_artefacts(cube=cube, los_noise_model="residuals")
    back = LidarModel.from_dict(json.loads(model.to_json()), cube=cube)
    assert back == model and back.los_noise_model == "residuals"
    assert LidarModel.from_dict(json.loads(json.dumps(model.to_dict(residuals=True)))) == model
    # beams 0 and 180 (cube rows 0, 2) have two residuals a bin, 90 and 270 one: 444 bins x (2 + 1 + 2 + 1)
    assert np.asarray(back.noise_table.residual_count).sum() == len(back.noise_table.residuals) == 444 * 6
    a, _ = run_los(model, periods=1)
    b, _ = run_los(back, periods=1)
    np.testing.assert_array_equal(a, b)
    # a model recorded before this option existed (no field, no residuals) reloads as Gaussian
    record = model.replace(noise_table=None, los_noise_model="gaussian").to_dict()
    del record["los_noise_model"]
    assert LidarModel.from_dict(record).los_noise_model == "gaussian"


def test_empty_bins_take_the_nearest_bins_residuals():
    values = np.full((*SHAPE, 1), np.nan)
    values[:, :, :, 0] = 0.5
    values[0, 5, 10:, 0] = np.nan                 # beam 0, CNR -18 dB, velocities -8...18 m/s empty
    values[0, 5, 9, 0] = -0.25                    # -9 m/s: the nearest populated bin in that row
    table = LidarModel.from_artefacts(cube=hand_cube(values), los_noise_model="residuals").noise_table
    count = np.asarray(table.residual_count)
    assert count.shape == (4, 12, 37) and (count == 1).all()
    r = np.asarray(table.residuals).reshape(4, 12, 37)
    # index-space nearest: (5, 10) -> (5, 9) at distance 1; (5, 20) -> (4, 20) or (6, 20) at distance 1
    assert r[0, 5, 10] == -0.25 and r[0, 5, 20] == 0.5


def test_old_cube_loads_gaussian_and_refuses_resampling():
    old = hand_cube()
    # not a full artefact (no provenance), but nothing is said about the missing residuals
    assert not any("los_residual" in p for p in validate_dataset(old, "bench_cube"))
    model = LidarModel.from_artefacts(cube=old)
    assert model.los_noise_model == "gaussian" and not model.noise_table.has_residuals
    with pytest.raises(MissingVariableError, match=r"hand_cube\.nc.*'los_residual'"):
        LidarModel.from_artefacts(cube=old, los_noise_model="residuals")


def test_bad_noise_options_and_tables_are_refused():
    with pytest.raises(InputError, match="los_noise_model must be one of"):
        LidarModel.from_artefacts(cube=hand_cube(), los_noise_model="poisson")
    with pytest.raises(InputError, match="needs a bench noise table with measured residuals"):
        LidarModel(los_noise_model="residuals")
    with pytest.raises(InputError, match="los_noise_model must be one of"):
        LidarModel(los_noise_model="uniform")
    cond = xr.Dataset(attrs={"lidarcal_source_file": "site.nc"})
    with pytest.raises(InputError, match="site.nc.*needs a bench cube"):
        LidarModel.from_attrs(cond, los_noise_model="residuals")
    table = LidarModel.from_artefacts(cube=hand_cube(np.zeros((*SHAPE, 1)))).noise_table
    fields = {"cnr": table.cnr, "velocity": table.velocity, "bias": table.bias, "std": table.std}
    with pytest.raises(InputError, match="residuals must be 1776 finite values"):
        NoiseTable(**fields, residual_count=table.residual_count, residuals=table.residuals[:-1])
    with pytest.raises(InputError, match="go together"):
        NoiseTable(**fields, residual_count=table.residual_count)
    zero = np.asarray(table.residual_count).copy()
    zero[0, 0, 0] = 0
    with pytest.raises(InputError, match="whole numbers >= 1"):
        NoiseTable(**fields, residual_count=zero, residuals=table.residuals[:-1])
    bad_dims = hand_cube().assign(los_residual=(("los", "cnr", "velocity"), np.zeros(SHAPE),
                                                {"units": "m s-1"}))
    with pytest.raises(InputError, match=r"hand_cube\.nc: variable 'los_residual' must have dims"):
        LidarModel.from_artefacts(cube=bad_dims)
    empty = np.full((*SHAPE, 2), np.nan)
    empty[1:] = 0.0
    with pytest.raises(InputError, match=r"'los_residual' is empty \(all NaN\)"):
        LidarModel.from_artefacts(cube=hand_cube(empty))


def test_pad_groups_by_hand():
    got = pad_groups(np.array([1.0, 2.0, 3.0, 4.0]), np.array([2, 0, 2, 2]), 4)
    expected = np.array([[2, np.nan, np.nan], [np.nan] * 3, [1, 3, 4], [np.nan] * 3])
    np.testing.assert_array_equal(got, expected)
    assert pad_groups(np.array([]), np.array([], dtype=int), 2).shape == (2, 1)


def test_ingest_keeps_every_candidate_residual(tmp_path):
    from lidarcal.bench.ingest import ingest

    # low CNR so that the MAD rule rejects bad estimates (p_bad 6 % at -23 dB, 25 % at -26 dB)
    run = simulate_run(seed=5, accumulation_time="40 s", los=("0", "90", "180", "270"), cnr=[-26.0, -22.0],
                       velocity=np.array([-3.0, 0.0, 4.0]) * ureg("m/s"))
    cube = ingest(run.rtd, run.control)
    assert int(cube.outlier_count.sum()) > 0
    res = cube.los_residual
    assert res.dims == ("los", "cnr", "velocity", "sample") and res.attrs["units"] == "m s-1"
    # brute force: per programmed row, the fed beam's records from 5 s after the start to the end
    rtd, ctl = run.rtd, run.control
    for i in range(len(ctl)):
        inside = (rtd.time_ns >= ctl.start_ns[i] + 5_000_000_000) & (rtd.time_ns < ctl.end_ns[i]) \
            & (rtd.los == ctl.los[i])
        expected = rtd.velocity[inside] - ctl.velocity[i]
        got = res.isel(los=int(ctl.los[i])).sel(cnr=ctl.cnr[i], velocity=ctl.velocity[i]).values
        np.testing.assert_array_equal(got[np.isfinite(got)], expected)  # time order, none dropped
        cell = cube.isel(los=int(ctl.los[i])).sel(cnr=ctl.cnr[i], velocity=ctl.velocity[i])
        assert int(cell.sample_count) + int(cell.outlier_count) == expected.size
    assert validate_dataset(cube, "bench_cube") == []
    path = write_artefact(cube, tmp_path / "cube.nc")
    back = open_artefact(path, "bench_cube")
    np.testing.assert_array_equal(back.los_residual.values, cube.los_residual.values)
    # the mixture fits p_bad over the CNRs the filtered lidar draws from: -26 and -22 dB unfiltered; with
    # the -23 dB filter only -22 dB is left, one CNR, so the default falls back to every residual
    assert LidarModel.from_artefacts(cube=back, cnr_threshold=None).los_noise_model == "mixture"
    assert LidarModel.from_artefacts(cube=back).los_noise_model == "residuals"


@pytest.mark.parametrize("command", ["calibrate", "simulate", "sweep"])
def test_los_noise_option(command, capsys):
    from lidarcal.cli import build_parser

    extra = [] if command == "calibrate" else ["-o", "x.nc"]
    parser = build_parser()
    assert parser.parse_args([command, *extra]).los_noise is None  # the cube decides
    assert parser.parse_args([command, *extra, "--los-noise", "gaussian"]).los_noise == "gaussian"
    with pytest.raises(SystemExit) as exc:
        parser.parse_args([command, *extra, "--los-noise", "poisson"])
    assert exc.value.code == 2 and "--los-noise" in capsys.readouterr().err


# -- the attribute form: residuals by digest, restored from the bench cube ----------------------------


def full_mixture_cube():
    """Every bin of every beam holds the 200-value mixture, shifted by 1e-3 m/s x the bin's flat index."""
    shift = 1e-3 * np.arange(np.prod(SHAPE)).reshape(SHAPE)[..., None]
    return hand_cube(mixture()[None, None, None, :] + shift)


def brute_force_digest(cube):
    """SHA-256 of (counts int64, values float64) written out by hand for a cube with full bins.

    Cube rows 0-3 are the beams at 0, 90, 180, 270°, its axes are already increasing and no bin
    is empty, so the table's bins are the cube's rows 0-3 in C order, 200 values each.
    """
    res = cube.los_residual.values[:4]
    counts = np.full(res.shape[:3], res.shape[3], dtype="<i8")
    return hashlib.sha256(counts.tobytes() + res.astype("<f8").tobytes()).hexdigest(), res.size


def los_digest(model, periods=2):
    los, _ = run_los(model, periods=periods)
    return hashlib.sha256(np.asarray(los, dtype="<f8").tobytes()).hexdigest()


def test_attributes_carry_a_digest_not_the_residuals():
    cube = full_mixture_cube()
    model = LidarModel.from_artefacts(cube=cube, los_noise_model="residuals")
    record = json.loads(model.to_json())
    table = record["noise_table"]
    assert "residuals" not in table and "residual_count" not in table
    sha, total = brute_force_digest(cube)
    assert (table["residuals_sha256"], table["residuals_total"]) == (sha, total) == (
        model.noise_table.residuals_sha256, 4 * 12 * 37 * 200)
    # size bound: the residuals cost only the digest, whatever their number: the record is the
    # Gaussian model's (same description) plus the two digest fields and "residuals" for "gaussian"
    gaussian = LidarModel.from_artefacts(cube=hand_cube(), los_noise_model="gaussian").replace(
        description=model.description)
    digest_fields = len(f', "residuals_sha256": "{sha}", "residuals_total": {total}')
    extra = digest_fields + len("residuals") - len("gaussian")
    assert len(model.to_json()) - len(gaussian.to_json()) == extra
    # a table without residuals is recorded with the four fields it had before residuals existed
    # a table without residuals is recorded by its bins and the digest of its bias and std
    assert sorted(json.loads(gaussian.to_json())["noise_table"]) == ["cnr", "table_sha256", "velocity"]
    assert len(model.to_json()) < 4000  # digests only: the values alone are 355,200 floats
    assert len(json.dumps(model.to_dict(residuals=True))) > 20 * len(model.to_json())


def test_cube_restores_the_same_draws():
    cube = full_mixture_cube()
    model = LidarModel.from_artefacts(cube=cube)
    bare = LidarModel.from_dict(model.to_json())
    assert bare.noise_table.needs_residuals and not bare.noise_table.has_residuals
    back = LidarModel.from_dict(model.to_json(), cube=cube)
    assert back == model and back.noise_table.has_residuals
    assert bare.with_residuals(cube) == model
    assert los_digest(back) == los_digest(model)
    # the Gaussian option draws from the table's bias and std, which the record also holds by digest
    gaussian = LidarModel.from_artefacts(cube=cube, los_noise_model="gaussian")
    with pytest.raises(InputError, match=r"records the bench noise table \(los_bias, los_std\) only by dig"):
        los_digest(bare.replace(los_noise_model="gaussian"))
    restored = bare.with_residuals(cube).replace(los_noise_model="gaussian")
    assert los_digest(restored) == los_digest(gaussian)  # bit for bit as built from the cube


def test_wrong_cube_is_refused_naming_both_digests():
    cube = full_mixture_cube()
    model = LidarModel.from_artefacts(cube=cube)
    other = cube.copy(deep=True)
    other["los_residual"].values[2, 3, 4, 5] = np.nextafter(other["los_residual"].values[2, 3, 4, 5], 1.0)
    found, _ = brute_force_digest(other)
    assert found != model.noise_table.residuals_sha256
    with pytest.raises(InputError) as exc:
        LidarModel.from_dict(model.to_json(), cube=other,
                             source="sim.nc: global attribute 'lidarcal_lidar_model'")
    message = str(exc.value)
    assert message.startswith("sim.nc: global attribute 'lidarcal_lidar_model': the bench cube hand_cube.nc")
    assert f"sha256 {found}" in message and f"expected sha256 {model.noise_table.residuals_sha256}" in message
    # a cube without residuals cannot restore them either
    with pytest.raises(MissingVariableError, match="los_residual"):
        LidarModel.from_dict(model.to_json(), cube=hand_cube())


def test_no_cube_refuses_to_draw_and_to_travel():
    model = LidarModel.from_artefacts(cube=full_mixture_cube())
    sha = model.noise_table.residuals_sha256
    bare = LidarModel.from_dict(model.to_json(), source="diag.nc: global attribute 'lidarcal_lidar_model'")
    expected = (r"diag\.nc: global attribute 'lidarcal_lidar_model' records the bench residuals only by "
                r"digest: no bench cube given; pass the cube the model was built from \(--cube\), its "
                rf"residuals have sha256 {sha} \(355200 values\)")
    with pytest.raises(InputError, match=expected):
        run_los(bare, periods=1)  # never a silent Gaussian
    with pytest.raises(InputError, match=expected):
        bare.to_dict(residuals=True)  # what simulate_campaign sends its workers
    # inconsistent records are refused
    fields = {k: getattr(model.noise_table, k) for k in ("cnr", "velocity", "bias", "std")}
    with pytest.raises(InputError, match="do not match residuals_sha256: expected sha256 0{64}, found"):
        NoiseTable(**fields, residual_count=model.noise_table.residual_count,
                   residuals=model.noise_table.residuals, residuals_sha256="0" * 64)
    with pytest.raises(InputError, match="residuals_sha256 must be 64 hexadecimal digits"):
        NoiseTable(**fields, residuals_sha256="abc", residuals_total=3)


def test_campaign_workers_resample_from_the_full_model():
    cube = full_mixture_cube()
    model = LidarModel.from_artefacts(cube=cube, cnr_threshold=None)
    cond = synthetic_conditions(6, (80, 100), seed=5)
    # processes: the task payloads are pickled to the workers
    ds = simulate_campaign(cond, model, heights=[100],
                           execution=Execution(scheduler="processes", workers=2, chunk=3))
    recorded = json.loads(ds.attrs["lidarcal_lidar_model"])["noise_table"]
    assert "residuals" not in recorded and recorded["residuals_sha256"] == model.noise_table.residuals_sha256
    assert len(ds.attrs["lidarcal_lidar_model"]) < 100_000 and len(ds.attrs["lidarcal_config"]) < 120_000
    names = ("wind_speed", "wind_from_direction", "turbulence_intensity", "wind_shear_exponent", "cnr",
             "cnr_gradient")
    for i in range(6):
        direct = simulate_period(model, heights=[100.0], **{k: cond[k].values[i, 1:] for k in names},
                                 seed=(20240101, int(ds.period_key.values[i])))
        # bit for bit
        got = ds.lidar_wind_speed.sel(height=100.0).values[i]
        np.testing.assert_array_equal(got, direct["lidar_wind_speed"][0])
    assert corrected_model(ds, cube=cube) == model
    with pytest.raises(InputError, match="no bench cube given"):
        simulate_campaign(cond, corrected_model(ds), execution=Execution(scheduler="synchronous"))
