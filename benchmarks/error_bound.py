"""The error bound against the exact error (`--error bound` beside `--error exact`).

    PYTHONPATH=. .venv/bin/python -m benchmarks.error_bound [--models cow ...] [--scenes gallery_1m]
        [--jobs 1] [--scene-jobs 2] [--target-tris 2000] [--out DIR]

For each input (the test models of tests/models.py, then the scenes named), one run bakes it
with the exact error and with the bound, interleaved (exact then bound, the same process, the same
load), and reports:
    seconds, triangles/s   bake() alone (reading the input excluded), each measure;
    ratio per depth        bound / exact of the nodes' errors (Hlod.error: what the SSE reads),
                           median and max over the inner nodes of each depth, and the smallest ratio
                           over all nodes (below 1: the sampled bound fell under the sampled exact,
                           tests/test_error_bound.py);
    drawn                  for scenes with a camera path: the nodes and triangles a view-frustum
                           SSE cut draws per frame (tau = 1 px, 640x480, the evaluation's VFC
                           selection computed in numpy, no GL), mean over the path, each measure.
The LODs are the same in both bakes (checked): only the errors differ.
The load average is recorded before and after (a 2-core VM shared with other work skews times).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import meshes
from hlod_core.model import camera_path
from hlod_core.traversal import boxes, metrics

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import models  # tests/models.py: the test models by role

ROOT = Path(__file__).resolve().parents[1]

#: The scenes and their camera paths.
SCENES = {"gallery_1m": ROOT / "tests" / "scenes" / "gallery_row_path.json",
          "crowd_1m": ROOT / "tests" / "scenes" / "crowd_inspection_path.json"}
#: The evaluation's viewport (cli.py --size default) and SSE threshold (RuntimeSettings.tau default), pixels.
VIEWPORT_PX = (640, 480)
TAU_PX = 1.0


def depth_ratios(exact, bound) -> dict:
    """{depth: {"nodes", "median", "max"}} of bound.error / exact.error over inner nodes, and "min" overall."""
    inner = ~exact.is_leaf
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(exact.error > 0, bound.error / exact.error, np.where(bound.error > 0, np.inf, 1.0))
    out = {}
    for d in np.unique(exact.depth[inner]).tolist():
        r = ratio[inner & (exact.depth == d)]
        out[str(d)] = {"nodes": int(r.size), "median": float(np.median(r)), "max": float(r.max())}
    return {"per_depth": out, "min": float(ratio[inner].min()), "below_exact": int((bound.error < exact.error).sum())}


def drawn_per_frame(hlod, path) -> dict:
    """Mean nodes and triangles of the VFC cut (traversal.VFC's selection) over the path's frames."""
    nodes, tris = [], []
    levels = [np.flatnonzero(hlod.depth == d) for d in range(1, int(hlod.depth.max()) + 1)]
    for i in range(len(path)):
        view = path.view(i, VIEWPORT_PX)
        inside = boxes.boxes_in_frustum(view, hlod.box_min, hlod.box_max)
        refine = ~hlod.is_leaf & ~(metrics.sse(view, hlod.error, center=hlod.sphere_center, radius=hlod.sphere_radius,
                                               is_leaf=hlod.is_leaf) <= TAU_PX)
        reached = np.zeros(hlod.node_count, bool)
        reached[0] = inside[0]
        for level in levels:
            reached[level] = reached[hlod.parent[level]] & refine[hlod.parent[level]] & inside[level]
        drawn = reached & ~refine
        nodes.append(int(drawn.sum()))
        tris.append(int(hlod.tri_count[drawn].sum()))
    return {"frames": len(path), "mean_nodes": float(np.mean(nodes)), "mean_tris": float(np.mean(tris))}


def compare(name: str, mesh, *, jobs: int, target_tris: int, path=None) -> dict:
    runs = {}
    for mode in ("exact", "bound"):
        started = time.perf_counter()
        hlod = bake(mesh, BakeSettings(jobs=jobs, target_tris=target_tris, error=mode))
        seconds = time.perf_counter() - started
        runs[mode] = {"hlod": hlod, "seconds": seconds, "tris_per_s": mesh.tri_count / seconds,
                      "phase_seconds": hlod.meta["phase_seconds"]}
    exact, bound = runs["exact"].pop("hlod"), runs["bound"].pop("hlod")
    if not (np.array_equal(exact.positions, bound.positions) and np.array_equal(exact.indices, bound.indices)):
        raise SystemExit(f"{name}: the two measures gave different LODs")
    result = {"input": name, "input_tris": mesh.tri_count, "nodes": exact.node_count, "jobs": jobs, **runs,
              "bound_time_ratio": runs["bound"]["seconds"] / runs["exact"]["seconds"], **depth_ratios(exact, bound)}
    if path is not None:
        result["drawn"] = {"exact": drawn_per_frame(exact, path), "bound": drawn_per_frame(bound, path)}
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="*", default=list(models.ROLES), choices=list(models.ROLES))
    parser.add_argument("--scenes", nargs="*", default=[], choices=sorted(SCENES))
    parser.add_argument("--jobs", type=int, default=1, help="worker processes for the models")
    parser.add_argument("--scene-jobs", type=int, default=2, help="worker processes for the scenes")
    parser.add_argument("--target-tris", type=int, default=2000)
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    report = {"load_before": os.getloadavg(), "inputs": []}
    inputs = [(m, models.path(m), args.jobs, None) for m in args.models]
    inputs += [(s, models.scene(s), args.scene_jobs, camera_path.load_path(SCENES[s])) for s in args.scenes]
    for name, source, jobs, path in inputs:
        mesh = meshes.load_inputs([source])
        row = compare(name, mesh, jobs=jobs, target_tris=args.target_tris, path=path)
        report["inputs"].append(row)
        print(json.dumps(row), flush=True)
    report["load_after"] = os.getloadavg()
    (args.out / "error_bound.json").write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
