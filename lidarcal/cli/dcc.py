"""``lidarcal dcc CERT.nc -o CERT.xml [--admin ADMIN.yaml] [--xsd dcc.xsd]``: Digital Calibration Certificate.

Writes the certificate as a PTB Digital Calibration Certificate (DCC XML, schema 3.1.2 with the
D-SI 2.1.0 units; docs/dcc.md): administrative data, the expanded uncertainty per height and
wind-speed bin (k = 2, coverage probability 0.95), the significant sensitivities, the method and
the bench, the status (demonstration or issued), and the SHA-256 of CERT.nc, which stays the
sealed original.  ``--admin`` adds what the certificate does not state (a customer, an
address ...); it may not contradict what it does.  With ``--xsd`` (default: the environment
variable LIDARCAL_DCC_XSD) the document is validated against PTB's dcc.xsd, with SI_Format.xsd
read from the same folder, before it is written; lidarcal does not ship the XSDs.
"""

from __future__ import annotations

import argparse
import os

from lidarcal.admin import load_admin, status_line
from lidarcal.cli import COMMANDS
from lidarcal.cli.options import add_overwrite_option
from lidarcal.dcc import DCC_SCHEMA_VERSION, dcc_attributes, write_dcc
from lidarcal.io import open_artefact
from lidarcal.provenance import sha256


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``dcc`` subcommand."""
    p = sub.add_parser("dcc", help=COMMANDS["dcc"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("certificate", metavar="CERT.nc", help="sealed netCDF certificate")
    p.add_argument("-o", "--output", required=True, metavar="CERT.xml")
    p.add_argument("--admin", metavar="ADMIN.yaml",
                   help="administrative data the certificate does not state (keys in docs/certificate.md)")
    p.add_argument("--xsd", metavar="dcc.xsd", default=os.environ.get("LIDARCAL_DCC_XSD") or None,
                   help="validate against this dcc.xsd (SI_Format.xsd beside it) before writing "
                   "(default: $LIDARCAL_DCC_XSD)")
    add_overwrite_option(p)
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Build, (validate) and write the DCC."""
    admin = load_admin(args.admin) if args.admin else None
    cert = open_artefact(args.certificate, "certificate")
    print(f"{args.output}: {status_line(dcc_attributes(cert, admin=admin))}")
    path = write_dcc(args.certificate, args.output, admin=admin, overwrite=args.overwrite, xsd=args.xsd)
    checked = f"valid against {args.xsd}" if args.xsd else "not validated (no --xsd / LIDARCAL_DCC_XSD)"
    digest = sha256(args.certificate)
    print(f"{path}: DCC {DCC_SCHEMA_VERSION} of {args.certificate} (sha256 {digest}); {checked}")
    return 0
