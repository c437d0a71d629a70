"""The evaluation report's figures (DESIGN §9), drawn with matplotlib (imported only here, and only
when an evaluation writes figures).

- error_vs_time.png: luminance RMSE against Full over the PSNR frames, against mean frame time; one
  point per method and per sweep value.
- per_frame.png: drawn nodes and frame time per frame (dissertation Figs. 8.4/8.5).
- alpha_estimators.png: median (bar: 90th percentile) error of each alpha estimator against its
  cost per node.
- modulation.png: Bool, Coh(P), Coh(mu) at one frame: shaded, modulation colours from the user's
  view, and the drawn front from above (Figs. 8.1-8.3); blue weak, magenta moderate, red strong.

Data form: in, the report dict (evaluate's report.json) and per_frame[key], (repeat, frames,
len(COUNTERS)) float64; out, PNG files in the report folder.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .traversal import ALPHA_MODES, COUNTERS

DPI = 110
GRID_ALPHA = 0.3  # opacity of the grid lines


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def draw(report: dict, per_frame: dict, out_dir: Path, *, labels: dict[str, str]) -> dict:
    """Write the figures of `report` (evaluate's JSON) and its per-frame counters into out_dir;
    `labels`: report key -> method name shown. Returns figure title -> file name."""
    plt = _pyplot()
    files = {}
    files["error against frame time"] = _error_vs_time(plt, report, labels, out_dir)
    files["per-frame drawn nodes and frame time"] = _per_frame(plt, report, per_frame, labels, out_dir)
    files["alpha estimators: error against cost"] = _alpha(plt, report, out_dir)
    if report.get("showcase"):
        files["modulation colours"] = _modulation(plt, report, labels, out_dir)
    return {k: v for k, v in files.items() if v}


def _save(plt, fig, out_dir: Path, name: str) -> str:
    fig.tight_layout()
    fig.savefig(out_dir / name, dpi=DPI)
    plt.close(fig)
    return name


def _error_vs_time(plt, report, labels, out_dir):
    points = [(labels[k], r) for k, r in report["methods"].items()]
    if report.get("sweep"):
        points += [(k, r) for k, r in report["sweep"]["points"].items()]
    points = [(name, r) for name, r in points if r["rmse_y_vs_full"] is not None]
    if not points:
        return None
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for name, r in points:
        swept = name.startswith("coh_p ")
        ax.scatter(r["frame_ms"], r["rmse_y_vs_full"], marker="x" if swept else "o", s=40)
        ax.annotate(name, (r["frame_ms"], r["rmse_y_vs_full"]), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.set_xlabel("mean frame time, ms (same run)")
    ax.set_ylabel("luminance RMSE against Full (0..255)")
    ax.set_title("Image error against frame time")
    ax.grid(alpha=GRID_ALPHA)
    return _save(plt, fig, out_dir, "error_vs_time.png")


def _per_frame(plt, report, per_frame, labels, out_dir):
    dn, ms = COUNTERS.index("dn"), COUNTERS.index("frame_ms")
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    colours = plt.get_cmap("tab20").colors
    for i, key in enumerate(report["methods"]):  # more methods than the default 10-colour cycle
        median = np.median(per_frame[key], axis=0)
        style = {"label": labels[key], "lw": 1, "color": colours[(2 * i) % 20 + (2 * i) // 20]}
        top.plot(median[:, dn], **style)
        bottom.plot(median[:, ms], **style)
    top.set_ylabel("drawn nodes")
    bottom.set_ylabel("frame ms")
    bottom.set_xlabel("frame")
    top.legend(ncol=5, fontsize=7)
    top.grid(alpha=GRID_ALPHA)
    bottom.grid(alpha=GRID_ALPHA)
    return _save(plt, fig, out_dir, "per_frame.png")


def _alpha(plt, report, out_dir):
    a = report["alpha_estimators"]
    if not a["nodes"]:
        return None
    fig, ax = plt.subplots(figsize=(6, 4))
    for mode in ALPHA_MODES:
        r = a[mode]
        med, p90 = r["median_rel_error_pct"], r["p90_rel_error_pct"]
        ax.errorbar([r["cost_us_per_node"]], [med], yerr=[[0.0], [p90 - med]], fmt="o", capsize=3, label=mode)
        ax.annotate(mode, (r["cost_us_per_node"], med), textcoords="offset points", xytext=(5, 5))
    ax.set_xscale("log")
    ax.set_xlabel("cost per node, µs (log)")
    ax.set_ylabel("error against the query count, %")
    ax.set_title(f"alpha estimators ({a['nodes']} boxes)")
    ax.grid(alpha=GRID_ALPHA)
    return _save(plt, fig, out_dir, "alpha_estimators.png")


def _modulation(plt, report, labels, out_dir):
    show = report["showcase"]
    keys = list(show["images"])
    rows = (("shaded", "image"), ("modulation", "modulation, user view"), ("birdseye", "drawn front from above"))
    fig, axes = plt.subplots(3, len(keys), figsize=(3.6 * len(keys), 8.4), squeeze=False)
    for col, key in enumerate(keys):
        for row, (name, title) in enumerate(rows):
            ax = axes[row][col]
            ax.imshow(plt.imread(out_dir / show["images"][key][name]))
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{labels[key]}: {title}" + (f" ({show['images'][key]['dn']} nodes)" if row == 0 else ""),
                         fontsize=8)
            if name == "birdseye":
                ax.plot(*show["eye_px"], marker="*", color="black", markersize=10)
    fig.suptitle(f"Frame {show['frame']}: modulation blue = weak, magenta = moderate, red = strong; * = eye",
                 fontsize=9)
    return _save(plt, fig, out_dir, "modulation.png")
