"""The pages of docs/ with examples are executed, so their commands and numbers cannot rot.

Walk-throughs (steward, analyst, cluster user) and the method and validation pages run in the
default suite; the heavy pages (the command line stage by stage, the diagnose examples, the
benchmark commands, the certificate's metadata options) are slow tests.  A page with examples
that no test runs fails :func:`test_every_page_with_examples_is_executed`.

Every fenced block whose info string is ``console`` or ``pycon`` runs, in page order, in one
temporary directory per page:

- ``console``: each ``$ `` line is a command (``lidarcal`` and ``dask`` run as
  ``python -m lidarcal`` / ``python -m dask`` of this interpreter, ``python`` is this
  interpreter); it must exit 0, or the code
  named by a trailing ``# exits N``.  The lines below a command are its illustrative output,
  not compared.
- ``pycon``: doctest examples; all blocks of a page share one namespace and their printed
  output is compared (ELLIPSIS and NORMALIZE_WHITESPACE on).

Blocks fenced as ``bash`` or ``python`` are shown only (SSH, job schedulers).  The cluster page's
scheduler address ``tcp://scheduler-host:8786`` is replaced by a real local ``dask scheduler``
with two ``dask worker`` processes on 127.0.0.1 started here.  The one ``lidarcal calibrate``
the steward and analyst pages share runs once; the second page gets a copy of its output.
"""

import doctest
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
BLOCK = re.compile(r"^```(console|pycon)[^\n]*\n(.*?)^```", re.M | re.S)
PLACEHOLDER = "tcp://scheduler-host:8786"
ENV = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
_calibrated: dict[str, Path] = {}  # calibrate command -> the directory its outputs went to


def blocks(page: Path) -> list[tuple[str, str, int]]:
    """``(kind, text, line number)`` of the executable blocks of a page."""
    text = page.read_text(encoding="utf-8")
    return [(m.group(1), m.group(2), text.count("\n", 0, m.start()) + 2) for m in BLOCK.finditer(text)]


def commands(text: str) -> list[str]:
    """The ``$ `` commands of a console block (a trailing backslash continues a line)."""
    out, current = [], None
    for line in text.splitlines():
        if current is not None:
            current += " " + line.strip()
        elif line.startswith("$ "):
            current = line[2:].strip()
        else:
            continue
        if current.endswith("\\"):
            current = current[:-1].rstrip()
        else:
            out.append(current)
            current = None
    return out


def run_command(command: str, cwd: Path, where: str) -> None:
    expected = 0
    m = re.search(r"#\s*exits\s+(\d+)\s*$", command)
    if m:
        expected = int(m.group(1))
    argv = shlex.split(command, comments=True)
    if argv[0] in ("lidarcal", "dask"):
        argv = [sys.executable, "-m", argv[0], *argv[1:]]
    elif argv[0] == "python":
        argv = [sys.executable, *argv[1:]]
    if argv[2:3] == ["calibrate"] and command in _calibrated and "-o" in argv:
        out = argv[argv.index("-o") + 1]
        shutil.copytree(_calibrated[command] / out, cwd / out)
        return
    proc = subprocess.run(argv, cwd=cwd, env=ENV, capture_output=True, text=True, timeout=900)
    assert proc.returncode == expected, (
        f"{where}: `{command}` exited {proc.returncode}, expected {expected}\n"
        f"stdout:\n{proc.stdout[-3000:]}\nstderr:\n{proc.stderr[-3000:]}"
    )
    if argv[2:3] == ["calibrate"]:
        _calibrated[command] = cwd


def run_page(name: str | Path, cwd: Path, monkeypatch, replace: dict[str, str] | None = None) -> int:
    """Run every executable block of ``docs/<name>`` in ``cwd``; returns the number of blocks."""
    page = DOCS / name
    name = page.name
    found = blocks(page)
    assert found, f"{page} has no console or pycon block"
    monkeypatch.chdir(cwd)
    globs: dict = {"__name__": f"docs.{name}"}
    parser = doctest.DocTestParser()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for kind, text, line in found:
        for old, new in (replace or {}).items():
            text = text.replace(old, new)
        where = f"docs/{name}:{line}"
        if kind == "console":
            for command in commands(text):
                run_command(command, cwd, where)
        else:
            test = parser.get_doctest(text, globs, where, str(page), line - 1)
            report: list[str] = []
            failed, _ = runner.run(test, out=report.append, clear_globs=False)
            assert failed == 0, "".join(report)
            globs.update(test.globs)  # DocTest ran on a copy; the next block sees these names
    return len(found)


def test_block_parser_reads_continuations_and_exit_codes():
    assert commands("$ a \\\n    b\noutput\n$ c  # exits 1\n") == ["a b", "c  # exits 1"]


@pytest.mark.parametrize(
    "block, message",
    [
        ("```pycon\n>>> 1 + 1\n3\n```\n", "Failed example:\n      1 + 1"),
        ("```console\n$ python -c 'import sys; sys.exit(3)'\n```\n", "exited 3, expected 0"),
        ("```console\n$ python -c 'pass'  # exits 1\n```\n", "exited 0, expected 1"),
    ],
)
def test_a_wrong_output_or_exit_status_fails_the_page(tmp_path, monkeypatch, block, message):
    page = tmp_path / "page.md"
    page.write_text("# page\n\n" + block, encoding="utf-8")
    with pytest.raises(AssertionError, match=re.escape(message)):
        run_page(page, tmp_path, monkeypatch)


def test_steward_walkthrough(tmp_path, monkeypatch):
    assert run_page("steward.md", tmp_path, monkeypatch) >= 4


def test_analyst_walkthrough(tmp_path, monkeypatch):
    assert run_page("analyst.md", tmp_path, monkeypatch) >= 3


def test_validation_page(tmp_path, monkeypatch):
    data = {"tests/data/": f"{ROOT / 'tests' / 'data'}/"}
    assert run_page("validation.md", tmp_path, monkeypatch, replace=data) >= 1


def test_method_notes(tmp_path, monkeypatch):
    assert run_page("method.md", tmp_path, monkeypatch) >= 4


@pytest.mark.slow
def test_command_line_walkthrough(tmp_path, monkeypatch):
    # the page's ``sample_data/...`` paths are the repository's, whatever directory it runs in
    sample = {"sample_data/": f"{ROOT / 'sample_data'}/"}
    assert run_page("cli.md", tmp_path, monkeypatch, replace=sample) >= 7


@pytest.mark.slow
def test_benchmark_scripts_run(tmp_path, monkeypatch):
    scripts = {"benchmarks/": f"{ROOT / 'benchmarks'}/"}
    assert run_page("performance.md", tmp_path, monkeypatch, replace=scripts) >= 1


@pytest.mark.slow
def test_certificate_page(tmp_path, monkeypatch):
    # the page's metadata options on a short run: the options parse and the run ends well
    short = {"lidarcal calibrate -o run": "lidarcal calibrate --periods 24 --heights 80 120 --min-periods 3 "
                                          "--max-replicas 1 --no-progress -o run"}
    assert run_page("certificate.md", tmp_path, monkeypatch, replace=short) >= 1


@pytest.mark.slow
def test_diagnose_examples(tmp_path, monkeypatch):
    assert run_page("diagnose_examples.md", tmp_path, monkeypatch) >= 2


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def local_cluster(tmp_path):
    """``dask scheduler`` (dashboard on a free port) and two one-thread ``dask worker`` on 127.0.0.1."""
    from distributed import Client

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = [sys.executable, "-m", "dask"]
    quiet = {"env": ENV, "cwd": tmp_path, "stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs = [subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--dashboard-address", f"127.0.0.1:{_free_port()}"], **quiet)]
    procs += [subprocess.Popen([*dask, "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                                "--no-dashboard"], **quiet) for _ in range(2)]
    try:
        with Client(address, timeout=60, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + 10
        for p in procs:
            try:
                p.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_cluster_walkthrough(tmp_path, monkeypatch, local_cluster):
    assert PLACEHOLDER in (DOCS / "cluster.md").read_text(encoding="utf-8")
    assert run_page("cluster.md", tmp_path, monkeypatch, replace={PLACEHOLDER: local_cluster}) >= 3


def test_every_page_with_examples_is_executed():
    # a page whose console or pycon blocks no test runs would go stale unnoticed
    tests = Path(__file__).parent
    executed = {name for path in tests.glob("test_*.py")
                for name in re.findall(r"run_page\(\s*\"([\w.\-]+\.md)\"", path.read_text(encoding="utf-8"))}
    with_examples = {page.name for page in DOCS.glob("*.md") if blocks(page)}
    assert with_examples - executed == set()
    assert executed - with_examples == set()  # and every page a test runs has something to run
