"""Range-weighting function (RWF), CNR weighting and zero distance (paper §2.2, Eqs. 1–2).

:func:`range_weighting_function` builds the ``rwf`` artefact (CONTRIBUTING.md): the pulse
envelope convolved with the squared apodization window (Eq. 1), evaluated on a
``range_offset`` grid (m along the beam from the nominal range-gate centre, positive away
from the lidar) and normalised to unit integral (m-1); the same RWF multiplied by
``10^(CNR(z)/20)`` with ``CNR(z) = g z`` for every CNR gradient ``g`` (Eq. 2), renormalised;
the ``barycenter`` of each, and the ``zero_distance`` Zd: the barycenter at zero gradient,
i.e. how far beyond the nominal gate centre the lidar effectively measures (the offset the
lidar must subtract from its ranges).

Pulse shapes
------------
``gaussian``
    A Gaussian of FWHM ``pulse_length`` (the range-equivalent FWHM ``c tau / 2``; the
    paper's WindCube has 25 m).
``two_sided_gaussian``
    Same FWHM, different widths nearer (``1 - asymmetry``) and farther (``1 + asymmetry``)
    than the peak; ``asymmetry`` in (-1, 1), positive = long tail away from the lidar.
    Its barycenter lies ``sqrt(2/pi) (s_far - s_near)`` beyond the peak even without CNR
    gradient: an asymmetric pulse biases the measurement height (§2.2).
``measured``
    Samples from a bench recording, read by :func:`read_pulse_csv`.

Both synthetic shapes accept ``pulse_offset`` (m): the peak's distance beyond the nominal
gate centre, i.e. a zero-distance (timing) error.

Measured pulse file (CSV)
-------------------------
UTF-8 text; lines starting with ``#`` are comments; one header row; then one row per sample.
Columns (the unit is the suffix of the name):

``range_offset_m`` *or* ``time_ns`` (``time_s``, ``time_us`` ... any time unit)
    Sample position.  A range offset is used as is.  A time is the emission time relative to
    the instant the lidar's gating takes as the pulse centre; it is mapped to range offset
    ``-c t / 2`` (the later part of the pulse samples ranges nearer the lidar).
``intensity``
    Pulse intensity (power, linear, any scale); must be finite and >= 0.

Positions must be finite and distinct; at least three rows; other columns are ignored.
Any violation raises an :class:`~lidarcal.errors.InputError` naming the file, the column,
the (1-based, counting comments and header) line, what was expected and what was found.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.errors import InputError, MissingVariableError, UnitError
from lidarcal.provenance import stamp
from lidarcal.rwf import kernels as k
from lidarcal.schema import output_attrs
from lidarcal.units import cf_units, convert_values, to_magnitude

__all__ = [
    "PulseSamples",
    "RwfConfig",
    "read_pulse_csv",
    "compute_rwf",
    "range_weighting_function",
    "DEFAULT_CNR_GRADIENTS",
]

#: Default CNR gradients (dB m-1): -0.1 ... 0.1 in 0.01 steps (Figure 3 covers this span).
DEFAULT_CNR_GRADIENTS = np.round(np.linspace(-0.1, 0.1, 21), 10)
#: Extent, in standard deviations, beyond which a Gaussian pulse is treated as zero.
_PULSE_SIGMAS = 9.0
_POSITION = re.compile(r"^(range_offset|time)_([A-Za-z0-9]+)$")


@dataclass(frozen=True)
class PulseSamples:
    """A measured pulse: sample range offsets (m) and intensities (linear, >= 0)."""

    range_offset: np.ndarray
    intensity: np.ndarray
    source: str = "<pulse>"


@dataclass(frozen=True)
class RwfConfig:
    """Everything that determines an RWF, in SI units (recorded in the artefact's config)."""

    pulse_shape: str = "gaussian"  # gaussian | two_sided_gaussian | measured
    pulse_length: float = 25.0  # m, FWHM in range
    asymmetry: float = 0.0
    pulse_offset: float = 0.0  # m
    fft_size: int = 64
    sampling_frequency: float = 250e6  # Hz
    window_std_fraction: float = 0.2
    resolution: float = 0.1  # m
    half_width: float | None = None  # m; None = wide enough for pulse and window
    cnr_gradient: tuple[float, ...] = field(default_factory=lambda: tuple(DEFAULT_CNR_GRADIENTS))

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable form."""
        return {**asdict(self), "cnr_gradient": list(self.cnr_gradient)}


def _fail(path: str, line: int, column: str, expected: str, found: str) -> InputError:
    return InputError(f"{path}: line {line}, column {column!r}: expected {expected}; found {found}")


def read_pulse_csv(path: str | os.PathLike) -> PulseSamples:
    """Read a measured pulse file (format in the module docstring); nothing is guessed."""
    path = Path(path)
    name = str(path)
    if path.is_dir():
        raise InputError(f"{name}: pulse file path is a directory; expected a CSV file")
    if not path.is_file():
        raise InputError(f"{name}: pulse file not found")
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            lines = [(i + 1, row) for i, row in enumerate(csv.reader(fh))]
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(f"{name}: pulse file is not a UTF-8 CSV text file (netCDF or other binary?); "
                         f"expected a CSV with 'intensity' and a position column: {exc}") from None
    rows = [(n, r) for n, r in lines if r and not r[0].lstrip().startswith("#") and any(c.strip() for c in r)]
    if not rows:
        raise InputError(f"{name}: pulse file is empty; expected a header row and at least 3 samples")
    header_line, header = rows[0]
    header = [h.strip() for h in header]
    positions = [h for h in header if _POSITION.match(h)]
    if "intensity" not in header:
        raise MissingVariableError(
            f"{name}: line {header_line}: column 'intensity' is missing; found {header}")
    if len(positions) != 1:
        raise MissingVariableError(
            f"{name}: line {header_line}: expected exactly one position column 'range_offset_<unit>' or "
            f"'time_<unit>' (e.g. range_offset_m, time_ns); found {positions or header}")
    pos_col = positions[0]
    quantity, unit = _POSITION.match(pos_col).groups()
    expected_unit = "m" if quantity == "range_offset" else "s"
    ip, ii = header.index(pos_col), header.index("intensity")
    data = rows[1:]
    if len(data) < 3:
        raise InputError(f"{name}: expected at least 3 pulse samples after the header; found {len(data)}")
    pos = np.empty(len(data))
    inten = np.empty(len(data))
    for j, (n, r) in enumerate(data):
        if len(r) <= max(ip, ii):
            raise _fail(name, n, "intensity" if ii > ip else pos_col, f"{len(header)} fields", f"{len(r)}")
        for col, idx, out in ((pos_col, ip, pos), ("intensity", ii, inten)):
            try:
                out[j] = float(r[idx])
            except ValueError:
                raise _fail(name, n, col, "a number", repr(r[idx])) from None
            if not np.isfinite(out[j]):
                raise _fail(name, n, col, "a finite number", repr(r[idx]))
        if inten[j] < 0:
            raise _fail(name, n, "intensity", "a non-negative intensity", repr(r[ii]))
    pos = convert_values(pos, unit, expected_unit, where=f"{name}: column {pos_col!r}")
    z = pos if quantity == "range_offset" else k.time_to_range_offset(pos)
    if len(np.unique(z)) != len(z):
        raise InputError(f"{name}: column {pos_col!r}: expected distinct sample positions; found duplicates")
    if inten.max() <= 0:
        raise InputError(f"{name}: column 'intensity': expected a positive maximum; found all zeros")
    return PulseSamples(range_offset=z, intensity=inten, source=name)


def _pulse_extent(cfg: RwfConfig, measured: PulseSamples | None) -> tuple[float, float]:
    """Smallest and largest range offset where the pulse is non-negligible."""
    if measured is not None:
        return float(measured.range_offset.min()), float(measured.range_offset.max())
    near, far = k.two_sided_sigmas(cfg.pulse_length, cfg.asymmetry)
    return cfg.pulse_offset - _PULSE_SIGMAS * near, cfg.pulse_offset + _PULSE_SIGMAS * far


def _check(cfg: RwfConfig, measured: PulseSamples | None) -> None:
    if cfg.pulse_shape not in ("gaussian", "two_sided_gaussian", "measured"):
        raise InputError(f"pulse_shape: expected 'gaussian', 'two_sided_gaussian' or 'measured'; "
                         f"found {cfg.pulse_shape!r}")
    if (cfg.pulse_shape == "measured") != (measured is not None):
        raise InputError("pulse_shape 'measured' needs pulse samples and only it accepts them")
    if not cfg.pulse_length > 0:
        raise InputError(f"argument 'pulse_length': expected a positive FWHM; found {cfg.pulse_length} m")
    if not -1 < cfg.asymmetry < 1:
        raise InputError(f"argument 'asymmetry': expected a value in (-1, 1); found {cfg.asymmetry}")
    if cfg.fft_size not in (64, 128):
        raise InputError(f"argument 'fft_size': expected 64 or 128 points; found {cfg.fft_size}")
    for name in ("sampling_frequency", "window_std_fraction", "resolution"):
        if not getattr(cfg, name) > 0:
            raise InputError(f"argument {name!r}: expected a positive value; found {getattr(cfg, name)}")
    if not np.all(np.isfinite(cfg.cnr_gradient)):
        raise InputError(f"argument 'cnr_gradient': expected finite values; found {cfg.cnr_gradient}")


def compute_rwf(cfg: RwfConfig, measured: PulseSamples | None = None) -> dict[str, np.ndarray]:
    """Evaluate Eqs. 1–2 for ``cfg``; returns SI arrays (the kernel behind the artefact).

    Keys: ``range_offset`` (m), ``cnr_gradient`` (dB m-1, always containing 0), ``pulse``
    and ``apodization`` (peak 1), ``rwf`` (range_offset, cnr_gradient; m-1),
    ``barycenter`` (m), ``zero_distance`` (m) and ``rwf_fwhm`` (m, at zero gradient).
    """
    _check(cfg, measured)
    dr = k.range_sample_spacing(cfg.sampling_frequency)
    window_half = 0.5 * cfg.fft_size * dr
    lo, hi = _pulse_extent(cfg, measured)
    half_width = cfg.half_width or (max(abs(lo), abs(hi)) + window_half + 5 * cfg.resolution)
    z = k.range_grid(half_width, cfg.resolution)
    if cfg.half_width is not None and (lo - window_half < z[0] or hi + window_half > z[-1]):
        raise InputError(
            f"argument 'half_width': the RWF spans [{lo - window_half:.1f}, {hi + window_half:.1f}] m; "
            f"found a grid of only ±{cfg.half_width} m")
    if measured is not None:
        clean = k.remove_noise_floor(measured.range_offset, measured.intensity)
        if not np.nanmax(clean) > 0:
            found = "a constant intensity" if np.ptp(measured.intensity) == 0 else "no sample above the floor"
            raise InputError(
                f"{measured.source}: column 'intensity': expected a pulse above the noise floor; found "
                f"{found} ({measured.intensity.min():g} to {measured.intensity.max():g})")
        pulse = k.sampled_pulse(z, measured.range_offset, clean)
    else:
        pulse = k.two_sided_gaussian_pulse(z, cfg.pulse_length, cfg.asymmetry, cfg.pulse_offset)
    window = k.gaussian_window(z, cfg.fft_size, dr, cfg.window_std_fraction)
    rwf0 = k.rwf_from_pulse(pulse, window, cfg.resolution)
    grads = np.unique(np.concatenate([np.asarray(cfg.cnr_gradient, dtype=float), [0.0]]))
    rwf = k.cnr_weighted_rwf(rwf0, z, grads, cfg.resolution)
    edge = np.maximum(rwf[0], rwf[-1]) / rwf.max(axis=0)
    if np.any(edge > 1e-6):
        bad = grads[edge > 1e-6]
        raise InputError(
            f"argument 'cnr_gradient': gradients {bad.tolist()} dB m-1 push the weighted RWF to the edge "
            f"of the ±{z[-1]:.1f} m grid (edge/peak up to {edge.max():.2g}, expected < 1e-6); "
            "use smaller gradients or a larger half_width")
    bary = k.barycenter(rwf, z)
    i0 = int(np.flatnonzero(grads == 0.0)[0])
    return {
        "range_offset": z,
        "cnr_gradient": grads,
        "pulse": pulse,
        "apodization": window,
        "rwf": rwf,
        "barycenter": bary,
        "zero_distance": float(bary[i0]),
        "rwf_fwhm": k.full_width_half_maximum(rwf[:, i0], z),
    }


def _gradients(value: Any) -> tuple[float, ...]:
    if value is None:
        return tuple(DEFAULT_CNR_GRADIENTS)
    if hasattr(value, "units"):
        found = cf_units(value.units)
        if found != "dB m-1":
            raise UnitError(f"argument 'cnr_gradient' has units {found!r}; expected 'dB m-1'")
    mags = np.atleast_1d(to_magnitude(value, "dB m-1", name="cnr_gradient"))
    return tuple(float(g) for g in mags)


def _si(value: Any, default: float | None, unit: str, name: str) -> float | None:
    return default if value is None else float(to_magnitude(value, unit, name=name))


def range_weighting_function(
    *,
    pulse_length: Any = None,
    asymmetry: float = 0.0,
    pulse_offset: Any = None,
    pulse_file: str | os.PathLike | None = None,
    fft_size: int = 64,
    sampling_frequency: Any = None,
    window_std_fraction: float = 0.2,
    cnr_gradient: Any = None,
    resolution: Any = None,
    half_width: Any = None,
    call: str = "lidarcal.rwf.range_weighting_function",
) -> xr.Dataset:
    """Build the ``rwf`` artefact (Eqs. 1–2, barycenters and zero distance).

    Parameters
    ----------
    pulse_length : pint.Quantity, default 25 m
        FWHM of the pulse intensity in range (``c tau / 2``); ignored with ``pulse_file``.
    asymmetry : float, default 0
        ``(s_far - s_near) / (s_far + s_near)`` of a two-sided Gaussian pulse; 0 = Gaussian.
    pulse_offset : pint.Quantity, default 0 m
        Peak position of a synthetic pulse beyond the nominal gate centre (a Zd error).
    pulse_file : path, optional
        Measured pulse CSV (see module docstring); overrides the synthetic shape.
    fft_size : {64, 128}
        FFT length in samples; sets the apodization window's span.
    sampling_frequency : pint.Quantity, default 250 MHz
        Digitiser rate; one sample spans ``c / (2 f_s)`` (0.6 m at 250 MHz).
    window_std_fraction : float, default 0.2
        Standard deviation of the Gaussian window as a fraction of the FFT length.
    cnr_gradient : pint.Quantity in dB m-1, default -0.1 ... 0.1 in 0.01 steps
        Gradients of Eq. 2; 0 is always added (Zd and the virtual lidar use it).
    resolution : pint.Quantity, default 0.1 m
        Grid spacing of ``range_offset``.
    half_width : pint.Quantity, optional
        Half extent of the grid; by default just wide enough for pulse and window.
    call : str
        Recorded in the ``history`` attribute.

    Returns
    -------
    xarray.Dataset
        ``rwf`` artefact, stamped with provenance (config, input checksum).

    Examples
    --------
    >>> from lidarcal.units import Q_
    >>> ds = range_weighting_function(pulse_length=Q_(25, "m"), cnr_gradient=Q_([0.0], "dB m-1"))
    >>> abs(float(ds.zero_distance)) < 1e-9
    True
    """
    offset = _si(pulse_offset, 0.0, "m", "pulse_offset")
    if pulse_file is not None and (asymmetry != 0 or offset != 0):
        raise InputError(f"{pulse_file}: a measured pulse carries its own shape and timing; "
                         "'asymmetry' and 'pulse_offset' apply to synthetic pulses only (expected 0)")
    measured = read_pulse_csv(pulse_file) if pulse_file is not None else None
    if measured is not None:
        shape = "measured"
    else:
        shape = "gaussian" if asymmetry == 0 else "two_sided_gaussian"
    cfg = RwfConfig(
        pulse_shape=shape,
        pulse_length=_si(pulse_length, 25.0, "m", "pulse_length"),
        asymmetry=float(asymmetry),
        pulse_offset=offset,
        fft_size=int(fft_size),
        sampling_frequency=_si(sampling_frequency, 250e6, "Hz", "sampling_frequency"),
        window_std_fraction=float(window_std_fraction),
        resolution=_si(resolution, 0.1, "m", "resolution"),
        half_width=_si(half_width, None, "m", "half_width"),
        cnr_gradient=_gradients(cnr_gradient),
    )
    out = compute_rwf(cfg, measured)
    return _to_dataset(out, cfg, measured, pulse_file, call)


def _to_dataset(out: dict, cfg: RwfConfig, measured: PulseSamples | None, pulse_file: Any,
                call: str) -> xr.Dataset:
    dr = k.range_sample_spacing(cfg.sampling_frequency)
    context = dict(pulse_content="physicalMeasurement" if measured is not None else "modelResult",
                   pulse_shape=cfg.pulse_shape, fft_size=np.int32(cfg.fft_size),
                   window_std_fraction=cfg.window_std_fraction, window_length_m=cfg.fft_size * dr)
    dims = {"rwf": ("range_offset", "cnr_gradient"), "pulse": "range_offset", "apodization": "range_offset",
            "barycenter": "cnr_gradient", "zero_distance": (), "rwf_fwhm": ()}
    ds = xr.Dataset(
        {name: (var_dims, out[name], output_attrs("rwf", name, **context))
         for name, var_dims in dims.items()},
        coords={name: (name, out[name], output_attrs("rwf", name))
                for name in ("range_offset", "cnr_gradient")},
    )
    ds.attrs.update({
        "pulse_shape": cfg.pulse_shape,
        "fft_size": np.int32(cfg.fft_size),
        "sampling_frequency_hz": cfg.sampling_frequency,
        "range_sample_spacing_m": dr,
        "apodization_window_length_m": cfg.fft_size * dr,
        "apodization_std_fraction": cfg.window_std_fraction,
    })
    if measured is None:
        ds.attrs.update({"pulse_length_fwhm_m": cfg.pulse_length, "pulse_asymmetry": cfg.asymmetry,
                         "pulse_offset_m": cfg.pulse_offset})
    else:
        ds.attrs["pulse_file"] = Path(pulse_file).name
    shape = f"of FWHM {cfg.pulse_length:g} m" if measured is None else f"measured in {Path(pulse_file).name}"
    summary = (
        f"Range-weighting function of a pulsed Doppler lidar: {cfg.pulse_shape.replace('_', ' ')} pulse "
        f"{shape} convolved with the square of a Gaussian apodization window over {cfg.fft_size} FFT points "
        f"at {cfg.sampling_frequency / 1e6:g} MHz (Eq. 1), CNR-weighted for {len(out['cnr_gradient'])} "
        f"gradients (Eq. 2). Zero distance {out['zero_distance']:.4f} m, FWHM {out['rwf_fwhm']:.3f} m."
    )
    return stamp(ds, "rwf", title="Lidar range-weighting function and zero distance", summary=summary,
                 call=call, inputs={"pulse_file": pulse_file} if pulse_file is not None else None,
                 config=cfg.to_dict(),
                 keywords="Doppler lidar, range-weighting function, zero distance, pulse, apodization")
