"""Checks shared by the diagnose tests (a test helper): the note and the answer agree.

``docs/diagnose.md``: the note ends with ``named: <ids>`` (``named: none`` when nothing is
named) and lists every strong candidate that is not named as ``minor: <id> (...)``.
"""

import re


def note_names(note: str) -> tuple[list[str], list[str]]:
    """(named, minor) catalogue ids as the note states them."""
    match = re.search(r"named: ([a-z_, ]+)$", note)
    assert match, f"the note does not end with 'named: ...': {note!r}"
    named = [] if match.group(1) == "none" else match.group(1).split(", ")
    return named, re.findall(r"minor: ([a-z_]+) \(", note)


def assert_note_matches_answer(js: dict) -> None:
    """The note and the ``--json`` answer never contradict each other."""
    named, minor = note_names(js["note"])
    ids = [e["effect"] for e in js["effects"]]
    assert named == ids, (named, ids, js["note"])
    assert js["effect"] == (ids[0] if ids else js["effect"]) and js["effect"] not in ("none", "unexplained") \
        if ids else js["effect"] in ("none", "unexplained"), (js["effect"], ids)
    assert minor == [m["effect"] for m in js["minor"]], (minor, js["minor"], js["note"])
    for eid in ids:  # a named effect is never said to be dropped, refused at the end or immaterial
        assert f"{eid} dropped" not in js["note"] and eid not in minor, (eid, js["note"])
    if js["effect"] == "none" and js["significant"]:
        assert "within the tolerance" in js["note"], js["note"]
