"""The bake's phases outside the simplify phase, timed one by one on a large scene, for this checkout
and (--baseline DIR) another version's, interleaved; and whether both find the same cell seams.

    PYTHONPATH=. .venv/bin/python -m benchmarks.serial_phases [--tris 10000000] [--baseline DIR]
        [--repeat 1] [--bakes N]

The scene: benchmarks/bake_memory.py's city of statues (the crowd's statues from the repository's
models, copies side by side) of at least --tris triangles. Each run is a fresh process of the
checkout's hlod_core (PYTHONPATH=DIR for the baseline: `git worktree add /tmp/old COMMIT`) that
reads the spec and times, in the bake's order: read (meshes.load_inputs), prepare, octree (in this
process), then, where the checkout has them, the three as tasks over chunks on a pool of 2 worker
processes started and warmed first (bake/space/chunk_store.py: "prepare into the store", "octree on
2 workers", "leaves on 2 workers"; the same layout and leaves as inline, checked), leaves
(prepare.leaf_lods, in this process), the cell seams in this process (cell_seams.build; on this many leaf vertices
one bucket per BUCKET_VERTICES), the cell seams as tasks on a pool of 2 worker processes started and
warmed first (where the checkout has them), and the exact measure's leaf arrays (leaf_arrays.build)
in this process and with their clusters cut on the 2 workers (where the checkout does that).
Each run prints the blake2b digest of its CellSeams' arrays: equal digests, the same seams, and
each phase's wall seconds and CPU seconds of the run's process (on a machine others load, the CPU
seconds move less; with workers, the workers' CPU is not counted: what is left is the bake
process's part). The baseline and this checkout alternate, the first swapped every repeat; the load
average is recorded with each run.

--bakes N (with --baseline): instead, the whole bake of the city of at least N triangles by the
command line of each checkout (`bake --no-cache`, in a fresh process run from the checkout) with
jobs 1, jobs 2 and `--scheduler` on a Dask LocalCluster of 2 worker processes, and whether each
file equals the baseline's of the same run, byte for byte once meta.VOLATILE_META is left out
(bake_memory.same_file).
"""
from __future__ import annotations

import argparse
import hashlib
import inspect
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEAM_ARRAYS = ("positions", "first_leaf", "last_leaf", "pair_leaf", "pair_position", "pair_start", "leaf_begin",
               "leaf_end")


def child(spec: str) -> dict:
    """One run (module docstring), in the checkout on sys.path."""
    import numpy as np

    from hlod_core.bake import prepare
    from hlod_core.bake.decimate import cell_seams
    from hlod_core.bake.measure import leaf_arrays
    from hlod_core.bake.settings import BakeSettings
    from hlod_core.bake.space.octree import build_octree
    from hlod_core.io import meshes

    settings = BakeSettings()
    seconds: dict[str, float] = {}
    cpu: dict[str, float] = {}
    started, cpu_started = time.perf_counter(), time.process_time()

    def lap(name: str) -> None:
        nonlocal started, cpu_started
        now, cpu_now = time.perf_counter(), time.process_time()
        seconds[name], cpu[name] = now - started, cpu_now - cpu_started
        started, cpu_started = now, cpu_now

    mesh = meshes.load_inputs([spec])
    lap("read")
    prepared = prepare.prepare(mesh, None)
    lap("prepare")
    layout = build_octree(prepared.centroids, target_tris=settings.target_tris, max_depth=settings.max_depth,
                          counted=prepared.counted, root=prepared.root_cell)
    lap("octree")
    tasks = None
    if _has_module("hlod_core.bake.space.chunk_store"):
        tasks = layout_tasks(mesh, settings, seconds, cpu)
        started, cpu_started = time.perf_counter(), time.process_time()
    lods = prepare.leaf_lods(layout, prepared)
    lap("leaves")
    if tasks is not None:
        check_tasks(layout, *tasks[:1], lods, tasks[1])
        del tasks
    seams = cell_seams.build(layout, lods)
    lap("seams inline")
    digest = hashlib.blake2b(digest_size=16)
    for name in SEAM_ARRAYS:
        digest.update(np.ascontiguousarray(getattr(seams, name)).tobytes())
    del seams
    if "workers" in inspect.signature(cell_seams.build).parameters:
        from hlod_core.bake.run.workers import open_workers

        with open_workers(2) as workers:
            for fut in [workers.executor.submit(time.sleep, 0.5) for _ in range(2)]:
                fut.result()  # started and warm
            started, cpu_started = time.perf_counter(), time.process_time()
            on_workers = cell_seams.build(layout, lods, workers=workers)
            lap("seams on 2 workers")
        again = hashlib.blake2b(digest_size=16)
        for name in SEAM_ARRAYS:
            again.update(np.ascontiguousarray(getattr(on_workers, name)).tobytes())
        del on_workers
        if again.hexdigest() != digest.hexdigest():
            raise SystemExit("serial_phases: the seams on the workers differ from the seams inline")
    started, cpu_started = time.perf_counter(), time.process_time()
    whole = leaf_arrays.build(layout, lods)
    lap("leaf arrays inline")
    if "workers" in inspect.signature(leaf_arrays.build).parameters:
        from hlod_core.bake.run.workers import open_workers

        with open_workers(2) as workers:
            for fut in [workers.executor.submit(time.sleep, 0.5) for _ in range(2)]:
                fut.result()
            started, cpu_started = time.perf_counter(), time.process_time()
            chunked = leaf_arrays.build(layout, lods, workers=workers)
            lap("leaf arrays on 2 workers")
        if any(not np.array_equal(a, chunked.arrays()[name]) for name, a in whole.arrays().items()):
            raise SystemExit("serial_phases: the leaf arrays on the workers differ from the leaf arrays inline")
    return {"tris": mesh.tri_count, "leaves": int(layout.is_leaf.sum()),
            "leaf_vertices": int(sum(lods[k][0].shape[0] for k in np.flatnonzero(layout.is_leaf))),
            "seconds": seconds, "cpu_seconds": cpu, "seams_digest": digest.hexdigest()}


def _has_module(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None


def layout_tasks(mesh, settings, seconds: dict, cpu: dict) -> tuple:
    """Prepare (its centroids written into the store's mapped file) and the octree's passes as
    tasks over index chunks on a pool of 2 worker processes (started and warmed first), then the
    leaves as tasks over runs of leaves: "prepare into the store", "octree on 2 workers" and
    "leaves on 2 workers", wall and this process's CPU. Returns (layout, leaf lods) to check."""
    from hlod_core.bake import prepare
    from hlod_core.bake.run.workers import open_workers
    from hlod_core.bake.space import chunk_store
    from hlod_core.bake.space.octree import build_octree

    with open_workers(2) as workers:
        for fut in [workers.executor.submit(time.sleep, 0.5) for _ in range(2)]:
            fut.result()
        with chunk_store.open_store(workers) as store:
            started, cpu_started = time.perf_counter(), time.process_time()
            prepared = prepare.prepare(mesh, None, store=store)
            now, cpu_now = time.perf_counter(), time.process_time()
            seconds["prepare into the store"], cpu["prepare into the store"] = now - started, cpu_now - cpu_started
            on_workers = build_octree(prepared.centroids, target_tris=settings.target_tris,
                                      max_depth=settings.max_depth, counted=prepared.counted,
                                      root=prepared.root_cell, store=store)
            seconds["octree on 2 workers"] = time.perf_counter() - now
            cpu["octree on 2 workers"] = time.process_time() - cpu_now
            now, cpu_now = time.perf_counter(), time.process_time()
            leaves = prepare.leaf_lods(on_workers, prepared, store)
            del prepared
        seconds["leaves on 2 workers"] = time.perf_counter() - now
        cpu["leaves on 2 workers"] = time.process_time() - cpu_now
    return on_workers, leaves

def check_tasks(layout, on_workers, lods, leaves) -> None:
    """SystemExit unless the octree and the leaves made by tasks (layout_tasks) are those made inline."""
    import numpy as np

    for name in ("parent", "child_offset", "tri_begin", "tri_end", "cell_center", "tri_order"):
        if not np.array_equal(getattr(layout, name), getattr(on_workers, name)):
            raise SystemExit(f"serial_phases: the octree on the workers differs from the one inline ({name})")
    for leaf in np.flatnonzero(layout.is_leaf):
        if any(not np.array_equal(a, b) for a, b in zip(lods[leaf][:2], leaves[leaf][:2])):
            raise SystemExit(f"serial_phases: leaf {leaf} made on the workers differs from the one made inline")


def run(checkout: Path, spec: Path) -> dict:
    """child() in a fresh process of `checkout`'s hlod_core."""
    load = os.getloadavg()[0]
    done = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", str(spec)], cwd=checkout,
                          env={**os.environ, "PYTHONPATH": str(checkout)}, capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f"serial_phases: {checkout}: {done.stderr.strip()[-2000:]}")
    return {"checkout": str(checkout), "load": [load, os.getloadavg()[0]],
            **json.loads(done.stdout.strip().splitlines()[-1])}


def same_bakes(checkouts: list[Path], tris: int) -> None:
    """--bakes (module docstring): prints one JSON line per bake, then whether the files match."""
    from benchmarks import bake_memory

    with tempfile.TemporaryDirectory(prefix="serial-phases-bakes-") as scratch:
        spec = bake_memory.spec_of(tris, Path(scratch))
        runs = {"jobs1": ["--jobs", "1"], "jobs2": ["--jobs", "2"], "dask2": ["--dask"]}
        files: dict[tuple[str, int], Path] = {}
        for name, options in runs.items():
            for k, checkout in enumerate(checkouts):
                out = Path(scratch) / f"{name}-{k}.hlod"
                started, load = time.perf_counter(), os.getloadavg()[0]
                command = [sys.executable, "-m", "hlod_core", "-q", "bake", str(spec), "-o", str(out), "--no-cache",
                           *options]
                if name == "dask2":  # a cluster of the checkout's own code (workers check the client's)
                    command = [sys.executable, str(Path(__file__).resolve()), "--dask-bake", str(spec), str(out)]
                subprocess.run(command, cwd=checkout, env={**os.environ, "PYTHONPATH": str(checkout)}, check=True,
                               stdout=subprocess.DEVNULL)
                files[name, k] = out
                print(json.dumps({"bake": name, "checkout": str(checkout), "seconds": time.perf_counter() - started,
                                  "load": load}), flush=True)
        for name in runs:
            print(f"{name}: the same file as the baseline's: {bake_memory.same_file(files[name, 1], files[name, 0])}")


def dask_bake(spec: str, out: str) -> None:
    """`bake --scheduler` on a LocalCluster of 2 worker processes of the checkout on PYTHONPATH."""
    import distributed

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address="127.0.0.1:0") as cluster:
        subprocess.run([sys.executable, "-m", "hlod_core", "-q", "bake", spec, "-o", out, "--no-cache", "--jobs", "1",
                        "--scheduler", cluster.scheduler_address], check=True, stdout=subprocess.DEVNULL)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tris", type=int, default=10_000_000)
    parser.add_argument("--baseline", type=Path, default=None, help="another checkout, run alternately")
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--bakes", type=int, default=None, help="whole bakes of this many triangles, compared")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--dask-bake", nargs=2, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child)))
        return
    if args.dask_bake:
        dask_bake(*args.dask_bake)
        return
    sys.path.insert(0, str(ROOT))
    from benchmarks import bake_memory

    checkouts = [ROOT] + ([args.baseline.resolve()] if args.baseline else [])
    if args.bakes:
        if len(checkouts) < 2:
            raise SystemExit("serial_phases: --bakes compares against --baseline")
        same_bakes(checkouts, args.bakes)
        return
    runs = []
    with tempfile.TemporaryDirectory(prefix="serial-phases-") as scratch:
        spec = bake_memory.spec_of(args.tris, Path(scratch))
        for rep in range(args.repeat):
            for checkout in (checkouts if rep % 2 == 0 else checkouts[::-1]):
                runs.append(run(checkout, spec))
                print(json.dumps(runs[-1]), flush=True)
    names = list(dict.fromkeys(name for r in runs for name in r["seconds"]))
    print(f"{runs[0]['tris']:,} triangles, {runs[0]['leaves']:,} leaves, {runs[0]['leaf_vertices']:,} leaf vertices")
    print("| checkout | load average | " + " | ".join(names) + " | seams digest |")
    print("|---|---:|" + "---:|" * len(names) + "---|")
    for key in ("seconds", "cpu_seconds"):
        print(f"{key} (cpu_seconds: this process's CPU, the workers' not counted)")
        for r in runs:
            cells = [f"{r[key][n]:.2f} s" if n in r[key] else "-" for n in names]
            print(f"| {Path(r['checkout']).name} | {sum(r['load']) / 2:.1f} | " + " | ".join(cells)
                  + f" | {r['seams_digest'][:12]} |")


if __name__ == "__main__":
    main()
