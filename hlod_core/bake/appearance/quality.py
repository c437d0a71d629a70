"""The proxy material's quality gate: a node's proxy and its sources rendered from the distance at
which the node first shows, compared as PSNR of luma Y (pure numpy: it runs in bake workers).

Data form: surface_colour.Surface in; a `Render` out: (h,w,3) float32 linear RGB, row 0 the bottom,
and its (h,w) bool coverage. The view is orthographic along -direction onto the sphere (center,
radius): pixel (i, j) has its centre at center + right (-radius + (j + 0.5) pixel_size) + up
(-radius + (i + 0.5) pixel_size). Triangles are rasterised by core/cpu_raster.py (both facings,
pixel centres inside, vectorised over the triangles' bounding boxes; a centre on a shared edge is
drawn by one of its triangles, as GL's fill rule does), z-buffered, and each pixel
shows colour_at at its face and barycentric point with footprint = pixel_size, unlit (the gate
compares what the surfaces show, not their shading). MASK fragments below their cutoff are not
drawn; BLEND fragments are composited front to back over the nearest opaque surface (or the
background) behind them, and count as coverage where their total opacity is at least 1/2.

Why the pixel size is error / tau: a node is drawn once its error projects under tau pixels, so at
the distance where it first shows (d_n = eps H / (2 tau tan(fov / 2))) a screen pixel spans
eps / tau model units (docs/how-it-works.md#sse).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...core.colour import srgb_from_linear, srgb_to_linear
from ...core.cpu_raster import covered
from .surface_colour import Surface, colour_at

#: A node whose proxy scores under this many dB is named in the bake log with its main cause.
GATE_DB = 25.0

#: PSNR given where the two renders agree exactly (the squared error is floored at 10^(-PSNR_CAP_DB / 10)),
#: so medians and means over nodes stay finite; the report's image error uses the same cap.
PSNR_CAP_DB = 100.0

#: Background behind both renders: mid-grey, sRGB 0.5 (linear 0.214).
BACKGROUND_SRGB = 0.5

#: BT.601 luma weights on sRGB-encoded R', G', B'.
LUMA = np.array([0.299, 0.587, 0.114])

#: The default view directions: 6 along the axes and the 8 cube diagonals.
DIRECTIONS = np.concatenate([np.vstack([np.eye(3), -np.eye(3)]),
                             np.array([[x, y, z] for x in (1, -1) for y in (1, -1) for z in (1, -1)]) / math.sqrt(3)])


@dataclass(frozen=True, eq=False)
class Render:
    """One view of a surface: rgb (h,w,3) float32 linear (the background where nothing shows),
    coverage (h,w) bool, pixel_size model units (larger than asked when the image would have been
    over max_side pixels across)."""

    rgb: np.ndarray
    coverage: np.ndarray
    pixel_size: float


def _basis(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, toward the viewer) orthonormal, for a view along -direction."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    helper = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(helper, d)
    right /= np.linalg.norm(right)
    return right, np.cross(d, right), d


def render(surface: Surface, *, direction: np.ndarray, center: np.ndarray, radius: float, pixel_size: float,
           max_side: int = 256, background: float = BACKGROUND_SRGB) -> Render:
    """`surface` seen along -direction (3,), orthographic, over the square of side 2 radius model
    units around `center` (3,), in pixels of side `pixel_size` model units (grown to 2 radius /
    max_side where more than max_side pixels would be needed); `background`: sRGB-encoded grey."""
    if not (radius > 0 and math.isfinite(radius)):
        raise ValueError(f"render: radius must be positive and finite, got {radius}")
    if not pixel_size > 0:  # also NaN
        raise ValueError(f"render: pixel_size must be positive, got {pixel_size}")
    side = int(math.ceil(2.0 * radius / pixel_size - 1e-9))
    if side > max_side:
        side, pixel_size = max_side, 2.0 * radius / max_side
    side = max(side, 1)
    rgb = np.full((side, side, 3), srgb_to_linear(np.full((1, 4), background))[0, 0], np.float32)
    coverage = np.zeros((side, side), bool)
    fragments = _fragments(surface, direction, center, radius, pixel_size, side)
    if fragments is None:
        return Render(rgb, coverage, pixel_size)
    pixel, depth, face, bary = fragments
    # what each fragment shows; OPAQUE faces only where they win the depth test (shading is the cost)
    mode = _alpha_mode(surface)[face]  # 0 OPAQUE, 1 MASK, 2 BLEND
    shaded = np.zeros((len(face), 4), np.float32)
    alpha_tested = np.flatnonzero(mode != 0)
    shaded[alpha_tested] = colour_at(surface, face[alpha_tested], bary[alpha_tested], footprint=pixel_size)
    drawn = (mode == 0) | ((mode == 1) & (shaded[:, 3] >= _cutoff(surface)[face]))
    solid = np.flatnonzero(drawn)
    order = solid[np.lexsort((depth[solid], pixel[solid]))]
    first = np.ones(len(order), bool)
    first[1:] = pixel[order[1:]] != pixel[order[:-1]]
    win = order[first]  # the nearest drawn fragment of each pixel
    opaque_win = win[mode[win] == 0]
    shaded[opaque_win] = colour_at(surface, face[opaque_win], bary[opaque_win], footprint=pixel_size)
    flat_rgb, flat_cov = rgb.reshape(-1, 3), coverage.reshape(-1)
    flat_rgb[pixel[win]] = shaded[win, :3]
    flat_cov[pixel[win]] = True
    nearest = np.full(side * side, np.inf)
    nearest[pixel[win]] = depth[win]
    blend = np.flatnonzero((mode == 2) & (depth < nearest[pixel]))
    if len(blend):
        _composite(flat_rgb, flat_cov, pixel[blend], depth[blend], shaded[blend])
    return Render(rgb, coverage, pixel_size)


def _alpha_mode(surface: Surface) -> np.ndarray:
    """(m,) int8 per face: 0 OPAQUE (or no material), 1 MASK, 2 BLEND."""
    if surface.face_material is None:
        return np.zeros(len(surface.faces), np.int8)
    code = np.array([("OPAQUE", "MASK", "BLEND").index(m.alpha_mode) for m in surface.materials], np.int8)
    return code[np.asarray(surface.face_material, np.int64)]


def _cutoff(surface: Surface) -> np.ndarray:
    """(m,) float32 per face: its material's alpha cutoff (0.5 without materials)."""
    if surface.face_material is None:
        return np.full(len(surface.faces), 0.5, np.float32)
    return np.array([m.alpha_cutoff for m in surface.materials], np.float32)[np.asarray(surface.face_material)]


def _fragments(surface, direction, center, radius, pixel_size, side):
    """Every fragment of `surface` in the view: (pixel (n,) int64 row * side + column, depth (n,)
    float64 smaller nearer, face (n,) int64, bary (n,3) float64), or None when there is none."""
    right, up, toward = _basis(direction)
    rel = np.asarray(surface.positions, np.float64) - np.asarray(center, np.float64)
    faces = np.asarray(surface.faces, np.int64)
    if not len(faces) or not len(rel):
        return None
    along = rel @ toward
    near, far = float(along.max()), float(along.min())
    span = near - far if near > far else 1.0
    window = np.empty((len(rel), 3))
    window[:, 0] = (rel @ right + radius) / pixel_size
    window[:, 1] = (rel @ up + radius) / pixel_size
    window[:, 2] = 0.05 + 0.9 * (near - along) / span  # window depth in [0.05, 0.95], nearer smaller
    triangles = window[faces]
    with np.errstate(invalid="ignore"):  # a degenerate triangle's depth plane is NaN; it covers nothing
        parts = list(covered(triangles, (side, side), front_only=False))
    if not parts:
        return None
    row, col, depth, face = (np.concatenate(p) for p in zip(*parts))
    px, py = col + 0.5, row + 0.5
    x, y = triangles[face, :, 0], triangles[face, :, 1]
    # cpu_raster's edge functions E_k = a_k px + b_k py + c_k (>= 0 inside, (a_k, b_k) the inward
    # normal), in its arithmetic so that E_k == 0 there exactly where it found the pixel on edge k
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    sign = np.sign(area)[:, None]
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    ea, eb = (y - yn) * sign, (xn - x) * sign
    edge = ea * px[:, None] + eb * py[:, None] - (ea * x + eb * y)
    # fill rule: a pixel centre on an edge belongs to the triangle it would enter if moved by
    # (1, tiny), so a shared edge is drawn once (no BLEND layer twice) whatever the windings
    owns = (ea > 0) | ((ea == 0) & (eb > 0))
    keep = np.all((edge > 0) | owns, axis=1)
    row, col, depth, face, px, py = row[keep], col[keep], depth[keep], face[keep], px[keep], py[keep]
    if not len(face):
        return None
    v = triangles[face, :, :2]
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    area = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # non-zero: covered drops degenerate triangles
    dx, dy = px - v[:, 0, 0], py - v[:, 0, 1]
    b1 = (dx * e2[:, 1] - dy * e2[:, 0]) / area
    b2 = (e1[:, 0] * dy - e1[:, 1] * dx) / area
    bary = np.clip(np.stack([1.0 - b1 - b2, b1, b2], axis=1), 0.0, 1.0)
    bary /= bary.sum(axis=1, keepdims=True)
    return row * side + col, depth, face, bary


def _composite(flat_rgb, flat_cov, pixel, depth, shaded) -> None:
    """Composite BLEND fragments (pixel, depth, shaded (n,4) straight RGBA) front to back over
    flat_rgb (p,3) in place; a pixel counts as covered where their total opacity is >= 1/2."""
    order = np.lexsort((depth, pixel))
    pixel, shaded = pixel[order], shaded[order]
    alpha = np.clip(shaded[:, 3].astype(np.float64), 0.0, 1.0)
    log_clear = np.log(np.maximum(1.0 - alpha, 1e-12))
    total = np.cumsum(log_clear)
    starts = np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]])
    group = np.cumsum(np.r_[True, pixel[1:] != pixel[:-1]]) - 1
    before = np.r_[0.0, total][starts][group]  # log transmittance up to each group's start
    clear_in_front = np.exp(total - log_clear - before)  # transmittance of the layers in front
    lit = np.zeros((len(starts), 3))
    np.add.at(lit, group, (clear_in_front * alpha)[:, None] * shaded[:, :3])
    pixels = pixel[starts]
    clear_all = np.exp(np.add.reduceat(log_clear, starts))
    flat_rgb[pixels] = (lit + clear_all[:, None] * flat_rgb[pixels]).astype(np.float32)
    flat_cov[pixels] |= clear_all <= 0.5


def _sphere(*surfaces: Surface) -> tuple[np.ndarray, float]:
    """(center (3,), radius) around every vertex of the surfaces (radius > 0: a point gets 1e-6)."""
    points = np.concatenate([np.asarray(s.positions, np.float64).reshape(-1, 3) for s in surfaces])
    if not len(points):
        return np.zeros(3), 1.0
    center = 0.5 * (points.min(axis=0) + points.max(axis=0))
    radius = float(np.sqrt(((points - center) ** 2).sum(axis=1).max()))
    return center, max(radius, 1e-6 * max(1.0, float(np.abs(center).max())))


def luma(rgb: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB -> (...) float64 BT.601 luma Y of the sRGB-encoded values, in [0, 1]."""
    return srgb_from_linear(np.asarray(rgb, np.float32)).astype(np.float64) @ LUMA


def node_psnr(proxy: Surface, sources: Surface, *, error: float, tau_px: float = 1.0, directions=None,
              max_side: int = 128) -> tuple[float, str | None]:
    """(PSNR-Y in dB, reason) of `proxy` against `sources`, both rendered over the mid-grey
    background from `directions` ((d,3); default DIRECTIONS, 14) in pixels of error / tau_px model
    units, at most max_side pixels across the sphere around both (a lossless node, error 0, is
    seen at max_side pixels). Y is BT.601 luma of sRGB-encoded values in [0, 1], peak 1; the
    squared differences of the pixels covered in either render are pooled over all directions;
    PSNR_CAP_DB where they agree. reason is None at GATE_DB or more, else the main cause: the part
    of the squared error from pixels only one render covers ("silhouette") or from pixels both
    cover ("colour"), whichever is larger."""
    center, radius = _sphere(proxy, sources)
    pixel_size = error / tau_px if error > 0 and tau_px > 0 and math.isfinite(error / tau_px) else 0.0
    pixel_size = max(pixel_size, 2.0 * radius / max_side)
    views = DIRECTIONS if directions is None else np.asarray(directions, np.float64).reshape(-1, 3)
    squared = {"silhouette": 0.0, "colour": 0.0}
    pixels = {"silhouette": 0, "colour": 0}
    for direction in views:
        a, b = (render(s, direction=direction, center=center, radius=radius, pixel_size=pixel_size,
                       max_side=max_side) for s in (proxy, sources))
        diff = (luma(a.rgb) - luma(b.rgb)) ** 2
        for key, where in (("silhouette", a.coverage ^ b.coverage), ("colour", a.coverage & b.coverage)):
            squared[key] += float(diff[where].sum())
            pixels[key] += int(where.sum())
    count = pixels["silhouette"] + pixels["colour"]
    mse = (squared["silhouette"] + squared["colour"]) / count if count else 0.0
    db = float(10.0 * math.log10(1.0 / max(mse, 10.0 ** (-PSNR_CAP_DB / 10.0))))
    if db >= GATE_DB:
        return db, None
    if squared["silhouette"] >= squared["colour"]:
        share = pixels["silhouette"] / count
        return db, (f"silhouette: coverage differs on {share:.0%} of pixels "
                    f"({squared['silhouette'] / (squared['silhouette'] + squared['colour']):.0%} of the error)")
    both = squared["colour"] / max(pixels["colour"], 1)
    inner = 10.0 * math.log10(1.0 / max(both, 10.0 ** (-PSNR_CAP_DB / 10.0)))
    return db, (f"colour: PSNR-Y {inner:.1f} dB where both cover "
                f"(coverage differs on {pixels['silhouette'] / count:.0%} of pixels)")
