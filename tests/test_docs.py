"""Everything the repository cites exists in the repository, and the README stays a front door.

* No file points to a document outside the repository (the old design and style notes, or a
  sibling ``shared`` directory): the project's own documentation is ``docs/``.
* Every repository path cited anywhere (``docs/seeds.md``, ``tests/test_terms.py``,
  ``schemas/rwf.yaml``, ...) exists; a glob such as ``tests/test_lidar*.py`` matches something.
* Links between the pages of ``docs/`` resolve, including their ``#anchors``.
* Every dotted ``lidarcal.…`` name in the Markdown documentation can be imported.
* The README is short (under 8 KB), its quick start is two commands, the second exactly the
  test command of ``.ci/run``, and every page of ``docs/`` is reachable from the docs index.
"""

from __future__ import annotations

import importlib
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

# Built from pieces so that this file does not contain the strings it forbids.
FORBIDDEN = ("DESIGN" + ".md", "STYLE" + ".md", ".." + "/shared")
#: The same documents cited by a section number (the word, then a digit or a section sign).
FORBIDDEN_SECTION = re.compile("DESIGN" + r"\s*(?:§|\d)")
_TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".cfg", ".ini", ".csv", ""}
_SKIP_DIRS = {".git", ".pytest_cache", ".ruff_cache", ".hypothesis", ".benchmarks", "__pycache__"}

#: A path into the repository's own top-level folders, not preceded by a path character.
CITED_PATH = re.compile(
    r"(?<![\w/.\-])((?:docs|tests|schemas|benchmarks|sample_data|lidarcal)/[\w.*/\-]*\.(?:md|py|yaml|csv|nc|gz))"
)
DOTTED_NAME = re.compile(r"(?<![\w.])(lidarcal(?:\.[A-Za-z_]\w*)+)")
MD_LINK = re.compile(r"\]\(([^)\s]+)\)")


def tracked_files(root: Path = ROOT) -> list[Path]:
    """Text files of the repository: ``git ls-files`` when available, else a walk of ``root``."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True, check=True).stdout
        names = [n for n in out.decode().split("\0") if n]
    except (OSError, subprocess.CalledProcessError):
        names = [str(p.relative_to(root)) for p in root.rglob("*")
                 if p.is_file() and not _SKIP_DIRS & set(p.relative_to(root).parts)]
    paths = [root / n for n in names]
    return [p for p in paths if p.suffix in _TEXT_SUFFIXES and p.is_file()]


def read_text(path: Path) -> str | None:
    """File contents, or None for a binary file."""
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        return None


def outside_references(files: list[Path], root: Path = ROOT) -> list[str]:
    """``file:line: text`` for every line that mentions a document outside the repository."""
    found = []
    for path in files:
        text = read_text(path)
        for n, line in enumerate((text or "").splitlines(), 1):
            if any(word in line for word in FORBIDDEN) or FORBIDDEN_SECTION.search(line):
                found.append(f"{path.relative_to(root)}:{n}: {line.strip()}")
    return found


def missing_cited_paths(files: list[Path], root: Path = ROOT) -> list[str]:
    """``file: path`` for every cited repository path that does not exist (globs must match)."""
    missing = []
    for path in files:
        for cited in sorted(set(CITED_PATH.findall(read_text(path) or ""))):
            exists = any(root.glob(cited)) if "*" in cited else (root / cited).exists()
            if not exists:
                missing.append(f"{path.relative_to(root)}: {cited}")
    return missing


def _anchors(markdown: str) -> set[str]:
    """GitHub-style anchors of the headings of a Markdown page."""
    out = set()
    for line in markdown.splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            title = re.sub(r"[^\w\- ]", "", title)
            out.add(title.replace(" ", "-"))
    return out


def test_the_scanners_find_what_they_look_for(tmp_path):
    # the checks below are only worth something if the scanners do flag a planted offence
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "README.md").write_text("x")
    gone, gone_glob = "docs/" + "gone.md", "tests/" + "test_gone*.py"  # pieces: this file is scanned too
    bad = tmp_path / "mod.py"
    section = "DESIGN" + " 3.2"
    bad.write_text(f"# see {FORBIDDEN[0]} 3.1\n# and docs/README.md, {gone}, {gone_glob}\n# {section}\n")
    expected = [f"mod.py:1: # see {FORBIDDEN[0]} 3.1", f"mod.py:3: # {section}"]
    assert outside_references([bad], tmp_path) == expected
    assert missing_cited_paths([bad], tmp_path) == [f"mod.py: {gone}", f"mod.py: {gone_glob}"]
    # a path inside another path (an output directory, a URL) is not a citation
    assert CITED_PATH.findall("lidarcal-output/docs/x.md https://x.org/docs/y.md") == []


def test_no_file_points_outside_the_repository():
    files = tracked_files()
    assert len(files) > 50  # the scan really covered the repository
    assert outside_references(files) == []


def test_every_cited_repository_path_exists():
    files = tracked_files()
    assert any(CITED_PATH.search(read_text(p) or "") for p in files if p.suffix == ".py")
    assert missing_cited_paths(files) == []


def test_docs_pages_exist_and_their_links_resolve():
    pages = sorted(DOCS.glob("*.md"))
    names = {p.name for p in pages}
    assert {"README.md", "contracts.md", "diagnose.md", "seeds.md", "units.md"} <= names
    broken = []
    for page in [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *pages]:
        for target in MD_LINK.findall(page.read_text(encoding="utf-8")):
            if re.match(r"[a-z]+:", target):
                continue  # an external URL
            file, _, anchor = target.partition("#")
            dest = (page.parent / file).resolve() if file else page
            if not dest.exists():
                broken.append(f"{page.name}: {target}")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest.read_text(encoding="utf-8")):
                broken.append(f"{page.name}: {target} (no such heading)")
    assert broken == []


def quick_start_commands(readme: str) -> list[str]:
    """The fenced commands of the README's quick-start section, one per block."""
    section = readme.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    return [block.strip() for block in re.findall(r"^```\n(.*?)^```", section, re.M | re.S)]


def test_the_readme_is_a_front_door():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.encode("utf-8")) < 8 * 1024, "README.md over 8 KB: move the detail into a docs/ page"
    install_and_run, install_and_test = quick_start_commands(readme)  # two commands, no more
    assert install_and_run == "pip install . && lidarcal calibrate"
    install, test = install_and_test.split(" && ")
    assert (install, test) == ('pip install -e ".[test]"', "python -m pytest")
    # .ci/run installs the same way and runs exactly the README's test command (then the slow suite)
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    lines = [line for line in ci if line.endswith(f"&& {test}")]
    assert len(lines) == 1 and '-e ".[test]"' in lines[0], lines


def test_every_docs_page_is_in_the_index():
    index = (DOCS / "README.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"\]\(([\w\-]+\.md)\)", index))
    assert listed == {p.name for p in DOCS.glob("*.md")} - {"README.md"}


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for name in parts[i:]:
                obj = getattr(obj, name)
        except AttributeError:
            return False
        return True
    return False


PAGES = ["README.md", "CONTRIBUTING.md", *sorted(f"docs/{p.name}" for p in DOCS.glob("*.md"))]


@pytest.mark.parametrize("page", PAGES)
def test_every_lidarcal_name_in_the_documentation_imports(page):
    text = (ROOT / page).read_text(encoding="utf-8")
    names = sorted(set(DOTTED_NAME.findall(text)))
    assert [n for n in names if not _resolves(n)] == []


# -- the docstring examples of the library run with the default suite ---------------------------

#: A doctest directive that keeps an example from running (``+SKIP``), in any spelling.
SKIPPED_EXAMPLE = re.compile(r"doctest:.*\+SKIP")


def skipped_examples(root: Path) -> list[str]:
    """``file:line`` of every docstring example under ``root`` marked not to run."""
    return [f"{path.relative_to(root.parent)}:{n}"
            for path in sorted(root.rglob("*.py"))
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if SKIPPED_EXAMPLE.search(line)]


def test_the_default_suite_runs_the_docstring_examples():
    import tomllib

    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    config = pyproject["tool"]["pytest"]["ini_options"]
    assert "--doctest-modules" in config["addopts"].split()
    assert "lidarcal" in config["testpaths"]


def test_no_docstring_example_is_skipped(tmp_path):
    # an example that does not run goes stale: it runs on small data, moves to a docs page, or goes
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "m.py").write_text('"""\n>>> 1 + 1\n2\n>>> heavy()  # doctest: +SKIP\n"""\n')
    assert skipped_examples(pkg) == ["pkg/m.py:4"]  # the scanner finds a planted one
    assert skipped_examples(ROOT / "lidarcal") == []
