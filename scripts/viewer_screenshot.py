"""The user guide's pictures of the 3D Tiles viewer: the default scene baked, exported as 3D Tiles, served
with hlod_core.export.viewer and shot in Chromium (Playwright, /usr/bin/chromium, WebGL through SwiftShader)
once all tiles are loaded, at the page's own first view, plain and coloured by depth.

    PYTHONPATH=. .venv/bin/python scripts/viewer_screenshot.py [--out docs] [--size 960x600] [--sse 1]

Writes OUT/viewer.png and OUT/viewer_depth.png; prints the page's counters as one JSON line.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.export import tiles3d, viewer
from hlod_core.io import procedural

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
LOAD_TIMEOUT_MS = 300_000


def main() -> None:
    from playwright.sync_api import sync_playwright

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs")
    parser.add_argument("--size", default="960x600")
    parser.add_argument("--sse", type=float, default=1.0,
                        help="maximum screen-space error, pixels (1: the preview's tau)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tiles = Path(tmp) / "tiles"
        tiles3d.export(bake(procedural.default_scene(seed=1), BakeSettings(jobs=2)), tiles)
        with viewer.serve(tiles) as server, sync_playwright() as pw:
            server.start()
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": width, "height": height})
                page.goto(server.url)
                page.wait_for_function("window.hlodViewer && hlodViewer.ready", timeout=LOAD_TIMEOUT_MS)
                page.evaluate(f"hlodViewer.setMaximumScreenSpaceError({args.sse:g})")
                shots = {}
                for name, depth in (("viewer.png", False), ("viewer_depth.png", True)):
                    page.evaluate(f"hlodViewer.setColorByDepth({str(depth).lower()})")
                    page.wait_for_timeout(300)
                    page.wait_for_function("hlodViewer.allTilesLoaded", timeout=LOAD_TIMEOUT_MS)
                    page.evaluate("hlodViewer.redraw().then(() => hlodViewer.redraw())")
                    page.screenshot(path=str(out / name))
                    shots[name] = page.evaluate("hlodViewer.stats()")
                errors = page.evaluate("hlodViewer.errors")
            finally:
                browser.close()
    print(json.dumps({"shots": shots, "errors": errors, "sse_px": args.sse, "size": [width, height]}))


if __name__ == "__main__":
    main()
