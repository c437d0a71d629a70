"""Axis-aligned boxes against a view, vectorised over the node table (DESIGN §5.4, §6): frustum
planes, the frustum test, boxes crossing the near plane (not queryable), the eye-to-box distance
(the traversal's priority key), the eye inside a box, and box corners and edges.

Data form: a `view.View`; boxes as box_min, box_max (n,3) float64 model units; (n,) results.
"""
from __future__ import annotations

import numpy as np

from .view import View

#: A plane with no normal, (0, 0, 0, d): every point is inside when d > 0 (the far plane at
#: infinity), none when d <= 0.
_PLANE_EVERYWHERE, _PLANE_NOWHERE = np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, -1.0])


def frustum_planes(view: View) -> np.ndarray:
    """(6,4) float64 world planes (a, b, c, d) with unit normals, inside where
    a x + b y + c z + d >= 0; order left, right, bottom, top, near, far.

    Gribb & Hartmann's rows P3 +- Pi, taken from the projection alone (so they are view-space
    planes) and moved to world space with the view matrix, plane_world = plane_view @ V. In view
    space the near and far rows have no x and y terms, so their normals point exactly along the
    view axis however much P3 - P2 cancels; rows of P @ V would mix that rounding into every
    component. When far/near exceeds about 1e16, P[2][2] rounds to -1 (the matrix is an infinite
    far projection) and the far row's normal is exactly zero: that plane lies at infinity and
    keeps every point in front, instead of a 0/0 that culls everything."""
    p = view.projection
    rows = np.array([p[3] + p[0], p[3] - p[0], p[3] + p[1], p[3] - p[1], p[3] + p[2], p[3] - p[2]])
    length = np.linalg.norm(rows[:, :3], axis=1)
    at_infinity = length == 0.0
    rows[at_infinity] = np.where(rows[at_infinity, 3:] > 0, _PLANE_EVERYWHERE, _PLANE_NOWHERE)
    length[at_infinity] = 1.0
    world = (rows / length[:, None]) @ view.view
    length = np.linalg.norm(world[:, :3], axis=1)  # 1 for a rigid view matrix; kept for a scaled one
    return world / np.where(length > 0.0, length, 1.0)[:, None]


def boxes_in_frustum(view: View, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) bool: the box is not entirely outside any frustum plane (conservative)."""
    planes = frustum_planes(view)
    normals = planes[:, :3]
    # the box corner farthest along each plane's normal ("p-vertex"), for every box and plane:
    # max on the axes where the normal is positive, min where it is negative, as two products
    # (planes as rows, boxes along the fast axis: the reduction over 6 planes runs on whole rows)
    reach = np.maximum(normals, 0.0) @ box_max.T + np.minimum(normals, 0.0) @ box_min.T
    return np.all(reach + planes[:, 3:] >= 0, axis=0)


def boxes_cross_near_plane(view: View, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) bool: part of the box lies on the eye's side of the near plane. The near plane clips
    such a box's front faces, so its occlusion query could see only (culled) back faces and read
    0 while the geometry inside is visible: these boxes must not be queried."""
    plane = frustum_planes(view)[4]
    n_vertex = np.where(plane[:3] >= 0, box_min, box_max)  # the corner farthest behind the plane
    return n_vertex @ plane[:3] + plane[3] < 0


def box_distance(eye: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) distance from the eye to the nearest point of each box; 0 inside (priority key)."""
    return np.linalg.norm(np.maximum(np.maximum(box_min - eye, eye - box_max), 0.0), axis=1)


def eye_in_boxes(eye: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    return np.all((eye >= box_min) & (eye <= box_max), axis=-1)


BOX_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                       [0, 4], [1, 5], [2, 6], [3, 7]])


def box_corners(box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(8,3) corners; corner c takes max on axis a when bit a of c is set. Broadcasts: boxes given
    as (n,1,3) give (n,8,3)."""
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    return np.where(bits == 1, box_max, box_min)
