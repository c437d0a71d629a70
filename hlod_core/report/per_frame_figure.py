"""per_frame.png (dissertation Figs. 8.4/8.5): per frame, drawn nodes as a ratio to SW(P)'s (the
count VMSSE asks for) and frame time as a ratio to Ideal's for the query-driven methods, Full and
VFC in their own panels, the camera path's parts marked on the frame axis; curves smoothed by a
running median on long paths.

Data form: medians[key], (frames, len(COUNTERS)) float64 per-frame medians over repeats
(evaluate's per_frame.npz); the report dict for its sweep points and the path's parts.
"""
from __future__ import annotations

import textwrap
import warnings

import numpy as np

from ..traversal.stats import COUNTERS
from .figure_style import (
    DPI,
    FONT_PT,
    GRID_ALPHA,
    LINE_WIDTH_PT,
    RANGE_MARGIN,
    TITLE_CHARS,
    display_name,
    padded_range,
    pyplot,
    style,
    sweep_keys,
)

# ratios for the methods that query (and their sweep points); Full and VFC in panels of their own
RATIO_METHODS = ("bool", "sw_p", "sw_mu", "simp_p", "simp_mu", "coh_p", "coh_mu", "coh_p_alg4")
NODES_REFERENCE, TIME_REFERENCE = "sw_p", "ideal"  # drawn nodes / SW(P)'s, frame time / Ideal's
OWN_PANEL_METHODS = ("full", "vfc")
SMOOTHING_FRAMES_PER_WINDOW = 80  # running median over about frames / 80 frames (odd; 13 of 1,020)
RATIO_PERCENTILES = (0.5, 99.5)  # the ratio panels' y range: these percentiles of the curves, and 1
DN, FRAME_MS = COUNTERS.index("dn"), COUNTERS.index("frame_ms")


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


class _Curves:
    """Draws the smoothed curves of one figure in their methods' styles and keeps one legend handle
    per method."""

    def __init__(self, frames: int, sweep: list[str]):
        self.x = np.arange(frames)
        self.window = smoothing_window(frames)
        self.sweep = sweep
        self.handles: dict = {}

    def line(self, ax, key: str, values: np.ndarray, *, smooth: bool = True) -> None:
        s = style(key, self.sweep)
        (self.handles[key],) = ax.plot(self.x, running_median(values, self.window) if smooth else values,
                                       color=s["color"], linestyle=s["linestyle"], lw=LINE_WIDTH_PT)


def per_frame_figure(report: dict, medians: dict, *, labels: dict[str, str]):
    """The per-frame figure (module docstring); `medians`: key -> (frames, len(COUNTERS))."""
    plt = pyplot()
    frames = next(iter(medians.values())).shape[0]
    curves = _Curves(frames, [k for k in sweep_keys(report) if k in medians])
    fig = plt.figure(figsize=(10, 8.4), dpi=DPI, layout="constrained")
    grid = fig.add_gridspec(3, 2, height_ratios=(3, 3, 2.2))
    nodes_ax = fig.add_subplot(grid[0, :])
    time_ax = fig.add_subplot(grid[1, :], sharex=nodes_ax)
    own_axes = (fig.add_subplot(grid[2, 0], sharex=nodes_ax), fig.add_subplot(grid[2, 1], sharex=nodes_ax))
    ratio_keys = [k for k in RATIO_METHODS if k in medians] + curves.sweep
    for ax, counter, ref, what in ((nodes_ax, DN, NODES_REFERENCE, "drawn nodes"),
                                   (time_ax, FRAME_MS, TIME_REFERENCE, "frame time")):
        _ratio_panel(ax, curves, medians=medians, keys=ratio_keys, counter=counter, ref=ref, what=what,
                     ref_label=labels.get(ref, ref))
    own = [k for k in OWN_PANEL_METHODS if k in medians]
    _own_panels(own_axes, curves, medians=medians, own=own, labels=labels)
    parts = report.get("parts") or []
    for ax in (nodes_ax, time_ax, *own_axes):
        ax.grid(alpha=GRID_ALPHA)
        ax.set_xlim(0, frames - 1)
        _mark_parts(ax, parts, frames)
    plt.setp(nodes_ax.get_xticklabels(), visible=False)
    if parts:
        _name_parts(nodes_ax, parts, frames)
    nodes_ax.set_title("\n".join(textwrap.wrap(_title(medians, window=curves.window, own=own, parts=parts),
                                               TITLE_CHARS)), fontsize=9.5)
    order = [k for k in ("full", "vfc", "ideal") + RATIO_METHODS + tuple(curves.sweep) if k in curves.handles]
    fig.legend([curves.handles[k] for k in order], [display_name(k, labels) for k in order],
               loc="outside upper center", ncol=-(-len(order) // 3), fontsize=FONT_PT, handlelength=3.2)
    return fig


def _ratio_panel(ax, curves: _Curves, *, medians: dict, keys: list[str], counter: int, ref: str, what: str,
                 ref_label: str) -> None:
    """`counter` of each of `keys` as a ratio to `ref`'s (drawn as 1), or the counts themselves when
    the run has no `ref`; y range from RATIO_PERCENTILES of the smoothed curves, 1 included."""
    if ref in medians:
        shown = [(k, _ratio(medians[k][:, counter], medians[ref][:, counter])) for k in keys if k != ref]
        curves.line(ax, ref, np.ones(len(curves.x)), smooth=False)
        ax.set_ylabel(f"{what} ÷ {ref_label}'s")
    else:  # no reference in this run: the counts themselves
        shown = [(k, medians[k][:, counter]) for k in keys]
        ax.set_ylabel(what + (" (ms)" if counter == FRAME_MS else ""))
    for key, values in shown:
        curves.line(ax, key, values)
    finite = np.concatenate([running_median(v, curves.window) for _, v in shown] + [np.ones(1)])
    finite = finite[np.isfinite(finite)]
    lo, hi = np.percentile(finite, RATIO_PERCENTILES)
    ax.set_ylim(*padded_range(np.array([min(lo, 1.0), max(hi, 1.0)]), RANGE_MARGIN))


def _own_panels(axes, curves: _Curves, *, medians: dict, own: list[str], labels: dict[str, str]) -> None:
    """Full's and VFC's drawn nodes (log scale) and frame ms, hidden when the run has neither."""
    for ax, counter, what in ((axes[0], DN, "drawn nodes"), (axes[1], FRAME_MS, "frame ms")):
        for key in own:
            curves.line(ax, key, medians[key][:, counter])
        ax.set_ylabel(f"{' and '.join(labels[k] for k in own)}: {what}")
        ax.set_xlabel("frame")
        ax.set_visible(bool(own))
    if own:
        axes[0].set_yscale("log")


def _name_parts(ax, parts: list[dict], frames: int) -> None:
    """The parts' names on a secondary axis on top, each at its part's middle."""
    top = ax.secondary_xaxis("top")
    ends = [p["start"] for p in parts[1:]] + [frames]
    top.set_xticks([(p["start"] + end - 1) / 2 for p, end in zip(parts, ends)],
                   labels=[p["name"] for p in parts], fontsize=FONT_PT + 0.5)
    top.tick_params(length=0)


def _title(medians: dict, *, window: int, own: list[str], parts: list[dict]) -> str:
    smoothing = f" (running median over {window} frames)" if window > 1 else ""
    nodes = "drawn nodes against SW(P)'s (the count VMSSE asks for)" if NODES_REFERENCE in medians else "drawn nodes"
    times = "frame time against Ideal's (SW(P)'s nodes without the queries)" if TIME_REFERENCE in medians \
        else "frame time"
    return (f"Per frame{smoothing}, for the methods that query: {nodes} and {times}"
            + ("; Full and VFC below" if own else "")
            + (". The camera path's parts are named on top and shaded alternately." if parts else "."))


def _mark_parts(ax, parts: list[dict], frames: int) -> None:
    """Every other part shaded, a line at each part's start."""
    ends = [p["start"] for p in parts[1:]] + [frames]
    for i, (part, end) in enumerate(zip(parts, ends)):
        if i % 2:
            ax.axvspan(part["start"] - 0.5, end - 0.5, color="0.5", alpha=0.09, lw=0)
        if part["start"] > 0:
            ax.axvline(part["start"] - 0.5, color="0.3", lw=0.8, ls=":")
