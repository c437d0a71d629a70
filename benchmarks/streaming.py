"""Node geometry streamed under a GPU budget (docs/performance.md#streaming-under-a-gpu-budget).

    PYTHONPATH=. .venv/bin/python -m benchmarks.streaming [--sizes 1 20] [--budget-mb 64] [--repeat 3]
        [--walk FILE.hlod --path PATH.json [--plan-time]] [--share 8] [--jobs 2] [--size 640x480] [--out DIR]

Start-up: for each size (millions of triangles) the instanced crowd spec of benchmarks.bake_memory
is baked out of core once (kept in --out as SIZEm.hlod and reused), then `python -m hlod_core run
FILE --method coh --gpu-budget MB --frames 3` runs in a fresh process, the sizes alternating,
--repeat times: its first_frame_ms (from opening the file to the end of the first frame: the
file's header and node table read, the pinned top levels uploaded, the frame drawn) and its
resident bytes. The target: the largest size's median within 2x the smallest's.

Walk-through (--walk FILE --path PATH): `run --compare-unlimited --gpu-budget` at 1/--share of the
file's node geometry and textures, Coh(P) with the defaults: the median PSNR-Y against the unlimited run's
frames after the tenth (target >= 40 dB), the resident peak against the budget (target: within
it), and the most a frame spent uploading against the unlimited run's median frame time (target:
at most 0.2 of it, so no frame takes more than 1.2x that median from loading). With --plan-time,
instead: VFC (whose cut does not depend on query timing) over the path in this process at the same
budget, the time `Residency.plan` takes each frame (its median, sum and most), the bytes uploaded
and the resident peak: what the bookkeeping itself costs, free of the GPU's and the queries' noise.

Data form: OUT/streaming.json {"startup": [{"size_m", "triangles", "file_bytes", "first_frame_ms":
[...], "median_ms"}], "startup_ratio", "walk": {run's JSON with the budget, "share"} or with
--plan-time {"plan_ms_median", "plan_ms_sum", "plan_ms_max", "uploaded_bytes", "resident_bytes_peak"}}.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

from benchmarks import bake_memory

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=float, nargs="*", default=[1, 20],
                        help="millions of triangles (none: no start-up run)")
    parser.add_argument("--budget-mb", type=float, default=64.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--walk", metavar="FILE.hlod", help="a baked file for the walk-through target")
    parser.add_argument("--path", metavar="PATH.json", help="the walk-through's camera path")
    parser.add_argument("--plan-time", action="store_true", help="time the residency's plan alone, VFC in process")
    parser.add_argument("--share", type=int, default=8,
                        help="the walk's budget: 1/share of the file's geometry and textures")
    parser.add_argument("--out", default="out/streaming")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report: dict = {"budget_mb": args.budget_mb, "size": args.size}
    if args.sizes:
        report["startup"] = startup(args, out)
        medians = [row["median_ms"] for row in report["startup"]]
        report["startup_ratio"] = max(medians) / min(medians)
    if args.walk:
        report["walk"] = plan_time(args) if args.plan_time else walk(args)
    (out / "streaming.json").write_text(json.dumps(report, indent=1))
    print(json.dumps(report))
    return 0


def _hlod(*argv) -> dict:
    """`python -m hlod_core ARGV` in a fresh process; its last stdout line."""
    proc = subprocess.run([sys.executable, "-m", "hlod_core", "-q", *map(str, argv)], cwd=ROOT, capture_output=True,
                          text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def startup(args, out: Path) -> list[dict]:
    files = []
    for size_m in args.sizes:
        target = out / f"{size_m:g}m.hlod"
        if not target.exists():
            spec = bake_memory.spec_of(int(size_m * 1e6), out)
            print(f"baking {target} out of core ...", file=sys.stderr)
            _hlod("bake", spec, "-o", target, "--jobs", args.jobs, "--no-cache", "--out-of-core")
        files.append((size_m, target, _hlod("info", target)))
    rows = {size_m: {"size_m": size_m, "triangles": info["input_tris"], "file_bytes": target.stat().st_size,
                     "first_frame_ms": [], "resident_bytes": []} for size_m, target, info in files}
    for _ in range(args.repeat):
        for size_m, target, _ in files:  # the sizes alternate: the machine's load falls on each alike
            run = _hlod("run", target, "--method", "coh", "--gpu-budget", args.budget_mb, "--frames", 3,
                        "--size", args.size)
            rows[size_m]["first_frame_ms"].append(run["first_frame_ms"])
            rows[size_m]["resident_bytes"].append(run["gpu_resident_bytes_peak"])
    for row in rows.values():
        row["median_ms"] = statistics.median(row["first_frame_ms"])
    return list(rows.values())


def walk(args) -> dict:
    whole = _hlod("run", args.walk, "--method", "vfc", "--frames", 1, "--size", "64x48")["gpu_resident_bytes_peak"]
    budget_mb = whole / args.share / 2**20
    argv = ["run", args.walk, "--method", "coh", "--gpu-budget", budget_mb, "--compare-unlimited", "--size", args.size]
    if args.path:
        argv += ["--path", args.path]
    run = _hlod(*argv)
    run["share"] = args.share
    run["file_gpu_bytes"] = whole  # node geometry and textures
    run["upload_ms_max_vs_unlimited_median"] = run["upload_ms_max"] / run["frame_ms_unlimited_median"]
    return run


def plan_time(args) -> dict:
    """--plan-time (module docstring): VFC over --path in this process, each plan timed."""
    import time

    import numpy as np

    from hlod_core.io import hlod_file
    from hlod_core.model.camera_path import load_path
    from hlod_core.render.renderer import Renderer
    from hlod_core.render.residency import StreamingSettings
    from hlod_core.traversal.methods import make

    whole = _hlod("run", args.walk, "--method", "vfc", "--frames", 1, "--size", "64x48")["gpu_resident_bytes_peak"]
    hlod, path = hlod_file.load(args.walk), load_path(args.path)
    size = tuple(int(v) for v in args.size.split("x"))
    renderer = Renderer.create_standalone(hlod, size, streaming=StreamingSettings(budget_bytes=whole // args.share))
    residency, spent = renderer.residency, []
    plan = residency.plan

    def timed():
        started = time.perf_counter()
        out = plan()
        spent.append((time.perf_counter() - started) * 1e3)
        return out

    residency.plan = timed  # this benchmark's instance only
    try:
        traversal = make("vfc", hlod, renderer)
        for i in range(len(path)):
            traversal.frame(path.view(i, size))
    finally:
        renderer.release()
    return {"share": args.share, "file_gpu_bytes": whole, "plan_ms_median": float(np.median(spent)),
            "plan_ms_sum": float(np.sum(spent)), "plan_ms_max": float(np.max(spent)),
            "uploaded_bytes": residency.uploaded_bytes, "resident_bytes_peak": residency.resident_bytes_peak}


if __name__ == "__main__":
    sys.exit(main())
