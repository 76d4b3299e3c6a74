"""The ``lidarcal`` command line: thin wrappers over the library, one subcommand per stage.

Each subcommand lives in a small module exposing ``register(subparsers)``; the module's
handler parses arguments, calls the dataset-level function and writes the artefact.
Errors derived from :class:`~lidarcal.errors.LidarcalError`, and operating-system errors
(:class:`OSError`: disk full, permissions), are printed as one clear line (exit status 2);
anything else is a bug and shows its traceback.  The library reports its
progress through :mod:`logging` (``lidarcal.*`` loggers); the command prints those INFO
messages on stderr, so stdout carries only the command's result.  Shared options are
declared once in :mod:`lidarcal.cli.options`.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import shlex
import sys
import warnings
from collections.abc import Iterable, Sequence
from typing import NamedTuple

from lidarcal import __version__
from lidarcal.errors import LidarcalError


class Command(NamedTuple):
    """A subcommand: the module under ``lidarcal.cli`` that builds it, and its line in ``lidarcal --help``."""

    module: str
    help: str


#: Every subcommand, in the order ``lidarcal --help`` lists them.  A command's module (and the
#: library behind it) is imported only when that command is run, so ``lidarcal --help`` and a
#: light command such as ``lidarcal verify`` do not pay for the simulation engine's imports.
COMMANDS = {
    "calibrate": Command("calibrate", "run the whole calibration (default: embedded sample data)"),
    "bench": Command("bench", "fiber-optic bench (SAFO-MV): simulate, ingest, repeatability"),
    "rwf": Command("rwf", "range-weighting function and zero distance (Eqs. 1-2)"),
    "terms": Command("terms", "non-simulated uncertainty terms (Eqs. 6-11, Table 4)"),
    "conditions": Command("conditions", "check or generate 10-minute conditions inputs"),
    "field": Command("field", "build a field_campaign from lidar .sta files and a mast record"),
    "turbulence": Command("turbulence", "turbulence at a virtual lidar's sample points"),
    "simulate": Command("simulate", "simulate a campaign of 10-minute periods (virtual lidar vs reference)"),
    "sensitivity": Command("sensitivity", "environmental sensitivities (IEC 50-2, Eqs. 12-13)"),
    "budget": Command("budget", "uncertainty budget per height and wind-speed bin"),
    "sweep": Command("sweep", "maximum deviation and slopes over a full grid of conditions"),
    "certificate": Command("certificate", "bundle and seal a calibration certificate"),
    "dcc": Command("dcc", "export a certificate as a PTB Digital Calibration Certificate (XML), "
                   "signed with an X.509 key on request; check a signed one"),
    "verify": Command("verify", "check a certificate's integrity record, signature and schema"),
    "keygen": Command("keygen", "new Ed25519 key pair for signing certificates (KEY, KEY.pub)"),
    "table": Command("table", "IEC-style result table of a certificate or an smc artefact "
                     "(CSV, Markdown, HTML)"),
    "diagnose": Command("diagnose", "name the model effect that explains a field campaign's gap"),
    "diagnose-generate": Command("diagnose", "write a synthetic field campaign with a hidden effect"),
    "compare": Command("compare", "the field campaign's slopes and budget beside the virtual lidar's"),
    "smc": Command("smc", "the certificate applied to a measurement campaign: each period's uncertainty"),
    "validate": Command("validate", "check artefacts against their schema and CF/ACDD"),
}


def build_parser(commands: Iterable[str] | None = None) -> argparse.ArgumentParser:
    """Build the argument parser: every subcommand in full, or only ``commands`` in full.

    The other subcommands are then listed with their help line only, without importing their
    modules (:data:`COMMANDS`); :func:`main` builds only the command it runs.
    """
    parser = argparse.ArgumentParser(
        prog="lidarcal",
        description="Anemometer-free calibration of pulsed Doppler wind lidars.",
    )
    parser.add_argument("--version", action="version", version=f"lidarcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    full = {COMMANDS[c].module for c in COMMANDS} if commands is None else \
        {COMMANDS[c].module for c in commands if c in COMMANDS}
    registered: set[str] = set()
    for name, command in COMMANDS.items():
        if command.module not in full:
            sub.add_parser(name, help=command.help, add_help=False)
        elif command.module not in registered:  # the module adds all of its commands
            importlib.import_module(f"lidarcal.cli.{command.module}").register(sub)
            registered.add(command.module)
    return parser


def _command_in(argv: Sequence[str]) -> str | None:
    """Return the subcommand ``argv`` names (its first word that is not an option), if any."""
    return next((a for a in argv if not a.startswith("-")), None)


def command_line(args: argparse.Namespace) -> str:
    """Return the command as the user typed it, for an artefact's ``history`` line."""
    argv = getattr(args, "argv", None)
    if argv is None:
        return f"lidarcal {getattr(args, 'command', '')}".strip()
    return "lidarcal " + shlex.join(argv)


def interrupted(args: argparse.Namespace) -> list[str]:
    """Say what an interrupted (Ctrl-C) command kept and the command that resumes it.

    A command that keeps finished simulation chunks sets ``resume`` (``set_defaults``): a function
    of its arguments returning the chunk directory (None: none kept) and the option the command
    needs to run again in place (``--overwrite`` for ``calibrate``, whose early files exist).
    """
    how = getattr(args, "resume", None)
    if how is None:
        return ["interrupted"]
    from lidarcal.campaign.chunks import finished_chunks  # deferred: only after an interrupt

    workdir, option = how(args)
    argv = list(getattr(args, "argv", None) or [args.command])
    again = "lidarcal " + shlex.join(argv + ([option] if option and option not in argv else []))
    if workdir is None:
        return ["interrupted; no finished chunk was kept (only --workdir DIR keeps them for a resume)",
                f"run it again with: {again} --workdir DIR"]
    n = finished_chunks(workdir)
    return [f"interrupted; {n} finished simulation chunk(s) kept in {workdir}",
            f"resume with: {again}" + ("" if n else " (nothing to reuse yet: it starts again)")]


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Print warnings as one plain line (no source excerpt) on stderr."""
    name = "warning" if category in (UserWarning,) or issubclass(category, UserWarning) else category.__name__
    print(f"lidarcal: {name}: {message}", file=sys.stderr)


class _StderrHandler(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is at the time (pytest swaps it)."""

    def emit(self, record: logging.LogRecord) -> None:
        self.setStream(sys.stderr)
        super().emit(record)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``lidarcal`` command."""
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser([_command_in(argv) or ""])
    args = parser.parse_args(argv)
    args.argv = argv
    warnings.showwarning = _show_warning
    if not getattr(args, "handler", None):
        parser.print_help()
        return 1
    logger = logging.getLogger("lidarcal")
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter(f"lidarcal {args.command}: %(message)s"))
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.INFO)
    from lidarcal.provenance import contact  # deferred: numpy and xarray, which --help does without

    try:
        # --creator, --institution ... (options.add_contact_options) for every file written
        given = {k[len("contact_"):]: v for k, v in vars(args).items() if k.startswith("contact_") and v}
        with contact(**given):
            return int(args.handler(args) or 0)
    except LidarcalError as exc:
        print(f"lidarcal {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the machine, not lidarcal: disk full, permissions changed mid-run ...
        where = exc.filename if exc.filename is not None else "input/output"
        print(f"lidarcal {args.command}: error: {where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        try:
            said = interrupted(args)
        except Exception:  # never a traceback after Ctrl-C: the bare fact is still right
            said = ["interrupted"]
        for line in said:
            print(f"lidarcal {args.command}: {line}", file=sys.stderr)
        return 130
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)

