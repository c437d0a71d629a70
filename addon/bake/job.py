"""A bake in a child process, for the Bake operator (modal or not) and the background command
(bake/from_scene.py). Imports no Blender module: the caller gathers the mesh on Blender's main
thread first.

`BakeJob` writes the mesh into a private scratch folder (`hlod-blender-*` in the temp folder;
hlod_core/bake/run/child.py says what is in it), then runs `python -m hlod_core.bake.run.child` with
Blender's own Python, which bakes with `settings.jobs` worker processes, started as the root of
a process tree that can be stopped on every platform (hlod_core.core.process_tree: its own process
group on POSIX; a new process group without a console on Windows, where stdin is the stop).

State, read from the main thread: `progress` (done, total, phase), from the child's progress lines
(read by a thread, never blocking the caller); once `running` is false, `result` (a BakeResult) or
`error`: BakeCancelled after `cancel()`, the core's typed error (InputError, ...) the child
reported, or BakeProcessError for a child that died (killed, crashed, out of memory) with its exit
signal or status and the last lines it wrote on stderr.

`cancel()` asks the child and its workers to stop (process_tree.ask_to_stop: SIGTERM to the group,
or on Windows its stdin closed), and kills the tree after STOP_GRACE_SECONDS (kill_tree: SIGKILL to
the group, or taskkill /T /F). Whatever ends the child, what is left of its tree
(process_tree.end_leftovers; on Windows the child's job object has ended it), the scratch folder
(core.atomic.remove_tree: retried on Windows while a dying worker still maps its files) and the
temporary files of its atomic write go before the job reports itself finished: an earlier .hlod
stays as it was unless the child renamed a complete new one over it. A scratch folder that cannot
be removed is named (`scratch_left`, and the result's), marked (LEFTOVER_MARK) and removed by the
next job (`sweep_leftovers`). If Blender dies, the child stops itself (its stdin closes).
Why: docs/how-it-works.md#the-bakes-child-process-and-its-cleanup
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import importlib.util
import json
import logging
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from ...hlod_core.bake.run import child
from ...hlod_core.bake.settings import BakeSettings
from ...hlod_core.core import atomic, process_tree
from ...hlod_core.core.errors import BakeCancelled, HlodError
from ...hlod_core.io.meshes import TriangleMesh

log = logging.getLogger(__name__)

#: The folder holding this extension's packages: the one hlod_core is in (hlod_core/bake/run/child.py).
EXTENSION_DIR = Path(child.__file__).resolve().parents[3]
#: Modules the bake imports besides hlod_core and the standard library: their folders go on the
#: child's path (in Blender, pymeshlab comes from the extension's wheels, numpy with Blender).
CHILD_MODULES = ("pymeshlab", "numpy")
SCRATCH_PREFIX = "hlod-blender-"
#: The file a job leaves in a scratch folder it could not remove: the next job removes the folder.
LEFTOVER_MARK = "hlod-leftover"
#: Between asking the child's tree to stop and killing it after a cancel.
STOP_GRACE_SECONDS = 0.5
#: How often the watcher looks at the child (and the cancel deadline).
POLL_SECONDS = 0.02
#: stderr lines kept, and how many of them an error message quotes.
STDERR_TAIL_LINES, REPORTED_TAIL_LINES = 40, 6

_active: list["BakeJob"] = []  # running jobs, for the panel


class BakeProcessError(HlodError):
    """The bake's child process ended without a result: killed, crashed, or out of memory."""


@dataclass(frozen=True)
class BakeResult:
    """What a finished child reported: output path, node count, input triangles, the bake's own
    seconds (bake() alone, in the child), worker processes, and the cache's statistics of the
    bake (None without a cache); scratch_left: the job's scratch folder when it could not be
    removed (BakeJob.scratch_left), else None."""

    output: str
    node_count: int
    input_tris: int
    bake_seconds: float
    jobs: int
    cache: dict | None = None
    scratch_left: str | None = None


def child_path() -> list[str]:
    """The child's PYTHONPATH: this extension's folder, then the folder each of CHILD_MODULES
    imports from here (for pymeshlab: where Blender installed the extension's wheels)."""
    folders = [str(EXTENSION_DIR)]
    for name in CHILD_MODULES:
        spec = importlib.util.find_spec(name)
        if spec is None:
            raise BakeProcessError(f"HLOD bake: {name} does not import in Blender's Python; reinstall the extension")
        where = Path(spec.submodule_search_locations[0] if spec.submodule_search_locations else spec.origin)
        folder = str(where.parent)
        if folder not in folders:
            folders.append(folder)
    return folders


def child_environment(scratch: str) -> dict[str, str]:
    """Blender's environment without Python's own variables (PYTHONHOME, a user's PYTHONPATH...),
    with the child's path, no user site-packages, and the temp folder inside `scratch`."""
    env = {k: v for k, v in os.environ.items() if not k.upper().startswith("PYTHON")}
    env.update(PYTHONPATH=os.pathsep.join(child_path()), PYTHONNOUSERSITE="1", PYTHONIOENCODING="utf-8",
               TMPDIR=scratch, TMP=scratch, TEMP=scratch)
    return env


class BakeJob:
    def __init__(self, mesh: TriangleMesh, settings: BakeSettings, output: str | os.PathLike, *,
                 extra_meta: dict | None = None, cache_dir: str | os.PathLike | None = None,
                 job_options: dict | None = None):
        """Start the bake of `mesh` into `output` (module notes). extra_meta: entries for the file's
        meta (the UV map's and colour attribute's names of a bake from Blender); cache_dir: the
        bake's cache folder (None: no cache); job_options: more of child.write_job's keywords
        (cache_budget_mb, frame_from)."""
        self.output = os.path.abspath(output)
        self.progress: tuple[int, int, str] = (0, 1, "starting")
        self.result: BakeResult | None = None
        self.error: BaseException | None = None
        self.jobs = settings.jobs
        self.started = time.perf_counter()
        self.stderr_tail: collections.deque[str] = collections.deque(maxlen=STDERR_TAIL_LINES)
        self.scratch_left: str | None = None  # set when the job could not remove its scratch folder
        self._events: dict[str, dict] = {}
        self._lock = threading.Lock()
        self._stop_at: float | None = None  # monotonic time of cancel()
        self._killed = False
        self._reaped = False
        self._finished = threading.Event()
        self._temp_before = self._output_temps()
        sweep_leftovers()
        self._scratch = tempfile.mkdtemp(prefix=SCRATCH_PREFIX)
        try:
            job_file = child.write_job(self._scratch, mesh, settings, output=self.output, extra_meta=extra_meta,
                                            cache_dir=cache_dir, **(job_options or {}))
            self._proc = subprocess.Popen(
                [sys.executable, "-m", child.MODULE, str(job_file), child.PARENT_STDIN],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=self._scratch,
                env=child_environment(self._scratch), **process_tree.child_options())
        except BaseException:
            shutil.rmtree(self._scratch, ignore_errors=True)
            raise
        self.pid = self._proc.pid
        self._readers = [threading.Thread(target=self._read_events, name="hlod-bake-events", daemon=True),
                         threading.Thread(target=self._read_stderr, name="hlod-bake-stderr", daemon=True)]
        for reader in self._readers:
            reader.start()
        _active.append(self)
        self._watcher = threading.Thread(target=self._watch, name="hlod-bake-watch", daemon=True)
        self._watcher.start()

    # --- the caller's side --------------------------------------------------------------------

    def cancel(self) -> None:
        """Stop the bake: the child's tree asked to stop now, killed after the grace (module notes)."""
        with self._lock:
            if self._stop_at is None and not self._reaped:
                self._stop_at = time.monotonic()
                process_tree.ask_to_stop(self._proc)

    @property
    def cancelled(self) -> bool:
        """Whether cancel() was called."""
        return self._stop_at is not None

    @property
    def running(self) -> bool:
        return not self._finished.is_set()

    @property
    def percent(self) -> float:
        done, total, _ = self.progress
        return 100.0 * done / total if total else 100.0

    def wait(self, timeout: float | None = None) -> bool:
        """Wait until the job has finished (child gone, scratch removed); whether it has."""
        return self._finished.wait(timeout)

    def join(self) -> None:
        """Wait for the end; Ctrl-C (KeyboardInterrupt) cancels the bake, waits for it, and is raised."""
        try:
            while not self._finished.wait(0.1):
                pass
        except KeyboardInterrupt:
            self.cancel()
            self._finished.wait()
            raise

    @property
    def seconds(self) -> float:
        return time.perf_counter() - self.started

    def status_line(self) -> str:
        done, total, phase = self.progress
        jobs = f"{self.jobs} job{'s' if self.jobs > 1 else ''}"
        return f"HLOD bake ({jobs}): {phase} {done}/{total} nodes ({self.percent:.0f}%)"

    # --- threads ------------------------------------------------------------------------------

    def _read_events(self) -> None:
        for raw in self._proc.stdout:
            line = raw.decode("utf-8", "replace").strip()
            try:
                event = json.loads(line)
                kind = event["event"]
            except (ValueError, TypeError, KeyError):
                self.stderr_tail.append(line)  # not the protocol: keep it with the messages
                continue
            if kind == "progress":
                self.progress = (int(event["done"]), int(event["total"]), str(event["phase"]))
            else:
                self._events[kind] = event

    def _read_stderr(self) -> None:
        for raw in self._proc.stderr:
            line = raw.decode("utf-8", "replace").rstrip()
            if line:
                self.stderr_tail.append(line)
                log.debug("bake child: %s", line)

    def _watch(self) -> None:
        try:
            returncode = self._wait_child()
            for reader in self._readers:
                reader.join(timeout=2.0)
            self._collect(returncode)
        except BaseException as exc:  # reported through `error`, never lost in a thread
            log.exception("HLOD bake watcher failed")
            self.error = self.error or exc
        finally:
            self._clean_up()
            if self in _active:
                _active.remove(self)
            self._finished.set()

    def _wait_child(self) -> int:
        """Wait for the child to end, escalating a cancel to a kill of its tree after the grace;
        then end what is left of its tree (orphaned workers: process_tree.end_leftovers) while the
        child's pid still names it (POSIX: the child is not reaped yet, `_exited`), and reap it."""
        while not self._exited():
            time.sleep(POLL_SECONDS)
            stop_at = self._stop_at
            if stop_at is not None and not self._killed and time.monotonic() - stop_at >= STOP_GRACE_SECONDS:
                with self._lock:
                    process_tree.kill_tree(self.pid)
                    self._killed = True
        with self._lock:
            process_tree.end_leftovers(self.pid)
            returncode = self._proc.wait()
            self._reaped = True
        self._proc.stdin.close()
        return returncode

    def _exited(self) -> bool:
        """Whether the child has ended. POSIX: without reaping it (waitid WNOWAIT), so that its pid
        keeps naming its process group until the group is killed."""
        if hasattr(os, "waitid") and hasattr(os, "WNOWAIT"):
            try:
                return os.waitid(os.P_PID, self.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
            except ChildProcessError:
                return True
        return self._proc.poll() is not None

    def _collect(self, returncode: int) -> None:
        done, failed = self._events.get("done"), self._events.get("error")
        if returncode == 0 and done is not None:
            self.result = BakeResult(output=done["output"], node_count=int(done["nodes"]),
                                     input_tris=int(done["input_tris"]), bake_seconds=float(done["bake_seconds"]),
                                     jobs=int(done["jobs"]), cache=done.get("cache"))
            self.progress = (self.progress[1], self.progress[1], "done")
        elif failed is not None:
            kind = child.ERROR_TYPES.get(failed["type"], HlodError)
            self.error = kind(failed["message"]) if failed["type"] != "OSError" else HlodError(
                f"HLOD bake: cannot write {failed['message']}")
        elif self._stop_at is not None:
            self.error = BakeCancelled("bake cancelled")
        else:
            self.error = BakeProcessError(self._death_message(returncode))
            log.error("%s", self.error)

    def _death_message(self, returncode: int) -> str:
        if returncode < 0:
            try:
                name = signal.Signals(-returncode).name
            except ValueError:
                name = "?"
            how = f"was killed by signal {name} ({-returncode})"
            if -returncode == getattr(signal, "SIGKILL", None):
                how += ": out of memory, or killed from outside"
        else:
            how = f"exited with status {returncode}"
        tail = [line for line in self.stderr_tail if line][-REPORTED_TAIL_LINES:]
        return (f"HLOD bake: the bake process (pid {self.pid}) {how}; nothing was written. Its last messages: "
                + (" | ".join(tail) if tail else "(none)"))

    def _clean_up(self) -> None:
        """Remove the scratch folder (the child's temporary files with it; atomic.remove_tree) and
        temporary files of the child's atomic write beside the output that were not there before
        the job. A scratch folder that stays is named (`scratch_left`, the result's, the log) and
        marked for the next job (LEFTOVER_MARK)."""
        if not atomic.remove_tree(self._scratch):
            self.scratch_left = self._scratch
            with contextlib.suppress(OSError):
                Path(self._scratch, LEFTOVER_MARK).touch()
            if self.result is not None:
                self.result = dataclasses.replace(self.result, scratch_left=self._scratch)
            log.warning("HLOD bake: %s: scratch folder not removed (a file in it is still held); the next bake "
                        "removes it", self._scratch)
        for leftover in self._output_temps() - self._temp_before:
            try:
                os.unlink(leftover)
            except OSError:
                pass

    def _output_temps(self) -> set[str]:
        """Temporary files of an atomic write to the output (hlod_core.core.atomic names them .NAME.*.tmp)."""
        folder, name = os.path.split(self.output)
        try:
            return {os.path.join(folder, entry) for entry in os.listdir(folder or ".")
                    if entry.startswith(f".{name}.") and entry.endswith(".tmp")}
        except OSError:
            return set()


def sweep_leftovers(folder: str | None = None) -> list[str]:
    """Remove the scratch folders earlier jobs could not remove (those holding LEFTOVER_MARK) in
    `folder` (default: the temp folder), in one pass (a bake's start waits on no retries); one a
    file still holds is marked again for the next job. Another job's folder in use has no mark.
    Returns the folders that stay."""
    folder = tempfile.gettempdir() if folder is None else folder
    try:
        marked = [os.path.join(folder, name) for name in os.listdir(folder)
                  if name.startswith(SCRATCH_PREFIX) and os.path.isfile(os.path.join(folder, name, LEFTOVER_MARK))]
    except OSError:
        return []
    left = []
    for scratch in marked:
        shutil.rmtree(scratch, ignore_errors=True)
        if os.path.lexists(scratch):
            with contextlib.suppress(OSError):
                Path(scratch, LEFTOVER_MARK).touch()
            left.append(scratch)
    return left


def active() -> BakeJob | None:
    """The running bake, if any (the panel shows its progress)."""
    return _active[-1] if _active else None
