"""Re-bake times with the bake cache: a full bake, a re-bake after changing nothing, a re-bake after
moving one object, and the undo (the spec again), in one run.

    PYTHONPATH=. .venv/bin/python -m benchmarks.rebake [--spec tests/scenes/crowd_1m.json]
        [--move 77] [--by 1.5 0 0] [--jobs 2] [--error exact|bound] [--verify] [--work] [--out DIR]
        [--repeat N]

The spec's instances are numbered in file order (models, then transforms); --move picks one and
--by translates it (model units), written as a modified spec in a temporary folder (model paths
made absolute). Times are bake() alone, as in bake_throughput.py (reading the input excluded):
    full       the spec, into an empty cache folder (it writes the cache);
    unchanged  the same mesh again with that cache;
    moved      the modified spec with that cache (in the full bake's frame while it fits:
               tests/scenes/yard_1m.json --move 0 --by -3.6 0 0 moves the corner statue outward by a
               tenth of the scene's extent, which grows the root cube);
    undo       the spec again with that cache.
--repeat N runs the whole sequence N times, each into a new cache folder (medians in the summary).
--error picks the inner nodes' error measure (BakeSettings.error: the bound measures a node
against its children's LODs, not every original below it); the figures go to rebake.json
(exact) or rebake-bound.json.
--verify also bakes the modified spec from scratch (no cache) in the full bake's frame (as
`--frame-from` does) and checks that the re-bake gave the same arrays, the same meta but
meta.VOLATILE_META and the same texture files (byte-identity). A spec of textured materials (the
statue square, tests/scenes/statue_square.py) bakes proxy materials (BakeSettings' defaults), each
bake's textures in a temporary folder of its own.
--work also measures what the moved re-bake cannot do without (tests/rebake_work.py): the cache is put
back to the spec's state (a bake of the spec), then the moved spec is re-baked with jobs 1, where
every task runs in this process, each decimation and measurement timed (wall seconds of each call,
perf_counter, on an otherwise idle process: what the task costs a worker), and the phases before
the first task (prepare, octree, leaves, cache keys and loads: the bake cannot know what changed
before them). A lower bound of the moved re-bake at --jobs N is those phases plus the tasks'
seconds / N (perfect packing, no assemble, no cache write, no wait on the decimation chain, and
the exact measure's leaf arrays left out too: at jobs 1 they are made inline, about 0.5 s on the
crowd); full / bound is the most the moved re-bake could gain over the full bake with this work.
The machine's load average is recorded before and after: other processes on a 2-core VM slow the
full bake (many seconds of decimation) and the re-bakes alike, but not in the same proportion.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hlod_core.bake.meta import stable_meta
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space.frame import Frame
from hlod_core.io import meshes

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import models  # tests/models.py: the test models by role
from rebake_work import rebuilt_work, timed_bake  # the timed re-bake, a test helper

ROOT = Path(__file__).resolve().parents[1]


def moved_spec(spec_path: Path, instance: int, offset: np.ndarray, *, folder: Path) -> Path:
    """A copy of the spec in `folder` with instance `instance` translated by `offset`."""
    spec = json.loads(spec_path.read_text())
    seen = 0
    for model in spec["models"]:
        model["path"] = str((spec_path.parent / model["path"]).resolve())
        transforms = model.setdefault("transforms", [np.eye(4).ravel().tolist()])
        if seen <= instance < seen + len(transforms):
            m = np.asarray(transforms[instance - seen], np.float64).reshape(4, 4)
            m[:3, 3] += offset
            transforms[instance - seen] = m.ravel().tolist()
        seen += len(transforms)
    if instance >= seen:
        raise SystemExit(f"--move {instance}: the spec has {seen} instances")
    out = folder / spec_path.name
    out.write_text(json.dumps(spec))
    return out


def identical(a, b) -> bool:
    """The same arrays, meta but meta.VOLATILE_META, and texture files byte for byte (a bake with
    proxy materials writes their PNGs into a folder of its own: the files are compared, not the paths)."""
    arrays = all(np.array_equal(x, getattr(b, name)) for name, x in a.node_arrays().items())
    geometry = all(np.array_equal(getattr(a, name), getattr(b, name)) for name in ("origin", "positions", "indices"))
    textures = len(a.materials) == len(b.materials) and all(
        (x.texture is None) == (y.texture is None) and (x.texture is None or x.texture == y.texture
                                                        or Path(x.texture).read_bytes() == Path(y.texture).read_bytes())
        for x, y in zip(a.materials, b.materials))
    return arrays and geometry and textures and stable_meta(a.meta) == stable_meta(b.meta)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=models.input_file, default=str(ROOT / "tests" / "scenes" / "crowd_1m.json"))
    parser.add_argument("--move", type=int, default=41, help="instance to move (file order)")
    parser.add_argument("--by", type=float, nargs=3, default=[1.5, 0.0, 0.0], help="translation, model units")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--error", choices=["exact", "bound"], default="exact",
                        help="error measure (BakeSettings.error)")
    parser.add_argument("--verify", action="store_true", help="also bake the moved spec from scratch and compare")
    parser.add_argument("--work", action="store_true",
                        help="also time the moved re-bake's decimations and measurements (jobs 1) and its lower bound")
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "bench")
    parser.add_argument("--repeat", type=int, default=1, help="runs of the whole sequence (fresh cache each)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    settings = BakeSettings(jobs=args.jobs, error=args.error)
    result: dict = {"spec": str(args.spec), "jobs": args.jobs, "error": args.error, "moved_instance": args.move,
                    "by": args.by, "load_before": os.getloadavg(), "repeats": []}
    with tempfile.TemporaryDirectory(prefix="rebake-") as scratch:
        mesh = meshes.load_inputs([args.spec])
        moved_mesh = meshes.load_inputs([moved_spec(args.spec, args.move, np.asarray(args.by), folder=Path(scratch))])
        result["input_tris"] = mesh.tri_count
        for repeat in range(args.repeat):
            cache = Path(scratch) / f"run{repeat}.hlod.cache"
            runs, kept = {}, {}
            for name, m in (("full", mesh), ("unchanged", mesh), ("moved", moved_mesh), ("undo", mesh)):
                seconds, hlod = timed_bake(m, settings, cache)
                runs[name] = {"seconds": seconds, "nodes": hlod.node_count, "cache": hlod.meta["cache"],
                              "frame_source": hlod.meta["frame_source"], "phase_seconds": hlod.meta["phase_seconds"]}
                kept[name] = hlod
                print(json.dumps({name: runs[name]}), flush=True)
            row = {"runs": runs, "load": os.getloadavg()[0],
                   "speedup_unchanged": runs["full"]["seconds"] / runs["unchanged"]["seconds"],
                   "speedup_moved": runs["full"]["seconds"] / runs["moved"]["seconds"],
                   "speedup_undo": runs["full"]["seconds"] / runs["undo"]["seconds"]}
            if args.verify:
                frame = Frame.from_meta(kept["full"].meta["frame"], where="the full bake")
                seconds, scratch_hlod = timed(lambda: bake(moved_mesh, settings, frame_from=frame))
                row["moved_from_scratch_seconds"] = seconds
                row["moved_rebake_identical_to_scratch"] = identical(kept["moved"], scratch_hlod)
                row["undo_identical_to_full"] = identical(kept["undo"], kept["full"])
            result["repeats"].append(row)
            print(json.dumps({k: v for k, v in row.items() if k != "runs"}), flush=True)
        rows = result["repeats"]
        for key in ("speedup_unchanged", "speedup_moved", "speedup_undo"):
            result[key] = float(np.median([r[key] for r in rows]))
        result["full_seconds"] = [r["runs"]["full"]["seconds"] for r in rows]
        result["moved_seconds"] = [r["runs"]["moved"]["seconds"] for r in rows]
        if args.verify:
            result["identical"] = all(r["moved_rebake_identical_to_scratch"] and r["undo_identical_to_full"]
                                      for r in rows)
        if args.work:
            cache = Path(scratch) / "work.hlod.cache"
            timed_bake(mesh, settings, cache)  # the cache in the spec's state
            work = rebuilt_work(moved_mesh, settings, cache)
            bound = work["before_tasks_s"] + (work["decimate_s"] + work["measure_s"]) / args.jobs
            result["moved_work"] = {**work, "lower_bound_s": bound,
                                    "max_speedup_moved": float(np.median(result["full_seconds"])) / bound}
    result["load_after"] = os.getloadavg()
    (args.out / ("rebake.json" if args.error == "exact" else f"rebake-{args.error}.json")).write_text(
        json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k != "repeats"}))


def timed(fn):
    started = time.perf_counter()
    out = fn()
    return time.perf_counter() - started, out


if __name__ == "__main__":
    main()
