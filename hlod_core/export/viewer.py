"""A local web viewer of a 3D Tiles export: a small static HTTP server on 127.0.0.1 that
serves the viewer page (`viewer_page/`), CesiumJS's built files and the tileset folder, and nothing
else. The page (viewer_page/viewer.js) shows the tileset with CesiumJS in a local frame (no globe,
no imagery, no token, no network), or, when the export is placed (its extras.place), on a plain
WGS84 globe of one colour (no imagery, no terrain, still no network), and exposes
`window.hlodViewer` for scripts and tests.

URL map (GET and HEAD only; anything else is 404, never a directory listing):
    /                 -> viewer_page/index.html
    /viewer/<file>    -> viewer_page/<file>
    /cesium/<path>    -> the CesiumJS build folder (`find_cesium`: Cesium.js, Workers/, Assets/ ...)
    /tiles/<path>     -> the tileset folder (tileset.json, tiles/*.glb, textures/)
A path with a `..` or empty segment, a backslash, a NUL, or one that resolves (through a symlink)
outside its folder is 404.

CesiumJS is not a Python package: the npm package `cesium` (pinned in tools/viewer/package.json,
installed by the setup) in a source checkout, or `viewer/cesium` inside the Blender extension's zip
(scripts/build_extension.py bundles it). Standard library only: the extension imports this module
when its View in Browser button is used, never before.
"""
from __future__ import annotations

import http.server
import logging
import os
import socket
import sys
import threading
import urllib.parse
from pathlib import Path
from typing import Callable

from ..core.errors import InputError
from ..core.signals import Terminated

log = logging.getLogger(__name__)

PAGE_DIR = Path(__file__).resolve().parent / "viewer_page"
HOST = "127.0.0.1"  # never another interface
#: Where CesiumJS's build may be, after --cesium and $HLOD_CESIUM_DIR, relative to hlod_core's parent:
#: a source checkout's npm install, and the extension's bundled copy.
CESIUM_PLACES = ("tools/viewer/node_modules/cesium/Build/Cesium", "viewer/cesium")
CESIUM_ENV = "HLOD_CESIUM_DIR"
MIME_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
              ".mjs": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
              ".json": "application/json", ".glb": "model/gltf-binary", ".gltf": "model/gltf+json",
              ".bin": "application/octet-stream", ".wasm": "application/wasm", ".png": "image/png",
              ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp", ".ktx2": "image/ktx2",
              ".svg": "image/svg+xml", ".xml": "application/xml", ".txt": "text/plain; charset=utf-8",
              ".woff": "font/woff", ".woff2": "font/woff2", ".ttf": "font/ttf"}
CHUNK_BYTES = 1 << 16
#: Windows' SO_REUSEADDR (winsock2.h); SO_EXCLUSIVEADDRUSE is its complement, ~SO_REUSEADDR.
SO_REUSEADDR_WINDOWS = 0x0004


def find_cesium(explicit: str | os.PathLike | None = None) -> Path:
    """The folder of CesiumJS's built files (holding Cesium.js): `explicit`, else $HLOD_CESIUM_DIR,
    else CESIUM_PLACES. InputError naming where it looked when none holds Cesium.js."""
    base = Path(__file__).resolve().parents[2]  # the repository (or the extension's folder)
    if explicit is not None:
        candidates = [Path(explicit)]
    elif os.environ.get(CESIUM_ENV):
        candidates = [Path(os.environ[CESIUM_ENV])]
    else:
        candidates = [base / place for place in CESIUM_PLACES]
    for folder in candidates:
        if (folder / "Cesium.js").is_file():
            return folder.resolve()
    raise InputError(f"CesiumJS not found (no Cesium.js in {', '.join(str(c) for c in candidates)}): "
                     "install it with `npm ci --prefix tools/viewer` (bash test.sh does), or give "
                     f"--cesium DIR / ${CESIUM_ENV} (a cesium/Build/Cesium folder)")


class _Handler(http.server.BaseHTTPRequestHandler):
    server: "ViewerServer"
    protocol_version = "HTTP/1.1"

    def do_GET(self) -> None:  # http.server's naming
        self._send(body=True)

    def do_HEAD(self) -> None:
        self._send(body=False)

    def _send(self, *, body: bool) -> None:
        file = self.server.resolve(self.path)
        if file is None:
            self.send_error(404, "not found")
            return
        size = file.stat().st_size
        self.send_response(200)
        self.send_header("Content-Type", MIME_TYPES.get(file.suffix.lower(), "application/octet-stream"))
        self.send_header("Content-Length", str(size))
        self.send_header("Cache-Control", "no-cache")  # a re-export in place shows at the next load
        self.end_headers()
        if body:
            with file.open("rb") as f:
                while chunk := f.read(CHUNK_BYTES):
                    self.wfile.write(chunk)

    def log_message(self, format: str, *args) -> None:  # noqa: A002 - http.server's signature
        log.debug("viewer: " + format, *args)


def port_options(platform: str | None = None) -> list[tuple[int, int, int]]:
    """The (level, option, value) socket options set before the viewer binds its port, on `platform`
    (a sys.platform string, default this machine's). POSIX (Linux, macOS): SO_REUSEADDR, so that a
    port just closed (in TIME_WAIT) can be listened on again at once; there it never lets a second
    socket listen on a port in use. Windows: SO_EXCLUSIVEADDRUSE and not SO_REUSEADDR, which there
    would let another program bind the port while the viewer listens on it and take its requests."""
    if (sys.platform if platform is None else platform) == "win32":
        return [(socket.SOL_SOCKET, getattr(socket, "SO_EXCLUSIVEADDRUSE", ~SO_REUSEADDR_WINDOWS), 1)]
    return [(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)]


def page_url(port: int) -> str:
    """The viewer page's URL on `port`: the address it listens on (HOST), never `localhost`, which
    Windows resolves to ::1 first; a client without a fallback to 127.0.0.1 (Python's urllib, a
    script) then waits 1 to 2 s on each connection for ::1 to refuse."""
    return f"http://{HOST}:{port}/"


class ViewerServer(http.server.ThreadingHTTPServer):
    """The viewer's HTTP server on 127.0.0.1:`port` (0 = a free one). `url` is its page (page_url). `start()`
    serves from a daemon thread, `serve_forever()` from the caller's; `close()` (or leaving the
    `with` block) stops serving and frees the port. Its socket options are `port_options()`'s."""

    daemon_threads = True
    allow_reuse_address = False  # port_options decides, per platform

    def server_bind(self) -> None:
        for level, option, value in port_options():
            self.socket.setsockopt(level, option, value)
        super().server_bind()

    def __init__(self, tiles_dir: Path, cesium_dir: Path, *, port: int = 0):
        self.roots = {"viewer": PAGE_DIR, "cesium": cesium_dir.resolve(), "tiles": tiles_dir.resolve()}
        try:
            super().__init__((HOST, port), _Handler)
        except OSError as exc:
            raise InputError(f"port {port}: cannot listen on {HOST} ({exc.strerror or exc})") from None
        self.port = int(self.server_address[1])
        self.url = page_url(self.port)
        self._thread: threading.Thread | None = None

    def resolve(self, request_path: str) -> Path | None:
        """The file a request path names, or None (404)."""
        path = urllib.parse.urlsplit(request_path).path
        if path == "/":
            return PAGE_DIR / "index.html"
        parts = urllib.parse.unquote(path).split("/")
        if len(parts) < 3 or parts[0] != "" or parts[1] not in self.roots:
            return None
        rest = parts[2:]
        if any(p in ("", ".", "..") or "\\" in p or "\0" in p for p in rest):
            return None
        root = self.roots[parts[1]]
        file = root.joinpath(*rest)
        try:
            real = file.resolve(strict=True)
        except (OSError, RuntimeError):
            return None
        if not real.is_relative_to(root) or not real.is_file():
            return None
        return real

    def start(self) -> "ViewerServer":
        if self._thread is None:
            self._thread = threading.Thread(target=self.serve_forever, name="hlod-viewer", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        if self._thread is not None:
            self.shutdown()
            self._thread.join()
            self._thread = None
        self.server_close()

    def __enter__(self) -> "ViewerServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def serve(tiles_dir: str | os.PathLike, *, port: int = 0, cesium_dir: str | os.PathLike | None = None) -> ViewerServer:
    """A ViewerServer for the 3D Tiles folder `tiles_dir` (not yet serving: call start() or
    serve_forever()). InputError: no tileset.json there, CesiumJS not found, the port taken."""
    tiles_dir = Path(tiles_dir)
    if not (tiles_dir / "tileset.json").is_file():
        raise InputError(f"{tiles_dir}: no tileset.json here (not a 3D Tiles export folder)")
    if not 0 <= port <= 65535:
        raise InputError(f"--port {port}: give 0 (a free port) or a port in 1..65535")
    return ViewerServer(tiles_dir, find_cesium(cesium_dir), port=port)


def serve_until_stopped(tiles_dir: str | os.PathLike, *, port: int = 0, cesium_dir: str | os.PathLike | None = None,
                        open_browser: bool = True, on_serving: Callable[[str], None] | None = None) -> str:
    """The `view` command of both front ends: serve `tiles_dir` (as `serve`) from this thread until
    Ctrl-C or a stop signal (core.signals.Terminated, under signals_as_exceptions), a normal end;
    returns the page's URL. `on_serving(url)` runs once the port is open (the commands print the
    URL there), then the page opens in the web browser unless `open_browser` is false. InputError
    as `serve`; the port is free again when this returns."""
    import webbrowser

    with serve(tiles_dir, port=port, cesium_dir=cesium_dir) as server:
        if on_serving is not None:
            on_serving(server.url)
        if open_browser and not webbrowser.open(server.url):
            log.info("no web browser found: open %s", server.url)
        try:
            server.serve_forever()
        except (KeyboardInterrupt, Terminated):
            pass
    return server.url
