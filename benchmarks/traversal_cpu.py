"""The traversal's own Python CPU cost per visited node, each method, with the GL calls excluded
(issue 15): the real renderer runs every draw and query, and a timing proxy around it takes the time
spent inside the renderer (GL calls, waits for query results, the frame's start and end) out of the
frame; what is left is the traversal's Python (the per-frame vectorised `_prepare` and the walk).

    .venv/bin/python -m benchmarks.traversal_cpu FILE.hlod --path PATH.json [--size 640x480] [--repeat 2]
        [--methods coh sw ...] [--alpha query|projected|cube]

Methods alternate order across repeats (timings compare as ratios within the run). Prints one JSON line
per method and a Markdown table: visited nodes a frame, prepare us a frame, walk us a visited node,
all us a visited node (prepare + walk over visited), renderer ms a frame (excluded).

Data form: out, {method: {"visited", "prepare_us", "walk_us_per_node", "python_us_per_node",
"renderer_ms", "frames"}} (medians over repeats of per-path means).
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

from hlod_core import fileformat
from hlod_core.camera import CameraPath, load_path
from hlod_core.hierarchy import Hlod
from hlod_core.renderer import Renderer
from hlod_core.textures import load_images
from hlod_core.traversal import METHODS, RuntimeSettings, make

US_PER_S = 1e6
MS_PER_S = 1e3
#: The renderer calls a traversal makes; time inside them is the renderer's, not the traversal's.
RENDERER_CALLS = ("begin_frame", "end_frame", "draw_node", "issue_query", "available", "result")


class TimedRenderer:
    """Forwards to a real renderer and sums the seconds spent inside RENDERER_CALLS."""

    def __init__(self, renderer: Renderer):
        self._renderer = renderer
        self.inside_s = 0.0
        self.calls = 0
        for name in RENDERER_CALLS:
            setattr(self, name, self._timed(getattr(renderer, name)))

    def _timed(self, call):
        def timed(*args, **kwargs):
            self.calls += 1
            started = time.perf_counter()
            try:
                return call(*args, **kwargs)
            finally:
                self.inside_s += time.perf_counter() - started
        return timed

    def __getattr__(self, name):  # attributes such as query_box_pad
        return getattr(self._renderer, name)


def _proxy_overhead_s(calls: int = 20000) -> float:
    """Seconds the proxy adds per call outside its own clock reads (the closure, the counter), measured
    here and taken out of the traversal's time."""
    proxy = TimedRenderer.__new__(TimedRenderer)
    proxy.inside_s, proxy.calls = 0.0, 0
    timed = TimedRenderer._timed(proxy, lambda: None)
    started = time.perf_counter()
    for _ in range(calls):
        timed()
    return max(0.0, (time.perf_counter() - started - proxy.inside_s) / calls)


def measure(hlod: Hlod, method: str, settings: RuntimeSettings, path: CameraPath, size: tuple[int, int], *,
            renderer: Renderer, call_overhead_s: float) -> dict:
    """One pass of `method` over `path`: per-frame means of the traversal's Python time."""
    proxy = TimedRenderer(renderer)
    traversal = make(method, hlod, proxy, settings)
    prepare = traversal._prepare
    prepare_s = {"s": 0.0}

    def timed_prepare(view):
        started = time.perf_counter()
        prepare(view)
        prepare_s["s"] += time.perf_counter() - started
    traversal._prepare = timed_prepare
    visited = 0
    total_s = 0.0
    for i in range(len(path)):
        view = path.view(i, size)
        started = time.perf_counter()
        stats = traversal.frame(view)
        total_s += time.perf_counter() - started
        visited += stats.traversed
    frames = len(path)
    python_s = total_s - proxy.inside_s - proxy.calls * call_overhead_s
    walk_s = python_s - prepare_s["s"]
    return {"visited": visited / frames, "prepare_us": US_PER_S * prepare_s["s"] / frames,
            "walk_us_per_node": US_PER_S * walk_s / max(visited, 1),
            "python_us_per_node": US_PER_S * python_s / max(visited, 1),
            "renderer_ms": MS_PER_S * proxy.inside_s / frames, "frames": frames}


def run(hlod: Hlod, path: CameraPath, size: tuple[int, int], *, methods: list[str], repeat: int,
        settings: RuntimeSettings) -> dict:
    overhead_s = _proxy_overhead_s()
    runs: dict[str, list[dict]] = {m: [] for m in methods}
    renderer = Renderer.create_standalone(hlod, size, images=load_images(hlod))
    try:
        for rep in range(repeat):
            for method in (methods if rep % 2 == 0 else methods[::-1]):
                runs[method].append(measure(hlod, method, settings, path, size, renderer=renderer,
                                            call_overhead_s=overhead_s))
    finally:
        renderer.release()
    return {m: {k: statistics.median(r[k] for r in runs[m]) for k in runs[m][0]} for m in methods}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("--path", required=True)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--alpha", default="query", choices=["query", "projected", "cube"])
    args = parser.parse_args()
    size = tuple(int(x) for x in args.size.split("x"))
    table = run(fileformat.load(args.file), load_path(args.path), size, methods=args.methods,
                repeat=args.repeat, settings=RuntimeSettings(alpha=args.alpha))
    for method, row in table.items():
        print(json.dumps({"method": method, **row}))
    print("| method | visited / frame | prepare us / frame | walk us / visited node | Python us / visited node "
          "| renderer ms / frame (excluded) |")
    print("|---|---:|---:|---:|---:|---:|")
    for method, t in table.items():
        print(f"| {method} | {t['visited']:.1f} | {t['prepare_us']:.0f} | {t['walk_us_per_node']:.2f} | "
              f"{t['python_us_per_node']:.2f} | {t['renderer_ms']:.2f} |")


if __name__ == "__main__":
    main()
