"""A DCC signed as a laboratory signs one: an enveloped XAdES-BES signature with its X.509 key and chain.

:func:`load_signer` reads the laboratory's private key (PEM, RSA or EC; an encrypted one with the
passphrase in ``$LIDARCAL_DCC_KEY_PASSPHRASE``) and its certificate chain (PEM: the signer's
certificate first, then the intermediates, the root optionally); :func:`sign_dcc` adds to the
DCC's root element an enveloped XML signature (W3C XML-DSig, RSA-SHA256 or ECDSA-SHA256,
Canonical XML 1.1) in the XAdES-BES form of ETSI EN 319 132-1, the form PTB's tools expect of
a signed DCC: besides the document, the signature covers its signing time and the digest of the
signer's certificate (``xades:SignedProperties``) and the certificates it carries
(``ds:KeyInfo``), so none can be swapped.  :func:`verify_dcc` checks a signed DCC: every
reference, the signature value, and the chain up to a root the caller trusts (``ca``), else
to the root the document carries (which shows it is intact, not who signed it).  It also
accepts a plain enveloped XML-DSig signature (one reference), as PTB's ``dcclib`` writes.

The signature covers the XML; the XML names the netCDF certificate by SHA-256, and the netCDF
keeps its own Ed25519 seal (:mod:`lidarcal.certificate.seal`).  The XML-DSig and XAdES work is
``signxml``'s; lidarcal chooses the form and reports the outcome.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives.asymmetric import ec, rsa
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat, load_pem_private_key
from lxml import etree

from lidarcal.certificate.dcc.export import dcc_tree
from lidarcal.certificate.signing import check_private_key_file
from lidarcal.errors import InputError
from lidarcal.io import check_input_file, open_artefact
from lidarcal.provenance import sha256

__all__ = ["DS_NS", "XADES_NS", "PASSPHRASE_ENV", "Signer", "DccSignatureReport", "load_signer", "sign_dcc",
           "verify_dcc", "same_results"]

DS_NS = "http://www.w3.org/2000/09/xmldsig#"
XADES_NS = "http://uri.etsi.org/01903/v1.3.2#"
_DCC_ROOT = "{https://ptb.de/dcc}digitalCalibrationCertificate"
#: The environment variable holding the passphrase of an encrypted signing key (never an option:
#: a command line is visible to every user of the machine).
PASSPHRASE_ENV = "LIDARCAL_DCC_KEY_PASSPHRASE"
#: Smallest RSA key accepted (bits): what current signature guidance (e.g. ETSI TS 119 312) allows.
MIN_RSA_BITS = 2048
_NETCDF_SHA = ("dcc:administrativeData/dcc:coreData/dcc:identifications/"
               "dcc:identification[@refType='lidarcal_netcdfCertificateSha256']/dcc:value")
_NS = {"dcc": "https://ptb.de/dcc", "ds": DS_NS, "xades": XADES_NS}


@dataclass
class Signer:
    """A laboratory's signing key and its certificate chain (the signer's certificate first)."""

    key: rsa.RSAPrivateKey | ec.EllipticCurvePrivateKey
    chain: list[x509.Certificate]

    @property
    def subject(self) -> str:
        """The signer's certificate subject (RFC 4514)."""
        return self.chain[0].subject.rfc4514_string()

    def sign(self, root: etree._Element) -> etree._Element:
        """Return ``root`` signed (:func:`sign_dcc`): what ``write_dcc`` calls."""
        return sign_dcc(root, self)


def _spki(key) -> bytes:
    return key.public_bytes(Encoding.DER, PublicFormat.SubjectPublicKeyInfo)


def load_signer(key: str | os.PathLike, chain: str | os.PathLike) -> Signer:
    """Read a laboratory's X.509 signing key and certificate chain (both PEM), checked for use.

    Raises
    ------
    InputError
        Naming the file: unreadable, not PEM, a key others can read (as ``lidarcal --sign``
        refuses), an encrypted key without ``$LIDARCAL_DCC_KEY_PASSPHRASE``, a key type XML-DSig
        verifiers do not all take (only RSA of at least 2048 bits and ECDSA), a chain whose first
        certificate is not the key's, is not valid now, or does not allow digital signatures.
    """
    key_path, chain_path = Path(key), Path(chain)
    for path, what in ((key_path, "signing key"), (chain_path, "certificate chain")):
        if not path.is_file():
            raise InputError(f"{path}: {what} not found" if not path.exists()
                             else f"{path}: {what} is not a file")
    check_private_key_file(key_path)
    passphrase = os.environ.get(PASSPHRASE_ENV)
    try:
        private = load_pem_private_key(key_path.read_bytes(), passphrase.encode() if passphrase else None)
    except TypeError:  # encrypted without a passphrase, or a passphrase for a plain key
        how = (f"unset {PASSPHRASE_ENV}" if passphrase
               else f"give its passphrase in the environment variable {PASSPHRASE_ENV}")
        state = "not encrypted" if passphrase else "encrypted"
        raise InputError(f"{key_path}: the signing key is {state}; {how}") from None
    except ValueError as exc:
        raise InputError(f"{key_path}: not a PEM private key, or a wrong passphrase ({exc})") from None
    if isinstance(private, rsa.RSAPrivateKey):
        if private.key_size < MIN_RSA_BITS:
            raise InputError(f"{key_path}: RSA key of {private.key_size} bits; a signature needs at least "
                             f"{MIN_RSA_BITS}")
    elif not isinstance(private, ec.EllipticCurvePrivateKey):
        kind = type(private).__name__.removeprefix("_")
        raise InputError(f"{key_path}: a {kind} key; a DCC's X.509 signature "
                         "takes an RSA or an ECDSA key (the lidarcal keygen Ed25519 key signs the netCDF "
                         "certificate, --sign)")
    try:
        certs = x509.load_pem_x509_certificates(chain_path.read_bytes())
    except ValueError as exc:
        raise InputError(f"{chain_path}: not a PEM certificate chain ({exc})") from None
    if _spki(certs[0].public_key()) != _spki(private.public_key()):
        mine = _spki(private.public_key())
        holder = next((i for i, c in enumerate(certs) if _spki(c.public_key()) == mine), None)
        raise InputError(f"{chain_path}: its first certificate ({certs[0].subject.rfc4514_string()}) is not "
                         f"the one of the key {key_path}"
                         + (f"; certificate {holder + 1} is: put it first" if holder is not None else
                            "; none of its certificates is"))
    leaf = certs[0]
    now = _now()
    if not leaf.not_valid_before_utc <= now <= leaf.not_valid_after_utc:
        start, end = (f"{t:%Y-%m-%d %H:%M}" for t in (leaf.not_valid_before_utc, leaf.not_valid_after_utc))
        raise InputError(f"{chain_path}: the signer's certificate ({leaf.subject.rfc4514_string()}) is valid "
                         f"from {start} to {end} UTC, not now: a signature made with it would not verify")
    try:
        usage = leaf.extensions.get_extension_for_class(x509.KeyUsage).value
    except x509.ExtensionNotFound:
        usage = None
    if usage is None or not usage.digital_signature:
        raise InputError(f"{chain_path}: the signer's certificate ({leaf.subject.rfc4514_string()}) has no "
                         "KeyUsage digitalSignature; verifiers refuse signatures made with it")
    return Signer(private, list(certs))


def _now():
    import datetime as _dt

    return _dt.datetime.now(_dt.UTC)


def sign_dcc(root: etree._Element, signer: Signer) -> etree._Element:
    """Return a copy of the DCC ``root`` element with an enveloped XAdES-BES signature by ``signer``.

    The signature is the root's last child (where the DCC schema places ``ds:Signature``); the
    signer's certificate and the rest of the chain are in its ``ds:KeyInfo``.
    """
    from signxml import SignatureMethod, methods
    from signxml.xades import XAdESSigner

    if root.tag != _DCC_ROOT:
        raise InputError(f"not a DCC: the root element is {root.tag!r}, expected {_DCC_ROOT!r}")
    method = (SignatureMethod.RSA_SHA256 if isinstance(signer.key, rsa.RSAPrivateKey)
              else SignatureMethod.ECDSA_SHA256)

    class _UTF8Signer(XAdESSigner):
        """Copy the element through UTF-8 text, not signxml's ASCII.

        Through ASCII, a comment's non-ASCII characters became literal ``&#8209;`` text (character
        references mean nothing in a comment).
        """

        def _tostring(self, xml_node, **kwargs):
            kwargs.setdefault("encoding", "UTF-8")
            return super()._tostring(xml_node, **kwargs)

    xades = _UTF8Signer(method=methods.enveloped, signature_algorithm=method)
    pems = [c.public_bytes(Encoding.PEM).decode("ascii") for c in signer.chain]
    return xades.sign(root, key=signer.key, cert=pems)


@dataclass
class DccSignatureReport:
    """Outcome of :func:`verify_dcc`."""

    path: str
    problems: list[str] = field(default_factory=list)
    #: "XAdES-BES" or "XML-DSig" (one reference, as dcclib signs)
    form: str | None = None
    #: subject of the verified signing certificate (RFC 4514)
    signer: str | None = None
    #: subjects of the chain as it was verified, signer first
    chain: list[str] = field(default_factory=list)
    #: the XAdES signing time the signature covers
    signing_time: str | None = None
    #: the roots the chain was checked against: the caller's file, or the document's own root
    trusted: str | None = None
    #: the netCDF certificate's SHA-256 as the signed XML states it
    netcdf_sha256: str | None = None
    #: the DCC element as signed (the signature removed): read this, never the file around it
    document: etree._Element | None = field(default=None, repr=False)

    @property
    def ok(self) -> bool:
        """True when the signature, every reference and the chain hold."""
        return not self.problems and self.signer is not None


def _own_root(certs: Sequence[x509.Certificate]) -> x509.Certificate | None:
    last = certs[-1] if certs else None
    return last if last is not None and last.subject == last.issuer else None


def verify_dcc(path: str | os.PathLike, *, ca: str | os.PathLike | None = None) -> DccSignatureReport:
    """Check the XML signature of a signed DCC; list what fails.

    Every reference (the whole document, and for XAdES its signed properties and key info), the
    signature value and the certificate chain are checked (``signxml``).  The chain must lead
    to a root in ``ca`` (PEM, the roots you trust) -- the only check that says who signed --
    else to the self-signed root the document carries, which shows the document is as that
    chain's holder signed it but not who that is (compare ``signer`` with whom you expect, or
    pass ``ca``).  Certificates are checked at the current time.

    Raises
    ------
    InputError
        If ``path`` or ``ca`` is missing or unreadable, or ``path`` is not a DCC.
    """
    from signxml import XMLVerifier
    from signxml.exceptions import InvalidInput, SignXMLException
    from signxml.xades import XAdESVerifier

    path = check_input_file(path, "DCC XML file")
    report = DccSignatureReport(str(path))
    data = path.read_bytes()
    parser = etree.XMLParser(resolve_entities=False, no_network=True, remove_blank_text=False)
    try:
        root = etree.fromstring(data, parser)
    except etree.XMLSyntaxError as exc:
        raise InputError(f"{path}: not an XML document: {exc}") from None
    if root.tag != _DCC_ROOT:
        raise InputError(f"{path}: not a DCC: its root element is {root.tag!r}")
    signatures = root.findall("ds:Signature", _NS)
    if not signatures:
        report.problems.append("unsigned: the DCC carries no ds:Signature")
        return report
    if len(signatures) > 1 or len(root.findall(".//ds:Signature", _NS)) > 1:
        report.problems.append(f"{len(root.findall('.//ds:Signature', _NS))} signatures: one enveloped "
                               "signature of the whole document is expected")
        return report
    xades = signatures[0].find(".//xades:QualifyingProperties", _NS) is not None
    report.form = "XAdES-BES" if xades else "XML-DSig"
    try:
        carried = [x509.load_der_x509_certificate(_b64(e.text))
                   for e in signatures[0].findall("ds:KeyInfo/ds:X509Data/ds:X509Certificate", _NS) if e.text]
    except ValueError as exc:  # binascii.Error is a ValueError too
        report.problems.append(f"a ds:X509Certificate of the signature is not a certificate ({exc})")
        return report
    with tempfile.TemporaryDirectory() as scratch:
        if ca is not None:
            ca_file = check_input_file(ca, "file of trusted root certificates (PEM)")
            try:
                x509.load_pem_x509_certificates(ca_file.read_bytes())
            except ValueError as exc:
                raise InputError(f"{ca_file}: not PEM certificates ({exc})") from None
            report.trusted = str(ca_file)
        else:
            own = _own_root(carried)
            if own is None:
                report.problems.append("the chain in the document does not end at a self-signed root; pass "
                                       "the roots you trust (--ca CA.pem)")
                return report
            ca_file = Path(scratch) / "root.pem"
            ca_file.write_bytes(own.public_bytes(Encoding.PEM))
            report.trusted = f"the root the document carries ({own.subject.rfc4514_string()})"
        try:
            if xades:
                results = XAdESVerifier().verify(data, ca_pem_file=str(ca_file))
            else:
                results = [XMLVerifier().verify(data, ca_pem_file=str(ca_file))]
        except InvalidInput as exc:
            report.problems.append(f"not a verifiable signature: {exc}")
            return report
        except SignXMLException as exc:  # InvalidSignature, InvalidDigest, InvalidCertificate
            report.problems.append(f"{type(exc).__name__}: {exc}")
            return report
        except ValueError as exc:  # a certificate or key in the signature that does not parse
            report.problems.append(f"the signature holds something that is not a certificate or key: {exc}")
            return report
    whole = [r for r in results if r.signed_xml is not None and r.signed_xml.tag == _DCC_ROOT]
    if not whole:
        report.problems.append("the signature does not cover the DCC element (no reference to the whole "
                               "document)")
        return report
    signed = whole[0].signed_xml  # read what was signed only, never the document around it
    key = whole[0].signature_key
    spki = PublicFormat.SubjectPublicKeyInfo
    leaf = next((c for c in carried if c.public_key().public_bytes(Encoding.PEM, spki) == key),
                carried[0] if carried else None)
    report.signer = leaf.subject.rfc4514_string() if leaf is not None else None
    report.chain = [c.subject.rfc4514_string() for c in carried]
    times = [r.signed_properties for r in results if hasattr(r, "signed_properties")]
    if times:
        report.signing_time = times[0].findtext(".//xades:SigningTime", namespaces=_NS)
    report.document = signed
    stated = signed.findtext(_NETCDF_SHA, namespaces=_NS) or ""
    report.netcdf_sha256 = stated.removeprefix("sha256:") or None
    return report


def same_results(document: etree._Element, certificate: str | os.PathLike) -> bool:
    """Say whether a DCC element's ``measurementResults`` are those lidarcal writes from ``certificate``.

    They come from the certificate alone (administrative data only adds to the rest), so a DCC
    that names a certificate but states other numbers is told apart, whoever signed it.
    """
    fresh = dcc_tree(open_artefact(certificate, "certificate"), certificate_sha256=sha256(certificate),
                     certificate_file=Path(certificate).name)
    tag = "{https://ptb.de/dcc}measurementResults"
    found, expected = document.find(tag), fresh.getroot().find(tag)

    def canonical(el: etree._Element) -> bytes:  # the layout's indentation is no part of the results
        bare = etree.fromstring(etree.tostring(el), etree.XMLParser(remove_blank_text=True))
        return etree.tostring(bare, method="c14n", exclusive=True)

    return found is not None and canonical(found) == canonical(expected)


def _b64(text: str) -> bytes:
    import base64

    return base64.b64decode("".join(text.split()), validate=True)
