"""Seconds from opening the viewer page to CesiumJS's first tile on screen, for this version's
export and page against another version's (the tileset.json a viewer reads first is what changed).

    PYTHONPATH=. .venv/bin/python -m benchmarks.viewer_first_tile NEW_TILES --baseline OLD_CODE OLD_TILES
        [--repeat R]

NEW_TILES is an export of this version; OLD_CODE a folder holding another version's hlod_core (e.g.
`git archive COMMIT hlod_core | tar -x -C OLD_CODE`) and OLD_TILES that version's export of the same
bake. Each is served by its own version's `python -m hlod_core view --no-browser` (its own page),
CesiumJS from tools/viewer's install for both, and opened in Debian's Chromium (Playwright,
SwiftShader WebGL, 640x480) R times, interleaved (new, old, old, new, ...); a run ends when
`hlodViewer.stats().tilesDrawn` is first above 0 after the page starts loading (polled every 10 ms).
Prints each run's seconds on stderr as it ends, then JSON: each side's seconds, their medians and
the ratio new / old.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CESIUM = ROOT / "tools/viewer/node_modules/cesium/Build/Cesium"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
TIMEOUT_S = 300.0


def _serve(code: Path, tiles: Path) -> tuple[subprocess.Popen, str]:
    """`python -m hlod_core view TILES` of the hlod_core in `code`; (process, page URL)."""
    proc = subprocess.Popen([sys.executable, "-m", "hlod_core", "view", str(tiles), "--no-browser", "--cesium",
                             str(CESIUM)], cwd=code, env={**os.environ, "PYTHONPATH": str(code)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return proc, proc.stdout.readline().strip()


def first_tile_seconds(browser, url: str) -> float:
    """Seconds from navigation to the first frame with a tile drawn, in a fresh page."""
    page = browser.new_page(viewport={"width": 640, "height": 480})
    try:
        started = time.perf_counter()
        page.goto(url, wait_until="commit")
        while time.perf_counter() - started < TIMEOUT_S:
            if page.evaluate("window.hlodViewer && hlodViewer.ready ? hlodViewer.stats().tilesDrawn : 0") > 0:
                return time.perf_counter() - started
            time.sleep(0.01)
        raise TimeoutError(f"{url}: no tile drawn in {TIMEOUT_S} s")
    finally:
        page.close()


def main(argv: list[str] | None = None) -> None:
    from playwright.sync_api import sync_playwright

    parser = argparse.ArgumentParser(prog="python -m benchmarks.viewer_first_tile",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("tiles", type=Path, metavar="NEW_TILES")
    parser.add_argument("--baseline", nargs=2, type=Path, required=True, metavar=("OLD_CODE", "OLD_TILES"))
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    sides = {"new": _serve(ROOT, args.tiles), "old": _serve(args.baseline[0], args.baseline[1])}
    seconds: dict[str, list[float]] = {"new": [], "old": []}
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
            try:
                for run in range(args.repeat):
                    for side in (("new", "old") if run % 2 == 0 else ("old", "new")):
                        seconds[side].append(first_tile_seconds(browser, sides[side][1]))
                        print(side, round(seconds[side][-1], 2), file=sys.stderr, flush=True)
            finally:
                browser.close()
    finally:
        for proc, _ in sides.values():
            proc.terminate()
            proc.communicate(timeout=30)
    medians = {side: statistics.median(values) for side, values in seconds.items()}
    print(json.dumps({"seconds": seconds, "median_s": medians, "ratio_new_over_old": medians["new"] / medians["old"],
                      "tileset_json_bytes": {"new": (args.tiles / "tileset.json").stat().st_size,
                                             "old": (args.baseline[1] / "tileset.json").stat().st_size}}))


if __name__ == "__main__":
    main()
