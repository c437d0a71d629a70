"""The leaves' triangles as the exact error measure reads them (tasks.measure_exact): every leaf's
vertices and faces concatenated in depth-first order, cut into hausdorff.Clusters once per bake
(on the bake's workers, runs of whole leaves a task: `cut_clusters`), and each node's ranges into
them.

Data form: positions (V,3) float32, faces (F,3) int32 (int64 from 2**31 vertices) rows into them,
in memory or (an out-of-core bake) memory-mapped .npy files in a scratch folder.
"""
from __future__ import annotations

import concurrent.futures as cf
import dataclasses
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...core.errors import BakeCancelled
from ..space.octree import OctreeLayout
from . import hausdorff

#: Faces from which the clusters are cut as tasks on the bake's workers, where there are several.
PARALLEL_FROM_FACES = 1 << 19
#: Faces a cluster task cuts at least (whole leaves: about that many).
TASK_FACES = 1 << 17
#: How often (seconds) `cut_clusters` wakes while its tasks run, to check cancel().
POLL_SECONDS = 0.25


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

    def ranges_only(self) -> "LeafArrays":
        """These ranges without the arrays (positions and clusters None): what the bake's process
        keeps once the workers read the arrays from their scratch folder."""
        return dataclasses.replace(self, positions=None, clusters=None)

    def ranges(self, node: int) -> tuple[int, int, int, int]:
        """(vertex_begin, vertex_end, cluster_begin, cluster_end) of `node` (tasks.measure_exact)."""
        return (int(self.vertex_begin[node]), int(self.vertex_end[node]), int(self.cluster_begin[node]),
                int(self.cluster_end[node]))


def build(layout: OctreeLayout, lods: list, *, folder: str | os.PathLike | None = None,
          workers=None, cancel: Callable[[], bool] | None = None) -> LeafArrays:
    """LeafArrays of the bake's leaves (lods[leaf] = (positions, local faces, ...)). folder: the
    leaves' positions and faces are concatenated into memory-mapped files there (an out-of-core
    bake: `concat_mapped`) instead of this process's memory; the same arrays either way. workers
    (workers.Workers) and cancel: where the clusters are cut, and when to stop (`cut_clusters`)."""
    leaves = np.flatnonzero(layout.is_leaf)
    leaves = leaves[np.argsort(layout.tri_begin[leaves], kind="stable")]  # depth-first
    positions, faces = concat_mapped([lods[leaf] for leaf in leaves], folder)
    counts = np.array([lods[leaf][0].shape[0] for leaf in leaves], np.int64)
    segments = np.concatenate([[0], np.cumsum([lods[leaf][1].shape[0] for leaf in leaves])]).astype(np.int64)
    ends = np.cumsum(counts)
    clusters = cut_clusters(positions, faces, segments, vertex_start=ends - counts, workers=workers, cancel=cancel)
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


def cut_clusters(positions: np.ndarray, faces: np.ndarray, segments: np.ndarray, *, vertex_start: np.ndarray,
                 workers=None, cancel: Callable[[], bool] | None = None) -> hausdorff.Clusters:
    """hausdorff.Clusters.build(positions, faces, segments) of the leaves (segments (S+1,): each
    leaf's faces; vertex_start (S,) int64: each leaf's first vertex, its faces using its own
    vertices only). On `workers` (workers.Workers) where there are several and at least
    PARALLEL_FROM_FACES faces: runs of whole leaves of about TASK_FACES faces or more, one task each
    (their vertices and faces sent with it), the results put together; the same arrays, since a
    cluster never crosses a leaf and the faces' order within a leaf is a stable sort's. cancel:
    checked while the tasks run."""
    count = faces.shape[0]
    if workers is None or workers.limit < 2 or count < PARALLEL_FROM_FACES:
        return hausdorff.Clusters.build(positions, faces, segments)
    pieces = int(min(max(2, count // TASK_FACES), 4 * workers.limit))
    cuts = np.unique(np.searchsorted(segments, np.linspace(0, count, pieces + 1)[1:-1]))
    bounds = np.concatenate([[0], cuts[(cuts > 0) & (cuts < segments.size - 1)], [segments.size - 1]])
    vertex_end = np.append(vertex_start[1:], positions.shape[0])
    index_type = np.int32 if positions.shape[0] < 2**31 else np.int64
    v0 = vertex_start[bounds[:-1]].astype(np.int64)
    f0 = segments[bounds[:-1]].astype(np.int64)
    out_faces = np.empty((count, 3), index_type)  # each part's faces shifted in place, no int64 copy of them all

    def submit(i: int) -> cf.Future:
        first, last = bounds[i], bounds[i + 1]
        v1, f1 = int(vertex_end[last - 1]), int(segments[last])
        part = np.array(faces[f0[i]:f1])  # the faces' own index type: Clusters.build stores that type either way
        part -= part.dtype.type(v0[i])
        return workers.submit((0, 0), hausdorff.Clusters.build, np.asarray(positions[v0[i]:v1]), part,
                              segments[first:last + 1] - f0[i])

    # at most workers.limit pieces in flight, each one's faces copied out as it comes back: the
    # process holds a few pieces' faces, not every piece's sent and returned copies at once
    parts: list = [None] * (bounds.size - 1)
    running: dict[cf.Future, int] = {}
    queued = iter(range(bounds.size - 1))
    for i in queued:
        running[submit(i)] = i
        if len(running) >= workers.limit:
            break
    while running:
        finished, _ = cf.wait(running, timeout=POLL_SECONDS, return_when=cf.FIRST_COMPLETED)
        if cancel is not None and cancel():
            raise BakeCancelled("bake cancelled")
        for fut in finished:
            i = running.pop(fut)
            p = fut.result()
            rows = out_faces[f0[i]:f0[i] + p.faces.shape[0]]
            rows[:] = p.faces
            rows += index_type(v0[i])
            parts[i] = dataclasses.replace(p, faces=None)
            following = next(queued, None)
            if following is not None:
                running[submit(following)] = following
    k0 = np.concatenate([[0], np.cumsum([p.radius.size for p in parts])])
    return hausdorff.Clusters(
        faces=out_faces,
        start=np.concatenate([p.start[:-1] + f for p, f in zip(parts, f0)] + [[count]]).astype(np.int64),
        first_cluster=np.concatenate([p.first_cluster[:-1] + k for p, k in zip(parts, k0)] + [[k0[-1]]]).astype(
            np.int64),
        box_min=np.concatenate([p.box_min for p in parts]), box_max=np.concatenate([p.box_max for p in parts]),
        centre=np.concatenate([p.centre for p in parts]), radius=np.concatenate([p.radius for p in parts]),
        surface_vertex=np.concatenate([p.surface_vertex + v for p, v in zip(parts, v0)]).astype(np.int64))


def concat_mapped(parts: list[tuple], folder: str | os.PathLike | None) -> tuple[np.ndarray, np.ndarray]:
    """concat_indexed of (positions (k,3) f32, faces (m,3)) parts, written part by part into
    memory-mapped .npy files in `folder` (None: arrays in memory): positions (V,3) float32, faces
    (F,3) int32 (int64 from 2**31 vertices), the values concat_indexed gives (Clusters.build stores
    them as this dtype), with no int64 copy of every face on the way."""
    vertex_count = sum(part[0].shape[0] for part in parts)
    face_count = sum(part[1].shape[0] for part in parts)
    index_type = np.int32 if vertex_count < 2**31 else np.int64
    if folder is None:
        positions, faces = np.empty((vertex_count, 3), np.float32), np.empty((face_count, 3), index_type)
    else:
        positions = np.lib.format.open_memmap(os.path.join(folder, "leaf-positions.npy"), mode="w+",
                                              dtype=np.float32, shape=(vertex_count, 3))
        faces = np.lib.format.open_memmap(os.path.join(folder, "leaf-faces.npy"), mode="w+", dtype=index_type,
                                          shape=(face_count, 3))
    v = f = 0
    for part in parts:
        k, m = part[0].shape[0], part[1].shape[0]
        positions[v:v + k] = part[0]
        faces[f:f + m] = np.asarray(part[1], index_type) + index_type(v)
        v, f = v + k, f + m
    return positions, faces
