"""The evaluation report's figures (DESIGN §9), drawn with matplotlib (imported only here, and only
when figures are drawn; Blender's Python has no matplotlib and gets a report without them).

- error_vs_time.png: luminance RMSE against Full over the PSNR frames, against mean frame time; one
  point per method and per sweep value, every label placed where it overlaps no other text (from
  matplotlib's own text extents), the Pareto front as a line, Full (the reference, RMSE 0) as an
  annotation at the edge so that its frame time does not set the scale.
- per_frame.png: per frame, drawn nodes as a ratio to SW(P)'s (the count VMSSE asks for) and frame
  time as a ratio to Ideal's for the query-driven methods, Full and VFC in their own panels, the
  path's parts marked on the frame axis (dissertation Figs. 8.4/8.5).
- alpha_estimators.png: median (bar: 90th percentile) error of each alpha estimator against its
  cost per node.
- modulation.png: Bool, Coh(P), Coh(mu) at one frame: shaded, modulation colours from the user's
  view, and the drawn front from above (Figs. 8.1-8.3); blue weak, magenta moderate, red strong.
- psnr_target.png (a tuning report, hlod_core/report/tuning.py): drawn nodes against the lowest PSNR-Y
  against Bool over the PSNR frames for each (s, t) tried, one line per s, the target as a
  vertical line, the chosen (s, t) marked.
- queries_pay.png (benchmarks/queries_pay.py): frame time and drawn nodes relative to VFC's on the
  low, middle and high depth-complexity scenes side by side.

Every method (and sweep point) has its own colour, line style and marker (`style`).

Data form: in, the report dict (evaluate's report.json) and medians[key], (frames, len(COUNTERS))
float64 per-frame medians over repeats (evaluate's per_frame.npz); out, PNG files in the report
folder (`python -m hlod_core.report.evaluate --redraw DIR` draws them again from the saved files).
"""
from __future__ import annotations

import logging
import textwrap
import warnings
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_file
from ..traversal.settings import ALPHA_MODES
from ..traversal.stats import COUNTERS

log = logging.getLogger(__name__)

DPI = 110
GRID_ALPHA = 0.3  # opacity of the grid lines
LINE_WIDTH_PT = 1.3
FONT_PT = 8.5  # point labels, legends, part names
BAR_LABEL_PT = 7.5
TITLE_CHARS = 105  # a wide figure's title wraps at this many characters a line (9.5 pt on 10 in)
# key -> (colour, dash pattern in points (None: solid), marker): all three differ between methods
METHOD_STYLES = {
    "coh_p": ("#d62728", None, "*"),
    "sw_p": ("#ff7f0e", (6, 2), "^"),
    "bool": ("#1f77b4", (6, 2, 1, 2), "o"),
    "ideal": ("#2ca02c", (1, 1.5), "X"),
    "coh_mu": ("#9467bd", (3, 1), "P"),
    "sw_mu": ("#8c564b", (8, 2, 2, 2, 2, 2), "<"),
    "simp_p": ("#bcbd22", (2, 2), "D"),
    "simp_mu": ("#17becf", (10, 3), "d"),
    "coh_p_alg4": ("#e377c2", (4, 1, 1, 1, 1, 1), "h"),
    "vfc": ("#7f7f7f", (12, 2, 3, 2), "v"),
    "full": ("#000000", (1, 3), "s"),
}
# sweep points, in the sweep's order (at most four values per sweep)
SWEEP_STYLES = (("#800000", (6, 1, 1, 1), "p"), ("#b8860b", (3, 3), ">"), ("#000080", (7, 2, 1, 2, 1, 2), "H"),
                ("#008080", (9, 1), "8"))
# per-frame panels: ratios for the methods that query (and their sweep points); Full and VFC apart
RATIO_METHODS = ("bool", "sw_p", "sw_mu", "simp_p", "simp_mu", "coh_p", "coh_mu", "coh_p_alg4")
NODES_REFERENCE, TIME_REFERENCE = "sw_p", "ideal"  # drawn nodes / SW(P)'s, frame time / Ideal's
OWN_PANEL_METHODS = ("full", "vfc")
SMOOTHING_FRAMES_PER_WINDOW = 80  # running median over about frames / 80 frames (odd; 13 of 1,020)
RATIO_PERCENTILES = (0.5, 99.5)  # the ratio panels' y range: these percentiles of the curves, and 1
RANGE_MARGIN = 0.08  # fraction of a data range added on each side
# point labels (error_vs_time, alpha_estimators): tried at these distances from the point, in
# display pixels, and in LABEL_DIRECTIONS directions each (starting up and to the right)
LABEL_RADII_PX = (5, 10, 16, 24, 33, 44, 56, 70, 86, 104, 124, 146, 170)
LABEL_DIRECTIONS = 16
LABEL_GAP_PX = 2.0  # clear space kept around every label
MARKER_HALF_PX = 6.0  # half the side of the box a point's marker keeps free
LEADER_MIN_PX = 12  # a label further than this from its point gets a leader line
LEADER_SAMPLE_PX = 3.0  # a leader line is kept clear of labels at points this far apart
FALLBACK_STEP_PX = 6  # grid of the last-resort search for a free spot in the axes
FRONT_STYLE = {"color": "0.55", "lw": 6, "alpha": 0.35, "solid_capstyle": "round", "zorder": 1}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def style(key: str, sweep_keys: list[str] = ()) -> dict:
    """Colour, dash pattern and marker of a method key (METHOD_STYLES) or of a sweep point (its
    place in `sweep_keys`), as matplotlib keyword arguments."""
    if key in METHOD_STYLES:
        colour, dashes, marker = METHOD_STYLES[key]
    else:
        colour, dashes, marker = SWEEP_STYLES[list(sweep_keys).index(key) % len(SWEEP_STYLES)]
    return {"color": colour, "linestyle": "-" if dashes is None else (0, dashes), "marker": marker}


def _sweep_keys(report: dict) -> list[str]:
    return list(report["sweep"]["points"]) if report.get("sweep") else []


def display_name(key: str, labels: dict[str, str]) -> str:
    """A method's label, or a sweep point's ("coh_p s,t=0.6,0.2" -> "Coh(P) s,t=0.6,0.2")."""
    if key in labels:
        return labels[key]
    method, _, value = key.partition(" ")
    return f"{labels.get(method, method)} {value}".strip()


def draw(report: dict, medians: dict | None, out_dir: Path, *, labels: dict[str, str]) -> dict:
    """Write the figures of `report` (evaluate's JSON) and its per-frame medians (None: no
    per-frame figure) into out_dir; `labels`: report key -> method name shown. Returns figure
    title -> file name."""
    plt = _pyplot()
    out_dir = Path(out_dir)
    files = {}
    fig = error_vs_time_figure(report, labels=labels)
    files["error against frame time"] = fig and save(fig, out_dir / "error_vs_time.png")
    fig = per_frame_figure(report, medians, labels=labels) if medians is not None else None
    files["per-frame drawn nodes and frame time"] = fig and save(fig, out_dir / "per_frame.png")
    fig = alpha_figure(report) if report.get("alpha_estimators") else None  # none in a tuning report
    files["alpha estimators: error against cost"] = fig and save(fig, out_dir / "alpha_estimators.png")
    if report.get("showcase"):
        files["modulation colours"] = _modulation(plt, report, labels, out_dir)
    if report.get("psnr_target"):
        fig = psnr_target_figure(report)
        files["drawn nodes against PSNR-Y, tuned to a target"] = save(fig, out_dir / "psnr_target.png")
    return {k: v for k, v in files.items() if v}


def save(fig, target: Path) -> str:
    """Write `fig` as PNG at DPI (atomically), close it; the file's name."""
    plt = _pyplot()
    with atomic_file(target) as f:
        fig.savefig(f, format="png", dpi=DPI)
    plt.close(fig)
    return Path(target).name


def _frozen_layout(fig):
    """Run the figure's constrained layout once and keep it: label placement works in the display
    pixels of the final layout. Returns the renderer."""
    fig.canvas.draw()
    fig.set_layout_engine("none")
    return fig.canvas.get_renderer()


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
    plt = _pyplot()
    sweep_keys = _sweep_keys(report)
    rows = dict(report["methods"]) | (report["sweep"]["points"] if report.get("sweep") else {})
    points = {k: (r["frame_ms"], r["rmse_y_vs_full"]) for k, r in rows.items()
              if r["rmse_y_vs_full"] is not None and r["frame_ms"] is not None}
    if not points:
        return None
    shown = {k: p for k, p in points.items() if k != "full"}
    front = pareto_front({k: p for k, p in points.items() if k != "ideal"})
    fig, ax = plt.subplots(figsize=(7.6, 5.0), dpi=DPI, layout="constrained")
    xy = np.array(list(shown.values()) or [points["full"]], np.float64).reshape(-1, 2)
    (x0, x1), (y0, y1) = (_padded_range(xy[:, 0], 2.5 * RANGE_MARGIN), _padded_range(xy[:, 1], 2.5 * RANGE_MARGIN))
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    for key, (x, y) in shown.items():
        s = style(key, sweep_keys)
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
    renderer = _frozen_layout(fig)
    avoid = []
    if "full" in points:
        full_ms = points["full"][0]
        target_x = min(max(full_ms, x0), x1)
        into_range = x0 <= full_ms <= x1  # else it lies off to the right, where the arrow points
        text = f"Full, the reference (RMSE 0): {full_ms:.1f} ms" + ("" if into_range else " →")
        note = ax.annotate(text, xy=(target_x, y0), xycoords="data", xytext=(0.99, 0.025), textcoords="axes fraction",
                           ha="right", va="bottom", fontsize=FONT_PT, color=METHOD_STYLES["full"][0],
                           arrowprops={"arrowstyle": "->", "color": "0.2", "lw": 0.8} if into_range else None)
        box = note.get_window_extent(renderer)
        avoid.append(box)
        if "full" in front and front_xy and not into_range:  # the front goes on to Full, off to the right
            end = ax.transData.inverted().transform((box.x0, 0.5 * (box.y0 + box.y1)))
            ax.plot([front_xy[-1][0], end[0]], [front_xy[-1][1], end[1]], **(FRONT_STYLE | {"alpha": 0.2}))
    names = {k: display_name(k, labels) for k in shown}
    if "ideal" in names:
        names["ideal"] += " (bound)"
    place_labels(ax, renderer, points=[shown[k] for k in shown], names=[names[k] for k in shown],
                 colours=[style(k, sweep_keys)["color"] for k in shown], avoid=avoid)
    return fig


def _padded_range(values: np.ndarray, margin: float) -> tuple[float, float]:
    lo, hi = float(np.min(values)), float(np.max(values))
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    return lo - margin * span, hi + margin * span


def place_labels(ax, renderer, *, points, names, colours, avoid=()) -> list:
    """Annotate each data point (x, y) with its name where the text's extent (measured by
    matplotlib) overlaps no other label, no marker and nothing in `avoid` (display-pixel Bboxes),
    and lies inside the axes: the nearest free place around the point (LABEL_RADII_PX x
    LABEL_DIRECTIONS), else the nearest free spot of the axes, with a leader line when it is more
    than LEADER_MIN_PX away. The most crowded points are placed first. Returns the annotations."""
    if not names:
        return []
    px = ax.transData.transform(np.asarray(points, np.float64).reshape(-1, 2))
    frame = ax.get_window_extent(renderer)
    inner = np.array([frame.x0, frame.y0, frame.x1, frame.y1]) + LABEL_GAP_PX * np.array([1, 1, -1, -1])
    taken = [np.array([b.x0, b.y0, b.x1, b.y1]) for b in avoid]
    taken += [np.array([x - MARKER_HALF_PX, y - MARKER_HALF_PX, x + MARKER_HALF_PX, y + MARKER_HALF_PX]) for x, y in px]
    distance = np.linalg.norm(px[:, None, :] - px[None, :, :], axis=2)
    crowding = np.sort(distance, axis=1)[:, 1] if len(px) > 1 else np.zeros(1)
    angles = np.pi / 4 + 2 * np.pi * np.arange(LABEL_DIRECTIONS) / LABEL_DIRECTIONS
    out = [None] * len(names)
    leaders = np.zeros((0, 2))  # sample points of the leader lines drawn so far
    for i in np.argsort(crowding, kind="stable"):
        probe = ax.text(0, 0, names[i], fontsize=FONT_PT)
        extent = probe.get_window_extent(renderer)
        probe.remove()
        w, h = extent.width, extent.height
        spot = _free_spot(px[i], w, h, inner=inner, taken=taken, angles=angles, leaders=leaders)
        # the point of the label's box nearest to the data point, as a fraction of the box
        nearest = np.clip((px[i] - spot) / [w, h], 0.0, 1.0)
        leader = np.linalg.norm(spot + nearest * [w, h] - px[i]) > LEADER_MIN_PX
        if leader:
            leaders = np.concatenate([leaders, _segment_samples(px[i], spot + nearest * [w, h])])
        dx, dy = spot - px[i]  # the label box's lower-left corner, relative to the point
        ann = ax.annotate(names[i], xy=points[i], xytext=(dx, dy), textcoords="offset pixels", fontsize=FONT_PT,
                          color=colours[i], ha="left", va="bottom", zorder=4,
                          arrowprops={"arrowstyle": "-", "color": colours[i], "lw": 0.6, "shrinkA": 0, "shrinkB": 4,
                                      "relpos": tuple(nearest)} if leader else None)
        ann.get_window_extent(renderer)  # places it
        box = text_extent(ann, renderer)
        taken.append(np.array([box.x0, box.y0, box.x1, box.y1]))
        out[i] = ann
    return out


def text_extent(text, renderer):
    """The display-pixel Bbox of a Text's glyphs alone (an Annotation's own extent includes its
    arrow)."""
    from matplotlib.text import Annotation, Text

    if isinstance(text, Annotation):
        text.update_positions(renderer)
    return Text.get_window_extent(text, renderer)


def _segment_samples(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 2) points along the segment a-b, LEADER_SAMPLE_PX apart or closer, ends included."""
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / LEADER_SAMPLE_PX)) + 1)
    return a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)


def _free_spot(point: np.ndarray, w: float, h: float, *, inner: np.ndarray, taken: list, angles: np.ndarray,
               leaders: np.ndarray):
    """Lower-left corner (display pixels) of a free w x h box near `point`: on the rings around it,
    the box's corner or edge middle facing the point set at the ring; else the free grid position
    of the axes nearest to the point; else beside the point. Free: inside the axes, clear of the
    `taken` boxes (x0, y0, x1, y1) and of the `leaders` (n, 2) points, and its own leader line
    (from the point to the box) clear of the taken boxes."""
    gap = LABEL_GAP_PX
    occupied = np.array(taken).reshape(-1, 4)

    def inside_any(xy: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(m, 2) points, (n, 4) boxes -> (n,) whether any point lies in each box."""
        return np.any((xy[None, :, 0] > boxes[:, None, 0]) & (xy[None, :, 0] < boxes[:, None, 2])
                      & (xy[None, :, 1] > boxes[:, None, 1]) & (xy[None, :, 1] < boxes[:, None, 3]), axis=1)

    def free(corners: np.ndarray, *, leaders_clear: bool = True) -> np.ndarray:
        """corners (n, 2) lower-left -> (n,) bool: inside the axes, clear of everything taken (and,
        with leaders_clear, of every leader line, its own leader crossing no label)."""
        boxes = np.concatenate([corners - gap, corners + [w + gap, h + gap]], axis=1)
        inside = ((boxes[:, 0] >= inner[0]) & (boxes[:, 1] >= inner[1]) & (boxes[:, 2] <= inner[2])
                  & (boxes[:, 3] <= inner[3]))
        clear = ~np.any((boxes[:, None, 0] < occupied[None, :, 2]) & (boxes[:, None, 2] > occupied[None, :, 0])
                        & (boxes[:, None, 1] < occupied[None, :, 3]) & (boxes[:, None, 3] > occupied[None, :, 1]),
                        axis=1)
        ok = inside & clear & ~inside_any(leaders, boxes) if leaders.size and leaders_clear else inside & clear
        for j in np.flatnonzero(ok) if leaders_clear else ():  # its own leader line must not cross a label
            nearest = np.clip(point, corners[j], corners[j] + [w, h])
            if np.linalg.norm(nearest - point) > LEADER_MIN_PX and occupied.size:
                samples = _segment_samples(point, nearest)[1:-1]
                labels_only = occupied[np.any(occupied[:, 2:] - occupied[:, :2] > 2 * MARKER_HALF_PX, axis=1)]
                ok[j] = not inside_any(samples, labels_only).any() if labels_only.size else True
        return ok

    cos, sin = np.cos(angles), np.sin(angles)
    for radius in LABEL_RADII_PX:
        # the box sits beyond the ring in direction (cos, sin): its facing side at the ring
        anchor = point + radius * np.stack([cos, sin], axis=1)
        corners = anchor - np.stack([w * (1 - np.clip(cos * 2, -1, 1)) / 2, h * (1 - np.clip(sin * 2, -1, 1)) / 2],
                                    axis=1)
        ok = free(corners)
        if ok.any():
            return corners[int(np.argmax(ok))]
    xs = np.arange(inner[0], inner[2] - w, FALLBACK_STEP_PX)
    ys = np.arange(inner[1], inner[3] - h, FALLBACK_STEP_PX)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    for leaders_clear in (True, False):  # a crossed leader line is legible; overlapping text is not
        ok = free(grid, leaders_clear=leaders_clear) if grid.size else np.zeros(0, bool)
        if ok.any():
            candidates = grid[ok]
            centre_distance = np.linalg.norm(candidates + [w / 2, h / 2] - point, axis=1)
            return candidates[int(np.argmin(centre_distance))]
    log.warning("no free place for a label of %.0f x %.0f px; it may overlap", w, h)
    return point + LABEL_RADII_PX[0]


# --- per frame ------------------------------------------------------------------------------------

def running_median(values: np.ndarray, window: int) -> np.ndarray:
    """(n,) centred running median over `window` (odd) samples, edges repeated, NaN ignored."""
    if window <= 1:
        return values
    half = window // 2
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(values, half, mode="edge"), window)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows stay NaN
        return np.nanmedian(windows, axis=-1)


def smoothing_window(frames: int) -> int:
    """Odd running-median window for a path of `frames` frames (1: none)."""
    return max(1, (frames // SMOOTHING_FRAMES_PER_WINDOW) | 1)


def _ratio(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a / b per frame, NaN where b is 0."""
    out = np.full(a.shape, np.nan)
    np.divide(a, b, out=out, where=b > 0)
    return out


def per_frame_figure(report: dict, medians: dict, *, labels: dict[str, str]):
    """The per-frame figure (module docstring); `medians`: key -> (frames, len(COUNTERS))."""
    plt = _pyplot()
    dn, ms = COUNTERS.index("dn"), COUNTERS.index("frame_ms")
    sweep_keys = [k for k in _sweep_keys(report) if k in medians]
    frames = next(iter(medians.values())).shape[0]
    window = smoothing_window(frames)
    x = np.arange(frames)
    fig = plt.figure(figsize=(10, 8.4), dpi=DPI, layout="constrained")
    grid = fig.add_gridspec(3, 2, height_ratios=(3, 3, 2.2))
    nodes_ax = fig.add_subplot(grid[0, :])
    time_ax = fig.add_subplot(grid[1, :], sharex=nodes_ax)
    full_nodes_ax = fig.add_subplot(grid[2, 0], sharex=nodes_ax)
    full_time_ax = fig.add_subplot(grid[2, 1], sharex=nodes_ax)
    ratio_keys = [k for k in RATIO_METHODS if k in medians] + sweep_keys
    handles = {}

    def line(ax, key, values):
        s = style(key, sweep_keys)
        (handles[key],) = ax.plot(x, running_median(values, window), color=s["color"], linestyle=s["linestyle"],
                                  lw=LINE_WIDTH_PT)

    for ax, counter, ref, what in ((nodes_ax, dn, NODES_REFERENCE, "drawn nodes"),
                                   (time_ax, ms, TIME_REFERENCE, "frame time")):
        if ref in medians:
            curves = [(k, _ratio(medians[k][:, counter], medians[ref][:, counter])) for k in ratio_keys if k != ref]
            s = style(ref, sweep_keys)
            (handles[ref],) = ax.plot(x, np.ones(frames), color=s["color"], linestyle=s["linestyle"], lw=LINE_WIDTH_PT)
            ax.set_ylabel(f"{what} ÷ {labels.get(ref, ref)}'s")
        else:  # no reference in this run: the counts themselves
            curves = [(k, medians[k][:, counter]) for k in ratio_keys]
            ax.set_ylabel(what + (" (ms)" if counter == ms else ""))
        for key, values in curves:
            line(ax, key, values)
        finite = np.concatenate([running_median(v, window) for _, v in curves] + [np.ones(1)])
        finite = finite[np.isfinite(finite)]
        lo, hi = np.percentile(finite, RATIO_PERCENTILES)
        ax.set_ylim(*_padded_range(np.array([min(lo, 1.0), max(hi, 1.0)]), RANGE_MARGIN))
    own = [k for k in OWN_PANEL_METHODS if k in medians]
    for ax, counter, what in ((full_nodes_ax, dn, "drawn nodes"), (full_time_ax, ms, "frame ms")):
        for key in own:
            line(ax, key, medians[key][:, counter])
        ax.set_ylabel(f"{' and '.join(labels[k] for k in own)}: {what}")
        ax.set_xlabel("frame")
        ax.set_visible(bool(own))
    if own:
        full_nodes_ax.set_yscale("log")
    parts = report.get("parts") or []
    for ax in (nodes_ax, time_ax, full_nodes_ax, full_time_ax):
        ax.grid(alpha=GRID_ALPHA)
        ax.set_xlim(0, frames - 1)
        _mark_parts(ax, parts, frames)
    plt.setp(nodes_ax.get_xticklabels(), visible=False)
    if parts:
        top = nodes_ax.secondary_xaxis("top")
        ends = [p["start"] for p in parts[1:]] + [frames]
        top.set_xticks([(p["start"] + end - 1) / 2 for p, end in zip(parts, ends)],
                       labels=[p["name"] for p in parts], fontsize=FONT_PT + 0.5)
        top.tick_params(length=0)
    smoothing = f" (running median over {window} frames)" if window > 1 else ""
    nodes = "drawn nodes against SW(P)'s (the count VMSSE asks for)" if NODES_REFERENCE in medians else "drawn nodes"
    times = "frame time against Ideal's (SW(P)'s nodes without the queries)" if TIME_REFERENCE in medians \
        else "frame time"
    title = (f"Per frame{smoothing}, for the methods that query: {nodes} and {times}"
             + ("; Full and VFC below" if own else "") + (". The camera path's parts are named on top and shaded "
                                                          "alternately." if parts else "."))
    nodes_ax.set_title("\n".join(textwrap.wrap(title, TITLE_CHARS)), fontsize=9.5)
    order = [k for k in ("full", "vfc", "ideal") + RATIO_METHODS + tuple(sweep_keys) if k in handles]
    fig.legend([handles[k] for k in order], [display_name(k, labels) for k in order], loc="outside upper center",
               ncol=-(-len(order) // 3), fontsize=FONT_PT, handlelength=3.2)
    return fig


def _mark_parts(ax, parts: list[dict], frames: int) -> None:
    """Every other part shaded, a line at each part's start."""
    ends = [p["start"] for p in parts[1:]] + [frames]
    for i, (part, end) in enumerate(zip(parts, ends)):
        if i % 2:
            ax.axvspan(part["start"] - 0.5, end - 0.5, color="0.5", alpha=0.09, lw=0)
        if part["start"] > 0:
            ax.axvline(part["start"] - 0.5, color="0.3", lw=0.8, ls=":")


# --- alpha estimators, modulation -----------------------------------------------------------------

def alpha_figure(report: dict):
    """Error against cost per node of the alpha estimators, or None without boxes."""
    plt = _pyplot()
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
    renderer = _frozen_layout(fig)
    from matplotlib.transforms import Bbox

    bar_boxes = []
    for (x, low), (_, high) in zip(points, tops):  # the error bars, caps included, as display boxes
        (x0, y0), (x1, y1) = ax.transData.transform([(x, low), (x, high)])
        bar_boxes.append(Bbox.from_extents(x0 - MARKER_HALF_PX, y0, x1 + MARKER_HALF_PX, y1 + LABEL_GAP_PX))
    place_labels(ax, renderer, points=points, names=list(ALPHA_MODES), colours=colours, avoid=bar_boxes)
    return fig


def _modulation(plt, report, labels, out_dir):
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
    plt = _pyplot()
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
    plt = _pyplot()
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
                      f"{results['frames']} frames of a seeded inspection path,\n{w}x{h}, per frame the median of {results['repeat']} passes; "
                      f"timings compare within a scene's run", fontsize=9.5)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside upper center", ncol=len(keys), fontsize=FONT_PT)
    return fig


def _ratio_or_nan(methods: dict, key: str, counter: str) -> float:
    """methods[key][counter] / VFC's, NaN where VFC's is 0."""
    reference = methods["vfc"][counter]
    return methods[key][counter] / reference if reference else float("nan")
