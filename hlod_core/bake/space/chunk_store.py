"""Arrays over every triangle that the bake's early phases (prepare's centroids, the octree's passes)
share with their tasks over index chunks, and how those tasks run: on the bake's workers
(bake/run/workers.py: a local pool or a Dask cluster) or, with jobs 1, in this process.

Data form: named arrays (each one array over the input's triangles or vertices), held as .npy
files in a folder of their own inside the workers' scratch folder, which every worker maps
read-write (np.load mmap_mode "r+"); a task writes only its own chunk's rows, so no two tasks write
the same bytes, and the bake's process reads the results after the tasks are done. Inline (no
workers, or jobs 1: the workers' scratch is ""), the arrays are this process's own.

What moves: a task carries the store's folder (its pickled form), its rows' bounds and the small
tables of its pass (per-cell planes and lookups: at most a few hundred kB); it returns per-key
counts. The triangles themselves move only through the mapped files: on one machine the page
cache, shared by the processes that map them (a local pool; a LocalCluster); on a cluster, the
shared scratch folder the workers already read (dask_cluster.check_scratch).
The folder is removed when the store closes (`open_store`); results the bake keeps are copied out
first (a mapped file cannot be removed on every system while a map is open).
"""
from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from typing import Callable, Iterable

import numpy as np

#: Rows (triangles) per task of a pass: about 8 MB of centroids and 24 MB of the passes' state a task.
TASK_ROWS = 1 << 20
#: Rows from which the tasks go to the workers: a smaller input is one task a pass, which would
#: only add the store's copies and a round trip a pass to an inline bake.
WORKERS_FROM_ROWS = 1 << 17
#: Rows a task has at least when the regions are cut smaller for many workers (`regions`).
MIN_TASK_ROWS = 1 << 16
#: The most bytes a store holds per triangle at once: centroids 24, faces 24, corners (16 a vertex,
#: about 10 a triangle), the octree's tris, cell8, key, node_of, pending and tri_order 48, counted,
#: uncounted 2.
BYTES_PER_ROW = 108


class ChunkStore:
    """The shared arrays of one bake's early phases (module docstring): `folder` ("" inline) and, in
    the process that made them, the arrays by name. Pickled (to a worker) as its folder alone; a
    worker maps a file when a task asks for its array."""

    def __init__(self, folder: str = "", workers=None):
        self.folder = folder
        self.workers = workers
        self.arrays: dict[str, np.ndarray] = {}

    def __getstate__(self) -> dict:
        return {"folder": self.folder, "workers": None, "arrays": {}}

    def __contains__(self, name: str) -> bool:
        return name in self.arrays

    def create(self, name: str, shape: tuple, dtype, *, zeros: bool = False) -> np.ndarray:
        """A new shared array (zeros: every element 0, else undefined until written)."""
        if not self.folder:
            array = (np.zeros if zeros else np.empty)(shape, dtype)
        else:  # a new file reads as zeros until written
            array = np.lib.format.open_memmap(self._path(name), mode="w+", dtype=dtype, shape=shape)
        self.arrays[name] = array
        return array

    def put(self, name: str, values: np.ndarray) -> np.ndarray:
        """`values` as the shared array `name` (inline: itself, with no copy; else written to its
        file in its own memory order, one sequential write, and mapped)."""
        if not self.folder:
            self.arrays[name] = values
            return values
        np.save(self._path(name), values)
        self.arrays[name] = array = np.load(self._path(name), mmap_mode="r+")
        return array

    def get(self, name: str) -> np.ndarray:
        """The array `name`: this process's own, or the file mapped read-write (a worker)."""
        array = self.arrays.get(name)
        if array is None:
            array = np.load(self._path(name), mmap_mode="r+")
        return array

    def drop(self, name: str) -> None:
        """Forget `name` and remove its file (where a map still holds it open, when the store closes)."""
        self.arrays.pop(name, None)
        if self.folder:
            with contextlib.suppress(OSError):
                os.remove(self._path(name))

    def regions(self, rows: int) -> list[tuple[int, int]]:
        """`regions` of `rows` rows for this store's workers."""
        return regions(rows, getattr(self.workers, "limit", 1) if self.folder else 1)

    def run(self, fn: Callable, calls: Iterable[tuple]) -> list:
        """fn(self, *call) for every call, as tasks on the workers (inline: here, in order); their
        results in the calls' order. A task's exception is raised here."""
        calls = list(calls)
        if not self.folder:
            return [fn(self, *call) for call in calls]
        futures = [self.workers.submit((0, 0), fn, self, *call) for call in calls]
        return [future.result() for future in futures]

    def _path(self, name: str) -> str:
        return os.path.join(self.folder, name + ".npy")


@contextlib.contextmanager
def open_store(workers=None, *, rows: int = 0):
    """A ChunkStore for `workers` (bake/run/workers.Workers; None, jobs 1 or fewer than
    WORKERS_FROM_ROWS rows: inline) over `rows` triangles, its folder `hlod-chunks-*` removed
    however the block exits: in the workers' shared memory folder (`Workers.memory`, a local
    pool's) where it has room for BYTES_PER_ROW x rows twice over, else in their scratch folder (a
    Dask cluster's shared one)."""
    on_workers = workers is not None and rows >= WORKERS_FROM_ROWS
    scratch = getattr(workers, "scratch", "") if on_workers else ""
    memory = getattr(workers, "memory", "") if on_workers else ""
    if scratch and memory and _free_bytes(memory) >= 2 * BYTES_PER_ROW * rows:
        scratch = memory
    if not scratch:
        store = ChunkStore()
        try:
            yield store
        finally:
            store.arrays.clear()
        return
    folder = tempfile.mkdtemp(prefix="hlod-chunks-", dir=scratch)
    store = ChunkStore(folder, workers)
    try:
        yield store
    finally:
        store.arrays.clear()
        shutil.rmtree(folder, ignore_errors=True)


def _free_bytes(folder: str) -> int:
    """Bytes free in `folder`'s file system (0 where it cannot be asked)."""
    try:
        stat = os.statvfs(folder)
    except (OSError, AttributeError):  # no statvfs (Windows): no shared memory folder there either
        return 0
    return stat.f_bavail * stat.f_frsize


def regions(rows: int, workers: int = 1) -> list[tuple[int, int]]:
    """(start, end) of each task's rows over `rows` rows: at most TASK_ROWS each, and on `workers`
    workers (the tasks they may hold: Workers.limit) small enough that each has two, but not under
    MIN_TASK_ROWS; the last one shorter; at least one (empty for no rows)."""
    size = min(TASK_ROWS, max(MIN_TASK_ROWS, -(-rows // (2 * max(1, workers)))))
    size = max(1, size)
    return [(start, min(rows, start + size)) for start in range(0, rows, size)] or [(0, 0)]
