"""The tiles CesiumJS chooses for a view against the nodes our VFC traversal draws for the same
camera and the same screen-space-error threshold.

    PYTHONPATH=. .venv/bin/python -m benchmarks.cesium_compare [--scene terrain city] [--tau 16 2]
        [--size 800x600] [--json OUT.json]

bakes a scene of `scene_setups` (tests/cesium_selection.py, which holds the comparison), exports
it as 3D Tiles, serves it with hlod_core.export.viewer, opens the viewer page in Chromium
(Playwright, /usr/bin/chromium, WebGL through SwiftShader), and
for each camera and each threshold prints |ours|, |Cesium's|, the intersection, the Jaccard index,
Cesium's choice as predicted by `cesium_rule.cesium_select` (a re-implementation of Cesium's rule,
must equal what Cesium chose) and, for every tile in one set only, the term of TERMS that decides it.

Both rules compute `SSE = geometricError * H / (d * 2 tan(fovy / 2))` and refine while SSE > tau;
they differ in the distance (our node's sphere, Cesium's box), Cesium's culling with children
bounds, Cesium keeping a tile with no visible child, the root's tileset error, and boxes touching a
frustum plane. Why: docs/how-it-works.md#vfcs-tile-choice-against-cesiumjss

Data form: a baked `Hlod` and its export's tileset.json (one tile per node with triangles, content
uri "tiles/<node>.glb", box = the node's subtree box, geometricError = the node's error), read as a
`cesium_rule.Tileset`; a `cesium_rule.Camera` in the tileset's frame.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from cesium_selection import Browser, bake_and_export, cesium_choose, compare, scene_setups

ROOT = Path(__file__).resolve().parents[1]


def run(scene: str, taus: list[float], *, size: tuple[int, int] = (800, 600), folder: Path) -> list[dict]:
    """Bake and export `scene`, serve it, and compare every camera at every threshold."""
    from hlod_core.export.viewer import serve

    hlod, ts = bake_and_export(scene, folder / "tiles")
    rows = []
    with serve(folder / "tiles") as server:
        server.start()
        with Browser(server.url, size=size) as browser:
            for name, make_camera in scene_setups()[scene][2].items():
                for tau in taus:
                    uris, seen = cesium_choose(browser.page, make_camera(size), tau)
                    row = compare(ts, hlod, seen, tau_px=tau, cesium_uris=uris)
                    row.update(scene=scene, camera=name)
                    rows.append(row)
    return rows


def summary_lines(row: dict) -> list[str]:
    """The terms of a row's differences, grouped by the tile where the rules part, one example each."""
    groups: dict = {}
    for d in row["differences"]:
        groups.setdefault((d.term, d.at), []).append(d)
    out = []
    for (term, at), ds in groups.items():
        ours = sum(d.side == "ours" for d in ds)
        tie = " (tie)" if any(d.tie for d in ds) else ""
        out.append(f"    {term} at {at}: {ours} ours only, {len(ds) - ours} Cesium only{tie}; {ds[0].detail}")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", nargs="+", default=["terrain", "city"], choices=sorted(scene_setups()))
    parser.add_argument("--tau", nargs="+", type=float, default=[16.0, 2.0], help="maximum SSE, pixels")
    parser.add_argument("--size", default="800x600")
    parser.add_argument("--json", help="write the rows here")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in args.scene:
            rows += run(scene, args.tau, size=size, folder=Path(tmp) / scene)
    print("| scene | camera | tau px | ours | Cesium | both | Jaccard | predicted = Cesium | ours by depth "
          "| Cesium by depth |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['camera']} | {r['tau_px']:g} | {r['ours']} | {r['cesium']} | {r['both']} | "
              f"{r['jaccard']:.2f} | {'yes' if r['prediction_exact'] else 'NO ' + str(r['prediction_misses'])} | "
              f"{r['ours_depth']} | {r['cesium_depth']} |")
    for r in rows:
        if r["differences"]:
            print(f"{r['scene']} {r['camera']} tau {r['tau_px']:g}:")
            print("\n".join(summary_lines(r)))
    if args.json:
        Path(args.json).write_text(json.dumps([{k: v for k, v in r.items() if k != "differences"} | {
            "differences": [d.__dict__ for d in r["differences"]]} for r in rows], indent=1))


if __name__ == "__main__":
    main()
