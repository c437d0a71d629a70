"""What differs by operating system, branch by branch (docs/how-it-works.md#what-differs-by-platform):
stopping the bake's process tree (core/process_tree.py), a .hlod replaced while it is loaded
(io/hlod_file.maps_files, core/atomic.replace), the viewer's port (export/viewer.port_options), and
paths with spaces and non-ASCII characters through the command line.

The POSIX branches run for real. Of the Windows branches, these run for real here, their platform
named: closing the bake child's stdin to stop it (a real bake child stops; and one started as on
Windows, without a process group and stop_self on its win32 branch, ends its workers itself), Terminated raised in
the main thread by stop_self, reading a .hlod into memory (no mapping or handle left: the condition
for Windows to let a re-bake replace the file). These are simulated, with the OS call recorded in
place of being made: taskkill of the tree, the rename retried while Windows refuses it, the
socket option. Only a Windows machine proves them end to end.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from helpers import ROOT, model
from hlod_core.bake.run import child
from hlod_core.bake.settings import BakeSettings
from hlod_core.core import atomic, process_tree
from hlod_core.core.errors import InputError
from hlod_core.core.png import write_png
from hlod_core.core.signals import Terminated, signals_as_exceptions
from hlod_core.export import viewer
from hlod_core.io import hlod_file, meshes, procedural
from processes import alive, hlod, last_json, live_group, live_processes, wait_gone

# --- the bake's process tree ------------------------------------------------------------------------

#: A child that starts a grandchild (printing its pid) and waits: a tree of two processes.
TREE = ("import subprocess, sys, time\n"
        "g = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
        "print(g.pid, flush=True)\n"
        "time.sleep(60)\n")


def test_the_child_is_started_as_the_root_of_a_tree_on_each_platform():
    assert process_tree.child_options(platform="linux") == {"start_new_session": True}
    assert process_tree.child_options(platform="darwin") == {"start_new_session": True}
    assert process_tree.child_options(platform="win32") == {"creationflags": 0x00000200 | 0x08000000}


@pytest.mark.parametrize("how", ["ask", "kill"])
def test_posix_stop_and_kill_reach_the_child_and_its_children(how):
    proc = subprocess.Popen([sys.executable, "-c", TREE], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            **process_tree.child_options())
    try:
        grandchild = int(proc.stdout.readline())
        assert alive(grandchild)
        if how == "ask":
            process_tree.ask_to_stop(proc)
        else:
            process_tree.kill_tree(proc.pid)
        assert proc.wait(timeout=20) == (-signal.SIGTERM if how == "ask" else -signal.SIGKILL)
        assert wait_gone([grandchild])
    finally:
        process_tree.kill_tree(proc.pid)
        proc.wait(timeout=20)
    process_tree.kill_tree(proc.pid)  # none left: nothing happens
    process_tree.ask_to_stop(proc)


def test_windows_kill_ends_the_tree_with_taskkill(monkeypatch):
    """Simulated: the command the Windows branch runs (not run here: there is no taskkill)."""
    ran = []
    monkeypatch.setattr(process_tree.subprocess, "run", lambda argv, **kw: ran.append((argv, kw["creationflags"])))
    process_tree.kill_tree(4321, platform="win32")
    assert ran == [(["taskkill", "/PID", "4321", "/T", "/F"], process_tree.CREATE_NO_WINDOW)]


def test_windows_stop_self_raises_terminated_in_the_main_thread():
    """The Windows branch of stop_self, run here: from another thread (the child's stdin watcher),
    Terminated(SIGTERM) reaches the main thread through the handler signals_as_exceptions installs,
    so the bake unwinds as after a SIGTERM on POSIX."""
    with pytest.raises(Terminated) as stopped:
        with signals_as_exceptions():
            threading.Timer(0.05, process_tree.stop_self, kwargs={"platform": "win32"}).start()
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                time.sleep(0.01)
    assert stopped.value.signum == signal.SIGTERM


def test_closing_the_bake_childs_stdin_stops_it_and_its_workers(tmp_path):
    """The Windows branch of ask_to_stop (its stdin closed), run here on a real bake child with two
    workers: the child stops as after SIGTERM (status 128 + 15), nothing is written, its job files
    are gone and no process of its group is left."""
    (tmp_path / "job").mkdir()
    job = child.write_job(tmp_path / "job", procedural.default_scene(seed=1), BakeSettings(jobs=2),
                          output=tmp_path / "out.hlod")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", child.MODULE, str(job), child.PARENT_STDIN], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, **process_tree.child_options())
    try:
        for line in proc.stdout:  # wait until the bake is under way (workers started)
            if json.loads(line)["event"] == "progress":
                break
        process_tree.ask_to_stop(proc, platform="win32")
        assert proc.wait(timeout=60) == 128 + signal.SIGTERM, proc.stderr.read()
    finally:
        process_tree.kill_tree(proc.pid)
        proc.wait(timeout=20)
    assert wait_gone(live_group(proc.pid)) and not live_group(proc.pid)
    assert not (tmp_path / "out.hlod").exists() and not (tmp_path / "job").exists()


#: The bake child as it runs on Windows: started without a process group of its own (no group
#: signal reaches its workers) and its stop_self taking the win32 branch (Terminated raised in its
#: main thread), so only its own clean-up can end its workers.
WINDOWS_CHILD = ("import sys\n"
                 "from hlod_core.core import process_tree\n"
                 "stop_self = process_tree.stop_self\n"
                 "process_tree.stop_self = lambda platform=None: stop_self(platform='win32')\n"
                 "from hlod_core.bake.run import child\n"
                 "sys.exit(child.main(sys.argv[1:]))\n")


def _workers(pid: int) -> set[int]:
    """The live worker processes (multiprocessing's spawned ones) below `pid`, from /proc."""
    found = set()
    for process in _descendants(pid):
        with contextlib.suppress(OSError):
            if b"spawn_main" in Path(f"/proc/{process}/cmdline").read_bytes():
                found.add(process)
    return found


def _descendants(pid: int) -> set[int]:
    """The live processes below `pid` (from /proc: each one's parent)."""
    parents = {process: parent for process, (parent, _) in live_processes().items()}
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _cpu_seconds(pid: int) -> float:
    """The CPU time (user + system, s) process `pid` has used; 0 once it has gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


#: A sphere of 360,000 triangles baked to depth 1: its eight leaves need no work, the root's
#: decimation takes about 18 s on the 2-core test machine (and its exact error as long again).
SPHERE_SEGMENTS = 600
#: The most a stop may take (s) from the stdin closed to the child gone: killing and joining the
#: workers takes well under a second (measured 0.45 s); a pool left to finish the running task
#: waited 17.5 s.
STOP_SECONDS = 5.0


def test_a_bake_child_without_a_process_group_ends_its_workers_itself(tmp_path):
    """The child as on Windows (WINDOWS_CHILD), stopped while a worker runs the root's long
    decimation: no signal reaches its workers, so its own unwinding must end them (killed and joined,
    the pool shut down) rather than wait for the task. It exits with 128 + 15 within STOP_SECONDS,
    no worker is left, nothing is written and its job files are gone."""
    positions, faces = procedural.uv_sphere((0.0, 0.0, 0.0), 1.0, segments=SPHERE_SEGMENTS,
                                            rings=SPHERE_SEGMENTS // 2)
    (tmp_path / "job").mkdir()
    job = child.write_job(tmp_path / "job", meshes.from_arrays(positions, faces, None, name="sphere"),
                          BakeSettings(jobs=2, max_depth=1), output=tmp_path / "out.hlod")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-c", WINDOWS_CHILD, str(job), child.PARENT_STDIN], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    workers: set[int] = set()
    try:
        assert os.getpgid(proc.pid) == os.getpgrp()  # no group of its own: stop_self cannot signal one
        for line in proc.stdout:  # until only the root's task is left
            event = json.loads(line)
            if event["event"] == "progress" and event["phase"] == "simplify" and event["done"] == event["total"] - 1:
                break
        workers = _workers(proc.pid)
        busy = {pid: _cpu_seconds(pid) for pid in workers}
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and all(_cpu_seconds(pid) < busy[pid] + 0.5 for pid in workers):
            time.sleep(0.05)  # until a worker is half a CPU second into the root's task
        process_tree.ask_to_stop(proc, platform="win32")
        stopped = time.monotonic()
        status = proc.wait(timeout=120)
        seconds = time.monotonic() - stopped
        left = [pid for pid in workers if alive(pid)]
    finally:
        for pid in workers | _descendants(proc.pid):  # this test's own processes, whatever happened
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        proc.kill()
        proc.wait(timeout=20)
    assert len(workers) == 2 and status == 128 + signal.SIGTERM, proc.stderr.read()
    assert seconds < STOP_SECONDS, f"the stop waited {seconds:.1f} s: for the worker's task, not ending it"
    assert left == [], f"workers left running after the child exited: {left}"
    assert not (tmp_path / "out.hlod").exists() and not (tmp_path / "job").exists()


# --- a .hlod replaced while it is loaded ----------------------------------------------------------------

def _mapped(path: Path) -> bool:
    """Whether this process maps `path` or holds it open (/proc/self/maps, /proc/self/fd)."""
    real = str(path.resolve())
    if real in Path("/proc/self/maps").read_text():
        return True
    return any(os.path.realpath(f"/proc/self/fd/{fd}") == real for fd in os.listdir("/proc/self/fd"))


def test_windows_reads_the_hlod_into_memory_so_a_rebake_can_replace_it(bakes, tmp_path):
    """The Windows branch (maps_files("win32") is False) run here: the loaded arrays are in memory,
    no mapping or handle of the file is left (what lets Windows replace it), and a re-bake saved
    over it leaves them as they were. The POSIX branch maps it, and the replaced file's old pages
    stay readable through the mapping."""
    _, first = bakes.baked("cow", target_tris=400)
    _, second = bakes.baked("cow", target_tris=400, offset=1.0)
    path = hlod_file.save(first, tmp_path / "scene.hlod")
    assert hlod_file.maps_files("win32") is False and hlod_file.maps_files("linux") is True
    assert hlod_file.maps_files("darwin") is True
    for platform in ("win32", "linux"):
        hlod_file.save(first, path)
        loaded = hlod_file.load(path, mmap=hlod_file.maps_files(platform))
        assert isinstance(loaded.positions, np.memmap) == (platform != "win32")
        assert _mapped(path) == (platform != "win32")
        hlod_file.save(second, path)  # the re-bake: an atomic rename over the loaded file
        assert np.array_equal(loaded.positions, first.positions)
        assert np.array_equal(hlod_file.load(path).positions, second.positions)
        del loaded


def test_windows_retries_a_replace_refused_for_a_moment_then_names_the_error(tmp_path, monkeypatch):
    """Simulated refusals (os.replace raising PermissionError, as Windows does while another process
    holds the target open): the Windows branch retries and succeeds; past REPLACE_RETRY_SECONDS it
    raises; POSIX does not retry."""
    real_replace, refusals = os.replace, []

    def refuse_twice(source, target):
        if len(refusals) < 2:
            refusals.append(target)
            raise PermissionError(13, "Access is denied", str(target))
        real_replace(source, target)

    monkeypatch.setattr(atomic.os, "replace", refuse_twice)
    monkeypatch.setattr(atomic, "REPLACE_RETRY_EVERY_SECONDS", 0.001)
    (tmp_path / "new").write_text("new")
    atomic.replace(tmp_path / "new", tmp_path / "target", platform="win32")
    assert (tmp_path / "target").read_text() == "new" and len(refusals) == 2
    refusals.clear()
    (tmp_path / "new").write_text("newer")
    with pytest.raises(PermissionError):
        atomic.replace(tmp_path / "new", tmp_path / "target", platform="linux")
    def refuse(source, target):
        raise PermissionError(13, "Access is denied", str(target))

    monkeypatch.setattr(atomic.os, "replace", refuse)
    monkeypatch.setattr(atomic, "REPLACE_RETRY_SECONDS", 0.05)
    started = time.monotonic()
    with pytest.raises(PermissionError, match="Access is denied"):
        atomic.replace(tmp_path / "new", tmp_path / "target", platform="win32")
    assert time.monotonic() - started >= 0.05


# --- the viewer's port -----------------------------------------------------------------------------------

def test_the_viewer_port_is_exclusive_on_windows_and_reusable_at_once_on_posix(tmp_path):
    """POSIX, for real: SO_REUSEADDR on the listening socket; a second server cannot take the port
    while the first listens, and one can listen on it again as soon as the first has closed (after
    a client's connection, its side in TIME_WAIT). Windows, its options only (simulated): exclusive
    use (SO_EXCLUSIVEADDRUSE = ~SO_REUSEADDR = -5) and no SO_REUSEADDR."""
    assert viewer.port_options("linux") == [(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)]
    assert viewer.port_options("darwin") == viewer.port_options("linux")
    assert viewer.port_options("win32") == [(socket.SOL_SOCKET, -5, 1)]
    tiles = tmp_path / "tiles"
    tiles.mkdir()
    (tiles / "tileset.json").write_text("{}")
    cesium = tmp_path / "cesium"
    cesium.mkdir()
    (cesium / "Cesium.js").write_text("")
    with viewer.serve(tiles, cesium_dir=cesium).start() as first:
        assert first.socket.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR) == 1
        with urllib.request.urlopen(first.url + "tiles/tileset.json", timeout=10) as response:
            assert response.read() == b"{}"
        with pytest.raises(InputError, match=f"port {first.port}: cannot listen"):
            viewer.serve(tiles, cesium_dir=cesium, port=first.port)
        port = first.port
    with viewer.serve(tiles, cesium_dir=cesium, port=port) as again:
        assert again.port == port


# --- paths with spaces and non-ASCII characters ------------------------------------------------------------

def _textured_obj(folder: Path) -> Path:
    """A two-triangle OBJ with an MTL and a PNG texture, every name with spaces and non-ASCII letters."""
    (folder / "tex 纹理").mkdir(parents=True)
    write_png(folder / "tex 纹理" / "brique été.png", np.full((4, 4, 3), (200, 60, 40), np.uint8))
    (folder / "matériaux été.mtl").write_text("newmtl Brique\nKd 1 1 1\nmap_Kd tex 纹理/brique été.png\n",
                                              encoding="utf-8")
    obj = folder / "maison été 模型.obj"
    obj.write_text("mtllib matériaux été.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                   "usemtl Brique\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n", encoding="utf-8")
    return obj


def test_paths_with_spaces_and_non_ascii_letters_through_bake_export_and_view(tmp_path):
    """A textured OBJ and the cow in a folder named with spaces, accents and CJK letters: baked,
    exported to 3D Tiles and served by `view`, through the command line, its output read through
    an ASCII-only stdout and stderr (as a Windows console's code page may be): the texture reaches
    the export (under the export's portable name) and is served from the folder; an error names the
    path escaped."""
    folder = tmp_path / "dossier été" / "ünï cødé 模型"
    folder.mkdir(parents=True)
    cow = folder / "vache à lait.obj"
    cow.write_bytes(model("cow").read_bytes())
    ascii_env = {"PYTHONIOENCODING": "ascii"}
    for source in (_textured_obj(folder), cow):
        out = folder / f"{source.stem} résultat.hlod"
        baked = last_json(hlod("-q", "bake", source, "-o", out, "--target-tris", "400", env=ascii_env))
        assert Path(baked["output"]) == out and out.is_file()
        tiles = folder / f"{source.stem} tuiles 3D"
        exported = last_json(hlod("-q", "export", out, "-o", tiles, env=ascii_env))
        assert Path(exported["output"]) == tiles and (tiles / "tileset.json").is_file()
    textured = folder / "maison été 模型 tuiles 3D"
    images = sorted(p.name for p in (textured / "textures").iterdir())
    assert images == ["brique_t.png"]  # the export's portable names (texture_folder.unique_file_name)
    server = subprocess.Popen([sys.executable, "-m", "hlod_core", "view", str(textured), "--no-browser"],
                              env=dict(os.environ, PYTHONPATH=str(ROOT), PYTHONIOENCODING="ascii"),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = server.stdout.readline().strip()
        with urllib.request.urlopen(f"{url}tiles/textures/brique_t.png", timeout=20) as response:
            assert response.read() == (textured / "textures" / "brique_t.png").read_bytes()
        with urllib.request.urlopen(f"{url}tiles/tileset.json", timeout=20) as response:
            assert json.loads(response.read())["root"]
    finally:
        server.send_signal(signal.SIGTERM)
        server.communicate(timeout=20)
    missing = hlod("-q", "info", folder / "absent été.hlod", check=False, env=ascii_env)
    assert missing.returncode == 2 and "absent \\xe9t\\xe9.hlod" in missing.stderr, missing.stderr
