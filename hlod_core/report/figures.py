"""The evaluation report's figures (docs/evaluation.md), drawn with matplotlib (imported only when figures are
drawn; Blender's Python has no matplotlib and gets a report without them).

- error_vs_time.png: luminance RMSE against Full over the PSNR frames, against mean frame time; one
  point per method and per sweep value, every label placed where it overlaps no other text
  (`label_placement`), the Pareto front as a line, Full (the reference, RMSE 0) as an annotation at
  the edge so that its frame time does not set the scale.
- per_frame.png: `per_frame_figure` (dissertation Figs. 8.4/8.5).
- alpha_estimators.png: median (bar: 90th percentile) error of each alpha estimator against its
  cost per node.
- modulation.png: Bool, Coh(P), Coh(mu) at one frame: shaded, modulation colours from the user's
  view, and the drawn front from above (Figs. 8.1-8.3); blue weak, magenta moderate, red strong.
- psnr_target.png (a tuning report, `tuning`): drawn nodes against the lowest PSNR-Y against Bool
  over the PSNR frames for each (s, t) tried, one line per s, the target as a vertical line, the
  chosen (s, t) marked.
- queries_pay.png (benchmarks/queries_pay.py): frame time and drawn nodes relative to VFC's on the
  low, middle and high depth-complexity scenes side by side.

Every method (and sweep point) has its own colour, line style and marker (`figure_style.style`).

Data form: in, the report dict (evaluate's report.json) and medians[key], (frames, len(COUNTERS))
float64 per-frame medians over repeats (evaluate's per_frame.npz); out, PNG files in the report
folder (`python -m hlod_core.report.evaluate --redraw DIR` draws them again from the saved files).
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..traversal.settings import ALPHA_MODES
from .figure_style import (
    BAR_LABEL_PT,
    DPI,
    FONT_PT,
    GRID_ALPHA,
    LINE_WIDTH_PT,
    METHOD_STYLES,
    RANGE_MARGIN,
    display_name,
    frozen_layout,
    padded_range,
    pyplot,
    save,
    style,
    sweep_keys,
)
from .label_placement import LABEL_GAP_PX, MARKER_HALF_PX, place_labels
from .per_frame_figure import per_frame_figure

log = logging.getLogger(__name__)

FRONT_STYLE = {"color": "0.55", "lw": 6, "alpha": 0.35, "solid_capstyle": "round", "zorder": 1}


def draw(report: dict, medians: dict | None, out_dir: Path, *, labels: dict[str, str]) -> dict:
    """Write the figures of `report` (evaluate's JSON) and its per-frame medians (None: no
    per-frame figure) into out_dir; `labels`: report key -> method name shown. Returns figure
    title -> file name."""
    out_dir = Path(out_dir)
    files = {}
    fig = error_vs_time_figure(report, labels=labels)
    files["error against frame time"] = fig and save(fig, out_dir / "error_vs_time.png")
    fig = per_frame_figure(report, medians, labels=labels) if medians is not None else None
    files["per-frame drawn nodes and frame time"] = fig and save(fig, out_dir / "per_frame.png")
    fig = alpha_figure(report) if report.get("alpha_estimators") else None  # none in a tuning report
    files["alpha estimators: error against cost"] = fig and save(fig, out_dir / "alpha_estimators.png")
    if report.get("showcase"):
        files["modulation colours"] = modulation_figure(report, labels=labels, out_dir=out_dir)
    if report.get("psnr_target"):
        fig = psnr_target_figure(report)
        files["drawn nodes against PSNR-Y, tuned to a target"] = save(fig, out_dir / "psnr_target.png")
    return {k: v for k, v in files.items() if v}


# --- error against frame time ---------------------------------------------------------------------

def pareto_front(points: dict[str, tuple[float, float]]) -> list[str]:
    """Keys of the points no other point beats on both axes ((time, error), both lower-better:
    another point at most as high on both and lower on one), in order of time."""
    keys = sorted(points, key=lambda k: points[k])
    xy = np.array([points[k] for k in keys], np.float64).reshape(-1, 2)
    at_most = np.all(xy[None, :, :] <= xy[:, None, :], axis=2)  # [i, j]: j at most i on both
    below = np.any(xy[None, :, :] < xy[:, None, :], axis=2)
    dominated = np.any(at_most & below, axis=1)
    return [k for k, d in zip(keys, dominated) if not d]


def error_vs_time_figure(report: dict, *, labels: dict[str, str]):
    """The error-against-time figure (module docstring), or None without image errors."""
    plt = pyplot()
    sweep = sweep_keys(report)
    rows = dict(report["methods"]) | (report["sweep"]["points"] if report.get("sweep") else {})
    points = {k: (r["frame_ms"], r["rmse_y_vs_full"]) for k, r in rows.items()
              if r["rmse_y_vs_full"] is not None and r["frame_ms"] is not None}
    if not points:
        return None
    shown = {k: p for k, p in points.items() if k != "full"}
    front = pareto_front({k: p for k, p in points.items() if k != "ideal"})
    fig, ax = plt.subplots(figsize=(7.6, 5.0), dpi=DPI, layout="constrained")
    xy = np.array(list(shown.values()) or [points["full"]], np.float64).reshape(-1, 2)
    ax.set_xlim(*padded_range(xy[:, 0], 2.5 * RANGE_MARGIN))
    ax.set_ylim(*padded_range(xy[:, 1], 2.5 * RANGE_MARGIN))
    for key, (x, y) in shown.items():
        s = style(key, sweep)
        ax.plot([x], [y], linestyle="none", marker=s["marker"], color=s["color"], markersize=7,
                markerfacecolor="white" if key == "ideal" else s["color"], zorder=3)
    front_xy = [shown[k] for k in front if k in shown]
    if front_xy:
        ax.plot(*np.array(front_xy).T, **FRONT_STYLE)
    ax.set_xlabel("mean frame time, ms (same run; left is faster)")
    ax.set_ylabel("luminance RMSE against Full, 0..255 (lower is better)")
    ax.set_title("Image error against frame time: lower left is better. The grey band is the Pareto front\n"
                 "(no other method both faster and closer to Full); Ideal (hollow) is a bound, off the front",
                 fontsize=9)
    ax.grid(alpha=GRID_ALPHA)
    renderer = frozen_layout(fig)
    avoid = []
    if "full" in points:
        avoid.append(_full_note(ax, renderer, full_ms=points["full"][0],
                                front_xy=front_xy if "full" in front else []))
    names = {k: display_name(k, labels) for k in shown}
    if "ideal" in names:
        names["ideal"] += " (bound)"
    place_labels(ax, renderer, points=[shown[k] for k in shown], names=[names[k] for k in shown],
                 colours=[style(k, sweep)["color"] for k in shown], avoid=avoid)
    return fig


def _full_note(ax, renderer, *, full_ms: float, front_xy: list):
    """Full's frame time as a note in the lower right corner, with an arrow to it when it lies in
    the axes' range, else pointing right (and `front_xy`, the front when Full ends it, drawn on
    to the note). Returns the note's display-pixel extent."""
    (x0, x1), (y0, _) = ax.get_xlim(), ax.get_ylim()
    target_x = min(max(full_ms, x0), x1)
    into_range = x0 <= full_ms <= x1  # else it lies off to the right, where the arrow points
    text = f"Full, the reference (RMSE 0): {full_ms:.1f} ms" + ("" if into_range else " →")
    note = ax.annotate(text, xy=(target_x, y0), xycoords="data", xytext=(0.99, 0.025), textcoords="axes fraction",
                       ha="right", va="bottom", fontsize=FONT_PT, color=METHOD_STYLES["full"][0],
                       arrowprops={"arrowstyle": "->", "color": "0.2", "lw": 0.8} if into_range else None)
    box = note.get_window_extent(renderer)
    if front_xy and not into_range:  # the front goes on to Full, off to the right
        end = ax.transData.inverted().transform((box.x0, 0.5 * (box.y0 + box.y1)))
        ax.plot([front_xy[-1][0], end[0]], [front_xy[-1][1], end[1]], **(FRONT_STYLE | {"alpha": 0.2}))
    return box


# --- alpha estimators, modulation -----------------------------------------------------------------

def alpha_figure(report: dict):
    """Error against cost per node of the alpha estimators, or None without boxes."""
    plt = pyplot()
    a = report["alpha_estimators"]
    if not a["nodes"]:
        return None
    fig, ax = plt.subplots(figsize=(6, 4), dpi=DPI, layout="constrained")
    points, tops, colours = [], [], []
    for mode in ALPHA_MODES:
        r = a[mode]
        med, p90 = r["median_rel_error_pct"], r["p90_rel_error_pct"]
        bars = ax.errorbar([r["cost_us_per_node"]], [med], yerr=[[0.0], [p90 - med]], fmt="o", capsize=3)
        points.append((r["cost_us_per_node"], med))
        tops.append((r["cost_us_per_node"], p90))
        colours.append(bars[0].get_color())
    costs = np.array([p[0] for p in points])
    ax.set_xscale("log")
    ax.set_xlim(costs.min() / 4, costs.max() * 4)
    top = max(max(t[1] for t in tops), 1.0)
    ax.set_ylim(-2 * RANGE_MARGIN * top, (1 + 3 * RANGE_MARGIN) * top)
    ax.set_xlabel("cost per node, µs (log)")
    ax.set_ylabel("error against the query count, %")
    ax.set_title(f"alpha estimators on {a['nodes']} boxes\n(dot: median error; bar: up to the 90th percentile)",
                 fontsize=9.5)
    ax.grid(alpha=GRID_ALPHA)
    renderer = frozen_layout(fig)
    from matplotlib.transforms import Bbox

    bar_boxes = []
    for (x, low), (_, high) in zip(points, tops):  # the error bars, caps included, as display boxes
        (x0, y0), (x1, y1) = ax.transData.transform([(x, low), (x, high)])
        bar_boxes.append(Bbox.from_extents(x0 - MARKER_HALF_PX, y0, x1 + MARKER_HALF_PX, y1 + LABEL_GAP_PX))
    place_labels(ax, renderer, points=points, names=list(ALPHA_MODES), colours=colours, avoid=bar_boxes)
    return fig


def modulation_figure(report: dict, *, labels: dict[str, str], out_dir: Path) -> str | None:
    """modulation.png from the showcase's images in out_dir (report["showcase"], showcase.py); its
    file name, or None when the images and an earlier composite are both missing."""
    plt = pyplot()
    show = report["showcase"]
    keys = list(show["images"])
    rows = (("shaded", "image"), ("modulation", "modulation, user view"), ("birdseye", "drawn front from above"))
    missing = [show["images"][k][name] for k in keys for name, _ in rows
               if not (out_dir / show["images"][k][name]).exists()]
    if missing:  # a folder that kept only the composite (docs/evaluation): keep it as it is
        log.warning("%s: missing; modulation.png %s", out_dir / missing[0],
                    "kept as it is" if (out_dir / "modulation.png").exists() else "not drawn")
        return "modulation.png" if (out_dir / "modulation.png").exists() else None
    fig, axes = plt.subplots(3, len(keys), figsize=(3.6 * len(keys), 8.4), squeeze=False, dpi=DPI,
                             layout="constrained")
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
    return save(fig, out_dir / "modulation.png")


# --- tuned to a PSNR target -----------------------------------------------------------------------

def psnr_target_figure(report: dict):
    """Drawn nodes against PSNR-Y of the (s, t) tried (report["psnr_target"], tuning.section):
    one line per s in order of t, s = 0 (P = mu) a point of its own, the target as a dashed
    vertical line, Bool's nodes as a dotted horizontal one, the chosen (s, t) as a star."""
    plt = pyplot()
    p = report["psnr_target"]
    fig, ax = plt.subplots(figsize=(9.6, 5.0), dpi=DPI, layout="constrained")
    by_s: dict[float, list] = {}
    for x in p["candidates"]:
        by_s.setdefault(x["s"], []).append(x)
    colours = plt.get_cmap("viridis")(np.linspace(0.0, 0.9, max(len(by_s), 1)))
    for colour, s in zip(colours, sorted(by_s)):
        points = sorted(by_s[s], key=lambda x: x["t"])
        ax.plot([x["psnr_y"] for x in points], [x["dn"] for x in points], marker="o", color=colour,
                lw=LINE_WIDTH_PT, markersize=5, label="s = 0 (P = mu)" if s == 0 else f"s = {s:g}")
    c = p["chosen"]
    ax.axvline(p["target_db"], color="#d62728", ls="--", lw=LINE_WIDTH_PT, label=f"target {p['target_db']:g} dB")
    ax.axhline(p["bool_dn"], color=METHOD_STYLES["bool"][0], ls=":", lw=LINE_WIDTH_PT,
               label=f"Bool: {p['bool_dn']:.1f} nodes (the reference)")
    ax.plot([c["psnr_y"]], [c["dn"]], marker="*", markersize=16, color="black", linestyle="none", zorder=4,
            label=(f"chosen (s, t) = ({c['s']:g}, {c['t']:g}): {c['dn']:.1f} nodes, {c['psnr_y']:.1f} dB"
                   + ("" if p["met"] else " (target not met)")))
    ax.set_xlabel(f"lowest PSNR-Y against Bool over the {len(report['psnr_frames'])} PSNR frames, dB "
                  "(100 = identical)")
    ax.set_ylabel("drawn nodes, mean over the path")
    ax.set_title(f"Tuning (s, t) to PSNR-Y >= {p['target_db']:g} dB: {len(p['candidates'])} candidates "
                 f"(t rises along each line)", fontsize=9.5)
    ax.grid(alpha=GRID_ALPHA)
    fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper", fontsize=FONT_PT)
    return fig


# --- when do queries pay --------------------------------------------------------------------------

def queries_pay_figure(results: dict, *, labels: dict[str, str]):
    """Frame time and drawn nodes of each method relative to VFC's, per scene side by side.
    `results`: benchmarks/queries_pay.py's JSON ({"scenes": {name: {"methods": {key: row}, "summary"}},
    "frames", "size"})."""
    plt = pyplot()
    scenes = list(results["scenes"])
    keys = [k for k in results["methods"] if k != "vfc"]
    fig, axes = plt.subplots(2, 1, figsize=(8, 6.4), dpi=DPI, layout="constrained", sharex=True)
    width = 0.8 / max(len(keys), 1)
    for ax, counter, what in ((axes[0], "frame_ms", "frame time"), (axes[1], "dn", "drawn nodes")):
        highest = 1.0
        for j, key in enumerate(keys):
            ratios = [_ratio_or_nan(results["scenes"][n]["methods"], key, counter) for n in scenes]
            bars = ax.bar(np.arange(len(scenes)) + (j - (len(keys) - 1) / 2) * width, ratios, width * 0.92,
                          color=style(key)["color"], edgecolor="black", lw=0.5, label=labels.get(key, key))
            ax.bar_label(bars, fmt="%.2f", fontsize=BAR_LABEL_PT, padding=1)
            highest = max(highest, np.nanmax(ratios))
        ax.axhline(1.0, color=METHOD_STYLES["vfc"][0], lw=1.5, ls="--")
        ax.set_ylim(0, highest * (1 + 1.5 * RANGE_MARGIN))
        ax.set_ylabel(f"{what} ÷ VFC's")
        ax.grid(axis="y", alpha=GRID_ALPHA)
    names = []
    for n in scenes:
        summary = results["scenes"][n]["summary"]
        names.append(f"{n} depth complexity\n{summary['input_tris'] / 1e3:,.0f}k triangles, {summary['nodes']:,} nodes")
    axes[1].set_xticks(np.arange(len(scenes)), labels=names)
    w, h = results["size"]
    axes[0].set_title(f"When do occlusion queries pay? Frame time and drawn nodes relative to VFC's (dashed line: no "
                      f"queries).\nA bar below the line: the method beats VFC there. Per scene "
                      f"{results['frames']} frames of a seeded inspection path,\n{w}x{h}, "
                      f"per frame the median of {results['repeat']} passes; "
                      f"timings compare within a scene's run", fontsize=9.5)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside upper center", ncol=len(keys), fontsize=FONT_PT)
    return fig


def _ratio_or_nan(methods: dict, key: str, counter: str) -> float:
    """methods[key][counter] / VFC's, NaN where VFC's is 0."""
    reference = methods["vfc"][counter]
    return methods[key][counter] / reference if reference else float("nan")
