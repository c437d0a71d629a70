"""The in-memory octree's per-triangle passes (octree.build_octree), one depth at a time: each
triangle's octant in its splitting cell, the counts per (cell, octant), and the triangles that go
on to the next depth, compacted in place; at the end a counting sort by leaf. Each pass runs as
tasks over index chunks of the triangles (chunk_store.regions: TASK_ROWS rows a task) on the bake's
workers or inline (chunk_store.py); the bake's process only sums their per-key counts and makes
the per-cell tables of the next pass.

Data form: the shared arrays (chunk_store.ChunkStore) "centroids" (3,f) float64 (each axis
contiguous: prepare writes them so), "tris" (f,) int64 input ids, "cell8" (f,) int64 (8 x their
cell's index among the splitting cells), "key" (f,) int64 (cell8 + octant), "uncounted" (f,) bool
(only where some triangle does not count), "node_of" (f,) int64 (each triangle's leaf, written as
it leaves), "pending" (f,) int64 (rows of cells that shrank) and "tri_order" (f,) int64. A
region (start, end) of the input's ids keeps its active triangles (those still in splitting cells)
in its first t rows (`ActiveTriangles.live`), in input order: the regions one after the other are
the one active list a single pass over every triangle keeps, so every key, count and leaf is the
same for any cut of the rows into regions (one, several, an uneven last one, one left empty).

Why in chunks of CHUNK rows within a task: a whole-array pass allocates a new array of the input's
length for every temporary, and numpy asks Linux for those in huge pages, whose first touch can
cost the kernel several times the pass itself (three 40 MB copies on the Xeon, its memory
fragmented by other work: 0.06 to 0.72 s, up to 0.32 s of it system time); a chunk's temporaries
are small, reused, and stay in the cache.
"""
from __future__ import annotations

import numpy as np

from . import chunk_store
from .root_cube import GrowthChain

#: Rows a pass handles at a time within a task (0.5 MB a float64 temporary).
CHUNK = 1 << 16
#: A stable sort of keys of at most 16 bits is numpy's radix sort (linear); wider keys sort by timsort.
RADIX_KEYS = 2**16
# A cell may shrink this many times in a row while all centroids stay in one octant; float64 has a
# 52-bit mantissa, so distinct centroids always separate well before this.
MAX_SHRINKS = 128
# Octant o has bit a set when it lies on the + side of axis a: its centre moves by sign * half / 2.
OCTANT_SIGNS = np.array([[(o >> a) & 1 for a in range(3)] for o in range(8)], np.float64) * 2.0 - 1.0


class ActiveTriangles:
    """The triangles still in splitting cells (module docstring), at first every one, in the root:
    the bake's process's view of the shared arrays, region by region. centroids: (f,3) float64
    (the (3,f) store array's transpose: used in place; else copied into the store); uncounted (f,)
    bool or None; store: where the arrays live and the tasks run (None: inline, here)."""

    def __init__(self, centroids: np.ndarray, uncounted: np.ndarray | None,
                 store: chunk_store.ChunkStore | None = None):
        self.store = store = chunk_store.ChunkStore() if store is None else store
        f = centroids.shape[0]
        self.f = f
        if "centroids" not in store or not np.may_share_memory(store.get("centroids"), centroids):
            store.put("centroids", np.ascontiguousarray(centroids.T, np.float64))
        for name in ("tris", "key", "pending"):
            store.create(name, (f,), np.int64)
        store.create("cell8", (f,), np.int64, zeros=True)  # every triangle in the root cell's
        store.create("node_of", (f,), np.int64, zeros=True)  # a root that never splits is the leaf
        self.with_uncounted = uncounted is not None
        if self.with_uncounted:
            store.put("uncounted", np.array(uncounted, bool))
        self.regions = store.regions(f)
        self.live = [end - start for start, end in self.regions]  # active rows per region
        self.unc_per: np.ndarray | None = None

    @property
    def t(self) -> int:
        """The active triangles."""
        return sum(self.live)

    def octants(self, plane: np.ndarray, only: np.ndarray | None = None, pending: list | None = None):
        """Every active triangle's octant in its cell, whose planes are plane (k,3): key filled;
        returns the counts (k,8) int64 per cell and octant (and the uncounted ones, `unc_per`).
        only: (k,) bool, the cells to do (the others keep their keys, counts zero); pending: per
        region its rows of `only`'s cells from the last call with `only` (None: all rows); returns
        the new pending (per region) as a second value."""
        k = plane.shape[0]
        calls = [(start, end - start, t, plane, only, None if pending is None else pending[r], self.with_uncounted)
                 for r, ((start, end), t) in enumerate(zip(self.regions, self.live))]
        results = self.store.run(octant_task, calls)
        per = np.zeros(8 * k, np.int64)
        unc = np.zeros(8 * k, np.int64) if self.with_uncounted else None
        for counts, uncounted, _ in results:
            per += counts
            if unc is not None:
                unc += uncounted
        if only is None:
            self.unc_per = unc
        elif unc is not None:
            self.unc_per.reshape(k, 8)[only] = unc.reshape(k, 8)[only]
        return per.reshape(k, 8), [rows for _, _, rows in results]

    def uncounted_per_key(self, size: int) -> np.ndarray | None:
        """(size,) int64: the uncounted active triangles per key (None: every triangle counts)."""
        return self.unc_per if self.with_uncounted else None

    def advance(self, cell8_at: np.ndarray, node_at: np.ndarray) -> None:
        """To the next depth: by key, cell8_at (8k,) int64 the triangle's next cell8 (-1: it is in
        a leaf now, node_at (8k,) int64: which, recorded in node_of); the others compacted."""
        calls = [(start, end - start, t, cell8_at, node_at, self.with_uncounted)
                 for (start, end), t in zip(self.regions, self.live)]
        self.live = self.store.run(advance_task, calls)

    def sort_by_leaf(self, leaf_rank: np.ndarray, rank: int) -> tuple[np.ndarray, np.ndarray]:
        """The triangles sorted stably by their leaf's rank (leaf_rank (n,) int64, rank leaves):
        tri_order (f,) int64 (this process's array) and per_rank (rank,) int64, each rank's
        triangles. A counting sort: each region's counts per rank (a task each), then each region
        places its triangles after those of the earlier regions of the same rank."""
        counts = self.store.run(rank_count_task, [(start, end, leaf_rank, rank) for start, end in self.regions])
        per_rank = np.sum(counts, axis=0, dtype=np.int64) if counts else np.zeros(rank, np.int64)
        place = np.cumsum(per_rank) - per_rank  # where each rank's first triangle goes
        calls = []
        for (start, end), region_counts in zip(self.regions, counts):
            calls.append((start, end, leaf_rank, place.copy()))
            place += region_counts
        tri_order = self.store.create("tri_order", (self.f,), np.int64)
        self.store.run(place_task, calls)
        return (tri_order if not self.store.folder else np.array(tri_order)), per_rank


def octant_task(store: chunk_store.ChunkStore, start: int, size: int, t: int, plane: np.ndarray,
                only: np.ndarray | None, pending: int | None, with_uncounted: bool):
    """A task of ActiveTriangles.octants over the region of `size` rows from `start`, its first t
    rows active: (counts (8k,) int64 per key, uncounted (8k,) int64 per key or None, the region's
    pending rows (with `only`: how many rows of its cells it holds now, from store "pending"))."""
    k = plane.shape[0]
    spread = np.zeros((3, 8 * k))  # the planes by 8 x cell, as cell8 looks them up
    spread[:, ::8] = plane.T
    xyz = store.get("centroids")
    tris, cell8_a, key_a = store.get("tris"), store.get("cell8"), store.get("key")
    uncounted = store.get("uncounted") if with_uncounted else None
    per = np.zeros(8 * k, np.int64)
    unc = np.zeros(8 * k, np.int64) if with_uncounted else None
    whole = t == size  # no triangle has left the region: tris[start:start + t] is start..start + t - 1
    if only is not None:
        return _octants_of_cells(store, start, t if pending is None else pending, pending is not None,
                                 (xyz, None if whole else tris, cell8_a, key_a, uncounted), spread, only, per, unc)
    for begin in range(start, start + t, CHUNK):
        end = min(start + t, begin + CHUNK)
        cell8 = cell8_a[begin:end]
        points = [a[begin:end] for a in xyz] if whole else [a.take(tris[begin:end]) for a in xyz]
        one = int(cell8[0])
        if (cell8 == one).all():  # one cell (shallow depths, or an object's run): its planes as scalars
            octant = octant_codes(points, one, spread)
            np.add(octant, one, out=key_a[begin:end], dtype=np.int64)  # int64 under any promotion rules
            per[one:one + 8] += np.bincount(octant, minlength=8)
        else:
            octant = octant_codes(points, cell8, spread)
            np.add(cell8, octant, out=key_a[begin:end])
            per += np.bincount(key_a[begin:end], minlength=8 * k)
        if unc is not None:
            unc += np.bincount(key_a[begin:end][uncounted[begin:end]], minlength=8 * k)
    return per, unc, None


def _octants_of_cells(store, start, count, from_pending, arrays, spread, only, per, unc):
    """octant_task for the rows of the cells `only` (k,) bool: of the region's first `count` active
    rows, or (from_pending) of its `count` rows in store "pending" from the last such call; those
    rows written to "pending" for the next. tris None: the region's rows are its input ids."""
    xyz, tris, cell8_a, key_a, uncounted = arrays
    pending_a = store.get("pending")
    kept = start
    for begin in range(start, start + count, CHUNK):
        end = min(start + count, begin + CHUNK)
        rows = np.array(pending_a[begin:end]) if from_pending else np.arange(begin, end)
        rows = rows[only.take(cell8_a.take(rows) >> 3)]
        pending_a[kept:kept + rows.shape[0]] = rows
        kept += rows.shape[0]
        if rows.size == 0:
            continue
        cell8 = cell8_a.take(rows)
        ids = rows if tris is None else tris.take(rows)
        octant = octant_codes([a.take(ids) for a in xyz], cell8, spread)
        key = cell8 + octant
        key_a[rows] = key
        per += np.bincount(key, minlength=per.shape[0])
        if unc is not None:
            unc += np.bincount(key[uncounted.take(rows)], minlength=per.shape[0])
    return per, unc, kept - start


def advance_task(store: chunk_store.ChunkStore, start: int, size: int, t: int, cell8_at: np.ndarray,
                 node_at: np.ndarray, with_uncounted: bool) -> int:
    """A task of ActiveTriangles.advance over the region of `size` rows from `start`, its first t
    rows active: each row's next cell8 by its key, node_of written for those that leave, the others
    moved down in order; returns how many stay active."""
    cell8_a, tris, key_a, node_of = store.get("cell8"), store.get("tris"), store.get("key"), store.get("node_of")
    uncounted = store.get("uncounted") if with_uncounted else None
    whole = t == size
    kept = start
    for begin in range(start, start + t, CHUNK):
        end = min(start + t, begin + CHUNK)
        key = key_a[begin:end]
        chunk = [cell8_at.take(key), np.arange(begin, end) if whole else tris[begin:end]]
        if uncounted is not None:
            chunk.append(uncounted[begin:end])
        done = chunk[0] < 0
        if done.any():
            gone = np.flatnonzero(done)
            node_of[chunk[1][gone]] = node_at.take(key[gone])
            keep = ~done
            chunk = [c[keep] for c in chunk]
        size_now = chunk[0].shape[0]
        for array, rows in zip((cell8_a, tris, uncounted), chunk):
            array[kept:kept + size_now] = rows
        kept += size_now
    return kept - start


def rank_count_task(store: chunk_store.ChunkStore, start: int, end: int, leaf_rank: np.ndarray,
                    rank: int) -> np.ndarray:
    """(rank,) int64: the triangles start..end-1 per their leaf's rank."""
    node_of = store.get("node_of")
    per_rank = np.zeros(rank, np.int64)
    for begin in range(start, end, CHUNK):
        per_rank += np.bincount(leaf_rank.take(node_of[begin:min(end, begin + CHUNK)]), minlength=rank)
    return per_rank


def place_task(store: chunk_store.ChunkStore, start: int, end: int, leaf_rank: np.ndarray, place: np.ndarray) -> None:
    """The triangles start..end-1 written into "tri_order" by their leaf's rank, stably: from
    place (rank,) int64, where each rank's next triangle goes. A chunk's rows sorted stably among
    themselves (radix sort for at most RADIX_KEYS ranks), then placed after the rows before."""
    node_of, tri_order = store.get("node_of"), store.get("tri_order")
    rank = place.shape[0]
    for begin in range(start, end, CHUNK):
        key = leaf_rank.take(node_of[begin:min(end, begin + CHUNK)])
        order = np.argsort(key.astype(np.uint16) if rank <= RADIX_KEYS else key, kind="stable")
        ranks = key[order]
        first = np.flatnonzero(np.concatenate([[True], ranks[1:] != ranks[:-1]]))  # each rank's first row
        size = np.diff(np.append(first, ranks.shape[0]))
        within = np.arange(ranks.shape[0]) - np.repeat(first, size)
        tri_order[place[ranks] + within] = order + begin
        place[ranks[first]] += size


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
    centroids share one octant shrinks into it and tries again (at most MAX_SHRINKS times), a pass
    over that cell's rows alone. A grown root cube (chain) splits at its plane, and shrinks into
    the cube it grew from exactly.

    Returns counts (k,8) int64 per octant of the cell that split (all zero: it could not),
    split_center (k,3) and split_half (k,): that (shrunk) cell, shrinks (k,) int32: how often it
    shrank; active's key: each triangle's cell8 + its octant in that cell."""
    k = center.shape[0]
    center, half = center.copy(), half.copy()
    counts = np.zeros((k, 8), np.int64)
    shrinks = np.zeros(k, np.int32)
    pending = np.arange(k)  # cells not yet split
    only, rows = None, None  # the cells still shrinking (k,) bool; per region, its rows of them
    for _ in range(MAX_SHRINKS):
        if pending.size == 0:
            break
        plane = center if chain is None else chain.planes(center, half)
        per, found = active.octants(plane, only, rows)
        rows = found if only is not None else None  # per region, how many rows of the shrinking cells
        per = per[pending]
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
        only = np.zeros(k, bool)
        only[shrink] = True
        pending = shrink
    return counts, center, half, shrinks
