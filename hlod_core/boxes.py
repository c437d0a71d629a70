"""Axis-aligned boxes against a view, vectorised over the node table (DESIGN §5.4, §6): frustum
planes, the frustum test, boxes crossing the near plane (not queryable), the eye-to-box distance
(the traversal's priority key), the eye inside a box, and box corners and edges.

Data form: a `view.View`; boxes as box_min, box_max (n,3) float64 model units; (n,) results.
`BoxRows` holds a node table's boxes as (3,n) rows, one contiguous row per axis, for the
traversal's per-frame `view_tests`: all of the frame's box tests with the frustum planes found
once and no reduction over a short axis (an (n,3) reduction over axis 1 costs about four
elementwise passes).
"""
from __future__ import annotations

from dataclasses import dataclass

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
    rows = p[3] + _ROW_SIGNS * p[_ROWS]  # P3 + P0, P3 - P0, P3 + P1, ...
    length = _row_lengths(rows[:, :3])
    at_infinity = length == 0.0
    if at_infinity.any():
        rows[at_infinity] = np.where(rows[at_infinity, 3:] > 0, _PLANE_EVERYWHERE, _PLANE_NOWHERE)
        length[at_infinity] = 1.0
    world = (rows / length[:, None]) @ view.view
    length = _row_lengths(world[:, :3])  # 1 for a rigid view matrix; kept for a scaled one
    return world / np.where(length > 0.0, length, 1.0)[:, None]


#: frustum_planes' rows of the projection and their signs, in the planes' order.
_ROWS, _ROW_SIGNS = np.array([0, 0, 1, 1, 2, 2]), np.array([[1.0], [-1.0], [1.0], [-1.0], [1.0], [-1.0]])


def _row_lengths(rows: np.ndarray) -> np.ndarray:
    """Euclidean length of each row of a small (m,3) array, as np.linalg.norm(axis=1) sums it."""
    return np.sqrt(np.add.reduce(rows * rows, axis=1))


def boxes_in_frustum(view: View, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) bool: the box is not entirely outside any frustum plane (conservative)."""
    return _in_frustum(frustum_planes(view), np.concatenate([box_max.T, box_min.T]))


#: Boxes per matrix product in `_in_frustum`: (6,6) @ (6,4096) stays below the 2^18 multiply-adds
#: from which OpenBLAS splits a matrix product over its threads. Their hand-off costs more than such
#: a product on a loaded machine (the rasteriser has threads too): a (6,) @ (6,3048) vector product,
#: which OpenBLAS splits from 9,216, made a frame's `view_tests` up to 1 ms slower (measured).
_PRODUCT_BOXES = 4096


def _in_frustum(planes: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """`boxes_in_frustum` of (6,4) planes and (6,n) corners, the rows of box_max over box_min."""
    normals = planes[:, :3]
    # the box corner farthest along each plane's normal ("p-vertex"), for every box and plane:
    # max on the axes where the normal is positive, min where it is negative, as one product of
    # the normal's two signed parts with the corners' rows (planes as rows, boxes along the fast
    # axis: the reduction over 6 planes runs on whole rows); inside all six: reach >= -d
    signed = np.concatenate([np.maximum(normals, 0.0), np.minimum(normals, 0.0)], axis=1)
    n = corners.shape[1]
    reach = signed @ corners if n <= _PRODUCT_BOXES else np.concatenate(
        [signed @ corners[:, i:i + _PRODUCT_BOXES] for i in range(0, n, _PRODUCT_BOXES)], axis=1)
    return np.all(reach >= -planes[:, 3:], axis=0)


def boxes_cross_near_plane(view: View, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) bool: part of the box lies on the eye's side of the near plane. The near plane clips
    such a box's front faces, so its occlusion query could see only (culled) back faces and read
    0 while the geometry inside is visible: these boxes must not be queried."""
    return _cross_near_plane(frustum_planes(view)[4], box_min.T, box_max.T)


def _cross_near_plane(plane: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """`boxes_cross_near_plane` of the (4,) near plane and (3,n) rows: the corner farthest behind
    the plane ("n-vertex", min where the normal is positive) is behind it, n . v < -d."""
    normal = plane[:3].tolist()
    reach = None
    for axis, component in enumerate(normal):
        term = (box_min if component >= 0 else box_max)[axis] * component
        reach = term if reach is None else np.add(reach, term, out=reach)
    return reach < -plane[3]


def box_distance(eye: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) distance from the eye to the nearest point of each box; 0 inside (priority key)."""
    return _box_distance(eye, box_min.T, box_max.T)


def _box_distance(eye: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """`box_distance` of (3,n) rows: |max(box_min - e, e - box_max, 0)|, the axes summed in order."""
    e = eye[:, None]
    gap = np.maximum(box_min - e, e - box_max)
    np.maximum(gap, 0.0, out=gap)
    gap *= gap
    squared = gap[0] + gap[1]
    squared += gap[2]
    return np.sqrt(squared, out=squared)


def eye_in_boxes(eye: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    return np.all((eye >= box_min) & (eye <= box_max), axis=-1)


@dataclass(frozen=True, eq=False)
class BoxRows:
    """A node table's boxes as (3,n) float64 rows, model units, one contiguous row per axis, all
    views of one (12,n) array `rows`: box_max, box_min (rows 0-5, together the frustum test's
    `corners`), then query_min, query_max, the query boxes (the boxes enlarged by `query_pad`,
    model units); `view_tests` reads them each frame."""

    rows: np.ndarray
    query_pad: float

    @classmethod
    def of(cls, box_min: np.ndarray, box_max: np.ndarray, query_pad: float) -> "BoxRows":
        """From (n,3) bounds; the query boxes as the renderer draws them (box -+ query_pad)."""
        rows = np.concatenate([box_max.T, box_min.T, (box_min - query_pad).T, (box_max + query_pad).T])
        return cls(rows=np.ascontiguousarray(rows, np.float64), query_pad=query_pad)

    box_max = property(lambda self: self.rows[0:3])
    box_min = property(lambda self: self.rows[3:6])
    corners = property(lambda self: self.rows[0:6])
    query_min = property(lambda self: self.rows[6:9])
    query_max = property(lambda self: self.rows[9:12])


def view_tests(view: View, rows: BoxRows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The traversal's per-frame box tests of every node: in_frustum (n,) bool (`boxes_in_frustum`),
    distance (n,) float64 model units from the eye (`box_distance`, the priority key), unqueryable
    (n,) bool: the query box holds the eye or reaches in front of the near plane (`eye_in_boxes` |
    `boxes_cross_near_plane` of the query boxes; DESIGN §5.4 names the first case, the second has
    the same problem: the near plane clips the box's front faces)."""
    planes = frustum_planes(view)
    e = view.eye[:, None]
    eye_inside = np.all((rows.query_min <= e) & (e <= rows.query_max), axis=0)
    unqueryable = eye_inside | _cross_near_plane(planes[4], rows.query_min, rows.query_max)
    return _in_frustum(planes, rows.corners), _box_distance(view.eye, rows.box_min, rows.box_max), unqueryable


BOX_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                       [0, 4], [1, 5], [2, 6], [3, 7]])


def box_corners(box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(8,3) corners; corner c takes max on axis a when bit a of c is set. Broadcasts: boxes given
    as (n,1,3) give (n,8,3)."""
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    return np.where(bits == 1, box_max, box_min)
