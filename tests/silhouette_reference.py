"""An independent reference for the vectorised `projected` alpha estimator (hlod_core.traversal.alpha_estimators):
one box at a time, its corners in front of the near plane and its edges' crossings of that plane
projected, their convex hull clipped to the viewport, the hull's area. (This was the product's own
estimator before it was vectorised; tests compare the two.) Polygons are (k,2) float64 pixels.
"""
from __future__ import annotations

import numpy as np

from hlod_core.model.view import View
from hlod_core.traversal.boxes import BOX_EDGES, box_corners

_MIN_CLIP_W = 1e-300


def convex_hull(p: np.ndarray) -> np.ndarray:
    """Andrew's monotone chain: the hull of (k,2) points, counter-clockwise, no repeated point."""
    p = np.unique(p, axis=0)
    if len(p) < 3:
        return p

    def half(points):
        out = []
        for q in points:
            while len(out) >= 2 and _cross_2d(out[-1] - out[-2], q - out[-2]) <= 0:
                out.pop()
            out.append(q)
        return out

    lower, upper = half(p), half(p[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _cross_2d(a: np.ndarray, b: np.ndarray) -> float:
    """z of the cross product of two 2-D vectors (numpy 2 refuses np.cross on 2-D vectors)."""
    return float(a[0] * b[1] - a[1] * b[0])


def clip_to_rectangle(poly: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """Sutherland-Hodgman against the viewport rectangle."""
    for axis, bound, keep_above in ((0, x0, True), (0, x1, False), (1, y0, True), (1, y1, False)):
        if len(poly) == 0:
            break
        out = []
        for i in range(len(poly)):
            a, b = poly[i - 1], poly[i]
            a_in = a[axis] >= bound if keep_above else a[axis] <= bound
            b_in = b[axis] >= bound if keep_above else b[axis] <= bound
            if b_in:
                if not a_in:
                    out.append(a + (b - a) * ((bound - a[axis]) / (b[axis] - a[axis])))
                out.append(b)
            elif a_in:
                out.append(a + (b - a) * ((bound - a[axis]) / (b[axis] - a[axis])))
        poly = np.array(out)
    return poly


def polygon_area(poly: np.ndarray) -> float:
    """Shoelace formula: the area of a simple polygon (k,2), 0 for fewer than 3 vertices."""
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def silhouette_pixels(view: View, box_min: np.ndarray, box_max: np.ndarray) -> float:
    """Pixels covered by one box's silhouette: corners (and edge crossings of the near plane)
    in front of the near plane, projected, convex hull, clipped to the viewport. One box."""
    corners = box_corners(box_min, box_max)
    clip = (view.projection @ view.view @ np.c_[corners, np.ones(8)].T).T
    near = clip[:, 2] + clip[:, 3]  # >= 0 in front of the near plane
    pts = [clip[i] for i in range(8) if near[i] >= 0]
    for a, b in BOX_EDGES:
        if (near[a] >= 0) != (near[b] >= 0):
            u = near[a] / (near[a] - near[b])
            pts.append(clip[a] + u * (clip[b] - clip[a]))
    if len(pts) < 3:
        return 0.0
    pts = np.array(pts)
    w = np.where(np.abs(pts[:, 3]) < _MIN_CLIP_W, _MIN_CLIP_W, pts[:, 3])
    xy = (pts[:, :2] / w[:, None] * 0.5 + 0.5) * [view.width, view.height]
    hull = convex_hull(xy)
    poly = clip_to_rectangle(hull, 0.0, 0.0, float(view.width), float(view.height))
    return polygon_area(poly)
