"""The method pages whose figures come from lidarcal or the paper's equations run here.

Every number these pages quote is printed by a ``pycon`` block on the page (see
:func:`test_walkthroughs.run_page`), so a change of lidarcal that moves one fails its page.
"""

from test_walkthroughs import run_page


def test_noise_terms_page(tmp_path, monkeypatch):
    assert run_page("noise_terms.md", tmp_path, monkeypatch) >= 6


def test_wfr_page(tmp_path, monkeypatch):
    assert run_page("wfr.md", tmp_path, monkeypatch) >= 2


def test_units_page(tmp_path, monkeypatch):
    assert run_page("units.md", tmp_path, monkeypatch) >= 5


def test_sensitivity_page(tmp_path, monkeypatch):
    assert run_page("sensitivity.md", tmp_path, monkeypatch) >= 3
