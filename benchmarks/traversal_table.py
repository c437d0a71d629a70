"""Per-method means on one path, all methods in one process with their order alternating across
repeats (timings compare as ratios within the run; node counts are what the method decides).

    .venv/bin/python -m benchmarks.traversal_table FILE.hlod --path PATH.json [--size 640x480] [--repeat 2]

Prints one JSON line per method (median over repeats of each per-frame mean) and a Markdown table.
"""
from __future__ import annotations

import argparse
import json
import statistics

from hlod_core import fileformat
from hlod_core.camera import load_path
from hlod_core.renderer import Renderer
from hlod_core.runner import run_path
from hlod_core.traversal import COUNTERS, METHODS, RuntimeSettings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("--path", required=True)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    size = tuple(int(x) for x in args.size.split("x"))
    hlod, path = fileformat.load(args.file), load_path(args.path)
    methods = list(METHODS)
    runs: dict[str, list[dict]] = {m: [] for m in methods}
    renderer = Renderer.create_standalone(hlod, size)
    try:
        for rep in range(args.repeat):
            for method in (methods if rep % 2 == 0 else methods[::-1]):
                runs[method].append(run_path(hlod, method, RuntimeSettings(), path, size, renderer=renderer))
    finally:
        renderer.release()
    table = {m: {c: statistics.median(r[c] for r in runs[m]) for c in COUNTERS} for m in methods}
    for m in methods:
        print(json.dumps({"method": m, **table[m]}))
    print("| method | DN | RARN | D | triangles | queries | stall ms | cpu ms | frame ms |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for m in methods:
        t = table[m]
        print(f"| {m} | {t['dn']:.2f} | {t['rarn']:.2f} | {t['d']:.2f} | {t['tris']:,.0f} | {t['queries']:.1f} | "
              f"{t['stall_ms']:.2f} | {t['cpu_ms']:.1f} | {t['frame_ms']:.1f} |")


if __name__ == "__main__":
    main()
