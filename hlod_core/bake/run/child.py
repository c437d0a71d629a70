"""A bake in a child process: `python -m hlod_core.bake.run.child JOB.json`.

The Blender extension gathers the mesh on Blender's main thread, writes it with `write_job` into a
private scratch folder and starts this module in a child process of Blender's own Python, which bakes
with worker processes (`BakeSettings.jobs`) and saves the .hlod atomically. A crash in the bake (a
segfault in pymeshlab, the out-of-memory killer) then ends the child, never Blender.

Data form of a job (one folder, written by `write_job`, read by `read_job`):
- `mesh.npz` (uncompressed): `positions` (v,3) float64, `faces` (f,3) int64, and as present
  `normals` (v,3) float32, `uvs` (v,2) float32, `colors` (v,4) float32, `material_ids` (f,) int32;
- `job.json`: {"version", "mesh" (the npz's name), "name" (the mesh's, for messages and meta),
  "materials" (appearance.Material.to_json rows, textures absolute), "settings" (BakeSettings
  fields), "output" (the .hlod path), "extra_meta", "cache_dir" (the bake's cache folder,
  cache.py; null: no cache), "cache_budget_mb" (its size budget), "frame_from" (an earlier bake's
  frame, frame.Frame.to_meta, to bake in while the input fits it; null: the cache's or the input's),
  "images" (`images.npz`: `image_<row>` (h,w,4) uint8 sRGB RGBA, top row first, the materials'
  texture images the proxy materials are baked from; null: none), "textures" ({"scratch", "final"}:
  the bake's texture folder, where the proxies' textures are written; null: a temporary folder)}.
Both are written atomically (hlod_core.core.atomic), the npz first, so a job.json always names a whole npz.

Protocol: stdout carries JSON lines only, one object per event, flushed at once:
    {"event": "progress", "done": d, "total": t, "phase": p}   one per bake progress update
    {"event": "done", "output", "nodes", "input_tris", "bake_seconds", "jobs",
     "cache": the file's meta["cache"] (inner nodes, reused_nodes, ...) or null without a cache,
     "frame": the file's meta["frame_source"] (where its frame came from, and why)}
    {"event": "error", "type": "InputError" | "FormatError" | "HlodError" | "OSError", "message"}
Everything else (logging, anything a library prints on fd 1) goes to stderr. Exit status: 0 done,
2 a typed error or a failed write (the error event says which), 128 + n for signal n (SIGTERM,
SIGHUP: the bake stops, its worker pool and scratch files go, nothing is written), 1 anything else
(traceback on stderr).

With `--parent-stdin` the parent keeps the child's stdin open and never writes to it: end of file
there means the parent is gone (Blender quit or crashed) or, on Windows, that it cancels the bake
(core.process_tree: Windows has no process groups to signal), and the child then stops itself and
its workers as if cancelled (process_tree.stop_self), and removes the job's files itself. However
the child ends, its workers end with it (process_tree.end_with_self, end_leftovers). Temporary
files of the bake (`hlod-bake-*`) go where TMPDIR says: the extension points it into its private
folder, which it removes whatever happens to the child.
"""
from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import sys
import threading
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from ...core import heap, process_tree
from ...core.atomic import atomic_file, write_text_atomic
from ...core.errors import FormatError, HlodError, InputError
from ...core.signals import Terminated, signals_as_exceptions
from ...io import hlod_file, meshes
from ...model.appearance import materials_from_json
from ..pipeline import bake
from ..settings import BakeSettings
from ..space.frame import Frame
from .cache import DEFAULT_BUDGET_MB

log = logging.getLogger("hlod_core")

JOB_VERSION = 1
JOB_FILE, MESH_FILE, IMAGES_FILE = "job.json", "mesh.npz", "images.npz"
MODULE = "hlod_core.bake.run.child"  # what `python -m` runs
PARENT_STDIN = "--parent-stdin"  # the option saying stdin is the parent's pipe (module notes)
#: Optional per-vertex / per-face arrays of a TriangleMesh carried in the npz when present.
OPTIONAL_ARRAYS = ("normals", "uvs", "colors", "material_ids")
#: Typed errors the error event may name (re-raised by that type in the parent).
ERROR_TYPES = {cls.__name__: cls for cls in (InputError, FormatError, HlodError)}


# --- the job files (written by the parent, read here) -------------------------------------------

def write_job(folder: str | os.PathLike, mesh: meshes.TriangleMesh, settings: BakeSettings, *,
              output: str | os.PathLike, extra_meta: dict | None = None,
              cache_dir: str | os.PathLike | None = None, cache_budget_mb: float = DEFAULT_BUDGET_MB,
              frame_from: Frame | None = None, images: dict | None = None, textures=None) -> Path:
    """Write `mesh` and what to do with it into `folder` (module notes); returns the job.json path.
    images: material row -> its texture image, (h,w,4) uint8 sRGB RGBA, top row first (what the proxy
    materials are baked from; `images.npz`); textures: the bake's texture folder (its `scratch` and
    `final` paths: io.texture_folder.EmbeddedTextures), where the proxies' textures go."""
    folder = Path(folder)
    arrays = {"positions": np.ascontiguousarray(mesh.positions, np.float64),
              "faces": np.ascontiguousarray(mesh.faces, np.int64)}
    arrays.update({name: np.ascontiguousarray(getattr(mesh, name)) for name in OPTIONAL_ARRAYS
                   if getattr(mesh, name) is not None})
    if images:
        with atomic_file(folder / IMAGES_FILE) as f:
            np.savez(f, **{f"image_{int(row)}": np.ascontiguousarray(image, np.uint8) for row, image in images.items()})
    with atomic_file(folder / MESH_FILE) as f:
        np.savez(f, **arrays)
    job = {"version": JOB_VERSION, "mesh": MESH_FILE, "name": mesh.name,
           "materials": [m.to_json() for m in mesh.materials], "settings": asdict(settings),
           "output": os.fspath(Path(output).absolute()), "extra_meta": extra_meta or {},
           "cache_dir": None if cache_dir is None else os.fspath(cache_dir), "cache_budget_mb": float(cache_budget_mb),
           "frame_from": None if frame_from is None else frame_from.to_meta(),
           "images": IMAGES_FILE if images else None,
           "textures": None if textures is None else {"scratch": os.fspath(Path(textures.scratch).absolute()),
                                                      "final": os.fspath(Path(textures.final).absolute())}}
    return write_text_atomic(folder / JOB_FILE, json.dumps(job))


def read_job(path: str | os.PathLike) -> tuple[meshes.TriangleMesh, BakeSettings, dict]:
    """(mesh, settings, job dict) of a job.json written by `write_job`; InputError naming the file."""
    path = Path(path)
    try:
        job = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the bake job ({exc})") from exc
    if not isinstance(job, dict) or job.get("version") != JOB_VERSION:
        raise InputError(f"{path}: not a bake job of version {JOB_VERSION}")
    known = {f.name for f in fields(BakeSettings)}
    settings = BakeSettings(**{k: v for k, v in job["settings"].items() if k in known})
    with np.load(path.parent / job["mesh"], allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    materials = materials_from_json(job["materials"], where=f"{path}: materials") if job["materials"] else ()
    mesh = meshes.from_arrays(arrays["positions"], arrays["faces"], arrays.get("normals"), name=job["name"],
                              uvs=arrays.get("uvs"), colors=arrays.get("colors"),
                              material_ids=arrays.get("material_ids"), materials=materials)
    return mesh, settings, job


def job_images(path: str | os.PathLike, job: dict) -> tuple[dict, JobTextures | None]:
    """The job's texture images (material row -> image) and texture folder (None: none given)."""
    images = {}
    if job.get("images"):
        with np.load(Path(path).parent / job["images"], allow_pickle=False) as npz:
            images = {int(name.split("_", 1)[1]): npz[name] for name in npz.files}
    folder = job.get("textures")
    return images, None if folder is None else JobTextures(scratch=Path(folder["scratch"]), final=Path(folder["final"]))


@dataclass(frozen=True)
class JobTextures:
    """The bake's texture folder as a job names it: where its files are written and what names them."""

    scratch: Path
    final: Path


# --- the child ----------------------------------------------------------------------------------

_parent_gone = threading.Event()


def _stop_when_parent_goes() -> None:
    """Block on stdin until end of file (the parent closed it or died), then stop the process group
    (module notes). Runs in a daemon thread."""
    with contextlib.suppress(OSError):
        while os.read(0, 65536):  # the raw descriptor: a buffered sys.stdin's lock would stall shutdown
            pass
    _parent_gone.set()
    log.error("the parent process is gone or asks the bake to stop; stopping the bake")
    process_tree.stop_self()  # POSIX: SIGTERM to its group, workers too; Windows: Terminated in the main thread


class _Events:
    """The protocol stream: JSON lines on the original stdout (fd 1 is pointed at stderr)."""

    def __init__(self):
        self._stream = os.fdopen(os.dup(1), "w", encoding="utf-8", buffering=1)
        os.dup2(2, 1)  # whatever else writes to stdout (C libraries, print) lands on stderr
        sys.stdout = sys.stderr
        self._lock = threading.Lock()

    def send(self, event: str, **data) -> None:
        """Write one event; once the parent has gone (a broken pipe) events are dropped."""
        with self._lock, contextlib.suppress(BrokenPipeError):
            self._stream.write(json.dumps({"event": event, **data}) + "\n")
            self._stream.flush()


def run(job_path: str, events: _Events) -> int:
    """Bake the job and save its output; the events say how it went (module notes)."""
    heap.return_freed_buffers()
    try:
        mesh, settings, job = read_job(job_path)
        started = time.perf_counter()
        frame_from = None if job.get("frame_from") is None else Frame.from_meta(job["frame_from"], where=job_path)
        images, textures = job_images(job_path, job)
        hlod = bake(mesh, settings, extra_meta=job["extra_meta"] or None, cache_dir=job["cache_dir"],
                    cache_budget_mb=job.get("cache_budget_mb", DEFAULT_BUDGET_MB), frame_from=frame_from,
                    images=images, textures=textures,
                    progress=lambda done, total, phase: events.send("progress", done=done, total=total, phase=phase))
        hlod_file.save(hlod, job["output"])
        log.info("saved %s (%d nodes) in %.2f s", job["output"], hlod.node_count, time.perf_counter() - started)
    except HlodError as exc:
        name = type(exc).__name__ if type(exc).__name__ in ERROR_TYPES else "HlodError"
        events.send("error", type=name, message=str(exc))
        return 2
    except OSError as exc:
        where = exc.filename or "the output"
        events.send("error", type="OSError", message=f"{where}: {exc.strerror or exc}")
        return 2
    meta = hlod.meta
    events.send("done", output=job["output"], nodes=hlod.node_count, input_tris=int(meta.get("input_tris", 0)),
                bake_seconds=float(meta.get("bake_seconds", 0.0)), jobs=settings.jobs, cache=meta.get("cache"),
                frame=meta.get("frame_source"))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    watch_parent = PARENT_STDIN in argv
    argv = [a for a in argv if a != PARENT_STDIN]
    if len(argv) != 1:
        print(f"usage: python -m {MODULE} JOB.json [{PARENT_STDIN}]", file=sys.stderr)
        return 2
    events = _Events()
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="hlod_core: %(message)s")
    parent = os.getppid()
    try:  # before any worker starts: on Windows its workers then end with it however it ends
        process_tree.end_with_self()
    except OSError as exc:
        log.warning("the bake's workers may outlive this process if it dies (%s)", exc)
    try:
        with signals_as_exceptions():
            if watch_parent:
                threading.Thread(target=_stop_when_parent_goes, name="hlod-parent-watch", daemon=True).start()
            return run(argv[0], events)
    except Terminated as exc:
        with contextlib.suppress(OSError):  # stderr is a broken pipe when the parent has gone
            print(f"hlod_core: bake stopped by {signal.Signals(exc.signum).name}", file=sys.stderr)
        return 128 + exc.signum
    finally:
        if watch_parent and (_parent_gone.is_set() or os.getppid() != parent):
            _remove_job(Path(argv[0]))  # nobody else will remove the job's files now


def _remove_job(job_path: Path) -> None:
    """Remove what write_job wrote, and its folder if that leaves it empty."""
    for name in (MESH_FILE, JOB_FILE):
        with contextlib.suppress(OSError):
            (job_path.parent / name).unlink()
    with contextlib.suppress(OSError):
        job_path.parent.rmdir()


if __name__ == "__main__":
    sys.exit(main())
