"""Top-down octree partition of triangles (docs/how-it-works.md#the-bake).

Data form in: triangle centroids (f,3) float64 (in the bake: relative to its origin). Data form
out: `OctreeLayout`, a node table in breadth-first order (children contiguous) with each node's
cell, plus a permutation of the triangles in which every subtree's triangles form one contiguous
range (leaves in depth-first order; input order within a leaf).

Cells: the root cell is a `root_cube.RootCube`: in a bake from scratch the cube around the
centroids' box (`tight_cube`: its lowest corner at the box's, side its longest extent), in a re-bake the earlier
bake's while the centroids fit it (frame.py), possibly grown by doublings that keep the earlier
cube as an octant; a cell splits at its centre into octants (a grown cube at the earlier cube's
face, its octant there being exactly the earlier cube: root_cube.GrowthChain), so every cell is
fixed by the root cell and its path. A node's cell (`cell_center`, `cell_half`, `cell_level`) is
the octant it was made as (the root: the root cube). An edit keeps every cell it does not overlap,
which is what the bake cache (bake/run/cache.py) reuses.
Why: docs/how-it-works.md#octree-cells-that-stay-put

Rules: a cell splits into its 8 octants while it holds more than `target_tris` (counted) triangles
and its depth is below `max_depth`; each triangle goes to the octant containing its centroid (a
centroid on a splitting plane goes to the + side); empty octants are dropped. When every centroid
falls in one octant, the cell shrinks to that octant without creating a node (a node with one
child would only repeat its child's LOD). A cell whose centroids all coincide (or still share one
octant after _MAX_SHRINKS shrinks) cannot be split and becomes a leaf over the budget.

Vectorised by depth (octree_passes.py): each depth costs two passes, in chunks, over the triangles
still in splitting cells (their octant codes and counts per (cell, octant); then their next cell,
those in leaves leaving), and a counting sort by leaf at the end; each pass is one task per region
of the triangles (chunk_store.py: on the bake's workers, or inline), the same layout for any regions.
Why: docs/how-it-works.md#the-early-phases-as-chunk-tasks

From counts (`build_octree_counted`, the out-of-core bakes of partition.py): the same layout,
float for float, without an (f,3) array of centroids: one counting pass over a stream of triangles
per depth (`OctantQuery.count` per chunk, summed). The layout's tri_order is None: the stream
routes each triangle to its leaf (`OctantRouter.route`) in input order, as tri_order lists them.
Why: docs/how-it-works.md#the-octree-from-counts
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .chunk_store import ChunkStore
from .octree_passes import MAX_SHRINKS as _MAX_SHRINKS
from .octree_passes import OCTANT_SIGNS as _OCTANT_SIGNS
from .octree_passes import ActiveTriangles, split_cells
from .root_cube import GrowthChain, RootCube, tight_cube


@dataclass(frozen=True, eq=False)
class OctreeLayout:
    """parent/child_offset/child_count/depth (n,) int32 as in hierarchy.Hlod;
    tri_order (f,) int64: input triangle ids, subtree-contiguous (None when built from counts:
    build_octree_counted);
    tri_begin/tri_end (n,) int64: each node's range in tri_order (its original triangles);
    cell_center (n,3) float64 and cell_half (n,) float64: each node's cell (in the centroids'
    frame), cell_level (n,) int32: its grid level (root 0; one more per
    split or shrink, so level >= depth)."""

    parent: np.ndarray
    child_offset: np.ndarray
    child_count: np.ndarray
    depth: np.ndarray
    tri_order: np.ndarray | None
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
                 counted: np.ndarray | None = None, root: RootCube | None = None,
                 store: ChunkStore | None = None) -> OctreeLayout:
    """Partition triangles by centroid. centroids: (f,3) float64, finite, f >= 1.
    counted: (f,) bool, the triangles that count toward `target_tris` (default all); the bake
    leaves out collapsed triangles, which welding drops and no LOD could ever reduce.
    root: the root cell, in the centroids' frame (default: `tight_cube` of the centroids' box).
    store: where the passes' arrays live and their tasks run (chunk_store.py: the bake's workers;
    None: in this process); the same layout wherever they run."""
    if target_tris < 1 or max_depth < 0:
        raise ValueError("target_tris must be >= 1 and max_depth >= 0")
    centroids = np.asarray(centroids, np.float64)
    f = centroids.shape[0]
    if root is None:
        root = tight_cube(centroids.min(axis=0), centroids.max(axis=0))
    counted_ids = np.ones(f, bool) if counted is None else np.asarray(counted, bool)

    rows, chain = _LevelRows.of(root), GrowthChain.of(root)
    active = ActiveTriangles(centroids, None if counted is None or counted_ids.all() else ~counted_ids, store)
    first, n = 0, 1  # id of the first node of the current depth, nodes so far
    # the current depth's nodes that split (indices from `first`)
    splitting = np.flatnonzero(np.array([int(counted_ids.sum())]) > target_tris) if max_depth > 0 else np.zeros(0, int)
    d = 0
    while splitting.size:
        counts, split_center, split_half, shrinks = split_cells(active, center=rows.center[-1][splitting],
                                                                half=rows.half[-1][splitting], chain=chain)
        split = np.flatnonzero(counts.any(axis=1))  # (k,) split nodes; the others stay leaves
        occupied = counts[split] > 0
        ids = first + splitting[split]
        offsets, m = rows.add_children(ids, occupied, d=d, first=first, n=n, cell_center=split_center[split],
                                       cell_half=split_half[split],
                                       child_level=rows.level[-1][splitting[split]] + shrinks[split] + 1, chain=chain)
        d += 1
        # the children's counted triangles, in their order (row-major over `occupied`)
        n_counted = counts[split][occupied]
        uncounted = active.uncounted_per_key(counts.size)
        if uncounted is not None:
            n_counted = n_counted - uncounted.reshape(counts.shape)[split][occupied]
        after = np.flatnonzero(n_counted > target_tris) if d < max_depth else np.zeros(0, np.int64)
        # per key (8 x cell + octant): the node a triangle is in now (its child; an unsplittable
        # cell's triangles stay in it), and 8 x its cell's index in `after` (-1: it is a leaf)
        node_at = np.repeat(first + splitting, 8)
        child = np.full(counts.size, -1, np.int64)
        child.reshape(-1, 8)[split] = np.where(occupied, offsets[:, None] - n + np.cumsum(occupied, axis=1) - 1, -1)
        has = np.flatnonzero(child >= 0)
        node_at[has] = n + child[has]
        cell8_at = np.full(counts.size, -1, np.int64)
        rank8 = np.full(m, -1, np.int64)
        rank8[after] = 8 * np.arange(after.size)
        cell8_at[has] = rank8[child[has]]
        active.advance(cell8_at, node_at)
        first, n, splitting = n, n + m, after

    _, child_offset_a, child_count_a, depth_a = rows.tree()
    tri_order, tri_begin, tri_end = _depth_first_ranges(child_offset_a, child_count_a, depth=depth_a, active=active)
    return rows.layout(tri_order, tri_begin, tri_end)


class _LevelRows:
    """The top-down builds' per-node rows, one array per depth: parent, depth, child_offset,
    child_count (int32), cell center (m,3), half (m,) float64 and level (int32)."""

    @staticmethod
    def of(root: RootCube) -> "_LevelRows":
        rows = _LevelRows()
        rows.parent, rows.depth = [np.array([-1], np.int32)], [np.array([0], np.int32)]
        top = root.top  # the base cube, or the cube it grew to
        rows.center, rows.half = [top.center[None, :].astype(np.float64)], [np.array([0.5 * top.side])]
        rows.level = [np.array([0], np.int32)]
        rows.child_offset, rows.child_count = [np.array([-1], np.int32)], [np.array([0], np.int32)]
        return rows

    def add_children(self, ids: np.ndarray, occupied: np.ndarray, *, d: int, first: int, n: int,
                     cell_center: np.ndarray, cell_half: np.ndarray, child_level: np.ndarray,
                     chain: GrowthChain | None = None) -> tuple[np.ndarray, int]:
        """The children of the nodes `ids` (k,) of depth d (ids first..n-1, n nodes so far): one
        per occupied (k,8) octant of the node's cell (cell_center (k,3), cell_half (k,), shrunk as
        it split), level child_level (k,), in row-major order (parents in id order, octants
        ascending); the child of a grown root cube in the octant it grew from is that cube
        (root_cube.GrowthChain). Returns (k,) the first child id of each, and m, the children added."""
        kids = occupied.sum(axis=1)
        offsets = n + np.concatenate([[0], np.cumsum(kids)[:-1]]).astype(np.int64)
        self.child_offset[-1][ids - first] = offsets
        self.child_count[-1][ids - first] = kids
        kid_parent, kid_octant = np.nonzero(occupied)
        m = kid_parent.shape[0]
        kid_half = 0.5 * cell_half[kid_parent]
        kid_center = cell_center[kid_parent] + _OCTANT_SIGNS[kid_octant] * kid_half[:, None]
        if chain is not None:
            chain.enter_inner(chain.index(cell_center, cell_half)[kid_parent], kid_octant, kid_center, kid_half)
        self.parent.append(ids[kid_parent].astype(np.int32))
        self.depth.append(np.full(m, d + 1, np.int32))
        self.center.append(kid_center)
        self.half.append(kid_half)
        self.level.append(child_level[kid_parent].astype(np.int32))
        self.child_offset.append(np.full(m, -1, np.int32))
        self.child_count.append(np.zeros(m, np.int32))
        return offsets, m

    def tree(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(n,) parent, child_offset, child_count, depth."""
        return tuple(np.concatenate(a) for a in (self.parent, self.child_offset, self.child_count, self.depth))

    def layout(self, tri_order, tri_begin: np.ndarray, tri_end: np.ndarray) -> OctreeLayout:
        parent, child_offset, child_count, depth = self.tree()
        return OctreeLayout(parent=parent, child_offset=child_offset, child_count=child_count, depth=depth,
                            tri_order=tri_order, tri_begin=tri_begin, tri_end=tri_end,
                            cell_center=np.concatenate(self.center), cell_half=np.concatenate(self.half),
                            cell_level=np.concatenate(self.level))


def _depth_first_ranges(child_offset, child_count, *, depth, active: ActiveTriangles):
    """tri_order (f,) int64 and tri_begin/tri_end (n,) int64: triangles sorted (stably) by their
    leaf's rank in depth-first order, so every subtree is one range."""
    leaf_rank, rank = _leaf_ranks(child_offset, child_count)
    tri_order, per_rank = active.sort_by_leaf(leaf_rank, rank)
    begin, end = _ranges(child_offset, child_count, depth=depth, leaf_rank=leaf_rank, per_rank=per_rank)
    return tri_order, begin, end


def _leaf_ranks(child_offset, child_count) -> tuple[np.ndarray, int]:
    """(n,) int64 each leaf's rank in depth-first order (children in id order), -1 for inner
    nodes; and the number of leaves."""
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
    return leaf_rank, rank


def _ranges(child_offset, child_count, *, depth, leaf_rank, per_rank):
    """tri_begin/tri_end (n,) int64 of the leaves (ranked), per_rank (leaves,) their triangle
    counts in rank order; an inner node spans its first to its last child's range."""
    n = child_offset.shape[0]
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
    return begin, end


# --- the same octree from counts (inputs bigger than memory) -----------------------------------

#: Octant levels a counting pass evaluates per splitting cell: a cell whose centroids share one
#: octant at the first k < COUNT_LEVELS levels shrinks k times and splits within the same pass.
COUNT_LEVELS = 8


@dataclass(frozen=True, eq=False)
class OctantRouter:
    """The tree built so far, as a stream descends it: per node, split_center (n,3) float64 (the
    centre of the cell it split at, after its shrinks; NaN where it did not split) and child (n,8)
    int64 (the child in each octant of that cell, -1 where none)."""

    split_center: np.ndarray
    child: np.ndarray

    def route(self, centroids: np.ndarray) -> np.ndarray:
        """(t,) int64: the node each centroid ((t,3) float64) lies in, as deep as the tree goes
        (build_octree's rule: the octant of the split cell, + side on a plane)."""
        node = np.zeros(centroids.shape[0], np.int64)
        active = np.arange(centroids.shape[0])
        while active.size:
            inner = ~np.isnan(self.split_center[node[active], 0])
            active = active[inner]
            if active.size == 0:
                break
            octant = _octants(centroids[active], self.split_center[node[active]])
            node[active] = self.child[node[active], octant]
        return node


def _octants(xyz: np.ndarray, center: np.ndarray) -> np.ndarray:
    """(t,) int64 octant of each point (t,3) in the cell of centre (t,3): bit a set on the + side
    of axis a, a point on a plane on its + side (build_octree's rule)."""
    octant = np.zeros(xyz.shape[0], np.int64)
    for a in range(3):
        octant |= (xyz[:, a] >= center[:, a]).astype(np.int64) << a
    return octant


@dataclass(frozen=True, eq=False)
class OctantQuery:
    """One counting pass: the splitting cells `nodes` (k,) int64 at their current cell, center
    (k,3) float64 and half (k,) float64, each evaluated at `levels` successive octant levels (a
    level's cell is the previous level's octant holding the centroid, as `octree_passes.split_cells` shrinks)."""

    router: OctantRouter
    nodes: np.ndarray
    center: np.ndarray
    half: np.ndarray
    levels: int

    def count(self, centroids: np.ndarray, counted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Counts of one chunk of triangles (centroids (t,3) float64, counted (t,) bool): all and
        counted, each (k, levels, 8) int64 per cell, level and octant. Sum them over the chunks."""
        k, levels = self.nodes.shape[0], self.levels
        local_of = np.full(self.router.child.shape[0], -1, np.int64)
        local_of[self.nodes] = np.arange(k)
        local = local_of[self.router.route(centroids)]
        rows = np.flatnonzero(local >= 0)
        local = local[rows]
        xyz = centroids[rows]
        center, half = self.center[local], self.half[local]
        key = np.empty((levels, rows.size), np.int64)
        for level in range(levels):
            octant = _octants(xyz, center)
            key[level] = (local * levels + level) * 8 + octant
            half = half * 0.5  # the octant as split_cells shrinks into it: half *= 0.5; center += sign * half
            center = center + _OCTANT_SIGNS[octant] * half[:, None]
        size = k * levels * 8
        every = np.bincount(key.ravel(), minlength=size).reshape(k, levels, 8)
        mine = np.bincount(key[:, counted[rows]].ravel(), minlength=size).reshape(k, levels, 8)
        return every, mine


@dataclass(frozen=True, eq=False)
class CountedOctree:
    """build_octree_counted's result: layout (tri_order None: the stream routes the triangles),
    router (OctantRouter of the whole tree: route a centroid to its leaf), tri_count and
    counted (n,) int64, each node's triangles and counted triangles."""

    layout: OctreeLayout
    router: OctantRouter
    tri_count: np.ndarray
    counted: np.ndarray


def build_octree_counted(count_pass, *, root: RootCube, tri_count: int, counted_count: int, target_tris: int,
                         max_depth: int, levels: int = COUNT_LEVELS) -> CountedOctree:
    """build_octree's layout (the same nodes, cells and ranges, float for float) from counts instead
    of an (f,3) array of centroids: count_pass(OctantQuery) -> (all, counted) (k, levels, 8) int64
    sums of OctantQuery.count over every triangle (one pass over the input). A depth costs one
    pass, plus one per COUNT_LEVELS shrinks its cells take in a row (rare)."""
    if target_tris < 1 or max_depth < 0:
        raise ValueError("target_tris must be >= 1 and max_depth >= 0")
    if root.growths:
        raise ValueError("the octree from counts splits cells at their centres: a root cube that never grew")
    rows = _LevelRows.of(root)
    n_all, n_counted = [np.array([tri_count], np.int64)], [np.array([counted_count], np.int64)]
    split_center, child = np.full((1, 3), np.nan), np.full((1, 8), -1, np.int64)
    first, n, d = 0, 1, 0
    while d < max_depth:
        splitting = np.flatnonzero(n_counted[-1] > target_tris)
        if splitting.size == 0:
            break
        ids = first + splitting
        router = OctantRouter(split_center, child)
        counts, counts_counted, cell_center, cell_half, shrinks = _resolve_splits(
            count_pass, router, ids, center=rows.center[-1][splitting], half=rows.half[-1][splitting], levels=levels)
        split = np.flatnonzero(counts.any(axis=1))
        occupied = counts[split] > 0
        _, m = rows.add_children(ids[split], occupied, d=d, first=first, n=n, cell_center=cell_center[split],
                                 cell_half=cell_half[split],
                                 child_level=rows.level[-1][splitting[split]] + shrinks[split] + 1)
        kid_parent, kid_octant = np.nonzero(occupied)  # row-major, as add_children numbers them
        n_all.append(counts[split][occupied])
        n_counted.append(counts_counted[split][occupied])
        split_center = np.concatenate([split_center, np.full((m, 3), np.nan)])
        split_center[ids[split]] = cell_center[split]
        child = np.concatenate([child, np.full((m, 8), -1, np.int64)])
        child[ids[split][kid_parent], kid_octant] = n + np.arange(m)
        first, n = n, n + m
        d += 1

    _, child_offset_a, child_count_a, depth_a = rows.tree()
    all_a = np.concatenate(n_all)
    leaf_rank, rank = _leaf_ranks(child_offset_a, child_count_a)
    per_rank = np.zeros(rank, np.int64)
    leaves = np.flatnonzero(leaf_rank >= 0)
    per_rank[leaf_rank[leaves]] = all_a[leaves]
    tri_begin, tri_end = _ranges(child_offset_a, child_count_a, depth=depth_a, leaf_rank=leaf_rank, per_rank=per_rank)
    layout = rows.layout(None, tri_begin, tri_end)
    return CountedOctree(layout=layout, router=OctantRouter(split_center, child), tri_count=all_a,
                         counted=np.concatenate(n_counted))


def _resolve_splits(count_pass, router: OctantRouter, ids: np.ndarray, *, center: np.ndarray, half: np.ndarray,
                    levels: int):
    """octree_passes.split_cells from counts: for the k cells `ids` (center (k,3), half (k,)), passes of
    `levels` octant levels until each splits or has shrunk _MAX_SHRINKS times. Returns counts and
    counted counts (k,8) int64 of the octants of the cell each split at (all zero: it could not),
    that cell's center (k,3) and half (k,), and shrinks (k,) int32."""
    k = ids.shape[0]
    center, half = center.copy(), half.copy()
    counts = np.zeros((k, 8), np.int64)
    counts_counted = np.zeros((k, 8), np.int64)
    shrinks = np.zeros(k, np.int32)
    pending = np.arange(k)
    evaluated = 0  # octant levels evaluated so far (the same for every pending cell)
    while pending.size and evaluated < _MAX_SHRINKS:
        step = min(levels, _MAX_SHRINKS - evaluated)
        every, mine = count_pass(OctantQuery(router=router, nodes=ids[pending], center=center[pending],
                                             half=half[pending], levels=step))
        splits_at = np.count_nonzero(every, axis=2) > 1  # (p, step)
        splits = splits_at.any(axis=1)
        first = np.where(splits, np.argmax(splits_at, axis=1), step)  # shrinks in this pass
        for lv in range(step):  # shrink into the one occupied octant, as split_cells does
            going = pending[first > lv]
            if going.size == 0:
                break
            octant = np.argmax(every[first > lv, lv] > 0, axis=1)
            half[going] *= 0.5
            center[going] += _OCTANT_SIGNS[octant] * half[going, None]
        done = pending[splits]
        counts[done] = every[splits, first[splits]]
        counts_counted[done] = mine[splits, first[splits]]
        shrinks[pending] += first.astype(np.int32)
        pending = pending[~splits]
        evaluated += step
    return counts, counts_counted, center, half, shrinks
