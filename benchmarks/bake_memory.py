"""Peak memory of a bake against its input size (issue 16: at most 300 bytes per input triangle).

    PYTHONPATH=. .venv/bin/python -m benchmarks.bake_memory [--sizes 1 5 10] [--jobs 2] [--out DIR]

For each size (millions of triangles) an instanced scene spec is written from the shared models
(tests/scenes/generate_specs.py's crowd: its 144 statues, then copies of the whole crowd side by
side, until the triangle count is reached; each instance its own geometry), and baked by the command line in a
fresh process (`python -m hlod_core bake SPEC -o OUT --jobs J --no-cache`), read from the file as a
user would. Peak resident memory is read from the kernel: the bake process's VmHWM (its high-water
mark, reading the input included), and each worker process's VmHWM sampled every 50 ms while it
runs (a worker's peak is its own; the machine's peak is at most the sum). Reported per size:
input triangles, seconds, parent peak MB, largest worker peak MB, and bytes per input triangle of
the parent alone and of parent + workers.

Data form: out/bake_memory.json, {"runs": [{"triangles", "seconds", "parent_peak_bytes",
"worker_peak_bytes": [...], "bytes_per_triangle", "bytes_per_triangle_with_workers"}]}.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "scenes"))
import generate_specs  # noqa: E402  (the crowd's statues and placement)

SAMPLE_SECONDS = 0.05


def spec_of(triangles: int, folder: Path) -> Path:
    """A spec of at least `triangles` triangles: the crowd's statues (generate_specs.crowd) in
    order, repeated in copies of the whole crowd side by side (each shifted by the crowd's width,
    four copies a row), until the count is reached."""
    from hlod_core import meshio

    base = ROOT / "tests" / "scenes"
    placed = [((base / m["path"]).resolve(), t) for m in generate_specs.crowd()["models"] for t in m["transforms"]]
    model_tris = {path: meshio.load_mesh(path).tri_count for path in {p for p, _ in placed}}
    width = generate_specs.CROWD_SIDE * generate_specs.CROWD_SPACING
    models: dict[Path, list] = {}
    total, k = 0, 0
    while total < triangles:
        path, transform = placed[k % len(placed)]
        copy = k // len(placed)
        shifted = list(transform)
        shifted[3] += width * (copy % 4)
        shifted[7] += width * (copy // 4)
        models.setdefault(path, []).append(shifted)
        total += model_tris[path]
        k += 1
    out = folder / f"memory_{triangles}.json"
    out.write_text(json.dumps({"models": [{"path": str(p), "transforms": t} for p, t in models.items()]}))
    return out


def _peak(pid: int) -> int | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def _children(pid: int) -> list[int]:
    try:
        return [int(p) for p in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def bake_measured(spec: Path, out: Path, jobs: int) -> dict:
    started = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "hlod_core", "-q", "bake", str(spec), "-o", str(out),
                             "--jobs", str(jobs), "--no-cache"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    parent_peak, workers = 0, {}
    done = threading.Event()

    def sample():
        nonlocal parent_peak
        while not done.is_set():
            parent_peak = max(parent_peak, _peak(proc.pid) or 0)
            for child in _children(proc.pid):
                workers[child] = max(workers.get(child, 0), _peak(child) or 0)
            time.sleep(SAMPLE_SECONDS)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    stdout, _ = proc.communicate()
    done.set()
    sampler.join()
    if proc.returncode != 0:
        raise SystemExit(f"bake of {spec} failed with status {proc.returncode}")
    summary = json.loads(stdout.strip().splitlines()[-1])
    return {"triangles": summary["input_tris"], "seconds": time.perf_counter() - started,
            "parent_peak_bytes": parent_peak, "worker_peak_bytes": sorted(workers.values(), reverse=True)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1, 5, 10], help="millions of triangles")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    with tempfile.TemporaryDirectory(prefix="bake-memory-") as scratch:
        for size in args.sizes:
            spec = spec_of(int(size * 1_000_000), Path(scratch))
            run = bake_measured(spec, Path(scratch) / "out.hlod", args.jobs)
            run["bytes_per_triangle"] = run["parent_peak_bytes"] / run["triangles"]
            run["bytes_per_triangle_with_workers"] = (run["parent_peak_bytes"] + sum(run["worker_peak_bytes"])) / run["triangles"]
            runs.append(run)
            print(json.dumps(run), flush=True)
            os.remove(Path(scratch) / "out.hlod")
    (args.out / "bake_memory.json").write_text(json.dumps({"jobs": args.jobs, "runs": runs}, indent=2))
    print("| input triangles | bake s | parent peak MB | largest worker peak MB | bytes / triangle (parent) | "
          "bytes / triangle (parent + workers) |")
    print("|---:|---:|---:|---:|---:|---:|")
    for r in runs:
        worst = r["worker_peak_bytes"][0] / 2**20 if r["worker_peak_bytes"] else 0.0
        print(f"| {r['triangles']:,} | {r['seconds']:.1f} | {r['parent_peak_bytes'] / 2**20:.0f} | {worst:.0f} | "
              f"{r['bytes_per_triangle']:.0f} | {r['bytes_per_triangle_with_workers']:.0f} |")


if __name__ == "__main__":
    main()
