"""Estimators of alpha, the pixels a node's box covers with nothing in front (DESIGN §5.3), besides
the exact `query` count that the renderer measures: `cube` (the 2006 paper's cube of equal volume,
vectorised over nodes) and `projected` (the box's silhouette, clipped to the viewport, one box).

Papers: the VMSSE `SSE * P(q/alpha)` and the cube estimate of alpha come from Charalambos,
"Coherent hierarchical level-of-detail (HLOD) refinement through hardware occlusion queries"
(SIACG 2006, `../shared/papers/charalambos2006-coherent-hlod-refinement-hoq.txt` §4); the bias
`P_{s,t}` from Charalambos, Bittner, Wimmer, Romero, "Optimized HLOD refinement driven by hardware
occlusion queries" (ISVC 2007, `...2007-optimized-hlod-refinement.txt` §3).
"""
from __future__ import annotations

import numpy as np

from .boxes import BOX_EDGES, box_corners
from .polygon import clip_to_rectangle, convex_hull, polygon_area
from .view import View

#: Clip-space w below this magnitude is replaced by it before the perspective divide (a point on
#: the eye plane; the near-plane clip keeps such points out, this only guards the division).
_MIN_CLIP_W = 1e-300


def alpha_cube(view: View, cube_side: np.ndarray, box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
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


def alpha_projected(view: View, box_min: np.ndarray, box_max: np.ndarray) -> float:
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
