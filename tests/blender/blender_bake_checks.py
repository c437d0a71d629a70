"""Checks of the bake outside Blender's process (a child process with workers) inside the real bpy
module, one per subprocess (tests/blender/test_addon_bake.py runs them):

    python tests/blender/blender_bake_checks.py REPO_DIR CHECK WORK_DIR [ARGUMENT ...]

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.

What the add-on does is watched from outside it, through /proc (Linux): the bake's child is a
process whose parent is this one and whose command line runs hlod_core.bake.run.child; its workers are
the processes of its process group. A process counts as gone when /proc has no entry for it or it
is a zombie (it has ended; only its exit status waits for its parent). Every check points Python's
temp folder (tempfile.tempdir, which the add-on's scratch folder and, through it, the child's
TMPDIR follow) into WORK_DIR/tmp, so "no scratch left" means that folder is empty afterwards, and
other processes' temp files cannot disturb the check.
"""
from __future__ import annotations

import contextlib
import dataclasses
import importlib
import io
import json
import os
import signal
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_checks  # the box row scene; it sets $HLOD_GPU_BACKEND's backend, before `import bpy`
import blender_preview

# isort: split
import bpy

NAME = "bl_ext.r.hlod"
CHILD_MODULE = "hlod_core.bake.run.child"
GONE_WITHIN_SECONDS = 1.0  # the requirement: the child and its workers are gone within 1 s of Esc
SPY_SECONDS = 0.02  # how often the spy reads /proc (every process's stat: not too often)
TIMING_KEYS = ("bake_seconds", "phase_seconds")  # meta entries that differ between any two bakes
CACHE_KEY = "cache"  # the meta entry of a bake with a cache (the in-process reference bakes without)


# --- processes, from /proc ------------------------------------------------------------------------

def _stat(pid: int) -> tuple[str, int, int] | None:
    """(state, parent pid, process group) of a process, None when it does not exist."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1]), int(fields[2])


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _pids() -> list[int]:
    return [int(name) for name in os.listdir("/proc") if name.isdigit()]


def alive(pid: int) -> bool:
    """Running (or stopped): exists and is not a zombie."""
    stat = _stat(pid)
    return stat is not None and stat[0] != "Z"


def bake_children() -> list[int]:
    """Live children of this process that run the bake's child module."""
    me = os.getpid()
    return [pid for pid in _pids() if (s := _stat(pid)) and s[1] == me and s[0] != "Z"
            and CHILD_MODULE in _cmdline(pid)]


def group(pgid: int) -> list[int]:
    """Live processes of process group `pgid` (the child and its workers)."""
    return [pid for pid in _pids() if (s := _stat(pid)) and s[2] == pgid and s[0] != "Z"]


def workers(pgid: int) -> list[int]:
    """The bake's worker processes in the child's group (multiprocessing's spawn_main)."""
    return [pid for pid in group(pgid) if "spawn_main" in _cmdline(pid)]


class Spy:
    """Watches /proc from a thread while a bake runs: the bake children seen, their command line,
    environment and group, and the most workers seen at once. `on_workers(child, pids)` (optional)
    is called once, when the child first has `min_workers` workers."""

    def __init__(self, *, on_workers=None, min_workers: int = 1):
        self.children: dict[int, dict] = {}
        self._on_workers, self._min_workers = on_workers, min_workers
        self._fired = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "Spy":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        while not self._stop.is_set():
            for child in bake_children():
                seen = self.children.setdefault(child, {"cmdline": _cmdline(child), "environ": _environ(child),
                                                        "max_workers": 0, "group": set()})
                now = workers(child)
                seen["group"].update(group(child))
                seen["max_workers"] = max(seen["max_workers"], len(now))
                if self._on_workers and not self._fired and len(now) >= self._min_workers:
                    self._fired = True
                    self._on_workers(child, now)
            self._stop.wait(SPY_SECONDS)


def _environ(pid: int) -> dict:
    try:
        raw = Path(f"/proc/{pid}/environ").read_bytes()
    except OSError:
        return {}
    return dict(item.decode(errors="replace").split("=", 1) for item in raw.split(b"\0") if b"=" in item)


def _wait_until(predicate, timeout_s: float, step_s: float = 0.002) -> float | None:
    """Seconds until predicate() held, None if it did not within timeout_s."""
    started = time.perf_counter()
    while time.perf_counter() - started < timeout_s:
        if predicate():
            return time.perf_counter() - started
        time.sleep(step_s)
    return None


def _wait_decimating(job, timeout_s: float) -> float | None:
    """Seconds until `job`'s workers decimate: its simplify phase has finished an inner node since
    it was first seen (the next ones are then under way), None if not within timeout_s."""
    started = time.perf_counter()
    if _wait_until(lambda: job.progress[2] == "simplify" or not job.running, timeout_s) is None:
        return None
    first = job.progress[0]
    left = timeout_s - (time.perf_counter() - started)
    if _wait_until(lambda: job.progress[0] > first or not job.running, left) is None or not job.running:
        return None
    return time.perf_counter() - started


# --- scenes and helpers ---------------------------------------------------------------------------

def _private_tmp(work) -> Path:
    """Python's temp folder for this process: WORK/tmp (module notes)."""
    folder = Path(work) / "tmp"
    folder.mkdir(exist_ok=True)
    tempfile.tempdir = str(folder)
    return folder


def _monkeys(count: int, levels: int, collection_name: str | None = None) -> int:
    """`count` Suzannes with a subdivision modifier of `levels` on a grid, selected (and linked
    into a new collection when named); their evaluated triangles (984 per Suzanne, x4 per level),
    counted by Blender."""
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    collection = None
    if collection_name:
        collection = bpy.data.collections.new(collection_name)
        bpy.context.scene.collection.children.link(collection)
    side = int(np.ceil(np.sqrt(count)))
    made = []
    for i in range(count):
        bpy.ops.mesh.primitive_monkey_add(size=2.0, location=(3.0 * (i % side), 3.0 * (i // side), 1.0))
        monkey = bpy.context.active_object
        monkey.modifiers.new("smooth", "SUBSURF").levels = levels
        monkey.modifiers["smooth"].render_levels = levels
        if collection is not None:
            for c in list(monkey.users_collection):
                c.objects.unlink(monkey)
            collection.objects.link(monkey)
        made.append(monkey)
    bpy.ops.object.select_all(action="DESELECT")
    for obj in made:
        obj.select_set(True)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    return sum(len(o.evaluated_get(depsgraph).to_mesh().loop_triangles) for o in made)


def _modules():
    return {name: importlib.import_module(f"{NAME}.{name}") for name in
            ("addon.bake.job", "addon.scene.gather", "hlod_core.bake.pipeline", "hlod_core.io.hlod_file",
             "hlod_core.core.errors")}


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _temps_beside(path: Path) -> list[str]:
    return sorted(p.name for p in path.parent.iterdir() if p.name.startswith(f".{path.name}."))


# --- checks -----------------------------------------------------------------------------------------

def check_child_bake(repo, work) -> dict:
    """The Bake operator with jobs 2 on the box row: it bakes in a child process of this one (run
    by this Python, with the extension's folder first on its path), with 2 worker processes; the
    file equals, array by array and in its meta (timings, the jobs setting and the cache's
    statistics aside), a bake of the same mesh by hlod_core in this process with jobs 1, without a
    cache; a re-bake of the unchanged scene takes every inner node from the cache beside the
    output (row.hlod.cache) and the panel's line says so; no scratch is left."""
    package = blender_preview.enable_from_repo(repo)
    tmp = _private_tmp(work)
    m = _modules()
    blender_checks._box_row_scene()
    props = bpy.context.scene.hlod
    out_path = Path(work) / "row.hlod"
    props.output_path, props.target_tris, props.jobs = str(out_path), 400, 2
    with Spy() as spy:
        result = sorted(bpy.ops.hlod.bake())
    objects = importlib.import_module(NAME + ".addon.scene.objects").source_objects(bpy.context, props)
    gathered = m["addon.scene.gather"].gather(bpy.context, objects)
    mesh, attributes = gathered.mesh, gathered.attributes
    bake = m["hlod_core.bake.pipeline"]
    settings = importlib.import_module(NAME + ".addon.settings").bake_settings(props)  # the panel's float32s
    here = bake.bake(mesh, dataclasses.replace(settings, jobs=1), extra_meta=attributes or None)
    child = m["hlod_core.io.hlod_file"].load(out_path)
    arrays_equal = {}
    for name in ("parent", "child_offset", "child_count", "depth", "lod_box_min", "lod_box_max", "box_min", "box_max",
                 "sphere_center", "sphere_radius", "error", "cube_side", "tri_offset", "tri_count", "vertex_offset",
                 "vertex_count", "origin", "positions", "indices", "normals", "uvs", "colors", "tri_material"):
        a, b = getattr(child, name), getattr(here, name)
        arrays_equal[name] = (a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b))

    def comparable(meta):
        kept = {k: v for k, v in meta.items() if k not in (*TIMING_KEYS, CACHE_KEY)}
        kept["settings"] = {k: v for k, v in meta["settings"].items() if k != "jobs"}
        return json.loads(json.dumps(kept))

    first_cache, first_line, first_bytes = child.meta.get(CACHE_KEY), props.last_bake, out_path.read_bytes()
    # a re-bake of the unchanged scene: every inner node from the cache beside the output
    again = sorted(bpy.ops.hlod.bake())
    rebaked = m["hlod_core.io.hlod_file"].load(out_path)
    same_again = all(np.array_equal(getattr(rebaked, k), getattr(child, k)) for k in ("positions", "indices", "error"))
    children = {pid: {**seen, "group": sorted(seen["group"])} for pid, seen in spy.children.items()}
    # errors inside the child come back typed: the core's InputError, a failed write
    job_cls, settings = m["addon.bake.job"].BakeJob, dataclasses.replace(settings, jobs=1)
    clash = job_cls(mesh, settings, str(Path(work) / "clash.hlod"), extra_meta={"generator": "me"})
    (Path(work) / "a_file").write_text("a file where the output's folder should be")
    unwritable = job_cls(mesh, settings, str(Path(work) / "a_file" / "x.hlod"))
    clash.wait(120.0)
    unwritable.wait(120.0)
    errors = {name: [type(job.error).__name__, str(job.error)] for name, job in
              (("clash", clash), ("unwritable", unwritable))}
    first = next(iter(children.values()), {})
    env = first.get("environ", {})
    return {"result": result, "blender_pid": os.getpid(), "executable": sys.executable,
            "children": {str(pid): {"cmdline": seen["cmdline"], "max_workers": seen["max_workers"]}
                         for pid, seen in children.items()},
            "child_pythonpath": env.get("PYTHONPATH", "").split(os.pathsep),
            "child_tmpdir": env.get("TMPDIR"), "extension_dir": package.__path__[0],
            "arrays_equal": arrays_equal, "meta_equal": comparable(child.meta) == comparable(here.meta),
            "meta_differs": sorted(k for k in {*comparable(child.meta), *comparable(here.meta)}
                                   if comparable(child.meta).get(k) != comparable(here.meta).get(k)),
            "file_jobs": child.meta["settings"]["jobs"], "last_bake": first_line, "first_cache": first_cache,
            "again": again, "again_cache": rebaked.meta.get(CACHE_KEY), "again_last_bake": props.last_bake,
            "again_same": same_again, "first_size": len(first_bytes),
            "cache_folder": sorted(p.name for p in out_path.parent.iterdir() if p.is_dir()),
            "errors": errors, "tmp_left": _leftovers(tmp), "temps_beside": _temps_beside(out_path),
            "group_alive": [pid for seen in children.values() for pid in seen["group"] if alive(pid)]}


def check_cancel(repo, work) -> dict:
    """A bake job (the modal operator's, driven directly: a headless bpy has no events to send it)
    of 16 subdivided Suzannes with jobs 2, cancelled while its workers decimate: the child and its
    workers are gone within GONE_WITHIN_SECONDS, the job reports BakeCancelled, the earlier file is
    byte-identical, nothing is left beside it, and the scratch folder (the child's hlod-bake-*
    folder inside it) is gone."""
    blender_preview.enable_from_repo(repo)
    tmp = _private_tmp(work)
    m = _modules()
    _monkeys(16, 2)
    mesh = m["addon.scene.gather"].gather(bpy.context, list(bpy.context.selected_objects)).mesh
    out_path = Path(work) / "monkeys.hlod"
    pipeline = m["hlod_core.bake.pipeline"]
    small = pipeline.bake(mesh, pipeline.BakeSettings(target_tris=1_000_000, max_depth=0))
    m["hlod_core.io.hlod_file"].save(small, out_path)  # the earlier file: the mesh as one node
    earlier = out_path.read_bytes()
    job = m["addon.bake.job"].BakeJob(mesh, pipeline.BakeSettings(jobs=2), str(out_path))
    started = _wait_until(lambda: len(workers(job.pid)) >= 2 and job.progress[2] == "simplify", 120.0)
    decimating = _wait_decimating(job, 120.0)
    processes = group(job.pid)
    worker_pids = workers(job.pid)
    scratch_seen = _leftovers(tmp)
    before_cancel = job.progress
    t0 = time.perf_counter()
    job.cancel()
    gone = _wait_until(lambda: not any(alive(pid) for pid in processes), 10.0)
    job.wait(30.0)
    return {"tris": mesh.tri_count, "workers_started_s": started, "decimating_s": decimating, "processes": processes,
            "workers": worker_pids, "progress": before_cancel,
            "scratch_seen": scratch_seen, "gone_s": gone, "finished_s": time.perf_counter() - t0,
            "error": type(job.error).__name__, "running": job.running, "earlier_kept": out_path.read_bytes() == earlier,
            "temps_beside": _temps_beside(out_path), "tmp_left": _leftovers(tmp),
            "alive_after": [pid for pid in processes if alive(pid)]}


def check_kill(repo, work) -> dict:
    """The Bake operator (jobs 2) on 16 subdivided Suzannes, its child killed with SIGKILL from
    outside while the workers decimate: the operator reports the signal and the child's last
    stderr lines, this process goes on (and bakes again), the earlier .hlod is byte-identical and
    still the scene's file, the orphaned workers are gone, no scratch is left."""
    blender_preview.enable_from_repo(repo)
    tmp = _private_tmp(work)
    props = bpy.context.scene.hlod
    out_path = Path(work) / "scene.hlod"
    blender_checks._box_row_scene()
    props.output_path, props.target_tris, props.jobs = str(out_path), 400, 2
    first = sorted(bpy.ops.hlod.bake())
    earlier, earlier_file = out_path.read_bytes(), props.file
    _monkeys(16, 2)
    killed: dict = {}

    def kill(child, worker_pids):
        # the workers start with the bake and import pymeshlab while it prepares; kill once they
        # decimate (the operator's job is the running one)
        _wait_decimating(importlib.import_module(NAME + ".addon.bake.job").active(), 60.0)
        killed.update(child=child, group=group(child), workers=worker_pids)
        os.kill(child, signal.SIGKILL)

    message = ""
    with Spy(on_workers=kill, min_workers=2):
        try:
            result = sorted(bpy.ops.hlod.bake())
        except RuntimeError as exc:
            result, message = ["CANCELLED"], str(exc)
    state = {"earlier_kept": out_path.read_bytes() == earlier, "file_kept": props.file == earlier_file,
             "temps_beside": _temps_beside(out_path), "tmp_left": _leftovers(tmp),
             "alive_after": [pid for pid in killed.get("group", []) if alive(pid)]}
    blender_checks._box_row_scene()  # Blender goes on: the next bake works
    again = sorted(bpy.ops.hlod.bake())
    return {"first": first, "result": result, "message": message, "killed": killed, **state, "again": again,
            "again_file": props.file, "tmp_left_after_again": _leftovers(tmp)}


def check_parent_dies(repo, work) -> dict:
    """Blender dies mid-bake: a bake job of 16 subdivided Suzannes with jobs 2 is started, and once
    its workers decimate this process prints the child's pid and its group and ends at once
    (os._exit: no cleanup of its own). The test then watches the child notice (its stdin reaches
    end of file), stop its group and remove the job's files."""
    blender_preview.enable_from_repo(repo)
    tmp = _private_tmp(work)
    m = _modules()
    _monkeys(16, 2)
    mesh = m["addon.scene.gather"].gather(bpy.context, list(bpy.context.selected_objects)).mesh
    settings = m["hlod_core.bake.pipeline"].BakeSettings(jobs=2)
    job = m["addon.bake.job"].BakeJob(mesh, settings, str(Path(work) / "x.hlod"))
    started = _wait_until(lambda: len(workers(job.pid)) >= 2 and job.progress[2] == "simplify", 120.0)
    out = {"child": job.pid, "group": group(job.pid), "workers_started_s": started, "tmp": str(tmp),
           "scratch": _leftovers(tmp)}
    print("\n" + json.dumps(out), flush=True)
    os._exit(0)


def check_cli_jobs(repo, work) -> dict:
    """The background command (`--command hlod bake`, the function Blender registers) with
    `--jobs 2 --error bound` on the open file: exit status 0, the summary says 2 jobs, a child with
    2 workers baked it, and the file records jobs 2 and the bound; `--jobs -1` is refused as a bad
    argument (the core command's option: exit status 2, one stderr line, no summary)."""
    blender_preview.enable_from_repo(repo)
    tmp = _private_tmp(work)
    cli = importlib.import_module(NAME + ".addon.cli")
    fileformat = importlib.import_module(NAME + ".hlod_core.io.hlod_file")
    blender_checks._box_row_scene()
    out_path = Path(work) / "cli.hlod"
    stdout = io.StringIO()
    with Spy() as spy, contextlib.redirect_stdout(stdout):
        status = cli.execute(["bake", "--jobs", "2", "--target-tris", "400", "--error", "bound", "-o", str(out_path)])
    summary = json.loads(stdout.getvalue().strip().splitlines()[-1])
    bad, bad_err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(bad), contextlib.redirect_stderr(bad_err):
        bad_status = cli.execute(["bake", "--jobs", "-1", "-o", str(Path(work) / "bad.hlod")])
    return {"status": status, "summary": summary,
            "children": [seen["max_workers"] for seen in spy.children.values()],
            "file_jobs": fileformat.load(out_path).meta["settings"]["jobs"] if out_path.is_file() else None,
            "file_error": fileformat.load(out_path).meta["settings"].get("error") if out_path.is_file() else None,
            "bad_status": bad_status, "bad_stdout": bad.getvalue(), "bad_stderr": bad_err.getvalue(),
            "tmp_left": _leftovers(tmp)}


def _mixed_statues(detail: int = 1) -> list:
    """Sixteen statues on a 4 x 4 grid, two meshes alternating: a UV sphere with UVs and a
    material, an ico sphere with neither (mixed attribute layouts: its rows get the default
    material and zero UVs). detail (a power of two) multiplies the sphere's segments and rings
    and each statue's triangles by detail^2 (1: 1,520 and 1,280 triangles)."""
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    stone = bpy.data.materials.new("Stone")
    stone.diffuse_color = (0.6, 0.5, 0.4, 1.0)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=40 * detail, ring_count=20 * detail, radius=0.8)
    textured = bpy.context.active_object
    textured.data.materials.append(stone)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4 + int(np.log2(detail)), radius=0.8)
    plain = bpy.context.active_object
    while plain.data.uv_layers:
        plain.data.uv_layers.remove(plain.data.uv_layers[0])
    statues = []
    for i in range(4):
        for j in range(4):
            source = textured if (i + j) % 2 == 0 else plain
            statue = source.copy()
            statue.name = f"statue {i} {j}"
            statue.location = (2.0 * i, 2.0 * j, 0.0)
            bpy.context.scene.collection.objects.link(statue)
            statues.append(statue)
    bpy.data.objects.remove(textured)
    bpy.data.objects.remove(plain)
    bpy.context.view_layer.update()
    return statues


def check_cache_mixed_scene(repo, work) -> dict:
    """The bake cache on a scene of two meshes with different attribute layouts (`_mixed_statues`),
    through the background command: a re-bake after linking a statue again (the depsgraph then
    lists the objects in another order; the geometry is the same) takes the whole result from the
    cache; after moving an interior statue by 0.05 it rebuilds only the inner nodes above it and
    the file equals a bake from scratch (--no-cache); after moving the corner statue outward by a
    tenth of the scene's extent it keeps the frame the cache holds, and the file equals a bake from
    scratch in the first file's frame (--no-cache --frame-from)."""
    blender_preview.enable_from_repo(repo)
    _private_tmp(work)
    cli = importlib.import_module(NAME + ".addon.cli")
    fileformat = importlib.import_module(NAME + ".hlod_core.io.hlod_file")
    statues = _mixed_statues()
    out_path, fresh_path = Path(work) / "statues.hlod", Path(work) / "fresh.hlod"

    def bake(path: Path, *extra: str) -> dict:
        with contextlib.redirect_stdout(io.StringIO()) as stdout:
            # the sources' materials on every level, as this check was written (proxy bakes' cache: test_cache_proxies)
            status = cli.execute(["bake", "--target-tris", "300", "--keep-materials", *extra, "-o", str(path)])
        summary = json.loads(stdout.getvalue().strip().splitlines()[-1])["files"][0]
        return {"status": status, "cache": summary.get("cache"), "error": summary.get("error"),
                "jobs": summary.get("jobs")}

    def order() -> list[str]:
        return [inst.object.name for inst in bpy.context.evaluated_depsgraph_get().object_instances][:4]

    names = ("parent", "child_offset", "child_count", "box_min", "box_max", "error", "origin", "positions", "indices",
             "uvs", "tri_material")

    def arrays_differ(path_a: Path, path_b: Path) -> list[str]:
        a, b = fileformat.load(path_a), fileformat.load(path_b)
        return [name for name in names if not np.array_equal(getattr(a, name), getattr(b, name))]

    first = bake(out_path)
    first_path = Path(work) / "first.hlod"
    first_path.write_bytes(out_path.read_bytes())
    order_before = order()
    bpy.context.scene.collection.objects.unlink(statues[0])
    bpy.context.scene.collection.objects.link(statues[0])
    bpy.context.view_layer.update()
    order_after = order()
    relinked = bake(out_path)
    relinked_differ = arrays_differ(first_path, out_path)
    statues[5].location.x += 0.05  # statue 1 1: inside the grid, the scene's box unchanged
    bpy.context.view_layer.update()
    moved = bake(out_path)
    fresh = bake(fresh_path, "--no-cache")
    moved_differ = arrays_differ(out_path, fresh_path)
    a = fileformat.load(out_path)
    statues[0].location.x -= 0.76  # statue 0 0, at the corner: a tenth of the scene's 7.6 units, outward
    bpy.context.view_layer.update()
    edge = bake(out_path)
    edge_fresh = bake(fresh_path, "--no-cache", "--frame-from", str(first_path))
    edge_meta, edge_fresh_meta = fileformat.load(out_path).meta, fileformat.load(fresh_path).meta
    return {"first": first, "relinked": relinked, "moved": moved, "fresh": fresh, "order_before": order_before,
            "order_after": order_after, "relinked_arrays_differ": relinked_differ,
            "moved_arrays_differ": moved_differ,
            "materials": [m.name for m in a.materials], "inner_nodes": int(np.count_nonzero(a.child_count)),
            "edge": edge, "edge_fresh": edge_fresh, "edge_frame_source": edge_meta.get("frame_source"),
            "edge_fresh_frame_source": edge_fresh_meta.get("frame_source"),
            "edge_same_frame": edge_meta.get("frame") == edge_fresh_meta.get("frame"),
            "edge_arrays_differ": arrays_differ(out_path, fresh_path)}


def check_mixed_rebake_speed(repo, work, detail: str = "8", jobs: str = "2") -> dict:
    """Benchmark (benchmarks/bench_blender_mixed_rebake.py): `_mixed_statues(detail)` through the
    background command with the cache: a full bake, a re-bake after moving an interior statue by
    0.05 (the scene's box unchanged), and a bake of the moved scene from scratch, wall seconds of
    each (cli.execute: gathering the mesh in Blender, the child's bake, the write)."""
    blender_preview.enable_from_repo(repo)
    _private_tmp(work)
    cli = importlib.import_module(NAME + ".addon.cli")
    fileformat = importlib.import_module(NAME + ".hlod_core.io.hlod_file")
    statues = _mixed_statues(int(detail))
    out_path, fresh_path = Path(work) / "statues.hlod", Path(work) / "fresh.hlod"

    def bake(path: Path, *extra: str) -> tuple[float, dict]:
        started = time.perf_counter()
        with contextlib.redirect_stdout(io.StringIO()) as stdout:
            cli.execute(["bake", "--jobs", jobs, "--keep-materials", *extra, "-o", str(path)])
        return time.perf_counter() - started, json.loads(stdout.getvalue().strip().splitlines()[-1])["files"][0]

    full_s, full = bake(out_path)
    statues[5].location.x += 0.05
    bpy.context.view_layer.update()
    moved_s, moved = bake(out_path)
    fresh_s, fresh = bake(fresh_path, "--no-cache")
    a, b = fileformat.load(out_path), fileformat.load(fresh_path)
    names = ("parent", "child_count", "box_min", "box_max", "error", "positions", "indices", "uvs", "tri_material")
    return {"tris": full.get("input_tris"), "full_s": full_s, "moved_s": moved_s, "fresh_s": fresh_s,
            "cache": moved.get("cache"), "identical": all(np.array_equal(getattr(a, n), getattr(b, n)) for n in names),
            "load_1min": os.getloadavg()[0]}


# Operators this check knows how to run, in order, with their arguments (set up by check_every_operator).
OPERATOR_RUNS = ("bake", "preview_toggle", "materialize", "export", "view_tiles", "benchmark", "tune_psnr",
                 "preview_toggle", "clear")


def check_every_operator(repo, work) -> dict:
    """Every operator the installed extension registers (enumerated from bpy.ops.hlod, so a new one
    cannot be missed: one this check does not know is reported) runs to FINISHED in this Blender's
    environment, where only Blender's own modules and the extension's wheels import (no matplotlib:
    the Benchmark writes its report without figures). Tune to PSNR runs on the same
    animated camera from s, t, bias = 0.42, 0.42, mu (no candidate of its search): what it set on
    the scene and the report it wrote come back under "tuning"."""
    import importlib.util

    blender_preview.enable_from_repo(repo)
    blender_preview.init_gpu()
    tmp = _private_tmp(work)
    blender_checks._box_row_scene()
    scene = bpy.context.scene
    props = scene.hlod
    props.output_path, props.target_tris = str(Path(work) / "row.hlod"), 400
    blender_preview.camera(scene, eye=(1.5, -8.0, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
    camera = scene.camera
    scene.frame_start, scene.frame_end = 1, 2
    camera.keyframe_insert("location", frame=1)
    camera.location = (1.5, -6.0, 1.5)
    camera.keyframe_insert("location", frame=2)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 120, 90, 100
    os.environ["BROWSER"] = "true"  # View in Browser serves and "opens" the page with the `true` command
    arguments = {"materialize": {"depth": 1},
                 "export": {"filepath": str(Path(work) / "copy.hlod"), "format": "3DTILES"},
                 "benchmark": {"directory": str(Path(work) / "report"), "repeat": 1},
                 "tune_psnr": {"directory": str(Path(work) / "tuning"), "repeat": 1}}
    props.s, props.t, props.bias, props.psnr_target = 0.42, 0.42, "mu", 40.0
    registered = sorted(name for name in dir(bpy.ops.hlod) if not name.startswith("_"))
    results = {}
    for name in OPERATOR_RUNS:
        try:
            results.setdefault(name, []).append(sorted(getattr(bpy.ops.hlod, name)(**arguments.get(name, {}))))
        except RuntimeError as exc:
            results.setdefault(name, []).append(f"error: {exc}")
    bpy.ops.hlod.view_tiles(stop=True)
    report = Path(work) / "report"
    tuned = Path(work) / "tuning"
    done = (tuned / "report.json").is_file()
    no_figures = done and "No figures: they were not drawn here" in (tuned / "report.md").read_text()
    return {"tuning": {"s": props.s, "t": props.t, "bias": props.bias, "last_tuning": props.last_tuning,
                       "psnr_target": json.loads((tuned / "report.json").read_text())["psnr_target"] if done else None,
                       "says_no_figures": no_figures},
            "registered": registered, "unknown": sorted(set(registered) - set(OPERATOR_RUNS)),
            "results": results, "matplotlib": importlib.util.find_spec("matplotlib") is not None,
            "report_says_no_figures": (report / "report.md").is_file()
            and "No figures: they were not drawn here" in (report / "report.md").read_text(),
            "report_figures": json.loads((report / "report.json").read_text())["figures"]
            if (report / "report.json").is_file() else None,
            "tmp_left": _leftovers(tmp)}


def check_bake_speed(repo, work, repeats: str = "1") -> dict:
    """Measurement: a collection of 64 Suzannes at subdivision level 2 (1,007,616
    triangles) baked by the Bake operator with jobs 1 and jobs 2, alternating, `repeats` pairs; and
    the child's overhead on the box row (5,028 triangles): the operator's whole bake (gather,
    scratch write, child start-up, bake, save) against an in-process bake() + save of the same mesh
    with jobs 1, as the add-on baked before (median of 5 each). Without the bake cache: every bake
    decimates and measures everything."""
    blender_preview.enable_from_repo(repo)
    _private_tmp(work)
    m = _modules()
    props = bpy.context.scene.hlod
    tris = _monkeys(64, 2, "city")
    props.source, props.collection = "COLLECTION", bpy.data.collections["city"]
    props.output_path, props.use_cache = str(Path(work) / "city.hlod"), False  # every bake from scratch
    seconds = {1: [], 2: []}
    for _ in range(int(repeats)):
        for jobs in (1, 2):
            props.jobs = jobs
            started = time.perf_counter()
            assert sorted(bpy.ops.hlod.bake()) == ["FINISHED"]
            seconds[jobs].append(time.perf_counter() - started)
    baked_tris = int(m["hlod_core.io.hlod_file"].load(props.output_path).meta["input_tris"])
    # the overhead of the child on a small scene
    blender_checks._box_row_scene()
    props.source, props.jobs, props.output_path, props.target_tris = "SELECTED", 1, str(Path(work) / "row.hlod"), 400
    objects = importlib.import_module(NAME + ".addon.scene.objects").source_objects(bpy.context, props)
    bake = m["hlod_core.bake.pipeline"]
    child_s, here_s = [], []
    for _ in range(5):
        started = time.perf_counter()
        assert sorted(bpy.ops.hlod.bake()) == ["FINISHED"]
        child_s.append(time.perf_counter() - started)
        started = time.perf_counter()
        mesh = m["addon.scene.gather"].gather(bpy.context, objects).mesh
        m["hlod_core.io.hlod_file"].save(bake.bake(mesh, bake.BakeSettings(target_tris=400, jobs=1)),
                                       Path(work) / "row_here.hlod")
        here_s.append(time.perf_counter() - started)
    one, two = statistics.median(seconds[1]), statistics.median(seconds[2])
    return {"tris": tris, "baked_tris": baked_tris, "jobs1_s": seconds[1], "jobs2_s": seconds[2],
            "speedup": one / two, "load_1min": os.getloadavg()[0], "cores": os.cpu_count(),
            "small_tris": int(m["hlod_core.io.hlod_file"].load(Path(work) / "row.hlod").meta["input_tris"]),
            "small_child_s": statistics.median(child_s), "small_in_process_s": statistics.median(here_s),
            "small_overhead_s": statistics.median(child_s) - statistics.median(here_s)}


if __name__ == "__main__":
    repo_dir, check, work_dir = sys.argv[1:4]
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    result = globals()[f"check_{check}"](repo_dir, work_dir, *sys.argv[4:])
    print("\n" + json.dumps(result))  # on a line of its own: Blender may leave a report unterminated
    blender_preview.exit_process(0)  # bpy 4.2 can crash at exit (see blender_preview.exit_process)
