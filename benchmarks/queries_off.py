"""No queries where they do not pay (traversal.query_gate, settings queries "auto"), measured on llvmpipe:

- open: the square of 36 scanned statues standing apart on flat ground (hlod_core.io.procedural
  square_scene) along its far-to-near path (square_far_path), Full, VFC and Coh(P) interleaved frame
  by frame in one evaluation (hlod_core.report.evaluate): Coh(P)'s frame time over VFC's, PSNR-Y
  against Full of both, the share of frames without queries;
- occluded: the crowd (its fast walk), the gallery (its row path) and the default city (a seeded
  inspection path): Coh(P) of this checkout against Coh(P) of another (`--main`, e.g. a worktree
  of the main branch), each `python -m hlod_core run` in its own process, the two alternating
  `--repeat` times: frame time and drawn nodes over the other's (medians over the runs);
- occluded, in one process: Coh(P) against Coh(P) with `--queries always` (this checkout's, which
  the traversal tests hold call for call to the published loop) on the same scenes, interleaved
  frame by frame as the evaluation does (hlod_core.report.interleaved): frame time and drawn nodes,
  the timing the alternating processes cannot give on a loaded machine;
- mid-path: the square beside a city block (square_and_street_scene) along square_to_street_path:
  the first frame, once the gate has turned the queries off, where Coh(P)'s queries, asked every
  frame (queries "always"), cull 10% of VFC's triangles, and how many frames later Coh(P) with the
  gate queries again (SW(P)'s culled share beside it, for the record).

    PYTHONPATH=. .venv/bin/python -m benchmarks.queries_off --work DIR --prepare    # bakes, untimed
    flock /tmp/hlod-bench.lock env PYTHONPATH=. .venv/bin/python -m benchmarks.queries_off --work DIR \\
        --main ../main-checkout [--size 640x480] [--repeat 3] [--frames 80] [--parts open mid main interleaved]

`--prepare` bakes the scenes into --work (the crowd and the gallery from tests/scenes/, whose models
tests/models.py writes first) and writes the paths; the timed run reads them. Prints one JSON line
per part and writes DIR/queries_off.json with all of them (queries_off_PARTS.json for some).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.io import hlod_file, procedural
from hlod_core.model.camera_path import inspection_path, load_path
from hlod_core.render.renderer import Renderer
from hlod_core.report import evaluate
from hlod_core.report.interleaved import Variant, run_interleaved
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings
from hlod_core.traversal.stats import COUNTERS

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "tests" / "scenes"
#: occluded scene -> (its .hlod in --work, its path file in --work)
OCCLUDED = ("crowd", "gallery", "city")
RESUME_SHARE = 0.10  # the triangles Coh(P)'s queries cull from which they must be back
PARTS = ("open", "mid", "main", "interleaved")


def prepare(work: Path, *, frames: int) -> None:
    """Bakes and paths into `work` (what exists is kept)."""
    work.mkdir(parents=True, exist_ok=True)
    made = {"square": lambda: procedural.square_scene(), "street": lambda: procedural.square_and_street_scene(),
            "city": lambda: procedural.default_scene(seed=1)}
    for name, scene in made.items():
        if not (work / f"{name}.hlod").exists():
            logging.info("baking %s", name)
            hlod_file.save(bake(scene(), BakeSettings(jobs=2)), work / f"{name}.hlod")
    sys.path.insert(0, str(ROOT / "tests"))
    import models  # tests/models.py: writes the models the specs read

    for name in ("crowd", "gallery"):
        if not (work / f"{name}.hlod").exists():
            logging.info("baking %s", name)
            subprocess.run([sys.executable, "-m", "hlod_core", "-q", "bake", str(models.scene(f"{name}_1m")), "-o",
                            str(work / f"{name}.hlod"), "--jobs", "2"], check=True, cwd=ROOT)
    procedural.square_far_path(frames=frames).save(work / "square.json")
    procedural.square_to_street_path(frames=90).save(work / "street.json")
    load_path(SCENES / "crowd_walk_path.json").save(work / "crowd.json")
    load_path(SCENES / "gallery_row_path.json").save(work / "gallery.json")
    inspection_path(hlod_file.load(work / "city.hlod"), seed=1, frames=120).save(work / "city.json")


def open_scene(work: Path, *, size: tuple[int, int], repeat: int) -> dict:
    """Full, VFC and Coh(P) interleaved on the open square (module docstring)."""
    hlod, path = hlod_file.load(work / "square.hlod"), load_path(work / "square.json")
    with tempfile.TemporaryDirectory(prefix="queries_off.") as out:
        report = evaluate.evaluate(hlod, path, size, methods=["full", "vfc", "coh_p"], repeat=repeat, out_dir=out,
                                   psnr_frames=20, figures=False)
    rows = report["methods"]
    coh, vfc = rows["coh_p"], rows["vfc"]
    return {"frames": len(path), "size": list(size), "repeat": repeat,
            "coh_p_over_vfc_frame_ms": coh["frame_ms"] / vfc["frame_ms"],
            "psnr_y_vs_full": {"coh_p": coh["psnr_y_vs_full"], "vfc": vfc["psnr_y_vs_full"]},
            "rows": {k: {c: r[c] for c in ("frame_ms", "dn", "tris", "queries", "stall_ms", "queries_off")}
                     for k, r in rows.items()},
            "queries_off_reason": coh["queries_off_reason"]}


def _run(checkout: Path, work: Path, name: str, *, size: tuple[int, int]) -> dict:
    """`python -m hlod_core run` of Coh(P) on scene `name` with `checkout`'s code: its JSON."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    done = subprocess.run([sys.executable, "-m", "hlod_core", "run", str(work / f"{name}.hlod"), "--method", "coh",
                           "--path", str(work / f"{name}.json"), "--size", f"{size[0]}x{size[1]}"],
                          check=True, cwd=checkout, env=env, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def occluded(work: Path, main: Path, *, size: tuple[int, int], repeat: int) -> dict:
    """Coh(P) of this checkout over `main`'s on the occluded scenes, alternating runs (module docstring)."""
    out = {}
    for name in OCCLUDED:
        runs: dict[str, list[dict]] = {"this": [], "main": []}
        for i in range(repeat):
            for which in (("this", "main") if i % 2 == 0 else ("main", "this")):
                runs[which].append(_run(ROOT if which == "this" else main, work, name, size=size))
        med = {w: {c: statistics.median(r[c] for r in rs) for c in ("frame_ms", "dn", "queries")}
               for w, rs in runs.items()}
        out[name] = {"frames": runs["this"][0]["frames"], "this": med["this"], "main": med["main"],
                     "frame_ms_ratio": med["this"]["frame_ms"] / med["main"]["frame_ms"],
                     "dn_ratio": med["this"]["dn"] / med["main"]["dn"],
                     "queries_off": statistics.median(r.get("queries_off", 0.0) for r in runs["this"]),
                     "frame_ms_runs": {w: [r["frame_ms"] for r in rs] for w, rs in runs.items()}}
    return out


def interleaved(work: Path, *, size: tuple[int, int], repeat: int) -> dict:
    """Coh(P) against Coh(P) asking every frame, interleaved frame by frame (module docstring)."""
    runs = [Variant("coh_p", "coh", RuntimeSettings()),
            Variant("coh_p always", "coh", RuntimeSettings(queries="always"))]
    ms, dn, off = (COUNTERS.index(c) for c in ("frame_ms", "dn", "queries_off"))
    out = {}
    for name in OCCLUDED:
        hlod, path = hlod_file.load(work / f"{name}.hlod"), load_path(work / f"{name}.json")
        renderer = Renderer.create_standalone(hlod, size)
        try:
            per_frame, _ = run_interleaved(hlod, renderer, path, size=size, runs=runs, repeat=repeat, picked=[],
                                           started=time.perf_counter(), label=f"{name}: ")
        finally:
            renderer.release()
        rows = {k: np.median(v, axis=0).mean(axis=0) for k, v in per_frame.items()}
        auto, always = rows["coh_p"], rows["coh_p always"]
        out[name] = {"frames": len(path), "frame_ms": [auto[ms], always[ms]], "dn": [auto[dn], always[dn]],
                     "frame_ms_ratio": auto[ms] / always[ms], "dn_ratio": auto[dn] / always[dn],
                     "queries_off": auto[off]}
    return out


def mid_path(work: Path, *, size: tuple[int, int]) -> dict:
    """The switch back to queries where occlusion appears (module docstring)."""
    hlod, path = hlod_file.load(work / "street.hlod"), load_path(work / "street.json")
    renderer = Renderer.create_standalone(hlod, size)
    try:
        vfc, sw, coh = (make(m, hlod, renderer) for m in ("vfc", "sw", "coh"))
        always = make("coh", hlod, renderer, settings=RuntimeSettings(queries="always"))
        culled, sw_culled, off = [], [], []
        for i in range(len(path)):
            view = path.view(i, size)
            vfc_tris = max(vfc.frame(view).tris, 1)
            culled.append(1.0 - always.frame(view).tris / vfc_tris)
            sw_culled.append(1.0 - sw.frame(view).tris / vfc_tris)
            off.append(coh.frame(view).queries_off)
    finally:
        renderer.release()
    went_off = off.index(1) if 1 in off else None
    first = next((i for i in range(went_off or 0, len(path)) if culled[i] >= RESUME_SHARE), None)
    back = next((i for i in range(first, len(path)) if not off[i]), None) if went_off is not None and first else None
    return {"frames": len(path), "parts": dict(path.parts), "went_off": went_off, "first_culling_frame": first,
            "queries_back": back, "latency_frames": None if back is None else back - first,
            "off": off, "culled": [round(c, 3) for c in culled], "sw_culled": [round(c, 3) for c in sw_culled]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", required=True, help="folder of the bakes and paths")
    parser.add_argument("--prepare", action="store_true", help="bake the scenes and write the paths, then stop")
    parser.add_argument("--main", help="another checkout whose Coh(P) the occluded scenes compare against")
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--frames", type=int, default=80, help="frames of the open square's path")
    parser.add_argument("--parts", nargs="+", default=list(PARTS), choices=list(PARTS), help="what to measure")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="queries_off: %(message)s")
    work = Path(args.work)
    size = tuple(int(v) for v in args.size.split("x"))
    if args.prepare:
        prepare(work, frames=args.frames)
        return 0
    started = time.perf_counter()
    results = {"size": list(size), "load_before": os.getloadavg()}
    if "open" in args.parts:
        results["open"] = open_scene(work, size=size, repeat=args.repeat)
        print(json.dumps({"open": {k: v for k, v in results["open"].items() if k != "rows"}}), flush=True)
    if "mid" in args.parts:
        results["mid_path"] = mid_path(work, size=size)
        series = ("off", "culled", "sw_culled")
        print(json.dumps({"mid_path": {k: v for k, v in results["mid_path"].items() if k not in series}}),
              flush=True)
    if "main" in args.parts and args.main:
        results["occluded"] = occluded(work, Path(args.main).resolve(), size=size, repeat=args.repeat)
        for name, r in results["occluded"].items():
            print(json.dumps({name: {k: v for k, v in r.items() if k != "frame_ms_runs"}}), flush=True)
    if "interleaved" in args.parts:
        results["interleaved"] = interleaved(work, size=size, repeat=args.repeat)
        print(json.dumps({"interleaved": results["interleaved"]}), flush=True)
    results["load_after"] = os.getloadavg()
    results["seconds"] = time.perf_counter() - started
    name = "queries_off" if set(args.parts) == set(PARTS) else "queries_off_" + "_".join(args.parts)
    (work / f"{name}.json").write_text(json.dumps(results, indent=1))
    print(json.dumps({"seconds": results["seconds"], "load": [results["load_before"], results["load_after"]]}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
