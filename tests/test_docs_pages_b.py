"""The diagnose and contracts pages are executed, so the numbers they quote cannot go stale.

Each page's ``pycon`` blocks print the defaults, thresholds and ranges the prose quotes from
the code (the command line's parser, the effect catalogue, the schemas, the lidar model) and
compute the rest on small data (the sample bench run, a two-period conditions record); the
runner is :func:`tests.test_walkthroughs.run_page`.
"""

from test_walkthroughs import ROOT, run_page

SAMPLE = {"sample_data/": f"{ROOT / 'sample_data'}/"}  # the pages name the repository's sample files


def test_diagnose_page(tmp_path, monkeypatch):
    data = {"tests/data/": f"{ROOT / 'tests' / 'data'}/"}  # the stored fit set of the hybrid weight's share
    assert run_page("diagnose.md", tmp_path, monkeypatch, replace=data) >= 4


def test_contracts_page(tmp_path, monkeypatch):
    assert run_page("contracts.md", tmp_path, monkeypatch, replace=SAMPLE) >= 4
