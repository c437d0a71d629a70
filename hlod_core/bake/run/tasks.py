"""What runs on a worker besides the decimation (simplify.decimate_node) and the bound's measure
(hausdorff.measure_to_children): the exact error measure, over the leaves' triangles that every
worker reads from shared, memory-mapped arrays.

Data form: the shared arrays (SHARED_ARRAYS: the leaves' positions (V,3) float32 and
hausdorff.Clusters' arrays over their faces; leaf_arrays.LeafArrays makes them) as .npy files in
a scratch folder every worker reads, or, inline (folder ""), this process's own arrays.

A worker loads a folder's arrays memory-mapped on first use and keeps them for the next tasks.
A Dask worker outlives bakes and may run several tasks at once in threads: one lock guards the
registry, each folder's file identity is recorded when loaded (a folder removed and made again
under the same name is loaded anew), and at most SHARED_FOLDERS bakes' maps are kept.
"""
from __future__ import annotations

import os
import threading

import numpy as np

from ..measure import hausdorff

#: The shared arrays' names: the leaves' positions and the Clusters over their faces.
SHARED_ARRAYS = ("positions", *hausdorff.Clusters.ARRAYS)
#: Bakes whose shared arrays a worker keeps mapped at once (the oldest go first).
SHARED_FOLDERS = 4

_SHARED: dict[str, dict[str, np.ndarray]] = {}  # folder ("" inline) -> its arrays
_SHARED_STAMP: dict[str, tuple] = {}  # folder -> (device, inode, size, mtime) of its first file when loaded
_SHARED_LOCK = threading.Lock()


def share_inline(arrays: dict[str, np.ndarray]) -> None:
    """Make this process's `arrays` (SHARED_ARRAYS) the shared arrays of folder "" (jobs = 1)."""
    with _SHARED_LOCK:
        _SHARED[""] = arrays


def save_shared(folder: str | os.PathLike, arrays: dict[str, np.ndarray]) -> None:
    """Write `arrays` (SHARED_ARRAYS) into `folder` as .npy files, for workers to map."""
    for name, array in arrays.items():
        np.save(os.path.join(folder, name + ".npy"), array)


def shared(folder: str) -> dict[str, np.ndarray]:
    """The shared arrays of `folder` ("" inline), loaded memory-mapped on a worker's first use
    (thread-safe; reloaded when the folder's files are not the ones loaded)."""
    if not folder:
        with _SHARED_LOCK:
            return _SHARED[""]
    first = os.stat(os.path.join(folder, SHARED_ARRAYS[0] + ".npy"))
    stamp = (first.st_dev, first.st_ino, first.st_size, first.st_mtime_ns)
    with _SHARED_LOCK:
        arrays = _SHARED.get(folder)
        if arrays is None or _SHARED_STAMP.get(folder) != stamp:
            arrays = {name: np.load(os.path.join(folder, name + ".npy"), mmap_mode="r") for name in SHARED_ARRAYS}
            _SHARED.pop(folder, None)
            _SHARED[folder], _SHARED_STAMP[folder] = arrays, stamp
            while len(_SHARED) > SHARED_FOLDERS:  # the oldest bake's maps go
                _forget(next(iter(_SHARED)))
    return arrays


def release_shared(folder: str) -> None:
    """Drop `folder`'s arrays (its memory maps close once no task holds them). Runs on every Dask
    worker when a bake ends (dask_cluster.on_cluster), and here when an inline bake ends."""
    with _SHARED_LOCK:
        _forget(folder)


def _forget(folder: str) -> None:
    """release_shared with the lock held."""
    _SHARED.pop(folder, None)
    _SHARED_STAMP.pop(folder, None)


def measure_exact(folder: str, lod: tuple[np.ndarray, np.ndarray], ranges: tuple[int, int, int, int]) -> float:
    """The exact error of a node's LOD (positions (k,3) f32, faces (m,3) int32), model units: its
    original triangles are the leaves' below it, one range of `folder`'s shared arrays: ranges =
    (vertex_begin, vertex_end, cluster_begin, cluster_end) (leaf_arrays.LeafArrays.ranges). Nodes
    with at least hausdorff.PRUNE_FROM_VERTICES original vertices are measured pruned, over their
    clusters (or whole where the clusters show pruning cannot pay); the others whole. Every way
    gives hausdorff.measure's float."""
    arrays = shared(folder)
    vertex_begin, vertex_end, cluster_begin, cluster_end = ranges
    clusters = hausdorff.Clusters(**{name: arrays[name] for name in hausdorff.Clusters.ARRAYS})
    tri_begin, tri_end = int(clusters.start[cluster_begin]), int(clusters.start[cluster_end])

    def original():
        return (np.asarray(arrays["positions"][vertex_begin:vertex_end]),
                (np.asarray(clusters.faces[tri_begin:tri_end]) - vertex_begin).astype(np.int32))

    if vertex_end - vertex_begin >= hausdorff.PRUNE_FROM_VERTICES:
        return hausdorff.measure_clustered(lod, arrays["positions"], clusters, first=cluster_begin, last=cluster_end,
                                           whole=original)
    return hausdorff.measure(lod, original())
