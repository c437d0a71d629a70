"""How a bake scales with its workers: each phase's time, the work and bytes of every parallel task,
a model of the wall time on N workers (1 to 256), and that model checked against real bakes.

    PYTHONPATH=. .venv/bin/python -m benchmarks.bake_scaling [--tris 2000000] [--no-dask] [--out DIR]

--tris: the scene's size, built as benchmarks/bake_memory.py builds it (the crowd's statues from
the repository's models, then copies of the whole crowd side by side: a city of statues); 2M by
default (this 2-core machine), 20M for the issue's target scene (a bake of several minutes a run).

In one run, on this machine:
1. Profile: one jobs 1 bake in this process with every parallel task timed as it runs (no worker,
   no transfer): per task its kind, node, seconds and the numpy bytes it sends and returns; the
   bake's own phase_seconds; the leaf arrays' build (serial, in the bake's process); per pass of
   prepare's and the octree's chunk tasks (chunk_store.ChunkStore.run), its tasks' seconds and bytes.
2. Per-task cost of the executors: tasks that do nothing, empty and carrying a typical decimation's
   arrays, 2 in flight on a local pool of 2 spawned processes and on a LocalCluster of 2 worker
   processes x 1 thread: the round trip per task (wall) and the bake's process's CPU per task; the
   rate at which a chunk store takes an array (written to shared memory and mapped).
   Cost of a task of b bytes = round trip(empty) + b x (round trip(loaded) - round trip(empty)) / b_loaded.
3. Model (`model_seconds`): wall(N) = serial + simplify(N). serial: the phases outside the simplify
   phase (prepare, octree, leaves, seams, assemble), prepare's, the octree's and the leaves' passes as their
   tasks over index chunks on N workers (`chunk_phases`: each pass's profiled work re-cut into the
   regions the bake makes for N workers, plus the executor's cost a task and the store's copies),
   the seams' buckets as their tasks on N workers;
   the leaf arrays, which the measurements wait for, their clusters as their tasks on N workers;
   simplify(N): the profiled tasks list-scheduled on N workers in the bake's own order (schedule.py:
   decimations deepest first once their children are decimated, then measurements largest first),
   each task its profiled seconds plus its executor cost (none at N = 1: inline), and at least
   tasks x the bake's process's CPU per task (its one event loop). The task-size distribution and
   the dependency chain decide the tail; Amdahl's serial part the limit.
4. Check: real bakes by the command line in fresh processes (`python -m hlod_core bake SPEC
   --no-cache`): jobs 1, jobs 2, and `--scheduler` on the LocalCluster (2 workers), each its
   bake_seconds against the model's, the error printed; the coordinating process's peak RSS (VmHWM,
   reading the input included) per input triangle; every file the same as the jobs 1 file
   (arrays and meta less meta.VOLATILE_META; jobs 2's meta says jobs 2).
The load average is recorded with every bake: the model assumes N free cores, and this machine's 2
cores are shared.

Data form: out/bake_scaling.json: {"tris", "phases", "tasks", "overhead", "model": {N: seconds},
"measured": [...], "load": [...]}.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import heapq
import json
import multiprocessing
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks import bake_memory
from benchmarks.dask_bake import WORKER_PROFILE, _noop, _sample_children
from hlod_core.bake.decimate import cell_seams, simplify
from hlod_core.bake.measure import hausdorff, leaf_arrays
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run import dask_cluster, schedule, tasks
from hlod_core.bake.run import workers as workers_module
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space import chunk_store
from hlod_core.io import meshes

ROOT = Path(__file__).resolve().parents[1]
#: The worker counts the model is evaluated at.
WORKERS = (1, 2, 4, 8, 16, 32, 64, 128, 256)
#: The phases of a bake outside its parallel tasks (phase_seconds' names); "simplify" holds the tasks.
SERIAL_PHASES = ("scan", "prepare", "octree", "route", "leaves", "seams", "cache", "assemble", "cache_write")
#: The phase each chunk task belongs to (chunk_store.ChunkStore.run's tasks; the others are the octree's).
CHUNK_PHASE = {"mark_used_task": "prepare", "used_box_task": "prepare", "position_task": "prepare",
               "centroid_task": "prepare", "leaf_task": "leaves"}
#: Tasks timed per executor for its per-task cost.
OVERHEAD_TASKS = 200


def profile(mesh, settings: BakeSettings) -> dict:
    """Part 1: a jobs 1 bake, every task of the simplify phase timed in this process. A task's node:
    a decimation's is the parent of its first child, found by the child's positions array (the
    leaves' from the lods the seams phase reads, the inner nodes' as their decimations return them);
    an exact measurement's by its ranges into the leaf arrays."""
    records: list[dict] = []
    decimate, measure, measure_children = simplify.decimate_node, tasks.measure_exact, hausdorff.measure_to_children
    build_seams, build_arrays, cut = cell_seams.build, leaf_arrays.build, hausdorff.Clusters.build
    seen: dict = {"by_array": {}, "by_ranges": {}}

    def record(kind: int, node: int, started: float, sent, value) -> None:
        records.append({"kind": kind, "node": int(node), "seconds": time.perf_counter() - started,
                        "sent": dask_cluster.array_bytes(sent),
                        "returned": 8 if isinstance(value, float) else dask_cluster.array_bytes(value)})

    def timed_decimate(children, *args, **options):
        started = time.perf_counter()
        lod = decimate(children, *args, **options)
        node = int(seen["layout"].parent[seen["by_array"][id(children[0][0])]])
        seen["by_array"][id(lod.positions)] = node
        record(schedule.TASK_DECIMATE, node, started, children, lod)
        return lod

    def timed_measure(folder, lod, ranges):
        started = time.perf_counter()
        value = measure(folder, lod, ranges)
        record(schedule.TASK_MEASURE, seen["by_ranges"][tuple(ranges)], started, lod, value)
        return value

    def timed_measure_children(lod, children):
        started = time.perf_counter()
        value = measure_children(lod, children)
        record(schedule.TASK_MEASURE, seen["by_array"][id(lod[0])], started, (lod, children), value)
        return value

    def timed_clusters(*args, **options):
        started = time.perf_counter()
        made = cut(*args, **options)
        seen["clusters"] = {"seconds": time.perf_counter() - started, "faces": int(made.faces.shape[0]),
                            "bytes": int(2 * made.faces.nbytes + np.asarray(args[0]).nbytes)}
        return made

    def timed_arrays(layout, lods, **options):
        started = time.perf_counter()
        made = build_arrays(layout, lods, **options)
        seen["leaf_arrays_seconds"] = time.perf_counter() - started
        seen["by_ranges"] = {made.ranges(int(node)): int(node) for node in np.flatnonzero(~layout.is_leaf)}
        return made

    def timed_seams(layout, lods, **options):
        started = time.perf_counter()
        made = build_seams(layout, lods, **options)
        seconds = time.perf_counter() - started
        seen["layout"] = layout
        seen["by_array"].update({id(lods[leaf][0]): int(leaf) for leaf in np.flatnonzero(layout.is_leaf)})
        seen["seams"] = seams_tasks(layout, lods, seconds)
        return made

    passes: list[dict] = []
    run_chunks = chunk_store.ChunkStore.run

    def timed_run(store, fn, calls):
        out, seconds = [], []
        calls = list(calls)
        for call in calls:
            started = time.perf_counter()
            out.append(fn(store, *call))
            seconds.append(time.perf_counter() - started)
        moved = [dask_cluster.array_bytes(call) + dask_cluster.array_bytes(value) for call, value in zip(calls, out)]
        passes.append({"fn": fn.__name__, "tasks": len(calls), "seconds": float(sum(seconds)),
                       "max_s": float(max(seconds, default=0.0)), "bytes": float(np.mean(moved)) if moved else 0.0})
        return out

    chunk_store.ChunkStore.run = timed_run
    cell_seams.build, leaf_arrays.build = timed_seams, timed_arrays
    hausdorff.Clusters.build = staticmethod(timed_clusters)
    simplify.decimate_node, tasks.measure_exact = timed_decimate, timed_measure
    hausdorff.measure_to_children = timed_measure_children
    try:
        started = time.perf_counter()
        hlod = bake(mesh, BakeSettings(**{**settings.__dict__, "jobs": 1}))
        seconds = time.perf_counter() - started
    finally:
        simplify.decimate_node, tasks.measure_exact, hausdorff.measure_to_children = decimate, measure, measure_children
        cell_seams.build, leaf_arrays.build = build_seams, build_arrays
        hausdorff.Clusters.build = staticmethod(cut)
        chunk_store.ChunkStore.run = run_chunks
    layout = seen["layout"]
    phases = {**hlod.meta["phase_seconds"], "seams": seen["seams"]["seconds"]}  # less this profile's own sampling
    return {"bake_seconds": seconds, "input_tris": mesh.tri_count, "input_vertices": int(mesh.positions.shape[0]),
            "chunk_passes": passes, "nodes": hlod.node_count, "phase_seconds": phases,
            "seams": seen["seams"], "leaf_arrays_seconds": seen.get("leaf_arrays_seconds", 0.0),
            "clusters": seen.get("clusters", {"seconds": 0.0, "faces": 0, "bytes": 0}),
            "tasks": records, "parent": layout.parent.tolist(), "is_leaf": layout.is_leaf.tolist(),
            "depth": layout.depth.tolist(), "node_tris": (layout.tri_end - layout.tri_begin).tolist()}


def seams_tasks(layout, lods, seconds: float) -> dict:
    """The seams phase's split (cell_seams.build took `seconds` inline): each bucket task reads every
    leaf vertex (h seconds) and sorts its bucket's (s / buckets); timed here on one bucket of 1 and
    one of 8 (the leaves' positions in memory); the rest of `seconds` is the bake's process's own."""
    leaves = np.flatnonzero(layout.is_leaf)
    leaves = leaves[np.argsort(layout.tri_begin[leaves], kind="stable")]
    ends = np.cumsum([lods[leaf][0].shape[0] for leaf in leaves])
    positions = cell_seams.concat_positions(lods, leaves, int(ends[-1]), None)
    timed = {}
    for buckets in (1, 8):
        started = time.perf_counter()
        cell_seams.shared_in_bucket(positions, ends, bucket=0, buckets=buckets)
        timed[buckets] = time.perf_counter() - started
    sort = max(timed[1] - timed[8], 0.0) * 8 / 7
    read = max(timed[1] - sort, 0.0)
    used = max(1, -(-int(ends[-1]) // cell_seams.BUCKET_VERTICES))  # the profile's buckets (jobs 1)
    return {"seconds": seconds, "vertices": int(ends[-1]), "leaves": int(leaves.size), "read_s": read,
            "sort_s": sort, "own_s": max(seconds - used * read - sort, 0.0), "task_bytes": int(8 * leaves.size)}


def seams_seconds(seams: dict, workers: int, cost: float) -> float:
    """The seams phase on `workers` workers: the bake's process's own part, then max(workers, the
    buckets the size needs) bucket tasks list-scheduled, each read + sort / buckets + cost."""
    buckets = max(workers, -(-seams["vertices"] // cell_seams.BUCKET_VERTICES))
    rounds = -(-buckets // workers)
    return seams["own_s"] + rounds * (seams["read_s"] + seams["sort_s"] / buckets + cost)


def arrays_seconds(prof: dict, workers: int, over: dict | None) -> float:
    """The leaf arrays on `workers` workers (leaf_arrays.build): the concatenation in the bake's
    process, then the clusters in runs of whole leaves as tasks (leaf_arrays.cut_clusters' count),
    each its share of the profiled cut plus its executor cost."""
    whole, clusters = prof["leaf_arrays_seconds"], prof["clusters"]
    if workers < 2 or over is None or clusters["faces"] < leaf_arrays.PARALLEL_FROM_FACES:
        return whole
    pieces = int(min(max(2, clusters["faces"] // leaf_arrays.TASK_FACES), 4 * workers))
    each = clusters["seconds"] / pieces + float(task_cost(over, np.array([clusters["bytes"] / pieces]))[0])
    return whole - clusters["seconds"] + -(-pieces // workers) * each


def chunk_phases(prof: dict, workers: int, over: dict | None) -> dict:
    """Prepare, the octree and the leaves on `workers` workers (chunk_store.py): per phase, its own
    part (the profiled phase less its passes' tasks), each pass's tasks re-cut into the regions the
    bake makes for that many workers (chunk_store.regions), list-scheduled, each its share of the
    pass's profiled work plus its executor cost for its bytes (the leaves, made leaf by leaf in the
    inline profile, as one pass of their whole time, each task sending back its leaves' positions
    and faces, 12 bytes a leaf vertex and a face); with workers, the store's copies (the
    faces and the input's positions in; the positions, counted and tri_order out) at the measured
    copy rate. "own_s": the phases' time outside tasks."""
    phases = prof["phase_seconds"]
    out = {"own_s": 0.0}
    work = {phase: [p for p in prof["chunk_passes"] if CHUNK_PHASE.get(p["fn"], "octree") == phase]
            for phase in ("prepare", "octree", "leaves")}
    if not work["leaves"]:  # made leaf by leaf in the inline profile: one pass of tasks, each sending its leaves back
        count = len(chunk_store.regions(prof["input_tris"], max(workers, 1)))
        work["leaves"] = [{"fn": "leaf_task", "tasks": count, "seconds": phases.get("leaves", 0.0),
                           "bytes": 12.0 * (prof["seams"]["vertices"] + prof["input_tris"]) / count}]
    on_workers = workers > 1 and over is not None and prof["input_tris"] >= chunk_store.WORKERS_FROM_ROWS
    copied = {"prepare": 25 * prof["input_tris"] + 36 * prof["input_vertices"], "octree": 8 * prof["input_tris"],
              "leaves": 0}  # in: faces, positions (float64); out: positions (float32), counted; tri_order
    for phase, passes in work.items():
        own = max(phases.get(phase, 0.0) - sum(p["seconds"] for p in passes), 0.0)
        if on_workers:
            count = len(chunk_store.regions(prof["input_tris"], workers))
            cost = float(task_cost(over, np.array([np.mean([p["bytes"] for p in passes]) if passes else 0.0]))[0])
            tasks = sum(-(-count // workers) * (p["seconds"] / count + cost) for p in passes)
            own += over.get("copy_s_per_byte", 0.0) * copied[phase]
        else:
            tasks = sum(p["seconds"] for p in passes)
        out[phase] = own + tasks
        out["own_s"] += own
    return out


def copy_rate() -> float:
    """Seconds per byte to write an array into a chunk store's folder in shared memory (or the
    temporary folder) and map it back, as prepare's store copies do: 48 MB, the best of 3."""
    folder = workers_module.SHARED_MEMORY if os.path.isdir(workers_module.SHARED_MEMORY) else None
    values = np.ones((2_000_000, 3), np.int64)
    best = float("inf")
    with tempfile.TemporaryDirectory(prefix="bake-scaling-copy-", dir=folder) as scratch:
        store = chunk_store.ChunkStore(scratch)
        for _ in range(3):
            started = time.perf_counter()
            store.put("values", values)
            best = min(best, time.perf_counter() - started)
            store.drop("values")
    return best / values.nbytes


def _round_trips(executor, payload, *, in_flight: int = 2, count: int = OVERHEAD_TASKS, **options) -> dict:
    """Wall and this process's CPU per task of `count` tasks doing nothing with `payload`."""
    running: set = set()
    started, cpu = time.perf_counter(), time.process_time()
    for _ in range(count):
        while len(running) >= in_flight:
            _, running = cf.wait(running, return_when=cf.FIRST_COMPLETED)
        running.add(executor.submit(_noop, payload, **options))
    cf.wait(running)
    return {"wall_s": (time.perf_counter() - started) / count * in_flight,
            "coordinator_cpu_s": (time.process_time() - cpu) / count}


def overheads(client) -> dict:
    """Part 2: per-task cost of a local pool of 2 and (client given) of the Dask cluster."""
    payload = _sample_children(BakeSettings())
    nbytes = dask_cluster.array_bytes(payload)
    out = {}
    pool = cf.ProcessPoolExecutor(max_workers=2, mp_context=multiprocessing.get_context("spawn"))
    with pool:
        cf.wait([pool.submit(_noop) for _ in range(4)])  # started
        out["pool"] = {"empty": _round_trips(pool, None), "loaded": _round_trips(pool, payload),
                       "payload_bytes": nbytes, "copy_s_per_byte": copy_rate()}
    if client is not None:
        executor = dask_cluster.DaskExecutor(client)
        out["dask"] = {"empty": _round_trips(executor, None, priority=0),
                       "loaded": _round_trips(executor, payload, priority=0), "payload_bytes": nbytes,
                       "copy_s_per_byte": out["pool"]["copy_s_per_byte"]}
    return out


def task_cost(overhead: dict, nbytes: np.ndarray) -> np.ndarray:
    """Seconds an executor adds to tasks moving `nbytes` (overhead: one executor's part 2 figures)."""
    empty, loaded = overhead["empty"]["wall_s"], overhead["loaded"]["wall_s"]
    return empty + nbytes * max(loaded - empty, 0.0) / overhead["payload_bytes"]


def simulate(prof: dict, workers: int, cost: np.ndarray, *, measure_ready: float) -> float:
    """Seconds of the simplify phase on `workers` workers: the profiled tasks list-scheduled in the
    scheduler's order (schedule._Scheduler._push), each its seconds + cost[i]; measurements not
    before `measure_ready` (the leaf arrays)."""
    records = prof["tasks"]
    parent = np.asarray(prof["parent"])
    depth, node_tris = np.asarray(prof["depth"]), np.asarray(prof["node_tris"])
    seconds = {(r["kind"], r["node"]): r["seconds"] + cost[i] for i, r in enumerate(records)}
    todo = np.zeros(parent.size, bool)
    todo[[r["node"] for r in records if r["kind"] == schedule.TASK_DECIMATE]] = True
    waiting = np.zeros(parent.size, np.int64)
    kids = np.flatnonzero(todo & (parent >= 0))
    np.add.at(waiting, parent[kids], 1)
    ready = [(schedule.TASK_DECIMATE, -int(depth[n]), int(n)) for n in np.flatnonzero(todo & (waiting == 0))]
    heapq.heapify(ready)
    running: list[tuple[float, int, int]] = []
    now, deferred = 0.0, []
    while ready or running or deferred:
        while ready and len(running) < workers:
            kind, size, node = heapq.heappop(ready)
            if kind == schedule.TASK_MEASURE and now < measure_ready:
                deferred.append((kind, size, node))
                continue
            heapq.heappush(running, (now + seconds[(kind, node)], kind, node))
        if deferred and (not running or running[0][0] >= measure_ready):  # the leaf arrays come first
            now = max(now, measure_ready)
            for item in deferred:
                heapq.heappush(ready, item)
            deferred = []
            continue
        now, kind, node = heapq.heappop(running)
        if kind == schedule.TASK_DECIMATE:
            heapq.heappush(ready, (schedule.TASK_MEASURE, -int(node_tris[node]), node))
            up = int(parent[node])
            if up >= 0 and todo[up]:
                waiting[up] -= 1
                if waiting[up] == 0:
                    heapq.heappush(ready, (schedule.TASK_DECIMATE, -int(depth[up]), up))
    return now


def model_seconds(prof: dict, over: dict | None, workers: int) -> dict:
    """Part 3: the modelled bake_seconds on `workers` workers of an executor (over: its part 2
    figures; None at 1 worker: inline)."""
    phases = prof["phase_seconds"]
    chunked = chunk_phases(prof, workers, over)
    serial = sum(chunked.get(k, v) for k, v in phases.items() if k in SERIAL_PHASES)
    arrays = arrays_seconds(prof, workers, over)
    nbytes = np.array([r["sent"] + r["returned"] for r in prof["tasks"]], np.float64)
    seams = prof["seams"]
    if workers == 1 and over is None:
        simplify_s = arrays + simulate(prof, 1, np.zeros(nbytes.size), measure_ready=0.0)
        seams_s = phases["seams"]
    else:
        simplify_s = max(simulate(prof, workers, task_cost(over, nbytes), measure_ready=arrays),
                         len(prof["tasks"]) * over["loaded"]["coordinator_cpu_s"])
        parallel = seams["vertices"] >= cell_seams.PARALLEL_FROM_VERTICES
        seams_s = seams_seconds(seams, workers, float(task_cost(over, np.array([seams["task_bytes"]]))[0])) \
            if parallel else phases["seams"]
    serial = serial - phases["seams"] + seams_s
    own = serial - (seams_s - seams["own_s"] if workers > 1 else 0.0)  # outside any task
    own -= chunked["prepare"] + chunked["octree"] + chunked["leaves"] - chunked["own_s"] if workers > 1 else 0.0
    return {"serial_s": own + (arrays if workers > 1 else 0.0), "seams_s": seams_s, "simplify_s": simplify_s,
            "prepare_s": chunked["prepare"], "octree_s": chunked["octree"], "leaves_s": chunked["leaves"],
            "seconds": serial + simplify_s}


def measured(spec: Path, out: Path, *, jobs: int, scheduler: str | None = None) -> dict:
    """Part 4: one command-line bake (bake_memory.bake_measured), with its summary and load."""
    load = os.getloadavg()[0]
    run = bake_memory.bake_measured(spec, out, jobs, extra=["--scheduler", scheduler] if scheduler else [])
    run["load"] = [load, os.getloadavg()[0]]
    run["bytes_per_triangle"] = run["parent_peak_bytes"] / run["triangles"]
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tris", type=int, default=2_000_000, help="the scene's triangles (at least)")
    parser.add_argument("--no-dask", action="store_true", help="leave out the Dask cluster's bake")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    import contextlib

    import dask
    import distributed

    dask.config.set({WORKER_PROFILE: False})
    result: dict = {"load_before": os.getloadavg()}
    with tempfile.TemporaryDirectory(prefix="bake-scaling-") as scratch, contextlib.ExitStack() as stack:
        spec = bake_memory.spec_of(args.tris, Path(scratch))
        started = time.perf_counter()
        mesh = meshes.load_inputs([spec])
        result.update(tris=mesh.tri_count, load_seconds=time.perf_counter() - started)
        prof = profile(mesh, BakeSettings())
        del mesh
        client = None
        if not args.no_dask:
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0"))
            client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
        over = overheads(client)
        runs = [measured(spec, Path(scratch) / "jobs1.hlod", jobs=1),
                measured(spec, Path(scratch) / "jobs2.hlod", jobs=2)]
        if client is not None:
            runs.append(measured(spec, Path(scratch) / "dask2.hlod", jobs=1, scheduler=cluster.scheduler_address))
        reference = Path(scratch) / "jobs1.hlod"
        for run, name in zip(runs, ("jobs1", "jobs2", "dask2")):
            run["name"] = name
            run["same_file"] = bake_memory.same_file(reference, Path(scratch) / f"{name}.hlod", meta=name != "jobs2")
    result["overhead"] = over
    (args.out / "bake_scaling-raw.json").write_text(json.dumps({"result": result, "profile": prof, "runs": runs}))
    result["profile"] = {k: v for k, v in prof.items() if k not in ("parent", "is_leaf", "depth", "node_tris")}
    model = {str(n): model_seconds(prof, over["pool"] if n > 1 else None, n) for n in WORKERS}
    result["model"] = model
    checks = []
    for run in runs:
        over_of = None if run["name"] == "jobs1" else over["pool" if run["name"] == "jobs2" else "dask"]
        predicted = model_seconds(prof, over_of, 1 if run["name"] == "jobs1" else 2)["seconds"]
        actual = sum(run["summary"]["phase_seconds"].values())
        checks.append({"name": run["name"], "measured_s": actual, "model_s": predicted,
                       "error": predicted / actual - 1})
    result["measured"], result["checks"] = runs, checks
    result["load_after"] = os.getloadavg()
    (args.out / "bake_scaling.json").write_text(json.dumps(result, indent=2))
    report(result)


def report(result: dict) -> None:
    """The tables docs/performance.md#scaling-with-the-workers shows."""
    prof = result["profile"]
    phases = dict(prof["phase_seconds"])
    phases["load"] = result["load_seconds"]
    serial = sum(v for k, v in phases.items() if k in SERIAL_PHASES or k == "load") + prof["leaf_arrays_seconds"]
    print(f"scene: {result['tris']:,} triangles, {prof['nodes']:,} nodes; load {result['load_before'][0]:.1f} before, "
          f"{result['load_after'][0]:.1f} after")
    print("| " + " | ".join(phases) + " | leaf arrays | serial total |")
    print("|" + "---:|" * (len(phases) + 2))
    print("| " + " | ".join(f"{v:.2f} s" for v in phases.values())
          + f" | {prof['leaf_arrays_seconds']:.2f} s | **{serial:.2f} s** |")
    rows = prof["tasks"]
    for kind, name in ((schedule.TASK_DECIMATE, "decimate"), (schedule.TASK_MEASURE, "measure")):
        of = [r for r in rows if r["kind"] == kind]
        if of:
            secs = np.array([r["seconds"] for r in of])
            moved = np.array([r["sent"] + r["returned"] for r in of])
            print(f"{name}: {len(of)} tasks, {secs.sum():.1f} s, per task median {1e3 * np.median(secs):.1f} ms, "
                  f"p99 {1e3 * np.percentile(secs, 99):.0f} ms, max {1e3 * secs.max():.0f} ms; "
                  f"bytes moved per task median {np.median(moved) / 1e3:.0f} kB, max {moved.max() / 1e3:.0f} kB")
    for name in ("pool", "dask"):
        if name in result["overhead"]:
            o = result["overhead"][name]
            print(f"{name}: round trip {1e3 * o['empty']['wall_s']:.1f} ms empty, "
                  f"{1e3 * o['loaded']['wall_s']:.1f} ms with {o['payload_bytes'] / 1e3:.0f} kB; "
                  f"coordinator CPU {1e3 * o['loaded']['coordinator_cpu_s']:.2f} ms a task")
    one = result["model"]["1"]["seconds"]
    sm = prof["seams"]
    print(f"seams: {sm['seconds']:.2f} s inline over {sm['vertices']:,} leaf vertices: a bucket task reads them "
          f"all ({sm['read_s']:.2f} s) and sorts its share of {sm['sort_s']:.2f} s; {sm['own_s']:.2f} s in the bake's "
          "process")
    for p in prof["chunk_passes"][:1]:
        print(f"chunk passes: {len(prof['chunk_passes'])}, {sum(q['seconds'] for q in prof['chunk_passes']):.2f} s "
              f"of tasks inline ({sum(q['tasks'] for q in prof['chunk_passes'])} tasks); copy into the store "
              f"{1e9 * result['overhead']['pool']['copy_s_per_byte']:.2f} s/GB")
    print("| workers | modelled s | outside tasks s | prepare s | octree s | leaves s | seams s | simplify s | "
          "speed-up |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n, m in result["model"].items():
        print(f"| {n} | {m['seconds']:.1f} | {m['serial_s']:.2f} | {m['prepare_s']:.2f} | {m['octree_s']:.2f} | "
              f"{m['leaves_s']:.2f} | {m['seams_s']:.2f} | {m['simplify_s']:.1f} | {one / m['seconds']:.1f}x |")
    print(f"knee: {knee(result['model'])} workers (the first count whose doubling saves less than a quarter)")
    print("| run | measured s | modelled s | error | load | CPU s | peak RSS | bytes / triangle | same file |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---|")
    for run, check in zip(result["measured"], result["checks"]):
        print(f"| {run['name']} | {check['measured_s']:.1f} | {check['model_s']:.1f} | {100 * check['error']:+.1f}% | "
              f"{statistics.mean(run['load']):.1f} | {run['cpu_seconds']:.1f} | "
              f"{run['parent_peak_bytes'] / 2**20:.0f} MiB | "
              f"{run['bytes_per_triangle']:.0f} | {run['same_file']} |")


def knee(model: dict) -> int:
    """The first worker count whose doubling cuts the modelled time by less than a quarter."""
    counts = [int(n) for n in model]
    for n, twice in zip(counts, counts[1:]):
        if model[str(twice)]["seconds"] > 0.75 * model[str(n)]["seconds"]:
            return n
    return counts[-1]


if __name__ == "__main__":
    sys.exit(main())
