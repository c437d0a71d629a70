"""Evaluation (docs/evaluation.md): every method on one camera path, image error against run time, written as
report.json, report.md, report.html and figures.

Reproduces the measurements of chapter 8 of J. P. Charalambos, "HLOD Refinement Driven by Hardware
Occlusion Queries", dissertation, 2007 (docs/how-it-works.md#papers): Table 8.1 (PSNR of
luminance and chrominance over 20 random frames against Bool), Table 8.2 (FPS, DN, RARN, D per
method), Tables 8.3/8.4 (speedup and node savings of Coh(P)/Coh(mu) over Bool, Simp and SW),
Figures 8.1-8.3 (`showcase`) and 8.4/8.5 (`per_frame_figure`); plus the alpha estimators
(docs/how-it-works.md#alpha-three-ways, `alpha_study`) and sweeps over tau, (s, t) and alpha. The variants run
interleaved on one renderer (`interleaved`); their rows are `rows`, image error `image_error`, the Markdown
`markdown`, the page `html_page`. Pass/fail targets are not the product's:
benchmarks/evaluation_targets.py reads a report.json and says which hold. `tuning` runs its candidates
through the same loop and rows and writes its report with `write_report`.

Data form: per_frame[key] (repeat, frames, len(COUNTERS)) float64 counters per report key (see
`interleaved`); per frame a counter's value is the median over repeats, a method's figure the mean
over frames of that. The report is a JSON-ready dict of measured figures (report.json); beside it
per_frame.npz (`per_frame_file`), from which `redraw` draws the figures and pages again:

    python -m hlod_core.report.evaluate --redraw DIR

Images for PSNR come from the first repeat, drawn with the HLOD's appearance where it has one
(base-colour textures: io.textures.load_images), so the Cb/Cr columns compare coloured images.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..core import jsonutil
from ..core.atomic import write_text_atomic
from ..core.errors import HlodError, InputError
from ..io.textures import load_images
from ..model.camera_path import CameraPath
from ..model.hierarchy import Hlod
from ..render.renderer import Renderer
from ..render.residency import StreamingSettings
from ..traversal.settings import ALPHA_MODES, RuntimeSettings
from . import html_page
from .alpha_study import alpha_estimators
from .draw_cost import COLUMNS, DrawCost, cost_row
from .interleaved import Variant, psnr_frame_indices, run_interleaved
from .markdown import markdown
from .per_frame_file import PER_FRAME_FILE, load_per_frame, save_per_frame
from .rows import SUMMARY_KEYS, queries_off_by_part, relative_tables, settings_json, variant_row
from .showcase import modulation_frames

log = logging.getLogger(__name__)

# report key -> (traversal method, settings it overrides); "ideal" draws SW(P)'s node set
METHOD_SPECS = {
    "full": ("full", {}), "vfc": ("vfc", {}), "bool": ("bool", {}),
    "sw_p": ("sw", {}), "sw_mu": ("sw", {"bias": "mu"}), "simp_p": ("simp", {}), "simp_mu": ("simp", {"bias": "mu"}),
    "coh_p": ("coh", {}), "coh_mu": ("coh", {"bias": "mu"}), "ideal": ("ideal", {}),
    # Coh(P) with Algorithm 4's shift-up as published: what the measured shift-up changes
    "coh_p_alg4": ("coh", {"shift_up": "children"}),
}
LABELS = {"full": "Full", "vfc": "VFC", "bool": "Bool", "sw_p": "SW(P)", "sw_mu": "SW(mu)",
          "simp_p": "Simp(P)", "simp_mu": "Simp(mu)", "coh_p": "Coh(P)", "coh_mu": "Coh(mu)", "ideal": "Ideal",
          "coh_p_alg4": "Coh(P) Alg. 4"}
# Sweeps vary Coh(P) only (the method under study); the values include the paper's settings.
SWEEPS = {"tau": (0.5, 1.0, 2.0, 4.0), "st": ((0.6, 0.2), (0.7, 0.15), (0.9, 0.05)), "alpha": ALPHA_MODES}
ALPHA_STUDY_VIEWS = 5  # the first of the PSNR frames, reused as the alpha estimators' views
REPORT_FILE = "report.json"


def variants(methods: list[str], settings: RuntimeSettings, sweep: str | None) -> list[Variant]:
    """The timed configurations: each method key of METHOD_SPECS with `settings` (bias P unless
    the key says mu), then Coh(P) at each value of `sweep`."""
    out = []
    for key in methods:
        method, overrides = METHOD_SPECS[key]
        out.append(Variant(key=key, method=method, settings=replace(settings, **{"bias": "P", **overrides})))
    for value in SWEEPS.get(sweep, ()):
        if sweep == "tau":
            changed, label = replace(settings, tau=float(value)), f"tau={value:g}"
        elif sweep == "st":
            changed, label = replace(settings, s=value[0], t=value[1]), f"s,t={value[0]:g},{value[1]:g}"
        else:
            changed, label = replace(settings, alpha=value), f"alpha={value}"
        out.append(Variant(key=f"coh_p {label}", method="coh", settings=replace(changed, bias="P"), sweep_value=value))
    return out


# --- the run --------------------------------------------------------------------------------------

def evaluate(hlod: Hlod, path: CameraPath, size: tuple[int, int], *, methods: list[str],
             settings: RuntimeSettings = RuntimeSettings(), repeat: int = 2, sweep: str | None = None,
             out_dir: str | os.PathLike, psnr_frames: int = 20, seed: int = 1, figures: bool = True,
             streaming: StreamingSettings | None = None) -> dict:
    """Runs, measures and writes report.json, per_frame.npz, report.md, report.html and (with
    `figures`, which needs matplotlib) the figures into out_dir; returns the report (the JSON
    contents). InputError for an unknown method or sweep, or repeat < 1, before any GL work.
    streaming: a GPU budget for node geometry and textures, shared by every method (render.residency)."""
    _check_arguments(methods, repeat=repeat, sweep=sweep)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = len(path)
    picked = psnr_frame_indices(frames, psnr_frames, seed)
    runs = variants(methods, settings, sweep)
    started = time.perf_counter()
    textures = load_images(hlod)
    renderer = Renderer.create_standalone(hlod, size, images=textures, streaming=streaming)  # coloured images: Cb/Cr
    costs: dict = {}
    try:
        notes: dict[str, str] = {}
        per_frame, images = run_interleaved(hlod, renderer, path, size=size, runs=runs, repeat=repeat, picked=picked,
                                            started=started, draw_cost=DrawCost(hlod, textures), costs=costs,
                                            notes=notes)
        alpha_study = alpha_estimators(hlod, renderer, [path.view(i, size) for i in picked[:ALPHA_STUDY_VIEWS]])
        showcase = modulation_frames(hlod, renderer, path=path, size=size, runs=runs, per_frame=per_frame,
                                     out_dir=out_dir)
    finally:
        renderer.release()
    report = _summarise(hlod, frames=frames, size=size, runs=runs, per_frame=per_frame, images=images,
                        picked=picked, repeat=repeat, settings=settings, sweep=sweep)
    for table in (report["methods"], (report["sweep"] or {}).get("points", {})):
        for key, row in table.items():
            row.update(cost_row(costs[key]))
    report["alpha_estimators"] = alpha_study
    report["figures"] = {}
    if showcase is not None:
        report["showcase"] = showcase
    report["parts"] = [{"name": name, "start": start} for name, start in path.parts]
    for key, row in report["methods"].items():
        row["queries_off_by_part"] = queries_off_by_part(per_frame[key], list(path.parts))
        row["queries_off_reason"] = notes.get(key, "")
    report["settings"]["gpu_budget_bytes"] = 0 if streaming is None else streaming.budget_bytes
    report["seconds"] = time.perf_counter() - started
    medians = {key: np.median(counters, axis=0) for key, counters in per_frame.items()}
    save_per_frame(out_dir / PER_FRAME_FILE, medians, costs={k: np.median(c, axis=0) for k, c in costs.items()})
    path.save(out_dir / "path.json")
    write_report(report, medians, out_dir, figures=figures)
    return report


def _check_arguments(methods: list[str], *, repeat: int, sweep: str | None) -> None:
    unknown = [m for m in methods if m not in METHOD_SPECS]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; expected some of {', '.join(METHOD_SPECS)}")
    if repeat < 1:
        raise InputError(f"repeat must be at least 1, got {repeat}")
    if sweep is not None and sweep not in SWEEPS:
        raise InputError(f"sweep must be one of {', '.join(SWEEPS)}, got {sweep!r}")


def write_report(report: dict, medians: dict | None, out_dir: Path, *, figures: bool) -> None:
    """The figures (with `figures`; `medians`: key -> (frames, len(COUNTERS)) per-frame medians, None
    when there are none: no per-frame figure), report.json, report.md and report.html into out_dir."""
    report["figures"] = {}
    if figures:
        from .figures import draw as draw_figures  # matplotlib: loaded only when figures are made

        report["figures"] = draw_figures(report, medians, out_dir, labels=LABELS)
    write_text_atomic(out_dir / REPORT_FILE, json.dumps(report, indent=1))
    write_text_atomic(out_dir / "report.md", markdown(report, labels=LABELS))
    write_text_atomic(out_dir / "report.html", html_page.page(report, labels=LABELS, folder=out_dir))


def redraw(out_dir: str | os.PathLike) -> dict:
    """The figures, report.md and report.html of an evaluation folder again, from its report.json
    and per_frame.npz (a folder without per_frame.npz gets no per-frame figure); returns the
    report. Raises InputError naming the file when one is missing or not an evaluation's."""
    out_dir = Path(out_dir)
    source = out_dir / REPORT_FILE
    report = jsonutil.read(source, what="the evaluation report")
    if not isinstance(report, dict) or not isinstance(report.get("methods"), dict):
        raise InputError(f"{source}: not an evaluation report (no \"methods\" table)")
    unknown = sorted(set(report["methods"]) - set(LABELS))
    if unknown:
        raise InputError(f"{source}: unknown method {unknown[0][:40]!r}; expected some of {', '.join(LABELS)}")
    medians = None
    if (out_dir / PER_FRAME_FILE).exists():
        medians = load_per_frame(out_dir / PER_FRAME_FILE, frames=report.get("frames"))
    else:
        log.warning("%s: not found; the per-frame figure is left out", out_dir / PER_FRAME_FILE)
    if importlib.util.find_spec("matplotlib") is None:  # the figures' only extra requirement
        raise InputError("redrawing the figures needs matplotlib, which this Python lacks")
    try:
        write_report(report, medians, out_dir, figures=True)
    except (KeyError, TypeError) as exc:  # a field missing or of the wrong kind: not evaluate's report
        raise InputError(f"{source}: not an evaluation report ({type(exc).__name__}: {exc})") from None
    return report


def _summarise(hlod: Hlod, *, frames: int, size: tuple[int, int], runs: list[Variant], per_frame: dict,
               images: dict, picked: list[int], repeat: int, settings: RuntimeSettings, sweep: str | None) -> dict:
    """The report's figures from the per-frame counters and the PSNR frames' images (see module
    docstring)."""
    methods, sweeps = {}, {}
    for v in runs:
        row = variant_row(per_frame[v.key], images, key=v.key, picked=picked)
        if v.sweep_value is None:
            methods[v.key] = row
        else:
            sweeps[v.key] = row | {"value": v.sweep_value}
    report = {"methods": methods, "frames": frames, "size": list(size), "repeat": repeat,
              "settings": settings_json(settings),
              "psnr_frames": picked, "sweep": {"name": sweep, "points": sweeps} if sweep else None,
              "scene": hlod.summary()}
    report["relative"] = relative_tables(methods)
    return report


def summary_line(report: dict, out_dir) -> dict:
    """The command's last stdout line: SUMMARY_KEYS, the PSNR columns and draw_cost.COLUMNS per method
    (and sweep point), frames, size, where the report is."""
    keys = SUMMARY_KEYS + ("psnr_y_vs_bool", "psnr_cb_vs_bool", "psnr_cr_vs_bool", "psnr_y_vs_full")
    methods = {k: {c: r[c] for c in keys} | {c: r.get(c) for c in COLUMNS}  # a tuning report has no COLUMNS
               for k, r in report["methods"].items()}
    out = {"methods": methods, "frames": report["frames"], "size": report["size"],
           "report": str(Path(out_dir) / "report.md")}
    if report.get("sweep"):
        out["sweep"] = {k: {c: r[c] for c in keys + COLUMNS} for k, r in report["sweep"]["points"].items()}
    return out


def main(argv: list[str] | None = None) -> int:
    """python -m hlod_core.report.evaluate --redraw DIR (`redraw`). Exit status 0, or 2 with one line on
    stderr naming the file at fault. (The evaluation itself is `python -m hlod_core evaluate`.)"""
    parser = argparse.ArgumentParser(prog="python -m hlod_core.report.evaluate",
                                     description="Draw an evaluation folder's figures, report.md and report.html "
                                                 "again from its report.json and per_frame.npz.")
    parser.add_argument("--redraw", required=True, metavar="DIR", help="an evaluation's --out folder")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="hlod_core: %(message)s")
    try:
        report = redraw(args.redraw)
    except HlodError as exc:
        print(f"hlod_core: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"hlod_core: error: {exc.filename or args.redraw}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    for name, file in report["figures"].items():
        log.info("%s: %s", name, Path(args.redraw) / file)
    return 0


if __name__ == "__main__":
    sys.exit(main())
