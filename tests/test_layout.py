"""The package layering stays true: read every module's imports with ``ast`` and check them.

Infrastructure modules (errors, units, schema, cf, binning, provenance, io, compliance, data
and the package root) never import a stage.  Stages may import infrastructure and the stages
*before* them in :data:`STAGES`; importing a later stage (one that may depend on the importer)
fails with the file, line and edge.  Function-local imports count like module-level ones, so
a cycle cannot hide inside a function, and each one must say why it is local (``# cycle:``
or ``# deferred:``).  Finally the module import graph has no cycle.  The checkers are
themselves tested on small packages written to ``tmp_path``.
"""

from __future__ import annotations

import ast
from collections.abc import Iterable
from pathlib import Path

import pytest

import lidarcal

PACKAGE = Path(lidarcal.__file__).parent

#: Shared infrastructure: importable from anywhere, imports no stage.
INFRASTRUCTURE = ("", "errors", "units", "schema", "cf", "binning", "provenance", "io", "compliance", "data",
                  "htmlpage", "signing", "admin")

#: Stages in dependency order: each may import only infrastructure and the stages before it.
#: ``analysis`` reads records but never runs a campaign, so it comes before ``campaign``
#: (running and analysing together is the ``pipeline``'s job).  ``__main__`` belongs with
#: the command line.
STAGES = (
    "bench",
    "rwf",
    "turbulence",
    "lidar",
    "conditions",
    "analysis",
    "campaign",
    "seal",
    "certificate",
    "dcc",
    "document",
    "report",
    "diagnose",
    "compare",
    "pipeline",
    "cli",
)
_ALIASES = {"__main__": "cli"}


def module_name(path: Path, root: Path) -> str:
    """Dotted module name of ``path`` inside the package directory ``root``."""
    parts = [root.name, *path.relative_to(root).with_suffix("").parts]
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports(path: Path, root: Path, modules: Iterable[str]) -> list[tuple[int, str]]:
    """(line, imported module) for every import of the package in ``path``, wherever it is."""
    known = set(modules)
    name = module_name(path, root)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == root.name]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                target = ".".join([*base, node.module] if node.module else base)
            else:
                target = node.module or ""
            if target.split(".")[0] != root.name:
                continue
            for alias in node.names:  # ``from pkg import submodule`` imports the submodule
                sub = f"{target}.{alias.name}"
                out.append((node.lineno, sub if sub in known else target))
    return sorted(set(out))


def stage_of(module: str) -> str:
    """``lidarcal.lidar.model`` -> ``lidar``; the package root -> ``""``."""
    parts = module.split(".")
    top = parts[1] if len(parts) > 1 else ""
    return _ALIASES.get(top, top)


def import_graph(root: Path) -> dict[str, list[tuple[str, int, str]]]:
    """Module -> [(file, line, imported module)] for every module of the package at ``root``."""
    files = {module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    return {
        mod: [(str(path.relative_to(root.parent)), line, to) for line, to in imports(path, root, files)]
        for mod, path in files.items()
    }


def layering_violations(root: Path, infrastructure=INFRASTRUCTURE, stages=STAGES) -> list[str]:
    """Every import that runs against the layering, as ``file:line: a -> b (why)``."""
    order = {s: i for i, s in enumerate(stages)}
    problems = []
    for mod, edges in import_graph(root).items():
        src = stage_of(mod)
        for file, line, target in edges:
            dst = stage_of(target)
            where = f"{file}:{line}: {mod} imports {target}"
            if src not in order and src not in infrastructure:
                problems.append(f"{where} ({src!r} is neither infrastructure nor a listed stage)")
            elif dst not in order and dst not in infrastructure:
                problems.append(f"{where} ({dst!r} is neither infrastructure nor a listed stage)")
            elif src == dst or dst in infrastructure:
                continue
            elif src in infrastructure:
                problems.append(f"{where} (infrastructure {src or root.name!r} imports stage {dst!r})")
            elif order[dst] > order[src]:
                problems.append(f"{where} (stage {src!r} imports the later stage {dst!r}, "
                                "which may depend on it)")
    return problems


def module_cycles(root: Path) -> list[list[str]]:
    """Cycles of the module import graph (each as the modules around it), by depth-first search."""
    graph = {mod: sorted({t for _, _, t in edges if t != mod}) for mod, edges in import_graph(root).items()}
    state: dict[str, int] = {}  # 1 on the stack, 2 done
    stack: list[str] = []
    cycles = []

    def visit(mod: str) -> None:
        state[mod] = 1
        stack.append(mod)
        for nxt in graph.get(mod, ()):
            if state.get(nxt) == 1:
                cycles.append([*stack[stack.index(nxt):], nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[mod] = 2

    for mod in sorted(graph):
        if mod not in state:
            visit(mod)
    return cycles


def _local_imports(node: ast.AST, in_function: bool = False):
    """Import statements inside a function (or lambda), at any depth."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.Import | ast.ImportFrom) and in_function:
            yield child
        funcs = ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda
        yield from _local_imports(child, in_function or isinstance(child, funcs))


def unexplained_local_imports(root: Path) -> list[str]:
    """``file:line`` of every import of the package inside a function without a reason comment.

    A function-local import is kept only to break a real cycle or to defer a heavy import;
    its line (or the line before) says which with ``# cycle:`` or ``# deferred:``.
    """
    found = []
    for path in sorted(root.rglob("*.py")):
        lines = path.read_text(encoding="utf-8").splitlines()
        for node in _local_imports(ast.parse("\n".join(lines))):
            if isinstance(node, ast.Import):
                ours = any(a.name.split(".")[0] == root.name for a in node.names)
            else:
                ours = bool(node.level) or (node.module or "").split(".")[0] == root.name
            said = " ".join(lines[max(node.lineno - 2, 0) : node.end_lineno])
            if ours and "# cycle:" not in said and "# deferred:" not in said:
                found.append(f"{path.relative_to(root.parent)}:{node.lineno}")
    return found


def test_every_module_is_placed():
    stages = {stage_of(m) for m in import_graph(PACKAGE)}
    unplaced = sorted(stages - set(STAGES) - set(INFRASTRUCTURE))
    assert not unplaced, f"add these to STAGES or INFRASTRUCTURE in {__file__}: {unplaced}"


def test_stages_import_only_earlier_stages_and_infrastructure():
    problems = layering_violations(PACKAGE)
    assert not problems, "imports against the layering:\n" + "\n".join(problems)


def test_function_local_imports_say_why():
    found = unexplained_local_imports(PACKAGE)
    assert not found, (
        "function-local imports of lidarcal without '# cycle: ...' or '# deferred: ...' "
        "(move them to the top of the module):\n" + "\n".join(found)
    )


def test_no_import_cycles_between_modules():
    cycles = module_cycles(PACKAGE)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


# -- the checker itself, on a tiny package written to tmp_path -----------------------------

def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "pkg"  # not "lidarcal": test_docs would take the paths below as cited
    for rel, text in {"__init__.py": "", **files}.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root


def test_checker_finds_a_backwards_edge_even_inside_a_function(tmp_path):
    root = _package(
        tmp_path,
        {
            "errors.py": "",
            "lidar/__init__.py": "from pkg.lidar.model import Model\n",
            "lidar/model.py": "from pkg.errors import InputError\n",
            "campaign/__init__.py": "from pkg.lidar import Model\n",
            "analysis/sweep.py": "import numpy\n\n\ndef sweep():\n    from pkg.campaign import run\n",
        },
    )
    problems = layering_violations(root)
    assert problems == [
        "pkg/analysis/sweep.py:5: pkg.analysis.sweep imports pkg.campaign "
        "(stage 'analysis' imports the later stage 'campaign', which may depend on it)"
    ]
    # the same tree with the edge the right way round is clean
    (root / "analysis" / "sweep.py").write_text("from pkg.lidar import Model\n")
    assert layering_violations(root) == []


def test_checker_finds_infrastructure_importing_a_stage_and_unknown_stages(tmp_path):
    root = _package(
        tmp_path,
        {
            "io.py": "from . import schema\nfrom .lidar import model\n",
            "schema.py": "",
            "lidar/__init__.py": "",
            "lidar/model.py": "",
            "extras/tool.py": "from pkg.io import x\n",
        },
    )
    problems = layering_violations(root)
    assert problems == [
        "pkg/extras/tool.py:1: pkg.extras.tool imports pkg.io "
        "('extras' is neither infrastructure nor a listed stage)",
        "pkg/io.py:2: pkg.io imports pkg.lidar.model "
        "(infrastructure 'io' imports stage 'lidar')",
    ]


def test_checker_finds_a_cycle_hidden_in_a_function(tmp_path):
    root = _package(
        tmp_path,
        {
            "turbulence/__init__.py": "",
            "turbulence/box.py": "from pkg.lidar.simulate import seed\n",
            "lidar/__init__.py": "",
            "lidar/simulate.py": "def f():\n    from pkg.turbulence import box\n",
        },
    )
    assert module_cycles(root) == [
        ["pkg.lidar.simulate", "pkg.turbulence.box", "pkg.lidar.simulate"]
    ]
    # the layering names the edge that runs the wrong way: turbulence (earlier) imports lidar
    assert [p.split(" (")[0] for p in layering_violations(root)] == [
        "pkg/turbulence/box.py:1: pkg.turbulence.box imports pkg.lidar.simulate"
    ]


@pytest.mark.parametrize("stage", STAGES)
def test_each_stage_exists(stage):
    # a stage listed here but renamed or removed would make the order check vacuous for it
    assert (PACKAGE / stage).is_dir() or (PACKAGE / f"{stage}.py").is_file()


def test_checker_finds_unexplained_local_imports(tmp_path):
    root = _package(
        tmp_path,
        {
            "errors.py": "",
            "io.py": (
                "import json\n"
                "from pkg.errors import E\n"
                "def f():\n"
                "    import numpy\n"  # third-party: not ours to judge
                "    from pkg import errors\n"
                "def g():\n"
                "    # deferred: heavy import\n"
                "    from pkg import errors\n"
                "class C:\n"
                "    def h(self):\n"
                "        from . import errors  # cycle: io <-> errors\n"
                "        x = 1\n"
                "        from . import errors\n"
            ),
        },
    )
    assert unexplained_local_imports(root) == ["pkg/io.py:5", "pkg/io.py:13"]
