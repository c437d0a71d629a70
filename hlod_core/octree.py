"""Top-down octree partition of triangles (DESIGN §4.2).

Data form in: triangle centroids (f,3) float64. Data form out: `OctreeLayout`, a node table in
breadth-first order (children contiguous) plus a permutation of the triangles in which every
subtree's triangles form one contiguous range (leaves in depth-first order).

Rules: a cell splits into its 8 octants while it holds more than `target_tris` (counted) triangles and its
depth is below `max_depth`; each triangle goes to the octant containing its centroid; empty octants
are dropped. When every centroid falls in one octant, the cell shrinks to that octant without
creating a node (a node with one child would only repeat its child's LOD). A cell whose centroids
all coincide cannot be split and becomes a leaf over the budget.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

# A cell may shrink this many times in a row while all centroids stay in one octant; float64 has a
# 52-bit mantissa, so distinct centroids always separate well before this.
_MAX_SHRINKS = 128
# Octant o has bit a set when it lies on the + side of axis a: its centre moves by sign * half / 2.
_OCTANT_SIGNS = np.array([[(o >> a) & 1 for a in range(3)] for o in range(8)], np.float64) * 2.0 - 1.0


@dataclass(frozen=True, eq=False)
class OctreeLayout:
    """parent/child_offset/child_count/depth (n,) int32 as in hierarchy.Hlod;
    tri_order (f,) int64: input triangle ids, subtree-contiguous;
    tri_begin/tri_end (n,) int64: each node's range in tri_order (its original triangles)."""

    parent: np.ndarray
    child_offset: np.ndarray
    child_count: np.ndarray
    depth: np.ndarray
    tri_order: np.ndarray
    tri_begin: np.ndarray
    tri_end: np.ndarray

    @property
    def node_count(self) -> int:
        return int(self.parent.shape[0])

    @property
    def is_leaf(self) -> np.ndarray:
        """(n,) bool."""
        return self.child_count == 0


def build_octree(centroids: np.ndarray, *, target_tris: int, max_depth: int,
                 counted: np.ndarray | None = None) -> OctreeLayout:
    """Partition triangles by centroid. centroids: (f,3) float64, finite, f >= 1.
    counted: (f,) bool, the triangles that count toward `target_tris` (default all); the bake
    leaves out collapsed triangles, which welding drops and no LOD could ever reduce."""
    if target_tris < 1 or max_depth < 0:
        raise ValueError("target_tris must be >= 1 and max_depth >= 0")
    lo, hi = centroids.min(axis=0), centroids.max(axis=0)
    root_center = 0.5 * (lo + hi)
    root_half = 0.5 * float(np.max(hi - lo))

    parent, child_offset, child_count, depth = [-1], [-1], [0], [0]
    leaf_tris: dict[int, np.ndarray] = {}
    counted_ids = np.ones(centroids.shape[0], bool) if counted is None else np.asarray(counted, bool)
    queue = deque([(0, np.arange(centroids.shape[0], dtype=np.int64), root_center, root_half)])
    while queue:  # FIFO: nodes are expanded in id order, so children ids come out contiguous
        node, tris, center, half = queue.popleft()
        split = _split_cell(centroids, tris, center, half) \
            if int(counted_ids[tris].sum()) > target_tris and depth[node] < max_depth else None
        if split is None:
            leaf_tris[node] = tris
            continue
        child_offset[node], child_count[node] = len(parent), len(split)
        for child_tris, child_center, child_half in split:
            queue.append((len(parent), child_tris, child_center, child_half))
            parent.append(node)
            child_offset.append(-1)
            child_count.append(0)
            depth.append(depth[node] + 1)

    parent_a = np.asarray(parent, np.int32)
    child_offset_a = np.asarray(child_offset, np.int32)
    child_count_a = np.asarray(child_count, np.int32)
    tri_order, tri_begin, tri_end = _depth_first_ranges(child_offset_a, child_count_a, leaf_tris)
    return OctreeLayout(parent=parent_a, child_offset=child_offset_a, child_count=child_count_a,
                        depth=np.asarray(depth, np.int32), tri_order=tri_order,
                        tri_begin=tri_begin, tri_end=tri_end)


def _split_cell(centroids, tris, center, half):
    """Octants of a cell as [(tris, center, half)], or None if it cannot be split."""
    c = centroids[tris]
    if np.all(c.min(axis=0) == c.max(axis=0)):
        return None  # all centroids coincide
    center = center.copy()
    for _ in range(_MAX_SHRINKS):
        code = ((c[:, 0] >= center[0]).astype(np.int8)
                | ((c[:, 1] >= center[1]).astype(np.int8) << 1)
                | ((c[:, 2] >= center[2]).astype(np.int8) << 2))
        counts = np.bincount(code, minlength=8)
        occupied = np.flatnonzero(counts)
        half = 0.5 * half
        if occupied.shape[0] > 1:
            order = np.argsort(code, kind="stable")
            ends = np.cumsum(counts)
            return [(tris[order[ends[o] - counts[o]:ends[o]]], center + _OCTANT_SIGNS[o] * half, half) for o in occupied]
        center = center + _OCTANT_SIGNS[occupied[0]] * half  # shrink into the one occupied octant
    return None


def _depth_first_ranges(child_offset, child_count, leaf_tris):
    n = child_offset.shape[0]
    begin = np.zeros(n, np.int64)
    end = np.zeros(n, np.int64)
    parts = []
    cursor = 0
    stack = [0]
    while stack:
        node = stack.pop()
        if child_count[node] == 0:
            tris = leaf_tris[node]
            begin[node], end[node] = cursor, cursor + tris.shape[0]
            cursor += tris.shape[0]
            parts.append(tris)
        else:  # push children in reverse so they are visited in id order
            stack.extend(range(child_offset[node] + child_count[node] - 1, child_offset[node] - 1, -1))
    for node in range(n - 1, -1, -1):  # children have larger ids than their parent
        if child_count[node]:
            first, last = child_offset[node], child_offset[node] + child_count[node] - 1
            begin[node], end[node] = begin[first], end[last]
    return np.concatenate(parts), begin, end
