"""The docs stay a user's guide that matches the code: every relative link and image of README.md and
docs/*.md resolves (anchors to a heading of the target page, as GitHub makes them), the options
docs/command-line.md documents are the parsers' options and no more, the README stays short, and
product text speaks of the product, not of its making. Fast: no GL, no bpy."""
from __future__ import annotations

import ast
import importlib.util
import os
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
COMMAND_LINE = ROOT / "docs" / "command-line.md"
ADDON_CLI = ROOT / "addon" / "cli.py"
README_MAX_LINES = 250
#: Options of other programs the command-line page shows: Blender's own (`blender -b --command hlod`)
#: and `dask worker`'s in the cluster recipe.
FOREIGN_OPTIONS = {"--command", "--nworkers", "--nthreads"}
#: Words about the making of the product, not the product (a design decision cites a paper or a page).
HISTORY = re.compile(r"\bissue \d+|\bthis round\b|\bthis session\b|\bthis machine\b", re.IGNORECASE)

FENCE = re.compile(r"^(```|~~~).*?^\1[ \t]*$", re.MULTILINE | re.DOTALL)
INLINE_CODE = re.compile(r"`[^`\n]*`")
LINK = re.compile(r"\]\(([^()\s]+)(?:\s+\"[^\"]*\")?\)")
HEADING = re.compile(r"^(#{1,6})[ \t]+(.+?)[ \t#]*$", re.MULTILINE)
LONG_OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def _prose(text: str) -> str:
    """The page without fenced code blocks (their `# comments` are not headings, their `](` not links)."""
    return FENCE.sub("", text)


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: its text (link text, no markup), lower case, punctuation
    other than '-' and '_' dropped, spaces to '-'."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """Every heading anchor of a Markdown page, with GitHub's -1, -2 suffixes for repeats."""
    seen: dict[str, int] = {}
    out = set()
    for match in HEADING.finditer(_prose(page.read_text(encoding="utf-8"))):
        slug = github_anchor(match.group(2))
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        out.add(slug if count == 0 else f"{slug}-{count}")
    return out


def relative_links(page: Path) -> list[str]:
    """Targets of the page's links and images that are not URLs (outside code)."""
    text = INLINE_CODE.sub("", _prose(page.read_text(encoding="utf-8")))
    return [t for t in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:", t)]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_and_image_resolves(page):
    broken = []
    for target in relative_links(page):
        path_part, _, anchor = target.partition("#")
        where = (page.parent / path_part).resolve() if path_part else page
        if not where.exists():
            broken.append(f"{target}: no such file")
        elif anchor and where.suffix == ".md" and anchor not in anchors(where):
            broken.append(f"{target}: no heading with anchor #{anchor} in {where.name}")
    assert not broken, f"{page.name}: " + "; ".join(broken)


def test_the_anchor_function_makes_githubs_anchors():
    # GitHub's anchors of headings these pages use: punctuation dropped, '_' and '-' kept
    assert github_anchor("python -m hlod_core bake") == "python--m-hlod_core-bake"
    assert github_anchor("The CHC++ query stream") == "the-chc-query-stream"
    assert github_anchor("Tuning (s, t) to a PSNR target") == "tuning-s-t-to-a-psnr-target"
    assert github_anchor("The `.hlod` file") == "the-hlod-file"
    assert github_anchor("Where Coh's extra nodes are") == "where-cohs-extra-nodes-are"


# --- the command-line page against the parsers ----------------------------------------------------

def _core_options() -> tuple[dict[str, set[str]], set[str]]:
    """({subcommand: its option strings}, the top level's) of `python -m hlod_core`."""
    import argparse

    from hlod_core.cli.main import build_parser

    parser = build_parser()
    commands: dict[str, set[str]] = {}
    top = set()
    for action in parser._actions:  # argparse has no public walk of its actions
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                commands[name] = {o for a in sub._actions if not isinstance(a, argparse._HelpAction)
                                  for o in a.option_strings}
        elif not isinstance(action, argparse._HelpAction):
            top.update(action.option_strings)
    return commands, top


def _core_option_group(name: str) -> set[str]:
    """The option strings the core's option group `name` (hlod_core.cli.options, e.g. bake_options)
    adds to a parser."""
    import argparse

    from hlod_core.cli import options

    parser = argparse.ArgumentParser(add_help=False)
    getattr(options, name)(parser)
    return {o for a in parser._actions for o in a.option_strings}


def _addon_options() -> dict[str, set[str]]:
    """{subcommand: its option strings} of the Blender command, read from addon/cli.py's AST
    (importing it needs bpy): `X = sub.add_parser("name")`, groups made from X, and
    `X.add_argument("--option", ...)`, or the core's option group `bake_options(X)`; a call on a
    name not traced to a subcommand counts under "*"."""
    tree = ast.parse(ADDON_CLI.read_text(encoding="utf-8"))
    commands: dict[str, set[str]] = {}
    for function in (n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)):
        owner: dict[str, str] = {}
        for node in ast.walk(function):
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call) and \
                    isinstance(node.value.func, ast.Attribute) and len(node.targets) == 1 and \
                    isinstance(node.targets[0], ast.Name):
                call, target = node.value, node.targets[0].id
                if call.func.attr == "add_parser" and call.args and isinstance(call.args[0], ast.Constant):
                    owner[target] = call.args[0].value
                    commands.setdefault(call.args[0].value, set())
                elif call.func.attr in ("add_mutually_exclusive_group", "add_argument_group") and \
                        isinstance(call.func.value, ast.Name):
                    owner[target] = owner.get(call.func.value.id, "*")
        for node in ast.walk(function):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and \
                    node.func.attr == "add_argument" and isinstance(node.func.value, ast.Name):
                strings = {a.value for a in node.args if isinstance(a, ast.Constant) and str(a.value).startswith("-")}
                commands.setdefault(owner.get(node.func.value.id, "*"), set()).update(strings)
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id.endswith("_options") \
                    and node.args and isinstance(node.args[0], ast.Name):
                commands.setdefault(owner.get(node.args[0].id, "*"), set()).update(_core_option_group(node.func.id))
    return commands


def _other_core_options() -> set[str]:
    """Option strings of any other argparse command in hlod_core (e.g. `python -m
    hlod_core.report.evaluate --redraw`), from the AST of its modules."""
    found = set()
    for path in (ROOT / "hlod_core").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "add_argument":
                found.update(a.value for a in node.args
                             if isinstance(a, ast.Constant) and str(a.value).startswith("--"))
    return found


def _documented() -> str:
    return COMMAND_LINE.read_text(encoding="utf-8")


def _headings(text: str) -> list[str]:
    return [m.group(2) for m in HEADING.finditer(_prose(text))]


def test_the_addon_parser_is_read_from_its_source():
    commands = _addon_options()
    assert {"bake", "export", "view"} <= set(commands), commands
    assert {"-o", "--output", "--collection", "--objects", "--no-cache"} <= commands["bake"]


def test_every_documented_option_exists_in_a_parser():
    core, top = _core_options()
    known = top.union(*core.values(), *_addon_options().values(), _other_core_options(), FOREIGN_OPTIONS)
    unknown = sorted(set(LONG_OPTION.findall(_documented())) - known - {"--help"})
    assert not unknown, f"docs/command-line.md documents options no parser has: {unknown}"


def test_every_parser_option_and_command_is_documented():
    text = _documented()
    headings = _headings(text)
    core, top = _core_options()
    missing = [f"python -m hlod_core {name}" for name in core
               if not any(f"hlod_core {name}" in h for h in headings)]
    missing += [f"--command hlod {name}" for name in _addon_options() if name != "*"
                and not any(f"--command hlod {name}" in h for h in headings)]
    for where, options in [("python -m hlod_core", top), *((f"hlod_core {n}", o) for n, o in core.items()),
                           *((f"hlod {n}", o) for n, o in _addon_options().items())]:
        missing += [f"{where}: {option}" for option in sorted(options)
                    if not re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text)]
    assert not missing, f"not documented in docs/command-line.md: {missing}"


# --- the README and product text ------------------------------------------------------------------

def test_the_readme_stays_short():
    lines = len(README.read_text(encoding="utf-8").splitlines())
    assert lines < README_MAX_LINES, f"README.md has {lines} lines; the rest belongs in docs/"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_the_docs_speak_of_the_product_not_its_making(page):
    found = [m.group(0) for m in HISTORY.finditer(page.read_text(encoding="utf-8"))]
    assert not found, f"{page.name}: {found}"


def test_the_overlay_legend_draws_from_the_code(tmp_path, monkeypatch):
    """scripts/docs_pictures.py's legend (matplotlib only) still runs against the colour ramp, the
    bias and the command line's defaults it reads."""
    pytest.importorskip("matplotlib")
    spec = importlib.util.spec_from_file_location("docs_pictures", ROOT / "scripts" / "docs_pictures.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # its dataclasses look their module up
    spec.loader.exec_module(module)
    path = module.draw_legend(tmp_path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


#: A docs page named in code (a docstring's "Why: docs/how-it-works.md#anchor"), wrapped or not.
CODE_DOC_LINK = re.compile(r"docs/([\w-]+\.md)(?:#([\w-]+))?")
CODE_FOLDERS = ("hlod_core", "addon", "operators", "panels", "scripts", "benchmarks")


def test_every_docs_page_and_anchor_named_in_the_code_exists():
    """The code points readers at docs pages for its reasoning: each page and anchor it names exists."""
    broken = []
    files = [ROOT / "__init__.py", *(p for folder in CODE_FOLDERS for p in sorted((ROOT / folder).rglob("*.py")))]
    for path in files:
        for match in CODE_DOC_LINK.finditer(path.read_text(encoding="utf-8")):
            page, anchor = ROOT / "docs" / match.group(1), match.group(2)
            if not page.is_file():
                broken.append(f"{path.relative_to(ROOT)}: docs/{match.group(1)}: no such page")
            elif anchor and anchor not in anchors(page):
                broken.append(f"{path.relative_to(ROOT)}: docs/{match.group(1)}#{anchor}: no such heading")
    assert not broken, "\n".join(broken)


# --- the developers' guide's layout against the tree -----------------------------------------------

DEVELOPMENT = ROOT / "docs" / "development.md"
#: Folders the layout check does not walk: environments, downloads, build outputs.
NOT_CODE = {"node_modules", "wheels", "dist", "out", "__pycache__"}
#: Where each room's line in the layout names every module of the room (the add-on's rooms; the
#: core's lines describe their modules in words).
ROOMS_NAMING_EVERY_MODULE = ("addon/",)


def _layout_entries() -> dict[str, str]:
    """{path: its description} of the Layout block of docs/development.md: a line that starts with
    a name is a top-level entry (`addon/`, `__init__.py`), an indented `name/` a folder inside the
    last top-level folder (indented two spaces more, a folder inside the last such folder);
    continuation lines join their entry's description."""
    text = DEVELOPMENT.read_text(encoding="utf-8")
    block = FENCE.search(text, text.index("\n## Layout")).group(0)
    entries: dict[str, str] = {}
    top = path = middle = None
    for line in block.splitlines()[1:-1]:
        head = re.match(r"(\S+)\s", line + " ")
        nested = re.match(r"  (\S+/)\s", line + " ")
        deeper = re.match(r"    (\S+/)\s", line + " ")
        if head:
            path = top = head.group(1)
        elif nested and top and top.endswith("/"):
            path = middle = top + nested.group(1)
        elif deeper and middle:
            path = middle + deeper.group(1)
        elif path is None:
            continue
        entries[path] = entries.get(path, "") + " " + line.strip()
    return entries


def _packages() -> set[str]:
    """The repository's package folders (holding __init__.py), relative, with a trailing '/'."""
    found = set()
    for folder, dirs, files in os.walk(ROOT):
        dirs[:] = [d for d in dirs if not d.startswith(".") and d not in NOT_CODE]
        if "__init__.py" in files and Path(folder) != ROOT:
            found.add(Path(folder).relative_to(ROOT).as_posix() + "/")
    return found


def test_the_layout_names_every_package_and_only_what_exists():
    """The Layout block names every package folder of the repository, and every path it names
    exists: its entries and the files (`name.py`) each entry names inside its folder; a room of
    ROOMS_NAMING_EVERY_MODULE (an indented folder entry) names each of its modules."""
    entries = _layout_entries()
    assert {"addon/", "addon/preview/", "hlod_core/bake/", "__init__.py"} <= set(entries), sorted(entries)
    problems = [f"{path}: named in the layout, not in the tree" for path in entries if not (ROOT / path).exists()]
    problems += [f"{path}: a package the layout does not name" for path in sorted(_packages() - set(entries))]
    for path, text in entries.items():
        folder = ROOT / path if path.endswith("/") else ROOT
        for name in re.findall(r"\b[\w-]+\.(?:py|sh)\b", text):
            if not (folder / name).exists() and not any(folder.rglob(name)):
                problems.append(f"{path}: names {name}, which is not there")
        if path.count("/") == 2 and path.startswith(ROOMS_NAMING_EVERY_MODULE) and folder.is_dir():
            words = set(re.findall(r"\w+", text))
            problems += [f"{path}: its module {m.name} is not named" for m in sorted(folder.glob("*.py"))
                         if m.stem != "__init__" and m.stem not in words]
    assert not problems, "\n".join(problems)


def test_how_it_works_contents_lists_every_section_once():
    """The grouped contents at the top of how-it-works.md (between its contents markers) links every
    "## " section of the page exactly once, so a new section cannot be left out of it."""
    page = ROOT / "docs" / "how-it-works.md"
    text = page.read_text(encoding="utf-8")
    contents = text[text.index("<!-- contents -->"):text.index("<!-- /contents -->")]
    listed = re.findall(r"\]\(#([^)]+)\)", contents)
    sections = [github_anchor(h) for h in re.findall(r"^## (.+)$", _prose(text), re.MULTILINE)]
    assert sorted(listed) == sorted(sections) and len(set(listed)) == len(listed)
