"""Cell seams: the vertices each octree node shares with the cells around it, which its decimation
keeps in place (simplify.decimate_node), so that neighbouring nodes at any levels meet without
cracks. Every other vertex may collapse, the models' own open boundaries included.

Data form in: the leaves' vertices, per leaf (positions (k,3) float32, points of the bake's
lattice), leaves in depth-first order (by their range in the octree's triangle order). A position
is a seam of node n when leaves inside n and leaves outside n both use it (bit-identical float32:
the weld's rule), i.e. when the depth-first leaf range of its users is not inside n's.
Data form out: `CellSeams`, the shared positions with the leaves that use them; `locked(node)`,
(s,3) float32, the node's seam positions (a set, in the order of their bits).
Why: docs/how-it-works.md#decimating-a-node
"""
from __future__ import annotations

import concurrent.futures as cf
import hashlib
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...core.errors import BakeCancelled
from ..space.octree import OctreeLayout

#: Leaf vertices sorted at a time while the shared positions are found: with more, they are
#: split into buckets by a hash of their position and each bucket is sorted on its own (an
#: out-of-core bake's leaves are memory-mapped; about 50 bytes a vertex while a bucket is sorted).
BUCKET_VERTICES = 1 << 21
#: Leaf vertices from which the shared positions are found as tasks on the bake's workers (one
#: bucket at least a worker), where there are several: fewer take less than a task's round trip.
PARALLEL_FROM_VERTICES = 1 << 18
#: The file in a scratch folder holding the leaves' positions for those tasks (`build`).
SEAM_POSITIONS = "seam-positions.npy"
#: How often (seconds) `build` wakes while its tasks run, to check cancel().
POLL_SECONDS = 0.25


@dataclass(frozen=True, eq=False)
class CellSeams:
    """positions (S,3) float32: the positions more than one leaf uses, numbered by first use
    (depth first); first_leaf / last_leaf (S,) int64: the lowest and highest depth-first leaf
    index using each; pair_leaf (P,) int64 ascending and pair_position (P,) int64: each (leaf,
    shared position) use; pair_start (L+1,) int64: leaf j's uses are pairs pair_start[j]..
    pair_start[j+1]; leaf_begin / leaf_end (n,) int64: each node's depth-first leaf range."""

    positions: np.ndarray
    first_leaf: np.ndarray
    last_leaf: np.ndarray
    pair_leaf: np.ndarray
    pair_position: np.ndarray
    pair_start: np.ndarray
    leaf_begin: np.ndarray
    leaf_end: np.ndarray

    def locked(self, node: int) -> np.ndarray:
        """(s,3) float32: the positions `node` shares with cells outside it, a set: in the order
        of their bits (x, y, z), which depends on nothing outside them."""
        a, b = int(self.leaf_begin[node]), int(self.leaf_end[node])
        ids = self.pair_position[self.pair_start[a]:self.pair_start[b]]
        ids = np.unique(ids[(self.first_leaf[ids] < a) | (self.last_leaf[ids] >= b)])
        xy, z = _keys(self.positions[ids])
        return self.positions[ids[np.lexsort((z, xy))]]

    def digest(self, node: int) -> bytes:
        """16 bytes naming locked(node) (the bake cache keys an inner node by it too: its LOD
        depends on what its neighbours share with it)."""
        return hashlib.blake2b(np.ascontiguousarray(self.locked(node)).tobytes(), digest_size=16).digest()


def build(layout: OctreeLayout, lods: list, *, workers=None, folder: str | os.PathLike | None = None,
          cancel: Callable[[], bool] | None = None) -> CellSeams:
    """The CellSeams of a bake: lods[leaf] = (positions (k,3) f32, ...) for every leaf (arrays in
    memory or memory-mapped); the inner nodes' entries are not read.

    The shared positions are found bucket by bucket (`shared_in_bucket`), as tasks on `workers`
    (workers.Workers) where there are several and the leaves have at least PARALLEL_FROM_VERTICES
    vertices: at least one bucket a worker, which reads the leaves' positions from one file in the
    workers' scratch folder. Inline, the leaves' positions are concatenated in memory, or into a file
    in `folder` (an out-of-core bake's scratch folder: not in memory). The buckets partition the
    positions, so every count of them gives the same CellSeams. cancel: checked while tasks run
    (BakeCancelled once true)."""
    leaves = np.flatnonzero(layout.is_leaf)
    leaves = leaves[np.argsort(layout.tri_begin[leaves], kind="stable")]  # depth first
    counts = np.array([lods[leaf][0].shape[0] for leaf in leaves], np.int64)
    ends = np.cumsum(counts)
    total = int(ends[-1]) if ends.size else 0
    parallel = workers is not None and workers.limit > 1 and total >= PARALLEL_FROM_VERTICES
    buckets = max(1, -(-total // BUCKET_VERTICES), workers.limit if parallel else 1)
    if parallel:
        source = concat_positions(lods, leaves, total, os.path.join(workers.scratch, SEAM_POSITIONS))
        found = _run_buckets(workers, source, ends, buckets, cancel)
    else:
        path = os.path.join(folder, SEAM_POSITIONS) if folder is not None else None
        source = concat_positions(lods, leaves, total, path)
        found = [shared_in_bucket(source, ends, bucket=b, buckets=buckets) for b in range(buckets)]
    positions_of = np.load(source, mmap_mode="r") if isinstance(source, str) else source
    # every leaf-vertex row whose position is shared, in row order (depth first), with its
    # position named by the row of its first use: unique across buckets, and numbered by it
    row = np.concatenate([f[0] for f in found]) if found else np.zeros(0, np.int64)
    name = np.concatenate([f[1] for f in found]) if found else np.zeros(0, np.int64)
    del found
    order = np.argsort(row, kind="stable")
    row, name = row[order], name[order]
    number, pair_position = np.unique(name, return_inverse=True)
    pair_position = pair_position.reshape(-1)
    pair_leaf = np.searchsorted(ends, row, side="right").astype(np.int64)  # the leaf of each row
    keep = np.ones(row.size, bool)  # one pair per (leaf, position): a leaf may list a position twice
    keep[1:] = (np.diff(pair_leaf) != 0) | (np.diff(pair_position) != 0)
    pair_leaf, pair_position = pair_leaf[keep], pair_position[keep]
    s = number.size
    first_leaf = np.full(s, leaves.size, np.int64)
    last_leaf = np.full(s, -1, np.int64)
    np.minimum.at(first_leaf, pair_position, pair_leaf)
    np.maximum.at(last_leaf, pair_position, pair_leaf)
    positions = np.asarray(positions_of[number], np.float32).reshape(-1, 3)
    del positions_of
    pair_start = np.searchsorted(pair_leaf, np.arange(leaves.size + 1), side="left").astype(np.int64)
    return CellSeams(positions=positions, first_leaf=first_leaf, last_leaf=last_leaf, pair_leaf=pair_leaf,
                     pair_position=pair_position, pair_start=pair_start, **_leaf_ranges(layout, leaves))


def shared_in_bucket(source: str | np.ndarray, ends: np.ndarray, *, bucket: int,
                     buckets: int) -> tuple[np.ndarray, np.ndarray]:
    """A task of `build`: the leaf-vertex rows (global, depth first) of bucket `bucket` (of
    `buckets`, by a hash of the position's bits) whose position more than one leaf uses, and the
    first row using the same position: (row, first) (r,) int64 each, rows ascending within a
    position. source: the leaves' positions (V,3) float32 concatenated depth first, or the .npy
    file holding them (memory-mapped, read BUCKET_VERTICES rows at a time); ends (L,) int64: each
    leaf's last row + 1."""
    positions = np.load(source, mmap_mode="r") if isinstance(source, str) else source
    total = int(positions.shape[0])
    xs, zs, row_ids = [], [], []
    for start in range(0, total, BUCKET_VERTICES):
        xy, z = _keys(np.asarray(positions[start:start + BUCKET_VERTICES]))
        ids = np.arange(start, start + xy.shape[0], dtype=np.int64)
        if buckets > 1:
            mine = _bucket_of(xy, z, buckets) == bucket
            xy, z, ids = xy[mine], z[mine], ids[mine]
        xs.append(xy)
        zs.append(z)
        row_ids.append(ids)
    del positions
    if not xs:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    xy, z, row = np.concatenate(xs), np.concatenate(zs), np.concatenate(row_ids)
    del xs, zs, row_ids
    order = np.lexsort((z, xy))  # by position; stable, so rows (depth first) stay ascending within one
    xy, z, row = xy[order], z[order], row[order]
    new = np.ones(row.size, bool)
    new[1:] = (xy[1:] != xy[:-1]) | (z[1:] != z[:-1])
    group = np.cumsum(new) - 1
    starts = np.flatnonzero(new)
    last = np.append(starts[1:], row.size) - 1
    first_row, last_row = row[starts][group], row[last][group]
    ends = np.asarray(ends, np.int64)
    leaf_of = np.repeat(np.arange(ends.size, dtype=np.int32), np.diff(ends, prepend=0))
    shared = leaf_of[first_row] != leaf_of[last_row]
    return row[shared], first_row[shared]


def concat_positions(lods: list, leaves: np.ndarray, total: int, path: str | None) -> str | np.ndarray:
    """The leaves' positions (total,3) float32 concatenated depth first: in memory (path None), or
    written leaf by leaf into the .npy file `path` (returned)."""
    if path is None:
        if leaves.size == 0:
            return np.zeros((0, 3), np.float32)
        return np.concatenate([np.asarray(lods[leaf][0], np.float32) for leaf in leaves])
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(total, 3))
    start = 0
    for leaf in leaves:
        part = lods[leaf][0]
        out[start:start + part.shape[0]] = part
        start += part.shape[0]
    out.flush()
    del out
    return path


def _run_buckets(workers, source: str | np.ndarray, ends: np.ndarray, buckets: int,
                 cancel: Callable[[], bool] | None) -> list[tuple[np.ndarray, np.ndarray]]:
    """shared_in_bucket of every bucket as tasks on `workers`, in bucket order; BakeCancelled once
    cancel() turns true (checked every POLL_SECONDS while they run)."""
    futures = [workers.submit((0, 0), shared_in_bucket, source, ends, bucket=b, buckets=buckets)
               for b in range(buckets)]
    try:
        waiting = set(futures)
        while waiting:
            _, waiting = cf.wait(waiting, timeout=POLL_SECONDS, return_when=cf.FIRST_COMPLETED)
            if cancel is not None and cancel():
                raise BakeCancelled("bake cancelled")
        return [fut.result() for fut in futures]
    finally:
        for fut in futures:
            fut.cancel()


def _keys(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(k,3) float32 positions as two sort keys: x and y bits (uint64), z bits (uint32)."""
    bits = np.ascontiguousarray(positions, np.float32).view(np.uint32).reshape(-1, 3)
    return (bits[:, 0].astype(np.uint64) << np.uint64(32)) | bits[:, 1].astype(np.uint64), bits[:, 2]


def _bucket_of(xy: np.ndarray, z: np.ndarray, buckets: int) -> np.ndarray:
    """(k,) int64: a hash of each position's bits, mod `buckets` (equal positions, equal buckets)."""
    h = xy * np.uint64(0x9E3779B97F4A7C15) ^ z.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
    return ((h >> np.uint64(29)) % np.uint64(buckets)).astype(np.int64)


def _leaf_ranges(layout: OctreeLayout, leaves: np.ndarray) -> dict[str, np.ndarray]:
    """Each node's depth-first leaf range [leaf_begin, leaf_end): the leaves whose triangles lie in
    its triangle range (leaves in depth-first order have ascending tri_begin)."""
    starts = layout.tri_begin[leaves]
    return {"leaf_begin": np.searchsorted(starts, layout.tri_begin, side="left").astype(np.int64),
            "leaf_end": np.searchsorted(starts, layout.tri_end, side="left").astype(np.int64)}


def node_borders(positions: np.ndarray, faces: np.ndarray, seams: np.ndarray | None, *,
                 position_ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What of a node's welded input (positions (k,3) float32, faces (m,3)) its decimation keeps in
    place, as (k,) bool masks (locked, rim, border):
    - locked: always kept: the vertices at a cell seam (seams (s,3) float32, `CellSeams.locked`;
      None: the node's neighbours are unknown, so every vertex on an open edge) and, with
      position_ids (k,) int64 (vertices split by attributes share one), those on an attribute
      border: an open edge of the split mesh whose positions' edge is not open (a material border
      or UV seam, which must stay closed);
    - rim: the vertices on the models' own open boundaries (edges open by position too) that are
      not locked: kept while the node's budget allows (collapse.py);
    - border: every vertex on an open edge of the split mesh (pymeshlab's boundary preservation
      keeps exactly these)."""
    k = positions.shape[0]
    locked, rim, border = np.zeros(k, bool), np.zeros(k, bool), np.zeros(k, bool)
    if k == 0:
        return locked, rim, border
    open_edges = _open_edges(faces, k)
    border[open_edges.ravel()] = True
    if seams is None:
        locked |= border
    elif seams.shape[0]:
        locked |= _among(positions, seams)
    by_position = np.ones(open_edges.shape[0], bool)
    if position_ids is not None and open_edges.shape[0]:
        by_position = _open_by_position(open_edges, faces, position_ids)
        locked[open_edges[~by_position].ravel()] = True
    rim[open_edges[by_position].ravel()] = True
    return locked, rim & ~locked, border


def _open_by_position(edges: np.ndarray, faces: np.ndarray, position_ids: np.ndarray) -> np.ndarray:
    """(e,) bool: which of the edges (e,2) (vertex ids) only one face has by position too."""
    ids = np.asarray(position_ids, np.int64)
    n = int(ids.max()) + 1
    pairs = np.sort(ids[faces][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    keys, count = np.unique(pairs[:, 0] * n + pairs[:, 1], return_counts=True)
    mine = np.sort(ids[edges], axis=1)
    return count[np.searchsorted(keys, mine[:, 0] * n + mine[:, 1])] == 1


def _open_edges(faces: np.ndarray, k: int) -> np.ndarray:
    """(e,2) int64: the edges of faces (m,3) over k vertices that only one face has, ascending."""
    f = np.asarray(faces, np.int64)
    a, b = f.ravel(), f[:, [1, 2, 0]].ravel()
    keys = np.sort(np.minimum(a, b) * k + np.maximum(a, b))
    single = np.ones(keys.shape[0], bool)
    same = keys[1:] == keys[:-1]
    single[1:] &= ~same
    single[:-1] &= ~same
    keys = keys[single]
    return np.stack([keys // k, keys % k], axis=1)


def _among(positions: np.ndarray, seams: np.ndarray) -> np.ndarray:
    """(k,) bool: which of positions (k,3) float32 are bit-identical to a row of seams (s,3) float32:
    their x and y bits first (one uint64 each, np.isin), then z among the seams of those x and y."""
    xy, z = _keys(positions)
    seam_xy, seam_z = _keys(seams)
    out = np.isin(xy, seam_xy)
    rows = np.flatnonzero(out)
    if rows.size == 0:
        return out
    order = np.lexsort((seam_z, seam_xy))
    seam_xy, seam_z = seam_xy[order], seam_z[order]
    lo = np.searchsorted(seam_xy, xy[rows], side="left")
    hi = np.searchsorted(seam_xy, xy[rows], side="right")
    found = np.zeros(rows.size, bool)
    for offset in range(int((hi - lo).max())):  # seams sharing x and y: almost always one
        at = lo + offset
        found |= (at < hi) & (seam_z[np.minimum(at, seam_z.shape[0] - 1)] == z[rows])
    out[rows] = found
    return out
