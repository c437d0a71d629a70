"""Where a bake's time goes: decimation, welding, Hausdorff sampling, process start and
data movement, on one input.

    PYTHONPATH=. .venv/bin/python -m benchmarks.bake_profile INPUT [INPUT ...] [--target-tris 2000] [--task-cpu]

An INPUT is a mesh file, a scene spec, or the name of a test model (tests/models.py: statue, bunny, ...).

Per input, two bakes in this process, reading excluded:
  jobs 1 under cProfile: every task runs here, so the profile splits the whole bake into the
    phases (meta.PhaseClock) and, inside the simplify phase, decimation (pymeshlab's quadric
    collapse; the weld; the unit frame's mapping back; building pymeshlab meshes; the coarse levels'
    cell seams, rims and pieces) and the error
    measure (nodes measured whole; nodes measured pruned, and in those the exact LOD -> original
    evaluation; pymeshlab's Hausdorff calls in all; the samples; the clusters, built once);
  jobs 2 with the real worker processes: the wall time, the worker start (spawn and pymeshlab's
    import, timed by starting a pool of 2 alone), and the data moved: the bytes pickled for every
    task's arguments and results (the LODs travel with their tasks) and the shared arrays written
    once to the scratch folder.
--task-cpu instead: one jobs 1 bake unprofiled, every decimation and measure timed with the
process's CPU clock (less moved by other processes' load than wall time), summed by kind and by
the node's original vertices (the measure) or input triangles (the decimation); one JSON line per
input. The module imports hlod_core from PYTHONPATH: run from another checkout to read that version.
Prints one JSON line per input and a Markdown table. cProfile's own overhead inflates the many
small calls a little (the shares are what to read); the jobs 2 time is unprofiled.
"""
from __future__ import annotations

import argparse
import concurrent.futures as cf
import cProfile
import json
import multiprocessing
import pickle
import pstats
import sys
import time
from pathlib import Path

from hlod_core.bake.pipeline import bake
from hlod_core.bake.run import workers
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import meshes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import models  # tests/models.py: the test models by role

ROOT = Path(__file__).resolve().parents[1]

#: (label, function name, file the function is in): cumulative seconds of each in the jobs 1 profile.
PARTS = (
    ("decimation", "decimate_node", "simplify.py"),
    ("  quadric collapse (pymeshlab)", "quadric_collapse", "meshlab.py"),
    ("  weld", "weld", "simplify.py"),
    ("  unit frame back to model (to_model)", "to_model", "meshlab.py"),
    ("  pymeshlab meshes made", "mesh_set", "meshlab.py"),
    ("  cell seams and rims found (node_borders)", "node_borders", "cell_seams.py"),
    ("  connected pieces found (pieces_of)", "pieces_of", "pieces.py"),
    ("  pieces chosen to drop (choose)", "choose", "pieces.py"),
    ("error measure", "measure_exact", "tasks.py"),
    ("  measured whole (small nodes; big ones pruning cannot help)", "measure", "hausdorff.py"),
    ("  big nodes (pruned, or whole inside)", "measure_clustered", "hausdorff.py"),
    ("    of which LOD -> original against clusters", "_max_to_faces", "hausdorff.py"),
    ("    of which the original's vertices as one point set", "add_points", "hausdorff.py"),
    ("  pymeshlab Hausdorff calls (all)", "hausdorff_max", "hausdorff.py"),
    ("  samples (vertices + 7 per face)", "surface_samples", "hausdorff.py"),
    ("clusters of the leaves (once)", "build", "hausdorff.py"),
)


def _cumulative(stats: pstats.Stats, name: str, file: str) -> tuple[float, int]:
    seconds, calls = 0.0, 0
    for (path, _, function), (_, ncalls, _, cumtime, _) in stats.stats.items():
        if function == name and path.endswith(file):
            seconds += cumtime
            calls += ncalls
    return seconds, calls


def _worker_start_seconds(jobs: int = 2) -> float:
    started = time.perf_counter()
    pool = cf.ProcessPoolExecutor(max_workers=jobs, initializer=workers.init_worker,
                                  mp_context=multiprocessing.get_context("spawn"))
    try:
        cf.wait([pool.submit(workers.warm_up) for _ in range(jobs)])
        return time.perf_counter() - started
    finally:
        pool.shutdown()


class _Moved:
    """Counts the pickled bytes of every task's arguments and result, wrapping workers.Workers.submit
    and .share for the block."""

    def __init__(self):
        self.task_bytes = 0
        self.tasks = 0
        self.shared_bytes = 0

    def __enter__(self):
        self._submit, self._share = workers.Workers.submit, workers.Workers.share
        moved = self

        def submit(where, order, fn, *args, **kwargs):
            moved.tasks += 1
            moved.task_bytes += len(pickle.dumps((args, kwargs), protocol=pickle.HIGHEST_PROTOCOL))
            future = moved._submit(where, order, fn, *args, **kwargs)
            future.add_done_callback(lambda f: moved._count_result(f))
            return future

        def share(where, arrays):
            moved.shared_bytes += sum(a.nbytes for a in arrays.values())
            return moved._share(where, arrays)

        workers.Workers.submit, workers.Workers.share = submit, share
        return self

    def _count_result(self, future):
        if future.exception() is None:
            self.task_bytes += len(pickle.dumps(future.result(), protocol=pickle.HIGHEST_PROTOCOL))

    def __exit__(self, *exc):
        workers.Workers.submit, workers.Workers.share = self._submit, self._share


def profile(path: Path, target_tris: int) -> dict:
    mesh = meshes.load_inputs([path])
    profiler = cProfile.Profile()
    started = time.perf_counter()
    profiler.enable()
    one = bake(mesh, BakeSettings(jobs=1, target_tris=target_tris))
    profiler.disable()
    jobs1 = time.perf_counter() - started
    stats = pstats.Stats(profiler)
    parts = {label: _cumulative(stats, name, file) for label, name, file in PARTS}
    with _Moved() as moved:
        started = time.perf_counter()
        bake(mesh, BakeSettings(jobs=2, target_tris=target_tris))
        jobs2 = time.perf_counter() - started
    return {"input": str(path), "triangles": mesh.tri_count, "nodes": one.node_count,
            "jobs1_profiled_seconds": jobs1, "phase_seconds": one.meta["phase_seconds"],
            "parts": {label: {"seconds": s, "calls": c} for label, (s, c) in parts.items()},
            "jobs2_seconds": jobs2, "worker_start_seconds": _worker_start_seconds(),
            "tasks": moved.tasks, "task_bytes": moved.task_bytes, "shared_bytes": moved.shared_bytes}


#: --task-cpu's node sizes: the measure's by original vertices, the decimation's by input triangles.
MEASURE_BINS = (0, 5_000, 20_000, 60_000)
DECIMATE_BINS = (0, 4_000, 8_000, 16_000)


def task_cpu(path: Path, target_tris: int) -> dict:
    """CPU seconds of a jobs 1 bake's decimations and measures, by node size (module docstring)."""
    from hlod_core.bake.decimate import simplify
    from hlod_core.bake.run import tasks

    spent = {"measure": [], "decimate": []}  # (size, cpu seconds) per task
    measure_exact, decimate_node = tasks.measure_exact, simplify.decimate_node

    def measured(folder, lod, ranges):
        started = time.process_time()
        error = measure_exact(folder, lod, ranges)
        spent["measure"].append((ranges[1] - ranges[0], time.process_time() - started))
        return error

    def decimated(*args, **kwargs):
        started = time.process_time()
        lod = decimate_node(*args, **kwargs)
        spent["decimate"].append((lod.input_tris, time.process_time() - started))
        return lod

    mesh = meshes.load_inputs([path])
    tasks.measure_exact, simplify.decimate_node = measured, decimated  # looked up at each submit
    try:
        started = time.process_time()
        hlod = bake(mesh, BakeSettings(jobs=1, target_tris=target_tris))
        total = time.process_time() - started
    finally:
        tasks.measure_exact, simplify.decimate_node = measure_exact, decimate_node

    def by_size(kind, bins):
        out = {}
        for low, high in zip(bins, (*bins[1:], None)):
            rows = [s for n, s in spent[kind] if n >= low and (high is None or n < high)]
            out[f"{low}-{high or ''}"] = {"tasks": len(rows), "cpu_seconds": round(sum(rows), 3)}
        return out

    return {"input": str(path), "nodes": hlod.node_count, "cpu_seconds": round(total, 3),
            "measure_cpu_seconds": round(sum(s for _, s in spent["measure"]), 3),
            "decimate_cpu_seconds": round(sum(s for _, s in spent["decimate"]), 3),
            "measure_by_original_vertices": by_size("measure", MEASURE_BINS),
            "decimate_by_input_tris": by_size("decimate", DECIMATE_BINS)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("inputs", nargs="+", type=models.input_file, metavar="INPUT")
    parser.add_argument("--target-tris", type=int, default=2000)
    parser.add_argument("--task-cpu", action="store_true", help="CPU seconds per task kind and node size instead")
    args = parser.parse_args()
    if args.task_cpu:
        for p in args.inputs:
            print(json.dumps(task_cpu(p, args.target_tris)), flush=True)
        return
    results = [profile(p, args.target_tris) for p in args.inputs]
    for r in results:
        print(json.dumps(r), flush=True)
    names = [Path(r["input"]).name for r in results]
    print("| part | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(results))

    def row(label, values):
        print(f"| {label} | " + " | ".join(values) + " |")

    row("jobs 1 (profiled), s", [f"{r['jobs1_profiled_seconds']:.1f}" for r in results])
    for phase in ("prepare", "octree", "leaves", "simplify", "assemble"):
        row(f"phase {phase}", [f"{r['phase_seconds'].get(phase, 0.0):.2f} s" for r in results])
    for label, _, _ in PARTS:
        row(label.replace("  ", "&nbsp;&nbsp;"), [
            f"{r['parts'][label]['seconds']:.2f} s "
            f"({100 * r['parts'][label]['seconds'] / r['jobs1_profiled_seconds']:.0f}%), "
            f"{r['parts'][label]['calls']} calls" for r in results])
    row("jobs 2 (unprofiled), s", [f"{r['jobs2_seconds']:.1f}" for r in results])
    row("worker start (2 spawned, pymeshlab imported), s", [f"{r['worker_start_seconds']:.2f}" for r in results])
    row("data sent with tasks and back (pickled)",
        [f"{r['task_bytes'] / 2**20:.0f} MB in {r['tasks']} tasks" for r in results])
    row("shared arrays written once", [f"{r['shared_bytes'] / 2**20:.0f} MB" for r in results])


if __name__ == "__main__":
    main()
