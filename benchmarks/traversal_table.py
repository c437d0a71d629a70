"""Per-method means on one path, all methods in one process with their order alternating across
repeats (timings compare as ratios within the run; node counts are what the method decides).

    .venv/bin/python -m benchmarks.traversal_table FILE.hlod (--path PATH.json | --inspection SEED:FRAMES)
        [--frames START:STOP] [--size 640x480] [--repeat 2] [--methods vfc,bool,coh,coh:skip_queries=off]
        [--psnr-frames 5] [--psnr-reference bool]

A method is a traversal name, optionally with RuntimeSettings fields after a colon
(`coh:skip_queries=off,alpha=projected`, `coh:multiquery=on,batch_queries=on`): each such entry is
a row. Prints one JSON line per row (median over repeats of each per-frame mean,
runner.run_path's), the renderer's cost model, a Markdown table with
each row's frame time relative to the faster of VFC and Bool when both run, and, with
--psnr-frames N, the mean PSNR-Y of each row's image against --psnr-reference's on N frames spread
over the path (each row and the reference run frame by frame side by side, own state each).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import statistics

import numpy as np

from hlod_core.io import hlod_file
from hlod_core.model.camera_path import inspection_path, load_path
from hlod_core.render.renderer import Renderer
from hlod_core.report import image_error
from hlod_core.report.runner import run_path
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings
from hlod_core.traversal.stats import COUNTERS, QUERY_COUNTERS

#: The per-frame means each row reports.
ROW_COUNTERS = COUNTERS + QUERY_COUNTERS


def parse_entry(entry: str) -> tuple[str, RuntimeSettings]:
    """'coh:skip_queries=off,alpha=projected' -> ('coh', RuntimeSettings(skip_queries='off', ...))."""
    method, _, rest = entry.partition(":")
    fields = {f.name: f.type for f in dataclasses.fields(RuntimeSettings)}
    values = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        if key not in fields:
            raise SystemExit(f"{entry}: unknown setting {key!r}; known: {', '.join(fields)}")
        default = getattr(RuntimeSettings(), key)
        values[key] = type(default)(value) if not isinstance(default, str) else value
    return method, RuntimeSettings(**values)


def psnr_y(hlod, renderer, path, *, size, entries: list[str], reference: str, frames: int) -> dict[str, float]:
    """Mean PSNR-Y (dB) of each entry's frames against the reference's on `frames` frames spread
    over the path; every traversal runs every frame (coherence), images compared where chosen."""
    chosen = set(np.linspace(0, len(path) - 1, frames).round().astype(int).tolist())
    ref = _make(reference, hlod, renderer)
    runs = {e: _make(e, hlod, renderer) for e in entries}
    scores = {e: [] for e in entries}
    for i in range(len(path)):
        view = path.view(i, size)
        ref.frame(view)
        ref_image = renderer.read_pixels() if i in chosen else None
        for e, traversal in runs.items():
            traversal.frame(view)
            if ref_image is not None:
                scores[e].append(float(image_error.psnr(ref_image, renderer.read_pixels())[0]))
    return {e: float(np.mean(v)) for e, v in scores.items()}


def _make(entry, hlod, renderer):
    method, settings = parse_entry(entry)
    return make(method, hlod, renderer, settings=settings)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--path")
    where.add_argument("--inspection", help="SEED:FRAMES of camera.inspection_path")
    parser.add_argument("--frames", help="START:STOP, the path's frames START .. STOP - 1 only (in order)")
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--methods", default="full,vfc,bool,sw,simp,coh,ideal")
    parser.add_argument("--psnr-frames", type=int, default=0)
    parser.add_argument("--psnr-reference", default="bool")
    args = parser.parse_args()
    size = tuple(int(x) for x in args.size.split("x"))
    hlod = hlod_file.load(args.file)
    if args.path:
        path = load_path(args.path)
    else:
        seed, frames = (int(x) for x in args.inspection.split(":"))
        path = inspection_path(hlod, seed=seed, frames=frames)
    if args.frames:
        start, stop = (int(x) for x in args.frames.split(":"))
        path = dataclasses.replace(path, frames=path.frames[start:stop], parts=())
    entries = _split_entries(args.methods)
    runs: dict[str, list[dict]] = {e: [] for e in entries}
    renderer = Renderer.create_standalone(hlod, size)
    try:
        print("cost model:", renderer.cost_model.describe())
        for rep in range(args.repeat):
            for entry in (entries if rep % 2 == 0 else entries[::-1]):
                method, settings = parse_entry(entry)
                runs[entry].append(run_path(hlod, method, settings, path=path, size=size, renderer=renderer))
        psnr = psnr_y(hlod, renderer, path, size=size, entries=entries, reference=args.psnr_reference,
                      frames=args.psnr_frames) if args.psnr_frames else {}
    finally:
        renderer.release()
    table = {e: {c: statistics.median(r[c] for r in runs[e]) for c in ROW_COUNTERS} for e in entries}
    best = min((table[e]["frame_ms"] for e in ("vfc", "bool") if e in table), default=None)
    for e in entries:
        print(json.dumps({"method": e, **table[e], **({"psnr_y": psnr[e]} if e in psnr else {})}))
    print("| method | DN | RARN | D | triangles | queries | multiqueries | state changes | stall ms | cpu ms "
          "| frame ms | / min(VFC, Bool) | PSNR-Y |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for e in entries:
        t = table[e]
        ratio = f"{t['frame_ms'] / best:.2f}" if best else "-"
        score = f"{psnr[e]:.1f}" if e in psnr else "-"
        print(f"| {e} | {t['dn']:.2f} | {t['rarn']:.2f} | {t['d']:.2f} | {t['tris']:,.0f} | {t['queries']:.1f} | "
              f"{t['multiqueries']:.1f} | {t['state_changes']:.1f} | {t['stall_ms']:.2f} | {t['cpu_ms']:.1f} | "
              f"{t['frame_ms']:.1f} | {ratio} | {score} |")


def _split_entries(text: str) -> list[str]:
    """Comma-separated entries, where a setting's comma stays with its entry
    ('vfc,coh:skip_queries=off,alpha=cube,bool' -> ['vfc', 'coh:skip_queries=off,alpha=cube', 'bool'])."""
    out: list[str] = []
    for part in text.split(","):
        if out and ":" in out[-1] and "=" in part and ":" not in part:
            out[-1] += "," + part
        else:
            out.append(part)
    return out


if __name__ == "__main__":
    main()
