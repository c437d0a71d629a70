"""LODs no task reads any more, moved out of the bake's process into a scratch file until the file
is written: the simplify phase spills a node's children once the node is decimated and measured
(schedule.simplify_phase), and assemble reads them back a block of nodes at a time
(bake/assemble.py). What comes back is the same bytes that went in.

Data form: a spilled LOD is a tuple (positions, faces, normals, rows) like an ordinary one, each
entry a `Spilled` (its dtype and shape, read with `load`) or None. The file is unlinked from the
start (tempfile.TemporaryFile in the bake's scratch folder): it is gone when the spill is, however
the bake ends; it holds what the LODs held, about 30 bytes an input triangle.
"""
from __future__ import annotations

import os
import tempfile
import threading

import numpy as np


class Spilled:
    """One array in a spill file: dtype, shape, and where its bytes are."""

    __slots__ = ("spill", "offset", "dtype", "shape")

    def __init__(self, spill: "LodSpill", offset: int, dtype: np.dtype, shape: tuple[int, ...]):
        self.spill, self.offset, self.dtype, self.shape = spill, offset, dtype, shape

    def load(self) -> np.ndarray:
        """The array, read into memory of its own."""
        return self.spill.read(self)


def loaded(array) -> np.ndarray | None:
    """`array` itself (an array or None), or a Spilled one read back."""
    return array.load() if isinstance(array, Spilled) else array


class LodSpill:
    """The spill file of one bake (module docstring), in `folder` (None: the temporary folder)."""

    def __init__(self, folder: str | os.PathLike | None = None):
        self._file = tempfile.TemporaryFile(prefix="hlod-lods-", dir=folder)
        self._end = 0
        self._lock = threading.Lock()
        self.nbytes = 0

    def put(self, lod: tuple) -> tuple:
        """`lod` (positions, faces, normals, rows; arrays or None) written to the file: the same
        tuple of Spilled entries. An entry already spilled, or already in a file (a memory map: an
        out-of-core bake's leaves), stays where it is."""
        return tuple(a if a is None or isinstance(a, (Spilled, np.memmap)) else self._write(np.ascontiguousarray(a))
                     for a in lod)

    def _write(self, array: np.ndarray) -> Spilled:
        with self._lock:
            self._file.seek(self._end)
            self._file.write(array.reshape(-1).view(np.uint8))
            entry = Spilled(self, self._end, array.dtype, array.shape)
            self._end += array.nbytes
            self.nbytes += array.nbytes
        return entry

    def read(self, entry: Spilled) -> np.ndarray:
        out = np.empty(entry.shape, entry.dtype)
        view = out.reshape(-1).view(np.uint8)
        with self._lock:
            self._file.seek(entry.offset)
            got = self._file.readinto(view) if view.size else 0
        if got != view.size:
            raise OSError(f"the bake's LOD spill file ended early ({got} of {view.size} bytes)")
        return out

    def close(self) -> None:
        self._file.close()
