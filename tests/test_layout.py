"""The package layering stays true: read every module's imports with ``ast`` and check them.

Infrastructure modules (errors, units, schema, cf, binning, provenance, io, compliance, data
and the package root) never import a stage.  Stages may import infrastructure and the stages
*before* them in :data:`STAGES`; importing a later stage (one that may depend on the importer)
fails with the file, line and edge.  Function-local imports count like module-level ones, so
a cycle cannot hide inside a function, and each one must say why it is local (``# cycle:``
or ``# deferred:``).  Finally the module import graph has no cycle.

CONTRIBUTING.md holds the one map of the package: every module is named there, one table row
each, and the stages appear in the order of :data:`STAGES`.  A ``kernels.py`` imports only the
standard library, numpy, scipy and lidarcal modules that themselves import nothing else,
followed through every import.  The checkers are themselves tested on small packages written
to ``tmp_path``.
"""

from __future__ import annotations

import ast
import re
import sys
from collections.abc import Iterable
from pathlib import Path

import pytest

import lidarcal

PACKAGE = Path(lidarcal.__file__).parent
CONTRIBUTING = PACKAGE.parent / "CONTRIBUTING.md"

#: Shared infrastructure: importable from anywhere, imports no stage.  ``htmlpage`` is the HTML
#: plotting API of every report (the calibration's, diagnose's, compare's, smc's), not the
#: certificate's alone.
INFRASTRUCTURE = ("", "errors", "units", "schema", "cf", "binning", "provenance", "io", "compliance", "data",
                  "htmlpage", "readback")

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
    "certificate",
    "diagnose",
    "compare",
    "smc",
    "pipeline",
    "cli",
)
_ALIASES = {"__main__": "cli"}

#: A stage that is one folder of several parts (the certificate wing: the certificate, its seal and
#: administrative data, the DCC, the PDF and the HTML report), its parts in dependency order: a part
#: may import only the parts before it, and none imports the wing's face (its ``__init__.py``, which
#: names the public functions and imports them on first use): the face would hide a back-arrow.
WINGS = {
    "certificate": ("admin", "signing", "seal", "layout", "inputs", "results", "measurand", "build", "dcc",
                    "document", "report"),
}


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


def part_of(module: str) -> str:
    """``lidarcal.certificate.dcc.export`` -> ``dcc``; a wing's face (``lidarcal.certificate``) -> ``""``."""
    parts = module.split(".")
    return parts[2] if len(parts) > 2 else ""


def wing_violation(mod: str, target: str, parts: tuple[str, ...]) -> str | None:
    """Why ``mod`` may not import ``target``, both in one wing whose parts are ``parts`` (None: it may)."""
    src, dst = part_of(mod), part_of(target)
    if not src or src == dst:
        return None  # the face imports its parts; a part its own modules
    if not dst:
        return "a part imports the wing's face, which imports every part"
    if src not in parts or dst not in parts:
        return f"{(src if src not in parts else dst)!r} is not a listed part of the wing"
    if parts.index(dst) > parts.index(src):
        return f"part {src!r} imports the later part {dst!r}, which may depend on it"
    return None


def layering_violations(root: Path, infrastructure=INFRASTRUCTURE, stages=STAGES, wings=WINGS) -> list[str]:
    """Every import that runs against the layering, as ``file:line: a -> b (why)``."""
    order = {s: i for i, s in enumerate(stages)}
    problems = []
    for mod, edges in import_graph(root).items():
        src = stage_of(mod)
        for file, line, target in edges:
            dst = stage_of(target)
            where = f"{file}:{line}: {mod} imports {target}"
            if src == dst and src in wings:
                if why := wing_violation(mod, target, wings[src]):
                    problems.append(f"{where} ({why})")
            elif src not in order and src not in infrastructure:
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


def test_provenance_reads_the_version_from_package_metadata(monkeypatch):
    # provenance sits under every stage: it reads lidarcal's version from the package metadata,
    # not from the package face (whose entry points import the stages)
    from importlib import metadata

    from lidarcal import provenance

    edges = import_graph(PACKAGE)["lidarcal.provenance"]
    assert "lidarcal" not in {target for _, _, target in edges}, edges
    assert provenance.__version__ == lidarcal.__version__

    def missing(name):
        raise metadata.PackageNotFoundError(name)

    monkeypatch.setattr(metadata, "version", missing)  # a checkout run without install
    assert provenance._lidarcal_version() == "0.0.0+unknown"


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


def test_each_wing_part_exists_and_every_module_is_a_part():
    for wing, parts in WINGS.items():
        here = PACKAGE / wing
        assert all((here / p).is_dir() or (here / f"{p}.py").is_file() for p in parts), parts
        found = {part_of(m) for m in import_graph(PACKAGE) if stage_of(m) == wing} - {""}
        assert found == set(parts), f"add these to WINGS[{wing!r}]: {sorted(found - set(parts))}"


def test_checker_finds_a_backwards_edge_inside_a_wing_and_an_import_of_its_face(tmp_path):
    root = _package(tmp_path, {
        "wing/__init__.py": "from pkg.wing.late import x\n",
        "wing/early.py": "def f():\n    from pkg.wing.late import x  # deferred: no\n",
        "wing/late/__init__.py": "from pkg.wing.early import f\n",
        "wing/other.py": "import pkg.wing\n",
    })
    found = layering_violations(root, infrastructure=("",), stages=("wing",),
                                wings={"wing": ("early", "other", "late")})
    assert [p.split(" (")[0] for p in found] == [
        "pkg/wing/early.py:2: pkg.wing.early imports pkg.wing.late",
        "pkg/wing/other.py:1: pkg.wing.other imports pkg.wing",
    ]


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


# -- the map in CONTRIBUTING.md names every module ---------------------------------------------

#: A map row: its first cell is a module path under the package, in backticks (bold or not).
MAP_ROW = re.compile(r"^\|\s*\**`([\w./]+)`\**\s*\|", re.M)


def package_modules(root: Path) -> list[str]:
    """Every module of the package at ``root`` as the map names it: ``x.py``, ``pkg/x.py``, ``pkg/``."""
    names = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.name != "__init__.py":
            names.append(rel.as_posix())
        elif rel.parent != Path("."):
            names.append(rel.parent.as_posix() + "/")
        else:
            names.append("__init__.py")
    return names


def map_problems(root: Path, markdown: str, stages: tuple[str, ...] = STAGES) -> list[str]:
    """What the map in ``markdown`` (its ``## Layout`` section) gets wrong about the package."""
    section = markdown.split("\n## Layout", 1)[-1].split("\n## ", 1)[0]
    named = MAP_ROW.findall(section)
    actual = package_modules(root)
    problems = [f"not in the map: {m}" for m in actual if m not in named]
    problems += [f"in the map but gone: {m}" for m in named if m not in actual]
    problems += [f"named twice: {m}" for m in sorted({m for m in named if named.count(m) > 1})]
    order = []
    for m in named:
        stage = stage_of(module_name(root / (m + "__init__.py" if m.endswith("/") else m), root))
        if stage in stages and stage not in order:
            order.append(stage)
    if order != [s for s in stages if s in order]:
        problems.append(f"stages in the map in the order {order}, not that of STAGES")
    return problems


def test_contributing_names_every_module():
    problems = map_problems(PACKAGE, CONTRIBUTING.read_text(encoding="utf-8"))
    assert not problems, (f"the map in {CONTRIBUTING.name} (add or remove a row `| `path` | what it holds |` "
                          "under the module's stage):\n" + "\n".join(problems))


def test_map_checker_finds_missing_gone_and_misordered_modules(tmp_path):
    root = _package(tmp_path, {"errors.py": "", "lidar/__init__.py": "", "lidar/wfr.py": "",
                               "bench/__init__.py": "", "bench/grid.py": ""})
    good = ("## Layout\n| module | holds |\n|---|---|\n| `__init__.py` | front |\n| `errors.py` | errors |\n"
            "| **`bench/`** | bench |\n| `bench/grid.py` | grid |\n| **`lidar/`** | lidar |\n"
            "| `lidar/wfr.py` | wfr |\n\n## Next\n| `gone.py` | outside the Layout section |\n")
    assert map_problems(root, good) == []
    bad = good.replace("| `lidar/wfr.py` | wfr |\n", "| `lidar/spectral.py` | moved |\n")
    assert map_problems(root, bad) == ["not in the map: lidar/wfr.py",
                                       "in the map but gone: lidar/spectral.py"]
    swapped = good.replace("| **`bench/`** | bench |\n| `bench/grid.py` | grid |\n", "") + \
        "| **`bench/`** | bench |\n| `bench/grid.py` | grid |\n"
    swapped = swapped.replace("\n## Next", "")  # the rows after the lidar ones, still in Layout
    assert map_problems(root, swapped) == [
        "in the map but gone: gone.py",
        "stages in the map in the order ['lidar', 'bench'], not that of STAGES"]


# -- kernels take numbers: numpy, scipy and the standard library only --------------------------

KERNEL_LIBRARIES = {"numpy", "scipy"}


def third_party_imports(path: Path, root: Path) -> set[str]:
    """Top-level names of what ``path`` imports outside the standard library and the package."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            tops = [a.name.split(".")[0] for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            tops = [(node.module or "").split(".")[0]]
        else:
            continue
        out |= {t for t in tops if t != root.name and t not in sys.stdlib_module_names}
    return out


def kernel_problems(root: Path) -> list[str]:
    """Each import of a ``kernels.py`` that brings in anything but numpy/scipy, and what it brings."""
    graph = import_graph(root)
    files = {module_name(p, root): p for p in root.rglob("*.py")}

    def reached(mod: str, seen: set[str]) -> set[str]:
        """Third-party libraries ``mod`` imports, directly or through the package's modules."""
        seen.add(mod)
        libs = third_party_imports(files[mod], root)
        for _, _, target in graph[mod]:
            if target in files and target not in seen:
                libs |= reached(target, seen)
        return libs

    problems = []
    for kernel in sorted(m for m in graph if m.endswith(".kernels")):
        own = sorted(third_party_imports(files[kernel], root) - KERNEL_LIBRARIES)
        problems += [f"{kernel} imports {lib}" for lib in own]
        for target in sorted({t for _, _, t in graph[kernel] if t in files and t != kernel}):
            extra = sorted(reached(target, {kernel}) - KERNEL_LIBRARIES)
            if extra:
                problems.append(f"{kernel} imports {target}, which brings in {', '.join(extra)}")
    return problems


def test_kernels_import_only_numpy_and_scipy():
    problems = kernel_problems(PACKAGE)
    assert not problems, "kernels must take and return numbers (numpy/scipy only):\n" + "\n".join(problems)


def test_kernel_checker_follows_imports(tmp_path):
    root = _package(tmp_path, {
        "binning.py": "import numpy as np\n",
        "units.py": "import pint\n",
        "lidar/__init__.py": "import xarray\n",
        "lidar/model.py": "from dataclasses import dataclass\nimport xarray as xr\nfrom pkg import units\n",
        "rwf/__init__.py": "",
        "rwf/kernels.py": "import math\nfrom scipy import stats\n",
        "analysis/__init__.py": "",
        "analysis/kernels.py": "from pkg.binning import f\nfrom pkg.rwf import kernels\n",
        "conditions/__init__.py": "",
        "conditions/kernels.py": "import pandas\n\ndef f():\n    from pkg.lidar.model import M\n",
    })
    assert kernel_problems(root) == [
        "pkg.conditions.kernels imports pandas",
        "pkg.conditions.kernels imports pkg.lidar.model, which brings in pint, xarray"]


# -- one HTML plotting API: plain bokeh (lidarcal.htmlpage), matplotlib for the PDFs ---------------

#: Libraries that draw another way in HTML; users may call ``.hvplot`` on an artefact themselves.
OTHER_HTML_PLOTTING = {"holoviews", "hvplot", "panel", "plotly", "altair"}


def test_one_html_plotting_api():
    # every module's imports, function-local ones included (ast.walk reaches them)
    found = {module_name(p, PACKAGE): sorted(third_party_imports(p, PACKAGE) & OTHER_HTML_PLOTTING)
             for p in PACKAGE.rglob("*.py")}
    assert {m: libs for m, libs in found.items() if libs} == {}
    # bokeh's figures are made through htmlpage.plot: no page builds its own
    makers = [module_name(p, PACKAGE) for p in PACKAGE.rglob("*.py")
              if "from bokeh.plotting import figure" in p.read_text(encoding="utf-8")]
    assert makers == ["lidarcal.htmlpage"]
