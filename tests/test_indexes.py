"""The core's hand-kept indexes match the tree: the rooms listed in hlod_core/__init__.py, each room's
modules named in its package docstring, the names its docstrings give in backticks, the public API,
the commands of hlod_core/cli/__init__.py, and every `*.py` path a module of the core names."""
from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

from helpers import ROOT

CORE = ROOT / "hlod_core"
PACKAGES = sorted(p for p in CORE.rglob("__init__.py") if "__pycache__" not in p.parts)
#: A name in backticks that is only a dotted identifier (`meshes.TriangleMesh`, `residency`), not a
#: command line, a call or a file name.
DOTTED = re.compile(r"`([a-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)`")
PY_PATH = re.compile(r"(?<![\w/.-])((?:[\w-]+/)*[A-Za-z_]\w*\.py)\b")


def _docstring(path: Path) -> str:
    return ast.get_docstring(ast.parse(path.read_text())) or ""


def _modules(package: Path) -> set[str]:
    """The modules and subpackages of a package folder."""
    return ({p.stem for p in package.glob("*.py") if p.stem not in ("__init__", "__main__")}
            | {p.name for p in package.iterdir() if (p / "__init__.py").is_file()})


def _dotted(path: Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def _resolves(name: str, package: str) -> bool:
    """`name` is a module or an attribute reached from `package` (relative) or from the top (absolute)."""
    for base in (f"{package}.{name}", name):
        parts = base.split(".")
        for cut in range(len(parts), 0, -1):
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ImportError:
                continue
            try:
                for attr in parts[cut:]:
                    obj = getattr(obj, attr)
            except AttributeError:
                break
            return True
    return False


def test_the_rooms_listed_in_the_core_docstring_are_its_subpackages():
    listed = re.findall(r"(?m)^    ([a-z_]+)/\s", _docstring(CORE / "__init__.py"))
    assert len(listed) == len(set(listed)) and set(listed) == _modules(CORE), (listed, sorted(_modules(CORE)))


@pytest.mark.parametrize("init", PACKAGES, ids=lambda p: _dotted(p))
def test_each_package_docstring_names_every_module_and_only_modules_that_exist(init):
    doc = _docstring(init)
    unnamed = sorted(m for m in _modules(init.parent) if not re.search(rf"\b{m}\b", doc))
    assert not unnamed, f"{init.relative_to(ROOT)}: its docstring does not name {unnamed}"
    package = _dotted(init)
    unknown = sorted({n for n in DOTTED.findall(doc) if not _resolves(n, package)})
    assert not unknown, f"{init.relative_to(ROOT)}: its docstring names {unknown}, which do not exist"


def test_the_public_api_in_the_core_docstring_exists():
    doc = _docstring(CORE / "__init__.py")
    api = doc[doc.index("Public API:"):]
    names = set(re.findall(r"\b((?:" + "|".join(sorted(_modules(CORE))) + r")(?:\.[A-Za-z_]\w*)+)", api))
    assert len(names) > 10
    files = ("json", "md", "html", "png", "npz")  # report.json and the like: file names, not the API
    assert not sorted(n for n in names if n.rsplit(".", 1)[-1] not in files and not _resolves(n, "hlod_core"))


def test_the_command_table_of_the_cli_package_matches_the_parser():
    """hlod_core/cli/__init__.py: one line per command, `COMMAND ... module.py`, the module that
    carries the command out (its `run` default)."""
    from hlod_core.cli.main import build_parser

    table = dict(re.findall(r"(?m)^    ([a-z]+) .*?\s(\w+)\.py\b", _docstring(CORE / "cli" / "__init__.py")))
    parser = build_parser("hlod")
    commands = next(a for a in parser._actions if a.dest == "command").choices  # argparse keeps subparsers here
    carried = {name: p.get_default("run").__module__.rsplit(".", 1)[-1] for name, p in commands.items()}
    assert table == carried


def test_every_python_file_a_core_module_names_exists():
    """A `something.py` in the core's text (docstrings, comments) is a file: next to the module, in
    hlod_core/, or from the repository root."""
    missing = []
    for path in sorted(CORE.rglob("*.py")):
        for name in set(PY_PATH.findall(path.read_text())):
            if not any((base / name).is_file() for base in (path.parent, CORE, ROOT)):
                missing.append(f"{path.relative_to(ROOT)}: {name}")
    assert not missing
