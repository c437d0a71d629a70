"""When do occlusion queries pay? The low, middle and high depth-complexity scenes (hlod_core.io.procedural,
`python -m hlod_core scene low|middle|high`) side by side: each is baked, then evaluated
(hlod_core.report.evaluate: methods interleaved frame by frame in one process, so timings compare as ratios
within a scene's run) along a seeded inspection path (orbit, fly-through, dolly, rotate), and each
method's frame time and drawn nodes are reported relative to VFC's, which issues no queries.

    .venv/bin/python -m benchmarks.queries_pay [--out docs/evaluation] [--frames 120] [--size 320x240]
        [--methods vfc bool sw_p coh_p coh_mu ideal] [--repeat 3] [--seed 1] [--jobs 2] [--work DIR]

Writes OUT/queries_pay.json ({"frames", "size", "repeat", "seed", "methods", "seconds", "scenes":
{name: {"summary": the bake's summary, "methods": {key: the evaluation's row}, "relative_to_vfc":
{key: {"frame_ms", "dn"}}, "seconds"}}}) and OUT/queries_pay.png (figures.queries_pay_figure),
and prints one JSON line per scene with the ratios. The evaluation folders (reports of their own)
go to --work (a temporary folder by default). Needs matplotlib.
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
import tempfile
import time
from pathlib import Path

from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.core.atomic import write_text_atomic
from hlod_core.core.errors import HlodError, InputError
from hlod_core.io import procedural
from hlod_core.model.camera_path import inspection_path
from hlod_core.report import evaluate, figures

SCENES = ("low", "middle", "high")
DEFAULT_METHODS = ("vfc", "bool", "sw_p", "coh_p", "coh_mu", "ideal")
REFERENCE = "vfc"  # no queries: the ratios' denominator
RATIO_COUNTERS = ("frame_ms", "dn")
ROW_KEYS = ("frame_ms", "dn", "queries", "stall_ms", "tris", "psnr_y_vs_bool")
PSNR_FRAMES = 5


def measure(*, work: Path, frames: int, size: tuple[int, int], methods: list[str], repeat: int, seed: int,
            jobs: int) -> dict:
    """Bake and evaluate each scene of SCENES; the queries_pay.json contents (module docstring)."""
    if REFERENCE not in methods:
        raise InputError(f"--methods must include {REFERENCE} (the reference of every ratio)")
    started = time.perf_counter()
    out = {"frames": frames, "size": list(size), "repeat": repeat, "seed": seed, "methods": methods, "scenes": {}}
    for name in SCENES:
        scene_started = time.perf_counter()
        logging.info("%s: baking", name)
        hlod = bake(procedural.SCENES[name](seed=seed), BakeSettings(jobs=jobs))
        path = inspection_path(hlod, seed=seed, frames=frames)
        logging.info("%s: evaluating %s over %d frames", name, " ".join(methods), frames)
        report = evaluate.evaluate(hlod, path, size, methods=methods, repeat=repeat, out_dir=work / name,
                                   psnr_frames=min(PSNR_FRAMES, frames), seed=seed, figures=False)
        rows = {k: {c: r[c] for c in ROW_KEYS} for k, r in report["methods"].items()}
        reference = rows[REFERENCE]
        out["scenes"][name] = {
            "summary": hlod.summary(), "methods": rows,
            "relative_to_vfc": {k: {c: r[c] / reference[c] if reference[c] else None for c in RATIO_COUNTERS}
                                for k, r in rows.items()},
            "seconds": time.perf_counter() - scene_started}
    out["seconds"] = time.perf_counter() - started
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/evaluation", help="folder for queries_pay.json and .png")
    parser.add_argument("--work", help="folder for the three evaluations (default: a temporary one)")
    parser.add_argument("--frames", type=int, default=120)
    parser.add_argument("--size", default="320x240")
    parser.add_argument("--methods", nargs="+", default=list(DEFAULT_METHODS))
    parser.add_argument("--repeat", type=int, default=3, help="passes over each path (per frame the median)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--jobs", type=int, default=2, help="bake worker processes")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="queries_pay: %(message)s")
    try:
        size = tuple(int(v) for v in args.size.split("x"))
        if len(size) != 2 or min(size) < 1:
            raise ValueError
    except ValueError:
        print(f"queries_pay: --size {args.size!r}: expected WxH, e.g. 320x240", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    try:
        with tempfile.TemporaryDirectory(prefix="queries_pay.") as scratch:
            results = measure(work=Path(args.work) if args.work else Path(scratch), frames=args.frames, size=size,
                              methods=args.methods, repeat=args.repeat, seed=args.seed, jobs=args.jobs)
    except HlodError as exc:
        print(f"queries_pay: {exc}", file=sys.stderr)
        return 2
    write_text_atomic(out / "queries_pay.json", json.dumps(results, indent=1))
    figures.save(figures.queries_pay_figure(results, labels=evaluate.LABELS), out / "queries_pay.png")
    for name, scene in results["scenes"].items():
        print(json.dumps({"scene": name, "relative_to_vfc": scene["relative_to_vfc"]}))
    print(json.dumps({"seconds": results["seconds"], "json": str(out / "queries_pay.json"),
                      "figure": str(out / "queries_pay.png")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
