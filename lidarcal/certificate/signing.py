"""Ed25519 keys and signatures for certificates (``lidarcal keygen``, ``--sign``, ``--public-key``).

A certificate's seal (``lidarcal_integrity``, :mod:`lidarcal.certificate`) is an unkeyed
SHA-256 record: it detects alteration, but whoever can rewrite the file can recompute it.  A
signature closes that: the signer's private key signs the exact UTF-8 bytes of the seal, and
anyone holding the matching public key can check that the seal -- hence every value and
attribute it covers -- is the one the key holder wrote.  It says nothing about who holds the
key: distribute the public key (or its fingerprint) through a channel you trust.

Keys are PEM files: the private key PKCS#8 unencrypted, written with mode 0600 (keep it
secret); the public key SubjectPublicKeyInfo, written next to it as ``KEY.pub``.  A key is
named by its fingerprint, ``sha256:`` and the hex SHA-256 of its 32 raw public bytes.
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import os
from pathlib import Path

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from lidarcal.errors import InputError
from lidarcal.io import check_writable, disk_full, part_path, publish, remove_stale_parts

__all__ = [
    "ALGORITHM",
    "fingerprint",
    "generate_keypair",
    "load_private_key",
    "load_public_key",
    "sign",
    "verify_signature",
]

#: What a signature is made of, as recorded next to it in the certificate.
ALGORITHM = "Ed25519 over the UTF-8 bytes of the global attribute lidarcal_integrity"


def fingerprint(key: Ed25519PublicKey | Ed25519PrivateKey) -> str:
    """``sha256:<hex>`` of the 32 raw bytes of the (public half of the) key."""
    public = key.public_key() if isinstance(key, Ed25519PrivateKey) else key
    raw = public.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return "sha256:" + hashlib.sha256(raw).hexdigest()


def generate_keypair(path: str | os.PathLike, *, overwrite: bool = False) -> tuple[Path, Path, str]:
    """Write a new private key to ``path`` (mode 0600) and its public key to ``path.pub``.

    Returns the two paths and the fingerprint.  Neither file is replaced unless ``overwrite``.
    """
    path = Path(path)
    pub = path.with_name(path.name + ".pub")
    check_writable(path, overwrite=overwrite)
    check_writable(pub, overwrite=overwrite)
    key = Ed25519PrivateKey.generate()
    private_pem = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    public_pem = key.public_key().public_bytes(
        serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo
    )
    # both files or neither: the two temporaries are complete before either is published, and
    # the private key is withdrawn again if the public one cannot follow it
    remove_stale_parts(path)
    remove_stale_parts(pub)
    tmp = part_path(path)  # created 0600 and never widened: the private key is never readable by others
    tmp_pub = part_path(pub)
    published = False
    try:
        try:
            tmp.write_bytes(private_pem)
            os.chmod(tmp, 0o600)
            tmp_pub.write_bytes(public_pem)
            os.chmod(tmp_pub, 0o644)
        except OSError as exc:
            raise disk_full(exc, path if tmp.stat().st_size < len(private_pem) else pub) or exc from None
        publish(tmp, path, overwrite=overwrite)
        published = True
        publish(tmp_pub, pub, overwrite=overwrite)
    except BaseException:
        if published:  # the public key could not follow: leave neither
            with contextlib.suppress(OSError):
                path.unlink()
        raise
    finally:
        for t in (tmp, tmp_pub):
            with contextlib.suppress(OSError):
                t.unlink()
    return path, pub, fingerprint(key)


def _read(path: str | os.PathLike, what: str) -> bytes:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} not found (expected a PEM file written by lidarcal keygen)")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read the {what}: {exc.strerror}") from None


def _check_private(path: str | os.PathLike) -> None:
    """Refuse a private key file other users can read or write, as ssh does."""
    if os.name != "posix":
        return  # Windows: access is by ACL, which st_mode does not show
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return  # _read reports it
    if mode & 0o077:
        raise InputError(
            f"{path}: private key is readable or writable by others (mode {mode & 0o777:04o}): refusing to "
            "sign with it (as ssh refuses such a key): anyone who could read it can sign certificates as "
            f"you. Restrict it with 'chmod 600 {path}', and if others may have copied it, make a new key "
            "(lidarcal keygen) and withdraw the old public key"
        )


#: The check every private key file lidarcal signs with passes (this one and the DCC's X.509 key).
check_private_key_file = _check_private


def load_private_key(path: str | os.PathLike) -> Ed25519PrivateKey:
    """Read an Ed25519 private key (PEM, unencrypted) with a clear error for anything else.

    On POSIX systems a key file other users can read or write (any group or other permission
    bit, e.g. mode 0644) is refused, as ssh refuses one: a signature vouches for a file only
    while the key is its holder's alone.
    """
    data = _read(path, "private key")
    try:
        key = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError) as exc:
        public = b"PUBLIC" in data
        hint = " (this is a public key; --sign takes the private key KEY, not KEY.pub)" if public else ""
        raise InputError(f"{path}: not an unencrypted PEM private key{hint}: {exc}") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise InputError(f"{path}: expected an Ed25519 private key; found {type(key).__name__}")
    _check_private(path)
    return key


def load_public_key(path: str | os.PathLike) -> Ed25519PublicKey:
    """Read an Ed25519 public key (PEM) with a clear error for anything else."""
    data = _read(path, "public key")
    try:
        key = serialization.load_pem_public_key(data)
    except (ValueError, TypeError) as exc:
        hint = " (this is a private key: give KEY.pub)" if b"PRIVATE" in data else ""
        raise InputError(f"{path}: not a PEM public key{hint}: {exc}") from None
    if not isinstance(key, Ed25519PublicKey):
        raise InputError(f"{path}: expected an Ed25519 public key; found {type(key).__name__}")
    return key


def sign(key: Ed25519PrivateKey, seal: str) -> str:
    """Base64 Ed25519 signature of the UTF-8 bytes of ``seal``."""
    return base64.b64encode(key.sign(seal.encode("utf-8"))).decode("ascii")


def verify_signature(key: Ed25519PublicKey, seal: str, signature: str) -> bool:
    """Check that ``signature`` (base64) is ``key``'s signature of ``seal``; never raises."""
    try:
        key.verify(base64.b64decode(signature, validate=True), seal.encode("utf-8"))
    except (InvalidSignature, ValueError):
        return False
    return True
