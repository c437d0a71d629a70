"""Invariant checks of a baked HLOD, computed from its own arrays (the `info` command).

- leaf_tris_equal_input: the leaves hold exactly as many triangles as the input had;
- nested_bounds: every node's LOD geometry lies in its LOD box, every LOD box in the node's box,
  every child's box in its parent's, every LOD vertex and child sphere in the node's sphere;
- monotone_error: errors finite, >= 0, 0 at leaves, a parent's >= each child's;
- leaf_budget: every leaf holds <= target_tris triangles, unless it could not be split (at
  max_depth, or all its triangle centroids coincide); those leaves are counted. Collapsed
  triangles (two corners at one float32 position) do not count, as in the bake.

Tolerances live here: TOLERANCE_REL times the root box diagonal, for float64 bounds compared with
float32 geometry offset by a float64 origin.
"""
from __future__ import annotations

import numpy as np

from ..core.arrays import segment_ranges
from ..model.hierarchy import Hlod
from .decimate.simplify import collapsed

TOLERANCE_REL = 1e-9


def check(hlod: Hlod) -> dict:
    """Return {"checks": {name: bool}, "leaves_unsplittable": int, "leaves_over_budget": int}."""
    tol = TOLERANCE_REL * max(1.0, float(np.linalg.norm(hlod.box_max[0] - hlod.box_min[0])),
                              float(np.abs(hlod.origin).max()))
    budget_ok, unsplittable, over = _leaf_budget(hlod)
    return {
        "checks": {
            "leaf_tris_equal_input": int(hlod.tri_count[hlod.is_leaf].sum()) == int(hlod.meta.get("input_tris", -1)),
            "nested_bounds": _nested_bounds(hlod, tol),
            "monotone_error": _monotone_error(hlod),
            "leaf_budget": budget_ok,
        },
        "leaves_unsplittable": unsplittable,
        "leaves_over_budget": over,
    }


def _children(hlod: Hlod) -> tuple[np.ndarray, np.ndarray]:
    """(child ids, their parent ids) for every non-root node."""
    child = np.arange(1, hlod.node_count)
    return child, hlod.parent[child].astype(np.int64)


def _nested_bounds(hlod: Hlod, tol: float) -> bool:
    owner = np.repeat(np.arange(hlod.node_count), hlod.vertex_count)
    v_rows = segment_ranges(hlod.vertex_offset, hlod.vertex_count)
    world = np.asarray(hlod.positions[v_rows], np.float64) + hlod.origin
    ok = bool(np.all(world >= hlod.lod_box_min[owner] - tol) and np.all(world <= hlod.lod_box_max[owner] + tol))
    ok &= bool(np.all(hlod.lod_box_min >= hlod.box_min - tol) and np.all(hlod.lod_box_max <= hlod.box_max + tol))
    dist = np.linalg.norm(world - hlod.sphere_center[owner], axis=1)
    ok &= bool(np.all(dist <= hlod.sphere_radius[owner] + tol))
    child, parent = _children(hlod)
    ok &= bool(np.all(hlod.box_min[child] >= hlod.box_min[parent] - tol)
               and np.all(hlod.box_max[child] <= hlod.box_max[parent] + tol))
    gap = np.linalg.norm(hlod.sphere_center[child] - hlod.sphere_center[parent], axis=1) + hlod.sphere_radius[child]
    ok &= bool(np.all(gap <= hlod.sphere_radius[parent] + tol))
    return ok


def _monotone_error(hlod: Hlod) -> bool:
    e = hlod.error
    if not np.all(np.isfinite(e)) or np.any(e < 0) or np.any(e[hlod.is_leaf] != 0):
        return False
    child, parent = _children(hlod)
    return bool(np.all(e[parent] >= e[child]))


def _leaf_budget(hlod: Hlod) -> tuple[bool, int, int]:
    target = int(hlod.meta.get("target_tris", 0))
    max_depth = int(hlod.meta.get("max_depth", -1))
    leaves = np.flatnonzero(hlod.is_leaf)
    candidates = leaves[hlod.tri_count[leaves] > target]
    over, unsplittable = 0, 0
    for leaf in candidates:
        tris = np.asarray(hlod.indices[hlod.tri_offset[leaf]:hlod.tri_offset[leaf] + hlod.tri_count[leaf]])
        if int((~collapsed(hlod.positions, tris)).sum()) <= target:
            continue
        over += 1
        if hlod.depth[leaf] >= max_depth:
            unsplittable += 1
            continue
        centroids = np.asarray(hlod.positions[tris.ravel()], np.float64).reshape(-1, 3, 3).mean(axis=1)
        if np.all(centroids.min(axis=0) == centroids.max(axis=0)):
            unsplittable += 1
    return unsplittable == over, unsplittable, over
