"""View in Browser and `--command hlod view` in the real bpy module, with the extension
built into its zip (CesiumJS bundled as viewer/cesium) and installed as Blender installs it
(conftest.py's fixtures; the main .venv's bpy 5.0: nothing here depends on the version).

This file is also the script its checks run in, one bpy process each (as tests/blender/blender_checks.py):

    python tests/blender/test_addon_viewer.py REPO_DIR CHECK WORK_DIR

prints one JSON object as its last line. The web browser is a recorder: $BROWSER is a shell script
that appends the URL it is given to a file, so "the page was opened" is checked and nothing opens.
"""
from __future__ import annotations

import http.client
import json
import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

NAME = "bl_ext.r.hlod"
HTTP_TIMEOUT_S = 30.0  # one request to the local server (a hang guard)
START_TIMEOUT_S = 120.0  # bpy's start-up and the extension's enabling, on a loaded 2-core machine
STOP_TIMEOUT_S = 120.0  # SIGTERM to exit (serve_forever polls every 0.5 s; bpy's exit): a hang guard


def http_status(port: int, path: str) -> int | str:
    """The status of GET `path` (sent as written: no normalisation of `..`), or the error's name."""
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=HTTP_TIMEOUT_S)
    try:
        connection.request("GET", path)
        response = connection.getresponse()
        response.read()
        return response.status
    except OSError as exc:
        return type(exc).__name__
    finally:
        connection.close()


def port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(HTTP_TIMEOUT_S)
        return s.connect_ex(("127.0.0.1", port)) == 0


def browser_recorder(folder: Path) -> tuple[str, Path]:
    """($BROWSER, the file it appends each URL to)."""
    script, record = folder / "browser.sh", folder / "opened.txt"
    script.write_text('#!/bin/sh\necho "$1" >> "$(dirname "$0")/opened.txt"\n')
    script.chmod(0o755)
    return f"{script} %s", record


def opened(record: Path) -> list[str]:
    return record.read_text().split() if record.is_file() else []


# --- the checks, in the bpy process ---------------------------------------------------------------

PATHS_200 = ("/", "/tiles/tileset.json", "/cesium/Cesium.js")
PATHS_404 = ("/tiles/../row.hlod", "/tiles/%2e%2e/row.hlod", "/row.hlod", "/cesium/../../blender_manifest.toml",
             "//etc/passwd")


def _error(call) -> str:
    """The operator's error report (bpy.ops raises RuntimeError with it), '' when it finished."""
    try:
        call()
    except RuntimeError as exc:
        return str(exc).strip()
    return ""


def check_operator(repo, work) -> dict:
    """The View in Browser operator on an export made by the Export operator: errors first, then
    serve, reopen, Stop, file load and disabling the add-on."""
    import importlib

    import bpy  # first: it puts Blender's scripts/modules (addon_utils) on sys.path

    # isort: split
    import addon_utils

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import blender_checks
    import blender_preview

    work = Path(work)
    threads_before = threading.active_count()
    package = blender_preview.enable_from_repo(repo)
    out = {"viewer_modules_on_enable": sorted(m for m in sys.modules if m.startswith(NAME) and "viewer" in m)}
    tiles_server = importlib.import_module(NAME + ".addon.tiles_server")
    props = bpy.context.scene.hlod
    out["no_export_error"] = _error(lambda: bpy.ops.hlod.view_tiles())
    (work / "empty").mkdir()
    out["no_tileset_error"] = _error(lambda: bpy.ops.hlod.view_tiles(directory=str(work / "empty")))
    # an export by the Export operator (which records its folder)
    blender_checks._box_row_scene()
    props.output_path, props.target_tris, props.jobs, props.use_cache = str(work / "row.hlod"), 400, 1, False
    out["bake"] = sorted(bpy.ops.hlod.bake())
    out["export"] = sorted(bpy.ops.hlod.export(filepath=str(work / "row.hlod"), format="3DTILES"))
    out["tiles_dir"] = bpy.path.abspath(props.tiles_dir)
    # CesiumJS missing: the bundled copy moved away (and no $HLOD_CESIUM_DIR)
    bundled = Path(package.__file__).parent / "viewer" / "cesium"
    out["bundled_cesium"] = (bundled / "Cesium.js").is_file()
    moved = bundled.with_name("cesium-moved")
    if bundled.is_dir():
        bundled.rename(moved)
    try:
        out["no_cesium_error"] = _error(lambda: bpy.ops.hlod.view_tiles())
    finally:
        if moved.is_dir():
            moved.rename(bundled)
    out["serving_after_errors"] = tiles_server.url()
    # serve
    out["view"] = sorted(bpy.ops.hlod.view_tiles())
    url = tiles_server.url()
    out["url"] = url
    port = int(url.rsplit(":", 1)[1].strip("/")) if url else 0
    out["bound"] = tiles_server.running_server().socket.getsockname()[0] if url else None
    out["statuses"] = {path: http_status(port, path) for path in PATHS_200 + PATHS_404}
    out["again"] = sorted(bpy.ops.hlod.view_tiles())  # a second press: the same server, the page again
    out["url_again"] = tiles_server.url()
    out["opened"] = opened(work / "opened.txt")
    out["stop"] = sorted(bpy.ops.hlod.view_tiles(stop=True))
    out["after_stop"] = {"url": tiles_server.url(), "port_open": port_open(port)}
    # file load closes it
    bpy.ops.hlod.view_tiles()
    port = int(tiles_server.url().rsplit(":", 1)[1].strip("/"))
    bpy.ops.wm.read_homefile(use_empty=True)
    out["after_load"] = {"url": tiles_server.url(), "port_open": port_open(port)}
    # a folder picked (the new file has no export recorded), then the add-on disabled
    out["picked"] = sorted(bpy.ops.hlod.view_tiles(directory=out["tiles_dir"]))
    out["picked_recorded"] = bpy.path.abspath(bpy.context.scene.hlod.tiles_dir) == out["tiles_dir"]
    url = tiles_server.url()
    port = int(url.rsplit(":", 1)[1].strip("/"))
    out["picked_status"] = http_status(port, "/tiles/tileset.json")
    addon_utils.disable(NAME, default_set=True)
    out["after_disable"] = {"url": tiles_server.url(), "port_open": port_open(port),
                            "threads": threading.active_count() - threads_before}
    return out


def main(argv: list[str]) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
    import blender_preview

    repo, check, work = argv[:3]
    out = globals()[f"check_{check}"](repo, work, *argv[3:])
    print(json.dumps(out, default=str))
    blender_preview.exit_process(0)


if __name__ == "__main__":
    main(sys.argv[1:])


# --- the tests, in pytest -------------------------------------------------------------------------

import pytest  # noqa: E402 - not needed by the checks above (Blender's Python has no pytest)

from blender_runs import all_hold, blender  # noqa: E402 - the tests' helpers, for the tests only
from helpers import ROOT  # noqa: E402 - the tests' helpers, for the tests only

pytestmark = pytest.mark.blender


@pytest.fixture()
def browser(tmp_path, monkeypatch) -> Path:
    """$BROWSER records instead of opening (the checks' processes inherit it); the record file."""
    command, record = browser_recorder(tmp_path)
    monkeypatch.setenv("BROWSER", command)
    monkeypatch.delenv("HLOD_CESIUM_DIR", raising=False)
    return record


def test_view_in_browser_serves_the_export_on_localhost_and_stops(repo, tmp_path, browser):
    """Enabling imports no viewer code; no export yet, a folder without tileset.json and CesiumJS
    missing are one-line errors; the export the Export operator wrote is served on 127.0.0.1 with
    the page, the tileset and the bundled CesiumJS (200) and nothing outside them (404); the page is
    opened, and opened again by a second press on the same server; Stop, loading a file and
    disabling the add-on each close the port (no thread left)."""
    out = blender(repo, "operator", tmp_path, script="test_addon_viewer.py")
    statuses = out["statuses"]
    errors = [out["no_export_error"], out["no_tileset_error"], out["no_cesium_error"]]
    all_hold(out,
             no_viewer_code_on_enable=out["viewer_modules_on_enable"] == [],
             no_export="no 3D Tiles export yet" in out["no_export_error"],
             no_tileset="tileset.json" in out["no_tileset_error"] and "empty" in out["no_tileset_error"],
             no_cesium="cesium" in out["no_cesium_error"].lower(),
             errors_one_line=all(e and "\n" not in e and "Traceback" not in e for e in errors),
             nothing_served_after_errors=out["serving_after_errors"] is None,
             exported=out["bake"] == out["export"] == ["FINISHED"]
             and out["tiles_dir"] == str(tmp_path / "row_3dtiles"),
             bundled=out["bundled_cesium"],
             serving=out["view"] == ["FINISHED"] and bool(out["url"]) and out["url"].startswith("http://127.0.0.1:"),
             localhost_only=out["bound"] == "127.0.0.1",
             served=all(statuses[p] == 200 for p in PATHS_200),
             nothing_else=all(statuses[p] == 404 for p in PATHS_404),
             reopened=out["again"] == ["FINISHED"] and out["url_again"] == out["url"]
             and out["opened"] == [out["url"]] * 2,
             stop_closes=out["stop"] == ["FINISHED"] and out["after_stop"] == {"url": None, "port_open": False},
             load_closes=out["after_load"] == {"url": None, "port_open": False},
             picked_folder=out["picked"] == ["FINISHED"] and out["picked_recorded"] and out["picked_status"] == 200,
             disable_closes=out["after_disable"] == {"url": None, "port_open": False, "threads": 0})


@pytest.fixture(scope="module")
def tiles(tmp_path_factory) -> Path:
    """A small 3D Tiles export (a 2,048-triangle terrain-like sheet, baked with 256 triangles per node)."""
    import numpy as np

    from hlod_core.bake.pipeline import BakeSettings, bake
    from hlod_core.export import tiles3d
    from hlod_core.io import meshes

    side = 33
    x, y = np.meshgrid(np.linspace(0.0, 8.0, side), np.linspace(0.0, 8.0, side))
    positions = np.stack([x, y, 0.3 * np.sin(x) * np.cos(y)], axis=-1).reshape(-1, 3)
    quads = (np.arange(side - 1)[:, None] * side + np.arange(side - 1)[None, :]).ravel()
    faces = np.concatenate([np.stack([quads, quads + 1, quads + side + 1], axis=1),
                            np.stack([quads, quads + side + 1, quads + side], axis=1)])
    mesh = meshes.from_arrays(positions, faces, name="sheet")
    out = tmp_path_factory.mktemp("viewer") / "sheet_3dtiles"
    tiles3d.export(bake(mesh, BakeSettings(target_tris=256, jobs=1)), out)
    return out


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _command(repo, *arguments: str) -> list[str]:
    return [sys.executable, str(ROOT / "scripts/hlod_blender.py"), "--extension-repo", str(repo / "repo"), *arguments]


def _environment(repo) -> dict:
    return {**os.environ, "BLENDER_USER_RESOURCES": str(repo / "user"), "PYTHONPATH": str(ROOT)}


def test_background_view_command_prints_the_url_and_serves_until_sigterm(repo, tiles, tmp_path, browser):
    """`--command hlod view DIR --no-browser --port N` (the registered command through the bpy
    module): the first stdout line is the URL, the tileset and the page answer, nothing is opened,
    SIGTERM ends it with exit status 0 and the port is free."""
    port = _free_port()
    proc = subprocess.Popen(_command(repo, "view", str(tiles), "--no-browser", "--port", str(port)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_environment(repo), cwd=ROOT)
    try:
        first = [None]
        reader = threading.Thread(target=lambda: first.__setitem__(0, proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(START_TIMEOUT_S)
        line = (first[0] or "").strip()
        statuses = {path: http_status(port, path) for path in ("/", "/tiles/tileset.json", "/tiles/../tileset.json")}
        proc.send_signal(signal.SIGTERM)
        status = proc.wait(timeout=STOP_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    stderr = proc.stderr.read()
    assert line == f"http://127.0.0.1:{port}/", (line, stderr[-3000:])
    assert statuses == {"/": 200, "/tiles/tileset.json": 200, "/tiles/../tileset.json": 404}, statuses
    assert status == 0, (status, stderr[-3000:])
    assert not port_open(port)
    assert opened(browser) == []


def test_background_view_command_refuses_a_folder_without_tileset_json(repo, tmp_path, browser):
    """One line naming the folder, exit status 2, nothing on stdout, nothing served."""
    (tmp_path / "not_tiles").mkdir()
    proc = subprocess.run(_command(repo, "view", str(tmp_path / "not_tiles"), "--no-browser"), capture_output=True,
                          text=True, env=_environment(repo), cwd=ROOT, timeout=START_TIMEOUT_S)
    errors = [line for line in proc.stderr.splitlines() if "hlod" in line or "Error" in line or "Traceback" in line]
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert len(errors) == 1 and errors[0].startswith("hlod: error: ") and "not_tiles" in errors[0], proc.stderr
    assert "tileset.json" in errors[0] and proc.stdout == ""
    assert opened(browser) == []


def test_the_build_bundles_cesium_less_its_module_entry_points_and_stops_when_asked_for_a_missing_one(tmp_path):
    """scripts/build_extension.py: viewer/cesium gets Build/Cesium's files (a nested index.js too)
    but not its top-level index.js / index.cjs, and the package's licence; `--cesium` naming a
    folder without Cesium.js stops the build in one line; `--viewer none` bundles nothing."""
    sys.path.insert(0, str(ROOT / "scripts"))
    import build_extension

    build = tmp_path / "node_modules/cesium/Build/Cesium"
    for name in ("Cesium.js", "index.js", "index.cjs", "Workers/index.js", "Assets/Textures/moonSmall.jpg"):
        (build / name).parent.mkdir(parents=True, exist_ok=True)
        (build / name).write_text(name)
    (build.parents[1] / "LICENSE.md").write_text("Apache-2.0")
    where = tmp_path / "stage"
    build_extension.stage_cesium(build, where)
    bundled = sorted(str(p.relative_to(where)) for p in where.rglob("*") if p.is_file())
    assert bundled == ["viewer/cesium/Assets/Textures/moonSmall.jpg", "viewer/cesium/Cesium.js",
                       "viewer/cesium/LICENSE.md", "viewer/cesium/Workers/index.js"]
    with pytest.raises(SystemExit) as stop:
        build_extension.cesium_build("bundle", str(tmp_path / "nothing"))
    assert str(stop.value) == f"build_extension: --cesium {tmp_path / 'nothing'}: no Cesium.js there " \
                              "(give npm's cesium/Build/Cesium)"
    assert build_extension.cesium_build("auto", str(build)) == build.resolve()
    assert build_extension.cesium_build("none", str(build)) is None
