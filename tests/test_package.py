"""The core as an installable package (pyproject.toml): `pip install .` gives `hlod-core` and an
importable hlod_core outside the repository, and the cluster recipe of docs/command-line.md works
as written with it: a scheduler and workers started with `dask scheduler` / `dask worker` in fresh
processes, none of which sees the repository, and a bake through them equal to a local one.

The environment: a fresh virtual environment whose dependencies are the test run's own (a .pth
file naming .venv's site-packages, as `pip install .[dask]` would have installed them: nothing is
downloaded), into which pip installs this repository's package without build isolation."""
from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

from helpers import ROOT, file_bytes, model


def _version_in_one_place() -> str:
    """hlod_core.__version__, the one version: pyproject.toml takes it from there (dynamic), and
    blender_manifest.toml, which Blender reads as it is, repeats it."""
    import tomllib

    import hlod_core

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" not in project["project"] and project["project"]["dynamic"] == ["version"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "hlod_core.__version__"}
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["version"] == hlod_core.__version__, "blender_manifest.toml repeats hlod_core.__version__"
    return hlod_core.__version__


def test_the_version_lives_in_one_place():
    assert _version_in_one_place().count(".") == 2


def _source_copy(where: Path) -> Path:
    """What `pip install .` reads (pyproject.toml, hlod_core/, the readme it names), copied to `where`:
    setuptools builds in the source folder (build/, *.egg-info), which must not be the checkout."""
    where.mkdir()
    shutil.copy2(ROOT / "pyproject.toml", where)
    (where / "docs").mkdir()
    shutil.copy2(ROOT / "docs" / "command-line.md", where / "docs")
    shutil.copytree(ROOT / "hlod_core", where / "hlod_core", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return where


def _venv_with_the_package(where: Path) -> Path:
    """A venv at `where` with hlod_core installed by pip from a copy of ROOT's package; its bin folder."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(where)], check=True)
    site = Path(subprocess.run([str(where / "bin" / "python"), "-c",
                                "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "test-run-dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(where / "bin" / "python"), "install", "-q",
                    "--disable-pip-version-check", "--no-deps", "--no-build-isolation",
                    str(_source_copy(where.parent / "source"))],
                   check=True, capture_output=True, text=True, timeout=600)
    return where / "bin"


def _outside_env() -> dict:
    """This process's environment without anything that points into the repository."""
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONSTARTUP")}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_workers(python: Path, address: str, workers: int, *, env: dict, cwd: Path, timeout_s: float = 120):
    script = ("import sys\nfrom distributed import Client\n"
              f"c = Client({address!r}, timeout=30)\nc.wait_for_workers({workers}, timeout={timeout_s})\nc.close()\n")
    subprocess.run([str(python), "-c", script], check=True, env=env, cwd=cwd, timeout=timeout_s + 60)


@pytest.mark.slow
def test_the_installed_core_bakes_on_a_cluster_started_as_the_docs_say(tmp_path):
    bin_dir = _venv_with_the_package(tmp_path / "venv")
    installed = subprocess.run([str(bin_dir / "python"), "-c",
                                "import importlib.metadata as m; print(m.version('hlod-core'))"],
                               capture_output=True, text=True, check=True, env=_outside_env(), cwd=tmp_path)
    assert installed.stdout.strip() == _version_in_one_place()
    python, env, away = bin_dir / "python", _outside_env(), tmp_path / "elsewhere"
    away.mkdir()
    where = subprocess.run([str(python), "-c", "import hlod_core; print(hlod_core.__file__)"], capture_output=True,
                           text=True, check=True, env=env, cwd=away).stdout.strip()
    assert where.startswith(str(tmp_path / "venv")), where  # the installed package, not the repository
    assert (Path(where).parent / "export" / "viewer_page" / "index.html").is_file()
    help_text = subprocess.run([str(bin_dir / "hlod-core"), "--help"], capture_output=True, text=True, check=True,
                               env=env, cwd=away).stdout
    assert "bake" in help_text and "evaluate" in help_text
    assert help_text.startswith("usage: hlod-core [-h]")  # the name it was run by

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    cluster_env = {**env, "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}
    scheduler = subprocess.Popen([str(python), "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                  "--dashboard-address", ":0"], cwd=away, env=cluster_env,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = subprocess.Popen([str(python), "-m", "dask", "worker", address, "--nworkers", "2", "--nthreads", "1",
                                "--dashboard-address", ":0"], cwd=away, env=cluster_env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for_workers(python, address, 2, env=env, cwd=away)
        scratch = tmp_path / "scratch"
        scratch.mkdir()
        on_cluster, local = tmp_path / "cluster.hlod", tmp_path / "local.hlod"
        baked = subprocess.run([str(bin_dir / "hlod-core"), "-q", "bake", str(model("cow")), "-o", str(on_cluster),
                                "--target-tris", "400", "--no-cache", "--scheduler", address,
                                "--scratch", str(scratch)],
                               capture_output=True, text=True, env=env, cwd=away, timeout=600)
        assert baked.returncode == 0, baked.stderr[-3000:]
        summary = json.loads(baked.stdout.strip().splitlines()[-1])
        assert summary["nodes"] > 1
    finally:
        for proc in (workers, scheduler):
            proc.terminate()
        for proc in (workers, scheduler):
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
    subprocess.run([str(bin_dir / "hlod-core"), "-q", "bake", str(model("cow")), "-o", str(local),
                    "--target-tris", "400", "--no-cache"], check=True, capture_output=True, env=env, cwd=away)
    from hlod_core.io import hlod_file

    assert file_bytes(hlod_file.load(on_cluster), tmp_path / "a.hlod") == \
        file_bytes(hlod_file.load(local), tmp_path / "b.hlod")
