"""What importing a host's depth costs a frame, and what reducing it changes
(docs/performance.md#depth-import).

    .venv/bin/python -m hlod_core scene default -o out/default.hlod
    .venv/bin/python -m benchmarks.depth_import out/default.hlod [--sizes 1920x1080,3840x2160]
        [--factors 1,2,4,8] [--repeat 5] [--frames 30] [--traversal-sizes 640x480,1920x1080] [--no-blender]

1. Cost: per size and reduction factor, the renderer's begin_frame with a new depth image set
   (reduce_depth, upload, the full-screen write) and glFinish, less the same frame start without a
   depth image; the median over --repeat rounds, the factors interleaved (order alternating).
2. Read-back in Blender (unless --no-blender, or bpy does not import): GPUFrameBuffer.read_depth of
   a GPUOffScreen of each size into a 1-D gpu Buffer and its numpy view, in a bpy process; the median of
   --repeat reads.
3. Effect: Coh on the street walk (`street_path`, the tests' walk down the default city's first
   street) with a wall over the left half of the view at 5 m (depth_import.wall_depth), each factor:
   drawn nodes, queries, and PSNR-Y of the frames against factor 1's.

Prints one JSON line per measurement, then Markdown tables.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

import numpy as np

from hlod_core.io import hlod_file
from hlod_core.model.camera_path import CameraPath
from hlod_core.render.depth_import import wall_depth
from hlod_core.render.renderer import Renderer
from hlod_core.report import image_error
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

#: The wall's distance in front of the camera, metres (the default city's units).
WALL_M = 5.0


def street_path(frames: int) -> CameraPath:
    """The walk down the default city's first street, eye at 1.7 m, looking along it (the tests'
    helpers.street_path): most of the city hides behind the first buildings."""
    out = []
    for i in range(frames):
        y = -5.0 + 100.0 * i / max(frames - 1, 1)
        out.append(([10.0, y, 1.7], [10.0 + 8.0 * np.sin(i / 5.0), y + 30.0, 4.0], [0.0, 0.0, 1.0]))
    return CameraPath(frames=np.array(out, float), near=0.05, far=400.0, fovy_deg=60.0)


def _size(text: str) -> tuple[int, int]:
    w, h = text.split("x")
    return int(w), int(h)


def import_cost(hlod, size: tuple[int, int], factors: list[int], repeat: int) -> dict[int, float]:
    """Median milliseconds per factor of a frame start with a new depth image over one without."""
    view = street_path(1).view(0, size)
    depth = wall_depth(view, distance=WALL_M)
    renderer = Renderer.create_standalone(hlod, size)
    times: dict[int | None, list[float]] = {f: [] for f in [None, *factors]}
    try:
        for rep in range(repeat + 1):  # the first round warms up (texture made, shaders compiled)
            order = [None, *factors] if rep % 2 == 0 else [*factors[::-1], None]
            for factor in order:
                renderer.set_scene_depth(None if factor is None else depth.copy(), reduce=factor or 1)
                started = time.perf_counter()
                renderer.begin_frame(view, time_gpu=False)
                renderer.ctx.finish()
                elapsed = (time.perf_counter() - started) * 1e3
                renderer.end_frame()
                if rep:
                    times[factor].append(elapsed)
    finally:
        renderer.release()
    base = statistics.median(times[None])
    return {f: statistics.median(times[f]) - base for f in factors}


BLENDER_READ = """
import json, sys, time
import bpy, gpu, numpy as np
scene = bpy.context.scene
scene.render.engine = "BLENDER_WORKBENCH"
scene.render.resolution_x = scene.render.resolution_y = 16
bpy.ops.render.render()  # the bpy module's GPU works after a first render
out = {}
for w, h in json.loads(sys.argv[1]):
    offscreen = gpu.types.GPUOffScreen(w, h)
    with offscreen.bind():
        fb = gpu.state.active_framebuffer_get()
        fb.clear(color=(1.0, 1.0, 1.0, 1.0), depth=0.5)
        times = []
        for _ in range(int(sys.argv[2]) + 1):
            started = time.perf_counter()  # as the preview reads it (addon/preview/batch_drawn_mode.py)
            buffer = gpu.types.Buffer("FLOAT", w * h)
            fb.read_depth(0, 0, w, h, data=buffer)
            depth = np.asarray(buffer, np.float32).reshape(h, w)
            times.append((time.perf_counter() - started) * 1e3)
        assert depth.shape == (h, w) and float(depth[0, 0]) == 0.5
    offscreen.free()
    out[f"{w}x{h}"] = sorted(times[1:])[len(times[1:]) // 2]
print(json.dumps({"backend": gpu.platform.backend_type_get(), "read_depth_ms": out}))
"""


def blender_read_cost(sizes: list[tuple[int, int]], repeat: int) -> dict | None:
    """Blender's read_depth into a one-dimensional gpu Buffer and its numpy view (as the preview
    reads it) at each size, in a bpy process; None without bpy."""
    if subprocess.run([sys.executable, "-c", "import bpy"], capture_output=True).returncode != 0:
        return None
    proc = subprocess.run([sys.executable, "-c", BLENDER_READ, json.dumps(sizes), str(repeat)],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        raise SystemExit(f"the bpy read-back failed: {proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def reduction_effect(hlod, size: tuple[int, int], factors: list[int], frames: int) -> dict[int, dict]:
    """Coh on the street walk with the wall, per factor: means of drawn nodes and queries, and
    the median and minimum PSNR-Y of its frames against the first factor's (all run frame by frame)."""
    path = street_path(frames)
    renderer = Renderer.create_standalone(hlod, size)
    try:
        runs = {f: make("coh", hlod, renderer, settings=RuntimeSettings()) for f in factors}
        rows = {f: {"dn": [], "queries": [], "psnr": [], "import_ms": []} for f in factors}
        for i in range(len(path)):
            view = path.view(i, size)
            depth = wall_depth(view, distance=WALL_M)
            reference = None
            for factor in factors:
                renderer.set_scene_depth(depth, reduce=factor)
                stats = runs[factor].frame(view)
                image = renderer.read_pixels()
                reference = image if reference is None else reference
                row = rows[factor]
                row["dn"].append(stats.dn)
                row["queries"].append(stats.queries)
                row["import_ms"].append(stats.depth_import_ms)
                row["psnr"].append(float(image_error.psnr(reference, image)[0]))
    finally:
        renderer.release()
    return {f: {"dn": float(np.mean(r["dn"])), "queries": float(np.mean(r["queries"])),
                "psnr_y_median": float(np.median(r["psnr"])), "psnr_y_min": float(np.min(r["psnr"])),
                "depth_import_ms_median": float(np.median(r["import_ms"]))} for f, r in rows.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("--sizes", default="1920x1080,3840x2160")
    parser.add_argument("--factors", default="1,2,4,8")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--traversal-sizes", default="640x480,1920x1080")
    parser.add_argument("--no-blender", action="store_true")
    args = parser.parse_args()
    hlod = hlod_file.load(args.file)
    sizes = [_size(s) for s in args.sizes.split(",")]
    factors = [int(f) for f in args.factors.split(",")]
    costs = {s: import_cost(hlod, s, factors, args.repeat) for s in sizes}
    for s, row in costs.items():
        factors_ms = {f"factor_{f}": v for f, v in row.items()}
        print(json.dumps({"measure": "import_ms", "size": f"{s[0]}x{s[1]}", **factors_ms}))
    read = None if args.no_blender else blender_read_cost(sizes, args.repeat)
    if read is not None:
        print(json.dumps({"measure": "blender_read_depth_ms", **read}))
    effects = {s: reduction_effect(hlod, s, factors, args.frames) for s in map(_size, args.traversal_sizes.split(","))}
    for s, rows in effects.items():
        for f, row in rows.items():
            print(json.dumps({"measure": "reduction_effect", "size": f"{s[0]}x{s[1]}", "factor": f, **row}))
    print("\n| size | " + " | ".join(f"import, factor {f} (ms)" for f in factors)
          + (" | Blender read_depth (ms)" if read else "") + " |")
    print("|---|" + "---:|" * (len(factors) + bool(read)))
    for s, row in costs.items():
        extra = f" | {read['read_depth_ms'][f'{s[0]}x{s[1]}']:.1f}" if read else ""
        print(f"| {s[0]}x{s[1]} | " + " | ".join(f"{row[f]:.2f}" for f in factors) + extra + " |")
    print("\n| size | factor | drawn nodes | queries | PSNR-Y vs factor 1, median / min (dB) "
          "| import ms in the frame |")
    print("|---|---:|---:|---:|---|---:|")
    for s, rows in effects.items():
        for f, row in rows.items():
            print(f"| {s[0]}x{s[1]} | {f} | {row['dn']:.2f} | {row['queries']:.1f} | "
                  f"{row['psnr_y_median']:.1f} / {row['psnr_y_min']:.1f} | {row['depth_import_ms_median']:.2f} |")


if __name__ == "__main__":
    main()
