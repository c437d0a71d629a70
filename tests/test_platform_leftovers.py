"""What Windows would leave behind, brought about here (docs/how-it-works.md#what-differs-by-platform):
a bake child that dies on its own with workers running (core/process_tree.end_with_self,
end_leftovers), a scratch folder a dying worker still maps (core/atomic.remove_tree, the bake job's
leftovers swept at the next bake), an export re-written while a viewer holds a tile open or with
an old copy left beside it (core/atomic.replace_folder, export/tiles3d.replace_export), and the
viewer's URL read by a client whose resolver answers ::1 first for localhost (export/viewer.page_url).

Real here: the bake child, its workers, the bake job, the exports, the viewer and the processes that
hold files. Simulated, as Windows behaves where Linux does not: `shutil.rmtree` leaves a file some
live process maps or holds open, and `os.replace` refuses (PermissionError) to rename a folder
holding such a file (`windows_rmtree`, `windows_replace`: which files are held is read from
/proc/*/maps and /proc/*/fd); the job object's Windows calls are recorded (`RecordedKernel32`); the
resolver puts ::1 first. Only a Windows machine proves those branches end to end.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import importlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from helpers import extension_package
from hlod_core.core import atomic, process_tree
from hlod_core.export import tiles3d, viewer
from hlod_core.io import procedural
from processes import alive, live_group, wait_for, wait_gone

#: A stand-in for a process that holds a file: maps it (mode "map": a worker's shared arrays) or
#: keeps it open (mode "open": a viewer serving a tile), says so, and lets go when its stdin closes.
HOLDER = ("import mmap, sys\n"
          "f = open(sys.argv[1], 'rb')\n"
          "if sys.argv[2] == 'map':\n"
          "    m = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)\n"
          "    f.close()\n"
          "print('held', flush=True)\n"
          "sys.stdin.read()\n")
REAL_RMTREE, REAL_REPLACE = shutil.rmtree, os.replace


@contextlib.contextmanager
def held(path: Path, mode: str = "map"):
    """A live process mapping (or holding open) `path` while the block runs; its Popen."""
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(path), mode], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        yield proc
    finally:
        release(proc)


def release(proc: subprocess.Popen) -> None:
    """Let the holder go and wait for it to end (its mappings and handles with it)."""
    if proc.stdin and not proc.stdin.closed:
        proc.stdin.close()
    proc.wait(timeout=20)


def held_files(folder) -> set[str]:
    """Files under `folder` that a live process maps or holds open (/proc/*/maps, /proc/*/fd)."""
    prefix = os.path.realpath(folder) + os.sep
    found = set()
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            with open(f"/proc/{entry.name}/maps") as f:
                found |= {line.split(maxsplit=5)[5] for line in f if len(line.split(maxsplit=5)) == 6
                          and line.split(maxsplit=5)[5].startswith(prefix)}
        with contextlib.suppress(OSError):
            for fd in os.listdir(f"/proc/{entry.name}/fd"):
                with contextlib.suppress(OSError):
                    target = os.readlink(f"/proc/{entry.name}/fd/{fd}")
                    if target.startswith(prefix):
                        found.add(target)
    return found


def windows_rmtree(path, ignore_errors=False, **kwargs):
    """shutil.rmtree as Windows does it: a file some live process maps or holds open stays, and so
    do the folders holding it (PermissionError, unless ignore_errors)."""
    held_now = held_files(path)
    if not held_now:
        return REAL_RMTREE(path, ignore_errors=ignore_errors, **kwargs)
    for root, folders, files in os.walk(path, topdown=False):
        for name in files:
            if os.path.realpath(os.path.join(root, name)) not in held_now:
                os.unlink(os.path.join(root, name))
        for name in folders:
            with contextlib.suppress(OSError):
                os.rmdir(os.path.join(root, name))
    if not ignore_errors:
        raise PermissionError(13, "The process cannot access the file because it is being used by another process",
                              sorted(held_now)[0])


def windows_replace(source, target):
    """os.replace as Windows does it: a folder holding a file some live process maps or holds open
    is not renamed (PermissionError, WinError 5)."""
    if os.path.isdir(source) and held_files(source):
        raise PermissionError(13, "Access is denied", str(source))
    REAL_REPLACE(source, target)


@pytest.fixture
def as_windows(monkeypatch):
    """Folder removal and renames behave as on Windows (windows_rmtree, windows_replace)."""
    monkeypatch.setattr(shutil, "rmtree", windows_rmtree)
    monkeypatch.setattr(os, "replace", windows_replace)


# --- the bake child's workers when the child dies on its own ------------------------------------------

class RecordedKernel32:
    """The kernel32 functions end_with_self calls, each recorded with its arguments (Linux has no
    job objects); CreateJobObjectW answers `job` (0: the call fails)."""

    def __init__(self, job: int = 0x1234):
        self.calls: list[tuple] = []

        def record(name, answer):
            def call(*args):
                self.calls.append((name, *args))
                return answer
            return call

        self.CreateJobObjectW = record("CreateJobObjectW", job)
        self.SetInformationJobObject = record("SetInformationJobObject", 1)
        self.GetCurrentProcess = record("GetCurrentProcess", 0xFFFFFFFFFFFFFFFF)
        self.AssignProcessToJobObject = record("AssignProcessToJobObject", 1)


def test_windows_puts_the_child_in_a_job_that_ends_its_workers_when_it_ends():
    """Simulated (the calls recorded): a job object with JOB_OBJECT_LIMIT_KILL_ON_JOB_CLOSE in
    JOBOBJECT_EXTENDED_LIMIT_INFORMATION (144 bytes on 64-bit Windows, the same layout here), this
    process assigned to it; a refused call is an OSError naming it. POSIX: nothing to do."""
    kernel32 = RecordedKernel32()
    assert process_tree.end_with_self(platform="win32", kernel32=kernel32) == 0x1234
    names = [call[0] for call in kernel32.calls]
    assert names == ["CreateJobObjectW", "SetInformationJobObject", "GetCurrentProcess", "AssignProcessToJobObject"]
    assert kernel32.calls[0][1:] == (None, None)
    _, job, info_class, limits, size = kernel32.calls[1]
    assert job.value == 0x1234 and info_class == 9
    assert limits._obj.BasicLimitInformation.LimitFlags == 0x2000 and size == ctypes.sizeof(limits._obj)
    if ctypes.sizeof(ctypes.c_void_p) == 8:
        assert size == 144
    _, job, process = kernel32.calls[3]
    assert job.value == 0x1234 and process.value == 0xFFFFFFFFFFFFFFFF  # GetCurrentProcess's pseudo-handle
    with pytest.raises(OSError, match="CreateJobObjectW failed"):
        process_tree.end_with_self(platform="win32", kernel32=RecordedKernel32(job=0))
    for platform in ("linux", "darwin"):
        assert process_tree.end_with_self(platform=platform, kernel32=kernel32) is None
    assert len(kernel32.calls) == 4


def test_end_leftovers_kills_a_dead_childs_group_on_posix_and_leaves_windows_to_the_job(monkeypatch):
    """POSIX, for real: a child that started a grandchild dies on its own (SIGKILL to it alone);
    before it is reaped, end_leftovers ends the grandchild through the group the dead child's pid
    still names. Windows runs nothing (taskkill /T cannot walk from a root that has gone; the job
    object has ended the workers)."""
    tree = ("import subprocess, sys, time\n"
            "g = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
            "print(g.pid, flush=True)\ntime.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", tree], stdout=subprocess.PIPE, text=True,
                            **process_tree.child_options())
    try:
        grandchild = int(proc.stdout.readline())
        os.kill(proc.pid, signal.SIGKILL)
        wait_for(lambda: not alive(proc.pid), 20, "the child's death")
        assert alive(grandchild)  # the orphan the child left
        process_tree.end_leftovers(proc.pid)
        assert wait_gone([grandchild])
    finally:
        process_tree.kill_tree(proc.pid)
        proc.wait(timeout=20)
    ran = []
    monkeypatch.setattr(process_tree.subprocess, "run", lambda *a, **kw: ran.append(a))
    process_tree.end_leftovers(proc.pid, platform="win32")
    assert ran == []


@pytest.fixture
def bake_job(tmp_path, monkeypatch):
    """The extension's bake job module (addon.bake.job, outside Blender), its scratch folders made in
    tmp_path/"temp" (the temp folder)."""
    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    package = extension_package()
    module = importlib.import_module(f"{package.__name__}.addon.bake.job")
    monkeypatch.setattr(module, "temp", temp, raising=False)  # where the test looks for its folders
    return module


def _settings(bake_job, **fields):
    return importlib.import_module(bake_job.__name__.replace("addon.bake.job", "hlod_core.bake.settings")) \
        .BakeSettings(**fields)


def _scratch_folders(bake_job) -> list[Path]:
    return sorted(bake_job.temp.glob(f"{bake_job.SCRATCH_PREFIX}*"))


def _shared_arrays(bake_job) -> list[Path]:
    """The shared arrays the bake's workers map (tasks.save_shared), in the job's scratch folder,
    those written so far (not empty: a file being written may be)."""
    found = []
    for path in sorted(bake_job.temp.glob(f"{bake_job.SCRATCH_PREFIX}*/hlod-bake-*/*.npy")):
        with contextlib.suppress(OSError):
            if path.stat().st_size > 0:
                found.append(path)
    return found


def _spawned_workers(pid: int) -> list[int]:
    """The pool's worker processes in the group of `pid` (multiprocessing's spawn_main)."""
    found = []
    for p in live_group(pid):
        with contextlib.suppress(OSError):
            if b"spawn_main" in Path(f"/proc/{p}/cmdline").read_bytes():
                found.append(p)
    return found


def test_a_bake_child_that_dies_on_its_own_leaves_no_worker_and_no_scratch(bake_job, tmp_path):
    """A real bake job (jobs 2) whose child is killed alone while its workers run, as a crash or End
    task does: the job reports the death, and no worker, scratch folder or output is left."""
    job = bake_job.BakeJob(procedural.default_scene(seed=1, scale=0.5), _settings(bake_job, jobs=2),
                           tmp_path / "out.hlod")
    try:
        wait_for(lambda: len(_spawned_workers(job.pid)) == 2 or not job.running, 120, "the bake's two workers")
        workers = _spawned_workers(job.pid)
        assert len(workers) == 2, job.error
        os.kill(job.pid, signal.SIGKILL)
        assert job.wait(60)
    finally:
        job.cancel()
        job.wait(60)
    assert isinstance(job.error, bake_job.BakeProcessError) and "SIGKILL" in str(job.error), job.error
    assert wait_gone(workers) and not live_group(job.pid)
    assert _scratch_folders(bake_job) == [] and job.scratch_left is None and not (tmp_path / "out.hlod").exists()


# --- the scratch folder a dying worker still maps ----------------------------------------------------

def test_windows_removes_a_folder_once_the_process_holding_it_has_gone(tmp_path, as_windows, monkeypatch):
    """remove_tree's Windows branch against a file mapped by a live process: it retries until the
    process has gone; past REMOVE_RETRY_SECONDS it gives up and says so. POSIX: one pass."""
    folder = tmp_path / "scratch"
    (folder / "inner").mkdir(parents=True)
    (folder / "inner" / "a.npy").write_bytes(b"x" * 4096)
    (folder / "b.npy").write_bytes(b"y" * 4096)
    monkeypatch.setattr(atomic, "REMOVE_RETRY_SECONDS", 60.0)  # a hang guard: released long before
    with held(folder / "inner" / "a.npy") as holder:
        threading.Timer(0.3, release, [holder]).start()
        started = time.monotonic()
        assert atomic.remove_tree(folder, platform="win32") and not folder.exists()
        assert time.monotonic() - started >= 0.3 and holder.poll() is not None
    folder.mkdir()
    (folder / "a.npy").write_bytes(b"x" * 4096)
    monkeypatch.setattr(atomic, "REMOVE_RETRY_SECONDS", 0.2)
    with held(folder / "a.npy"):
        assert atomic.remove_tree(folder, platform="win32") is False
        assert atomic.remove_tree(folder, platform="linux") is False  # POSIX would remove it: one try here
        assert sorted(p.name for p in folder.iterdir()) == ["a.npy"]
    assert atomic.remove_tree(folder, platform="linux") and atomic.remove_tree(folder, platform="win32")


def test_a_killed_bake_removes_its_scratch_once_the_dying_worker_lets_go(bake_job, tmp_path, as_windows, monkeypatch):
    """A real bake job (jobs 2) whose tree is killed at once (a forced cancel: kill_tree, as taskkill
    /F, which returns before the processes have gone) while a process maps one of the workers'
    shared arrays (a worker still dying): the job's scratch removal (Windows branch) waits for it
    to let go, then the folder is gone and the job finished."""
    monkeypatch.setattr(bake_job.atomic, "remove_tree", functools.partial(bake_job.atomic.remove_tree,
                                                                          platform="win32"))
    monkeypatch.setattr(bake_job.atomic, "REMOVE_RETRY_SECONDS", 60.0)  # a hang guard; released long before
    job = bake_job.BakeJob(procedural.default_scene(seed=1, scale=0.5), _settings(bake_job, jobs=2),
                           tmp_path / "out.hlod")
    try:
        wait_for(lambda: _shared_arrays(bake_job) or not job.running, 120, "the workers' shared arrays")
        with held(_shared_arrays(bake_job)[0]) as holder:
            process_tree.kill_tree(job.pid)
            wait_for(lambda: not alive(job.pid), 60, "the child's end")
            assert not job.wait(0.5) and _shared_arrays(bake_job)  # held: the job is still removing it
            release(holder)
            assert job.wait(60)
    finally:
        job.cancel()
        job.wait(60)
    assert isinstance(job.error, bake_job.BakeProcessError) and "SIGKILL" in str(job.error), job.error
    assert job.scratch_left is None and _scratch_folders(bake_job) == []


def test_a_scratch_folder_that_stays_is_named_and_swept_by_the_next_bake(bake_job, tmp_path, as_windows,
                                                                         monkeypatch):
    """A real bake (jobs 1) whose scratch a process still maps past the retries: the result and the
    job name the folder, it is marked, and the next bake (once it is free) removes it; another
    job's scratch folder in use (no mark) is left alone."""
    monkeypatch.setattr(bake_job.atomic, "remove_tree", functools.partial(bake_job.atomic.remove_tree,
                                                                          platform="win32"))
    monkeypatch.setattr(bake_job.atomic, "REMOVE_RETRY_SECONDS", 0.2)
    mesh, settings = procedural.default_scene(seed=1, scale=0.25), _settings(bake_job, jobs=1, target_tris=4000)
    in_use = bake_job.temp / f"{bake_job.SCRATCH_PREFIX}in-use"
    in_use.mkdir()
    (in_use / "mesh.npz").write_bytes(b"another Blender's bake")
    job = bake_job.BakeJob(mesh, settings, tmp_path / "first.hlod")
    scratch = next(p for p in _scratch_folders(bake_job) if p != in_use)
    with held(scratch / "mesh.npz"):
        assert job.wait(120) and job.error is None, job.error
        assert job.result.scratch_left == job.scratch_left == str(scratch)
        assert (scratch / bake_job.LEFTOVER_MARK).is_file() and (scratch / "mesh.npz").is_file()
        assert bake_job.sweep_leftovers() == [str(scratch)]  # still held: stays, still marked
        assert (scratch / bake_job.LEFTOVER_MARK).is_file()
    second = bake_job.BakeJob(mesh, settings, tmp_path / "second.hlod")
    assert not scratch.exists() and in_use.is_dir()
    assert second.wait(120) and second.error is None and second.result.scratch_left is None
    assert _scratch_folders(bake_job) == [in_use]


# --- re-exporting 3D Tiles over a served folder ------------------------------------------------------------

def _tileset(folder: Path) -> bytes:
    return (folder / "tileset.json").read_bytes()


def test_a_reexport_waits_while_a_tile_is_held_open_and_never_leaves_it_half_replaced(bakes, tmp_path, as_windows,
                                                                                     monkeypatch):
    """Windows' renames (simulated refusals while a process holds a tile open): the re-export is
    retried until the viewer lets go, then the new export is in place and nothing is left beside
    it; held past the retries, the error is raised and the earlier export is still whole in place."""
    _, first = bakes.baked("cow", target_tris=400)
    _, second = bakes.baked("cow", target_tris=400, offset=1.0)
    out = tmp_path / "tiles"
    tiles3d.export(first, out, platform="win32")
    earlier = _tileset(out)
    tile = next((out / "tiles").iterdir())
    monkeypatch.setattr(atomic, "REPLACE_RETRY_SECONDS", 60.0)  # a hang guard: released long before
    with held(tile, "open") as viewer_process:
        threading.Timer(0.3, release, [viewer_process]).start()
        summary = tiles3d.export(second, out, platform="win32")
    assert summary["warnings"] == [] and _tileset(out) != earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]
    newer = _tileset(out)
    monkeypatch.setattr(atomic, "REPLACE_RETRY_SECONDS", 0.2)
    with held(next((out / "tiles").iterdir()), "open"):
        with pytest.raises(PermissionError, match="Access is denied"):
            tiles3d.export(first, out, platform="win32")
    assert _tileset(out) == newer and sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]


def test_the_earlier_export_is_put_back_when_the_new_one_cannot_take_its_place(bakes, tmp_path, as_windows,
                                                                               monkeypatch):
    """The earlier export renamed aside, the new one refused its place (a process holds one of its
    files past the retries): the earlier export is renamed back, whole, and the error raised."""
    _, first = bakes.baked("cow", target_tris=400)
    out, staging = tmp_path / "tiles", tmp_path / ".tiles.new"
    tiles3d.export(first, out)
    earlier = _tileset(out)
    shutil.copytree(out, staging)
    (staging / "tileset.json").write_text("{}")
    monkeypatch.setattr(atomic, "REPLACE_RETRY_SECONDS", 0.2)
    with held(staging / "tileset.json", "open"):
        with pytest.raises(PermissionError):
            tiles3d.replace_export(out, staging, platform="win32")
    assert _tileset(out) == earlier and (staging / "tileset.json").read_text() == "{}"
    assert sorted(p.name for p in tmp_path.iterdir()) == [".tiles.new", "tiles"]


def test_stale_copies_beside_an_export_do_not_stop_the_next_one_and_are_cleared(bakes, tmp_path, as_windows,
                                                                               monkeypatch):
    """A `.NAME.old` folder a process still maps a tile of (as a removal Windows refused leaves it;
    it made the next export fail with FileExistsError) and an aside folder left free: the export
    goes through, removes the free one, names the one still held in its warnings, and the export
    after it (the tile let go) clears it."""
    _, first = bakes.baked("cow", target_tris=400)
    out = tmp_path / "tiles"
    tiles3d.export(first, out)
    held_aside = tmp_path / ".tiles.old"
    shutil.copytree(out, held_aside)
    shutil.copytree(out, tmp_path / ".tiles.old-0123abcd")
    tile = next((held_aside / "tiles").iterdir())
    monkeypatch.setattr(atomic, "REMOVE_RETRY_SECONDS", 0.2)
    with held(tile):
        summary = tiles3d.export(first, out, platform="win32")
        assert summary["warnings"] == [f"{held_aside}: an earlier export, not removed yet (a file in it is open); "
                                       "the next export removes it"]
        assert sorted(p.name for p in tmp_path.iterdir()) == [".tiles.old", "tiles"]
    assert tiles3d.export(first, out, platform="win32")["warnings"] == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles"]


# --- the viewer's URL --------------------------------------------------------------------------------------

def test_the_viewers_url_is_the_address_it_listens_on(tmp_path, monkeypatch):
    """A resolver that answers ::1 first for localhost (as Windows does; a client without a fallback
    waits on ::1): the page's URL names 127.0.0.1, the address the server is bound to, and a
    client reaching it asks the resolver for nothing but that address."""
    tiles, cesium = tmp_path / "tiles", tmp_path / "cesium"
    tiles.mkdir()
    (tiles / "tileset.json").write_text("{}")
    cesium.mkdir()
    (cesium / "Cesium.js").write_text("")
    real_getaddrinfo, asked = socket.getaddrinfo, []

    def windows_resolver(host, port, *args, **kwargs):
        asked.append(host)
        answers = real_getaddrinfo("127.0.0.1", port, *args, **kwargs)
        if host == "localhost":
            return [(socket.AF_INET6, socket.SOCK_STREAM, 6, "", ("::1", port, 0, 0)), *answers]
        return real_getaddrinfo(host, port, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", windows_resolver)
    assert socket.getaddrinfo("localhost", 80)[0][4][0] == "::1"  # the condition
    with viewer.serve(tiles, cesium_dir=cesium).start() as server:
        assert server.url == viewer.page_url(server.port) == f"http://{server.server_address[0]}:{server.port}/"
        asked.clear()
        with urllib.request.urlopen(server.url + "tiles/tileset.json", timeout=10) as response:
            assert response.read() == b"{}"
        assert asked == ["127.0.0.1"]
