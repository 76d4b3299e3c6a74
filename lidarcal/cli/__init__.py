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
from collections.abc import Sequence

from lidarcal import __version__
from lidarcal.errors import LidarcalError
from lidarcal.provenance import contact

#: Subcommand modules, in the order they appear in ``lidarcal --help``.
COMMANDS = (
    "calibrate",
    "bench",
    "rwf",
    "terms",
    "conditions",
    "field",
    "turbulence",
    "simulate",
    "sensitivity",
    "budget",
    "sweep",
    "certificate",
    "dcc",
    "verify",
    "keygen",
    "table",
    "diagnose",
    "compare",
    "smc",
    "validate",
)


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser from every subcommand module."""
    parser = argparse.ArgumentParser(
        prog="lidarcal",
        description="Anemometer-free calibration of pulsed Doppler wind lidars.",
    )
    parser.add_argument("--version", action="version", version=f"lidarcal {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"lidarcal.cli.{name}").register(sub)
    return parser


def command_line(args: argparse.Namespace) -> str:
    """Return the command as the user typed it, for an artefact's ``history`` line."""
    argv = getattr(args, "argv", None)
    if argv is None:
        return f"lidarcal {getattr(args, 'command', '')}".strip()
    return "lidarcal " + shlex.join(argv)


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
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
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
        print("interrupted", file=sys.stderr)
        return 130
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)

