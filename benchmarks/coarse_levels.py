"""Coarse levels on a scene of open-boundary statues: a bake of this checkout against a bake of an
earlier one (`--before DIR`, e.g. `git worktree add /tmp/before COMMIT`), in one run.

    PYTHONPATH=. .venv/bin/python -m benchmarks.coarse_levels --before /tmp/before
        [--spec tests/scenes/open_statues_5m.json | --procedural pieces [--scale 1]]
        [--path tests/scenes/open_statues_far_path.json | --no-path]
        [--jobs 2] [--repeat 1] [--target-tris 2000] [--out DIR]

`--procedural NAME` bakes a procedural scene of this checkout (hlod_core.io.procedural.SCENES),
written once as an OBJ that both checkouts read (the earlier one may not have the scene).

Each repeat bakes the spec with both checkouts' command line (`python -m hlod_core bake SPEC
--no-cache --jobs N`, each in its own folder and PYTHONPATH), alternating which goes first, and
reports per bake:
    bake seconds        the command's own `seconds` (reading the input excluded), median of the repeats;
    root / per depth    the root's triangles, and per depth the inner nodes, their triangles, the
                        largest and how many are above 1.25 x target_tris;
    total               triangles stored (every node's LOD, leaves included);
    pruned              pieces the bake dropped (meta; 0 before it could);
    drawn               Coh(P) over the far camera path (an orbit pulling back from 2 to 45 times
                        the grid's side) with this checkout's renderer (`python -m hlod_core run
                        FILE --method coh --path PATH`, 640x480, tau 1): the mean triangles and nodes
                        drawn per frame; the same renderer for both files, so only the bakes differ.
The load average is recorded before and after (a 2-core VM shared with other work skews times).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from hlod_core.io import hlod_file

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "tests" / "scenes" / "open_statues_5m.json"
FAR_PATH = ROOT / "tests" / "scenes" / "open_statues_far_path.json"
#: The log line tells nodes over the budget from this factor (bake.collapse.OVER_BUDGET_FACTOR).
OVER_FACTOR = 1.25


def _last_json(text: str) -> dict:
    return json.loads([line for line in text.splitlines() if line.startswith("{")][-1])


def bake_with(checkout: Path, spec: Path, out: Path, *, jobs: int, target_tris: int) -> dict:
    """The bake command's JSON line of `checkout`'s code baking `spec` into `out`."""
    env = {**os.environ, "PYTHONPATH": str(checkout)}
    done = subprocess.run([sys.executable, "-m", "hlod_core", "-q", "bake", str(spec), "-o", str(out), "--no-cache",
                           "--jobs", str(jobs), "--target-tris", str(target_tris)],
                          cwd=checkout, env=env, capture_output=True, text=True, check=True)
    return _last_json(done.stdout)


def levels(path: Path, target_tris: int) -> dict:
    """Per depth of the file's inner nodes: nodes, triangles, largest, above OVER_FACTOR x target."""
    hlod = hlod_file.load(path)
    inner = ~hlod.is_leaf
    out = {}
    for d in range(int(hlod.depth.max()) + 1):
        level = inner & (hlod.depth == d)
        if level.any():
            tris = hlod.tri_count[level]
            out[str(d)] = {"nodes": int(level.sum()), "tris": int(tris.sum()), "largest": int(tris.max()),
                           "over": int((tris > OVER_FACTOR * target_tris).sum())}
    return {"root_tris": int(hlod.tri_count[0]), "total_tris": int(hlod.indices.shape[0]),
            "root_error": float(hlod.error[0]), "per_depth": out,
            "pruned_pieces": int(hlod.meta.get("pruned_pieces", 0)),
            "pruned_tris": int(hlod.meta.get("pruned_tris", 0)),
            "nodes_over_budget": int((hlod.tri_count[inner] > OVER_FACTOR * target_tris).sum())}


def drawn(path: Path, camera: Path) -> dict:
    """Coh(P)'s mean triangles and nodes per frame over `camera`, with this checkout's renderer."""
    done = subprocess.run([sys.executable, "-m", "hlod_core", "-q", "run", str(path), "--method", "coh", "--path",
                           str(camera)], cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, check=True)
    result = _last_json(done.stdout)
    return {"tris": float(result["tris"]), "dn": float(result["dn"]), "frames": int(result["frames"])}


def write_obj(path: Path, name: str, *, scale: float) -> Path:
    """The procedural scene `name` at `scale` as an OBJ (float64 coordinates written exactly)."""
    from hlod_core.io import procedural

    mesh = procedural.SCENES[name](seed=1, scale=scale)
    with open(path, "w", encoding="ascii") as f:
        np.savetxt(f, mesh.positions, fmt="v %.17g %.17g %.17g")
        np.savetxt(f, mesh.faces + 1, fmt="f %d %d %d")
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--before", type=Path, required=True, help="a checkout of the earlier commit")
    parser.add_argument("--spec", type=Path, default=SPEC)
    parser.add_argument("--procedural", default=None, help="a procedural scene's name instead of --spec")
    parser.add_argument("--scale", type=float, default=1.0, help="with --procedural: its scale")
    parser.add_argument("--path", type=Path, default=FAR_PATH)
    parser.add_argument("--no-path", action="store_true", help="skip the drawn triangles")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--target-tris", type=int, default=2000)
    parser.add_argument("--out", type=Path, default=None, help="keep the bakes and report.json here")
    args = parser.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="coarse-levels-"))
    out.mkdir(parents=True, exist_ok=True)
    checkouts = {"before": args.before.resolve(), "after": ROOT}
    spec = args.spec.resolve()
    if args.procedural:
        spec = write_obj(out / f"{args.procedural}.obj", args.procedural, scale=args.scale)
    load = [os.getloadavg()]
    seconds: dict[str, list[float]] = {name: [] for name in checkouts}
    for r in range(args.repeat):
        for name in (("before", "after") if r % 2 == 0 else ("after", "before")):
            summary = bake_with(checkouts[name], spec, out / f"{name}.hlod", jobs=args.jobs,
                                target_tris=args.target_tris)
            seconds[name].append(float(summary["seconds"]))
            print(f"{name}: bake {summary['seconds']:.1f} s, root {summary['root_tris']}", flush=True)
    report = {"spec": str(spec), "path": None if args.no_path else str(args.path), "jobs": args.jobs,
              "target_tris": args.target_tris}
    for name in checkouts:
        report[name] = {"bake_seconds": float(np.median(seconds[name])), "bake_seconds_all": seconds[name],
                        **levels(out / f"{name}.hlod", args.target_tris),
                        "drawn": None if args.no_path else drawn(out / f"{name}.hlod", args.path)}
    load.append(os.getloadavg())
    report["load_average"] = [list(x) for x in load]
    (out / "report.json").write_text(json.dumps(report, indent=1))
    for name in checkouts:
        r = report[name]
        depths = ", ".join(f"d{d}: {v['tris']} ({v['nodes']} nodes, largest {v['largest']}, {v['over']} over)"
                           for d, v in r["per_depth"].items())
        print(f"{name}: bake {r['bake_seconds']:.1f} s; root {r['root_tris']} (error {r['root_error']:.4g}); "
              f"total {r['total_tris']}; nodes over {OVER_FACTOR} x target {r['nodes_over_budget']}; pruned "
              f"{r['pruned_pieces']} pieces ({r['pruned_tris']} tris)"
              + ("" if r["drawn"] is None else f"; Coh(P) far path {r['drawn']['tris']:.0f} tris, "
                                               f"{r['drawn']['dn']:.1f} nodes per frame") + f"\n  {depths}")
    print(f"load average before/after: {load[0]} / {load[1]}; report: {out / 'report.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
