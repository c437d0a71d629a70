"""Point labels that overlap nothing: each label is measured by matplotlib's own text extent and put
at the nearest free place around its point (rings of LABEL_RADII_PX in LABEL_DIRECTIONS directions),
else at the nearest free spot of the axes with a leader line (error_vs_time, alpha_estimators).

Data form: display pixels throughout; boxes as (x0, y0, x1, y1) float arrays, points (n, 2).
"""
from __future__ import annotations

import logging

import numpy as np

from .figure_style import FONT_PT

log = logging.getLogger(__name__)

# labels are tried at these distances from the point, in display pixels, and in LABEL_DIRECTIONS
# directions each (starting up and to the right)
LABEL_RADII_PX = (5, 10, 16, 24, 33, 44, 56, 70, 86, 104, 124, 146, 170)
LABEL_DIRECTIONS = 16
LABEL_GAP_PX = 2.0  # clear space kept around every label
MARKER_HALF_PX = 6.0  # half the side of the box a point's marker keeps free
LEADER_MIN_PX = 12  # a label further than this from its point gets a leader line
LEADER_SAMPLE_PX = 3.0  # a leader line is kept clear of labels at points this far apart
FALLBACK_STEP_PX = 6  # grid of the last-resort search for a free spot in the axes


def place_labels(ax, renderer, *, points, names, colours, avoid=()) -> list:
    """Annotate each data point (x, y) with its name where the text's extent (measured by
    matplotlib) overlaps no other label, no marker and nothing in `avoid` (display-pixel Bboxes),
    and lies inside the axes (module docstring), with a leader line when it is more than
    LEADER_MIN_PX away. The most crowded points are placed first. Returns the annotations."""
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


def _inside_any(xy: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(m, 2) points, (n, 4) boxes -> (n,) whether any point lies in each box."""
    return np.any((xy[None, :, 0] > boxes[:, None, 0]) & (xy[None, :, 0] < boxes[:, None, 2])
                  & (xy[None, :, 1] > boxes[:, None, 1]) & (xy[None, :, 1] < boxes[:, None, 3]), axis=1)


def _free(corners: np.ndarray, *, point: np.ndarray, size: tuple[float, float], inner: np.ndarray,
          occupied: np.ndarray, leaders: np.ndarray, leaders_clear: bool = True) -> np.ndarray:
    """corners (n, 2) lower-left of a label box of `size` (w, h) -> (n,) bool: inside the axes
    (`inner`), clear of the `occupied` (k, 4) boxes and (with leaders_clear) of the `leaders` (m, 2)
    points, its own leader line from `point` crossing no label."""
    w, h = size
    gap = LABEL_GAP_PX
    boxes = np.concatenate([corners - gap, corners + [w + gap, h + gap]], axis=1)
    inside = ((boxes[:, 0] >= inner[0]) & (boxes[:, 1] >= inner[1]) & (boxes[:, 2] <= inner[2])
              & (boxes[:, 3] <= inner[3]))
    clear = ~np.any((boxes[:, None, 0] < occupied[None, :, 2]) & (boxes[:, None, 2] > occupied[None, :, 0])
                    & (boxes[:, None, 1] < occupied[None, :, 3]) & (boxes[:, None, 3] > occupied[None, :, 1]),
                    axis=1)
    ok = inside & clear & ~_inside_any(leaders, boxes) if leaders.size and leaders_clear else inside & clear
    for j in np.flatnonzero(ok) if leaders_clear else ():  # its own leader line must not cross a label
        nearest = np.clip(point, corners[j], corners[j] + [w, h])
        if np.linalg.norm(nearest - point) > LEADER_MIN_PX and occupied.size:
            samples = _segment_samples(point, nearest)[1:-1]
            labels_only = occupied[np.any(occupied[:, 2:] - occupied[:, :2] > 2 * MARKER_HALF_PX, axis=1)]
            ok[j] = not _inside_any(samples, labels_only).any() if labels_only.size else True
    return ok


def _free_spot(point: np.ndarray, w: float, h: float, *, inner: np.ndarray, taken: list, angles: np.ndarray,
               leaders: np.ndarray):
    """Lower-left corner (display pixels) of a free w x h box near `point`: on the rings around it,
    the box's corner or edge middle facing the point set at the ring; else the free grid position
    of the axes nearest to the point; else beside the point (`_free` says what is free)."""
    clearance = {"point": point, "size": (w, h), "inner": inner, "occupied": np.array(taken).reshape(-1, 4),
                 "leaders": leaders}
    cos, sin = np.cos(angles), np.sin(angles)
    for radius in LABEL_RADII_PX:
        # the box sits beyond the ring in direction (cos, sin): its facing side at the ring
        anchor = point + radius * np.stack([cos, sin], axis=1)
        corners = anchor - np.stack([w * (1 - np.clip(cos * 2, -1, 1)) / 2, h * (1 - np.clip(sin * 2, -1, 1)) / 2],
                                    axis=1)
        ok = _free(corners, **clearance)
        if ok.any():
            return corners[int(np.argmax(ok))]
    xs = np.arange(inner[0], inner[2] - w, FALLBACK_STEP_PX)
    ys = np.arange(inner[1], inner[3] - h, FALLBACK_STEP_PX)
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    for leaders_clear in (True, False):  # a crossed leader line is legible; overlapping text is not
        ok = _free(grid, leaders_clear=leaders_clear, **clearance) if grid.size else np.zeros(0, bool)
        if ok.any():
            candidates = grid[ok]
            centre_distance = np.linalg.norm(candidates + [w / 2, h / 2] - point, axis=1)
            return candidates[int(np.argmin(centre_distance))]
    log.warning("no free place for a label of %.0f x %.0f px; it may overlap", w, h)
    return point + LABEL_RADII_PX[0]
