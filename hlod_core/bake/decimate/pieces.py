"""A node's connected pieces, and the ones its LOD drops: pieces below the node's error, and where
the pieces keep the LOD over its budget, all but the largest piece of each grid cell
(docs/how-it-works.md#decimating-a-node).

Data form: a node's welded input in its unit frame (meshlab.NodeFrame): positions (k,3) float64,
faces (m,3) int rows, locked (k,) bool (cell_seams.node_borders) and position ids (k,) int64
(vertices split by attributes share one). A piece is a set of vertices connected through faces,
by position. A free piece has no locked vertex, so it lies wholly inside the node; a piece with a
seam vertex goes on in a neighbouring cell and is never dropped (the seam would crack).

Which free pieces go (`choose`), given L0, the LOD made with all of them (n0 triangles, t0 of
each piece), and its error e0 = the largest distance of an input vertex to L0:
1. Below the error: a free piece whose extent (its box's diagonal) is at most e0 and whose every
   vertex lies within e0 of the rest of L0 (the other pieces' triangles, not counting other
   pieces this small). Where the node is drawn its error projects to at most tau pixels, so such
   a piece spans at most tau pixels (the papers' tau is 1) and the rest of the LOD stands in for
   it within the error.
2. Over the budget: where what is left would keep more than target_tris triangles (L0 stopped
   above the target: each piece is at the fewest triangles the collapse gives it) and dropping
   free pieces can bring it down to the target (not where the cell seams alone hold it over), the
   free pieces are binned on a grid of cell side h, from e0 up in steps of 2^(1/4), and each cell
   keeps its piece of most input triangles (then the lowest id): at the first h whose binned-out
   pieces would free enough triangles (or where one cell holds the node), just enough of them go,
   those nearest their cell's kept piece first.
The node's error is measured afterwards against every original vertex below it (bake/measure/hausdorff.py,
or its bound against the children's vertices), the dropped pieces' too: it bounds what was dropped.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .meshlab import UNIT_DIAGONAL, point_distances

#: Grid cells of the budget rule are at least this (unit frame); they grow by CELL_STEP up to
#: 2 x UNIT_DIAGONAL, where one cell holds the whole node.
SMALLEST_CELL = 2.0 ** -20
CELL_STEP = 2.0 ** 0.25


@dataclass(frozen=True, eq=False)
class Pieces:
    """of_vertex (k,) int64: each vertex's piece, numbered by first vertex; free (p,) bool;
    box_min / box_max (p,3) float64 unit frame; input_tris (p,) int64: the input faces of each."""

    of_vertex: np.ndarray
    free: np.ndarray
    box_min: np.ndarray
    box_max: np.ndarray
    input_tris: np.ndarray

    @property
    def count(self) -> int:
        return int(self.free.shape[0])

    @property
    def with_faces(self) -> int:
        """Pieces with at least one face (a vertex no face uses is a piece of its own)."""
        return int((self.input_tris > 0).sum())

    @property
    def extent(self) -> np.ndarray:
        """(p,) float64: each piece's box diagonal, unit frame."""
        return np.linalg.norm(self.box_max - self.box_min, axis=1)


@dataclass(frozen=True)
class Pruned:
    """What `choose` dropped: dropped (p,) bool; below_error / over_budget: pieces dropped by each
    rule; budget_cell: the last grid cell side of the budget rule (0: not used), unit frame."""

    dropped: np.ndarray
    below_error: int = 0
    over_budget: int = 0
    budget_cell: float = 0.0


def pieces_of(local: np.ndarray, faces: np.ndarray, locked: np.ndarray, *,
              position_ids: np.ndarray | None = None) -> Pieces:
    """The Pieces of a welded node input (module docstring)."""
    k = local.shape[0]
    ids = np.arange(k, dtype=np.int64) if position_ids is None else np.asarray(position_ids, np.int64)
    n = int(ids.max()) + 1 if k else 0
    comp = components(ids[faces], n)
    # pieces by their lowest id (the components' roots), then numbered by first vertex
    by_root = np.cumsum(comp == np.arange(n)) - 1
    of_vertex = by_root[comp[ids]]
    p = int(by_root[-1]) + 1 if n else 0
    first = np.full(p, k, np.int64)
    np.minimum.at(first, of_vertex, np.arange(k, dtype=np.int64))
    rank = np.empty(p, np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(p)
    of_vertex = rank[of_vertex]
    free = np.ones(p, bool)
    free[of_vertex[locked]] = False
    # boxes: each piece's vertices in one run (every piece has one at least)
    order = np.argsort(of_vertex, kind="stable")
    starts = np.concatenate([[0], np.cumsum(np.bincount(of_vertex, minlength=p))[:-1]]).astype(np.int64)
    box_min = np.minimum.reduceat(np.asarray(local, np.float64)[order], starts, axis=0) if p else np.zeros((0, 3))
    box_max = np.maximum.reduceat(np.asarray(local, np.float64)[order], starts, axis=0) if p else np.zeros((0, 3))
    input_tris = np.bincount(of_vertex[faces[:, 0]], minlength=p).astype(np.int64)
    free &= input_tris > 0  # a vertex no face uses is a piece of its own, and nothing to drop
    return Pieces(of_vertex=of_vertex, free=free, box_min=box_min, box_max=box_max, input_tris=input_tris)


def components(faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) int64: for each of n vertex ids, the lowest id connected to it through faces (f,3)
    (hooking to the lowest root, then pointer jumping to a fixed point)."""
    label = np.arange(n, dtype=np.int64)
    if faces.shape[0] == 0:
        return label
    a = np.asarray(faces, np.int64).ravel()
    b = np.asarray(faces, np.int64)[:, [1, 2, 0]].ravel()
    while True:
        la, lb = label[a], label[b]
        low = np.minimum(la, lb)
        hooked = label.copy()
        np.minimum.at(hooked, la, low)
        np.minimum.at(hooked, lb, low)
        while True:
            jumped = hooked[hooked]
            if np.array_equal(jumped, hooked):
                break
            hooked = jumped
        if np.array_equal(hooked, label):
            return label
        label = hooked


def choose(pieces: Pieces, *, local: np.ndarray, faces: np.ndarray, lod_local: np.ndarray, lod_faces: np.ndarray,
           lod_piece: np.ndarray, target_tris: int) -> Pruned:
    """The free pieces the LOD drops (module docstring). local (k,3) / faces (m,3): the node's
    welded input, unit frame; lod_local (j,3) / lod_faces (n0,3): L0; lod_piece (j,) int64: the
    piece of each L0 vertex (-1: unknown, counted with no piece)."""
    dropped = np.zeros(pieces.count, bool)
    if pieces.with_faces < 2 or not pieces.free.any() or lod_faces.shape[0] == 0:
        return Pruned(dropped)
    face_piece = lod_piece[lod_faces[:, 0]]
    lod_tris = np.bincount(face_piece[face_piece >= 0], minlength=pieces.count).astype(np.int64)
    error = float(point_distances(local, lod_local, lod_faces).max())
    below = _below_error(pieces, local=local, lod_local=lod_local, lod_faces=lod_faces, face_piece=face_piece,
                         error=error)
    dropped |= below
    over, cell = _over_budget(pieces, dropped=dropped, lod_tris=lod_tris, lod_total=int(lod_faces.shape[0]),
                              target_tris=target_tris, start=error)
    dropped |= over
    return Pruned(dropped, below_error=int(below.sum()), over_budget=int(over.sum()), budget_cell=cell)


def _below_error(pieces: Pieces, *, local: np.ndarray, lod_local: np.ndarray, lod_faces: np.ndarray,
                 face_piece: np.ndarray, error: float) -> np.ndarray:
    """Rule 1: (p,) bool, the free pieces no larger than `error` within `error` of the rest of L0."""
    small = pieces.free & (pieces.extent <= error)
    if not small.any() or error <= 0:
        return np.zeros(pieces.count, bool)
    rest = ~small[np.maximum(face_piece, 0)] | (face_piece < 0)
    if not rest.any():
        return np.zeros(pieces.count, bool)
    mine = small[pieces.of_vertex]
    distance = point_distances(local[mine], lod_local, lod_faces[rest])
    farthest = np.zeros(pieces.count)
    np.maximum.at(farthest, pieces.of_vertex[mine], distance)
    return small & (farthest <= error)


def _over_budget(pieces: Pieces, *, dropped: np.ndarray, lod_tris: np.ndarray, lod_total: int, target_tris: int,
                 start: float) -> tuple[np.ndarray, float]:
    """Rule 2: ((p,) bool, the grid cell side used or 0), the free pieces binned out: the smallest
    cell side (from `start` up, in steps of CELL_STEP) whose binned-out pieces free enough
    triangles, and of those only as many as needed, nearest to their cell's kept piece first."""
    none = np.zeros(pieces.count, bool)
    excess = lod_total - int(lod_tris[dropped].sum()) - target_tris
    candidates = np.flatnonzero(pieces.free & ~dropped)
    if excess <= 0 or candidates.size < 2 or int(lod_tris[candidates].sum()) - int(lod_tris[candidates].max()) < excess:
        return none, 0.0  # within budget, or held over it by what no drop can free (its cell seams)
    centre = 0.5 * (pieces.box_min[candidates] + pieces.box_max[candidates])
    centre -= centre.min(axis=0)  # cells from the lowest centre: at a side of 2 x UNIT_DIAGONAL, one cell
    # largest first (then lowest id): the first piece of each cell in this order is the one kept
    order = np.lexsort((candidates, -pieces.input_tris[candidates]))
    centre, candidates = centre[order], candidates[order]
    cell = CELL_STEP ** np.ceil(np.log(max(start, SMALLEST_CELL)) / np.log(CELL_STEP))
    while True:
        _, first, bin_of = np.unique(np.floor(centre / cell).astype(np.int64), axis=0, return_index=True,
                                     return_inverse=True)
        out = np.ones(candidates.size, bool)
        out[first] = False
        gain = int(lod_tris[candidates[out]].sum())
        if gain >= excess or cell >= 2.0 * UNIT_DIAGONAL:
            break
        cell *= CELL_STEP
    binned = np.flatnonzero(out)
    gap = np.linalg.norm(centre[binned] - centre[first[bin_of.reshape(-1)[binned]]], axis=1)
    nearest = binned[np.lexsort((candidates[binned], gap))]
    freed = np.cumsum(lod_tris[candidates[nearest]])
    enough = int(np.searchsorted(freed, excess, side="left")) + 1
    chosen = np.zeros(pieces.count, bool)
    chosen[candidates[nearest[:enough]]] = True
    return chosen, float(cell)
