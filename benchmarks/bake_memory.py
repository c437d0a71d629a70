"""Peak memory of a bake against its input size (the target: at most 300 bytes per input triangle).

    PYTHONPATH=. .venv/bin/python -m benchmarks.bake_memory [--sizes 1 5 10] [--jobs 2] [--out DIR]
        [--modes memory out-of-core] [--chunk-tris N] [--error exact|bound]

--modes: the in-memory bake (`memory`, the default) and/or the streamed one (`out-of-core`:
`bake --out-of-core`, the spec read one instance at a time through per-cell scratch files in a
folder of this benchmark's temporary folder, `--chunk-tris` triangles at a time). With both, the
two files of each size are compared without their volatile meta (meta.stable_meta): "same_file".

For each size (millions of triangles) an instanced scene spec is written from the test models
(tests/models.py; tests/scenes/generate_specs.py's crowd: its 144 statues, then copies of the whole crowd side by
side, until the triangle count is reached; each instance its own geometry), and baked by the command line in a
fresh process (`python -m hlod_core bake SPEC -o OUT --jobs J --no-cache`), read from the file as a
user would. Peak resident memory is read from the kernel: the bake process's VmHWM (its high-water
mark, reading the input included), and each worker process's VmHWM sampled every 50 ms while it
runs (a worker's peak is its own; the machine's peak is at most the sum). Reported per size:
input triangles, seconds, parent peak MB, largest worker peak MB, and bytes per input triangle of
the parent alone and of parent + workers.

Data form: out/bake_memory.json, {"jobs", "chunk_tris", "error", "runs": [{"mode", "triangles", "seconds",
"parent_peak_bytes", "worker_peak_bytes": [...], "bytes_per_triangle",
"bytes_per_triangle_with_workers", "same_file" (out-of-core runs, when both modes ran)}]}.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "scenes"))
import generate_specs  # the crowd's statues and placement

ROOT = Path(__file__).resolve().parents[1]

SAMPLE_SECONDS = 0.05


def spec_of(triangles: int, folder: Path) -> Path:
    """A spec of at least `triangles` triangles: the crowd's statues (generate_specs.crowd) in
    order, repeated in copies of the whole crowd side by side (each shifted by the crowd's width,
    four copies a row), until the count is reached."""
    from hlod_core.io import meshes

    base = ROOT / "tests" / "scenes"
    placed = [((base / m["path"]).resolve(), t) for m in generate_specs.crowd()["models"] for t in m["transforms"]]
    model_tris = {path: meshes.load_mesh(path).tri_count for path in {p for p, _ in placed}}
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


MODES = ("memory", "out-of-core")


def bake_measured(spec: Path, out: Path, jobs: int, *, mode: str = "memory", chunk_tris: int | None = None,
                  error: str = "exact", extra: list[str] | tuple = ()) -> dict:
    """One bake in a fresh process, its peaks sampled (module docstring); mode: one of MODES; extra:
    more options of `bake`. "summary": the bake's summary line; "cpu_seconds": the CPU seconds of
    the bake process and of its workers (its reaped children)."""
    started, cpu = time.perf_counter(), _children_cpu()
    command = [sys.executable, "-m", "hlod_core", "-q", "bake", str(spec), "-o", str(out), "--jobs", str(jobs),
               "--error", error, *extra]
    if mode == "out-of-core":
        command += ["--out-of-core", "--scratch", str(out.parent)]
        if chunk_tris is not None:
            command += ["--chunk-tris", str(chunk_tris)]
    else:
        command += ["--no-cache"]
    proc = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.PIPE, text=True)
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
    return {"mode": mode, "triangles": summary["input_tris"], "seconds": time.perf_counter() - started,
            "parent_peak_bytes": parent_peak, "worker_peak_bytes": sorted(workers.values(), reverse=True),
            "summary": summary, "cpu_seconds": _children_cpu() - cpu}


def _children_cpu() -> float:
    """User + system CPU seconds of this process's reaped children, and theirs."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def same_file(a: Path, b: Path, *, meta: bool = True) -> bool:
    """Whether two .hlod files hold the same bytes once their volatile meta is left out (meta=False:
    and the rest of the meta too, for bakes whose settings differ only in where the work ran)."""
    from hlod_core.bake.meta import stable_meta
    from hlod_core.io import hlod_file

    def stable_bytes(path: Path) -> bytes:
        hlod = hlod_file.load(path)
        out = path.with_name(path.stem + ".stable.hlod")
        hlod_file.save(hlod.replace(meta=stable_meta(hlod.meta) if meta else {}), out)
        data = out.read_bytes()
        os.remove(out)
        return data

    return stable_bytes(a) == stable_bytes(b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[1, 5, 10], help="millions of triangles")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--modes", nargs="+", choices=MODES, default=["memory"])
    parser.add_argument("--chunk-tris", type=int, default=None, help="--out-of-core's --chunk-tris (default its own)")
    parser.add_argument("--error", choices=["exact", "bound"], default="exact", help="the bakes' --error")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    with tempfile.TemporaryDirectory(prefix="bake-memory-") as scratch:
        for size in args.sizes:
            spec = spec_of(int(size * 1_000_000), Path(scratch))
            outputs = {}
            for mode in args.modes:
                outputs[mode] = Path(scratch) / f"out-{mode}.hlod"
                run = bake_measured(spec, outputs[mode], args.jobs, mode=mode, chunk_tris=args.chunk_tris,
                                    error=args.error)
                run["bytes_per_triangle"] = run["parent_peak_bytes"] / run["triangles"]
                with_workers = run["parent_peak_bytes"] + sum(run["worker_peak_bytes"])
                run["bytes_per_triangle_with_workers"] = with_workers / run["triangles"]
                if mode == "out-of-core" and "memory" in outputs:
                    run["same_file"] = same_file(outputs["memory"], outputs[mode])
                runs.append(run)
                print(json.dumps(run), flush=True)
            for path in outputs.values():
                os.remove(path)
    (args.out / "bake_memory.json").write_text(json.dumps({"jobs": args.jobs, "chunk_tris": args.chunk_tris,
                                                           "error": args.error, "runs": runs}, indent=2))
    print("| mode | input triangles | bake s | parent peak MB | largest worker peak MB | bytes / triangle (parent) | "
          "bytes / triangle (parent + workers) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in runs:
        worst = r["worker_peak_bytes"][0] / 2**20 if r["worker_peak_bytes"] else 0.0
        print(f"| {r['mode']} | {r['triangles']:,} | {r['seconds']:.1f} | {r['parent_peak_bytes'] / 2**20:.0f} | "
              f"{worst:.0f} | {r['bytes_per_triangle']:.0f} | {r['bytes_per_triangle_with_workers']:.0f} |")


if __name__ == "__main__":
    main()
