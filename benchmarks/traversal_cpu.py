"""The traversal's own Python CPU cost per visited node, each method, with the GL calls excluded:
the real renderer runs every draw and query, and a timing proxy around it takes the time
spent inside the renderer (GL calls, waits for query results, the frame's start and end) out of the
frame; what is left is the traversal's Python (the per-frame vectorised `prepare` and the walk).

    .venv/bin/python -m benchmarks.traversal_cpu FILE.hlod --path PATH.json [--size 640x480] [--repeat 2]
        [--methods coh sw ...] [--alpha query|projected|cube] [--clock wall|thread] [--renderer gl|null]
        [--baseline DIR]

`--renderer null` runs the traversals against a renderer without GL (NullRenderer: nothing drawn,
every query back at once with a seeded visibility per node), which leaves the Python alone on warm
caches. `--clock thread` times with this thread's CPU time instead of wall time (the default): on a shared
machine it leaves out the time other processes held the core, not the slower caches and the busy
sibling core they leave behind. Methods alternate order across repeats (timings compare as ratios
within the run). Prints one JSON line
per method and a Markdown table: visited nodes a frame, prepare us a frame, walk us a visited node,
all us a visited node (prepare + walk over visited), renderer ms a frame (excluded).

`--baseline DIR` also runs the traversal of another version (DIR holds its `hlod_core` package, e.g.
`git archive COMMIT hlod_core | tar -x -C DIR`) on the same renderer, its pass of each method next to
this version's (the two alternate first), as rows "METHOD (baseline)": a paired comparison, since
the figures move by tens of percent between runs on a shared machine.

The measurement is tests/traversal_timing.py's (its data form there).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from hlod_core.io import hlod_file
from hlod_core.model.camera_path import load_path
from hlod_core.traversal.methods import METHODS
from hlod_core.traversal.settings import RuntimeSettings

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from traversal_timing import CLOCKS, baseline_traversal, run  # the measurement, a test helper

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("--path", required=True)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--alpha", default="query", choices=["query", "projected", "cube"])
    parser.add_argument("--clock", default="wall", choices=list(CLOCKS))
    parser.add_argument("--renderer", default="gl", choices=["gl", "null"])
    parser.add_argument("--baseline", help="a folder holding another version's hlod_core, run next to this one")
    args = parser.parse_args()
    baseline = baseline_traversal(args.baseline) if args.baseline else None
    size = tuple(int(x) for x in args.size.split("x"))
    table = run(hlod_file.load(args.file), load_path(args.path), size, methods=args.methods,
                repeat=args.repeat, settings=RuntimeSettings(alpha=args.alpha), clock=args.clock,
                null_renderer=args.renderer == "null", baseline=baseline)
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
