"""Runtime metrics of DESIGN §5, vectorised over the node table.

Papers: the VMSSE `SSE * P(q/alpha)` and the cube estimate of alpha come from Charalambos,
"Coherent hierarchical level-of-detail (HLOD) refinement through hardware occlusion queries"
(SIACG 2006, `../shared/papers/charalambos2006-coherent-hlod-refinement-hoq.txt` §4); the bias
`P_{s,t}` from Charalambos, Bittner, Wimmer, Romero, "Optimized HLOD refinement driven by hardware
occlusion queries" (ISVC 2007, `...2007-optimized-hlod-refinement.txt` §3).

Data form: a `View` (camera in float64: eye, view and projection matrices, viewport in pixels)
and per-node arrays of the `hierarchy.Hlod` table; every function returns (n,) arrays.
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np


@dataclass(frozen=True, eq=False)
class View:
    """eye (3,) float64 world; view (4,4) and projection (4,4) float64 (OpenGL conventions,
    column vectors: clip = projection @ view @ world); width/height: viewport in pixels."""

    eye: np.ndarray
    view: np.ndarray
    projection: np.ndarray
    width: int
    height: int

    @property
    def orthographic(self) -> bool:
        return bool(self.projection[3, 3] == 1.0 and self.projection[3, 2] == 0.0)

    @property
    def pixels_per_unit_y(self) -> float:
        """(H/2) * P[1][1]: pixels per model unit at distance 1 (perspective) or anywhere (ortho)."""
        return 0.5 * self.height * float(self.projection[1, 1])

    @property
    def pixels_per_unit_x(self) -> float:
        return 0.5 * self.width * float(self.projection[0, 0])


def look_at(eye, target, up) -> np.ndarray:
    """OpenGL view matrix (4,4) float64."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    norm = np.linalg.norm(s)
    if norm < 1e-12:  # up parallel to the view direction: pick any perpendicular
        s = np.cross(f, [1.0, 0.0, 0.0] if abs(f[0]) < 0.9 else [0.0, 1.0, 0.0])
        norm = np.linalg.norm(s)
    s /= norm
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fovy_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    f = 1.0 / np.tan(np.radians(fovy_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = (far + near) / (near - far), 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(height: float, aspect: float, near: float, far: float) -> np.ndarray:
    """`height`: model units visible vertically."""
    m = np.eye(4)
    m[0, 0], m[1, 1] = 2.0 / (height * aspect), 2.0 / height
    m[2, 2], m[2, 3] = -2.0 / (far - near), -(far + near) / (far - near)
    return m


# --- SSE (DESIGN §5.1) --------------------------------------------------------------------------

def sphere_distance(view: View, center: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """d = |e - c| - r (n,), model units; <= 0 when the eye is inside the sphere."""
    return np.linalg.norm(center - view.eye, axis=1) - radius


def sse(view: View, error: np.ndarray, center: np.ndarray, radius: np.ndarray, is_leaf: np.ndarray) -> np.ndarray:
    """Screen-space error in pixels (n,): a sphere of diameter MSE at the point of the node's
    sphere nearest the eye. Perspective: MSE * (H/2) P11 / d; orthographic: MSE * (H/2) P11.
    d <= 0 (eye inside the sphere): +inf, the node must refine. Leaves: 0 (never 0 * inf)."""
    if view.orthographic:
        out = error * view.pixels_per_unit_y
    else:
        d = sphere_distance(view, center, radius)
        out = np.full(error.shape, np.inf)
        ahead = d > 0
        with np.errstate(over="ignore"):  # d tiny but positive: a huge finite or inf SSE, both refine
            out[ahead] = error[ahead] * view.pixels_per_unit_y / d[ahead]
    out[is_leaf] = 0.0
    return out


# --- the bias P_{s,t} (DESIGN §5.2) -------------------------------------------------------------

#: Below this k the normalised logistic is computed as its k -> 0 limit, mu itself (the
#: difference of two logistics then cancels catastrophically).
_K_LINEAR = 1e-6


def logistic(x: np.ndarray) -> np.ndarray:
    """L(x) = 1 / (1 + exp(-x)) as (1 + tanh(x/2)) / 2: no overflow for any finite or infinite x."""
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x, np.float64)))


def sigmoid_step(mu, t: float, k: float = np.inf) -> np.ndarray:
    """S_t(mu): the normalised logistic with turnover t and steepness k, or for k = inf the step
    [mu >= t] with S(0) = 0 and S(1) = 1. mu is clamped to [0, 1]."""
    mu = np.clip(np.asarray(mu, np.float64), 0.0, 1.0)
    if k <= 0 or np.isnan(k):
        raise ValueError(f"steepness k must be > 0, got {k}")
    if np.isinf(k):
        out = (mu >= t).astype(np.float64)
    elif k < _K_LINEAR:
        out = mu.copy()
    else:
        lo = logistic(-k * t)
        den = logistic(k * (1.0 - t)) - lo
        out = (logistic(k * (mu - t)) - lo) / den
    out = np.where(mu <= 0.0, 0.0, np.where(mu >= 1.0, 1.0, out))
    return np.clip(out, 0.0, 1.0)


def bias(mu, s: float, t: float, k: float = np.inf) -> np.ndarray:
    """P_{s,t}(mu) = (1 - s) mu + s S_t(mu); P(0) = 0 and P(1) = 1 exactly; s = 0 gives mu.

    Regions (the papers' aggressive/conservative split): for the step, P <= mu below t and P >= mu
    from t on, exactly. For finite k the same holds outside the band |mu - t| < band_half_width(k)
    (tests check k = 10 .. 1e9 on a grid)."""
    if not (0.0 <= s <= 1.0 and 0.0 <= t <= 1.0):
        raise ValueError(f"s and t must lie in [0, 1], got s={s}, t={t}")
    mu = np.clip(np.asarray(mu, np.float64), 0.0, 1.0)
    p = (1.0 - s) * mu + s * sigmoid_step(mu, t, k)
    p = np.where(mu <= 0.0, 0.0, np.where(mu >= 1.0, 1.0, p))
    return np.clip(p, 0.0, 1.0)


def bias_scalar(mu: float, s: float, t: float, k: float = math.inf) -> float:
    """`bias` for one float, in plain Python (the traversal calls it per node; a numpy call per
    scalar costs more than the arithmetic). Same values as `bias` (tests compare them on a grid);
    s, t, k are not validated here (RuntimeSettings does it once); NaN mu counts as 0."""
    if not mu > 0.0:
        return 0.0
    if mu >= 1.0:
        return 1.0
    if math.isinf(k):
        step = 1.0 if mu >= t else 0.0
    elif k < _K_LINEAR:
        step = mu
    else:
        lo = 0.5 * (1.0 + math.tanh(-0.5 * k * t))
        den = 0.5 * (1.0 + math.tanh(0.5 * k * (1.0 - t))) - lo
        step = min(1.0, max(0.0, (0.5 * (1.0 + math.tanh(0.5 * k * (mu - t))) - lo) / den))
    return min(1.0, max(0.0, (1.0 - s) * mu + s * step))


def band_half_width(k: float) -> float:
    """Half-width of the band around t where a finite-k logistic may cross the identity."""
    return 0.0 if np.isinf(k) else 2.0 * max(10.0, float(np.log(k))) / k


def modulation(p: np.ndarray) -> np.ndarray:
    """m = 1 - P: how strongly occlusion lowered the node's error (overlay: 0 blue, 0.5 magenta, 1 red)."""
    return 1.0 - np.asarray(p, np.float64)


def modulation_colour(m: np.ndarray) -> np.ndarray:
    """(n,3) float32 RGB ramp blue (m=0) -> magenta (0.5) -> red (1)."""
    m = np.clip(np.asarray(m, np.float64), 0.0, 1.0)[..., None]
    blue, magenta, red = np.array([0.1, 0.2, 1.0]), np.array([0.9, 0.1, 0.9]), np.array([1.0, 0.1, 0.05])
    lower = blue + (magenta - blue) * (m / 0.5)
    upper = magenta + (red - magenta) * ((m - 0.5) / 0.5)
    return np.where(m <= 0.5, lower, upper).astype(np.float32)


# --- frustum and distances -----------------------------------------------------------------------

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
    # the box corner farthest along each plane's normal ("p-vertex"), for every box and plane
    p_vertex = np.where(normals[None] >= 0, box_max[:, None, :], box_min[:, None, :])
    return np.all(np.einsum("npk,pk->np", p_vertex, normals) + planes[None, :, 3] >= 0, axis=1)


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


# --- alpha, the unoccluded pixel count of a box (DESIGN §5.3) ----------------------------------

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


BOX_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7],
                       [0, 4], [1, 5], [2, 6], [3, 7]])


def box_corners(box_min: np.ndarray, box_max: np.ndarray) -> np.ndarray:
    """(8,3) corners; corner c takes max on axis a when bit a of c is set. Broadcasts: boxes given
    as (n,1,3) give (n,8,3)."""
    bits = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1
    return np.where(bits == 1, box_max, box_min)


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
    w = np.where(np.abs(pts[:, 3]) < 1e-300, 1e-300, pts[:, 3])
    xy = (pts[:, :2] / w[:, None] * 0.5 + 0.5) * [view.width, view.height]
    hull = _convex_hull(xy)
    poly = _clip_polygon(hull, 0.0, 0.0, float(view.width), float(view.height))
    return _polygon_area(poly)


def _convex_hull(p: np.ndarray) -> np.ndarray:
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


def _clip_polygon(poly: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
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


def _polygon_area(poly: np.ndarray) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
