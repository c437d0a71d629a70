"""Bake throughput of this checkout against another version's, interleaved in one run.

    PYTHONPATH=. .venv/bin/python -m benchmarks.bake_against --baseline DIR INPUT [--jobs 2] [--repeat 3]
                                                              [--instances N]

DIR is a checkout of the other version (`git worktree add /tmp/old COMMIT`), run with this .venv.
Each bake runs in its own subprocess (`python -m hlod_core bake INPUT --jobs N --no-cache`; its
seconds are the command line's own: bake and save, reading excluded), the two versions alternating,
the first of each pair swapped every repeat, so load drifts reach both alike. Per bake: seconds,
input triangles per second, the CPU seconds of the bake's process and its workers (the whole
command: its start and reading included; on a machine others load, the wall time moves with their
load and the CPU time much less), nodes, and the inner nodes over 1.25 x target_tris (the written
file read by this checkout's reader). --instances N: a scene spec's first N instances of each model only
(a smaller scene of the same kind, for a run that must stay short).
Prints one JSON line per bake, then the medians and their ratio (this / baseline).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import models  # tests/models.py: the test models by role

ROOT = Path(__file__).resolve().parents[1]

#: An inner node over this many times target_tris breaks the coarse levels' budget (collapse.py).
OVER_BUDGET_FACTOR = 1.25


def bake_once(checkout: Path, spec: Path, out: Path, *, jobs: int, target_tris: int) -> dict:
    """One bake of `spec` by the checkout's hlod_core in a fresh process: the command line's summary
    (seconds: bake and save, reading excluded; nodes; input_tris) and the inner nodes over budget."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    run = subprocess.run([sys.executable, "-m", "hlod_core", "bake", str(spec), "-o", str(out), "--jobs", str(jobs),
                          "--no-cache", "--target-tris", str(target_tris)],
                         cwd=checkout, env={**os.environ, "PYTHONPATH": str(checkout)},
                         capture_output=True, text=True, check=False)
    if run.returncode:
        raise SystemExit(f"bake_against: {checkout}: bake failed: {run.stderr.strip()[-2000:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    return {"seconds": summary["seconds"], "cpu_seconds": cpu, "tris_per_second": summary["tris_per_second"],
            "input_tris": summary["input_tris"], "nodes": summary["nodes"], **_budget(out, target_tris)}


def first_instances(spec: Path, count: int, folder: Path) -> Path:
    """A copy of the scene spec `spec` in `folder` with each model's first `count` transforms (paths
    made absolute)."""
    scene = json.loads(spec.read_text())
    for model in scene["models"]:
        model["path"] = str((spec.parent / model["path"]).resolve())
        model["transforms"] = model["transforms"][:count]
    out = folder / f"{spec.stem}-first{count}.json"
    out.write_text(json.dumps(scene))
    return out


def _budget(path: Path, target_tris: int) -> dict:
    """The inner nodes over OVER_BUDGET_FACTOR x target_tris in a written .hlod, and the largest inner node."""
    from hlod_core.io import hlod_file

    hlod = hlod_file.load(path, mmap=False)
    inner = np.asarray(hlod.tri_count)[~hlod.is_leaf]
    return {"inner_over_budget": int((inner > OVER_BUDGET_FACTOR * target_tris).sum()),
            "largest_inner_tris": int(inner.max(initial=0))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of the version to compare with")
    parser.add_argument("input", type=models.input_file, metavar="INPUT")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--target-tris", type=int, default=2000)
    parser.add_argument("--instances", type=int, help="a scene spec's first N instances of each model only")
    args = parser.parse_args()
    versions = {"this": ROOT, "baseline": args.baseline.resolve()}
    seconds: dict[str, list[float]] = {name: [] for name in versions}
    cpu: dict[str, list[float]] = {name: [] for name in versions}
    with tempfile.TemporaryDirectory(prefix="hlod-bake-against-") as tmp:
        spec = args.input.resolve()
        if args.instances:
            spec = first_instances(spec, args.instances, Path(tmp))
        for repeat in range(args.repeat):
            order = list(versions) if repeat % 2 == 0 else list(reversed(versions))
            for name in order:
                got = bake_once(versions[name], spec, Path(tmp) / f"{name}.hlod", jobs=args.jobs,
                                target_tris=args.target_tris)
                seconds[name].append(got["seconds"])
                cpu[name].append(got["cpu_seconds"])
                print(json.dumps({"version": name, "repeat": repeat, **got}), flush=True)
    medians = {name: statistics.median(s) for name, s in seconds.items()}
    cpu_medians = {name: statistics.median(s) for name, s in cpu.items()}
    print(json.dumps({"median_bake_seconds": medians,
                      "throughput_this_over_baseline": medians["baseline"] / medians["this"],
                      "median_cpu_seconds": cpu_medians,
                      "cpu_throughput_this_over_baseline": cpu_medians["baseline"] / cpu_medians["this"]}))


if __name__ == "__main__":
    main()
