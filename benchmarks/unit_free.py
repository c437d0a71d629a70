"""Is the bake unit-free? Root error / scale and node count of the test models baked at x1e-3, x1 and
x1e3, and, for comparison, the spread of the root error at one scale when every float32 coordinate
moves by at most one step (seeded): what rounding alone does to greedy decimation.

    python -m benchmarks.unit_free [--jitter-seeds 6]

Prints one JSON line per model, then the jitter lines (docs/performance.md#unit-free-bakes).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import meshes

from .bake_throughput import ROOT

sys.path.insert(0, str(ROOT / "tests"))
import models  # tests/models.py: the test models by role

#: (role, target triangles) of the test models (tests/models.py).
MODELS = (("spot", 200), ("cow", 200), ("creased", 500), ("ring", 500), ("teapot", 200), ("airplane", 500),
          ("bunny", 2000), ("bust", 200), ("statue", 200))
SCALES = (1e-3, 1.0, 1e3)
JITTERED = ("spot", "creased")


def _scaled(mesh: meshes.TriangleMesh, scale: float) -> meshes.TriangleMesh:
    m = np.eye(4) * scale
    m[3, 3] = 1.0
    return meshes.transform_mesh(mesh, m, name=f"{mesh.name} x{scale:g}")


def _jittered(mesh: meshes.TriangleMesh, seed: int) -> meshes.TriangleMesh:
    """Each float32 coordinate moved one step down, kept, or moved one step up, at random."""
    rng = np.random.default_rng(seed)
    p32 = mesh.positions.astype(np.float32)
    step = rng.integers(-1, 2, size=p32.shape)
    moved = np.nextafter(p32, np.where(step > 0, np.float32(np.inf), np.float32(-np.inf)))
    return meshes.from_arrays(np.where(step == 0, p32, moved).astype(np.float64), mesh.faces, name=mesh.name)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.unit_free", description=__doc__.splitlines()[0])
    parser.add_argument("--jitter-seeds", type=int, default=6)
    args = parser.parse_args(argv)
    targets = dict(MODELS)
    for name, target in MODELS:
        mesh = models.load(name)
        row = {"model": name, "target_tris": target}
        for scale in SCALES:
            hlod = bake(_scaled(mesh, scale), BakeSettings(target_tris=target))
            row[f"x{scale:g}"] = {"root_error_over_scale": float(hlod.error[0] / scale), "nodes": hlod.node_count}
        errors = [row[f"x{scale:g}"]["root_error_over_scale"] for scale in SCALES]
        row["spread"] = max(errors) / min(errors) - 1.0
        print(json.dumps(row), flush=True)
    for name in JITTERED:
        mesh = models.load(name)
        errors = [float(bake(_jittered(mesh, seed), BakeSettings(target_tris=targets[name])).error[0])
                  for seed in range(args.jitter_seeds)]
        print(json.dumps({"model": name, "jitter_one_step_root_errors": errors}), flush=True)


if __name__ == "__main__":
    main()
