"""A certificate's numbers are shown only after its seal is checked.

Issue 20, item 3: ``lidarcal table`` printed a tampered certificate (uncertainties halved in
place, seal left as it was) as if it were valid.  Every command or function that shows a
certificate's numbers (``table``, the HTML report, ``result_table``, ``open_certificate``)
now refuses it (exit 2, a message naming the file and what changed), or with an explicit
``--allow-invalid`` / ``allow_invalid=True`` shows them under a warning banner.  Signing keys
readable by others (item 10) are refused too.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import xarray as xr
from analysis_factories import make_records

import lidarcal
from lidarcal.analysis import budget, sensitivity
from lidarcal.analysis.terms import PAPER_INPUTS, TABLE4_WIND_SPEEDS, uncertainty_terms
from lidarcal.certificate import make_certificate, result_table
from lidarcal.certificate.document import write_document
from lidarcal.certificate.report import write_report
from lidarcal.certificate.seal import INTEGRITY_ATTR, require_valid_seal, write_certificate
from lidarcal.cli import main
from lidarcal.errors import InputError, SealError
from lidarcal.io import open_artefact, write_artefact

HALVED = ("budget_uncertainty", "budget_expanded_uncertainty", "budget_relative_expanded_uncertainty")


@pytest.fixture(scope="module")
def sealed(tmp_path_factory):
    d = tmp_path_factory.mktemp("seal-check")
    make_records(n=300).to_netcdf(d / "records.nc")
    records = open_artefact(d / "records.nc")
    out = {"budget": write_artefact(budget(records), d / "budget.nc"),
           "sens": write_artefact(sensitivity(records, "wind_shear_exponent"), d / "sens.nc"),
           # Table 4 terms: text variables stored as netCDF variable-length strings, which the
           # SIGSEGV of issue 27 needed (a second open reading them while a first was open)
           "terms": write_artefact(uncertainty_terms(TABLE4_WIND_SPEEDS, **PAPER_INPUTS), d / "terms.nc")}
    cert = make_certificate(budget=open_artefact(out["budget"]), sensitivities=[open_artefact(out["sens"])],
                            demonstration=True)  # test data: no issuer
    out["cert"] = write_certificate(cert, d / "cert.nc")
    # with the terms: opened only in child processes below, so that a crash fails a test, not pytest
    parts = {"budget": open_artefact(out["budget"]), "sensitivities": [open_artefact(out["sens"])]}
    with_terms = make_certificate(**parts, terms=open_artefact(out["terms"]), demonstration=True)
    out["cert_terms"] = write_certificate(with_terms, d / "cert_terms.nc")
    return out


@pytest.fixture
def tampered(sealed, tmp_path):
    """The certificate with its uncertainties halved in place (the seal left as it was)."""
    path = tmp_path / "tampered.nc"
    path.write_bytes(sealed["cert"].read_bytes())
    with netCDF4.Dataset(path, "a") as nc:
        for name in HALVED:
            nc[name][...] = nc[name][...] / 2
    return path


def _run(capsys, *argv):
    capsys.readouterr()
    code = main(list(map(str, argv)))
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.parametrize("fmt", ["csv", "md", "html"])
def test_table_refuses_a_tampered_certificate(tampered, capsys, tmp_path, fmt):
    code, out, err = _run(capsys, "table", tampered, "--format", fmt)
    assert code == 2, err
    assert out == ""  # not one number shown
    assert f"{tampered}: refusing to show this certificate's numbers" in err
    assert "'budget_expanded_uncertainty': values altered" in err and "--allow-invalid" in err
    code, out, err = _run(capsys, "table", tampered, "-o", tmp_path / f"t.{fmt}")
    assert code == 2 and not (tmp_path / f"t.{fmt}").exists()


def test_table_allow_invalid_shows_a_banner(sealed, tampered, capsys, tmp_path):
    code, out, err = _run(capsys, "table", tampered, "--allow-invalid")
    assert code == 0, err
    assert out.startswith("# WARNING: INVALID CERTIFICATE") and "NOT certified" in out.splitlines()[0]
    assert "WARNING: INVALID CERTIFICATE" in err
    code, md, _ = _run(capsys, "table", tampered, "--allow-invalid", "--format", "md")
    assert code == 0 and md.startswith("**WARNING: INVALID CERTIFICATE")
    # the halved numbers are what is shown: the banner is about these very numbers
    code, good, _ = _run(capsys, "table", sealed["cert"])
    assert code == 0 and not good.startswith("#")
    col = [c for c in good.splitlines()[0].split(",") if c.endswith("_m_s") and "expanded" in c][0]
    import io

    import pandas as pd
    shown = pd.read_csv(io.StringIO(out), comment="#")[col].to_numpy()
    truth = pd.read_csv(io.StringIO(good))[col].to_numpy()
    np.testing.assert_allclose(shown, truth / 2)


def test_table_refuses_an_unsealed_certificate(sealed, tmp_path, capsys):
    path = tmp_path / "unsealed.nc"
    path.write_bytes(sealed["cert"].read_bytes())
    with netCDF4.Dataset(path, "a") as nc:
        nc.delncattr(INTEGRITY_ATTR)
    code, out, err = _run(capsys, "table", path)
    assert code == 2 and out == "" and f"'{INTEGRITY_ATTR}' is missing" in err


def test_result_table_and_report_check_the_seal(sealed, tampered, tmp_path):
    assert len(result_table(xr.open_dataset(sealed["cert"]))) > 0
    with pytest.raises(SealError, match="values altered"):
        result_table(xr.open_dataset(tampered))
    with pytest.raises(SealError, match="values altered"):
        write_report(tmp_path / "r.html", certificate=open_artefact(tampered), png=False)
    assert not (tmp_path / "r.html").exists()
    write_report(tmp_path / "r.html", certificate=open_artefact(tampered), png=False, allow_invalid=True)
    assert "WARNING: INVALID CERTIFICATE" in (tmp_path / "r.html").read_text()
    with pytest.raises(SealError, match="values altered"):
        lidarcal.open_certificate(tampered)
    tree = lidarcal.open_certificate(tampered, allow_invalid=True)
    assert "INVALID CERTIFICATE" in tree.attrs["lidarcal_seal_problems"]
    assert "lidarcal_seal_problems" not in lidarcal.open_certificate(sealed["cert"]).attrs
    # a certificate being built (in memory, not yet sealed) has nothing to check
    fresh = make_certificate(budget=open_artefact(sealed["budget"]),
                             sensitivities=[open_artefact(sealed["sens"])], demonstration=True)
    assert require_valid_seal(fresh) is None
    # a sealed dataset whose file is unknown cannot be checked: refused
    detached = xr.open_dataset(sealed["cert"]).load()
    detached.encoding = {}
    with pytest.raises(SealError, match="cannot be checked"):
        require_valid_seal(detached)


def test_the_certificate_document_checks_the_seal(sealed, tampered, tmp_path, poppler):
    """write_document on its own (not through write_report): refused, or the warning on every page."""
    with pytest.raises(SealError, match="values altered"):
        write_document(tmp_path / "d.pdf", open_artefact(tampered))
    assert list(tmp_path.glob("*.pdf")) == []
    written = write_document(tmp_path / "d.pdf", open_artefact(tampered), allow_invalid=True)
    pages = subprocess.run([poppler[1], str(written["pdf"]), "-"], capture_output=True, text=True,
                           check=True).stdout.split("\f")[:written["pages"]]
    assert "WARNING: INVALID CERTIFICATE" in pages[0]
    assert all("INVALID SEAL: these numbers are NOT certified" in p for p in pages), len(pages)
    intact = write_document(tmp_path / "s.pdf", open_artefact(sealed["cert"]))
    text = subprocess.run([poppler[1], str(intact["pdf"]), "-"], capture_output=True, text=True,
                          check=True).stdout
    assert "INVALID" not in text


def test_signing_key_readable_by_others_is_refused(sealed, tmp_path, capsys):
    """Item 10: like ssh, a private key others can read is not used (exit 2, nothing written)."""
    key = tmp_path / "KEY"
    assert main(["keygen", "-o", str(key)]) == 0
    os.chmod(key, 0o644)
    out = tmp_path / "c.nc"
    code, _, err = _run(capsys, "certificate", "--budget", sealed["budget"], "--sensitivity", sealed["sens"],
                        "-o", out, "--sign", key, "--demonstration")
    assert code == 2 and not out.exists()
    assert f"{key}: private key is readable or writable by others (mode 0644)" in err and "chmod 600" in err
    os.chmod(key, 0o640)  # group-readable: refused as well
    with pytest.raises(InputError, match="mode 0640"):
        from lidarcal.certificate.signing import load_private_key
        load_private_key(key)
    os.chmod(key, 0o600)
    code, _, err = _run(capsys, "certificate", "--budget", sealed["budget"], "--sensitivity", sealed["sens"],
                        "-o", out, "--sign", key, "--demonstration")
    assert code == 0, err


# ------------------------------------------------------------------ issue 27: no crash, trees accepted


def _child(code: str, *args: str, cwd):
    """Run ``code`` in a new Python with this lidarcal (the one under test), so a crash is an exit code."""
    import subprocess
    import sys

    here = str(Path(lidarcal.__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd, env=env)


_OPEN_IN_A_CHILD = """
import sys
import lidarcal
path, allow = sys.argv[1], sys.argv[2] == "allow"
try:
    tree = lidarcal.open_certificate(path, allow_invalid=allow)
except lidarcal.errors.SealError as exc:
    print("SealError", exc)
    sys.exit(3)
print("opened", "lidarcal_seal_problems" in tree.attrs, float(tree["budget"]["expanded_uncertainty"].max()))
"""


@pytest.mark.parametrize("allow", ["allow", "refuse"])
@pytest.mark.parametrize("how", ["halved", "attribute"])
def test_open_certificate_on_a_broken_seal_refuses_or_opens_never_crashes(sealed, tmp_path, how, allow):
    """Issue 27: SIGSEGV (exit -11) on a seal that exists but does not match, with or without allow_invalid.

    The cause: verifying reopened the file through netCDF-C while open_certificate held it open,
    and a variable-length string (``terms_equation``) read through the second open corrupted
    the file object HDF5 shares between the opens; the next open died.  Run in a child process,
    so a crash fails this test instead of killing pytest.
    """
    path = tmp_path / f"{how}.nc"
    path.write_bytes(sealed["cert_terms"].read_bytes())
    with netCDF4.Dataset(path, "a") as nc:
        if how == "attribute":
            nc.setncattr("item_serial_number", "FORGED-1")
        else:
            for name in HALVED:
                nc[name][...] = nc[name][...] / 2
        assert nc["terms_equation"].dtype is str  # the variable-length strings are there
    done = _child(_OPEN_IN_A_CHILD, str(path), allow, cwd=tmp_path)
    assert done.returncode in (0, 3), f"exit {done.returncode} (negative: killed by a signal)\n{done.stderr}"
    if allow == "allow":
        assert done.returncode == 0 and done.stdout.startswith("opened True"), done.stdout
    else:
        what = ("'item_serial_number' altered" if how == "attribute"
                else "'budget_expanded_uncertainty': values altered")
        assert done.returncode == 3 and what in done.stdout, done.stdout


def test_a_reader_holding_the_certificate_open_does_not_crash_the_check(sealed, tmp_path):
    """A Dataset the caller keeps open on the same file (its text read) does not crash verification."""
    tampered = tmp_path / "tampered.nc"
    tampered.write_bytes(sealed["cert_terms"].read_bytes())
    with netCDF4.Dataset(tampered, "a") as nc:
        for name in HALVED:
            nc[name][...] = nc[name][...] / 2
    code = (f"import xarray as xr, lidarcal\nheld = xr.open_dataset({str(tampered)!r})\n"
            "held['terms_equation'].values\n"
            f"for _ in range(3):\n    print(len(lidarcal.verify({str(tampered)!r}).problems))\n"
            f"print(float(xr.open_dataset({str(tampered)!r})['budget_expanded_uncertainty'].max()))")
    done = _child(code, cwd=tmp_path)
    assert done.returncode == 0, f"exit {done.returncode}\n{done.stderr}"
    assert done.stdout.split()[:3] == ["3", "3", "3"]  # the three halved variables, every time


def test_result_table_accepts_what_open_certificate_returns(sealed, tampered):
    """Issue 27: ``result_table(open_certificate(path))`` raised a SealError naming ``<dataset>``."""
    import pandas as pd

    tree = lidarcal.open_certificate(sealed["cert"])
    from_tree = lidarcal.result_table(tree)
    from_flat = lidarcal.result_table(xr.open_dataset(sealed["cert"]))
    pd.testing.assert_frame_equal(from_tree, from_flat)  # the same table either way
    assert len(from_tree) == tree["budget"].sizes["height"] * tree["budget"].sizes["wind_speed"]
    # a tree opened with allow_invalid is still refused by a reader not told to allow it
    bad = lidarcal.open_certificate(tampered, allow_invalid=True)
    with pytest.raises(SealError, match=f"{tampered}: refusing .* values altered"):
        lidarcal.result_table(bad)
    shown = lidarcal.result_table(bad, allow_invalid=True)
    col = [c for c in shown.columns if c.startswith("expanded_uncertainty_k") and c.endswith("_m_s")][0]
    np.testing.assert_allclose(shown[col], from_flat[col] / 2)


# ------------------------------------------------------------------ the promise, enumerated (issue 27)
#
# docs/reliability.md: every command and public function that shows a certificate's numbers
# checks its seal first.  The commands are read from the argparse parser and the functions from
# the public modules' ``__all__``: a new one fails here until it is placed in one of the tables.


def _leaf_commands(parser, prefix=()):
    """Yield ``(("bench", "simulate"), parser)`` for every runnable subcommand of the parser."""
    import argparse

    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield prefix, parser
        return
    for action in subs:
        for name, sub in action.choices.items():
            yield from _leaf_commands(sub, (*prefix, name))


_SAMPLE_STA = Path(__file__).resolve().parents[1] / "sample_data" / "sta" / "example_newer.sta"

#: Commands that read a certificate: argv on the tampered file, the exit status, what it must say.
SHOWS_A_CERTIFICATE = {
    ("table",): (lambda cert, tmp: ["table", cert], 2, "refusing to show this certificate's numbers"),
    ("dcc",): (lambda cert, tmp: ["dcc", cert, "-o", tmp / "x.xml"], 2, "refusing to export this"),
    ("verify",): (lambda cert, tmp: ["verify", cert], 1, "ALTERED or invalid"),
    # the campaign's files are never read: the seal is checked before anything else
    ("smc",): (lambda cert, tmp: ["smc", cert, _SAMPLE_STA, "-o", tmp / "s.nc", "--no-monte-carlo",
                                  "--report", tmp / "s.html"],
               2, "refusing to show this certificate's numbers"),
    # shows no number, but its "ok" would vouch for the file: the seal is part of its check
    ("validate",): (lambda cert, tmp: ["validate", "--no-compliance", cert], 1, "tampered.nc: FAIL"),
}
#: Commands that take no certificate, or show none of its numbers, and why.
NO_CERTIFICATE_SHOWN = {
    ("calibrate",): "writes a certificate, reads none",
    ("bench", "simulate"): "bench data only",
    ("bench", "ingest"): "bench data only",
    ("bench", "repeatability"): "bench cubes only",
    ("rwf",): "a pulse recording only",
    ("terms",): "numbers given on the command line",
    ("conditions", "check"): "a conditions file only",
    ("conditions", "synthetic"): "writes conditions",
    ("conditions", "from-sta"): ".sta files only",
    ("field", "from-sta"): ".sta files and a mast record",
    ("turbulence",): "writes a turbulence box",
    ("simulate",): "conditions, cube and RWF",
    ("sensitivity",): "simulated or field records",
    ("budget",): "simulated or field records",
    ("sweep",): "writes a sweep",
    ("certificate",): "writes and seals a certificate from its components; reads none",
    ("keygen",): "writes keys",
    ("diagnose",): "a field campaign",
    ("diagnose-generate",): "writes a field campaign",
    ("compare",): "a field campaign and a lidar's components",
}


def test_every_command_that_shows_a_certificate_checks_its_seal(tampered, tmp_path, capsys):
    from lidarcal.cli import build_parser

    leaves = dict(_leaf_commands(build_parser()))
    unclassified = sorted(set(leaves) - set(SHOWS_A_CERTIFICATE) - set(NO_CERTIFICATE_SHOWN))
    assert unclassified == [], (f"new command(s) {unclassified}: does it show a certificate's numbers? "
                                "Call lidarcal.certificate.seal.require_valid_seal first and add it to "
                                "SHOWS_A_CERTIFICATE, or say why not in NO_CERTIFICATE_SHOWN")
    assert sorted(set(SHOWS_A_CERTIFICATE) | set(NO_CERTIFICATE_SHOWN)) == sorted(leaves)  # none gone
    # an input named like a certificate (not the -o of the command that writes one) is read
    for name, parser in leaves.items():
        for action in parser._actions:
            meta = action.metavar
            meta = " ".join(meta) if isinstance(meta, tuple) else str(meta or "")
            if meta.upper().startswith("CERT") and meta.endswith(".nc") and action.dest != "output":
                assert name in SHOWS_A_CERTIFICATE, f"{' '.join(name)} reads {meta}: it must check the seal"
    outputs = tmp_path / "outputs"
    outputs.mkdir()
    for name, (argv, status, says) in SHOWS_A_CERTIFICATE.items():
        code, out, err = _run(capsys, *argv(tampered, outputs))
        assert code == status, (name, err)
        assert says in out + err, (name, out, err)
        assert "'budget_expanded_uncertainty': values altered" in out + err, (name, out, err)
        if status == 2:
            assert out == "" and list(outputs.iterdir()) == [], name  # not one number, no file


def _readers():
    """Public functions that show a certificate's numbers: how to call each on a certificate file."""
    from lidarcal.certificate.dcc.export import dcc_tree, write_dcc
    from lidarcal.smc import smc

    return {
        "lidarcal.open_certificate": lambda p, tmp: lidarcal.open_certificate(p),
        "lidarcal.result_table": lambda p, tmp: lidarcal.result_table(xr.open_dataset(p)),
        "lidarcal.certificate.open_certificate": lambda p, tmp: lidarcal.certificate.open_certificate(p),
        "lidarcal.certificate.result_table": lambda p, tmp: result_table(open_artefact(p)),
        "lidarcal.certificate.dcc.write_dcc": lambda p, tmp: write_dcc(p, tmp / "x.xml"),
        "lidarcal.certificate.dcc.dcc_tree": lambda p, tmp: dcc_tree(open_artefact(p),
                                                                     certificate_sha256="0" * 64),
        "lidarcal.certificate.report.write_report": lambda p, tmp: write_report(
            tmp / "r.html", certificate=open_artefact(p)),
        "lidarcal.smc.smc": lambda p, tmp: smc(p, [_SAMPLE_STA], monte_carlo=False),
        "lidarcal.certificate.document.write_document": lambda p, tmp: write_document(tmp / "r.pdf",
                                                                                      open_artefact(p)),
    }


#: Public names that show no certificate's numbers on their own, and why.
NOT_READERS = {
    "lidarcal.verify": "the check itself (VerificationReport lists what changed)",
    "lidarcal.calibrate": "writes a certificate", "lidarcal.CalibrationConfig": "configuration",
    "lidarcal.CalibrationResult": "a run's result (its certificate built in that run)",
    "lidarcal.open_artefact": "any artefact; numbers of a certificate go through the readers",
    "lidarcal.LidarModel": "lidar model", "lidarcal.simulate_campaign": "simulation",
    "lidarcal.sensitivity": "analysis", "lidarcal.budget": "analysis",
    "lidarcal.diagnose_campaign": "analysis",
    "lidarcal.make_certificate": "builds one (in memory, unsealed)",
    "lidarcal.certificate.make_certificate": "builds one (in memory, unsealed)",
    "lidarcal.certificate.extract_component": "the flat layout's accessor on a Dataset the caller opened "
                                              "through a reader",
    "lidarcal.certificate.components": "the list of components (names and files), no numbers",
    "lidarcal.certificate.container_attributes": "a provenance variable's attributes",
    "lidarcal.certificate.provenance_chain": "provenance (files, SHA-256), no numbers",
    "lidarcal.certificate.records_summary": "how many periods, which heights",
    "lidarcal.certificate.PROVENANCE_PREFIX": "a constant",
    "lidarcal.certificate.headline_range": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.headline_sentence": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.certified_rule": "the rule in words",
    "lidarcal.certificate.not_settled": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.headline_text": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.not_settled_sentence": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.not_settled_items": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.HEADLINE_LABEL": "a constant (the label before the headline)",
    "lidarcal.certificate.model_form_values": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.model_form_summary": "a budget's helper, called by the readers after their check",
    "lidarcal.certificate.MEASURAND": "a constant (the measurand in words)",
    "lidarcal.certificate.dcc.validate_dcc": "checks an XML against the XSD",
    "lidarcal.certificate.dcc.dcc_attributes": "the attributes dcc_tree states, after dcc_tree's check",
    "lidarcal.certificate.dcc.DCC_NS": "a constant", "lidarcal.certificate.dcc.SI_NS": "a constant",
    "lidarcal.certificate.dcc.DCC_SCHEMA_VERSION": "a constant",
    "lidarcal.certificate.dcc.SI_SCHEMA_URL": "a constant",
    "lidarcal.certificate.dcc.COVERAGE_PROBABILITY": "a constant",
    "lidarcal.certificate.report.report_figures": "figures of components the caller passes",
    "lidarcal.certificate.report.Figure": "a class",
    "lidarcal.smc.smc_dataset": "the artefact of what smc computed (after smc's check)",
    "lidarcal.smc.binned": "an smc artefact's per-bin view, no certificate read",
    "lidarcal.smc.binned_table": "an smc artefact's table, no certificate read",
    "lidarcal.certificate.document.parts_of": "the components of a certificate the caller opened through a "
                                              "reader",
    "lidarcal.certificate.document.seal_statement": "a sentence about a seal, no numbers",
    "lidarcal.certificate.document.fmt": "formats a number",
    "lidarcal.certificate.document.units_suffix": "formats a unit",
    "lidarcal.certificate.document.VARIABLE_NAMES": "a constant",
}


def test_every_public_reader_checks_the_seal(tampered, tmp_path):
    import importlib

    public = {f"lidarcal.{n}" for n in lidarcal.__all__ if n != "__version__"}
    for module in ("lidarcal.certificate", "lidarcal.certificate.dcc", "lidarcal.certificate.report",
                   "lidarcal.certificate.document", "lidarcal.smc"):
        public |= {f"{module}.{n}" for n in importlib.import_module(module).__all__}
    readers = _readers()
    unclassified = sorted(public - set(readers) - set(NOT_READERS))
    assert unclassified == [], (f"new public name(s) {unclassified}: if it shows a certificate's numbers, "
                                "call require_valid_seal and add it to _readers(); else say why in "
                                "NOT_READERS")
    assert sorted(set(readers) | set(NOT_READERS)) == sorted(public)  # nothing listed that is gone
    outputs = tmp_path / "outputs"
    outputs.mkdir()
    for name, call in readers.items():
        with pytest.raises(SealError, match="values altered"):
            call(tampered, outputs)
        assert list(outputs.iterdir()) == [], name  # nothing written
