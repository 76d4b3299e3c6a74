"""``lidarcal dcc CERT.nc -o CERT.xml [--admin A.yaml] [--xsd dcc.xsd] [--sign-x509 KEY.pem --chain C.pem]``.

Writes the certificate as a PTB Digital Calibration Certificate (DCC XML, schema 3.1.2 with the
D-SI 2.1.0 units; docs/dcc.md): administrative data, the expanded uncertainty per height and
wind-speed bin (k = 2, coverage probability 0.95), the significant sensitivities, the method and
the bench, the status (demonstration or issued), and the SHA-256 of CERT.nc, which stays the
sealed original.  CERT.nc's seal is checked first: an altered or unsealed certificate is never
exported.  ``--admin`` adds what the certificate does not state (a customer, an address ...);
it may not contradict what it does.  With ``--xsd`` (default: the environment variable
LIDARCAL_DCC_XSD) the document is validated against PTB's dcc.xsd, with SI_Format.xsd read from
the same folder, before it is written; lidarcal does not ship the XSDs.

``--sign-x509 KEY.pem --chain CHAIN.pem`` signs the DCC as a laboratory does: an enveloped
XAdES-BES XML signature with the laboratory's X.509 key (RSA or EC, PEM; an encrypted one with its
passphrase in LIDARCAL_DCC_KEY_PASSPHRASE) and certificate chain (PEM, the signer's certificate
first).  ``lidarcal dcc --verify CERT.xml [--ca CA.pem] [CERT.nc]`` checks such a signature
(exit 0 valid, 1 not, 2 unreadable): against the roots in CA.pem, else only against the root the
document carries; with CERT.nc, also that the XML names that file's SHA-256 and that its seal holds.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from lidarcal.certificate.admin import load_admin, status_line
from lidarcal.certificate.dcc.export import DCC_SCHEMA_VERSION, dcc_attributes, write_dcc
from lidarcal.cli import COMMANDS
from lidarcal.cli.options import add_overwrite_option
from lidarcal.errors import InputError
from lidarcal.io import open_artefact
from lidarcal.provenance import sha256


def register(sub: argparse._SubParsersAction) -> None:
    """Add the ``dcc`` subcommand."""
    p = sub.add_parser("dcc", help=COMMANDS["dcc"].help,
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("certificate", metavar="CERT.nc", nargs="?",
                   help="sealed netCDF certificate (with --verify: the one the XML should name)")
    p.add_argument("-o", "--output", metavar="CERT.xml")
    p.add_argument("--admin", metavar="ADMIN.yaml",
                   help="administrative data the certificate does not state (keys in docs/certificate.md)")
    p.add_argument("--xsd", metavar="dcc.xsd", default=os.environ.get("LIDARCAL_DCC_XSD") or None,
                   help="validate against this dcc.xsd (SI_Format.xsd beside it) before writing "
                   "(default: $LIDARCAL_DCC_XSD)")
    s = p.add_argument_group("the laboratory's X.509 signature (docs/dcc.md)")
    s.add_argument("--sign-x509", metavar="KEY.pem",
                   help="sign the DCC with this private key (RSA or EC, PEM, mode 0600)")
    s.add_argument("--chain", metavar="CHAIN.pem",
                   help="the key's certificate chain (PEM: the signer's certificate first, then "
                   "intermediates)")
    s.add_argument("--verify", metavar="CERT.xml", help="check the signature of this signed DCC instead")
    s.add_argument("--ca", metavar="CA.pem",
                   help="with --verify: the root certificates you trust (PEM); without it the chain is "
                   "checked only against the root the document carries")
    add_overwrite_option(p)
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    """Check the certificate's seal, then build, (validate, sign) and write the DCC; or verify one."""
    if args.verify:
        return _verify(args)
    if args.ca:
        raise InputError("--ca: only with --verify CERT.xml")
    if not args.certificate or not args.output:
        raise InputError("dcc: give the certificate and -o CERT.xml (or --verify CERT.xml to check a signed "
                         "DCC)")
    if bool(args.sign_x509) != bool(args.chain):
        raise InputError("--sign-x509 KEY.pem and --chain CHAIN.pem go together: the key signs, the chain "
                         "says whose it is")
    admin = load_admin(args.admin) if args.admin else None
    signer = None
    if args.sign_x509:
        from lidarcal.certificate.dcc.sign import load_signer  # deferred: signxml only when signing

        signer = load_signer(args.sign_x509, args.chain)  # a bad key or chain fails before any work
    path = write_dcc(args.certificate, args.output, admin=admin, overwrite=args.overwrite, xsd=args.xsd,
                     signer=signer)
    cert = open_artefact(args.certificate, "certificate")  # its seal checked by write_dcc
    name = Path(args.certificate).name
    print(f"{path}: {status_line(dcc_attributes(cert, admin=admin, certificate_file=name))}")
    checked = f"valid against {args.xsd}" if args.xsd else "not validated (no --xsd / LIDARCAL_DCC_XSD)"
    signed = (f"; signed (XAdES-BES) by {signer.subject} (check with: lidarcal dcc --verify {path} "
              "--ca CA.pem)" if signer else "; unsigned")
    digest = sha256(args.certificate)
    print(f"{path}: DCC {DCC_SCHEMA_VERSION} of {args.certificate} (sha256 {digest}, its seal checked); "
          f"{checked}{signed}")
    return 0


def _verify(args: argparse.Namespace) -> int:
    """``--verify``: 0 when the signature, the chain (and the netCDF named) hold, 1 when not."""
    from lidarcal.certificate.dcc.sign import same_results, verify_dcc  # deferred: signxml when verifying
    from lidarcal.certificate.seal import verify_certificate  # deferred: with it

    if args.output or args.sign_x509 or args.chain or args.admin:
        raise InputError("--verify checks a DCC: it takes no -o, --sign-x509, --chain or --admin")
    report = verify_dcc(args.verify, ca=args.ca)
    if report.ok and args.certificate:
        digest = sha256(args.certificate) if Path(args.certificate).is_file() else None
        if digest is None:
            raise InputError(f"{args.certificate}: file not found")
        if report.netcdf_sha256 != digest:
            report.problems.append(f"the signed XML names the netCDF certificate sha256:"
                                   f"{report.netcdf_sha256}, but {args.certificate} has sha256:{digest}: not "
                                   "the file it was made from")
        else:
            seal = verify_certificate(args.certificate)
            if not seal.ok:
                report.problems.append(f"{args.certificate} is the file the XML names, but its seal does not "
                                       f"hold: {'; '.join(seal.problems[:3])}")
            elif not same_results(report.document, args.certificate):
                report.problems.append(f"the signed XML names {args.certificate}, but its measurement "
                                       "results are not that certificate's (lidarcal dcc writes other "
                                       "numbers from it)")
    if not report.ok:
        print(f"{args.verify}: signature NOT valid ({len(report.problems) or 1} problem(s))")
        for line in report.problems:
            print(f"  - {line}")
        return 1
    whom = (f"checked against the roots in {args.ca}" if args.ca else
            f"checked only against {report.trusted}: pass --ca CA.pem to check it is a root you trust")
    print(f"{args.verify}: signature valid ({report.form}) by {report.signer}; chain "
          f"{' <- '.join(report.chain)} {whom}" + (f"; signed at {report.signing_time}" if report.signing_time
                                                   else ""))
    named = f"names the netCDF certificate sha256:{report.netcdf_sha256}"
    print(f"{args.verify}: {named}" + (f" = {args.certificate}, whose seal holds" if args.certificate
                                       else " (give CERT.nc to check it is that file and its seal holds)"))
    sys.stdout.flush()
    return 0
