"""Evaluation (DESIGN §9): every method on one camera path, image error against run time.

Reproduces the measurements of Charalambos' dissertation, chapter 8
(`../shared/papers/charalambos2007-dissertation-hlod-refinement-hoq.txt`): Table 8.1 (PSNR of
luminance and chrominance over 20 random frames against Bool), Table 8.2 (FPS, DN, RARN, D per
method), Tables 8.3/8.4 (speedup and node savings of Coh(P)/Coh(mu) over Bool, Simp and SW),
Figures 8.1-8.3 (modulation colours from the user's view and a bird's-eye view) and 8.4/8.5
(per-frame drawn nodes and frame times); plus the alpha estimators of DESIGN §5.3 (error against
cost) and sweeps over tau, (s, t) and alpha.

All variants run in one process on one renderer over the same path, interleaved frame by frame
(each keeps its own traversal state; the order rotates every frame and runs backwards on odd
repeats), so a drift in the machine's speed hits them alike and timings compare as ratios within
the run. Per frame, a counter's value is the median over repeats; a method's figure is the mean
over frames of that.
Images for PSNR come from the first repeat, read back outside the timed frame.

PSNR: YCbCr of ITU-R BT.601 (full range, as JPEG), peak 255, per frame; identical images count as
100 dB (the MSE is floored at 255^2 * 1e-10) so means and deviations stay finite.
"""
from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from . import metrics
from .camera import CameraPath
from .hierarchy import Hlod
from .metrics import View
from .png import write_png
from .renderer import DEFAULT_COLOUR, Renderer
from .runner import COUNTERS
from .traversal import ALPHA_MODES, RuntimeSettings, make

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
PSNR_CAP_DB = 100.0
SUMMARY_KEYS = ("fps", "frame_ms", "dn", "rarn", "d", "tris", "queries", "stall_ms", "cpu_ms", "gpu_ms")


@dataclass(frozen=True)
class Variant:
    """One timed configuration: a report key (a method key, or "coh_p tau=2" in a sweep)."""

    key: str
    method: str
    settings: RuntimeSettings
    sweep_value: object = None


def variants(methods: list[str], settings: RuntimeSettings, sweep: str | None) -> list[Variant]:
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


# --- image error ------------------------------------------------------------------------------------

def ycbcr(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) uint8 RGB -> float64 Y, Cb, Cr (BT.601 full range, 0..255)."""
    m = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]])
    out = rgb.astype(np.float64) @ m.T
    out[..., 1:] += 128.0
    return out


def psnr(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """PSNR in dB of Y, Cb, Cr between two RGB images of one size; 100 dB where identical."""
    if a.shape != b.shape:
        raise ValueError(f"images differ in size: {a.shape} vs {b.shape}")
    mse = np.mean((ycbcr(a) - ycbcr(b)) ** 2, axis=(0, 1))
    return 10.0 * np.log10(255.0 ** 2 / np.maximum(mse, 255.0 ** 2 * 10 ** (-PSNR_CAP_DB / 10)))


def rmse_y(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((ycbcr(a)[..., 0] - ycbcr(b)[..., 0]) ** 2)))


# --- the run ------------------------------------------------------------------------------------------

def evaluate(hlod: Hlod, path: CameraPath, size: tuple[int, int], *, methods: list[str],
             settings: RuntimeSettings = RuntimeSettings(), repeat: int = 2, sweep: str | None = None,
             out_dir: str | os.PathLike, psnr_frames: int = 20, seed: int = 1, figures: bool = True) -> dict:
    """Runs, measures and writes report.json, report.md and the figures into out_dir; returns the
    report (the JSON contents)."""
    unknown = [m for m in methods if m not in METHOD_SPECS]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)}; expected some of {', '.join(METHOD_SPECS)}")
    if repeat < 1:
        raise ValueError("repeat must be at least 1")
    if sweep is not None and sweep not in SWEEPS:
        raise ValueError(f"sweep must be one of {', '.join(SWEEPS)}, got {sweep!r}")
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
                if (i + 1) % max(frames // 10, 1) == 0 or i + 1 == frames:
                    log.info("repeat %d/%d: frame %d/%d (%.0f s)", rep + 1, repeat, i + 1, frames,
                             time.perf_counter() - started)
        alpha_study = alpha_estimators(hlod, renderer, [path.view(i, size) for i in picked[:5]])
        showcase = modulation_frames(hlod, renderer, path, size, runs, per_frame, out_dir)
    finally:
        renderer.release()
    report = _summarise(hlod, path, size, runs, per_frame, images, picked, repeat, settings, sweep)
    report["alpha_estimators"] = alpha_study
    report["figures"] = {}
    if showcase is not None:
        report["showcase"] = showcase
    report["seconds"] = time.perf_counter() - started
    if figures:
        from . import report_figures  # matplotlib: loaded only when figures are made

        report["figures"] = report_figures.draw(report, per_frame, out_dir)
    path.save(out_dir / "path.json")
    _write_atomic(out_dir / "report.json", json.dumps(report, indent=1))
    _write_atomic(out_dir / "report.md", markdown(report))
    return report


def _summarise(hlod, path, size, runs, per_frame, images, picked, repeat, settings, sweep) -> dict:
    index = {c: j for j, c in enumerate(COUNTERS)}
    methods, sweeps = {}, {}
    for v in runs:
        median = np.median(per_frame[v.key], axis=0)  # per frame, over repeats
        row = {c: float(np.mean(median[:, index[c]])) for c in COUNTERS}
        row["fps"] = 1e3 / row["frame_ms"] if row["frame_ms"] > 0 else None
        row = {k: row[k] for k in SUMMARY_KEYS} | {"traversed": row["traversed"]}
        for ref in ("bool", "full"):
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
    report = {"methods": methods, "frames": len(path), "size": list(size), "repeat": repeat,
              "settings": {"tau": settings.tau, "s": settings.s, "t": settings.t,
                           "k": None if np.isinf(settings.k) else settings.k, "alpha": settings.alpha},
              "psnr_frames": picked, "sweep": {"name": sweep, "points": sweeps} if sweep else None,
              "scene": hlod.summary()}
    report["relative"] = relative_tables(methods)
    report["targets"] = targets(methods)
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


def targets(methods: dict) -> list[dict]:
    """The targets of the evaluation issue, each with its measured value and whether it holds."""
    need = {"coh_p", "sw_p", "bool"}
    if not need <= set(methods):
        return []
    coh, sw, boolean = methods["coh_p"], methods["sw_p"], methods["bool"]
    rows = [
        ("DN Coh(P) / SW(P) <= 1.02", coh["dn"] / sw["dn"] if sw["dn"] else None, lambda x: x <= 1.02),
        ("DN Coh(P) / Bool <= 0.85", coh["dn"] / boolean["dn"] if boolean["dn"] else None, lambda x: x <= 0.85),
        ("RARN / DN of Coh(P) <= 0.5%", 100 * coh["rarn"] / coh["dn"] if coh["dn"] else 0.0, lambda x: x <= 0.5),
        ("PSNR-Y Coh(P) vs Bool >= 34 dB", coh["psnr_y_vs_bool"], lambda x: x >= 34.0),
        ("frame ms Coh(P) / Bool < 1", coh["frame_ms"] / boolean["frame_ms"], lambda x: x < 1.0),
        ("frame ms Coh(P) / SW(P) < 1", coh["frame_ms"] / sw["frame_ms"], lambda x: x < 1.0),
        ("stall ms Coh(P) / SW(P) <= 0.2", coh["stall_ms"] / sw["stall_ms"] if sw["stall_ms"] > 0 else 0.0,
         lambda x: x <= 0.2),
    ]
    return [{"target": name, "value": value, "holds": None if value is None else bool(check(value))}
            for name, value, check in rows]


# --- alpha estimators -----------------------------------------------------------------------------

def alpha_estimators(hlod: Hlod, renderer: Renderer, views: list[View], max_nodes: int = 300) -> dict:
    """Error of `projected` and `cube` against the exact `query` count, and each one's cost per
    node, over queryable boxes in the frustum at the given views (seeded sample of max_nodes)."""
    pad = renderer.query_box_pad
    lo, hi = hlod.box_min - pad, hlod.box_max + pad
    rng = np.random.default_rng(0)
    errors = {"query": [], "projected": [], "cube": []}
    cost_s = {mode: 0.0 for mode in ALPHA_MODES}
    count = 0
    for view in views:
        usable = (metrics.boxes_in_frustum(view, hlod.box_min, hlod.box_max)
                  & ~metrics.eye_in_boxes(view.eye, lo, hi) & ~metrics.boxes_cross_near_plane(view, lo, hi))
        nodes = np.flatnonzero(usable)
        if nodes.size > max_nodes:
            nodes = np.sort(rng.choice(nodes, max_nodes, replace=False))
        if nodes.size == 0:
            continue
        renderer.begin_frame(view, time_gpu=False)
        t0 = time.perf_counter()
        pending = [renderer.issue_query(int(n), with_alpha=True) for n in nodes]
        exact = np.array([renderer.result(p)[1] for p in pending], np.float64)
        t1 = time.perf_counter()
        projected = np.array([metrics.alpha_projected(view, lo[n], hi[n]) for n in nodes])
        t2 = time.perf_counter()
        cube = metrics.alpha_cube(view, hlod.cube_side, hlod.box_min, hlod.box_max)[nodes]
        t3 = time.perf_counter()
        renderer.end_frame()
        # the query estimator costs two GL queries per node (q and alpha): charge it one of them
        cost_s["query"] += 0.5 * (t1 - t0)
        cost_s["projected"] += t2 - t1
        cost_s["cube"] += (t3 - t2)
        count += nodes.size
        ok = exact > 0
        errors["query"].extend([0.0] * int(ok.sum()))  # the reference itself
        errors["projected"].extend((np.abs(projected[ok] - exact[ok]) / exact[ok]).tolist())
        errors["cube"].extend((np.abs(cube[ok] - exact[ok]) / exact[ok]).tolist())
    out = {"nodes": count, "views": len(views)}
    for mode in ALPHA_MODES:
        rel = np.asarray(errors[mode], np.float64)
        out[mode] = {"cost_us_per_node": 1e6 * cost_s[mode] / max(count, 1),
                     "median_rel_error_pct": 100 * float(np.median(rel)) if rel.size else None,
                     "p90_rel_error_pct": 100 * float(np.percentile(rel, 90)) if rel.size else None}
    return out


# --- modulation frames (Figs. 8.1-8.3) ----------------------------------------------------------------

def bird_view(hlod: Hlod, size: tuple[int, int], up_axis: int = 2) -> View:
    """Orthographic view straight down the up axis onto the root box, all of it in the picture."""
    lo, hi = hlod.box_min[0], hlod.box_max[0]
    centre = 0.5 * (lo + hi)
    a, b = [ax for ax in range(3) if ax != up_axis]
    w, h = size
    extent_a, extent_b = hi[a] - lo[a], hi[b] - lo[b]
    height = 1.05 * max(extent_b, extent_a * h / w, 1e-9)
    depth = hi[up_axis] - lo[up_axis]
    eye = centre.copy()
    eye[up_axis] = hi[up_axis] + depth + 1e-3 * height
    up = np.zeros(3)
    up[b] = 1.0
    far = 3.0 * depth + 1e-2 * height
    return View(eye=eye, view=metrics.look_at(eye, centre, up),
                projection=metrics.orthographic(height, w / h, 1e-3 * far, far), width=w, height=h)


def draw_nodes(renderer: Renderer, view: View, nodes, colours) -> np.ndarray:
    renderer.begin_frame(view, time_gpu=False)
    for node, colour in zip(nodes, colours):
        renderer.draw_node(int(node), colour)
    renderer.end_frame()
    return renderer.read_pixels()


def modulation_frames(hlod, renderer, path, size, runs, per_frame, out_dir) -> dict | None:
    """At the frame where Coh(P) saves the most nodes over Bool (else the middle frame), the
    images of Bool, Coh(P) and Coh(mu): shaded, modulation-coloured from the user's view, and the
    drawn front modulation-coloured from a bird's-eye view. Untimed reruns of the path up to it."""
    by_key = {v.key: v for v in runs}
    shown = [k for k in ("bool", "coh_p", "coh_mu") if k in by_key]
    if not shown:
        return None
    dn = COUNTERS.index("dn")
    frame = len(path) // 2
    if "bool" in by_key and "coh_p" in by_key:
        saving = np.median(per_frame["bool"][:, :, dn], 0) - np.median(per_frame["coh_p"][:, :, dn], 0)
        frame = int(np.argmax(saving))
    bird = bird_view(hlod, size)
    eye_px = _project(bird, path.view(frame, size).eye)
    files = {}
    for key in shown:
        v = by_key[key]
        traversal = make(v.method, hlod, renderer, v.settings)
        for i in range(frame + 1):
            stats = traversal.frame(path.view(i, size))
        shaded = renderer.read_pixels()
        colours = metrics.modulation_colour(traversal.modulation(stats.drawn))
        user = draw_nodes(renderer, path.view(frame, size), stats.drawn, colours)
        above = draw_nodes(renderer, bird, stats.drawn, colours)
        files[key] = {}
        for name, image in (("shaded", shaded), ("modulation", user), ("birdseye", above)):
            files[key][name] = write_png(out_dir / f"{key}_{name}.png", image).name
        files[key]["dn"] = stats.dn
    return {"frame": frame, "eye_px": eye_px, "images": files, "default_colour": list(DEFAULT_COLOUR)}


def _project(view: View, point) -> list[float]:
    clip = view.projection @ view.view @ np.append(point, 1.0)
    ndc = clip[:2] / clip[3]
    return [float((ndc[0] + 1) / 2 * view.width), float((1 - ndc[1]) / 2 * view.height)]


# --- output -----------------------------------------------------------------------------------------

def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _f(x, digits=2) -> str:
    return "–" if x is None else f"{x:,.{digits}f}"


def markdown(report: dict) -> str:
    m = report["methods"]
    w, h = report["size"]
    st = report["settings"]
    lines = [f"# HLOD evaluation: {report['frames']} frames at {w}x{h}",
             "",
             f"Scene: {report['scene']['input_tris']:,} input triangles, {report['scene']['nodes']:,} nodes, "
             f"depth {report['scene']['depth']}. tau = {st['tau']:g} px, (s, t) = ({st['s']:g}, {st['t']:g}), "
             f"k = {'inf' if st['k'] is None else st['k']}, alpha = {st['alpha']}. {report['repeat']} repeats, methods "
             f"interleaved frame by frame in a rotating order; per frame the median over repeats, then the mean over frames. Timings compare as "
             f"ratios within this run (on llvmpipe, absolute times are the CPU rasteriser's).",
             "",
             "## Per method (Table 8.2 columns and more)",
             "",
             "| method | FPS | frame ms | DN | RARN | D | triangles | queries | stall ms | CPU ms | GPU ms |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for key, r in m.items():
        lines.append(f"| {LABELS[key]} | {_f(r['fps'], 1)} | {_f(r['frame_ms'])} | {_f(r['dn'])} | {_f(r['rarn'])} | "
                     f"{_f(r['d'])} | {_f(r['tris'], 0)} | {_f(r['queries'], 1)} | {_f(r['stall_ms'])} | "
                     f"{_f(r['cpu_ms'])} | {_f(r['gpu_ms'])} |")
    lines += ["", "## Speedup and node savings (Tables 8.3 / 8.4), percent", "",
              "| method | over | speedup % | node savings % |", "|---|---|---:|---:|"]
    for coh, rows in report["relative"].items():
        for other, r in rows.items():
            lines.append(f"| {LABELS[coh]} | {LABELS[other]} | {_f(r['speedup_pct'], 1)} | {_f(r['node_savings_pct'], 1)} |")
    lines += ["", f"## Image quality (Table 8.1): PSNR dB, mean ± s.d. over {len(report['psnr_frames'])} seeded "
              "frames (100 = identical)", "",
              "| method | Y vs Bool | Cb vs Bool | Cr vs Bool | Y vs Full | Cb vs Full | Cr vs Full | RMSE Y vs Full |",
              "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for key, r in m.items():
        cells = [f"{_f(r[f'psnr_{c}_vs_{ref}'], 1)} ± {_f(r[f'psnr_{c}_vs_{ref}_sd'], 1)}"
                 if r[f"psnr_{c}_vs_{ref}"] is not None else "–" for ref in ("bool", "full") for c in ("y", "cb", "cr")]
        lines.append(f"| {LABELS[key]} | " + " | ".join(cells) + f" | {_f(r['rmse_y_vs_full'])} |")
    if report.get("sweep"):
        lines += ["", f"## Sweep over {report['sweep']['name']} (Coh(P))", "",
                  "| variant | frame ms | DN | RARN | stall ms | PSNR-Y vs Bool | RMSE Y vs Full |",
                  "|---|---:|---:|---:|---:|---:|---:|"]
        for key, r in report["sweep"]["points"].items():
            lines.append(f"| {key} | {_f(r['frame_ms'])} | {_f(r['dn'])} | {_f(r['rarn'])} | {_f(r['stall_ms'])} | "
                         f"{_f(r['psnr_y_vs_bool'], 1)} | {_f(r['rmse_y_vs_full'])} |")
    a = report["alpha_estimators"]
    lines += ["", f"## alpha estimators ({a['nodes']} boxes over {a['views']} views; error against the exact "
              "`query` count)", "", "| estimator | cost µs per node | median error % | 90th percentile error % |",
              "|---|---:|---:|---:|"]
    for mode in ALPHA_MODES:
        r = a[mode]
        lines.append(f"| {mode} | {_f(r['cost_us_per_node'], 1)} | {_f(r['median_rel_error_pct'])} | "
                     f"{_f(r['p90_rel_error_pct'])} |")
    lines.append("")
    lines.append("`query` is exact by definition (its cost is one extra GL query per node: charged as half "
                 "the measured time of issuing and reading both queries).")
    if report["targets"]:
        lines += ["", "## Targets", "", "| target | measured | holds |", "|---|---:|---|"]
        for t in report["targets"]:
            lines.append(f"| {t['target']} | {_f(t['value'], 3)} | {t['holds']} |")
    if report.get("figures"):
        lines += ["", "## Figures", ""]
        for name, file in report["figures"].items():
            lines.append(f"![{name}]({file})")
            lines.append("")
    return "\n".join(lines) + "\n"


def summary_line(report: dict, out_dir) -> dict:
    """The command's last stdout line: the issue's keys per method, frames, size, where the report is."""
    keys = SUMMARY_KEYS + ("psnr_y_vs_bool", "psnr_cb_vs_bool", "psnr_cr_vs_bool", "psnr_y_vs_full")
    methods = {k: {c: r[c] for c in keys} for k, r in report["methods"].items()}
    out = {"methods": methods, "frames": report["frames"], "size": report["size"],
           "report": str(Path(out_dir) / "report.md")}
    if report.get("sweep"):
        out["sweep"] = {k: {c: r[c] for c in keys} for k, r in report["sweep"]["points"].items()}
    if report["targets"]:
        out["targets_hold"] = all(t["holds"] for t in report["targets"])
    return out

