"""``lidarcal keygen -o KEY``: a new Ed25519 key pair for signing certificates.

Writes the private key to KEY (PEM, unencrypted, mode 0600: keep it secret; whoever holds it
can sign) and the public key to KEY.pub (give it to whoever checks your certificates, through
a channel they trust).  Prints the key's fingerprint.  Use them as::

    lidarcal certificate ... --sign KEY -o CERT.nc      (or: lidarcal calibrate --sign KEY)
    lidarcal verify CERT.nc --public-key KEY.pub

A signed certificate checked with ``--public-key`` cannot be altered and re-sealed by anyone
without KEY; an unsigned one is protected against accidental alteration only.  Neither file is
replaced without ``--overwrite``.
"""

from __future__ import annotations

import argparse

from lidarcal.certificate.signing import generate_keypair
from lidarcal.cli import COMMANDS
from lidarcal.cli.options import add_output_options


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``keygen`` subcommand."""
    p = sub.add_parser(
        "keygen",
        help=COMMANDS["keygen"].help,
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_output_options(p, "KEY", help="private key file to write (the public key goes to KEY.pub)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Generate and write the key pair."""
    private, public, fp = generate_keypair(args.output, overwrite=args.overwrite)
    print(f"{private}: private key (mode 0600, keep it secret)\n{public}: public key\nfingerprint {fp}")
    return 0
