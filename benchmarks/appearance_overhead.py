"""What carrying appearance (materials, UVs, colours) costs the bake, in time and in geometric error.

    .venv/bin/python -m benchmarks.appearance_overhead [--repeat R] [--input SCENE] [--out DIR]
    .venv/bin/python -m benchmarks.appearance_overhead --errors [--models NAME ...]

Time (default): an untextured bake of tests/scenes/gallery_1m.json with today's code against the
code of the commit before the appearance work (BEFORE: the commit before the contract, taken with
`git archive` into a temporary folder), each run as `python -m hlod_core -q bake INPUT -o OUT --jobs 1`
in its own process, interleaved (old, new, new, old, ...) so drifts in machine load fall on both.
Prints JSON: the median wall seconds of each, their ratio (new / old; the target is <= 1.05), the
bake's own seconds from each file's meta, and every run.

Errors (--errors): the node errors (Hausdorff MSE) of one geometry baked without attributes and
with them, node by node (the octree depends on the geometry only, so the nodes correspond).
"colours": smooth per-vertex colours, no seams, so what it costs is the decimation keeping
vertices in place; "textured": planar UVs, colours and two materials alternating across the
planes x = c and z = c through the model's centre, which adds material borders that stay put.
Prints the root's ratio and the median of the inner nodes' ratios (with / without).
"""
from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np

from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import hlod_file, meshes
from hlod_core.model.appearance import Material

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import models  # tests/models.py: the test models by role

ROOT = Path(__file__).resolve().parents[1]

#: The commit before the appearance contract (b4edc98^): the bake as it was without appearance.
BEFORE = "fed64e9de7e20efcd316ea19c5ab79df4e2bd22a"


def old_code(folder: Path) -> Path:
    """Extract BEFORE's hlod_core into `folder`; returns the folder to run it from."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", BEFORE, "hlod_core"],
                             capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    return folder


def timed_bake(code: Path, scene: Path, out: Path) -> float:
    """Wall seconds of one command-line bake with the hlod_core found in `code`."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "hlod_core", "-q", "bake", str(scene), "-o", str(out), "--jobs", "1"],
                   cwd=code, env=env, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started


def time_overhead(scene: Path, repeat: int) -> dict:
    with tempfile.TemporaryDirectory(prefix="hlod-appearance-") as scratch:
        scratch = Path(scratch)
        codes = {"old": old_code(scratch / "before"), "new": ROOT}
        runs: dict[str, list[float]] = {"old": [], "new": []}
        bake_seconds: dict[str, list[float]] = {"old": [], "new": []}
        for rep in range(repeat):
            for which in (("old", "new") if rep % 2 == 0 else ("new", "old")):
                out = scratch / f"{which}.hlod"
                runs[which].append(timed_bake(codes[which], scene, out))
                hlod = hlod_file.load(out)
                bake_seconds[which].append(float(hlod.meta["bake_seconds"]))
                if which == "new":
                    assert not hlod.has_appearance, "an untextured bake stored appearance arrays"
                print(json.dumps({"run": rep, "code": which, "seconds": runs[which][-1]}), file=sys.stderr, flush=True)
    old, new = statistics.median(runs["old"]), statistics.median(runs["new"])
    return {"input": str(scene), "before_commit": BEFORE, "repeat": repeat,
            "median_seconds_old": old, "median_seconds_new": new, "ratio_new_over_old": new / old,
            "median_bake_seconds_old": statistics.median(bake_seconds["old"]),
            "median_bake_seconds_new": statistics.median(bake_seconds["new"]),
            "bake_ratio_new_over_old": statistics.median(bake_seconds["new"]) / statistics.median(bake_seconds["old"]),
            "runs": runs, "bake_seconds": bake_seconds}


def with_appearance(mesh: meshes.TriangleMesh, kind: str) -> meshes.TriangleMesh:
    """`mesh` with colours (and, for "textured", planar UVs and two materials) as described above."""
    lo, hi = mesh.positions.min(axis=0), mesh.positions.max(axis=0)
    unit = (mesh.positions - lo) / np.where(hi > lo, hi - lo, 1.0)
    colors = np.concatenate([unit, np.ones((unit.shape[0], 1))], axis=1)
    if kind == "colours":
        return meshes.from_arrays(mesh.positions, mesh.faces, mesh.normals, name=mesh.name, colors=colors)
    centroid = unit[mesh.faces].mean(axis=1)
    material = ((centroid[:, 0] > 0.5) ^ (centroid[:, 2] > 0.5)).astype(np.int32)
    return meshes.from_arrays(mesh.positions, mesh.faces, mesh.normals, name=mesh.name, colors=colors,
                              uvs=unit[:, :2], material_ids=material, materials=(Material("a"), Material("b")))


def error_ratios(names: list[str], target_tris: int) -> dict:
    out = {}
    for name in names:
        mesh = models.load(name)
        plain = bake(mesh, BakeSettings(target_tris=target_tris))
        inner = np.flatnonzero(~plain.is_leaf)
        out[name] = {"input_tris": mesh.tri_count, "inner_nodes": int(inner.size), "root_error": float(plain.error[0])}
        for kind in ("colours", "textured"):
            dressed = bake(with_appearance(mesh, kind), BakeSettings(target_tris=target_tris))
            assert np.array_equal(dressed.parent, plain.parent), "the octree should not depend on attributes"
            ratio = dressed.error[inner] / plain.error[inner]
            out[name][kind] = {"root_ratio": float(ratio[0]), "median_inner_ratio": float(np.median(ratio)),
                               "root_error": float(dressed.error[0]),
                               "root_tris": int(dressed.tri_count[0]), "root_tris_without": int(plain.tri_count[0])}
        print(json.dumps({name: out[name]}), file=sys.stderr, flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed bakes of each code (time mode)")
    parser.add_argument("--input", type=Path, help="scene to bake (time mode; default tests/scenes/gallery_1m.json)")
    parser.add_argument("--errors", action="store_true", help="measure node errors instead of time")
    parser.add_argument("--models", nargs="+", default=["bunny", "statue"], choices=list(models.ROLES),
                        help="test models (tests/models.py) for --errors")
    parser.add_argument("--target-tris", type=int, default=BakeSettings.target_tris, help="for --errors")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = parser.parse_args()
    if args.errors:
        results = {"errors": error_ratios(args.models, args.target_tris), "target_tris": args.target_tris}
        name = "appearance_errors.json"
    else:
        results = time_overhead((args.input or models.scene("gallery_1m")).resolve(), args.repeat)
        name = "appearance_overhead.json"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / name).write_text(json.dumps(results, indent=2))
    print(json.dumps(results))


if __name__ == "__main__":
    main()
