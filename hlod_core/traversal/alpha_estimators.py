"""Estimators of alpha, the pixels a node's box covers with nothing in front (docs/how-it-works.md#alpha-three-ways),
besides the exact `query` count that the renderer measures: `cube` (the 2006 paper's cube of equal volume,
vectorised over nodes) and `projected` (the box's silhouette clipped to the viewport: the summed
area of its back faces' projections, vectorised over nodes).

Papers (docs/how-it-works.md#papers): the VMSSE `SSE * P(q/alpha)` and the cube estimate of alpha
come from J. P. Charalambos, "Coherent Hierarchical Level-of-Detail (HLOD) Refinement Through
Hardware Occlusion Queries", SIACG 2006 (section 4); the bias `P_{s,t}` from J. P. Charalambos,
J. Bittner, M. Wimmer, E. Romero, "Optimized HLOD Refinement Driven by Hardware Occlusion
Queries", ISVC 2007 (section 3).
"""
from __future__ import annotations

import numpy as np

from ..model.view import View
from .boxes import box_corners

#: Clip-space w below this magnitude is replaced by it before the perspective divide (a point on
#: the eye plane; the near-plane clip keeps such points out, this only guards the division).
_MIN_CLIP_W = 1e-300


def alpha_cube(view: View, cube_side: np.ndarray, *, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """2006 paper §4.3: a cube with the box's volume, one face seen head-on at the distance d of
    the box centre; alpha = f_hat (d_hat / d)^2 with f_hat d_hat^2 = side^2 * (W/2 P00)(H/2 P11),
    which depends only on the side and the projection. Orthographic: the face's pixel area.
    The eye at the centre (d = 0) gives +inf; callers clamp q/alpha to [0, 1]."""
    face_pixels_at_unit = cube_side ** 2 * view.pixels_per_unit_x * view.pixels_per_unit_y
    if view.orthographic:
        return face_pixels_at_unit
    d = np.linalg.norm(0.5 * (box_min + box_max) - view.eye, axis=1)
    out = np.full(d.shape, np.inf)
    ahead = d > 0
    with np.errstate(over="ignore", under="ignore"):  # d tiny: inf, which clamps mu to its floor
        out[ahead] = np.broadcast_to(face_pixels_at_unit, d.shape)[ahead] / d[ahead] ** 2
    return out


#: The six faces of a box as corner indices (box_corners' numbering), counter-clockwise seen from
#: outside: a face turned to the eye projects counter-clockwise (positive area, GL's front face).
BOX_FACES = np.array([[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]])
#: Clip-space half-spaces kept, as rows r with r . (x, y, z, w) >= 0: near, left, right, bottom,
#: top. The far plane is not clipped (a box beyond it still covers its pixels in the estimate).
_CLIP_PLANES = np.array([[0, 0, 1, 1], [1, 0, 0, 1], [-1, 0, 0, 1], [0, 1, 0, 1], [0, -1, 0, 1]], np.float64)


def alpha_projected(view: View, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray | float:
    """Pixels covered by boxes' silhouettes in the viewport, vectorised over boxes: (n,3) bounds
    give (n,) float64; (3,) bounds give a float.

    A ray from the eye through the silhouette of a convex body leaves it exactly once, through a
    face turned away from the eye; so the silhouette's area is the summed area of the back faces'
    projections. Each face is clipped in clip space (Sutherland-Hodgman, all faces at once) to the
    near plane and the viewport's four sides, projected, and its signed area taken; back faces
    project clockwise. The near plane's cut through the box faces the eye, so back faces alone
    stay exact for a box crossing the near plane or holding the eye (the whole viewport)."""
    lo, hi = np.asarray(box_min, np.float64), np.asarray(box_max, np.float64)
    single = lo.ndim == 1
    lo, hi = np.atleast_2d(lo), np.atleast_2d(hi)
    corners = box_corners(lo[:, None, :], hi[:, None, :])  # (n,8,3)
    clip = np.c_[corners.reshape(-1, 3), np.ones(corners.shape[0] * 8)] @ (view.projection @ view.view).T
    polys = clip.reshape(-1, 8, 4)[:, BOX_FACES].reshape(-1, 4, 4)  # (6n, 4 vertices, xyzw)
    count = np.full(len(polys), 4)
    for plane in _CLIP_PLANES:
        polys, count = _clip_polygons(polys, count, plane)
    w = polys[..., 3]
    w = np.where(np.abs(w) < _MIN_CLIP_W, _MIN_CLIP_W, w)
    xy = (polys[..., :2] / w[..., None] * 0.5 + 0.5) * [view.width, view.height]
    x, y = xy[..., 0], xy[..., 1]
    signed = 0.5 * np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    back = np.where(count >= 3, np.maximum(-signed, 0.0), 0.0).reshape(-1, 6).sum(axis=1)
    return float(back[0]) if single else back


def _clip_polygons(polys: np.ndarray, count: np.ndarray, plane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One Sutherland-Hodgman pass over (m,k,4) convex polygons with count (m,) vertices each,
    keeping plane . v >= 0; only polygons with a vertex outside are cut. Out: (m,k',4) polygons and
    their counts; slots past a polygon's count repeat its first vertex (they add nothing to a
    shoelace sum)."""
    d = polys @ plane
    slot = np.arange(polys.shape[1])
    used = slot[None, :] < count[:, None]
    cut_rows = np.flatnonzero(np.any(used & (d < 0), axis=1))
    if cut_rows.size == 0:
        return polys, count
    part, part_count = polys[cut_rows], count[cut_rows]
    d, used = d[cut_rows], used[cut_rows]
    m, k = part.shape[:2]
    nxt = np.where(slot[None, :] + 1 < part_count[:, None], slot[None, :] + 1, 0)
    d_next = np.take_along_axis(d, nxt, axis=1)
    inside, inside_next = d >= 0, d_next >= 0
    crossing = used & (inside != inside_next)
    denom = np.where(crossing, d - d_next, 1.0)
    t = np.where(crossing, d / denom, 0.0)
    cut = part + t[..., None] * (np.take_along_axis(part, nxt[..., None], axis=1) - part)
    both = np.stack([part, cut], axis=2).reshape(m, 2 * k, 4)  # vertex j, then the cut of edge j
    keep = np.stack([used & inside, crossing], axis=2).reshape(m, 2 * k)
    order = np.argsort(~keep, axis=1, kind="stable")[:, :k + 1]
    part_count = keep.sum(axis=1)
    part = np.take_along_axis(both, order[..., None], axis=1)
    part = np.where((np.arange(k + 1)[None, :] >= part_count[:, None])[..., None], part[:, :1], part)
    out = np.concatenate([polys, polys[:, :1]], axis=1)  # one slot more, the first vertex repeated
    out[cut_rows] = part
    count = count.copy()
    count[cut_rows] = part_count
    return out, count
