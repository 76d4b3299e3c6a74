"""Option groups shared by the subcommands: one spelling, one default and one check each.

Every command that runs simulations takes the same parallel options, every command that
configures the virtual lidar takes the same ``--cube``/``--rwf``, and so on.  Each function
here adds one argparse group to a subcommand's parser; the ``*_from_args`` helpers turn the
parsed options back into library keyword arguments.

* progress: a live bar when stderr is a terminal, else a line every ``--progress-interval``
  seconds (default 30: periods done, time left); ``--progress`` forces the bar, ``--no-progress``
  silences both (:class:`lidarcal.campaign.progress.Progress`).
* heights: ``--heights M [M ...]`` (metres).
* seed: ``--seed N``, default :data:`lidarcal.campaign.DEFAULT_BASE_SEED` (docs/seeds.md).
* numbers are checked at parse time by the ``type`` functions below (:func:`number`,
  :func:`positive`, :func:`nonnegative`, :func:`probability`, :func:`finite`,
  :func:`positive_int`, :func:`nonnegative_int`, :func:`positive_quantity`): ``--workers 0`` or
  ``--alpha 2`` is refused by argparse with exit 2 and a message naming the option.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from lidarcal.certificate.admin import load_admin, merge_admin
from lidarcal.provenance import ACDD_SPELLINGS, USER_ATTRIBUTES

__all__ = [
    "number",
    "finite",
    "positive",
    "nonnegative",
    "probability",
    "positive_int",
    "nonnegative_int",
    "positive_quantity",
    "add_parallel_options",
    "add_lidar_options",
    "add_los_noise_option",
    "add_reference_turbulence_option",
    "add_progress_option",
    "add_seed_option",
    "add_heights_option",
    "add_output_options",
    "add_contact_options",
    "add_overwrite_option",
    "add_admin_options",
    "admin_from_args",
    "progress_of",
    "execution_of",
    "rule_of",
]

#: Most significant digits ``--significant-digits`` accepts: what a float64 holds (numpy's
#: ``finfo(float).precision``); a certified value cannot settle beyond its own resolution.
MAX_SIGNIFICANT_DIGITS = int(np.finfo(np.float64).precision)
#: Most replicas ``--max-replicas`` accepts (the reason is in its message).
MAX_REPLICAS = 10_000

SCHEDULER_HELP = (
    "'processes' (default), 'threads', 'synchronous', 'local' (LocalCluster) or the address of a "
    "dask.distributed scheduler, e.g. tcp://127.0.0.1:8786"
)


def _interval(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {hi:g}"
    return "finite"


def number(option: str, *, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
           hi_open: bool = False, integer: bool = False, reason: str | None = None) -> Callable[[str], float]:
    """Return an argparse ``type`` for a finite number in a range, naming ``option`` when refused.

    ``lo``/``hi`` are the bounds (None: unbounded), ``lo_open``/``hi_open`` exclude them; with
    ``integer`` only whole numbers are accepted (``1e3`` is 1000) and an ``int`` is returned.  NaN
    and infinities are always refused.  ``reason`` says why the bounds are what they are; a refusal
    gives it, with what was wrong with the value.
    """
    bounds = _interval(lo, hi, lo_open, hi_open)
    bounds = "" if bounds == "finite" else f" {bounds}"
    what = f"a whole number{bounds}" if integer else f"a finite number{bounds}"
    why = f" ({reason})" if reason else ""

    def refuse(text: str, problem: str) -> argparse.ArgumentTypeError:
        return argparse.ArgumentTypeError(f"{option} expects {what}; got {text!r}: {problem}{why}")

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise refuse(text, "not a number") from None
        if not np.isfinite(value):
            raise refuse(text, "not finite")
        if integer:
            if not value.is_integer():
                raise refuse(text, "not a whole number")
            try:
                value = int(text)  # exact, however long
            except ValueError:
                value = int(value)  # written as a float: 1e3
        if lo is not None and (value < lo or (lo_open and value == lo)):
            raise refuse(text, "too small")
        if hi is not None and (value > hi or (hi_open and value == hi)):
            raise refuse(text, "too large")
        return value

    parse.__name__ = f"{option} value"
    return parse


def finite(option: str) -> Callable[[str], float]:
    """Return a ``type`` accepting any finite number (no NaN, no infinity)."""
    return number(option)


def positive(option: str) -> Callable[[str], float]:
    """Return a ``type`` accepting a finite number > 0."""
    return number(option, lo=0.0, lo_open=True)


def nonnegative(option: str) -> Callable[[str], float]:
    """Return a ``type`` accepting a finite number >= 0."""
    return number(option, lo=0.0)


def probability(option: str) -> Callable[[str], float]:
    """Return a ``type`` accepting a probability strictly between 0 and 1 (e.g. a false-alarm rate)."""
    return number(option, lo=0.0, hi=1.0, lo_open=True, hi_open=True)


def positive_int(option: str) -> Callable[[str], int]:
    """Return an argparse ``type`` accepting integers >= 1 and naming ``option`` otherwise."""
    return number(option, lo=1, integer=True)


def nonnegative_int(option: str) -> Callable[[str], int]:
    """Return a ``type`` accepting integers >= 0 (seeds, indices, counts that may be zero)."""
    return number(option, lo=0, integer=True)


def positive_quantity(option: str, unit: str | None = None) -> Callable[[str], str]:
    """Return a ``type`` accepting a quantity such as ``'0.5 m s-1'`` (or a number), finite and > 0.

    The text is returned unchanged (the library converts it); with ``unit`` it must convert to
    that unit.
    """

    def parse(text: str) -> str:
        from lidarcal.units import ureg  # deferred: the unit registry, built when a quantity is given

        try:
            q = ureg.Quantity(text.strip())
            magnitude = float(q.to(unit).magnitude) if unit and not q.dimensionless else float(q.magnitude)
        except Exception:  # pint raises many types for unparsable text
            raise argparse.ArgumentTypeError(
                f"{option} expects a quantity > 0{f' in {unit}' if unit else ''}, e.g. '0.5 m s-1'; "
                f"got {text!r}") from None
        if not (np.isfinite(magnitude) and magnitude > 0):
            raise argparse.ArgumentTypeError(f"{option} expects a quantity > 0; got {text!r}")
        return text

    parse.__name__ = f"{option} value"
    return parse


def add_parallel_options(parser: argparse.ArgumentParser, *, workdir: bool = True) -> argparse._ArgumentGroup:
    """``--scheduler``, ``--workers``, ``--chunk`` and (if ``workdir``) ``--workdir``."""
    g = parser.add_argument_group("parallel execution (the result does not depend on these)")
    g.add_argument("--scheduler", metavar="NAME|ADDRESS", help=SCHEDULER_HELP)
    g.add_argument("--workers", type=positive_int("--workers"), metavar="N",
                   help="local worker processes (default: CPU count)")
    g.add_argument("--chunk", type=positive_int("--chunk"), default=64, metavar="N",
                   help="periods per simulation task (default %(default)s)")
    if workdir:
        g.add_argument("--workdir", metavar="DIR", help="cache finished chunks here; rerun to resume")
    return g


def add_lidar_options(parser: argparse.ArgumentParser, *,
                      default: str = "the ideal lidar") -> argparse._ArgumentGroup:
    """``--cube`` and ``--rwf``: the bench cube and range-weighting function configuring the lidar."""
    g = parser.add_argument_group("virtual lidar")
    g.add_argument("--cube", metavar="CUBE.nc",
                   help=f"bench_cube artefact: LOS bias and noise (default: {default})")
    g.add_argument("--rwf", metavar="RWF.nc",
                   help=f"rwf artefact: range-weighting function (default: {default})")
    return g


def add_los_noise_option(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--los-noise mixture|residuals|gaussian``: the bench-calibrated lidar's LOS error model.

    Unset (``None``) means the mixture when the cube has measured residuals, Gaussian otherwise
    (``LidarModel.from_artefacts``).
    """
    from lidarcal.lidar.noise import LOS_NOISE_MODELS  # deferred: light CLI start

    parser.add_argument("--los-noise", choices=LOS_NOISE_MODELS, default=None,
                        help="LOS error of the bench-calibrated lidar: 'mixture' bad estimates at the rate "
                        "p_bad(CNR) fitted to the bench, otherwise a good residual of the bench bin; "
                        "'residuals' every residual of the bin resampled, bad estimates included (runs "
                        "before the mixture existed); 'gaussian' N(los_bias, los_std) after the outlier "
                        "rule (default: mixture when the cube has residuals; docs/method.md)")


def add_reference_turbulence_option(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--reference-turbulence pinned_u|pinned_uvw|free`` (``LidarModel.reference_turbulence``).

    Unset (``None``) keeps the model's own value (the default ``pinned_u`` for a new model, the
    recorded one for ``--model``).
    """
    from lidarcal.lidar.model import REFERENCE_TURBULENCE  # deferred: light CLI start

    parser.add_argument("--reference-turbulence", choices=REFERENCE_TURBULENCE, default=None,
                        help="what the virtual reference's turbulence is conditioned on: pinned_u (its "
                        "realised sigma_u is the period's TI*U, the rest Gaussian through the RWF; the "
                        "default), pinned_uvw (the engine's convention before this option: sigma_u and "
                        "sigma_v pinned, fixed amplitudes; reproduces earlier results), free (a "
                        "Gaussian process) or inferred_level (sigma_u pinned, the field's level unknown "
                        "given it); docs/validation.md")


def add_progress_option(parser: argparse.ArgumentParser) -> None:
    """``--progress`` / ``--no-progress`` and ``--progress-interval S`` (see :func:`progress_of`)."""
    from lidarcal.campaign.progress import PROGRESS_INTERVAL  # deferred: light CLI start

    parser.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None,
                        help="progress on stderr: --progress a live bar, --no-progress nothing (default: "
                        "the bar when stderr is a terminal, else a line every --progress-interval seconds "
                        "with the periods done and the time left)")
    parser.add_argument("--progress-interval", type=positive("--progress-interval"), metavar="S",
                        default=PROGRESS_INTERVAL,
                        help="seconds between two progress lines (default %(default)g)")


def progress_of(args: argparse.Namespace) -> Any:
    """Return the :class:`~lidarcal.campaign.progress.Progress` the options ask for.

    ``--progress``: a bar; ``--no-progress``: nothing; neither: a bar when stderr is a terminal,
    else a line every ``--progress-interval`` seconds.
    """
    from lidarcal.campaign.progress import PROGRESS_INTERVAL, Progress  # deferred: light CLI start

    choice = getattr(args, "progress", None)
    interval = float(getattr(args, "progress_interval", PROGRESS_INTERVAL))
    if choice is None:
        return Progress("bar" if sys.stderr.isatty() else "lines", interval)
    return Progress("bar" if choice else "off", interval)


def add_seed_option(parser: argparse.ArgumentParser, *, default: int | None = None,
                    help: str = "base seed of the Monte Carlo; see docs/seeds.md") -> None:
    """``--seed N``; ``default`` None is the project's base seed."""
    if default is None:
        from lidarcal.campaign import DEFAULT_BASE_SEED  # deferred: light CLI start

        default = DEFAULT_BASE_SEED
    parser.add_argument("--seed", type=nonnegative_int("--seed"), default=default, metavar="N",
                        help=f"{help} (default %(default)s)")


def add_heights_option(parser: argparse.ArgumentParser, *, default: Sequence[float] | None = None,
                       help: str = "heights, m") -> None:
    """``--heights M [M ...]``."""
    parser.add_argument("--heights", type=positive("--heights"), nargs="+", metavar="M",
                        default=None if default is None else list(default), help=help)


def add_output_options(parser: argparse.ArgumentParser, metavar: str, *, help: str | None = None) -> None:
    """``-o/--output FILE`` (required), ``--overwrite`` and the contact options."""
    parser.add_argument("-o", "--output", required=True, metavar=metavar, help=help)
    add_overwrite_option(parser)
    add_contact_options(parser)


#: option -> (attribute recorded by lidarcal.provenance.stamp, environment variable)
CONTACT_OPTIONS = {
    "--institution": ("institution", "LIDARCAL_INSTITUTION"),
    "--creator": ("creator_name", "LIDARCAL_CREATOR"),
    "--creator-email": ("creator_email", "LIDARCAL_CREATOR_EMAIL"),
    "--creator-url": ("creator_url", "LIDARCAL_CREATOR_URL"),
    "--publisher": ("publisher_name", "LIDARCAL_PUBLISHER"),
    "--publisher-email": ("publisher_email", "LIDARCAL_PUBLISHER_EMAIL"),
    "--publisher-url": ("publisher_url", "LIDARCAL_PUBLISHER_URL"),
    "--site-latitude": ("site_latitude", "LIDARCAL_SITE_LATITUDE"),
    "--site-longitude": ("site_longitude", "LIDARCAL_SITE_LONGITUDE"),
}


def _degrees(lo: float, hi: float):
    def parse(text: str) -> str:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected decimal degrees in [{lo}, {hi}]; found {text!r}")
        return text
    return parse


class _AttributeAction(argparse.Action):
    """``--attribute NAME=VALUE``: one of :data:`lidarcal.provenance.USER_ATTRIBUTES`, as ``contact_NAME``."""

    def __call__(self, parser, namespace, values, option_string=None):
        name, sep, value = str(values).partition("=")
        name = name.strip()
        if not sep or not value.strip():
            parser.error(f"{option_string}: expected NAME=VALUE; found {values!r}")
        name = ACDD_SPELLINGS.get(name, name)  # acknowledgment (ACDD-1.1) is written acknowledgement
        if name not in USER_ATTRIBUTES:
            parser.error(f"{option_string}: {name!r} is not an attribute the user sets; "
                         f"expected one of {', '.join(USER_ATTRIBUTES)}")
        setattr(namespace, f"contact_{name}", value.strip())


def add_contact_options(parser: argparse.ArgumentParser) -> None:
    """``--institution``, ``--creator``, ``--creator-email`` ... recorded in every file written.

    Each defaults to its environment variable (``LIDARCAL_INSTITUTION`` ...), then to nothing
    (``creator_name`` "lidarcal", ``institution`` "unspecified").
    """
    g = parser.add_argument_group("who made the files (ACDD attributes of every file written; "
                                  "each defaults to its environment variable)")
    for option, (attr, env) in CONTACT_OPTIONS.items():
        site = attr.startswith("site_")
        g.add_argument(option, dest=f"contact_{attr}", metavar="DEGREES" if site else "TEXT",
                       type=_degrees(*((-90, 90) if "latitude" in attr else (-180, 180))) if site else str,
                       help=(f"site {attr[5:]}, decimal degrees WGS 84: geospatial_* attributes "
                             f"(default: ${env})") if site else f"{attr} attribute (default: ${env})")
    g.add_argument("--attribute", action=_AttributeAction, metavar="NAME=VALUE",
                   help="a further ACDD attribute only you know, recorded in every file written "
                        f"(repeatable; NAME one of {', '.join(USER_ATTRIBUTES)}; ACDD-1.3 spellings: "
                        "acknowledgment is accepted and written acknowledgement)")


#: option -> administrative attribute (lidarcal.certificate.admin; docs/certificate.md)
ADMIN_OPTIONS = {
    "--certificate-id": "certificate_id",
    "--item-manufacturer": "item_manufacturer",
    "--item-model": "item_model",
    "--item-serial-number": "item_serial_number",
    "--item-firmware": "item_firmware",
    "--laboratory-address": "laboratory_address",
    "--customer-name": "customer_name",
    "--customer-address": "customer_address",
    "--calibration-location": "calibration_location",
    "--method-reference": "method_reference",
}


def add_admin_options(parser: argparse.ArgumentParser) -> None:
    """``--admin ADMIN.yaml``, ``--demonstration`` and one option per administrative attribute.

    The laboratory is ``--institution`` and the first responsible person ``--creator`` (the
    contact options); options win over the file.
    """
    g = parser.add_argument_group(
        "certificate status and administrative data (docs/certificate.md); an issued certificate needs "
        "--creator and --institution or an --admin file naming the laboratory and responsible persons")
    g.add_argument("--admin", metavar="ADMIN.yaml",
                   help="administrative data: item, laboratory, responsible persons, customer, place, dates, "
                   "bench traceability, certificate id (keys in docs/certificate.md)")
    g.add_argument("--demonstration", action="store_true",
                   help="mark the certificate calibration_status = demonstration (automatic when an input is "
                   "lidarcal's sample data or a simulated bench run)")
    for option, attr in ADMIN_OPTIONS.items():
        g.add_argument(option, dest=f"admin_{attr}", metavar="TEXT",
                       help=f"{attr} attribute (default: from --admin"
                       f"{', or generated' if attr == 'certificate_id' else ''})")
    g.add_argument("--responsible-person", dest="admin_responsible_persons", action="append",
                   metavar="'NAME (ROLE)'",
                   help="a person responsible for the certificate (repeatable; default: --creator)")


def admin_from_args(args: argparse.Namespace) -> dict[str, str]:
    """Return the administrative data of ``--admin`` with the options' values on top (validated)."""
    given = load_admin(args.admin) if getattr(args, "admin", None) else {}
    options = {attr: getattr(args, f"admin_{attr}", None)
               for attr in [*ADMIN_OPTIONS.values(), "responsible_persons"]}
    return merge_admin(given, {k: v for k, v in options.items() if v}, source="options")


def add_overwrite_option(parser: argparse.ArgumentParser) -> None:
    """``--overwrite``: replace existing outputs (otherwise they are refused before any work)."""
    parser.add_argument("--overwrite", action="store_true", help="replace existing outputs")


def execution_of(args: argparse.Namespace) -> Any:
    """Return the :class:`~lidarcal.campaign.settings.Execution` the shared options ask for (once a command).

    ``--chunk``, ``--scheduler``, ``--workers``, ``--workdir`` (where the command has it), the
    progress options (:func:`progress_of`: one Progress for every set of tasks, so the dashboard
    is said once) and ``--timeout`` / ``--worker-timeout`` (``simulate``).
    """
    from lidarcal.campaign.settings import CONNECT_TIMEOUT, WORKER_TIMEOUT, Execution  # deferred: light start

    return Execution(chunk=args.chunk, scheduler=args.scheduler, workers=args.workers,
                     workdir=getattr(args, "workdir", None), progress=progress_of(args),
                     connect_timeout=getattr(args, "timeout", CONNECT_TIMEOUT),
                     worker_timeout=getattr(args, "worker_timeout", WORKER_TIMEOUT))


def rule_of(args: argparse.Namespace) -> Any:
    """Return the :class:`~lidarcal.analysis.rule.CertificationRule` the certification options ask for.

    ``--min-periods``, ``--certified-range``, ``--significant-digits``, ``--coverage-interval``
    and (``budget``) ``--coverage-factor``; an option a command lacks keeps the rule's default.
    """
    from lidarcal.analysis.rule import CertificationRule  # deferred: light CLI start

    given = {"min_periods": getattr(args, "min_periods", None),
             "certified_range": getattr(args, "certified_range", None),
             "significant_digits": getattr(args, "significant_digits", None),
             "coverage_factor": getattr(args, "coverage_factor", None),
             "coverage_interval": getattr(args, "coverage_interval", None)}
    if given["certified_range"] is not None:
        given["certified_range"] = tuple(given["certified_range"])
    return CertificationRule(**{k: v for k, v in given.items() if v is not None})


def add_certification_options(parser: argparse.ArgumentParser) -> None:
    """``--certified-range LO HI`` and ``--min-periods N``: the one rule for certified bins."""
    from lidarcal.analysis.budget import (  # deferred: light CLI start
        DEFAULT_CERTIFIED_RANGE,
        DEFAULT_MIN_PERIODS,
    )

    g = parser.add_argument_group("what is certified (docs/certificate.md)")
    g.add_argument("--certified-range", type=nonnegative("--certified-range"), nargs=2, metavar=("LO", "HI"),
                   default=list(DEFAULT_CERTIFIED_RANGE),
                   help="bin centres (m/s) a certified bin may have (default %(default)s)")
    g.add_argument("--min-periods", type=number("--min-periods", lo=2, integer=True),
                   default=DEFAULT_MIN_PERIODS, metavar="N",
                   help="fewest distinct 10-minute periods of the conditions in a certified bin "
                   "(default %(default)s; replicas add trials, not periods)")


def add_monte_carlo_options(parser: argparse.ArgumentParser, *, replicas: bool = True,
                            max_replicas: int | None = None) -> None:
    """``--significant-digits N``, ``--coverage-interval`` and (if ``replicas``) ``--max-replicas M``.

    JCGM 101 7.7 and 7.9; docs/seeds.md, docs/certificate.md.

    ``max_replicas`` is the default of ``--max-replicas`` (None: the calibration's default).
    """
    from lidarcal.analysis.budget import DEFAULT_SIGNIFICANT_DIGITS  # deferred: light CLI start

    g = parser.add_argument_group("numerical accuracy of the Monte Carlo (JCGM 101 7.9)")
    g.add_argument("--significant-digits", type=number(
                       "--significant-digits", lo=1, hi=MAX_SIGNIFICANT_DIGITS, integer=True,
                       reason=f"a certified value is a float64, which holds {MAX_SIGNIFICANT_DIGITS} "
                       "significant decimal digits: no number of replicas settles more"),
                   default=DEFAULT_SIGNIFICANT_DIGITS, metavar="N",
                   help="significant digits (of each bin's expanded uncertainty U) every certified value "
                   "must settle to (default %(default)s)")
    g.add_argument("--coverage-interval", choices=("symmetric", "shortest"), default="symmetric",
                   help="the Monte Carlo 95 %% coverage interval of each bin (JCGM 101 7.7): "
                   "probabilistically symmetric (default) or the shortest")
    if replicas:
        from lidarcal.campaign.adaptive import DEFAULT_MAX_REPLICAS  # deferred: light CLI start

        default = DEFAULT_MAX_REPLICAS if max_replicas is None else int(max_replicas)
        g.add_argument("--max-replicas", type=number(
                           "--max-replicas", lo=1, hi=MAX_REPLICAS, integer=True,
                           reason="the records keep every replica's values of each period and height, so "
                           "memory grows with them, while the tolerance falls only as 1/sqrt(replicas): "
                           f"{MAX_REPLICAS} replicas make it 100 times smaller than one replica's spread"),
                       default=default,
                       metavar="M", help="most replicas (re-simulations of the unsettled bins' periods, "
                       "replica 0 included) before the run stops unsettled (default %(default)s; 1: no "
                       "replica)")
