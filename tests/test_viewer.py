"""The 3D Tiles viewer. The server (hlod_core/export/viewer.py: localhost only, its folders only),
the `view` command, and the page itself in a real browser: Debian's Chromium driven by Playwright,
WebGL through SwiftShader, CesiumJS from tools/viewer's npm install, loading an export of the
default city."""
from __future__ import annotations

import contextlib
import http.client
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from helpers import ROOT
from hlod_core.core.errors import InputError
from hlod_core.export import place, tiles3d, viewer

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
VIEWPORT = {"width": 640, "height": 480}
LOAD_TIMEOUT_MS = 120_000
#: The page's background (viewer.css and viewer.js), and how far a pixel may be from it and still count
BACKGROUND_RGB = (0x30, 0x34, 0x3A)
BACKGROUND_TOLERANCE = 6
#: Share of the picture the city covers at the fitted first view, measured 0.30: not only background.
MIN_GEOMETRY_SHARE = 0.15


@pytest.fixture(scope="module")
def tiles(tmp_path_factory, city_hlod) -> Path:
    folder = tmp_path_factory.mktemp("viewer") / "tiles"
    tiles3d.export(city_hlod, folder)
    return folder


def _get(url: str, path: str, method: str = "GET") -> tuple[int, dict, bytes]:
    host, port = url.removeprefix("http://").rstrip("/").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=10)
    try:
        conn.request(method, path)
        response = conn.getresponse()
        return response.status, dict(response.getheaders()), response.read()
    finally:
        conn.close()


# --- the server -----------------------------------------------------------------------------------

def test_server_serves_the_page_cesium_and_the_tiles_with_their_types(tiles):
    with viewer.serve(tiles) as server:
        server.start()
        assert server.url == f"http://127.0.0.1:{server.port}/" and server.server_address[0] == "127.0.0.1"
        status, headers, body = _get(server.url, "/")
        assert status == 200 and headers["Content-Type"].startswith("text/html") and b"/viewer/viewer.js" in body
        for path, kind in (("/viewer/viewer.js", "text/javascript"), ("/viewer/viewer.css", "text/css"),
                           ("/cesium/Cesium.js", "text/javascript"), ("/tiles/tileset.json", "application/json")):
            status, headers, body = _get(server.url, path)
            assert status == 200 and headers["Content-Type"].startswith(kind), (path, status, headers)
            assert int(headers["Content-Length"]) == len(body) > 0
        tileset = json.loads(_get(server.url, "/tiles/tileset.json")[2])
        uri = tileset["root"]["content"]["uri"]
        status, headers, body = _get(server.url, f"/tiles/{uri}")
        assert status == 200 and headers["Content-Type"] == "model/gltf-binary" and body[:4] == b"glTF"
        status, headers, body = _get(server.url, f"/tiles/{uri}", method="HEAD")
        assert status == 200 and body == b"" and int(headers["Content-Length"]) == (tiles / uri).stat().st_size


def test_server_serves_nothing_outside_its_folders(tiles, tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_text("not for the browser")
    link = tiles / "escape.txt"
    link.symlink_to(secret)
    try:
        with viewer.serve(tiles) as server:
            server.start()
            for path in ("/secret.txt", "/tiles/../tiles/tileset.json", "/tiles/%2e%2e/secret.txt", "//etc/passwd",
                         "/cesium/../../../etc/passwd", "/tiles/escape.txt", "/tiles/", "/tiles/tiles",
                         "/viewer/../viewer.py", "/tiles/.%2F..%2Fsecret.txt", "/etc/passwd", "/tiles//tileset.json",
                         "/tiles/..%5Csecret.txt", "/nothing"):
                status, _, body = _get(server.url, path)
                assert status == 404 and b"not for the browser" not in body, path
    finally:
        link.unlink()


def test_server_listens_on_loopback_only(tiles):
    """Not reachable on the machine's other addresses (where it has one besides loopback)."""
    with viewer.serve(tiles) as server:
        server.start()
        assert server.socket.getsockname()[0] == "127.0.0.1"
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            probe.connect(("192.0.2.1", 9))  # no packet is sent: this only picks the outgoing address
            address = probe.getsockname()[0]
        except OSError:
            address = "127.0.0.1"
        finally:
            probe.close()
        if address.startswith("127."):
            address = socket.gethostbyname(socket.gethostname())
        assert not address.startswith("127."), f"no address besides loopback to check: {address}"
        with pytest.raises(OSError):
            socket.create_connection((address, server.port), timeout=2).close()


def test_bad_folder_missing_cesium_and_a_taken_port_are_one_line_errors(tiles, tmp_path):
    with pytest.raises(InputError, match=rf"{tmp_path}: no tileset\.json"):
        viewer.serve(tmp_path)
    with pytest.raises(InputError, match=r"CesiumJS not found .*npm ci --prefix tools/viewer"):
        viewer.serve(tiles, cesium_dir=tmp_path)
    with viewer.serve(tiles) as server:
        with pytest.raises(InputError, match=rf"port {server.port}: cannot listen"):
            viewer.serve(tiles, port=server.port)


def test_view_command_prints_the_url_serves_and_ends_cleanly_on_sigterm(tiles, tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT), BROWSER="true")
    proc = subprocess.Popen([sys.executable, "-m", "hlod_core", "view", str(tiles), "--no-browser"], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:"), url
        assert _get(url, "/tiles/tileset.json")[0] == 200
    finally:
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert json.loads(out.strip().splitlines()[-1])["url"] == url
    bad = subprocess.run([sys.executable, "-m", "hlod_core", "view", str(tmp_path), "--no-browser"], env=env,
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and bad.stderr.strip().count("\n") == 0
    assert f"{tmp_path}: no tileset.json" in bad.stderr


# --- the page, in Chromium ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def browser():
    """Debian's Chromium through Playwright (one per module: Playwright's sync API runs one at a time)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        try:
            yield chromium
        finally:
            chromium.close()


@contextlib.contextmanager
def _open_page(browser, tiles: Path):
    """The viewer page on `tiles`, loaded; console errors and failed requests in `.problems`."""
    with viewer.serve(tiles) as server:
        server.start()
        tab = browser.new_page(viewport=VIEWPORT)
        try:
            problems: list[str] = []
            tab.on("console", lambda m: m.type == "error" and problems.append(f"console: {m.text}"))
            tab.on("pageerror", lambda e: problems.append(f"page error: {e}"))
            tab.on("response", lambda r: r.status >= 400 and problems.append(f"HTTP {r.status}: {r.url}"))
            requested: list[str] = []  # paths under /tiles/, in the export folder
            tab.on("request", lambda r: r.url.startswith(server.url + "tiles/")
                   and requested.append(r.url.removeprefix(server.url + "tiles/")))
            tab.requested = requested
            tab.goto(server.url)
            _wait_loaded(tab)
            tab.problems = problems
            yield tab
        finally:
            tab.close()


@pytest.fixture(scope="module")
def page(browser, tiles):
    """The viewer page on the city's export, loaded."""
    with _open_page(browser, tiles) as tab:
        yield tab


def _wait_loaded(tab) -> None:
    """Until the tileset is loaded for the current view and two more frames have been drawn."""
    tab.wait_for_function("window.hlodViewer && hlodViewer.ready && hlodViewer.allTilesLoaded",
                          timeout=LOAD_TIMEOUT_MS)
    _wait_drawn(tab)
    tab.wait_for_function("hlodViewer.allTilesLoaded", timeout=LOAD_TIMEOUT_MS)


def _wait_drawn(tab) -> None:
    """Until two more frames have been drawn: Cesium has drawn the page's state as it is now
    (however long a frame takes on a loaded machine; no fixed wait). The page draws on demand, so each
    frame is asked for (hlodViewer.redraw)."""
    tab.evaluate("hlodViewer.redraw().then(() => hlodViewer.redraw())")


def _picture(tab, tmp_path: Path, name: str) -> np.ndarray:
    """The 3D view (the panel left out), RGB."""
    file = tmp_path / f"{name}.png"
    tab.locator("#cesium canvas").screenshot(path=str(file))
    return np.asarray(Image.open(file).convert("RGB"), np.int16)


def _geometry_share(rgb: np.ndarray) -> float:
    return float(np.mean(np.abs(rgb - np.array(BACKGROUND_RGB)).max(axis=2) > BACKGROUND_TOLERANCE))


def test_page_loads_every_tile_and_shows_the_city_without_errors(page, tmp_path):
    from playwright.sync_api import expect

    stats = page.evaluate("hlodViewer.stats()")
    assert stats["tilesLoaded"] >= stats["tilesDrawn"] > 0 and stats["trianglesDrawn"] > 0, stats
    assert page.evaluate("hlodViewer.errors") == [] and page.problems == []
    assert _geometry_share(_picture(page, tmp_path, "fitted")) > MIN_GEOMETRY_SHARE
    # the panel's counters follow at most 200 ms behind the frames: wait for them, do not read once
    expect(page.locator("#tiles-drawn")).to_have_text(f"{stats['tilesDrawn']:,}", timeout=LOAD_TIMEOUT_MS)


def test_lower_screen_space_error_loads_more_tiles_and_deeper_levels(page):
    page.evaluate("hlodViewer.setMaximumScreenSpaceError(32)")
    _wait_loaded(page)
    coarse = page.evaluate("hlodViewer.stats()")
    page.evaluate("hlodViewer.setMaximumScreenSpaceError(2)")
    _wait_loaded(page)
    fine = page.evaluate("hlodViewer.stats()")
    assert fine["tilesLoaded"] > coarse["tilesLoaded"] and fine["tilesDrawn"] > coarse["tilesDrawn"], (coarse, fine)
    assert fine["maxDepthDrawn"] > coarse["maxDepthDrawn"] and fine["trianglesDrawn"] > coarse["trianglesDrawn"]
    assert page.locator("#sse-value").inner_text() == "2"
    assert page.problems == []


def test_colour_by_depth_and_boxes_change_the_picture(page, tmp_path):
    page.evaluate("hlodViewer.setMaximumScreenSpaceError(4)")
    _wait_loaded(page)
    plain = _picture(page, tmp_path, "plain")
    page.locator("#depth-colours").check()
    _wait_drawn(page)
    coloured = _picture(page, tmp_path, "depth")
    page.locator("#depth-colours").uncheck()
    page.locator("#boxes").check()
    _wait_drawn(page)
    boxed = _picture(page, tmp_path, "boxes")
    page.locator("#boxes").uncheck()
    _wait_drawn(page)
    again = _picture(page, tmp_path, "again")

    def changed(a, b):
        return float(np.mean(np.abs(a - b).max(axis=2) > BACKGROUND_TOLERANCE))

    # the city's grey turns to the depth palette's hues: a picture of several saturated colours
    saturation = coloured.max(axis=2) - coloured.min(axis=2)
    assert changed(plain, coloured) > 0.5 * _geometry_share(plain) and np.mean(saturation > 60) > 0.1
    assert changed(plain, boxed) > 0.002  # box outlines: thin lines
    assert changed(plain, again) < 0.002  # and back
    assert page.problems == []


#: CesiumJS's picture of a compact export (quantized or Draco) against the plain one's, PSNR-Y (the
#: issue's target).
MIN_QUANTIZED_PSNR_Y_DB = 40.0


# slow: a textured bake (shared with the textured acceptance check) and a second page; the GLBs' materials pass
# the validators in test_export
@pytest.mark.slow
def test_page_shows_the_exports_textures_and_colours(browser, textured_scene_bake, tmp_path):
    """The textured test scene (tests/scenes/textured_scene.py, read from its GLB) exported with its
    materials, textures and vertex colours: the page draws them (the city above is one grey). Its
    compact export (Draco: normals, UVs and colours compressed, a primitive per material; textures
    as WebP through EXT_texture_webp) draws the same picture within MIN_QUANTIZED_PSNR_Y_DB."""
    from hlod_core.report.image_error import psnr

    folder = tmp_path / "tiles"
    summary = tiles3d.export(textured_scene_bake[1], folder)
    assert summary["image_files"] >= 2
    compact = tiles3d.export(textured_scene_bake[1], tmp_path / "draco", mesh="draco", textures="webp")
    assert sorted(p.suffix for p in (tmp_path / "draco/textures").iterdir()) == [".webp"] * compact["image_files"]
    pictures = {}
    for name, source in (("plain", folder), ("draco", tmp_path / "draco")):
        with _open_page(browser, source) as tab:
            pictures[name] = _picture(tab, tmp_path, f"textured_{name}")
            assert tab.problems == [] and tab.evaluate("hlodViewer.errors") == []
    rgb = pictures["plain"]
    y_db = float(psnr(rgb.astype(np.uint8), pictures["draco"].astype(np.uint8))[0])
    assert y_db >= MIN_QUANTIZED_PSNR_Y_DB, y_db
    geometry = np.abs(rgb - np.array(BACKGROUND_RGB)).max(axis=2) > BACKGROUND_TOLERANCE
    assert geometry.mean() > MIN_GEOMETRY_SHARE
    pixels = rgb[geometry]
    saturated = pixels[(pixels.max(axis=1) - pixels.min(axis=1)) > 40]
    assert len(saturated) > 0.15 * len(pixels)  # measured 0.30 (the city's grey: none)
    dominant = np.bincount(saturated.argmax(axis=1), minlength=3) / len(saturated)
    assert np.count_nonzero(dominant > 0.05) >= 2, dominant  # red roofs and green ground, at least


# --- a placed export on the globe -------------------------------------------------------------------

#: Where the placed export stands: San Francisco, 16 m above the ellipsoid, turned 30 degrees.
PLACE = place.place(-122.4194, 37.7749, 16.0, 30.0)
#: ([origin], place) -> the root's computed transform against CesiumJS's own frame at the place: the
#: distance of the scene's origin from Cesium's point (m), the cosines of +Z with Cesium's ellipsoid
#: normal and of +Y with north turned clockwise by the heading.
ROOT_FRAME_JS = """([o, p]) => {
  const V = Cesium.Cartesian3, M = Cesium.Matrix4, m = hlodViewer.tileset.root.computedTransform;
  const at = V.fromDegrees(p.longitude_deg, p.latitude_deg, p.height_m);
  const enu = Cesium.Transforms.eastNorthUpToFixedFrame(at);
  const col = (k, mat) => V.normalize(M.multiplyByPointAsVector(mat, [V.UNIT_X, V.UNIT_Y, V.UNIT_Z][k], new V()),
    new V());
  const origin = M.multiplyByPoint(m, new V(-o[0], -o[1], -o[2]), new V());
  const h = Cesium.Math.toRadians(p.heading_deg);
  const y = V.add(V.multiplyByScalar(col(0, enu), Math.sin(h), new V()),
    V.multiplyByScalar(col(1, enu), Math.cos(h), new V()), new V());
  return {distance: V.distance(origin, at), up: V.dot(col(2, m), Cesium.Ellipsoid.WGS84.geodeticSurfaceNormal(at)),
    y: V.dot(col(1, m), y)};
}"""


def test_a_placed_export_stands_on_a_plain_globe_and_every_tile_is_requested(browser, city_hlod, tmp_path):
    """The city exported at PLACE (split into external tilesets: 445 nodes): the page reads its
    place, draws a plain globe (no imagery layer, the ellipsoid terrain) with the city standing at
    that longitude and latitude (the root frame as CesiumJS's own geodesy computes it), no console
    error or failed request; at a maximum screen-space error
    of 1e-6 px (every tile with an error refines) from the fitted view every tileset file and every
    GLB of the export is requested and every tile loaded, and the city is drawn over the globe."""
    folder = tmp_path / "placed"
    summary = tiles3d.export(city_hlod, folder, place=PLACE)
    assert summary["tileset_files"] > 1
    with _open_page(browser, folder) as tab:
        assert tab.evaluate("hlodViewer.place") == PLACE.as_dict()
        globe = tab.evaluate("""() => { const s = hlodViewer.viewer.scene, c = Cesium.Cartographic.fromCartesian(
            hlodViewer.tileset.boundingSphere.center);
            return {shown: s.globe !== undefined && s.globe.show, layers: s.globe.imageryLayers.length,
                    terrain: s.globe.terrainProvider instanceof Cesium.EllipsoidTerrainProvider,
                    lon: Cesium.Math.toDegrees(c.longitude), lat: Cesium.Math.toDegrees(c.latitude)}; }""")
        assert globe["shown"] and globe["layers"] == 0 and globe["terrain"], globe
        # the city's bounding sphere (320 m across) is centred within 0.01 degrees (about 1 km) of the place
        assert abs(globe["lon"] - PLACE.longitude_deg) < 0.01 and abs(globe["lat"] - PLACE.latitude_deg) < 0.01
        # CesiumJS's own geodesy: the root's computed transform stands the scene's origin at Cesium's
        # point of the place (within 1 mm), +Z along its ellipsoid normal, +Y north turned 30 degrees
        frame = tab.evaluate(ROOT_FRAME_JS, [list(map(float, city_hlod.origin)), PLACE.as_dict()])
        assert frame["distance"] < 1e-3 and frame["up"] > 1 - 1e-12 and frame["y"] > 1 - 1e-12, frame
        with_city = _picture(tab, tmp_path, "placed")
        tab.evaluate("hlodViewer.tileset.show = false")
        _wait_drawn(tab)
        globe_only = _picture(tab, tmp_path, "globe_only")
        tab.evaluate("hlodViewer.tileset.show = true")
        tab.evaluate("hlodViewer.setMaximumScreenSpaceError(1e-6)")  # every tile with an error refines
        _wait_loaded(tab)
        stats = tab.evaluate("hlodViewer.stats()")
        assert tab.problems == [] and tab.evaluate("hlodViewer.errors") == []
        requested = set(tab.requested)
    files = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.suffix in (".json", ".glb")}
    assert requested == files, sorted(files - requested)[:10]
    assert stats["tilesLoaded"] == summary["glb_files"], stats
    # the globe's colour fills what the city leaves; the city is drawn over it, not buried in it
    assert float(np.mean(np.abs(with_city - globe_only).max(axis=2) > BACKGROUND_TOLERANCE)) > MIN_GEOMETRY_SHARE
    globe_rgb = np.array([0x6B, 0x7A, 0x66])
    assert float(np.mean(np.abs(globe_only - globe_rgb).max(axis=2) <= 24)) > 0.2


# --- quantized tile content -----------------------------------------------------------------------

def test_quantized_and_draco_exports_look_like_the_plain_one(browser, page, city_hlod, tmp_path):
    """The city exported with positions and normals quantized (KHR_mesh_quantization) and Draco
    compressed (KHR_draco_mesh_compression, decoded by CesiumJS's own Draco decoder) with each node's
    leaves in one tile (`--merge-leaves`): CesiumJS loads each without an error, and its picture from
    the same fitted camera at 16 px and at 2 px is within MIN_QUANTIZED_PSNR_Y_DB of the plain
    export's (measured: quantized 60.0 and 60.3 dB, Draco with merged leaves 54.0 and 41.7 dB)."""
    from hlod_core.report.image_error import psnr

    def pictures_of(tab, name: str) -> None:
        for sse in (16, 2):
            tab.evaluate(f"hlodViewer.setMaximumScreenSpaceError({sse})")
            _wait_loaded(tab)
            pictures[name, sse] = _picture(tab, tmp_path, f"{name}_{sse}").astype(np.uint8)
        assert tab.problems == [] and tab.evaluate("hlodViewer.errors") == []

    pictures = {}
    # the plain export: the module's page, already open on it (one page less to start), from the fitted
    # view as every page opens with, without the depth colours and boxes the tests above turned off again
    page.evaluate("hlodViewer.setColorByDepth(false); hlodViewer.setShowBoxes(false); hlodViewer.fitCamera()")
    pictures_of(page, "plain")
    for mesh in ("quantized", "draco"):  # Draco with a node's leaves in one tile (export --merge-leaves)
        tiles3d.export(city_hlod, tmp_path / mesh, mesh=mesh, merge_leaves=(mesh == "draco"))
        with _open_page(browser, tmp_path / mesh) as tab:
            pictures_of(tab, mesh)
    for mesh in ("quantized", "draco"):
        for sse in (16, 2):
            y_db = float(psnr(pictures["plain", sse], pictures[mesh, sse])[0])
            assert y_db >= MIN_QUANTIZED_PSNR_Y_DB, (mesh, sse, y_db)
            assert _geometry_share(pictures[mesh, sse]) > MIN_GEOMETRY_SHARE
