"""The structure bar, read from the source (imports run one way, core <- adapters <- UI <-
registration; a cycle is a design question; docs/development.md#layout):
  - hlod_core imports nothing of addon/, operators/, panels/ or Blender's modules, and outside itself
    only the standard library and its declared dependencies; addon/ (adapters) imports no UI;
  - no module-level or deferred import forms a cycle; the core's rooms (its subpackages) import only
    rooms below them (ROOM_LAYERS), and so do the add-on's (ADDON_LAYERS);
  - the UI (operators/, panels/) calls into the add-on: it imports neither the other UI package nor
    the core's bake, traversal, renderer or reports (UI_CORE_ROOMS);
  - an add-on module whose docstring says it imports no Blender module imports none;
  - no private name (leading underscore) of a project module is used from another package: another
    room of the core or of the add-on, operators/, panels/, benchmarks/, scripts/ or tests/;
  - no module of the core or the extension is longer than MAX_MODULE_LINES;
  - test modules share fixtures (conftest.py) and helper modules, never another test module, a
    module-level cache or a GL context of their own;
and every module imports on its own, first, in a fresh interpreter."""
from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

from helpers import ROOT

PACKAGES = ("hlod_core", "addon", "operators", "panels")
#: Folders of Python that use the project's modules without being part of them.
USERS = ("benchmarks", "scripts", "tests")
BLENDER_MODULES = {"bpy", "mathutils", "gpu", "gpu_extras", "bmesh", "addon_utils", "blf", "bl_ui"}
#: The core's rooms, lowest first: a room imports only rooms of a lower layer (and itself). The
#: renderer implements the traversal's renderer protocol (and fits its cost model), so render sits
#: above traversal; the reports drive renderer and traversal; the command line is the top.
ROOM_LAYERS = {"core": 0, "model": 1, "io": 2, "traversal": 2, "render": 3, "bake": 3, "export": 4, "report": 4,
               "cli": 5, "__main__": 6}
#: The add-on's rooms (its subpackages, and its modules at the top of addon/), lowest first: a room
#: imports only rooms of a lower layer (and itself). Materials, the settings converter and the 3D
#: Tiles server read Blender data and the core only; the scene reads materials; the preview and
#: the bake work on the scene; the property group (whose statistics read the preview), the
#: background command (the bake) and the Benchmark's work (the preview's file and contexts) are the top.
ADDON_LAYERS = {"settings": 0, "materials": 0, "tiles_server": 0, "scene": 1, "preview": 2, "bake": 2,
                "properties": 3, "cli": 3, "evaluation": 3}
#: The core's rooms the UI (operators/, panels/) imports: typed errors, files, exports. The bake, the
#: traversal, the renderer and the reports are reached through the add-on's rooms.
UI_CORE_ROOMS = {"core", "io", "export"}
#: What an add-on module's docstring says when it imports no Blender module, not even inside a
#: function (it runs, or is tested, outside Blender); the test holds it to that.
NO_BLENDER_CLAIM = re.compile(r"imports\s+no\s+Blender\s+module", re.IGNORECASE)
#: Lines a module may have (modules of a few hundred lines, one topic each).
MAX_MODULE_LINES = 500
#: Libraries of the command line only (requirements.txt): Blender ships none of them, nor does the
#: extension's manifest, so no module the extension can reach may import them.
COMMAND_LINE_ONLY = {"trimesh", "PIL", "matplotlib", "dask", "distributed", "DracoPy"}
#: What the core may import besides the standard library: numpy (Blender ships it), the extension's
#: wheels (blender_manifest.toml) and the command-line-only libraries.
CORE_DEPENDENCIES = {"numpy", "pymeshlab", "moderngl", "glcontext", "xatlas"} | COMMAND_LINE_ONLY
#: Modules the extension reaches that may touch a command-line-only library, each behind a guard
#: that works without it (and the test suite runs that path with the library blocked).
GUARDED = {"hlod_core.report.figures": {"matplotlib"}, "hlod_core.io.textures": {"PIL"},
           "hlod_core.io.gltf": {"trimesh"}, "hlod_core.bake.run.dask_cluster": {"distributed"},
           "hlod_core.report.figure_style": {"matplotlib"}, "hlod_core.report.label_placement": {"matplotlib"},
           "hlod_core.export.draco": {"DracoPy"}, "hlod_core.export.texture_codec": {"PIL"}}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts) or "<root>"


def _modules(folders=PACKAGES) -> dict[str, Path]:
    out = {"<root>": ROOT / "__init__.py"} if folders == PACKAGES else {}
    for folder in folders:
        for path in sorted((ROOT / folder).rglob("*.py")):
            out[_module_name(path)] = path
    return out


def _package_of(name: str) -> str:
    """The package whose private names a module may use: a room of the core (hlod_core.bake, ...;
    hlod_core.cli for the command line) or of the add-on (addon.preview, ...; addon.cli), else the
    top folder (operators, benchmarks, tests, ...)."""
    parts = name.split(".")
    return ".".join(parts[:2]) if parts[0] in ("hlod_core", "addon") and len(parts) > 1 else parts[0]


def _room(name: str, package: str = "hlod_core") -> str | None:
    """The room of module `name` in `package`: the core's (core, model, ..., cli, __main__) or the
    add-on's (materials, scene, ..., cli); None for the package itself or a module outside it."""
    parts = name.split(".")
    return parts[1] if parts[0] == package and len(parts) > 1 else None


def _import_targets(name: str, path: Path, node: ast.AST) -> list[tuple[str, str | None]]:
    """[(imported module or name, local alias or None)] of one Import / ImportFrom node of module
    `name`, relative imports resolved."""
    if isinstance(node, ast.Import):
        return [(alias.name, alias.asname) for alias in node.names]
    if not isinstance(node, ast.ImportFrom):
        return []
    if node.level:
        package = "" if name == "<root>" else name if path.name == "__init__.py" else name.rpartition(".")[0]
        base = package.split(".") if package else []
        base = base[:len(base) - (node.level - 1)] if node.level > 1 else base
        stem = ".".join(base + ([node.module] if node.module else []))
    else:
        stem = node.module or ""
    return [(stem, None)] + [(f"{stem}.{alias.name}" if stem else alias.name, alias.asname or alias.name)
                             for alias in node.names]


def _imports(name: str, path: Path, known: set[str], walk=ast.walk) -> tuple[set[str], set[str]]:
    """(project modules, external top-level modules) that `name` imports anywhere in its body
    (module level and deferred imports inside functions alike; walk=_module_level: only the former)."""
    project, external = set(), set()
    for node in walk(ast.parse(path.read_text(encoding="utf-8"))):
        for target, _ in _import_targets(name, path, node):
            if target in known:
                project.add(target)
            elif target and target.split(".")[0] not in PACKAGES and target not in ("", "<root>"):
                external.add(target.split(".")[0])
    project.discard(name)
    return project, external


def _module_level(tree: ast.AST):
    """ast.walk without the bodies of functions: the nodes that run when the module is imported."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            todo.extend(ast.iter_child_nodes(node))


@pytest.fixture(scope="module")
def graph() -> dict[str, tuple[set[str], set[str]]]:
    modules = _modules()
    return {name: _imports(name, path, set(modules)) for name, path in modules.items()}


def _room_edges(graph, package: str = "hlod_core") -> dict[tuple[str, str], list[str]]:
    """{(importing room, imported room): ["a -> b", ...]} between different rooms of `package`."""
    edges: dict[tuple[str, str], list[str]] = {}
    for name, (project, _) in graph.items():
        for target in project:
            a, b = _room(name, package), _room(target, package)
            if a and b and a != b:
                edges.setdefault((a, b), []).append(f"{name} -> {target}")
    return edges


def test_the_core_imports_no_blender_and_no_adapter_or_ui(graph):
    offending = {name: sorted(project | (external & BLENDER_MODULES))
                 for name, (project, external) in graph.items() if name.startswith("hlod_core")
                 if any(not p.startswith("hlod_core") for p in project) or external & BLENDER_MODULES}
    assert not offending


def test_the_core_imports_only_the_standard_library_and_its_dependencies(graph):
    """Nothing outside hlod_core: not benchmarks/, scripts/ or tests/, nor an undeclared library."""
    allowed = set(sys.stdlib_module_names) | CORE_DEPENDENCIES
    offending = {name: sorted(external - allowed) for name, (_, external) in graph.items()
                 if name.startswith("hlod_core") and external - allowed}
    assert not offending, offending


def test_adapters_import_no_ui(graph):
    offending = {name: sorted(p for p in project if p.startswith(("operators", "panels")))
                 for name, (project, _) in graph.items() if name.startswith("addon")}
    assert not any(offending.values()), offending


def test_the_command_line_is_a_front_end(graph):
    """Library code lives in library modules: only `python -m hlod_core` imports the core's CLI."""
    importers = sorted(name for name, (project, _) in graph.items()
                       if "hlod_core.cli" in project and not name.startswith("hlod_core.cli."))
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


def test_the_core_has_no_back_imports(graph):
    """Every room of the core is in ROOM_LAYERS and imports only rooms of lower layers (deferred
    imports included): no import goes up or sideways."""
    rooms = {_room(name) for name in graph} - {None}
    assert rooms <= set(ROOM_LAYERS), rooms - set(ROOM_LAYERS)
    back = {edge: importers for edge, importers in _room_edges(graph).items()
            if ROOM_LAYERS[edge[1]] >= ROOM_LAYERS[edge[0]]}
    assert not back, back


def test_the_addon_rooms_import_only_rooms_below_them(graph):
    """Every room of the add-on is in ADDON_LAYERS (and every room there exists) and imports only
    rooms of lower layers (deferred imports included)."""
    rooms = {_room(name, "addon") for name in graph} - {None}
    assert rooms == set(ADDON_LAYERS), (rooms ^ set(ADDON_LAYERS))
    back = {edge: importers for edge, importers in _room_edges(graph, "addon").items()
            if ADDON_LAYERS[edge[1]] >= ADDON_LAYERS[edge[0]]}
    assert not back, back


def test_the_ui_calls_into_the_addon(graph):
    """operators/ and panels/ import, of the project, only their own package, the add-on and the
    core's UI_CORE_ROOMS: a panel does not reach into an operator (nor the other way), and the bake,
    the traversal, the renderer and the reports are the add-on's to call."""
    offending = {}
    for name, (project, _) in graph.items():
        ui = name.split(".")[0]
        if ui not in ("operators", "panels"):
            continue
        wrong = sorted(p for p in project if p.split(".")[0] not in (ui, "addon", "hlod_core")
                       or p.startswith("hlod_core") and _room(p) not in UI_CORE_ROOMS)
        if wrong:
            offending[name] = wrong
    assert not offending, offending


def test_addon_modules_that_say_they_import_no_blender_module_import_none(graph):
    """An add-on module whose docstring claims NO_BLENDER_CLAIM imports no Blender module anywhere
    (deferred imports included); the bake's job, the settings converter and the colour formulas
    claim it."""
    modules = _modules()
    claiming = sorted(name for name in graph if name.startswith("addon.") and NO_BLENDER_CLAIM.search(
        ast.get_docstring(ast.parse(modules[name].read_text(encoding="utf-8"))) or ""))
    assert {"addon.bake.job", "addon.settings", "addon.materials.colour_formulas"} <= set(claiming), claiming
    offending = {name: sorted(graph[name][1] & BLENDER_MODULES) for name in claiming
                 if graph[name][1] & BLENDER_MODULES}
    assert not offending, offending


#: Packages whose docstring indexes them: it names (in backticks) each of their modules and
#: subpackages, and nothing of that form that is not there.
INDEXED_PACKAGES = ("addon", "addon.materials", "addon.scene", "addon.preview", "addon.bake", "operators")


def test_package_docstrings_name_every_module_they_hold():
    problems = []
    for package in INDEXED_PACKAGES:
        folder = ROOT.joinpath(*package.split("."))
        doc = ast.get_docstring(ast.parse((folder / "__init__.py").read_text(encoding="utf-8"))) or ""
        named = set(re.findall(r"`([a-z_][a-z0-9_]*)`", doc))
        held = {p.stem for p in folder.glob("*.py") if p.stem != "__init__"}
        held |= {p.name for p in folder.iterdir() if (p / "__init__.py").is_file()}
        problems += [f"{package}: holds {name}, its docstring does not name it" for name in sorted(held - named)]
        problems += [f"{package}: its docstring names {name}, which it does not hold" for name in sorted(named - held)]
    assert not problems, "\n".join(problems)


# --- private names ------------------------------------------------------------------------------------

def _project_modules() -> dict[str, Path]:
    """Every module whose private names are guarded: the core and the extension, benchmarks and
    scripts (scripts are imported by their bare name too, as tests put scripts/ on sys.path)."""
    modules = {**_modules(), **_modules(("benchmarks", "scripts"))}
    modules |= {name.split(".", 1)[1]: path for name, path in _modules(("scripts",)).items() if "." in name}
    return modules


def _dotted(node: ast.AST) -> str | None:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        base = _dotted(node.value)
        return f"{base}.{node.attr}" if base else None
    return None


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _bindings(name: str, path: Path, node: ast.AST, known: dict[str, Path]) -> tuple[dict[str, str], list[str]]:
    """({local name: project module} an import binds, [names it imports from a project module])."""
    if isinstance(node, ast.Import):
        bound = {alias.asname: alias.name for alias in node.names if alias.asname and alias.name in known}
        bound |= {alias.name.split(".")[0]: alias.name.split(".")[0] for alias in node.names
                  if not alias.asname and alias.name.split(".")[0] in known}
        return bound, []
    if not isinstance(node, ast.ImportFrom):
        return {}, []
    stem, bound, names = _import_targets(name, path, node)[0][0], {}, []
    for alias in node.names:
        if f"{stem}.{alias.name}" in known:
            bound[alias.asname or alias.name] = f"{stem}.{alias.name}"
        elif stem in known:
            names.append(f"{stem}.{alias.name}")
    return bound, names


def private_uses(name: str, path: Path, source: str, known: dict[str, Path]) -> list[str]:
    """The private names of other packages' modules that module `name` imports or uses: `from m
    import _f`, `m._f` through an imported module, setattr/getattr/monkeypatch on (m, "_f"), and
    "pkg.m._f" targets of mock.patch / monkeypatch.setattr."""
    own = _package_of(name)
    tree = ast.parse(source)
    aliases: dict[str, str] = {}  # local name -> project module
    found = []

    def foreign_private(module: str | None, attribute: str) -> str | None:
        """"module.attribute" (the module by its full name) if that is another package's private name."""
        if module not in known or not _private(attribute):
            return None
        full = _module_name(known[module])
        return f"{full}.{attribute}" if _package_of(full) != own else None

    for node in ast.walk(tree):
        bound, imported = _bindings(name, path, node, known)
        aliases |= bound
        for target in imported:
            hit = foreign_private(*target.rsplit(".", 1))
            found += [f"{name}: from {hit.rpartition('.')[0]} import {hit.rpartition('.')[2]}"] if hit else []

    def resolve(expression: ast.AST) -> str | None:
        first, _, rest = (_dotted(expression) or "").partition(".")
        return ".".join(filter(None, [aliases[first], rest])) if first in aliases else None

    for node in ast.walk(tree):
        hit = None
        if isinstance(node, ast.Attribute):
            hit = foreign_private(resolve(node.value), node.attr)
        elif isinstance(node, ast.Call) and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) \
                and isinstance(node.args[1].value, str):
            hit = foreign_private(resolve(node.args[0]), node.args[1].value)
            hit = hit and f"{hit} (by name)"
        if isinstance(node, ast.Call) and (_dotted(node.func) or "").endswith(("patch", "setattr")) and node.args \
                and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str) \
                and re.fullmatch(r"(hlod_core|addon|operators|panels)(\.\w+)+", node.args[0].value):
            string_hit = foreign_private(*node.args[0].value.rsplit(".", 1))
            hit = hit or (string_hit and f"{string_hit} (a string)")
        found += [f"{name}: {hit}"] if hit else []
    return sorted(set(found))


def test_no_private_name_is_used_across_packages():
    """A room of the core, the extension, benchmarks/, scripts/ and tests/ use another package's
    public names only: what another package needs is public, with a name and a docstring."""
    known = _project_modules()
    users = {**_modules(), **_modules(USERS)}
    found = [use for name, path in sorted(users.items())
             for use in private_uses(name, path, path.read_text(encoding="utf-8"), known)]
    assert not found, "\n".join(found)


def test_modules_stay_under_the_size_bar():
    sizes = {name: len(path.read_text(encoding="utf-8").splitlines()) for name, path in _modules().items()}
    assert len(sizes) > 40 and max(sizes.values()) > 100  # the bar sees the modules
    over = {name: lines for name, lines in sizes.items() if lines > MAX_MODULE_LINES}
    assert not over, over


# --- the tests themselves -----------------------------------------------------------------------------

#: Scripts in tests/ that run in their own process (bpy, in tests/blender/; the fuzz run's worker),
#: not in pytest's.
OWN_PROCESS = re.compile(r"blender_\w*checks\.py|hlod_fuzz_worker\.py")
#: Where the test run's GL context is made: the fixture and the function it calls; and the tests of
#: making contexts (hlod_core/render/gl_platform.py), whose subject it is.
GL_CONTEXT_HOMES = {"conftest.py", "helpers.py", "test_gl_platform.py"}
#: Old cached functions of helpers.py (replaced by the bakes / city_hlod fixtures).
OLD_CACHES = {"baked", "baked_city"}
CACHE_DECORATORS = {"lru_cache", "cache", "functools.lru_cache", "functools.cache"}


def _empty_container(value: ast.AST | None) -> bool:
    if isinstance(value, ast.Dict):
        return not value.keys
    if isinstance(value, (ast.List, ast.Set)):
        return not value.elts
    return isinstance(value, ast.Call) and _dotted(value.func) in ("dict", "list", "set") and not value.args


def _decorator_name(node: ast.AST) -> str | None:
    return _dotted(node.func if isinstance(node, ast.Call) else node)


def _test_state_findings(path: Path, *, gl_contexts: bool = True) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            modules = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            found += [f"imports the test module {m}" for m in modules if m.split(".")[0].startswith("test_")]
            if isinstance(node, ast.ImportFrom) and node.module == "helpers":
                found += [f"imports helpers.{a.name} (use the fixture)" for a in node.names if a.name in OLD_CACHES]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            found += [f"{node.name}: a module-level cache (@{_decorator_name(d)}): make it a fixture"
                      for d in node.decorator_list if _decorator_name(d) in CACHE_DECORATORS]
        elif isinstance(node, ast.Call) and gl_contexts and path.name not in GL_CONTEXT_HOMES \
                and (_dotted(node.func) or "").rpartition(".")[2] in ("create_context", "standalone_gl"):
            found.append(f"line {node.lineno}: makes a GL context (use the gl_ctx fixture)")
    for node in tree.body:  # module-level mutable containers: state shared by every test of the module
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and _empty_container(node.value):
            found.append(f"line {node.lineno}: a module-level container filled while tests run (use a fixture)")
    return found


def test_tests_share_fixtures_not_module_state():
    """Test modules and their helpers import no test module, keep no module-level cache, and make
    no GL context but conftest's gl_ctx; benchmarks/ (some run under pytest) import no test module."""
    tests = [p for p in sorted((ROOT / "tests").rglob("*.py")) if not OWN_PROCESS.fullmatch(p.name)]
    found = [f"{p.relative_to(ROOT)}: {finding}" for p in tests for finding in _test_state_findings(p)]
    found += [f"{p.relative_to(ROOT)}: {finding}" for p in sorted((ROOT / "benchmarks").glob("*.py"))
              for finding in _test_state_findings(p, gl_contexts=False) if "test module" in finding]
    assert not found, "\n".join(found)


# --- what the extension reaches -------------------------------------------------------------------------

def _reached(graph, cut: set[tuple[str, str]] = frozenset()) -> set[str]:
    """The modules the extension imports, transitively from `<root>` (deferred imports included);
    cut: (importer, imported) imports left out."""
    reached, todo = set(), ["<root>"]
    while todo:
        name = todo.pop()
        if name in reached or name not in graph:
            continue
        reached.add(name)
        todo.extend(p for p in graph[name][0] if (name, p) not in cut)
    return reached


def test_the_extension_reaches_no_command_line_only_library(graph):
    """Everything the extension imports, transitively (deferred imports included), from the
    registration module `<root>`: none of it imports trimesh, PIL or matplotlib except the
    guarded modules above."""
    reached = _reached(graph)
    offending = {name: sorted((graph[name][1] & COMMAND_LINE_ONLY) - GUARDED.get(name, set()))
                 for name in reached}
    assert any(n.startswith("hlod_core.bake.") for n in reached) and any(n.startswith("addon.preview") for n in reached)
    assert not any(offending.values()), {k: v for k, v in offending.items() if v}


def test_dask_is_imported_only_by_a_bake_given_a_scheduler(graph):
    """Dask is a command-line-only dependency. Only hlod_core.bake.run.dask_cluster imports dask or
    distributed, and only inside its functions; every import of dask_cluster is deferred (inside a
    function), and without those imports the extension reaches neither. In a fresh interpreter a
    bake without a scheduler (jobs 1 and 2) leaves both out of sys.modules."""
    dask, cluster = {"dask", "distributed"}, "hlod_core.bake.run.dask_cluster"
    modules = _modules()
    assert sorted(name for name, (_, external) in graph.items() if external & dask) == [cluster]
    importers = [name for name, (project, _) in graph.items() if cluster in project]
    assert importers, "nothing imports dask_cluster: the check below would be empty"
    for name in importers + [cluster]:
        project, external = _imports(name, modules[name], set(modules), walk=_module_level)
        assert not external & dask and cluster not in project, f"{name} imports Dask at module level"
    reached = _reached(graph, cut={(name, cluster) for name in importers})
    assert cluster not in reached and not {name for name in reached if graph[name][1] & dask}
    script = ("import sys\nsys.path.insert(0, 'tests')\nfrom helpers import load_model\n"
              "from hlod_core.bake.pipeline import bake\nfrom hlod_core.bake.settings import BakeSettings\n"
              "for jobs in (1, 2):\n    bake(load_model('cow'), BakeSettings(target_tris=1000, jobs=jobs))\n"
              "loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed'))\n"
              f"assert not loaded and {cluster!r} not in sys.modules, loaded\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_the_graph_sees_known_edges(graph):
    """The checks above would pass on an empty graph or a blind scanner: pin edges and findings that
    must be there."""
    assert "hlod_core.cli" in graph["hlod_core.__main__"][0]
    rooms = set(_room_edges(graph))
    assert {("model", "core"), ("io", "model"), ("traversal", "model"), ("render", "model"), ("render", "traversal"),
            ("bake", "io"), ("export", "io"), ("report", "render"), ("report", "traversal"), ("cli", "bake"),
            ("cli", "report")} <= rooms, rooms
    assert any(p.startswith("hlod_core.bake") for name, (project, _) in graph.items() if name.startswith("addon")
               for p in project)
    assert any(p.startswith("addon") for p in graph["panels"][0])
    assert {("preview", "scene"), ("scene", "materials"), ("bake", "scene"), ("cli", "bake")} <= set(
        _room_edges(graph, "addon")), _room_edges(graph, "addon")
    assert any(_room(p) == "bake" for p in graph["addon.bake.from_scene"][0])
    assert any("bpy" in external for name, (_, external) in graph.items() if name.startswith("addon"))
    assert "numpy" in graph["hlod_core.model.hierarchy"][1]
    known = _project_modules()
    sample = ("from hlod_core.bake import pipeline as p\nfrom hlod_core.io.hlod_file import _x, load\n"
              "import hlod_core.model.hierarchy\np._y()\nhlod_core.model.hierarchy._z\n"
              "monkeypatch.setattr(p, '_w', None)\nmock.patch('hlod_core.bake.pipeline._v')\np.bake\n")
    assert private_uses("tests.test_x", ROOT / "tests" / "test_x.py", sample, known) == sorted([
        "tests.test_x: from hlod_core.io.hlod_file import _x", "tests.test_x: hlod_core.bake.pipeline._w (by name)",
        "tests.test_x: hlod_core.bake.pipeline._y", "tests.test_x: hlod_core.model.hierarchy._z",
        "tests.test_x: hlod_core.bake.pipeline._v (a string)"])
    # inside one room a module may use its neighbours' private names
    assert private_uses("hlod_core.bake.run.cache", ROOT / "hlod_core/bake/run/cache.py", sample, known) == sorted([
        "hlod_core.bake.run.cache: from hlod_core.io.hlod_file import _x",
        "hlod_core.bake.run.cache: hlod_core.model.hierarchy._z"])


#: Each core module imported first in a process of its own: forked from one interpreter that has
#: imported numpy (the third-party package every room imports) and nothing of hlod_core, so a module
#: that needs another imported before it fails as in a fresh interpreter, without an interpreter's
#: start and numpy's import per module. Prints the modules that failed, one "name: error" a line.
FORKED_IMPORTS = """\
import importlib, os, sys, traceback
import numpy
assert not [m for m in sys.modules if m.split('.')[0] == 'hlod_core']
for name in sys.argv[1:]:
    pid = os.fork()
    if pid == 0:
        try:
            importlib.import_module(name)
        except BaseException:
            print(name + ': ' + traceback.format_exc().strip().splitlines()[-1], flush=True)
            os._exit(1)
        os._exit(0)
    code = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    if code not in (0, 1):  # 1: the child printed its error
        print(name + ': the import ended the process (' + str(code) + ')', flush=True)
"""


@pytest.mark.slow
def test_every_core_module_imports_first_in_a_fresh_interpreter():
    names = [n for n in _modules() if n.startswith("hlod_core")]
    script = "import importlib, sys\nfor n in sys.argv[1:]:\n    importlib.import_module(n)\n"
    for order in (names, names[::-1]):
        # the first module in an interpreter of its own; then all of them in both orders
        for name in order[:1]:
            subprocess.run([sys.executable, "-c", script, name], check=True, cwd=ROOT, timeout=120)
        proc = subprocess.run([sys.executable, "-c", script, *order], capture_output=True, text=True, cwd=ROOT,
                              timeout=120)
        assert proc.returncode == 0, proc.stderr[-2000:]
    proc = subprocess.run([sys.executable, "-c", FORKED_IMPORTS, *names], capture_output=True, text=True, cwd=ROOT,
                          timeout=600)
    assert proc.returncode == 0 and proc.stdout == "", (proc.stdout[-2000:], proc.stderr[-2000:])


def test_a_module_that_needs_another_imported_first_fails_alone(tmp_path):
    """FORKED_IMPORTS names a module that only imports after another: each import starts from the
    parent's modules, not from what an earlier child imported."""
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "a.py").write_text("import sys\nsys.modules['pkg'].ready = True\n")
    (package / "b.py").write_text("import pkg\nassert pkg.ready, 'pkg.a not imported'\n")
    proc = subprocess.run([sys.executable, "-c", FORKED_IMPORTS, "pkg.a", "pkg.b"], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.stdout.splitlines() == ["pkg.b: AttributeError: module 'pkg' has no attribute 'ready'"], proc.stdout


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
