"""Bakes on a Dask cluster against local worker processes, per-task costs, and the bake
time they predict for 100M triangles on 1, 4 and 16 machines of 16 cores.

    PYTHONPATH=. .venv/bin/python -m benchmarks.dask_bake [--spec tests/scenes/gallery_1m.json]
        [--repeat 3] [--error exact|bound] [--out DIR]

In one run, on this machine:
1. bake() of the spec (reading it excluded) with jobs 1, jobs 2 (local processes) and on a real
   distributed.LocalCluster of 2 worker processes x 1 thread (started once, before; its start-up
   time is reported apart), `--repeat` rounds, the order reversed every other round; each
   speed-up over jobs 1 is the ratio of medians. Every cluster bake is checked to be the file of
   the jobs 1 bake (arrays and meta less meta.VOLATILE_META) and jobs 2 the same arrays. The
   target: the cluster's speed-up within 15% of jobs 2's (>= 0.85 x).
2. Per-task costs, from one more jobs 1 bake with simplify.decimate_node and tasks.measure_exact
   timed in this process (no worker, no transfer): per kind, tasks, seconds per task, seconds per
   input triangle (a decimation: its children's LOD triangles; a measurement: the original
   triangles below the node), the numpy bytes each task sends and returns, and the root's
   measurement; plus the bake's fixed phases (prepare, octree, leaves, assemble: serial, in the
   bake's own process) per input triangle.
3. The cluster's own cost per task (per_task_overhead), on a scheduler and workers started with
   the `dask scheduler` / `dask worker` commands: tasks that do nothing through
   dask_cluster.DaskExecutor, empty and carrying a typical decimation's arrays; wall time per task
   and the CPU time per task of the client (this process) and of the scheduler.
4. The prediction for N = 100M triangles on M machines x 16 cores (P = 16 M worker threads), from
   those measured costs (the model is written out in `predict` and in
   docs/performance.md#baking-on-a-dask-cluster):
       W_d = decimation seconds x N / N_here                (inner nodes grow with N)
       W_m = measure seconds per original triangle per level x N x L(N),
             L(N) = L_here + log8(N / N_here)                (each octree level measures every original once)
       C   = root measure seconds x N / N_here + depth(N) x the slowest decimation here
             (the critical path: the decimation chain, then the root's measurement, one task)
       O   = tasks(N) x the busier of the client's and the scheduler's CPU per task (both serial:
             the bake's process submits and collects every task, the scheduler routes it)
       F   = fixed phases per triangle x N                   (prepare, octree, leaves, assemble: serial)
       T(M) between F + max(W / P, C, O) and F + W / P + C + O   (greedy list scheduling: Graham's bound)
   Assumptions: the 16-core machines' cores as fast as one here; the network and the shared
   storage never the bottleneck (stated: bytes per task x tasks, compared with 1 GB/s); the bake's
   process holds every LOD (memory), and the octree is as deep and as full at 100M as here.
The load average is recorded before and after, and with each bake: other work on a 2-core VM
skews absolute times; the ratios compare bakes run in turn in the same minutes. Each bake's CPU
seconds (this process, its reaped children, the cluster's worker processes) say what it costs
whatever else runs: the cluster's overhead over local processes, apart from the load.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import json
import logging
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil  # a dependency of distributed

from hlod_core.bake.decimate import simplify
from hlod_core.bake.measure import hausdorff, leaf_arrays
from hlod_core.bake.meta import stable_meta
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run import dask_cluster, tasks
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import meshes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import models  # tests/models.py: the test models by role

ROOT = Path(__file__).resolve().parents[1]

#: The prediction's scene size, machines and cores per machine.
PREDICT_TRIS = 100_000_000
PREDICT_MACHINES = (1, 4, 16)
CORES_PER_MACHINE = 16
#: Network / shared-storage bandwidth the prediction compares the data movement with (bytes/s).
ASSUMED_BANDWIDTH = 1e9
#: Dask's setting of the workers' profiler, off for the cluster bakes here
#: (docs/command-line.md#baking-on-a-dask-cluster).
WORKER_PROFILE = "distributed.worker.profile.enabled"
#: The bake's phases that run in its own process, whatever executes the tasks (assemble includes
#: the bounds); the simplify phase adds the leaf arrays (leaf_arrays.build), timed apart.
FIXED_PHASES = ("prepare", "octree", "leaves", "assemble")


def identical(a, b, *, meta: bool = True) -> bool:
    """Same node arrays, geometry and (meta=True) meta less meta.VOLATILE_META (benchmarks/rebake.py)."""
    arrays = all(np.array_equal(x, getattr(b, name)) for name, x in a.node_arrays().items())
    geometry = all(np.array_equal(getattr(a, name), getattr(b, name)) for name in ("origin", "positions", "indices"))
    return arrays and geometry and (not meta or stable_meta(a.meta) == stable_meta(b.meta))


class _Stats(logging.Handler):
    """Catches dask_cluster's end-of-bake line: tasks, threads, MB sent, MB returned."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.last = None

    def emit(self, record):
        if record.msg.startswith("dask:"):
            self.last = record.args


def compare(mesh, settings: BakeSettings, client, *, repeat: int) -> dict:
    """Part 1: alternated bakes, jobs 1 / jobs 2 / the cluster."""
    stats = _Stats()
    logging.getLogger("hlod_core.bake.run.dask_cluster").addHandler(stats)
    logging.getLogger("hlod_core.bake.run.dask_cluster").setLevel(logging.INFO)
    kinds = ("jobs1", "jobs2", "dask2")
    runs: dict[str, list[float]] = {k: [] for k in kinds}
    cpu: dict[str, list[float]] = {k: [] for k in kinds}
    own: dict[str, list[float]] = {k: [] for k in kinds}  # of it, this process's (the client, the scheduler)
    workers = [psutil.Process(pid) for pid in client.run(os.getpid).values()]
    reference = bake(mesh, settings)  # jobs 1: the file every other bake is compared with (also a warm-up)
    same = {k: True for k in kinds}
    with tempfile.TemporaryDirectory(prefix="dask-bench-") as scratch:
        for rep in range(repeat):
            for kind in (kinds if rep % 2 == 0 else kinds[::-1]):
                one = BakeSettings(**{**settings.__dict__, "jobs": 2 if kind == "jobs2" else 1})
                cpu_before, own_before = _cpu_seconds(workers), _own_cpu_seconds()
                started = time.perf_counter()
                hlod = bake(mesh, one, scheduler=client if kind == "dask2" else None, scratch_dir=scratch)
                runs[kind].append(time.perf_counter() - started)
                cpu[kind].append(_cpu_seconds(workers) - cpu_before)
                own[kind].append(_own_cpu_seconds() - own_before)
                print(json.dumps({"round": rep, kind: runs[kind][-1], "cpu": cpu[kind][-1],
                                  "load": os.getloadavg()[0]}), flush=True)
                same[kind] &= identical(reference, hlod, meta=kind != "jobs2")  # jobs 2: meta says jobs 2
    median = {k: statistics.median(v) for k, v in runs.items()}
    speedup = {k: median["jobs1"] / median[k] for k in kinds}
    task_count, threads, sent_mb, returned_mb = stats.last
    return {"runs": runs, "median_seconds": median, "speedup_over_jobs1": speedup,
            "cpu_seconds": cpu, "median_cpu_seconds": {k: statistics.median(v) for k, v in cpu.items()},
            "median_own_cpu_seconds": {k: statistics.median(v) for k, v in own.items()},
            "dask_over_jobs2_speedup": speedup["dask2"] / speedup["jobs2"],
            "target_met": speedup["dask2"] >= 0.85 * speedup["jobs2"], "identical": same,
            "dask_tasks": task_count, "dask_threads": threads, "dask_sent_mb": sent_mb, "dask_returned_mb": returned_mb}


def _cpu_seconds(workers) -> float:
    """CPU seconds (user + system) of this process (the bake; a LocalCluster's scheduler and
    nannies), of its finished children (a local pool's workers, reaped when the bake ends) and of
    the cluster's worker processes: what a bake costs whatever else the machine runs."""
    own = os.times()
    return own.user + own.system + own.children_user + own.children_system \
        + sum(sum(w.cpu_times()[:2]) for w in workers)


def _own_cpu_seconds() -> float:
    own = os.times()
    return own.user + own.system


def task_costs(mesh, settings: BakeSettings) -> dict:
    """Part 2: one jobs 1 bake with every task timed in this process."""
    records: list[dict] = []
    decimate, measure = simplify.decimate_node, tasks.measure_exact
    measure_children = hausdorff.measure_to_children

    def timed_decimate(children, *rest, **options):
        started = time.perf_counter()
        lod = decimate(children, *rest, **options)
        records.append({"kind": "decimate", "seconds": time.perf_counter() - started,
                        "tris": int(sum(c[1].shape[0] for c in children)),
                        "sent": dask_cluster.array_bytes(children), "returned": dask_cluster.array_bytes(lod)})
        return lod

    def timed_measure(folder, lod, ranges):
        started = time.perf_counter()
        value = measure(folder, lod, ranges)
        start = tasks.shared(folder)["start"]
        records.append({"kind": "measure", "seconds": time.perf_counter() - started,
                        "tris": int(start[ranges[3]] - start[ranges[2]]),
                        "sent": dask_cluster.array_bytes(lod), "returned": 8})
        return value

    def timed_measure_children(lod, children):
        started = time.perf_counter()
        value = measure_children(lod, children)
        records.append({"kind": "measure", "seconds": time.perf_counter() - started,
                        "tris": int(sum(c[1].shape[0] for c in children)),
                        "sent": dask_cluster.array_bytes((lod, children)), "returned": 8})
        return value

    build_leaf_arrays = leaf_arrays.build
    shared: dict = {"seconds": 0.0, "bytes": 0}

    def timed_leaf_arrays(*args, **options):
        started = time.perf_counter()
        made = build_leaf_arrays(*args, **options)
        shared["seconds"] += time.perf_counter() - started
        arrays = made.arrays()
        shared["bytes"] = sum(a.nbytes for a in arrays.values())
        with tempfile.TemporaryDirectory() as folder:  # what a cluster bake adds: the .npy files
            started = time.perf_counter()
            tasks.save_shared(folder, arrays)
            shared["save_seconds"] = time.perf_counter() - started
        return made

    simplify.decimate_node, tasks.measure_exact = timed_decimate, timed_measure
    hausdorff.measure_to_children = timed_measure_children
    leaf_arrays.build = timed_leaf_arrays
    try:
        started = time.perf_counter()
        hlod = bake(mesh, BakeSettings(**{**settings.__dict__, "jobs": 1}))
        seconds = time.perf_counter() - started - shared.get("save_seconds", 0.0)
    finally:
        simplify.decimate_node, tasks.measure_exact = decimate, measure
        hausdorff.measure_to_children = measure_children
        leaf_arrays.build = build_leaf_arrays
    out: dict = {"bake_seconds": seconds, "input_tris": mesh.tri_count, "nodes": hlod.node_count,
                 "inner_nodes": int((~hlod.is_leaf).sum()), "depth": int(hlod.depth.max()),
                 "phase_seconds": hlod.meta["phase_seconds"]}
    for kind in ("decimate", "measure"):
        rows = [r for r in records if r["kind"] == kind]
        total = sum(r["seconds"] for r in rows)
        tris = sum(r["tris"] for r in rows)
        out[kind] = {"tasks": len(rows), "seconds": total, "seconds_per_task": total / len(rows),
                     "max_seconds": max(r["seconds"] for r in rows), "input_tris": tris,
                     "us_per_input_tri": 1e6 * total / tris,
                     "sent_kb_per_task": sum(r["sent"] for r in rows) / len(rows) / 1e3,
                     "returned_kb_per_task": sum(r["returned"] for r in rows) / len(rows) / 1e3}
    root = max((r for r in records if r["kind"] == "measure"), key=lambda r: r["tris"])
    out["root_measure"] = {"seconds": root["seconds"], "tris": root["tris"]}
    out["shared_arrays"] = shared
    out["fixed_seconds"] = sum(v for k, v in hlod.meta["phase_seconds"].items() if k in FIXED_PHASES) \
        + shared["seconds"] + shared.get("save_seconds", 0.0)
    return out


def _noop(payload=None) -> int:
    return 0


@contextlib.contextmanager
def command_line_cluster(workers: int = 2):
    """A scheduler and `workers` worker processes of one thread, started as docs/command-line.md says to start
    them on machines (`dask scheduler`, `dask worker ADDRESS --nworkers N --nthreads 1`), here on
    localhost: yields (scheduler address, the scheduler's process id)."""
    dask = Path(sys.executable).with_name("dask")
    with tempfile.TemporaryDirectory(prefix="dask-bench-") as folder:
        address_file = Path(folder) / "scheduler.json"
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
        scheduler = subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file",
                                      str(address_file), "--dashboard-address", "127.0.0.1:0"], **quiet)
        worker = None
        try:
            deadline = time.monotonic() + 60
            while not address_file.is_file() or not address_file.read_text().strip():
                if time.monotonic() > deadline or scheduler.poll() is not None:
                    raise RuntimeError("dask scheduler did not start")
                time.sleep(0.1)
            time.sleep(0.2)  # written, not necessarily flushed
            address = json.loads(address_file.read_text())["address"]
            worker = subprocess.Popen([str(dask), "worker", address, "--nworkers", str(workers), "--nthreads", "1",
                                       "--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0"],
                                      env={**os.environ, "PYTHONPATH": str(ROOT),
                                           "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED": "False"}, **quiet)
            yield address, scheduler.pid
        finally:
            for proc in (worker, scheduler):
                if proc is not None:
                    proc.terminate()
                    try:
                        proc.wait(timeout=30)
                    except subprocess.TimeoutExpired:
                        proc.kill()


def per_task_overhead(sample_args, tasks: int = 400) -> dict:
    """Part 3: the cluster's cost per task, on a scheduler and 2 workers started as on machines
    (command_line_cluster), of a task that does nothing, empty and carrying `sample_args` (a
    decimation's children's LODs): wall ms per task with 2 in flight (as a bake on 2 threads keeps
    them: the round trip) and with 32 (throughput), and the CPU ms per task of this process (the
    client: submit, collect) and of the scheduler's process. Client and scheduler are serial
    event loops: a large cluster's tasks queue behind the busier of the two."""
    import distributed

    out = {}
    with command_line_cluster() as (address, scheduler_pid):
        scheduler = psutil.Process(scheduler_pid)
        with distributed.Client(address, set_as_default=False, timeout=60) as client:
            client.wait_for_workers(2, timeout=120)
            executor = dask_cluster.DaskExecutor(client)
            for name, payload in (("empty", None), ("decimation_args", sample_args)):
                for in_flight in (2, 32):
                    running: set = set()
                    started, cpu, other = time.perf_counter(), time.process_time(), sum(scheduler.cpu_times()[:2])
                    for _ in range(tasks):
                        while len(running) >= in_flight:
                            _, running = cf.wait(running, return_when=cf.FIRST_COMPLETED)
                        running.add(executor.submit(_noop, payload, priority=0))
                    cf.wait(running)
                    key = f"{name}_{in_flight}_in_flight"
                    out[key] = {"wall_ms": 1e3 * (time.perf_counter() - started) / tasks,
                                "client_cpu_ms": 1e3 * (time.process_time() - cpu) / tasks,
                                "scheduler_cpu_ms": 1e3 * (sum(scheduler.cpu_times()[:2]) - other) / tasks}
    out["decimation_args_kb"] = dask_cluster.array_bytes(sample_args) / 1e3
    return out


def predict(costs: dict, overhead: dict, *, tris: int = PREDICT_TRIS) -> dict:
    """Part 4: the model of the module docstring, for `tris` triangles on PREDICT_MACHINES. It is
    the exact error's: with --error bound a measurement reads only the children's LODs, so its
    work grows with the nodes, not with the levels (the figures then overstate W_m)."""
    n_here = costs["input_tris"]
    grow = tris / n_here
    dec, mea = costs["decimate"], costs["measure"]
    levels_here = mea["input_tris"] / n_here  # original triangles measured per input triangle
    extra_levels = math.log(grow, 8)
    w_d = dec["seconds"] * grow
    w_m = mea["seconds"] / mea["input_tris"] * tris * (levels_here + extra_levels)
    depth = costs["depth"] + extra_levels
    critical = costs["root_measure"]["seconds"] * grow + depth * dec["max_seconds"]
    tasks = (dec["tasks"] + mea["tasks"]) * grow
    # the busier of the client's and the scheduler's CPU per task carrying a decimation's arrays, many in flight
    loaded = overhead["decimation_args_32_in_flight"]
    client_s = max(loaded["client_cpu_ms"], loaded["scheduler_cpu_ms"]) / 1e3
    o = tasks * client_s
    fixed = costs["fixed_seconds"] * grow
    data = (dec["sent_kb_per_task"] + dec["returned_kb_per_task"]) * 1e3 * dec["tasks"] * grow \
        + (mea["sent_kb_per_task"] + mea["returned_kb_per_task"]) * 1e3 * mea["tasks"] * grow
    rows = {}
    for machines in PREDICT_MACHINES:
        p = machines * CORES_PER_MACHINE
        low = fixed + max((w_d + w_m) / p, critical, o)
        high = fixed + (w_d + w_m) / p + critical + o
        rows[str(machines)] = {"threads": p, "work_over_threads_s": (w_d + w_m) / p, "low_s": low, "high_s": high}
    return {"tris": tris, "work_decimate_s": w_d, "work_measure_s": w_m, "levels": levels_here + extra_levels,
            "depth": depth, "critical_path_s": critical, "tasks": tasks, "client_s_per_task": client_s,
            "client_total_s": o, "fixed_s": fixed, "data_gb": data / 1e9,
            "data_at_1gbs_s": data / ASSUMED_BANDWIDTH, "machines": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=models.input_file, default=str(ROOT / "tests" / "scenes" / "gallery_1m.json"))
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--error", choices=["exact", "bound"], default="exact")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    import dask
    import distributed

    # The workers' statistical profiler samples every task's stack every 10 ms: about 4% of a
    # bake's CPU here (igea, 7.6 against 7.4 s), for a profile the bake does not read
    # (docs/command-line.md#baking-on-a-dask-cluster).
    dask.config.set({WORKER_PROFILE: False})
    settings = BakeSettings(error=args.error)
    result: dict = {"spec": str(args.spec), "error": args.error, "load_before": os.getloadavg()}
    mesh = meshes.load_inputs([args.spec])
    started = time.perf_counter()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0") as cluster, \
            distributed.Client(cluster, set_as_default=False) as client:
        result["cluster_start_seconds"] = time.perf_counter() - started
        result["compare"] = compare(mesh, settings, client, repeat=args.repeat)
        result["costs"] = task_costs(mesh, settings)
    result["overhead"] = per_task_overhead(_sample_children(settings))
    result["predict"] = predict(result["costs"], result["overhead"])
    result["load_after"] = os.getloadavg()
    name = "dask_bake.json" if args.error == "exact" else "dask_bake-bound.json"
    (args.out / name).write_text(json.dumps(result, indent=2))
    print(json.dumps(result))


def _sample_children(settings: BakeSettings) -> list:
    """Eight LODs of about target_tris triangles each: a typical decimation's arguments."""
    tris = settings.target_tris
    rng = np.random.default_rng(0)
    verts = tris // 2 + 2
    return [(rng.random((verts, 3), dtype=np.float32), rng.integers(0, verts, (tris, 3)).astype(np.int32), None)
            for _ in range(8)]


if __name__ == "__main__":
    main()
