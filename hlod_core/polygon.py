"""Plane polygons for the projected alpha estimator: the convex hull of points, clipping to a
rectangle (the viewport), and the area. Data form: (k,2) float64 vertices in pixels, in order.
"""
from __future__ import annotations

import numpy as np


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
