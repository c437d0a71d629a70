"""A bake running in a worker thread for the modal Bake operator: progress to poll, cancel to ask for,
the result or the error to collect on the main thread. No bpy here: the operator gathers the mesh
on the main thread first, and Blender data is never touched from the thread.

Cancelling is checked between bake tasks (hlod_core.bake); a cancelled or failed bake writes
nothing (the file is written only at the end, atomically), so an earlier file stays as it was."""
from __future__ import annotations

import logging
import threading
import time

from ..hlod_core import fileformat
from ..hlod_core.bake import BakeSettings, bake
from ..hlod_core.errors import BakeCancelled, HlodError
from ..hlod_core.meshio import TriangleMesh

log = logging.getLogger(__name__)


class BakeJob:
    def __init__(self, mesh: TriangleMesh, settings: BakeSettings, output: str, *, extra_meta: dict | None = None):
        """extra_meta: entries for the file's meta (bake's extra_meta: the UV map's and colour
        attribute's names of a bake from Blender)."""
        self.output = output
        self.progress: tuple[int, int, str] = (0, 1, "octree")
        self.result = None
        self.error: BaseException | None = None
        self.started = time.perf_counter()
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._work, args=(mesh, settings, extra_meta),
                                        name="hlod-bake", daemon=True)
        self._thread.start()

    def _work(self, mesh, settings, extra_meta) -> None:
        try:
            hlod = bake(mesh, settings, progress=self._on_progress, cancel=self._cancel.is_set, extra_meta=extra_meta)
            fileformat.save(hlod, self.output)
            self.result = hlod
        except BaseException as exc:  # noqa: BLE001 - collected by the main thread, which reports it
            if not isinstance(exc, HlodError):  # an unexpected failure: keep its traceback in the log
                log.exception("HLOD bake failed")
            elif not isinstance(exc, BakeCancelled):
                log.error("HLOD bake: %s", exc)
            self.error = exc

    def _on_progress(self, done: int, total: int, phase: str) -> None:
        self.progress = (done, total, phase)

    def cancel(self) -> None:
        self._cancel.set()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    @property
    def percent(self) -> float:
        done, total, _ = self.progress
        return 100.0 * done / total if total else 100.0

    def wait(self, timeout: float | None = None) -> bool:
        self._thread.join(timeout)
        return not self._thread.is_alive()

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.started
