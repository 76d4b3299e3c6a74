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


def test_diagnose_page_shows_the_catalogue():
    # the effect table of docs/diagnose.md is the catalogue's own (declared once, in EFFECTS)
    from lidarcal.diagnose.effects import EFFECTS, catalogue_table

    lines = (ROOT / "docs" / "diagnose.md").read_text(encoding="utf-8").splitlines()
    start = lines.index("## The effect catalogue")
    first = next(i for i in range(start, len(lines)) if lines[i].startswith("|"))
    end = next(i for i in range(first, len(lines)) if not lines[i].startswith("|"))
    table = catalogue_table()
    assert "\n".join(lines[first:end]) == table, (
        "docs/diagnose.md's effect table is not the catalogue's; replace it with\n" + table)
    # one row per effect, header and rule apart, in the catalogue's order with none last
    ids = [row.split("|")[1].strip().strip("`") for row in table.splitlines()[2:]]
    assert ids == [e for e in EFFECTS if e != "none"] + ["none"]
