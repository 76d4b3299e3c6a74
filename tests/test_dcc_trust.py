"""``lidarcal dcc`` exports only what it can vouch for, and never ends in a traceback (issue 27 §1).

Before: ``dcc`` exported a certificate whose uncertainties were halved, whose seal was deleted or
whose serial number was changed (exit 0, the tampered file's SHA-256 in the XML); a control
character in ``--creator`` or an administrative customer name ended in lxml's ``ValueError``;
a deeply nested ``--admin`` value in ``RecursionError``; a full disk in lxml's
``SerialisationError: IO_ENOSPC``.
"""

from __future__ import annotations

import errno
import hashlib
import sys
from pathlib import Path

import netCDF4
import pytest
import yaml
from analysis_factories import make_records

from lidarcal.analysis import budget, sensitivity
from lidarcal.certificate import make_certificate
from lidarcal.certificate.dcc.export import dcc_tree, write_dcc
from lidarcal.certificate.seal import INTEGRITY_ATTR, write_certificate
from lidarcal.cli import main
from lidarcal.errors import InputError, SealError
from lidarcal.io import open_artefact, write_artefact

HALVED = ("budget_uncertainty", "budget_expanded_uncertainty", "budget_relative_expanded_uncertainty")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("dcc-trust")
    make_records(n=300).to_netcdf(d / "records.nc")
    records = open_artefact(d / "records.nc")
    out = {"budget": write_artefact(budget(records), d / "budget.nc"),
           "sens": write_artefact(sensitivity(records, "wind_shear_exponent"), d / "sens.nc"), "dir": d}
    cert = make_certificate(budget=open_artefact(out["budget"]), sensitivities=[open_artefact(out["sens"])],
                            demonstration=True)
    out["cert"] = write_certificate(cert, d / "cert.nc")
    return out


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


def _halved(path):
    with netCDF4.Dataset(path, "a") as nc:
        for name in HALVED:
            nc[name][...] = nc[name][...] / 2


def _unsealed(path):
    with netCDF4.Dataset(path, "a") as nc:
        nc.delncattr(INTEGRITY_ATTR)


def _serial(path):
    with netCDF4.Dataset(path, "a") as nc:
        nc.setncattr("item_serial_number", "FORGED-0001")


def _run(capsys, *argv):
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize(("tamper", "found"), [
    (_halved, "'budget_expanded_uncertainty': values altered"),
    (_unsealed, f"'{INTEGRITY_ATTR}' is missing"),
    (_serial, "global attribute 'item_serial_number' altered"),
])
def test_dcc_refuses_a_tampered_certificate(inputs, tmp_path, capsys, tamper, found):
    cert = _copy(inputs["cert"], tmp_path / "cert.nc")
    tamper(cert)
    out = tmp_path / "cert.xml"
    code, stdout, err = _run(capsys, "dcc", cert, "-o", out)
    assert code == 2, err
    assert f"{cert}: refusing to export this certificate as a DCC" in err and found in err, err
    assert "Traceback" not in err and stdout == "" and not out.exists()
    assert list(tmp_path.glob(".cert.xml*")) == []  # no temporary left either
    with pytest.raises(SealError, match="refusing to export"):
        write_dcc(cert, out)
    # dcc_tree on a Dataset read from the tampered file checks the file too
    with pytest.raises(SealError, match=found.replace("'", ".")):
        dcc_tree(open_artefact(cert), certificate_sha256="0" * 64)
    # the genuine one is exported, and its XML names the SHA-256 of the bytes that were checked
    code, stdout, err = _run(capsys, "dcc", inputs["cert"], "-o", out)
    digest = hashlib.sha256(inputs["cert"].read_bytes()).hexdigest()
    assert code == 0 and f"(sha256 {digest}, its seal checked)" in stdout, err
    assert f"sha256:{digest}" in out.read_text()


@pytest.mark.parametrize("where", ["--creator", "customer name", "environment"])
def test_control_characters_are_refused_where_text_enters_a_certificate(inputs, tmp_path, capsys,
                                                                        monkeypatch, where):
    """U+0007 (bell) and U+001B (escape: a terminal obeys what follows) never reach a certificate."""
    common = ["certificate", "--budget", inputs["budget"], "--sensitivity", inputs["sens"], "--demonstration",
              "-o", tmp_path / "c.nc"]
    if where == "--creator":
        argv, named = [*common, "--creator", "Eve\a\x1b[2J"], "creator_name (option)"
    elif where == "customer name":
        admin = tmp_path / "admin.yaml"
        admin.write_text('customer: {name: "ACME\\a\\e[31m"}\n')  # YAML escapes: the file itself is clean
        argv, named = [*common, "--admin", admin], f"{admin}: key 'customer.name'"
    else:
        monkeypatch.setenv("LIDARCAL_INSTITUTION", "Lab\x1b]0;pwned\a")
        argv, named = common, "institution (environment variable LIDARCAL_INSTITUTION)"
    code, _, err = _run(capsys, *argv)
    assert code == 2 and "Traceback" not in err, err
    assert f"{named}: contains the control character U+00" in err and "no control characters" in err, err
    assert not (tmp_path / "c.nc").exists()
    # the same administrative file is refused by dcc --admin, before anything is written
    if where == "customer name":
        code, _, err = _run(capsys, "dcc", inputs["cert"], "-o", tmp_path / "c.xml", "--admin", admin)
        assert code == 2 and "U+0007" in err and not (tmp_path / "c.xml").exists(), err


def test_every_writer_refuses_a_control_character_in_an_attribute(inputs, tmp_path):
    """The writers' own check (lidarcal.io): whatever an entry point let through is never written."""
    ds = open_artefact(inputs["budget"])
    ds.attrs["comment"] = "fine\tand\nfine"  # tab and line breaks are text
    write_artefact(ds, tmp_path / "ok.nc")
    ds.attrs["comment"] = "bell\a"
    with pytest.raises(InputError, match="global attribute 'comment' contains the control character U.0007"):
        write_artefact(ds, tmp_path / "bad.nc")
    ds.attrs["comment"] = "ok"
    ds["expanded_uncertainty"].attrs["comment"] = "\x1b[31mred"
    with pytest.raises(InputError, match="variable 'expanded_uncertainty': attribute 'comment' .*U\\+001B"):
        write_artefact(ds, tmp_path / "bad.nc")
    assert not (tmp_path / "bad.nc").exists()


def test_dcc_of_a_certificate_sealed_with_a_control_character_is_refused(inputs, tmp_path, capsys,
                                                                         monkeypatch):
    """A certificate sealed with ``--creator $'\\a'`` (older lidarcal): a clear refusal, no ValueError."""
    ds = open_artefact(inputs["cert"])
    ds = ds.assign_attrs(creator_name="Eve\a")
    for key in [k for k in ds.attrs if k.startswith(("lidarcal_integrity", "lidarcal_source_"))]:
        del ds.attrs[key]
    import lidarcal.io

    path = tmp_path / "old.nc"
    with monkeypatch.context() as m:
        m.setattr(lidarcal.io, "text_problems", lambda ds: [])  # written as an older lidarcal did
        write_certificate(ds, path)
    code, _, err = _run(capsys, "dcc", path, "-o", tmp_path / "old.xml")
    assert code == 2 and "Traceback" not in err, err
    assert f"{path.name}: global attribute 'creator_name'" in err and "U+0007" in err, err
    assert not (tmp_path / "old.xml").exists()


def test_deeply_nested_admin_is_refused(inputs, tmp_path, capsys):
    deep = tmp_path / "deep.yaml"
    levels = sys.getrecursionlimit() * 2  # deeper than any recursive reader can go
    deep.write_text("customer:\n  name: " + "[" * levels + "]" * levels + "\n")
    for argv in (["dcc", inputs["cert"], "-o", tmp_path / "x.xml", "--admin", deep],
                 ["certificate", "--budget", inputs["budget"], "--sensitivity", inputs["sens"],
                  "--demonstration", "-o", tmp_path / "c.nc", "--admin", deep]):
        code, _, err = _run(capsys, *argv)
        assert code == 2 and "Traceback" not in err and "RecursionError" not in err, err
        assert f"{deep}: line 2: administrative data nested deeper than 3 levels" in err, err
    assert not (tmp_path / "x.xml").exists() and not (tmp_path / "c.nc").exists()
    # the deepest legal structure (a list of persons, each a mapping) still reads
    legal = tmp_path / "legal.yaml"
    legal.write_text(yaml.safe_dump({"responsible_persons": [{"name": "A. Engineer", "role": "engineer"}],
                                     "laboratory": {"country_code": "FR"}}))
    code, _, err = _run(capsys, "dcc", inputs["cert"], "-o", tmp_path / "x.xml", "--admin", legal)
    assert code == 0, err
    # nested data given from Python (not a file) is bounded the same way
    from lidarcal.certificate.admin import parse_admin

    nested: list = []
    for _ in range(10_000):
        nested = [nested]
    with pytest.raises(InputError, match="nested deeper than 3 levels"):
        parse_admin({"customer": {"name": nested}}, "given")


def test_dcc_on_a_full_disk_is_one_clear_error(inputs, tmp_path, capsys, monkeypatch):
    """ENOSPC while the XML is written: exit 2, the message of every other writer, nothing left."""
    real = Path.write_bytes

    def write_bytes(self, data):
        if self.name.startswith(".cert.xml."):
            real(self, data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    out = tmp_path / "cert.xml"
    code, _, err = _run(capsys, "dcc", inputs["cert"], "-o", out)
    assert code == 2 and "Traceback" not in err, err
    assert f"no space left on device writing {out}" in err and "nothing was written" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == []
