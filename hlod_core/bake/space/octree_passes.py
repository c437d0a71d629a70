"""The in-memory octree's per-triangle passes (octree.build_octree), one depth at a time: each
triangle's octant in its splitting cell, the counts per (cell, octant), and the triangles that go
on to the next depth, compacted in place.

Data form: `ActiveTriangles`, the triangles in splitting cells: tris (t,) int64 input ids, cell8
(t,) int64 (8 x their cell's index among the splitting cells), key (t,) int64 (cell8 + octant),
uncounted (t,) bool or None (None: every triangle counts), each the first t rows of an array of
the input's length, allocated once; the centroids' axes xyz (three (f,) float64, the caller's
columns, never copied whole) are read by tris.

Why in chunks of CHUNK rows: a whole-array pass allocates a new array of the input's length for
every temporary, and numpy asks Linux for those in huge pages, whose first touch can cost the
kernel several times the pass itself (three 40 MB copies on the Xeon, its memory fragmented by
other work: 0.06 to 0.72 s, up to 0.32 s of it system time); a chunk's temporaries are small,
reused, and stay in the cache.
"""
from __future__ import annotations

import numpy as np

from .root_cube import GrowthChain

#: Rows a pass handles at a time (0.5 MB a float64 temporary).
CHUNK = 1 << 16
#: A stable sort of keys of at most 16 bits is numpy's radix sort (linear); wider keys sort by timsort.
RADIX_KEYS = 2**16
# A cell may shrink this many times in a row while all centroids stay in one octant; float64 has a
# 52-bit mantissa, so distinct centroids always separate well before this.
MAX_SHRINKS = 128
# Octant o has bit a set when it lies on the + side of axis a: its centre moves by sign * half / 2.
OCTANT_SIGNS = np.array([[(o >> a) & 1 for a in range(3)] for o in range(8)], np.float64) * 2.0 - 1.0


class ActiveTriangles:
    """The triangles still in splitting cells (module docstring); at first every one, in the root."""

    def __init__(self, centroids: np.ndarray, uncounted: np.ndarray | None):
        f = centroids.shape[0]
        self.t = f
        self.tris = np.arange(f, dtype=np.int64)
        self.xyz = [np.ascontiguousarray(centroids[:, a], np.float64) for a in range(3)]  # views of F-ordered ones
        self.cell8 = np.zeros(f, np.int64)
        self.key = np.empty(f, np.int64)
        self.uncounted = None if uncounted is None else np.array(uncounted, bool)

    def octants(self, plane: np.ndarray) -> np.ndarray:
        """Every active triangle's octant in its cell, whose planes are plane (k,3): key filled;
        returns the counts (k,8) int64 per cell and octant."""
        k = plane.shape[0]
        spread = np.zeros((3, 8 * k))  # the planes by 8 x cell, as cell8 looks them up
        spread[:, ::8] = plane.T
        per = np.zeros(8 * k, np.int64)
        for start in range(0, self.t, CHUNK):
            end = min(self.t, start + CHUNK)
            cell8 = self.cell8[start:end]
            one = int(cell8[0])
            if (cell8 == one).all():  # one cell (shallow depths, or an object's run): its planes as scalars
                octant = octant_codes(self.points(start, end), one, spread)
                np.add(octant, one, out=self.key[start:end], dtype=np.int64)  # int64 under any promotion rules
                per[one:one + 8] += np.bincount(octant, minlength=8)
                continue
            octant = octant_codes(self.points(start, end), cell8, spread)
            key = self.key[start:end]
            np.add(cell8, octant, out=key)
            per += np.bincount(key, minlength=8 * k)
        return per.reshape(k, 8)

    def points(self, start: int, end: int) -> list[np.ndarray]:
        """The centroids' axes of active rows start..end: three (end - start,) float64."""
        if self.t == self.xyz[0].shape[0]:  # every triangle is active: tris is 0..f-1
            return [a[start:end] for a in self.xyz]
        tris = self.tris[start:end]
        return [a.take(tris) for a in self.xyz]

    def uncounted_per_key(self, size: int) -> np.ndarray | None:
        """(size,) int64: the uncounted active triangles per key (None: every triangle counts)."""
        if self.uncounted is None:
            return None
        t = self.t
        return np.bincount(self.key[:t][self.uncounted[:t]], minlength=size)

    def advance(self, cell8_at: np.ndarray, node_at: np.ndarray, node_of: np.ndarray) -> None:
        """To the next depth: by key, cell8_at (8k,) int64 the triangle's next cell8 (-1: it is in
        a leaf now, node_at (8k,) int64: which, recorded in node_of (f,)); the others compacted."""
        live = [self.cell8, self.tris] + ([] if self.uncounted is None else [self.uncounted])
        kept = 0
        for start in range(0, self.t, CHUNK):
            end = min(self.t, start + CHUNK)
            key = self.key[start:end]
            chunk = [cell8_at.take(key)] + [a[start:end] for a in live[1:]]
            done = chunk[0] < 0
            if done.any():
                gone = np.flatnonzero(done)
                node_of[chunk[1][gone]] = node_at.take(key[gone])
                keep = ~done
                chunk = [c[keep] for c in chunk]
            size = chunk[0].shape[0]
            for array, rows in zip(live, chunk):
                if kept != start or rows.base is not array:  # rows of a later chunk move down
                    array[kept:kept + size] = rows
            kept += size
        self.t = kept


def octant_codes(xyz: list[np.ndarray], index: np.ndarray | int, plane: np.ndarray) -> np.ndarray:
    """(r,) uint8 octant of the points xyz (three (r,) float64) in the cells whose planes are column
    index (r,) int64 (or one int for all) of plane (3,.): bit a set on the + side of axis a (a point
    on a plane on its + side)."""
    octant = None
    for a in range(3):
        bit = (xyz[a] >= plane[a].take(index)).view(np.uint8)
        if octant is None:
            octant = bit
        else:
            bit <<= np.uint8(a)
            octant |= bit
    return octant


def split_cells(active: ActiveTriangles, *, center: np.ndarray, half: np.ndarray, chain: GrowthChain | None = None):
    """Split the k cells of the active triangles at once (center (k,3), half (k,)). A cell whose
    centroids share one octant shrinks into it and tries again (at most MAX_SHRINKS times). A grown
    root cube (chain) splits at its plane, and shrinks into the cube it grew from exactly.

    Returns counts (k,8) int64 per octant of the cell that split (all zero: it could not),
    split_center (k,3) and split_half (k,): that (shrunk) cell, shrinks (k,) int32: how often it
    shrank; active.key: each triangle's cell8 + its octant in that cell."""
    k = center.shape[0]
    center, half = center.copy(), half.copy()
    counts = np.zeros((k, 8), np.int64)
    shrinks = np.zeros(k, np.int32)
    pending = np.arange(k)  # cells not yet split
    rows = None  # their triangles (None: all)
    local = None  # each row's index into pending
    t = active.t
    for _ in range(MAX_SHRINKS):
        if pending.size == 0:
            break
        plane = center if chain is None else chain.planes(center, half)
        if rows is None:
            per = active.octants(plane)
        else:  # the triangles of cells that shrank: few
            cell = active.cell8[:t][rows] >> 3
            octant = octant_codes([a.take(active.tris[rows]) for a in active.xyz], cell, np.ascontiguousarray(plane.T))
            active.key[rows] = 8 * cell + octant
            per = np.bincount(local * 8 + octant, minlength=8 * pending.size).reshape(-1, 8)
        splits_now = np.count_nonzero(per, axis=1) > 1
        counts[pending[splits_now]] = per[splits_now]
        shrink = pending[~splits_now]
        if shrink.size == 0:
            break
        first_octant = np.argmax(per[~splits_now] > 0, axis=1)
        grown = None if chain is None else chain.index(center[shrink], half[shrink])
        half[shrink] *= 0.5
        center[shrink] += OCTANT_SIGNS[first_octant] * half[shrink, None]
        if grown is not None:
            shrunk_center, shrunk_half = center[shrink], half[shrink]
            chain.enter_inner(grown, first_octant, shrunk_center, shrunk_half)
            center[shrink], half[shrink] = shrunk_center, shrunk_half
        shrinks[shrink] += 1
        still = ~splits_now[active.cell8[:t] >> 3 if rows is None else local]
        rows = np.flatnonzero(still) if rows is None else rows[still]
        local_of = np.full(k, -1, np.int64)
        local_of[shrink] = np.arange(shrink.size)
        local = local_of[active.cell8[:t][rows] >> 3]
        pending = shrink
    return counts, center, half, shrinks


def sort_by_leaf(leaf_rank: np.ndarray, rank: int, node_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The triangles (node_of (f,) int64: each one's leaf) sorted stably by their leaf's rank
    (leaf_rank (n,) int64, rank leaves): tri_order (f,) int64 and per_rank (rank,) int64, each
    rank's triangles. A counting sort, a chunk at a time: each chunk's rows sorted stably among
    themselves, then placed after the rows of earlier chunks of the same rank."""
    f = node_of.shape[0]
    per_rank = np.zeros(rank, np.int64)
    for start in range(0, f, CHUNK):
        per_rank += np.bincount(leaf_rank.take(node_of[start:start + CHUNK]), minlength=rank)
    place = np.cumsum(per_rank) - per_rank  # where each rank's next triangle goes
    tri_order = np.empty(f, np.int64)
    for start in range(0, f, CHUNK):
        key = leaf_rank.take(node_of[start:start + CHUNK])
        order = np.argsort(key.astype(np.uint16) if rank <= RADIX_KEYS else key, kind="stable")
        ranks = key[order]
        first = np.flatnonzero(np.concatenate([[True], ranks[1:] != ranks[:-1]]))  # each rank's first row
        size = np.diff(np.append(first, ranks.shape[0]))
        within = np.arange(ranks.shape[0]) - np.repeat(first, size)
        tri_order[place[ranks] + within] = order + start
        place[ranks[first]] += size
    return tri_order, per_rank
