"""The main job: a whole calibration, bench to certificate, as one function.

:func:`calibrate` chains the stages exactly as a user would on the command line and writes
every artefact into one output directory::

    bench RTD + control log ──ingest──> cube.nc
    pulse file ───────────────────────> rwf.nc          (Eq. 1-2, Zd)
    conditions (real, extended) ──────> conditions.nc
    cube + rwf + conditions ──simulate─> simulated.nc   (virtual lidar vs virtual reference)
    Table 4 inputs ───────────────────> terms.nc        (Eqs. 6-11, per height)
    simulated ──────────────────────── > sensitivity_<variable>.nc (Eqs. 12-13)
    simulated + terms ────────────────> budget.nc       (§3.4, 0.5 m/s bins)
    everything ───────────────────────> certificate.nc + report.html + report.pdf

Every input defaults to the embedded sample data and can be replaced by the user's own file.
Outputs that already exist are refused before any work starts, unless ``overwrite``.
One line per finished stage is logged at INFO level on the ``lidarcal.pipeline`` logger (the
command line prints it on stderr).  :func:`calibrate` returns a :class:`CalibrationResult`
holding the path and the (re-read) dataset of every artefact::

    result = calibrate("run1", CalibrationConfig(periods=144, min_periods=3))
    result.datasets["budget"].sel(height=120).relative_uncertainty
"""

from __future__ import annotations

import logging
import os
import shutil
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from lidarcal.analysis.budget import (
    DEFAULT_CERTIFIED_RANGE,
    DEFAULT_MIN_PERIODS,
    DEFAULT_SIGNIFICANT_DIGITS,
    budget,
)
from lidarcal.analysis.rule import CertificationRule
from lidarcal.analysis.sensitivity import sensitivity
from lidarcal.analysis.sweep import analyse_sweep
from lidarcal.analysis.terms import PAPER_INPUTS, uncertainty_terms
from lidarcal.bench.formats import read_control_log
from lidarcal.bench.ingest import ingest
from lidarcal.campaign import DEFAULT_BASE_SEED, simulate_campaign
from lidarcal.campaign.adaptive import DEFAULT_MAX_REPLICAS, adaptive_replicas
from lidarcal.campaign.model_form import DEFAULT_PER_BIN, model_form_runs
from lidarcal.campaign.progress import Progress
from lidarcal.campaign.settings import Execution
from lidarcal.certificate import make_certificate
from lidarcal.certificate.admin import demonstration_reasons, issuer_problem
from lidarcal.certificate.document import seal_statement
from lidarcal.certificate.report import write_report
from lidarcal.certificate.seal import write_certificate
from lidarcal.certificate.signing import fingerprint, load_private_key
from lidarcal.conditions import SkippedPeriodsWarning, load_conditions, synthetic_conditions
from lidarcal.conditions.grid import sweep_conditions
from lidarcal.data import sample_file
from lidarcal.errors import InputError
from lidarcal.io import check_writable, open_artefact, write_artefact
from lidarcal.lidar import LidarModel
from lidarcal.provenance import contact_attributes, sha256, stamp
from lidarcal.readback import read_attr
from lidarcal.rwf import range_weighting_function
from lidarcal.units import Q_

__all__ = ["CalibrationConfig", "CalibrationResult", "calibrate", "sweep", "OUTPUT_NAMES", "DEFAULT_HEIGHTS"]

log = logging.getLogger(__name__)

#: Heights of the default run (m): the mast's 40/60/80 m plus the range a profiler calibrates.
DEFAULT_HEIGHTS = (40.0, 60.0, 80.0, 100.0, 120.0, 140.0, 160.0, 200.0)

#: File name of each artefact inside the output directory.
OUTPUT_NAMES = {
    "cube": "cube.nc",
    "rwf": "rwf.nc",
    "conditions": "conditions.nc",
    "simulated": "simulated.nc",
    "terms": "terms.nc",
    "budget": "budget.nc",
    "certificate": "certificate.nc",
    "report": "report.html",
    "report_pdf": "report.pdf",  # written by write_report beside report.html
}

#: Scratch directory (inside the output directory) for finished simulation chunks.
CHUNK_DIR = ".simulation-chunks"

SENSITIVITY_VARIABLES = ("wind_shear_exponent", "turbulence_intensity", "cnr_gradient")


@dataclass
class CalibrationConfig:
    """Everything that shapes a calibration run; recorded in the certificate.

    Paths left as ``None`` use the embedded sample data.  ``periods`` limits the number of
    10-minute periods taken from the start of the conditions record (``None`` = all).
    ``min_periods`` is the fewest distinct periods a certified wind-speed bin holds (its centre
    in ``certified_range``, m/s) and a sensitivity bin needs to enter the regression: one rule
    (docs/certificate.md); a short run (a few hundred periods) may need fewer than the default.
    ``significant_digits`` and ``max_replicas`` drive the adaptive Monte Carlo (JCGM 101 7.9,
    :mod:`lidarcal.campaign.adaptive`); ``coverage_interval`` chooses the Monte Carlo coverage
    interval of each bin (JCGM 101 7.7: ``"symmetric"`` or ``"shortest"``).  ``model_form_periods``
    is the most periods per (height, wind-speed bin) each model-form alternative re-simulates
    (:mod:`lidarcal.campaign.model_form`; 0: no model-form term).
    """

    bench_rtd: str | None = None
    bench_control: str | None = None
    cube: str | None = None
    rwf: str | None = None
    pulse_file: str | None = None
    conditions: str | None = None
    heights: tuple[float, ...] = DEFAULT_HEIGHTS
    periods: int | None = 2016
    base_seed: int = DEFAULT_BASE_SEED
    chunk: int = 64
    workers: int | None = None
    scheduler: str | None = None
    fft_size: int = 64
    min_periods: int = DEFAULT_MIN_PERIODS
    certified_range: tuple[float, float] = DEFAULT_CERTIFIED_RANGE
    significant_digits: int = DEFAULT_SIGNIFICANT_DIGITS
    max_replicas: int = DEFAULT_MAX_REPLICAS
    #: The Monte Carlo coverage interval (JCGM 101 7.7): "symmetric" or "shortest"
    coverage_interval: str = "symmetric"
    model_form_periods: int = DEFAULT_PER_BIN
    #: LOS error model (``LidarModel.los_noise_model``); None: the mixture when the cube has residuals
    los_noise_model: str | None = None
    #: ``LidarModel.reference_turbulence``; None: the model's default (``"pinned_u"``)
    reference_turbulence: str | None = None
    terms: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form, for provenance."""
        out = asdict(self)
        out["heights"] = list(self.heights)
        out["certified_range"] = list(self.certified_range)
        return out


def _terms_per_height(records: xr.Dataset, overrides: dict[str, Any]) -> xr.Dataset:
    """Table 4 terms at every simulated height, with that height's median shear exponent.

    Eq. 11 at each height with the campaign's median shear (Table 4 fixes 100 m and 0.2).
    """
    heights = np.asarray(records.height.values, dtype=float)
    alphas = [abs(float(np.nanmedian(records.wind_shear_exponent.sel(height=z).values))) for z in heights]
    inputs = {**PAPER_INPUTS, "height": Q_(heights, "m"), "shear_exponent": alphas, **overrides}
    return uncertainty_terms(Q_(np.arange(0.25, 40.01, 0.25), "m/s"), **inputs,
                             call=f"lidarcal calibrate (terms at {', '.join(f'{z:g}' for z in heights)} m, "
                                  "each height's median shear exponent)")


@dataclass(frozen=True)
class CalibrationResult:
    """What :func:`calibrate` wrote: the path and the dataset of every artefact.

    ``paths`` maps each artefact key (``cube``, ``rwf``, ``conditions``, ``simulated``,
    ``terms``, ``sensitivity_<variable>``, ``budget``, ``certificate``, ``report`` (HTML) and
    ``report_pdf`` (the certificate document)) to its file.  ``datasets`` maps the netCDF artefacts' keys to
    the dataset as read back from that file with :func:`lidarcal.io.open_artefact`.
    """

    paths: dict[str, Path]
    datasets: dict[str, xr.Dataset]

    def __repr__(self) -> str:
        outdir = self.paths["certificate"].parent
        return f"CalibrationResult(outdir={outdir}, datasets={sorted(self.datasets)})"


def _conditions(cfg: CalibrationConfig) -> tuple[xr.Dataset, dict]:
    if cfg.conditions is not None:
        path = Path(cfg.conditions)
        ds = load_conditions(path)
        if cfg.periods is not None:
            ds = ds.isel(time=slice(0, cfg.periods))
        return ds, {"conditions": path}
    path = sample_file("conditions/conditions.nc")
    with warnings.catch_warnings():  # gaps in the whole record; those used are reported later
        warnings.simplefilter("ignore", SkippedPeriodsWarning)
        base = load_conditions(path)
    n = base.sizes["time"] if cfg.periods is None else min(cfg.periods, base.sizes["time"])
    log.info("conditions: %d periods of the real brightwind sample (40/60/80 m) carried to %s m with "
             "each period's shear", n, ", ".join(f"{h:g}" for h in cfg.heights))
    ds = synthetic_conditions(n, cfg.heights, base=base, call="lidarcal calibrate")
    return ds, {}  # stamped by synthetic_conditions, with the sample in its provenance chain


def _check_issuer(cfg: CalibrationConfig, admin: Mapping[str, str], demonstration: bool) -> None:
    """Refuse, before any work, a run that would issue a certificate without an issuer."""
    if demonstration:
        return
    attrs = {**contact_attributes(), **admin}
    if attrs.get("institution") not in (None, "unspecified"):
        attrs.setdefault("laboratory_name", attrs["institution"])
    if attrs.get("creator_name") not in (None, "lidarcal"):
        attrs.setdefault("responsible_persons", attrs["creator_name"])
    problem = issuer_problem(attrs)
    if problem is None:
        return
    bench = [cfg.cube] if cfg.cube is not None else [cfg.bench_rtd, cfg.bench_control]
    given = [*bench, cfg.rwf or cfg.pulse_file, cfg.conditions]
    if any(path is None for path in given):
        return  # the embedded sample data: a demonstration
    records = [{"file": Path(p).name, "sha256": sha256(p)} for p in given if Path(p).is_file()]
    for path in (cfg.cube, cfg.rwf, cfg.conditions):  # artefacts: their own provenance chain counts too
        if path is not None and Path(path).is_file() and Path(path).suffix == ".nc":
            records.append(dict(open_artefact(path, load=False).attrs))
    if cfg.cube is None and cfg.bench_control is not None and Path(cfg.bench_control).is_file():
        records.append({"data_origin": read_control_log(cfg.bench_control).metadata.get("data_origin")})
    if not any(demonstration_reasons(rec) for rec in records) and not demonstration_reasons({}, records):
        raise InputError(problem)


def _retire_previous(paths: Mapping[str, Path], *, overwrite: bool) -> None:
    """Remove an earlier run's certificate and report before this run replaces their artefacts.

    Each removal is logged (WARNING) with the file's SHA-256, so the user knows what went.
    """
    if not overwrite:
        return  # existing outputs were refused before any work
    for key in ("certificate", "report", "report_pdf"):
        path = paths[key]
        if not path.is_file():
            continue
        digest = sha256(path)
        path.unlink()
        log.warning("removed the previous run's %s %s (sha256 %s) before writing this run's artefacts: it "
                    "was not built from them (this run's certificate is written last)", key, path, digest)


@dataclass(frozen=True)
class _Run:
    """What every stage of one :func:`calibrate` run shares: its settings, files and clock."""

    cfg: CalibrationConfig
    paths: dict[str, Path]
    overwrite: bool
    t0: float

    def done(self, key: str, what: str) -> None:
        """Log a finished stage: elapsed time, what it made, where."""
        log.info("[%6.1f s] %s: %s", time.perf_counter() - self.t0, what, self.paths[key])

    def publish(self, ds: xr.Dataset, key: str, kind: str) -> xr.Dataset:
        """Write ``ds`` as artefact ``key``; return it read back (its checksum then chains on)."""
        write_artefact(ds, self.paths[key], overwrite=self.overwrite)
        return open_artefact(self.paths[key], kind)

    @property
    def rule(self) -> CertificationRule:
        """The certification rule shared by the adaptive replicas and the budget."""
        cfg = self.cfg
        return CertificationRule(min_periods=cfg.min_periods, certified_range=tuple(cfg.certified_range),
                                 significant_digits=cfg.significant_digits,
                                 coverage_interval=cfg.coverage_interval)


def _output_paths(outdir: Path, *, overwrite: bool) -> dict[str, Path]:
    """Create ``outdir``; return every artefact's path, refusing existing ones unless ``overwrite``."""
    if outdir.exists() and not outdir.is_dir():
        raise InputError(f"{outdir}: output directory is a file; expected a directory (or a new name)")
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{outdir}: cannot create the output directory ({exc.strerror})") from None
    paths = {key: outdir / name for key, name in OUTPUT_NAMES.items()}
    for var in SENSITIVITY_VARIABLES:
        paths[f"sensitivity_{var}"] = outdir / f"sensitivity_{var}.nc"
    for path in paths.values():  # refuse before doing an hour of work
        check_writable(path, overwrite=overwrite)
    return paths


def _bench_cube(run: _Run) -> xr.Dataset:
    """Stage 1: the bench cube, the user's artefact or ingested from the bench files (not yet written)."""
    cfg = run.cfg
    if cfg.cube is not None:
        return open_artefact(cfg.cube, "bench_cube")
    rtd = cfg.bench_rtd or sample_file("bench/rtd.csv.gz")
    control = cfg.bench_control or sample_file("bench/control_log.csv")
    return ingest(rtd, control, call=f"lidarcal calibrate (bench ingest {Path(rtd).name})")


def _rwf(run: _Run) -> xr.Dataset:
    """Stage 2: the range-weighting function and Zd, given or from the pulse file (not yet written)."""
    cfg = run.cfg
    if cfg.rwf is not None:
        return open_artefact(cfg.rwf, "rwf")
    pulse = cfg.pulse_file or sample_file("rwf/pulse_example.csv")
    return range_weighting_function(pulse_file=pulse, fft_size=cfg.fft_size,
                                    call=f"lidarcal calibrate (rwf from {Path(pulse).name})")


def _conditions_artefact(run: _Run) -> xr.Dataset:
    """Stage 3: the conditions the Monte Carlo runs on (not yet written)."""
    cond, cond_inputs = _conditions(run.cfg)
    if read_attr(cond, "lidarcal_artefact") != "conditions":
        # a user's file that is not a lidarcal conditions artefact (a field campaign, a plain
        # input): stamped as this run's file, with the file in its provenance chain
        cond = stamp(cond, "conditions", title="Conditions simulated by lidarcal calibrate",
                     summary="10-minute conditions (lidarcal docs/contracts.md) used as Monte Carlo input.",
                     call="lidarcal calibrate",
                     input_datasets={role: open_artefact(p) for role, p in cond_inputs.items()})
    return cond


def _publish_inputs(run: _Run, cube: xr.Dataset, rwf: xr.Dataset, cond: xr.Dataset) -> tuple[xr.Dataset, ...]:
    """Write the three inputs of the simulation (read back: their checksums chain on)."""
    cube = run.publish(cube, "cube", "bench_cube")
    serial = read_attr(cube, "lidar_serial", kind="bench_cube")
    run.done("cube", f"bench cube ({int(cube.sample_count.sum())} samples, lidar {serial})")
    rwf = run.publish(rwf, "rwf", "rwf")
    run.done("rwf", f"range-weighting function (Zd = {float(rwf.zero_distance):+.3f} m)")
    write_artefact(cond, run.paths["conditions"], overwrite=run.overwrite)
    run.done("conditions", f"conditions ({cond.sizes['time']} periods x {cond.sizes['height']} heights)")
    return cube, rwf


def _simulate(run: _Run, cube: xr.Dataset, rwf: xr.Dataset, *,
              progress: Progress) -> tuple[xr.Dataset, xr.Dataset]:
    """Stage 4: the Monte Carlo records, with replicas until every certified value settles.

    Returns the records (read back) and the Table 4 terms (not yet written) the budget needs.
    """
    cfg, paths = run.cfg, run.paths
    model = LidarModel.from_artefacts(cube=cube, rwf=rwf, los_noise_model=cfg.los_noise_model)
    if cfg.reference_turbulence:
        model = model.replace(reference_turbulence=cfg.reference_turbulence)
    # finished chunks are kept here until the simulation completes, so a killed run re-started
    # with --overwrite resumes instead of starting again (chunk files are keyed by their inputs)
    workdir = paths["simulated"].parent / CHUNK_DIR
    workdir.mkdir(exist_ok=True)
    execution = Execution(chunk=cfg.chunk, scheduler=cfg.scheduler, workers=cfg.workers, workdir=workdir,
                          progress=progress)
    records = simulate_campaign(
        paths["conditions"], model, base_seed=cfg.base_seed, execution=execution.labelled("replica 0"),
        call="lidarcal calibrate (simulate)",
        inputs={"conditions": paths["conditions"], "cube": paths["cube"], "rwf": paths["rwf"]},
    )
    if serial := read_attr(cube, "lidar_serial", kind="bench_cube"):
        records.attrs["lidar_serial"] = serial
    if cfg.model_form_periods:  # the alternatives with replica 0's seeds: the budget's model_form term
        records = model_form_runs(records, paths["conditions"], model, per_bin=cfg.model_form_periods,
                                  wind_speeds=tuple(cfg.certified_range), base_seed=cfg.base_seed,
                                  execution=execution)
        log.info("[%6.1f s] model-form runs: %d alternatives, %d (period, height) samples each",
                 time.perf_counter() - run.t0, records.sizes.get("model_form_alternative", 0),
                 records.sizes.get("model_form_sample", 0))
    # replicas until every certified value settles (JCGM 101 7.9): the budget needs the terms
    terms = _terms_per_height(records, cfg.terms)
    records, _ = adaptive_replicas(
        records, paths["conditions"], model, terms=terms, max_replicas=cfg.max_replicas,
        base_seed=cfg.base_seed, execution=execution, rule=run.rule)
    write_artefact(records, paths["simulated"], overwrite=run.overwrite)
    shutil.rmtree(workdir)
    records = open_artefact(paths["simulated"], "simulated_rtd")
    replicas = 1 + (int(records["trial_replica"].max()) if "trial_replica" in records else 0)
    run.done("simulated", f"simulated records ({replicas} Monte Carlo replica(s), "
             f"{records.sizes.get('trial', 0)} further trials)")
    return records, terms


def _sensitivities(run: _Run, records: xr.Dataset) -> dict[str, xr.Dataset]:
    """Stage 5b: the sensitivity to each variable (Eqs. 12-13) a regression can be fitted for."""
    sens = {}
    for var in SENSITIVITY_VARIABLES:
        key = f"sensitivity_{var}"
        try:
            ds = sensitivity(records, var, min_periods=run.cfg.min_periods,
                             call=f"lidarcal calibrate (sensitivity {var})")
        except InputError as exc:
            # a short run, or a site where the variable hardly varies, leaves too few full bins
            # for a regression: the certificate then carries no sensitivity to this variable
            log.warning("sensitivity to %s not computed, so the certificate has none: %s", var, exc)
            path = run.paths.pop(key)
            if run.overwrite and path.exists():
                path.unlink()  # a previous run's file would contradict this certificate
            continue
        sens[var] = run.publish(ds, key, "sensitivity")
        run.done(key, f"sensitivity to {var}")
    return sens


def _issue(run: _Run, cert: xr.Dataset, signer: Any, signing_key: str | os.PathLike | None) -> None:
    """Stage 6: the report, then the certificate.

    The certificate is the last file written, so that one present always belongs to the
    artefacts beside it.
    """
    # the document states the seal the certificate gets when it is written, just below
    public = f"{signing_key}.pub" if signer else None
    written = write_report(run.paths["report"], certificate=cert, overwrite=run.overwrite,
                           seal=seal_statement(fingerprint(signer) if signer else None,
                                               run.paths["certificate"].name, public))
    run.done("report", "HTML report (interactive plots)")
    run.done("report_pdf", f"certificate document ({written['pages']} pages, A4)")
    write_certificate(cert, run.paths["certificate"], overwrite=run.overwrite, signing_key=signer)
    run.done("certificate", f"calibration certificate (check with: lidarcal verify {run.paths['certificate']}"
             + (f" --public-key {public})" if signer else ")"))


def calibrate(
    outdir: str | os.PathLike = "lidarcal-output",
    config: CalibrationConfig | None = None,
    *,
    overwrite: bool = False,
    progress: Any = False,
    signing_key: str | os.PathLike | None = None,
    admin: Mapping[str, str] | None = None,
    demonstration: bool = False,
) -> CalibrationResult:
    """Run the whole calibration; return the path and dataset of every artefact written.

    Parameters
    ----------
    outdir : path
        Output directory (created if missing).
    config : CalibrationConfig, optional
        Inputs and settings; defaults to the embedded sample data.
    overwrite : bool
        Replace existing outputs; otherwise existing files are refused before any work.
    progress : bool, str or Progress
        How the simulation reports its progress (:class:`lidarcal.campaign.progress.Progress`): True
        a tqdm bar on stderr, ``"lines"`` a line every 30 s on the ``lidarcal.campaign.progress``
        logger (periods done, time left), False nothing.
    signing_key : path, optional
        Ed25519 private key (``lidarcal keygen``) signing the certificate's seal; read before
        any work.  Not part of the configuration: it changes who vouches, not the numbers.
    admin : mapping, optional
        Administrative data of the certificate (:func:`lidarcal.certificate.admin.load_admin`).
    demonstration : bool
        Force the demonstration status.  Without it a run on anything but the sample data or a
        simulated bench run issues the certificate, which needs an issuer (laboratory and
        responsible person: the contact options or ``admin``); that is checked before any work.

    Returns
    -------
    CalibrationResult
        ``.paths`` and ``.datasets`` of every artefact.  Each finished stage is also logged at
        INFO level on the ``lidarcal.pipeline`` logger.
    """
    cfg = config or CalibrationConfig()
    created = not Path(outdir).exists()
    paths = _output_paths(Path(outdir), overwrite=overwrite)
    signer = load_private_key(signing_key) if signing_key is not None else None
    _check_issuer(cfg, admin or {}, demonstration)
    run = _Run(cfg, paths, overwrite, time.perf_counter())
    # Every input is read and checked before anything is written (or removed): a conditions
    # file that is not one must not leave this run's cube and RWF behind.
    try:
        cube, rwf, cond = _bench_cube(run), _rwf(run), _conditions_artefact(run)  # 1-3.
    except BaseException:
        if created and not any(Path(outdir).iterdir()):
            Path(outdir).rmdir()  # the directory this run made for nothing
        raise
    # A certificate (and the report showing it) from an earlier run in this directory would sit
    # beside artefacts it was not built from, still verifying, if this run stopped half-way:
    # remove it before the first new artefact is published; this run's is written last.
    _retire_previous(paths, overwrite=overwrite)

    # Each artefact is written, then read back with open_artefact: downstream stages then
    # record the checksum of the file on disk as their input (the certificate's chain).
    cube, rwf = _publish_inputs(run, cube, rwf, cond)  # 1. bench cube, 2. RWF and Zd, 3. conditions
    records, terms = _simulate(run, cube, rwf, progress=Progress.of(progress))  # 4. Monte Carlo
    # 5. Table 4 terms, sensitivities, budget
    terms = run.publish(terms, "terms", "uncertainty_terms")
    run.done("terms", "uncertainty terms not modelled by Monte Carlo (Table 4)")
    sens = _sensitivities(run, records)
    bud = run.publish(budget(records, terms=terms, rule=run.rule, call="lidarcal calibrate (budget)"),
                      "budget", "uncertainty_budget")
    run.done("budget", "uncertainty budget (Monte Carlo approach)")
    # 6. report, then the certificate
    cert = make_certificate(budget=bud, sensitivities=sens, cube=cube, rwf=rwf, terms=terms,
                            records=records, config=cfg.to_dict(), call="lidarcal calibrate",
                            admin=admin, demonstration=demonstration)
    _issue(run, cert, signer, signing_key)
    datasets = {"cube": cube, "rwf": rwf, "conditions": open_artefact(paths["conditions"], "conditions"),
                "simulated": records, "terms": terms, **{f"sensitivity_{v}": d for v, d in sens.items()},
                "budget": bud, "certificate": open_artefact(paths["certificate"], "certificate")}
    return CalibrationResult(paths=paths, datasets=datasets)


def sweep(
    model: LidarModel,
    *,
    grid: Mapping[str, Any] | None = None,
    heights: Sequence[float] = (100.0,),
    repeats: int = 1,
    base_seed: int | None = None,
    execution: Execution | Mapping[str, Any] | None = None,
    call: str | None = None,
    inputs: Mapping[str, Any] | None = None,
) -> tuple[xr.Dataset, xr.Dataset]:
    """Classification-style sweep: simulate ``model`` on a full grid of conditions and analyse it.

    The grid is built by :func:`lidarcal.conditions.grid.sweep_conditions`, simulated by
    :func:`lidarcal.campaign.simulate_campaign` (seed ``base_seed``, default
    :data:`~lidarcal.campaign.DEFAULT_BASE_SEED`; where and how: ``execution``,
    :class:`~lidarcal.campaign.settings.Execution`) and analysed by
    :func:`lidarcal.analysis.sweep.analyse_sweep`.

    Returns
    -------
    (sweep, records)
        The ``sweep`` artefact and the ``simulated_rtd`` records it was computed from.
    """
    conditions = sweep_conditions(grid, heights=heights, repeats=repeats)
    records = simulate_campaign(
        conditions,
        model,
        base_seed=DEFAULT_BASE_SEED if base_seed is None else int(base_seed),
        execution=execution,
        inputs=dict(inputs or {}),
    )
    out = analyse_sweep(records, grid, repeats=repeats, call=call or "lidarcal.pipeline.sweep", inputs=inputs)
    return out, records
