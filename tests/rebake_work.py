"""The work a re-bake must redo, timed (benchmarks/rebake.py --work; tests/test_bake_cache.py checks
it): the re-bake at jobs 1, where every task runs in this process, each decimation and measurement
timed (wall seconds of each call), and the phases before the first task (prepare, octree, leaves,
cache keys and loads: the bake cannot know what changed before them)."""
from __future__ import annotations

import time
from dataclasses import replace

from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings


def rebuilt_work(mesh, settings: BakeSettings, cache_dir) -> dict:
    """The re-bake of `mesh` with `cache_dir` at jobs 1, its decimations and measurements timed
    (module docstring): {"seconds", "rebuilt_nodes", "decimations", "decimate_s",
    "measurements", "measure_s", "before_tasks_s"}. The bake's own functions are wrapped in
    place for the call (jobs 1 runs every task in this process) and restored after."""
    from hlod_core.bake.decimate import simplify
    from hlod_core.bake.measure import hausdorff
    from hlod_core.bake.run import tasks

    spent = {"decimate": [], "measure": []}
    decimate, measure = simplify.decimate_node, tasks.measure_exact  # the scheduler's task functions
    to_children = hausdorff.measure_to_children  # the measure's task with --error bound

    def timed(kind, fn):
        def run(*args, **kwargs):
            started = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[kind].append(time.perf_counter() - started)
        return run

    simplify.decimate_node, tasks.measure_exact = timed("decimate", decimate), timed("measure", measure)
    hausdorff.measure_to_children = timed("measure", to_children)
    try:
        seconds, hlod = timed_bake(mesh, replace(settings, jobs=1), cache_dir)
    finally:
        simplify.decimate_node, tasks.measure_exact = decimate, measure
        hausdorff.measure_to_children = to_children
    phases = hlod.meta["phase_seconds"]
    return {"seconds": seconds, "rebuilt_nodes": hlod.meta["cache"]["rebuilt_nodes"],
            "decimations": len(spent["decimate"]), "decimate_s": sum(spent["decimate"]),
            "measurements": len(spent["measure"]), "measure_s": sum(spent["measure"]),
            "before_tasks_s": sum(phases.get(name, 0.0) for name in ("prepare", "octree", "leaves", "cache"))}


def timed_bake(mesh, settings, cache_dir) -> tuple[float, object]:
    started = time.perf_counter()
    hlod = bake(mesh, settings, cache_dir=cache_dir)
    return time.perf_counter() - started, hlod
