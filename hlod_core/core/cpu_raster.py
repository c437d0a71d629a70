"""Triangles rasterised with numpy into a small depth buffer: the CPU occlusion test's GL
(docs/how-it-works.md#the-cpu-occlusion-test), and the coverage of the bake's quality gate
(bake/appearance/quality.py).

Data form: triangles as (t, 3, 4) float64 clip-space vertices (clip = MVP @ (x, y, z, 1), OpenGL
conventions); a depth buffer as (h, w) float32 window depth in [0, 1], row 0 the bottom row, as GL's
(render/depth_import.py). A pixel (i, j) (row i, column j) is covered by a triangle when its centre
(j + 0.5, i + 0.5) lies inside it, edges included; its depth is the triangle's window depth
z = (z_ndc + 1) / 2 there, linear in window x and y as GL interpolates it. Every step is vectorised
over all triangles and all the pixels of their bounding boxes: no Python loop over triangles or
pixels.

Clipping: triangles are clipped against the near plane (z_clip >= -w) in clip space, a triangle
with one vertex behind it becoming two and one with two becoming one; beyond the far plane and
outside the viewport, pixels are dropped (GL clips there too).
"""
from __future__ import annotations

import numpy as np

#: Pixels of bounding box rasterised per batch: the candidates' arrays stay a few MB.
BATCH_PIXELS = 1 << 20


def clip_near(clip: np.ndarray) -> np.ndarray:
    """(t, 3, 4) clip-space triangles -> (t', 3, 4) their parts in front of the near plane
    (z_clip + w >= 0), vertex order (and so the facing) kept."""
    d = clip[:, :, 2] + clip[:, :, 3]  # (t, 3) signed distance to the near plane, >= 0 in front
    inside = d >= 0.0
    count = inside.sum(axis=1)
    kept = [clip[count == 3]]
    for n_in in (1, 2):
        rows = np.flatnonzero(count == n_in)
        if not len(rows):
            continue
        # rotate each triangle so the lone vertex (the inside one for 1, the outside one for 2) is
        # first (1) or last (2): cyclic order, so the facing is kept
        lone = np.argmax(inside[rows] if n_in == 1 else ~inside[rows], axis=1)
        shift = lone if n_in == 1 else lone + 1
        order = (shift[:, None] + np.arange(3)[None, :]) % 3
        v = np.take_along_axis(clip[rows], order[:, :, None], axis=1)
        dv = np.take_along_axis(d[rows], order, axis=1)
        if n_in == 1:  # a in, b and c out: the triangle a, ab, ac
            a, b, c = v[:, 0], v[:, 1], v[:, 2]
            ab = a + (b - a) * (dv[:, 0] / (dv[:, 0] - dv[:, 1]))[:, None]
            ac = a + (c - a) * (dv[:, 0] / (dv[:, 0] - dv[:, 2]))[:, None]
            kept.append(np.stack([a, ab, ac], axis=1))
        else:  # a and b in, c out: the quad a, b, bc, ac as two triangles
            a, b, c = v[:, 0], v[:, 1], v[:, 2]
            bc = b + (c - b) * (dv[:, 1] / (dv[:, 1] - dv[:, 2]))[:, None]
            ac = a + (c - a) * (dv[:, 0] / (dv[:, 0] - dv[:, 2]))[:, None]
            kept += [np.stack([a, b, bc], axis=1), np.stack([a, bc, ac], axis=1)]
    return np.concatenate(kept) if len(kept) > 1 else kept[0]


def to_window(clip: np.ndarray, viewport: tuple[float, float]) -> np.ndarray:
    """(t, 3, 4) clip-space triangles in front of the near plane -> (t, 3, 3) window x, y (pixels of
    a `viewport` of (width, height) pixels, not necessarily whole, origin bottom left) and z (window depth)."""
    ndc = clip[:, :, :3] / clip[:, :, 3:4]
    out = np.empty_like(ndc)
    out[:, :, 0] = (ndc[:, :, 0] + 1.0) * (0.5 * viewport[0])
    out[:, :, 1] = (ndc[:, :, 1] + 1.0) * (0.5 * viewport[1])
    out[:, :, 2] = (ndc[:, :, 2] + 1.0) * 0.5
    return out


def pixel_limits(viewport: tuple[float, float]) -> tuple[int, int]:
    """(columns, rows) whose pixel centres lie inside a `viewport` of (width, height) pixels."""
    return int(np.ceil(viewport[0] - 0.5)), int(np.ceil(viewport[1] - 0.5))


def covered(window: np.ndarray, limits: tuple[int, int], *, front_only: bool):
    """The pixels the triangles cover among the first `limits` = (columns, rows): (row, column,
    depth) as (k,) int64, int64, float64 arrays and the (k,) int64 triangle each belongs to;
    front_only: back faces (clockwise in window space, GL's default culling) and degenerate ones
    cover nothing; otherwise both facings do. Yields batches of at most about BATCH_PIXELS
    bounding-box pixels."""
    w, h = limits
    x, y, z = window[:, :, 0], window[:, :, 1], window[:, :, 2]
    # twice the signed area; > 0 counter-clockwise (front facing)
    area = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (x[:, 2] - x[:, 0]) * (y[:, 1] - y[:, 0])
    keep = area > 0.0 if front_only else area != 0.0
    # pixel centres j + 0.5 inside [min x, max x]: j from ceil(min x - 0.5) to floor(max x - 0.5)
    x0 = np.clip(np.ceil(x.min(axis=1) - 0.5), 0, w).astype(np.int64)
    x1 = np.clip(np.floor(x.max(axis=1) - 0.5), -1, w - 1).astype(np.int64)
    y0 = np.clip(np.ceil(y.min(axis=1) - 0.5), 0, h).astype(np.int64)
    y1 = np.clip(np.floor(y.max(axis=1) - 0.5), -1, h - 1).astype(np.int64)
    bw, bh = np.maximum(x1 - x0 + 1, 0), np.maximum(y1 - y0 + 1, 0)
    pixels = np.where(keep, bw * bh, 0)
    tris = np.flatnonzero(pixels)
    if not len(tris):
        return
    # edge functions E_k(p) = a_k px + b_k py + c_k of edge k (vertex k to k+1), >= 0 inside a
    # counter-clockwise triangle; a clockwise one has them all <= 0, so they are multiplied by its sign
    sign = np.sign(area)[:, None]
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    ea, eb = (y - yn) * sign, (xn - x) * sign
    ec = -(ea * x + eb * y)
    # depth plane z = z_0 + dzdx px + dzdy py
    dx1, dy1, dz1 = x[:, 1] - x[:, 0], y[:, 1] - y[:, 0], z[:, 1] - z[:, 0]
    dx2, dy2, dz2 = x[:, 2] - x[:, 0], y[:, 2] - y[:, 0], z[:, 2] - z[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):  # degenerate triangles cover no pixel
        dzdx = (dz1 * dy2 - dz2 * dy1) / area
        dzdy = (dz2 * dx1 - dz1 * dx2) / area
    plane = (z[:, 0] - dzdx * x[:, 0] - dzdy * y[:, 0], dzdx, dzdy)
    ends = np.cumsum(pixels[tris])
    start = 0
    while start < len(tris):
        stop = max(int(np.searchsorted(ends, (ends[start - 1] if start else 0) + BATCH_PIXELS, side="right")),
                   start + 1)
        yield _batch(tris[start:stop], pixels, (x0, y0, bw), (ea, eb, ec), plane)
        start = stop


def _batch(tris, pixels, box, edges, plane):
    """The covered pixels of triangles `tris`: (row, column, depth, triangle), from covered's
    (t,) arrays indexed by triangle: pixels, box (first column, first row, width), edges (three
    (t, 3)) and depth plane (three (t,))."""
    x0, y0, bw = box
    ea, eb, ec = edges
    counts = pixels[tris]
    tri = np.repeat(tris, counts)
    offset = np.arange(len(tri)) - np.repeat(np.cumsum(counts) - counts, counts)
    col = x0[tri] + offset % bw[tri]
    row = y0[tri] + offset // bw[tri]
    px, py = col + 0.5, row + 0.5
    inside = np.ones(len(tri), bool)
    for k in range(3):  # the three edges
        inside &= ea[tri, k] * px + eb[tri, k] * py + ec[tri, k] >= 0.0
    tri, row, col, px, py = tri[inside], row[inside], col[inside], px[inside], py[inside]
    z0, dzdx, dzdy = plane
    depth = z0[tri] + dzdx[tri] * px + dzdy[tri] * py
    in_range = (depth >= 0.0) & (depth <= 1.0)  # GL clips beyond the far plane
    return row[in_range], col[in_range], depth[in_range], tri[in_range]


def draw(window: np.ndarray, depth_buffer: np.ndarray, *, limits: tuple[int, int]) -> None:
    """Write the triangles' depth into `depth_buffer` (h, w) float32 where nearer (depth test "<=",
    no culling: as the renderer draws nodes), over its first `limits` (columns, rows)."""
    w = depth_buffer.shape[1]
    flat = depth_buffer.reshape(-1)
    for row, col, depth, _ in covered(window, limits, front_only=False):
        np.minimum.at(flat, row * w + col, depth.astype(np.float32))


def count(window: np.ndarray, depth_buffer: np.ndarray, *, groups: np.ndarray, group_count: int,
          limits: tuple[int, int]):
    """Per group of triangles (`groups` (t,) int64 in [0, group_count)): (q, alpha), each a
    (group_count,) int64 count of pixels its front faces cover among `depth_buffer`'s first
    `limits` (columns, rows): q where the depth test "<=" against `depth_buffer` passes, alpha with
    the test off (as a GL_SAMPLES_PASSED query of the group's triangles with back faces culled, the
    depth test on and off)."""
    w = depth_buffer.shape[1]
    q = np.zeros(group_count, np.int64)
    alpha = np.zeros(group_count, np.int64)
    flat = depth_buffer.reshape(-1)
    for row, col, depth, tri in covered(window, limits, front_only=True):
        g = groups[tri]
        alpha += np.bincount(g, minlength=group_count)
        passed = depth <= flat[row * w + col]
        q += np.bincount(g[passed], minlength=group_count)
    return q, alpha
