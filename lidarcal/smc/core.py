"""``lidarcal smc``: the uncertainty of the calibrated unit's wind speed in a specific measurement campaign.

:func:`smc` takes a sealed certificate and the campaign's lidar files (``.sta``, or a
``conditions`` file read from them) and returns the ``smc`` artefact: per 10-minute period and
height the lidar's wind speed and its combined standard uncertainty, with the contributors kept
apart (``docs/smc.md``):

1. **checks before any work** — the certificate's seal (and signature with ``public_key``); the
   files' unit (``ID System``) is the certificate's item (no override); their cone angle is the
   calibrated one (a header ``NA`` takes the certificate's, :mod:`lidarcal.conditions.stafile`);
   a stated hybrid weight matches; at least two periods; at least one certified height (the
   others are reported as not covered, never interpolated);
2. ``calibration`` — the certificate's certified value at the period's height and wind-speed
   bin (:func:`lidarcal.smc.routes.calibration_part`, applied block by block in
   :mod:`lidarcal.smc.periods`);
3. ``environmental_iec`` — the 50-2 route (:func:`lidarcal.smc.routes.iec_route`);
4. ``environmental_monte_carlo`` — the Monte Carlo route (:func:`lidarcal.smc.montecarlo.monte_carlo_route`);
5. the user's terms (:mod:`lidarcal.smc.user_terms`).

The quoted ``uncertainty`` combines the calibration, the Monte Carlo route's environmental term
(the 50-2 route's when the Monte Carlo route is not run) and the user terms in quadrature; both
routes' combinations are kept (``uncertainty_iec_route``, ``uncertainty_monte_carlo_route``).
A demonstration certificate gives a demonstration result, said in the title, the summary and
``calibration_status``.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import dask
import numpy as np
import xarray as xr

from lidarcal.analysis.rule import CertificationRule
from lidarcal.campaign import DEFAULT_BASE_SEED
from lidarcal.campaign.settings import Execution
from lidarcal.conditions import load_conditions
from lidarcal.conditions.formats import read_lidar_files
from lidarcal.conditions.sta import measured_conditions
from lidarcal.conditions.stafile import CONE_ANGLE_TOLERANCE
from lidarcal.errors import InputError
from lidarcal.io import open_artefact, source_name
from lidarcal.provenance import lidar_serial
from lidarcal.readback import read_attr
from lidarcal.smc.certified import Certified, read_certified
from lidarcal.smc.montecarlo import MonteCarloRoute, monte_carlo_route
from lidarcal.smc.routes import IecRoute, envelope_bounds, iec_route, table_edges
from lidarcal.smc.subsample import DEFAULT_PERIODS_PER_BIN
from lidarcal.smc.user_terms import UserTerm, load_user_terms

__all__ = ["smc", "Campaign", "campaign_conditions", "HEIGHT_TOLERANCE", "BLOCK_PERIODS"]

log = logging.getLogger(__name__)

#: Periods per block: a campaign is read, computed and written 30 days of 10-minute periods at a
#: time (a year is 13 blocks; :mod:`lidarcal.smc.periods`).
BLOCK_PERIODS = 4320
#: A campaign height within this distance (m) of a certified height is that height.
HEIGHT_TOLERANCE = 1e-3
#: Budget contributors the Monte Carlo route carries over from the certificate (its trials cannot
#: give them: the model-form term needs the alternative models' runs of the calibration).
CARRIED = ("model_form",)


@dataclass
class Campaign:
    """Everything :func:`smc` computed before it is written (:func:`lidarcal.smc.dataset.smc_dataset`).

    Nothing here is per period but the campaign's conditions: each period's values are computed
    from them block by block (:func:`lidarcal.smc.periods.period_block`).
    """

    cert: Certified
    conditions: xr.Dataset  #: the campaign's conditions (time, height), canonical units
    inputs: dict[str, Path]  #: role -> file, recorded with its SHA-256
    source: str  #: how messages name the campaign's files
    height_index: np.ndarray  #: (height,) certified height of each campaign height, -1: none
    edges: np.ndarray  #: the campaign's wind-speed bin edges, m s-1 (:func:`.routes.table_edges`)
    #: the calibrated envelope (lows, highs), :func:`~lidarcal.smc.routes.envelope_bounds`
    envelope: tuple[list[np.ndarray], list[np.ndarray]]
    iec: IecRoute
    monte_carlo: MonteCarloRoute | None
    monte_carlo_note: str
    user_terms: list[UserTerm]
    settings: dict[str, Any] = field(default_factory=dict)


def _serial_check(cert: Certified, found: str | None, where: str) -> None:
    if not cert.serial:
        raise InputError(
            f"{cert.path}: the certificate names no calibrated item (global attributes "
            "'item_serial_number' and 'lidar_serial' missing), so the campaign's unit cannot be "
            "checked against it"
        )
    if (found or "").strip() != str(cert.serial).strip():
        raise InputError(
            f"{where}: expected the certificate's item {cert.serial!r} ({cert.path.name}); found "
            f"{found!r}: these files come from another unit, which this certificate does not "
            "calibrate"
        )


def _from_sta(
    cert: Certified, files: Sequence[str | os.PathLike], min_availability: float, allow_gaps: bool
) -> tuple[xr.Dataset, dict[str, Path], str]:
    if cert.cone_angle is None:
        raise InputError(
            f"{cert.path}: the certificate states no cone angle (no lidar model, no Table 4 terms), so the "
            f"files' cone angle cannot be checked against the calibrated one"
        )
    given_by = cert.cone_angle_origin
    parsed = read_lidar_files(
        files, allow_gaps=allow_gaps, cone_angle=cert.cone_angle, cone_angle_from=given_by
    )
    first = parsed[0]
    line = first.line_of("idsystem")
    where = (
        f"{first.path}: line {line} ('ID System={first.serial}')"
        if line
        else f"{first.path}: header (no 'ID System' key)"
    )
    _serial_check(cert, first.serial, where)
    ds = measured_conditions(parsed, min_availability, warn=True)
    inputs = {f"sta_{k}": Path(p) for k, p in enumerate(files, start=1)}
    return ds, inputs, ", ".join(Path(p).name for p in files)


def _from_conditions(cert: Certified, path: str | os.PathLike) -> tuple[xr.Dataset, dict[str, Path], str]:
    raw = open_artefact(path, load=False)  # read block by block (lidarcal.smc.periods)
    try:
        _check_configuration(cert, raw, source_name(path))
    except BaseException:
        raw.close()
        raise
    return raw, {"conditions": Path(path)}, Path(path).name


def _check_configuration(cert: Certified, raw: xr.Dataset, name: str) -> None:
    """Refuse a conditions file of another unit, cone angle or hybrid weight than the certificate's."""
    _serial_check(cert, lidar_serial(raw.attrs), f"{name}: global attribute 'lidar_serial'")
    cone = read_attr(raw, "lidar_cone_angle", kind="conditions", default=None, source=name)
    if cone is None:
        raise InputError(
            f"{name}: global attribute 'lidar_cone_angle' is missing; expected the campaign lidar's "
            f"cone angle ({cert.cone_angle:g} degree, the certificate's) to check the configuration"
        )
    _cone_check(cert, cone, f"{name}: global attribute 'lidar_cone_angle'")
    p = read_attr(raw, "lidar_hybrid_weight", kind="conditions", default=None, source=name)
    if p is not None and cert.hybrid_weight is not None:
        if abs(p - cert.hybrid_weight) > 1e-6:
            raise InputError(
                f"{name}: global attribute 'lidar_hybrid_weight': expected {cert.hybrid_weight:.6g} "
                f"(the certificate's lidar model); found {p:.6g}"
            )


def _with_time_bounds(ds: xr.Dataset, raw: xr.Dataset) -> xr.Dataset:
    """Return ``ds`` with the interval bounds of ``raw`` if it has them, else without ``bounds``."""
    if "time_bounds" in raw.variables and raw["time_bounds"].shape == (ds.sizes["time"], 2):
        bounds = raw["time_bounds"]
        ds = ds.assign_coords(time_bounds=(("time", "nv"), bounds.values, dict(bounds.attrs)))
        ds["time"].attrs["bounds"] = "time_bounds"
    else:
        ds["time"].attrs.pop("bounds", None)
    return ds


def _cone_check(cert: Certified, found: float, where: str) -> None:
    if cert.cone_angle is None:
        raise InputError(
            f"{cert.path}: the certificate states no cone angle (no lidar model, no Table 4 terms), so the "
            f"campaign's cone angle cannot be checked against the calibrated one"
        )
    if abs(found - cert.cone_angle) > CONE_ANGLE_TOLERANCE:
        raise InputError(
            f"{where}: expected the certificate's cone angle {cert.cone_angle:g} degree; found "
            f"{found:g} degree (another lidar configuration)"
        )


def campaign_conditions(
    cert: Certified,
    files: Sequence[str | os.PathLike] | None = None,
    *,
    conditions: str | os.PathLike | None = None,
    min_availability: float = 80.0,
    allow_gaps: bool = False,
) -> tuple[xr.Dataset, dict[str, Path], str]:
    """Return the campaign's conditions, checked against the certificate (unit, cone angle, hybrid weight).

    Returns (conditions in canonical units, input files by role, a name for messages).
    """
    if (files is None or not len(files)) == (conditions is None):
        raise InputError(
            "give the campaign's lidar files (FILE.sta ...) or a conditions file (--conditions), "
            "one of the two"
        )
    if conditions is not None:
        raw, inputs, source = _from_conditions(cert, conditions)
    else:
        raw, inputs, source = _from_sta(cert, list(files), min_availability, allow_gaps)
    # a conditions file is read lazily, a block of periods at a time (each read through a handle of
    # its own: the one opened here is closed once the checks are done); .sta files are parsed in memory
    block = BLOCK_PERIODS if conditions is not None else None
    try:
        ds = _with_time_bounds(load_conditions(raw, warn=False, block=block), raw)
    finally:
        raw.close()
    if ds.sizes["time"] < 2:
        raise InputError(
            f"{source}: dimension 'time': expected at least 2 ten-minute periods (a campaign); "
            f"found {ds.sizes['time']}"
        )
    return ds, inputs, source


def _heights(cert: Certified, ds: xr.Dataset, source: str) -> np.ndarray:
    z, certified = np.asarray(ds["height"].values, dtype=float), cert.heights
    idx = np.array(
        [
            int(np.argmin(np.abs(certified - h))) if np.min(np.abs(certified - h)) <= HEIGHT_TOLERANCE else -1
            for h in z
        ]
    )
    if (idx < 0).all():
        raise InputError(
            f"{source}: variable 'height': none of the campaign's heights "
            f"{[float(h) for h in z]} m is certified; expected some of the certificate's "
            f"{[float(h) for h in certified]} m ({cert.path.name}); heights are never interpolated"
        )
    if (idx < 0).any():
        log.warning(
            "heights %s m are not certified (%s certifies %s m): reported as not covered, never interpolated",
            [float(h) for h in z[idx < 0]],
            cert.path.name,
            [float(h) for h in certified],
        )
    return idx


def _covered_centres(cert: Certified, height_index: np.ndarray):
    """Return ``covered(i, centres)``: the bin centres the certificate certifies at simulated height i."""
    bud = cert.budget.transpose("height", "wind_speed", ...)
    certified = bud["bin_flag"].values == cert.certified_flag
    centres = np.asarray(bud["wind_speed"].values, dtype=float)
    rows = height_index[height_index >= 0]

    def covered(i: int, at: np.ndarray) -> np.ndarray:
        j = np.abs(np.asarray(at, dtype=float)[:, None] - centres[None, :]).argmin(axis=1)
        close = np.abs(centres[j] - at) < 1e-6
        return close & certified[rows[i], j]

    return covered


def _carried(cert: Certified, height_index: np.ndarray) -> xr.Dataset | None:
    """Return the certificate's relative contributions the trials cannot give, at the simulated heights.

    Today the ``model_form`` contributor (the alternative models' runs are the calibration's);
    None when the certificate's budget has none.
    """
    have = [str(c) for c in cert.budget["contributor"].values]
    names = [c for c in CARRIED if c in have]
    if not names:
        return None
    rows = height_index[height_index >= 0]
    return cert.budget[["relative_contribution"]].sel(contributor=names).isel(height=rows)


def smc(
    certificate: str | os.PathLike,
    files: Sequence[str | os.PathLike] | None = None,
    *,
    conditions: str | os.PathLike | None = None,
    public_key: str | os.PathLike | None = None,
    user_terms: str | os.PathLike | None = None,
    monte_carlo: bool = True,
    min_availability: float = 80.0,
    allow_gaps: bool = False,
    base_seed: int = DEFAULT_BASE_SEED,
    max_replicas: int | None = None,
    periods_per_bin: int | None = DEFAULT_PERIODS_PER_BIN,
    execution: Execution | Mapping[str, Any] | None = None,
) -> Campaign:
    """Compute the campaign uncertainty (module docstring); :func:`.dataset.smc_dataset` writes it.

    Parameters
    ----------
    certificate : path
        The sealed certificate of the campaign's lidar.
    files : sequence of path, optional
        The campaign's 10-minute statistics files (``.sta``, :mod:`lidarcal.conditions.formats`).
    conditions : path, optional
        Instead of ``files``: a ``conditions`` file read from them (``lidarcal conditions from-sta``).
    public_key : path, optional
        Require the certificate's signature by this Ed25519 public key.
    user_terms : path, optional
        YAML file of the user's own terms (:mod:`lidarcal.smc.user_terms`).
    monte_carlo : bool
        Run the Monte Carlo route (the default); without it the 50-2 route is quoted.
    min_availability, allow_gaps
        As for ``lidarcal conditions from-sta``.
    base_seed : int
        Base seed of the Monte Carlo route (docs/seeds.md).
    max_replicas : int, optional
        Most Monte Carlo replicas (default: the certificate's own ``monte_carlo_replicas``, at least 4).
    periods_per_bin : int or None
        Most periods the Monte Carlo route simulates per height and wind-speed bin, a stratified
        subsample whose tolerance the artefact states (:mod:`lidarcal.smc.subsample`); None: every
        period of the campaign.
    execution : Execution or mapping, optional
        Where and how the Monte Carlo route runs (:class:`~lidarcal.campaign.settings.Execution`).
    """
    execution = Execution.of(execution)
    if periods_per_bin is not None and int(periods_per_bin) < 2:
        raise InputError(f"periods_per_bin: expected at least 2 periods per bin (a spread needs two), "
                         f"or None for every period; found {periods_per_bin!r}")
    cert = read_certified(certificate, public_key=public_key)  # the seal first, before any number
    terms = load_user_terms(user_terms) if user_terms is not None else []
    ds, inputs, source = campaign_conditions(
        cert, files, conditions=conditions, min_availability=min_availability, allow_gaps=allow_gaps
    )
    inputs = {"certificate": cert.path, **inputs, **({"user_terms": Path(user_terms)} if user_terms else {})}
    height_index = _heights(cert, ds, source)
    ws = ds["wind_speed"]  # reductions in one pass over a lazily read campaign
    certified = ws.isel(height=np.flatnonzero(height_index >= 0))
    lowest, highest, total = dask.compute(ws.min(), ws.max(), certified.count())
    if not int(total):
        raise InputError(
            f"{source}: variable 'wind_speed': no period has a wind speed at a certified height "
            "(an empty campaign)"
        )
    edges = table_edges(cert.budget, np.array([float(lowest), float(highest)]))
    iec = iec_route(cert, ds, height_index)
    mc, note = None, "not run (monte_carlo=False, --no-monte-carlo)"
    replicas = (
        max(4, read_attr(cert.attrs, "monte_carlo_replicas", kind="certificate")) if max_replicas is None
        else int(max_replicas)
    )
    lacking = [cert.missing[k] for k in ("lidar_model", "terms") if k in cert.missing]
    if monte_carlo and lacking:  # an older certificate: say what it lacks, quote the 50-2 route
        note = f"not computed: the certificate cannot give it: {'; '.join(lacking)}"
        log.warning("%s: the Monte Carlo route is %s; the 50-2 route is quoted", cert.path, note)
        monte_carlo = False
    if not monte_carlo and iec.note != "computed":
        raise InputError(f"{cert.path}: neither environmental route can be computed: 50-2 route {iec.note}; "
                         f"Monte Carlo route {note}")
    if monte_carlo:
        model = cert.lidar_model()
        cov = _covered_centres(cert, height_index)
        mc = monte_carlo_route(
            ds.isel(height=np.flatnonzero(height_index >= 0)),
            model,
            terms=cert.terms,
            covered=cov,
            lookup_edges=edges,
            rule=CertificationRule(
                certified_range=read_attr(cert.budget, "certified_range_m_s", kind="uncertainty_budget"),
                significant_digits=read_attr(cert.attrs, "monte_carlo_significant_digits",
                                             kind="certificate"),
                coverage_factor=read_attr(cert.budget, "coverage_factor", kind="uncertainty_budget"),
            ),
            max_replicas=replicas,
            base_seed=int(base_seed),
            periods_per_bin=None if periods_per_bin is None else int(periods_per_bin),
            execution=execution,
            carried=_carried(cert, height_index),
        )
        sampled = mc.simulated
        total = int(total)
        note = (f"run: {mc.replicas} replica(s), base seed {int(base_seed)}, "
                + ("every period" if periods_per_bin is None else
                   f"at most {int(periods_per_bin)} periods per height and wind-speed bin")
                + f" ({sampled} of {total} period-heights simulated)")
    settings = {
        "min_availability": float(min_availability),
        "allow_gaps": bool(allow_gaps),
        "monte_carlo": bool(monte_carlo),
        "base_seed": int(base_seed),
        "max_replicas": replicas,
        "monte_carlo_periods_per_bin": "all" if periods_per_bin is None else int(periods_per_bin),
        "simulate_options": execution.record(where=False),
        "user_terms": [t.describe() for t in terms],
    }
    return Campaign(
        cert=cert,
        conditions=ds,
        inputs=inputs,
        source=source,
        height_index=height_index,
        edges=edges,
        envelope=envelope_bounds(cert, height_index),
        iec=iec,
        monte_carlo=mc,
        monte_carlo_note=note,
        user_terms=terms,
        settings=settings,
    )


def settings_json(campaign: Campaign) -> str:
    """Return the settings as JSON text (recorded in the artefact)."""
    return json.dumps(campaign.settings, sort_keys=True)
