"""The import graph (STYLE: imports run one way, core <- adapters <- UI <- registration; a cycle is a
design question): hlod_core imports nothing of addon/, operators/, panels/ or Blender's modules;
addon/ (adapters) imports no UI; no module-level or deferred import forms a cycle; and every module
imports on its own, first, in a fresh interpreter."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import ROOT

PACKAGES = ("hlod_core", "addon", "operators", "panels")
BLENDER_MODULES = {"bpy", "mathutils", "gpu", "gpu_extras", "bmesh", "addon_utils", "blf", "bl_ui"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts) or "<root>"


def _modules() -> dict[str, Path]:
    out = {"<root>": ROOT / "__init__.py"}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            out[_module_name(path)] = path
    return out


def _imports(name: str, path: Path, known: set[str], walk=ast.walk) -> tuple[set[str], set[str]]:
    """(project modules, external top-level modules) that `name` imports anywhere in its body
    (module level and deferred imports inside functions alike; walk=_module_level: only the former)."""
    is_package = path.name == "__init__.py"
    package = name if is_package else name.rpartition(".")[0]
    if name == "<root>":
        package = ""
    project, external = set(), set()
    for node in walk(ast.parse(path.read_text(encoding="utf-8"))):
        targets = []
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".") if package else []
                base = base[:len(base) - (node.level - 1)] if node.level > 1 else base
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            targets = [stem] + [f"{stem}.{alias.name}" if stem else alias.name for alias in node.names]
        for target in targets:
            if target in known:
                project.add(target)
            elif target and target.split(".")[0] not in PACKAGES and target not in ("", "<root>"):
                external.add(target.split(".")[0])
    project.discard(name)
    return project, external


@pytest.fixture(scope="module")
def graph() -> dict[str, tuple[set[str], set[str]]]:
    modules = _modules()
    return {name: _imports(name, path, set(modules)) for name, path in modules.items()}


def test_the_core_imports_no_blender_and_no_adapter_or_ui(graph):
    offending = {name: sorted(project | (external & BLENDER_MODULES))
                 for name, (project, external) in graph.items() if name.startswith("hlod_core")
                 if any(not p.startswith("hlod_core") for p in project) or external & BLENDER_MODULES}
    assert not offending


def test_adapters_import_no_ui(graph):
    offending = {name: sorted(p for p in project if p.startswith(("operators", "panels")))
                 for name, (project, _) in graph.items() if name.startswith("addon")}
    assert not any(offending.values()), offending


def test_the_command_line_is_a_front_end(graph):
    """Library code lives in library modules: only `python -m hlod_core` imports the core's CLI."""
    importers = sorted(name for name, (project, _) in graph.items() if "hlod_core.cli" in project)
    assert importers == ["hlod_core.__main__"], importers


def test_no_import_cycles(graph):
    edges = {name: set(project) for name, (project, _) in graph.items()}
    for name in list(edges):  # importing a.b runs a/__init__.py first: a package is a dependency
        edges[name] |= {p.rpartition(".")[0] for p in edges[name] if "." in p} - {name, ""}
    cycles = []
    colour: dict[str, int] = {}

    def visit(node: str, stack: list[str]) -> None:
        colour[node] = 1
        for nxt in sorted(edges.get(node, ())):
            if colour.get(nxt) == 1:
                cycles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in colour:
                visit(nxt, stack + [nxt])
        colour[node] = 2

    for start in sorted(edges):
        if start not in colour:
            visit(start, [start])
    assert not cycles, cycles


#: Libraries of the command line only (requirements.txt): Blender ships none of them, nor does the
#: extension's manifest, so no module the extension can reach may import them.
COMMAND_LINE_ONLY = {"trimesh", "PIL", "matplotlib", "dask", "distributed"}
#: Modules the extension reaches that may touch a command-line-only library, each behind a guard
#: that works without it (and the test suite runs that path with the library blocked).
GUARDED = {"hlod_core.report.figures": {"matplotlib"}, "hlod_core.io.textures": {"PIL"},
           "hlod_core.io.gltf": {"trimesh"}, "hlod_core.bake.dask_cluster": {"distributed"}}


def _reached(graph, cut: tuple[str, str] | None = None) -> set[str]:
    """The modules the extension imports, transitively from `<root>` (deferred imports included);
    cut (importer, imported): that one import left out."""
    reached, todo = set(), ["<root>"]
    while todo:
        name = todo.pop()
        if name in reached or name not in graph:
            continue
        reached.add(name)
        todo.extend(graph[name][0] - ({cut[1]} if cut is not None and name == cut[0] else set()))
    return reached


def test_the_extension_reaches_no_command_line_only_library(graph):
    """Everything the extension imports, transitively (deferred imports included), from the
    registration module `<root>`: none of it imports trimesh, PIL or matplotlib except the
    guarded modules above."""
    reached = _reached(graph)
    offending = {name: sorted((graph[name][1] & COMMAND_LINE_ONLY) - GUARDED.get(name, set()))
                 for name in reached}
    assert "hlod_core.bake.pipeline" in reached and "addon.preview" in reached  # the walk sees the extension
    assert not any(offending.values()), {k: v for k, v in offending.items() if v}


def _module_level(tree: ast.AST):
    """ast.walk without the bodies of functions: the nodes that run when the module is imported."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            todo.extend(ast.iter_child_nodes(node))


def test_dask_is_imported_only_by_a_bake_given_a_scheduler(graph):
    """Dask is a command-line-only dependency. Everything the extension imports (transitively
    from `<root>`, deferred imports included), less hlod_core.bake.workers' one deferred import of
    hlod_core.bake.dask_cluster, imports neither dask nor distributed; that import sits in
    `open_workers` under `if scheduler is not None`; dask_cluster itself imports distributed only
    when it is used, not at module level. And in a fresh interpreter a bake without a scheduler (jobs 1
    and 2) leaves both out of sys.modules."""
    dask = {"dask", "distributed"}
    importers = sorted(name for name, (project, external) in graph.items()
                       if external & dask or "hlod_core.bake.dask_cluster" in project)
    assert importers == ["hlod_core.bake.dask_cluster", "hlod_core.bake.workers", "hlod_core.cli"], importers
    reached = _reached(graph, cut=("hlod_core.bake.workers", "hlod_core.bake.dask_cluster"))
    assert "hlod_core.bake.pipeline" in reached and "addon.preview" in reached
    assert "hlod_core.bake.dask_cluster" not in reached
    assert not {name for name in reached if graph[name][1] & dask}
    modules = _modules()
    for name in ("hlod_core.bake.workers", "hlod_core.bake.dask_cluster"):
        project, external = _imports(name, modules[name], set(modules), walk=_module_level)
        assert not external & dask and "hlod_core.bake.dask_cluster" not in project, name
    tree = ast.parse((ROOT / "hlod_core" / "bake" / "workers.py").read_text(encoding="utf-8"))
    guarded = [node for node in ast.walk(tree) if isinstance(node, ast.If)
               and ast.unparse(node.test) == "scheduler is not None"
               and any(isinstance(n, ast.ImportFrom) and [a.name for a in n.names] == ["dask_cluster"]
                       for n in ast.walk(node))]
    every = [node for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
             and "dask_cluster" in [a.name for a in node.names]]
    assert len(guarded) == 1 and len(every) == 1
    script = ("import sys\nsys.path.insert(0, 'tests')\nfrom helpers import load_model\n"
              "from hlod_core.bake.pipeline import BakeSettings, bake\n"
              "for jobs in (1, 2):\n    bake(load_model('cow.obj'), BakeSettings(target_tris=1000, jobs=jobs))\n"
              "loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))\n"
              "assert not loaded and 'hlod_core.bake.dask_cluster' not in sys.modules, loaded\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_the_graph_sees_known_edges(graph):
    """The checks above would pass on an empty graph: pin a few edges that must be found."""
    assert "hlod_core.io.hlod_file" in graph["hlod_core.cli"][0]
    assert "hlod_core.bake.pipeline" in graph["addon.bake_job"][0]
    assert "addon.preview" in graph["panels"][0]
    assert "bpy" in graph["addon.preview"][1] and "numpy" in graph["hlod_core.bake.pipeline"][1]


@pytest.mark.slow
def test_every_core_module_imports_first_in_a_fresh_interpreter():
    names = [n for n in _modules() if n.startswith("hlod_core")]
    script = "import importlib, sys\nfor n in sys.argv[1:]:\n    importlib.import_module(n)\n"
    for order in (names, names[::-1]):
        # one interpreter per module for the first import; then all of them in both orders
        for name in order[:1]:
            subprocess.run([sys.executable, "-c", script, name], check=True, cwd=ROOT, timeout=120)
        proc = subprocess.run([sys.executable, "-c", script, *order], capture_output=True, text=True, cwd=ROOT,
                              timeout=120)
        assert proc.returncode == 0, proc.stderr[-2000:]
    for name in names:
        proc = subprocess.run([sys.executable, "-c", script, name], capture_output=True, text=True, cwd=ROOT,
                              timeout=120)
        assert proc.returncode == 0, f"{name}: {proc.stderr[-2000:]}"


@pytest.mark.blender
def test_every_extension_module_imports_first_under_a_package_name():
    """addon/, operators/ and panels/ use relative imports: import the folder as a package (as
    Blender does, under another name) and each module first, in a fresh bpy interpreter, in two orders."""
    names = [n for n in _modules() if not n.startswith("hlod_core") and n != "<root>"]
    script = ("import importlib, importlib.util, sys\n"
              f"spec = importlib.util.spec_from_file_location('pkg', {str(ROOT / '__init__.py')!r}, "
              f"submodule_search_locations=[{str(ROOT)!r}])\n"
              "pkg = importlib.util.module_from_spec(spec); sys.modules['pkg'] = pkg; spec.loader.exec_module(pkg)\n"
              "for n in sys.argv[1:]:\n    importlib.import_module('pkg.' + n)\n")
    for order in (names, names[::-1]):
        proc = subprocess.run([sys.executable, "-c", script, *order], capture_output=True, text=True, cwd="/",
                              timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
