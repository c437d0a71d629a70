"""Top-down octree partition of triangles (DESIGN §4.2).

Data form in: triangle centroids (f,3) float64 (in the bake: relative to its origin). Data form
out: `OctreeLayout`, a node table in breadth-first order (children contiguous) with each node's
cell, plus a permutation of the triangles in which every subtree's triangles form one contiguous
range (leaves in depth-first order; input order within a leaf).

Cells: the root cell (`tight_cube`) is the cube around the centroids' box (centred on it, side its
longest extent); a cell splits at its centre into octants, so every cell is fixed by the root cell
and its path. A node's cell (`cell_center`, `cell_half`, `cell_level`) is the octant it was made as
(the root: the root cube). An edit that keeps the centroids' box (a statue moved inside a crowd)
leaves every cell it does not overlap where it was, which is what the bake cache (bake_cache.py)
reuses; an edit that changes the box moves every cell. (A root cube snapped to a power-of-two grid
would keep cells through such edits too, but not through a change of units by a non-power of two,
which README "Unit-free bakes" promises; issue 14's note says what was measured.)

Rules: a cell splits into its 8 octants while it holds more than `target_tris` (counted) triangles
and its depth is below `max_depth`; each triangle goes to the octant containing its centroid (a
centroid on a splitting plane goes to the + side); empty octants are dropped. When every centroid
falls in one octant, the cell shrinks to that octant without creating a node (a node with one
child would only repeat its child's LOD). A cell whose centroids all coincide (or still share one
octant after _MAX_SHRINKS shrinks) cannot be split and becomes a leaf over the budget.

Vectorised by depth: each depth costs a few passes over the triangles still in splitting nodes
(their octant codes, counts per (node, octant)), and one stable sort by leaf at the end.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# A cell may shrink this many times in a row while all centroids stay in one octant; float64 has a
# 52-bit mantissa, so distinct centroids always separate well before this.
_MAX_SHRINKS = 128
# Octant o has bit a set when it lies on the + side of axis a: its centre moves by sign * half / 2.
_OCTANT_SIGNS = np.array([[(o >> a) & 1 for a in range(3)] for o in range(8)], np.float64) * 2.0 - 1.0
# A stable sort of keys of at most 16 bits is numpy's radix sort (linear); wider keys sort by timsort.
_RADIX_KEYS = 2**16


@dataclass(frozen=True)
class RootCube:
    """corner (3,) float64 and side, model units, in the frame of the centroids."""

    corner: np.ndarray
    side: float

    @property
    def center(self) -> np.ndarray:
        """(3,) float64."""
        return self.corner + 0.5 * self.side


def tight_cube(lo: np.ndarray, hi: np.ndarray) -> RootCube:
    """The cube centred on the box [lo, hi] ((3,) float64, finite) with its longest extent as side
    (0 for a box of one point)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    side = float(np.max(hi - lo))
    return RootCube(corner=0.5 * (lo + hi) - 0.5 * side, side=side)


@dataclass(frozen=True, eq=False)
class OctreeLayout:
    """parent/child_offset/child_count/depth (n,) int32 as in hierarchy.Hlod;
    tri_order (f,) int64: input triangle ids, subtree-contiguous;
    tri_begin/tri_end (n,) int64: each node's range in tri_order (its original triangles);
    cell_center (n,3) float64 and cell_half (n,) float64: each node's cell (in the centroids'
    frame), cell_level (n,) int32: its grid level (root 0; one more per
    split or shrink, so level >= depth)."""

    parent: np.ndarray
    child_offset: np.ndarray
    child_count: np.ndarray
    depth: np.ndarray
    tri_order: np.ndarray
    tri_begin: np.ndarray
    tri_end: np.ndarray
    cell_center: np.ndarray
    cell_half: np.ndarray
    cell_level: np.ndarray

    @property
    def node_count(self) -> int:
        return int(self.parent.shape[0])

    @property
    def is_leaf(self) -> np.ndarray:
        """(n,) bool."""
        return self.child_count == 0


def build_octree(centroids: np.ndarray, *, target_tris: int, max_depth: int,
                 counted: np.ndarray | None = None, root: RootCube | None = None) -> OctreeLayout:
    """Partition triangles by centroid. centroids: (f,3) float64, finite, f >= 1.
    counted: (f,) bool, the triangles that count toward `target_tris` (default all); the bake
    leaves out collapsed triangles, which welding drops and no LOD could ever reduce.
    root: the root cell, in the centroids' frame (default: `tight_cube` of the centroids' box)."""
    if target_tris < 1 or max_depth < 0:
        raise ValueError("target_tris must be >= 1 and max_depth >= 0")
    centroids = np.asarray(centroids, np.float64)
    f = centroids.shape[0]
    if root is None:
        root = tight_cube(centroids.min(axis=0), centroids.max(axis=0))
    counted_ids = np.ones(f, bool) if counted is None else np.asarray(counted, bool)

    parent = [np.array([-1], np.int32)]
    depth = [np.array([0], np.int32)]
    center = [root.center[None, :].astype(np.float64)]
    half = [np.array([0.5 * root.side])]
    level = [np.array([0], np.int32)]
    child_offset = [np.array([-1], np.int32)]
    child_count = [np.array([0], np.int32)]
    node_of = np.zeros(f, np.int64)  # each triangle's node; its leaf at the end
    # the triangles in splitting nodes of the current depth, ascending, with their centroids by axis
    tris = np.arange(f, dtype=np.int64)
    axes = [np.ascontiguousarray(centroids[:, a]) for a in range(3)]
    where = np.zeros(f, np.int64)  # their node, as an index into the current depth
    first, n = 0, 1  # id of the first node of the current depth, nodes so far
    n_counted = np.array([int(counted_ids.sum())])
    d = 0
    while d < max_depth:
        splitting = np.flatnonzero(n_counted > target_tris)  # among the current depth's nodes
        if splitting.size == 0:
            break
        w_of = np.full(n - first, -1, np.int64)
        w_of[splitting] = np.arange(splitting.size)
        w = w_of[where]
        if splitting.size < n - first:
            keep = w >= 0
            tris, w, axes = tris[keep], w[keep], [a[keep] for a in axes]
        counts, split_center, split_half, shrinks, code = _split_cells(axes, w, center[-1][splitting],
                                                                        half[-1][splitting])
        split = np.flatnonzero(counts.any(axis=1))  # (k,) split nodes; the others stay leaves
        occupied = counts[split] > 0
        kids = occupied.sum(axis=1)
        offsets = n + np.concatenate([[0], np.cumsum(kids)[:-1]]).astype(np.int64)
        ids = first + splitting[split]
        child_offset[-1][ids - first] = offsets
        child_count[-1][ids - first] = kids
        child_local = np.full((splitting.size, 8), -1, np.int64)  # child id - n
        child_local[split] = np.where(occupied, offsets[:, None] - n + np.cumsum(occupied, axis=1) - 1, -1)
        where = child_local[w, code]
        if not np.all(where >= 0):  # triangles of unsplittable cells stay in their leaf
            keep = where >= 0
            tris, where, axes = tris[keep], where[keep], [a[keep] for a in axes]
        node_of[tris] = where + n
        kid_parent, kid_octant = np.nonzero(occupied)  # row-major: parents in id order, octants ascending
        m = kid_parent.shape[0]
        kid_half = 0.5 * split_half[split][kid_parent]
        parent.append(ids[kid_parent].astype(np.int32))
        depth.append(np.full(m, d + 1, np.int32))
        center.append(split_center[split][kid_parent] + _OCTANT_SIGNS[kid_octant] * kid_half[:, None])
        half.append(kid_half)
        level.append((level[-1][splitting[split]] + shrinks[split] + 1)[kid_parent].astype(np.int32))
        child_offset.append(np.full(m, -1, np.int32))
        child_count.append(np.zeros(m, np.int32))
        first, n = n, n + m
        n_counted = np.bincount(where, weights=counted_ids[tris], minlength=m) if counted is not None \
            else np.bincount(where, minlength=m)
        d += 1

    parent_a, child_offset_a, child_count_a, depth_a = (np.concatenate(a) for a in (parent, child_offset,
                                                                                   child_count, depth))
    tri_order, tri_begin, tri_end = _depth_first_ranges(child_offset_a, child_count_a, depth_a, node_of)
    return OctreeLayout(parent=parent_a, child_offset=child_offset_a, child_count=child_count_a, depth=depth_a,
                        tri_order=tri_order, tri_begin=tri_begin, tri_end=tri_end,
                        cell_center=np.concatenate(center), cell_half=np.concatenate(half),
                        cell_level=np.concatenate(level))


def _split_cells(axes: list[np.ndarray], w: np.ndarray, center: np.ndarray, half: np.ndarray):
    """Split k cells at once. axes: three (t,) float64, the x, y, z of their triangles' centroids;
    w (t,) int64: each triangle's cell in 0..k-1; center (k,3), half (k,): the cells. A cell whose
    centroids share one octant shrinks into it and tries again (at most _MAX_SHRINKS times).

    Returns counts (k,8) int64 per octant of the cell that split (all zero: it could not),
    split_center (k,3) and split_half (k,): that (shrunk) cell, shrinks (k,) int32: how often it
    shrank, code (t,) uint8: each triangle's octant in it."""
    k = center.shape[0]
    center, half = center.copy(), half.copy()
    counts = np.zeros((k, 8), np.int64)
    shrinks = np.zeros(k, np.int32)
    code = np.zeros(w.shape[0], np.uint8)
    pending = np.arange(k)  # cells not yet split
    rows = None  # their triangles (None: all)
    local = w  # each row's index into pending
    for _ in range(_MAX_SHRINKS):
        if pending.size == 0:
            break
        cell = w if rows is None else w[rows]
        octant = np.zeros(cell.shape[0], np.uint8)
        for a in range(3):  # bit a: on the + side of axis a
            coordinate = axes[a] if rows is None else axes[a][rows]
            octant |= (coordinate >= center[cell, a]).view(np.uint8) << np.uint8(a)
        per = np.bincount(local * 8 + octant, minlength=8 * pending.size).reshape(-1, 8)
        splits_now = np.count_nonzero(per, axis=1) > 1
        counts[pending[splits_now]] = per[splits_now]
        if rows is None:
            code = octant
        else:
            code[rows] = octant
        shrink = pending[~splits_now]
        if shrink.size == 0:
            break
        first_octant = np.argmax(per[~splits_now] > 0, axis=1)
        half[shrink] *= 0.5
        center[shrink] += _OCTANT_SIGNS[first_octant] * half[shrink, None]
        shrinks[shrink] += 1
        still = ~splits_now[local]
        rows = np.flatnonzero(still) if rows is None else rows[still]
        local_of = np.full(k, -1, np.int64)
        local_of[shrink] = np.arange(shrink.size)
        local = local_of[w[rows]]
        pending = shrink
    return counts, center, half, shrinks, code


def _depth_first_ranges(child_offset, child_count, depth, node_of):
    """tri_order (f,) int64 and tri_begin/tri_end (n,) int64: triangles sorted (stably) by their
    leaf's rank in depth-first order, so every subtree is one range."""
    n = child_offset.shape[0]
    leaf_rank = np.full(n, -1, np.int64)
    rank = 0
    stack = [0]
    while stack:
        node = stack.pop()
        if child_count[node] == 0:
            leaf_rank[node] = rank
            rank += 1
        else:  # push children in reverse so they are visited in id order
            stack.extend(range(child_offset[node] + child_count[node] - 1, child_offset[node] - 1, -1))
    key = leaf_rank[node_of]
    tri_order = np.argsort(key.astype(np.uint16) if rank <= _RADIX_KEYS else key, kind="stable").astype(np.int64)
    per_rank = np.bincount(key, minlength=rank)
    ends = np.cumsum(per_rank)
    leaves = np.flatnonzero(leaf_rank >= 0)
    begin = np.zeros(n, np.int64)
    end = np.zeros(n, np.int64)
    begin[leaves] = ends[leaf_rank[leaves]] - per_rank[leaf_rank[leaves]]
    end[leaves] = ends[leaf_rank[leaves]]
    for d in range(int(depth.max()), -1, -1):  # deepest first: children are final before their parent
        inner = np.flatnonzero((depth == d) & (child_count > 0))
        begin[inner] = begin[child_offset[inner]]
        end[inner] = end[child_offset[inner] + child_count[inner] - 1]
    return tri_order, begin, end
