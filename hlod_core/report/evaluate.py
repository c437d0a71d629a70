"""Evaluation (DESIGN §9): every method on one camera path, image error against run time; the run
loop and the report's summary tables.

Reproduces the measurements of Charalambos' dissertation, chapter 8
(`../shared/papers/charalambos2007-dissertation-hlod-refinement-hoq.txt`): Table 8.1 (PSNR of
luminance and chrominance over 20 random frames against Bool), Table 8.2 (FPS, DN, RARN, D per
method), Tables 8.3/8.4 (speedup and node savings of Coh(P)/Coh(mu) over Bool, Simp and SW),
Figures 8.1-8.3 (`showcase`) and 8.4/8.5 (`report_figures`); plus the alpha estimators of DESIGN
§5.3 (`alpha_study`) and sweeps over tau, (s, t) and alpha. Image error is `imagemetrics`, the
Markdown `report_text`; pass/fail targets are not the product's: benchmarks/evaluation_targets.py
reads a report.json and says which hold. `tuning` (issue 15: (s, t) tuned to a PSNR target) runs
its candidates through the same loop (`run_interleaved`) and rows (`variant_row`, `psnr_against`)
and writes its report with `write_report`.

Data form: per_frame[key] is a (repeat, frames, len(COUNTERS)) float64 array of FrameStats
counters (traversal.COUNTERS order) per report key; the report is a JSON-ready dict of measured
figures (report.json). Written beside it: per_frame.npz, the per-frame medians over repeats that
the figures draw ("keys" (V,) report keys, "counters" (C,) COUNTERS, "median" (V, frames, C)
float32), report.md, report.html (report_html: one self-contained page, figures embedded) and the
figures; `redraw` draws the figures and pages again from report.json and per_frame.npz alone:

    python -m hlod_core.report.evaluate --redraw DIR

All variants run in one process on one renderer over the same path, interleaved frame by frame
(each keeps its own traversal state; the order rotates every frame and runs backwards on odd
repeats), so a drift in the machine's speed hits them alike and timings compare as ratios within
the run. Per frame, a counter's value is the median over repeats; a method's figure is the mean
over frames of that. Images for PSNR come from the first repeat, read back outside the timed frame,
drawn with the HLOD's appearance where it has one (base-colour textures: textures.load_images),
so the Cb/Cr columns compare coloured images.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import logging
import os
import sys
import time
import zipfile
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from ..core import jsonutil
from . import html_page
from .alpha_study import alpha_estimators
from ..core.atomic import atomic_file, write_text_atomic
from ..model.camera_path import CameraPath
from ..core.errors import HlodError, InputError
from ..model.hierarchy import Hlod
from .image_error import psnr, rmse_y
from ..render.renderer import Renderer
from .markdown import markdown
from .showcase import modulation_frames
from ..io.textures import load_images
from ..traversal.methods import make
from ..traversal.settings import ALPHA_MODES, RuntimeSettings
from ..traversal.stats import COUNTERS

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
SUMMARY_KEYS = ("fps", "frame_ms", "dn", "rarn", "d", "tris", "queries", "stall_ms", "cpu_ms", "gpu_ms")
PSNR_REFERENCES = ("bool", "full")  # the PSNR columns are against these methods' images
ALPHA_STUDY_VIEWS = 5  # the first of the PSNR frames, reused as the alpha estimators' views
PROGRESS_STEPS = 10  # log lines per repeat
MS_PER_S = 1e3
PER_FRAME_FILE = "per_frame.npz"
REPORT_FILE = "report.json"


@dataclass(frozen=True)
class Variant:
    """One timed configuration: a report key (a method key, or "coh_p tau=2" in a sweep)."""

    key: str
    method: str
    settings: RuntimeSettings
    sweep_value: object = None


def variants(methods: list[str], settings: RuntimeSettings, sweep: str | None) -> list[Variant]:
    """The timed configurations: each method key of METHOD_SPECS with `settings` (bias P unless
    the key says mu), then Coh(P) at each value of `sweep`."""
    out = []
    for key in methods:
        method, overrides = METHOD_SPECS[key]
        out.append(Variant(key, method, replace(settings, **{"bias": "P", **overrides})))
    for value in SWEEPS.get(sweep, ()):
        if sweep == "tau":
            changed, label = replace(settings, tau=float(value)), f"tau={value:g}"
        elif sweep == "st":
            changed, label = replace(settings, s=value[0], t=value[1]), f"s,t={value[0]:g},{value[1]:g}"
        else:
            changed, label = replace(settings, alpha=value), f"alpha={value}"
        out.append(Variant(f"coh_p {label}", "coh", replace(changed, bias="P"), value))
    return out


# --- the run --------------------------------------------------------------------------------------

def evaluate(hlod: Hlod, path: CameraPath, size: tuple[int, int], *, methods: list[str],
             settings: RuntimeSettings = RuntimeSettings(), repeat: int = 2, sweep: str | None = None,
             out_dir: str | os.PathLike, psnr_frames: int = 20, seed: int = 1, figures: bool = True) -> dict:
    """Runs, measures and writes report.json, per_frame.npz, report.md, report.html and (with
    `figures`, which needs matplotlib) the figures into out_dir; returns the report (the JSON
    contents)."""
    unknown = [m for m in methods if m not in METHOD_SPECS]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; expected some of {', '.join(METHOD_SPECS)}")
    if repeat < 1:
        raise InputError(f"repeat must be at least 1, got {repeat}")
    if sweep is not None and sweep not in SWEEPS:
        raise InputError(f"sweep must be one of {', '.join(SWEEPS)}, got {sweep!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frames = len(path)
    picked = psnr_frame_indices(frames, psnr_frames, seed)
    runs = variants(methods, settings, sweep)
    started = time.perf_counter()
    renderer = Renderer.create_standalone(hlod, size, images=load_images(hlod))  # coloured images: Cb/Cr
    try:
        per_frame, images = run_interleaved(hlod, renderer, path, size=size, runs=runs, repeat=repeat, picked=picked,
                                            started=started)
        alpha_study = alpha_estimators(hlod, renderer, [path.view(i, size) for i in picked[:ALPHA_STUDY_VIEWS]])
        showcase = modulation_frames(hlod, renderer, path=path, size=size, runs=runs, per_frame=per_frame,
                                     out_dir=out_dir)
    finally:
        renderer.release()
    report = _summarise(hlod, frames=frames, size=size, runs=runs, per_frame=per_frame, images=images,
                        picked=picked, repeat=repeat, settings=settings, sweep=sweep)
    report["alpha_estimators"] = alpha_study
    report["figures"] = {}
    if showcase is not None:
        report["showcase"] = showcase
    report["parts"] = [{"name": name, "start": start} for name, start in path.parts]
    report["seconds"] = time.perf_counter() - started
    medians = {key: np.median(counters, axis=0) for key, counters in per_frame.items()}
    save_per_frame(out_dir / PER_FRAME_FILE, medians)
    path.save(out_dir / "path.json")
    write_report(report, medians, out_dir, figures=figures)
    return report


def psnr_frame_indices(frames: int, count: int, seed: int) -> list[int]:
    """The seeded PSNR frames: `count` distinct frame indices of a `frames`-frame path (all of them
    when count >= frames), ascending."""
    rng = np.random.default_rng(seed)
    return sorted(rng.choice(frames, size=min(count, frames), replace=False).tolist())


def run_interleaved(hlod: Hlod, renderer: Renderer, path: CameraPath, *, size: tuple[int, int], runs: list[Variant],
                    repeat: int, picked: list[int], started: float, label: str = "") -> tuple[dict, dict]:
    """One timed pass of `runs` over the path, `repeat` times (module docstring: interleaved per
    frame, each variant keeping its own traversal state, the order rotating every frame and running
    backwards on odd repeats). Returns (per_frame, images): per_frame[key] (repeat, frames,
    len(COUNTERS)) float64 counters; images[key][frame] (H, W, 3) uint8 of the first repeat at the
    `picked` frames, read back outside the timed frame. `label` prefixes the progress lines."""
    frames = len(path)
    picked_set = set(picked)
    per_frame = {v.key: np.zeros((repeat, frames, len(COUNTERS))) for v in runs}
    images: dict[str, dict[int, np.ndarray]] = {v.key: {} for v in runs}
    for rep in range(repeat):
        # Interleaved per frame, each method keeping its own traversal state: a drift in the
        # machine's speed (on a shared VM, tens of percent over minutes) then hits every method
        # alike. The order rotates every frame and runs backwards on odd repeats.
        traversals = [(v, make(v.method, hlod, renderer, settings=v.settings)) for v in runs]
        for i in range(frames):
            view = path.view(i, size)
            turn = traversals[i % len(traversals):] + traversals[:i % len(traversals)]
            for v, traversal in (turn if rep % 2 == 0 else turn[::-1]):
                stats = traversal.frame(view)
                per_frame[v.key][rep, i] = [getattr(stats, c) for c in COUNTERS]
                if rep == 0 and i in picked_set:
                    images[v.key][i] = renderer.read_pixels()
            if (i + 1) % max(frames // PROGRESS_STEPS, 1) == 0 or i + 1 == frames:
                log.info("%srepeat %d/%d: frame %d/%d (%.0f s)", label, rep + 1, repeat, i + 1, frames,
                         time.perf_counter() - started)
    return per_frame, images


def write_report(report: dict, medians: dict | None, out_dir: Path, *, figures: bool) -> None:
    """The figures (with `figures`; `medians`: key -> (frames, len(COUNTERS)) per-frame medians, None
    when there are none: no per-frame figure), report.json, report.md and report.html into out_dir."""
    report["figures"] = {}
    if figures:
        from . import figures as report_figures  # matplotlib: loaded only when figures are made

        report["figures"] = report_figures.draw(report, medians, out_dir, labels=LABELS)
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


def save_per_frame(target: Path, medians: dict) -> None:
    """per_frame.npz (module docstring) of `medians`: report key -> (frames, len(COUNTERS))."""
    keys = list(medians)
    with atomic_file(target) as f:
        np.savez_compressed(f, keys=np.array(keys, dtype=str), counters=np.array(COUNTERS, dtype=str),
                            median=np.array([medians[k] for k in keys], dtype=np.float32))


def load_per_frame(source: Path, *, frames: int | None = None) -> dict:
    """report key -> (frames, len(COUNTERS)) float64 medians from per_frame.npz, in COUNTERS order
    whatever order the file lists its counters in. Raises InputError naming the file when it is not
    one (or holds another number of frames than `frames`, the report's)."""
    try:
        with np.load(source, allow_pickle=False) as data:
            keys, counters, median = data["keys"], data["counters"], data["median"]
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{source}: not an evaluation's per-frame file ({exc})") from None
    missing = [c for c in COUNTERS if c not in counters.tolist()]
    if median.ndim != 3 or median.shape[0] != len(keys) or median.shape[2] != len(counters) or missing:
        raise InputError(f"{source}: not an evaluation's per-frame file (median {median.shape}, "
                         f"{len(keys)} keys, counters missing: {', '.join(missing) or 'none'})")
    if frames is not None and median.shape[1] != frames:
        raise InputError(f"{source}: {median.shape[1]} frames, its report.json {frames}")
    order = [counters.tolist().index(c) for c in COUNTERS]
    return {str(k): median[i][:, order].astype(np.float64) for i, k in enumerate(keys)}


def _summarise(hlod: Hlod, *, frames: int, size: tuple[int, int], runs: list[Variant], per_frame: dict,
               images: dict, picked: list[int], repeat: int, settings: RuntimeSettings, sweep: str | None) -> dict:
    """The report's figures from the per-frame counters and the PSNR frames' images (see module
    docstring)."""
    methods, sweeps = {}, {}
    for v in runs:
        row = variant_row(per_frame[v.key], images, v.key, picked)
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


def settings_json(settings: RuntimeSettings) -> dict:
    """report.json's "settings": every field of the run's RuntimeSettings but the bias (each method
    has its own), k None for inf, so two reports made with different query options tell themselves
    apart."""
    out = {name: value for name, value in asdict(settings).items() if name != "bias"}
    out["k"] = None if np.isinf(settings.k) else settings.k
    return out


def variant_row(counters: np.ndarray, images: dict, key: str, picked: list[int]) -> dict:
    """One variant's row of the report: `counters` (repeat, frames, len(COUNTERS)) -> per frame the
    median over repeats, then the mean over frames of each of SUMMARY_KEYS (and fps); PSNR mean and
    s.d. per channel against each of PSNR_REFERENCES present in `images` (key -> frame -> image), and
    the luminance RMSE against Full, over the `picked` frames (None where the reference is absent)."""
    index = {c: j for j, c in enumerate(COUNTERS)}
    median = np.median(counters, axis=0)  # per frame, over repeats
    row = {c: float(np.mean(median[:, index[c]])) for c in COUNTERS}
    row["fps"] = MS_PER_S / row["frame_ms"] if row["frame_ms"] > 0 else None
    row = {k: row[k] for k in SUMMARY_KEYS} | {"traversed": row["traversed"]}
    for ref in PSNR_REFERENCES:
        values = psnr_against(images, key, ref, picked)
        for c, name in enumerate(("y", "cb", "cr")):
            row[f"psnr_{name}_vs_{ref}"] = None if values is None else float(np.mean(values[:, c]))
            row[f"psnr_{name}_vs_{ref}_sd"] = None if values is None else float(np.std(values[:, c]))
    rmse = [rmse_y(images[key][i], images["full"][i]) for i in picked] if "full" in images else None
    row["rmse_y_vs_full"] = None if rmse is None else float(np.mean(rmse))
    return row


def psnr_against(images: dict, key: str, ref: str, picked: list[int]) -> np.ndarray | None:
    """(len(picked), 3) PSNR dB of Y, Cb, Cr of `key`'s images against `ref`'s at the picked frames;
    None when either has no images."""
    if ref not in images or not images[ref] or not images[key]:
        return None
    return np.array([psnr(images[key][i], images[ref][i]) for i in picked])


def relative_tables(methods: dict) -> dict:
    """Tables 8.3/8.4: percent speedup (FPS ratio - 1) and node savings (1 - DN ratio) of Coh(P)
    and Coh(mu) over Bool, Simp and SW of the same bias."""
    out = {}
    for coh, others in (("coh_p", ("bool", "simp_p", "sw_p", "coh_p_alg4")), ("coh_mu", ("bool", "simp_mu", "sw_mu"))):
        if coh not in methods:
            continue
        rows = {}
        for other in others:
            if other in methods:
                a, b = methods[coh], methods[other]
                rows[other] = {"speedup_pct": 100.0 * (a["fps"] / b["fps"] - 1.0),
                               "node_savings_pct": 100.0 * (1.0 - a["dn"] / b["dn"]) if b["dn"] > 0 else None}
        out[coh] = rows
    return out


def summary_line(report: dict, out_dir) -> dict:
    """The command's last stdout line: the issue's keys per method, frames, size, where the report is."""
    keys = SUMMARY_KEYS + ("psnr_y_vs_bool", "psnr_cb_vs_bool", "psnr_cr_vs_bool", "psnr_y_vs_full")
    methods = {k: {c: r[c] for c in keys} for k, r in report["methods"].items()}
    out = {"methods": methods, "frames": report["frames"], "size": report["size"],
           "report": str(Path(out_dir) / "report.md")}
    if report.get("sweep"):
        out["sweep"] = {k: {c: r[c] for c in keys} for k, r in report["sweep"]["points"].items()}
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
