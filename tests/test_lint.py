"""The lint (docs/development.md#linting): ruff, configured in pyproject.toml ([tool.ruff]), finds
nothing in the repository, and every `noqa` that stays names its codes and says why, as in

    import bpy  # noqa: E402 - bpy picks its GPU backend while it is imported

(the codes, then a separator such as " - " or "(", then a reason of two words or more)."""
from __future__ import annotations

import io
import os
import re
import subprocess
import sys
import tokenize
from fnmatch import fnmatch
from pathlib import Path

import pytest

from helpers import ROOT

#: Folders never linted: environments, installed npm packages, downloads, caches, build outputs (the
#: same as [tool.ruff] extend-exclude, plus what ruff leaves out by itself).
EXCLUDED = (".venv*", "node_modules", "wheels", ".cache", "build", "dist", "stage", "out", ".git", "__pycache__",
            ".pytest_cache", ".ruff_cache", "*.egg-info")
#: The directive with its codes (module docstring); what follows the codes is its reason.
NOQA = re.compile(r"noqa:\s*(?P<codes>[A-Z]+[0-9]+(?:\s*,\s*[A-Z]+[0-9]+)*)(?P<reason>.*)$")
REASON_WORDS = 2


def _ruff(*args: str, stdin: str | None = None) -> subprocess.CompletedProcess:
    """`ruff` of this environment (requirements.txt pins it), run from the repository root so that
    it reads pyproject.toml; fails the test, never skips it, when ruff is not installed."""
    proc = subprocess.run([sys.executable, "-m", "ruff", *args], cwd=ROOT, input=stdin, capture_output=True,
                          text=True)
    if proc.returncode != 0 and "No module named ruff" in proc.stderr:
        pytest.fail(f"ruff is not installed in {sys.executable}'s environment: it is a test requirement "
                    "(requirements.txt; bash test.sh installs it, or pip install -r requirements.txt)")
    return proc


def _python_files() -> list[Path]:
    files = []
    for folder, dirs, names in os.walk(ROOT):
        dirs[:] = [d for d in dirs if not any(fnmatch(d, pattern) for pattern in EXCLUDED)]
        files += [Path(folder) / name for name in names if name.endswith(".py")]
    return sorted(files)


def noqa_without_reason(source: str) -> list[tuple[int, str]]:
    """(line, comment) of each comment of `source` that holds `noqa` without codes and a reason."""
    bad = []
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type != tokenize.COMMENT or not re.search(r"\bnoqa\b", token.string, re.IGNORECASE):
            continue
        match = NOQA.search(token.string)
        reason = match["reason"].strip().lstrip("-(:").strip() if match else ""
        if len(reason.split()) < REASON_WORDS:
            bad.append((token.start[0], token.string))
    return bad


def test_ruff_finds_nothing():
    proc = _ruff("check", "--no-cache", "--output-format", "concise", ".")
    assert proc.returncode == 0, f"ruff check . (pyproject.toml [tool.ruff]) found:\n{proc.stdout}{proc.stderr}"


def test_ruff_uses_the_project_configuration_and_honours_noqa_with_a_reason():
    """The configuration is the one in force (a late import is a finding, E402) and a `noqa` written
    as this repository writes it, with its reason after the code, still silences it."""
    late = "x = 1\nimport os{}\n\nprint(os.sep, x)\n"
    found = _ruff("check", "--no-cache", "--output-format", "concise", "--stdin-filename", "late.py", "-",
                  stdin=late.format(""))
    assert found.returncode == 1 and "E402" in found.stdout, found.stdout + found.stderr
    silenced = _ruff("check", "--no-cache", "--stdin-filename", "late.py", "-",
                     stdin=late.format("  # noqa: E402 - after a statement, for the example"))
    assert silenced.returncode == 0, silenced.stdout + silenced.stderr


def test_every_noqa_names_its_codes_and_gives_a_reason():
    files = _python_files()
    assert ROOT / "hlod_core" / "bake" / "run" / "dask_cluster.py" in files and len(files) > 200  # walked
    bad = [f"{path.relative_to(ROOT)}:{line}: {comment}"
           for path in files for line, comment in noqa_without_reason(path.read_text(encoding="utf-8"))]
    assert not bad, "a noqa without its codes and reason (write `# noqa: CODE - why`):\n" + "\n".join(bad)


@pytest.mark.parametrize(("comment", "accepted"), [
    ("# noqa: E402 - bpy picks its GPU backend while it is imported", True),
    ("# noqa: E402 (tests/models.py: the test models by role)", True),
    ("# noqa: BLE001, E722 - the fuzz looks for everything else", True),
    ("# noqa", False),
    ("# noqa: E402", False),
    ("# noqa: E402 -", False),
    ("# noqa: E402 - why", False),  # one word is no reason
    ("# NOQA:E731", False),
    ("# ruff: noqa", False),
])
def test_the_noqa_check_itself(comment, accepted):
    assert (noqa_without_reason(f"x = 1  {comment}\n") == []) == accepted
