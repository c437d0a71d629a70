"""The leaves' triangles as the exact error measure reads them (tasks.measure_exact): every leaf's
vertices and faces concatenated in depth-first order, cut into hausdorff.Clusters once per bake,
and each node's ranges into them.

Data form: positions (V,3) float32, faces (F,3) int32 (int64 from 2**31 vertices) rows into them,
in memory or (an out-of-core bake) memory-mapped .npy files in a scratch folder.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..core.arrays import concat_indexed
from . import hausdorff
from .octree import OctreeLayout


@dataclass(frozen=True, eq=False)
class LeafArrays:
    """positions (V,3) f32, the leaves' vertices concatenated in depth-first order; clusters
    (hausdorff.Clusters) over their faces, in tri_order with each leaf's faces reordered into
    clusters (a leaf's face set is unchanged, so a node's triangles are still rows
    tri_begin..tri_end); per node (n,) int64 its vertex range and cluster range."""

    positions: np.ndarray
    clusters: hausdorff.Clusters
    vertex_begin: np.ndarray
    vertex_end: np.ndarray
    cluster_begin: np.ndarray
    cluster_end: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays workers share (tasks.SHARED_ARRAYS)."""
        return {"positions": self.positions, **self.clusters.arrays()}

    def ranges(self, node: int) -> tuple[int, int, int, int]:
        """(vertex_begin, vertex_end, cluster_begin, cluster_end) of `node` (tasks.measure_exact)."""
        return (int(self.vertex_begin[node]), int(self.vertex_end[node]), int(self.cluster_begin[node]),
                int(self.cluster_end[node]))


def build(layout: OctreeLayout, lods: list, *, folder: str | os.PathLike | None = None) -> LeafArrays:
    """LeafArrays of the bake's leaves (lods[leaf] = (positions, local faces, ...)). folder: the
    leaves' positions and faces are concatenated into memory-mapped files there (an out-of-core
    bake: `concat_mapped`) instead of this process's memory; the same arrays either way."""
    leaves = np.flatnonzero(layout.is_leaf)
    leaves = leaves[np.argsort(layout.tri_begin[leaves], kind="stable")]  # depth-first
    if folder is None:
        positions, faces = concat_indexed((lods[leaf][0], lods[leaf][1]) for leaf in leaves)
    else:
        positions, faces = concat_mapped([lods[leaf] for leaf in leaves], folder)
    counts = np.array([lods[leaf][0].shape[0] for leaf in leaves], np.int64)
    segments = np.concatenate([[0], np.cumsum([lods[leaf][1].shape[0] for leaf in leaves])]).astype(np.int64)
    clusters = hausdorff.Clusters.build(positions, faces, segments)
    ends = np.cumsum(counts)
    n = layout.node_count
    ranges = np.zeros((4, n), np.int64)  # vertex begin, end; cluster begin, end
    ranges[0, leaves], ranges[1, leaves] = ends - counts, ends
    ranges[2, leaves], ranges[3, leaves] = clusters.first_cluster[:-1], clusters.first_cluster[1:]
    for d in range(int(layout.depth.max()), -1, -1):  # deepest first: children before their parent
        nodes = np.flatnonzero((layout.depth == d) & ~layout.is_leaf)
        first, last = layout.child_offset[nodes], layout.child_offset[nodes] + layout.child_count[nodes] - 1
        ranges[0, nodes], ranges[2, nodes] = ranges[0, first], ranges[2, first]
        ranges[1, nodes], ranges[3, nodes] = ranges[1, last], ranges[3, last]
    return LeafArrays(positions=positions, clusters=clusters, vertex_begin=ranges[0], vertex_end=ranges[1],
                      cluster_begin=ranges[2], cluster_end=ranges[3])


def concat_mapped(parts: list[tuple], folder: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """concat_indexed of (positions (k,3) f32, faces (m,3)) parts, written part by part into
    memory-mapped .npy files in `folder`: positions (V,3) float32, faces (F,3) int32 (int64 from
    2**31 vertices), the values concat_indexed gives (Clusters.build stores them as this dtype)."""
    vertex_count = sum(part[0].shape[0] for part in parts)
    face_count = sum(part[1].shape[0] for part in parts)
    index_type = np.int32 if vertex_count < 2**31 else np.int64
    positions = np.lib.format.open_memmap(os.path.join(folder, "leaf-positions.npy"), mode="w+", dtype=np.float32,
                                          shape=(vertex_count, 3))
    faces = np.lib.format.open_memmap(os.path.join(folder, "leaf-faces.npy"), mode="w+", dtype=index_type,
                                      shape=(face_count, 3))
    v = f = 0
    for part in parts:
        k, m = part[0].shape[0], part[1].shape[0]
        positions[v:v + k] = part[0]
        faces[f:f + m] = np.asarray(part[1], index_type) + index_type(v)
        v, f = v + k, f + m
    return positions, faces
