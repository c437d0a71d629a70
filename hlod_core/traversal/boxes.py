"""Axis-aligned boxes against a view, vectorised over the node table (docs/how-it-works.md#query-boxes): frustum
planes, the frustum test, boxes crossing the near plane (not queryable), the eye-to-box distance
(the traversal's priority key), the eye inside a box, and box corners and edges.

Data form: a `view.View`; boxes as box_min, box_max (n,3) float64 model units; (n,) results.
`BoxRows` holds a node table's boxes (and centres) as rows, one contiguous row per axis, for the
traversal's per-frame `view_tests`: all of the frame's box tests in a dozen whole-table numpy
calls, with the frustum planes found once in plain Python and no reduction over a short axis (an
(n,3) reduction over axis 1 costs about four elementwise passes).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..model.view import View


def frustum_planes(view: View) -> np.ndarray:
    """(6,4) float64 world planes (a, b, c, d) with unit normals, inside where
    a x + b y + c z + d >= 0; order left, right, bottom, top, near, far (`_frustum_plane_rows`)."""
    return np.array(_frustum_plane_rows(view))


def _frustum_plane_rows(view: View) -> list[list[float]]:
    """`frustum_planes` as six Python lists of four floats (plain Python: cheaper than numpy on
    (6,4) arrays): Gribb & Hartmann's rows P3 +- Pi of the projection, moved to world space with
    the view matrix; a plane at infinity (far/near above about 1e16) keeps every point in front.
    Why: docs/how-it-works.md#frustum-planes"""
    p, v = view.projection.tolist(), view.view.tolist()
    p3, planes = p[3], []
    for axis, sign in _PLANE_ROWS:
        pi = p[axis]
        a, b, c, d = (p3[j] + sign * pi[j] for j in range(4))
        length = math.sqrt(a * a + b * b + c * c)
        if length == 0.0:  # a plane at infinity: everything inside (d > 0) or nothing
            a, b, c, d, length = 0.0, 0.0, 0.0, 1.0 if d > 0 else -1.0, 1.0
        a, b, c, d = a / length, b / length, c / length, d / length
        world = [a * v[0][j] + b * v[1][j] + c * v[2][j] + d * v[3][j] for j in range(4)]
        length = math.sqrt(world[0] * world[0] + world[1] * world[1] + world[2] * world[2])
        if length > 0.0:  # 1 for a rigid view matrix; kept for a scaled one
            world = [x / length for x in world]
        planes.append(world)
    return planes


#: frustum_planes' (row of the projection, sign), in the planes' order.
_PLANE_ROWS = ((0, 1.0), (0, -1.0), (1, 1.0), (1, -1.0), (2, 1.0), (2, -1.0))
#: The index of the near plane in frustum_planes.
NEAR = 4


def boxes_in_frustum(view: View, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) bool: the box is not entirely outside any frustum plane (conservative)."""
    return view_tests(view, BoxRows.of(box_min, box_max, query_pad=0.0, centre=box_min)).in_frustum  # centres unused


def boxes_cross_near_plane(view: View, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) bool: part of the box lies on the eye's side of the near plane. The near plane clips
    such a box's front faces, so its occlusion query could see only (culled) back faces and read
    0 while the geometry inside is visible: these boxes must not be queried."""
    return view_tests(view, BoxRows.of(box_min, box_max, query_pad=0.0, centre=box_min)).behind_near  # centres unused


def box_distance(eye: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(n,) distance from the eye to the nearest point of each box; 0 inside (priority key):
    |max(box_min - e, e - box_max, 0)|, the axes summed in order."""
    e = np.asarray(eye, np.float64)
    gap = np.maximum(np.asarray(box_min, np.float64) - e, e - np.asarray(box_max, np.float64))
    np.maximum(gap, 0.0, out=gap)
    gap *= gap
    return np.sqrt(np.add.reduce(gap.T, axis=0))


def eye_in_boxes(eye: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    return np.all((eye >= box_min) & (eye <= box_max), axis=-1)


#: BoxRows' row blocks, three rows (x, y, z) each, in order: the centres (sphere centres, or the
#: boxes' own), box_min, box_max.
_CENTRE, _MIN, _MAX = slice(0, 3), slice(3, 6), slice(6, 9)
#: Boxes per matrix product in `view_tests`: (7,6) @ (6,4096) stays below the 2^18 multiply-adds
#: from which OpenBLAS splits a matrix product over its threads. Their hand-off costs more than such
#: a product on a loaded machine (the rasteriser has threads too): a (6,) @ (6,3048) vector product,
#: which OpenBLAS splits from 9,216, made a frame's `view_tests` up to 1 ms slower (measured).
PRODUCT_BOXES = 4096


@dataclass(frozen=True, eq=False)
class BoxRows:
    """A node table's boxes as (9,n) float64 rows `rows`, model units, one contiguous row per axis
    and block (`_CENTRE`, `_MIN`, `_MAX`): the centres (the nodes' sphere centres, for the SSE's
    distance, or the boxes' own), box_min, box_max; `query_pad`, model units the renderer enlarges
    the query boxes by. `view_tests` reads them each frame; `scratch` is its (9,n) offsets from the
    eye, reused."""

    rows: np.ndarray
    query_pad: float
    scratch: np.ndarray

    @classmethod
    def of(cls, box_min: np.ndarray, box_max: np.ndarray, *, query_pad: float,
           centre: np.ndarray | None = None) -> "BoxRows":
        """From (n,3) bounds and, optionally, (n,3) centres (default: the boxes' centres)."""
        box_min, box_max = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
        centre = 0.5 * (box_min + box_max) if centre is None else np.asarray(centre, np.float64)
        rows = np.ascontiguousarray(np.concatenate([centre.T, box_min.T, box_max.T]), np.float64)
        return cls(rows=rows, query_pad=float(query_pad), scratch=np.empty_like(rows))

    centre = property(lambda self: self.rows[_CENTRE])
    box_min = property(lambda self: self.rows[_MIN])
    box_max = property(lambda self: self.rows[_MAX])


class ViewTests(NamedTuple):
    """`view_tests`' (n,) results."""

    in_frustum: np.ndarray       # bool: not entirely outside any frustum plane
    distance: np.ndarray         # float64 model units, eye to the box's nearest point (the priority key)
    unqueryable: np.ndarray      # bool: the query box holds the eye or reaches in front of the near plane
    centre_distance: np.ndarray  # float64 model units, eye to the centre
    behind_near: np.ndarray      # bool: the query box reaches in front of the near plane


def view_tests(view: View, rows: BoxRows) -> ViewTests:
    """The traversal's per-frame tests of every node's box (`ViewTests`, (n,) each) in a dozen
    whole-table numpy calls: in the frustum (the p-vertex inside every plane), behind the near plane
    (the padded box's n-vertex), the distances from the eye, and unqueryable = the eye inside the
    padded box | behind the near plane. Why: docs/how-it-works.md#the-frames-box-tests-in-one-pass"""
    planes = _frustum_plane_rows(view)
    pad = rows.query_pad
    product = [[min(a, 0.0), min(b, 0.0), min(c, 0.0), max(a, 0.0), max(b, 0.0), max(c, 0.0)] for a, b, c, _ in planes]
    a, b, c, d = planes[NEAR]
    product.append([max(a, 0.0), max(b, 0.0), max(c, 0.0), min(a, 0.0), min(b, 0.0), min(c, 0.0)])
    boxes = rows.rows[3:]
    n = boxes.shape[1]
    product = np.array(product)
    reach = product @ boxes if n <= PRODUCT_BOXES else np.concatenate(
        [product @ boxes[:, i:i + PRODUCT_BOXES] for i in range(0, n, PRODUCT_BOXES)], axis=1)
    in_frustum = np.all(reach[:6] >= np.array([[-plane[3]] for plane in planes]), axis=0)
    behind_near = reach[6] < -d + pad * (abs(a) + abs(b) + abs(c))
    eye = view.eye[:, None]
    offsets = rows.scratch
    np.subtract(rows.rows[:6], np.concatenate([eye, eye]), out=offsets[:6])  # centre - e, box_min - e
    gap = offsets[_MIN]
    np.maximum(gap, np.subtract(eye, rows.rows[_MAX], out=offsets[_MAX]), out=gap)
    eye_inside = np.all(gap <= pad, axis=0)
    np.maximum(gap, 0.0, out=gap)
    squares = offsets[:6]
    np.multiply(squares, squares, out=squares)
    lengths = np.add.reduce(squares.reshape(2, 3, n), axis=1)
    np.sqrt(lengths, out=lengths)
    return ViewTests(in_frustum, lengths[1], eye_inside | behind_near, lengths[0], behind_near)


BOX_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                       [0, 4], [1, 5], [2, 6], [3, 7]])


def box_corners(box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(8,3) corners; corner c takes max on axis a when bit a of c is set. Broadcasts: boxes given
    as (n,1,3) give (n,8,3)."""
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    return np.where(bits == 1, box_max, box_min)
