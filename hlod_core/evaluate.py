"""Evaluation (DESIGN §9): every method on one camera path, image error against run time; the run
loop and the report's summary tables.

Reproduces the measurements of Charalambos' dissertation, chapter 8
(`../shared/papers/charalambos2007-dissertation-hlod-refinement-hoq.txt`): Table 8.1 (PSNR of
luminance and chrominance over 20 random frames against Bool), Table 8.2 (FPS, DN, RARN, D per
method), Tables 8.3/8.4 (speedup and node savings of Coh(P)/Coh(mu) over Bool, Simp and SW),
Figures 8.1-8.3 (`showcase`) and 8.4/8.5 (`report_figures`); plus the alpha estimators of DESIGN
§5.3 (`alpha_study`) and sweeps over tau, (s, t) and alpha. Image error is `imagemetrics`, the
Markdown `report_text`; pass/fail targets are not the product's: benchmarks/evaluation_targets.py
reads a report.json and says which hold.

Data form: per_frame[key] is a (repeat, frames, len(COUNTERS)) float64 array of FrameStats
counters (traversal.COUNTERS order) per report key; the report is a JSON-ready dict of measured
figures (report.json).

All variants run in one process on one renderer over the same path, interleaved frame by frame
(each keeps its own traversal state; the order rotates every frame and runs backwards on odd
repeats), so a drift in the machine's speed hits them alike and timings compare as ratios within
the run. Per frame, a counter's value is the median over repeats; a method's figure is the mean
over frames of that. Images for PSNR come from the first repeat, read back outside the timed frame.
"""
from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .alpha_study import alpha_estimators
from .atomic import write_text_atomic
from .camera import CameraPath
from .errors import InputError
from .hierarchy import Hlod
from .imagemetrics import psnr, rmse_y
from .renderer import Renderer
from .report_text import markdown
from .showcase import modulation_frames
from .traversal import ALPHA_MODES, COUNTERS, RuntimeSettings, make

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
    """Runs, measures and writes report.json, report.md and the figures into out_dir; returns the
    report (the JSON contents)."""
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
    rng = np.random.default_rng(seed)
    picked = sorted(rng.choice(frames, size=min(psnr_frames, frames), replace=False).tolist())
    picked_set = set(picked)
    runs = variants(methods, settings, sweep)
    per_frame = {v.key: np.zeros((repeat, frames, len(COUNTERS))) for v in runs}
    images: dict[str, dict[int, np.ndarray]] = {v.key: {} for v in runs}
    started = time.perf_counter()
    renderer = Renderer.create_standalone(hlod, size)
    try:
        for rep in range(repeat):
            # Interleaved per frame, each method keeping its own traversal state: a drift in the
            # machine's speed (on a shared VM, tens of percent over minutes) then hits every method
            # alike. The order rotates every frame and runs backwards on odd repeats.
            traversals = [(v, make(v.method, hlod, renderer, v.settings)) for v in runs]
            for i in range(frames):
                view = path.view(i, size)
                turn = traversals[i % len(traversals):] + traversals[:i % len(traversals)]
                for v, traversal in (turn if rep % 2 == 0 else turn[::-1]):
                    stats = traversal.frame(view)
                    per_frame[v.key][rep, i] = [getattr(stats, c) for c in COUNTERS]
                    if rep == 0 and i in picked_set:
                        images[v.key][i] = renderer.read_pixels()
                if (i + 1) % max(frames // PROGRESS_STEPS, 1) == 0 or i + 1 == frames:
                    log.info("repeat %d/%d: frame %d/%d (%.0f s)", rep + 1, repeat, i + 1, frames,
                             time.perf_counter() - started)
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
    report["seconds"] = time.perf_counter() - started
    if figures:
        from . import report_figures  # matplotlib: loaded only when figures are made

        report["figures"] = report_figures.draw(report, per_frame, out_dir, labels=LABELS)
    path.save(out_dir / "path.json")
    write_text_atomic(out_dir / "report.json", json.dumps(report, indent=1))
    write_text_atomic(out_dir / "report.md", markdown(report, labels=LABELS))
    return report


def _summarise(hlod: Hlod, *, frames: int, size: tuple[int, int], runs: list[Variant], per_frame: dict,
               images: dict, picked: list[int], repeat: int, settings: RuntimeSettings, sweep: str | None) -> dict:
    """The report's figures from the per-frame counters and the PSNR frames' images (see module
    docstring)."""
    index = {c: j for j, c in enumerate(COUNTERS)}
    methods, sweeps = {}, {}
    for v in runs:
        median = np.median(per_frame[v.key], axis=0)  # per frame, over repeats
        row = {c: float(np.mean(median[:, index[c]])) for c in COUNTERS}
        row["fps"] = MS_PER_S / row["frame_ms"] if row["frame_ms"] > 0 else None
        row = {k: row[k] for k in SUMMARY_KEYS} | {"traversed": row["traversed"]}
        for ref in PSNR_REFERENCES:
            values = _psnr_against(images, v.key, ref, picked)
            for c, name in enumerate(("y", "cb", "cr")):
                row[f"psnr_{name}_vs_{ref}"] = None if values is None else float(np.mean(values[:, c]))
                row[f"psnr_{name}_vs_{ref}_sd"] = None if values is None else float(np.std(values[:, c]))
        rmse = [rmse_y(images[v.key][i], images["full"][i]) for i in picked] if "full" in images else None
        row["rmse_y_vs_full"] = None if rmse is None else float(np.mean(rmse))
        if v.sweep_value is None:
            methods[v.key] = row
        else:
            sweeps[v.key] = row | {"value": v.sweep_value}
    report = {"methods": methods, "frames": frames, "size": list(size), "repeat": repeat,
              "settings": {"tau": settings.tau, "s": settings.s, "t": settings.t,
                           "k": None if np.isinf(settings.k) else settings.k, "alpha": settings.alpha},
              "psnr_frames": picked, "sweep": {"name": sweep, "points": sweeps} if sweep else None,
              "scene": hlod.summary()}
    report["relative"] = relative_tables(methods)
    return report


def _psnr_against(images, key, ref, picked) -> np.ndarray | None:
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

