"""Signed certificates: ``lidarcal keygen``, ``--sign``, ``verify --public-key``, and forgeries.

The forger here can do everything the issue describes: rewrite the file, halve every
uncertainty and recompute the unkeyed seal with the documented canonical form
(:func:`lidarcal.certificate.seal.integrity_record`), strip the signature, or sign with a key of
their own.  Only a check against the genuine public key must catch every one of them.
"""

from __future__ import annotations

import base64
import json
import os
import stat

import netCDF4
import numpy as np
import pytest
from analysis_factories import make_records
from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

from lidarcal.analysis import budget, sensitivity
from lidarcal.certificate.seal import INTEGRITY_ATTR, integrity_record
from lidarcal.certificate.signing import ALGORITHM, fingerprint, load_private_key, load_public_key, sign
from lidarcal.cli import main
from lidarcal.io import open_artefact, write_artefact

HALVED = ("budget_uncertainty", "budget_expanded_uncertainty", "budget_relative_uncertainty")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("sig-inputs")
    make_records(n=300).to_netcdf(d / "records.nc")
    records = open_artefact(d / "records.nc")
    return {
        "budget": write_artefact(budget(records), d / "budget.nc"),
        "sens": write_artefact(sensitivity(records, "wind_shear_exponent"), d / "sens.nc"),
    }


@pytest.fixture(scope="module")
def keys(tmp_path_factory):
    d = tmp_path_factory.mktemp("keys")
    assert main(["keygen", "-o", str(d / "key")]) == 0
    assert main(["keygen", "-o", str(d / "attacker")]) == 0
    return d / "key", d / "key.pub", d / "attacker"


def _certificate(inputs, out, *extra):
    code = main(["certificate", "--budget", str(inputs["budget"]), "--sensitivity", str(inputs["sens"]),
                 "-o", str(out), "--demonstration", *extra])
    assert code == 0
    return out


def _verify(capsys, path, *extra):
    capsys.readouterr()
    code = main(["verify", str(path), *extra])
    out = capsys.readouterr()
    return code, out.out + out.err


def _forge(path, *, strip=False, resign=None):
    """Halve the uncertainties and re-seal as an attacker would (optionally strip or re-sign)."""
    with netCDF4.Dataset(path, "a") as nc:
        for name in HALVED:
            nc[name][...] = nc[name][...] / 2
        if strip:
            for attr in [a for a in nc.ncattrs() if a.startswith("lidarcal_signature")]:
                nc.delncattr(attr)
        if resign is not None:
            nc.setncattr("lidarcal_signature_key", fingerprint(resign))
            nc.setncattr("lidarcal_signature_algorithm", ALGORITHM)
            raw = resign.public_key().public_bytes(Encoding.Raw, PublicFormat.Raw)
            nc.setncattr("lidarcal_signature_public_key", base64.b64encode(raw).decode())
    seal = json.dumps(integrity_record(path), sort_keys=True)
    with netCDF4.Dataset(path, "a") as nc:
        nc.setncattr(INTEGRITY_ATTR, seal)
        if resign is not None:
            nc.setncattr("lidarcal_signature", sign(resign, seal))


def test_keygen_writes_private_0600_and_public(keys, capsys, tmp_path):
    private, public, _ = keys
    assert stat.S_IMODE(os.stat(private).st_mode) == 0o600
    assert load_private_key(private).public_key() == load_public_key(public)
    assert sorted(p.name for p in private.parent.iterdir()) == ["attacker", "attacker.pub", "key", "key.pub"]
    before = private.read_bytes()
    assert main(["keygen", "-o", str(private)]) == 2  # never replaced silently
    assert private.read_bytes() == before
    capsys.readouterr()
    assert main(["keygen", "-o", str(tmp_path / "k")]) == 0
    assert f"fingerprint {fingerprint(load_public_key(tmp_path / 'k.pub'))}" in capsys.readouterr().out


def test_signed_certificate_verifies_against_its_key(inputs, keys, tmp_path, capsys):
    private, public, attacker = keys
    cert = _certificate(inputs, tmp_path / "c.nc", "--sign", str(private))
    fp = fingerprint(load_public_key(public))
    code, out = _verify(capsys, cert, "--public-key", str(public))
    assert code == 0 and f"signed by {fp} (checked against {public})" in out, out
    code, out = _verify(capsys, cert)
    assert code == 0 and f"signed by {fp} (against the key stored in the file" in out, out
    main(["keygen", "-o", str(tmp_path / "other")])
    code, out = _verify(capsys, cert, "--public-key", str(tmp_path / "other.pub"))
    assert code == 1 and f"signed by {fp}, not by the given public key" in out, out


def test_unsigned_certificate_says_integrity_only(inputs, keys, tmp_path, capsys):
    cert = _certificate(inputs, tmp_path / "c.nc")
    code, out = _verify(capsys, cert)
    assert code == 0 and "unsigned: integrity only" in out, out
    code, out = _verify(capsys, cert, "--public-key", str(keys[1]))
    assert code == 1 and "unsigned (integrity only), but a public key was given" in out, out
    # issue 27: its seal matches, so it is not called altered: intact, unsigned, not by that key
    assert "ALTERED" not in out, out
    assert f"{cert}: NOT SIGNED by {keys[1]}: intact but unsigned (its " in out, out


def test_forgery_of_unsigned_file_passes_integrity_only(inputs, keys, tmp_path, capsys):
    """The documented limit of the unkeyed seal: a re-sealed unsigned file is 'OK, unsigned'."""
    cert = _certificate(inputs, tmp_path / "c.nc")
    before = open_artefact(cert)["budget_uncertainty"].values
    _forge(cert)
    np.testing.assert_array_equal(open_artefact(cert)["budget_uncertainty"].values, before / 2)
    code, out = _verify(capsys, cert)
    assert code == 0 and "unsigned: integrity only" in out, out
    code, out = _verify(capsys, cert, "--public-key", str(keys[1]))  # the key catches it
    assert code == 1, out


@pytest.mark.parametrize("how", ["resealed", "stripped", "resigned"])
def test_forgery_of_signed_file_fails_with_public_key(inputs, keys, tmp_path, capsys, how):
    private, public, attacker = keys
    cert = _certificate(inputs, tmp_path / "c.nc", "--sign", str(private))
    genuine, forger = fingerprint(load_public_key(public)), fingerprint(load_private_key(attacker))
    _forge(cert, strip=how == "stripped", resign=load_private_key(attacker) if how == "resigned" else None)
    code, out = _verify(capsys, cert, "--public-key", str(public))
    assert code == 1, out
    expected = {
        "resealed": f"signature by {genuine} does not match the seal",
        "stripped": "unsigned (integrity only), but a public key was given",
        "resigned": f"signed by {forger}, not by the given public key ({genuine})",
    }[how]
    assert expected in out, out
    # without the key: a kept signature still fails; stripped or re-signed files say plainly
    # that they are unsigned or signed by someone else's key
    code, out = _verify(capsys, cert)
    if how == "resealed":
        assert code == 1 and "does not match the seal" in out, out
    elif how == "stripped":
        assert code == 0 and "unsigned: integrity only" in out, out
    else:
        assert code == 0 and f"signed by {forger}" in out and genuine not in out, out


def test_key_files_mixed_up_are_refused(inputs, keys, tmp_path, capsys):
    private, public, _ = keys
    capsys.readouterr()
    assert main(["certificate", "--budget", str(inputs["budget"]), "--sensitivity", str(inputs["sens"]),
                 "-o", str(tmp_path / "c.nc"), "--sign", str(public)]) == 2
    assert "this is a public key" in capsys.readouterr().err
    assert not (tmp_path / "c.nc").exists()
    cert = _certificate(inputs, tmp_path / "c.nc", "--sign", str(private))
    code, out = _verify(capsys, cert, "--public-key", str(private))
    assert code == 2 and "this is a private key" in out, out
