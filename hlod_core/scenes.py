"""Procedural scenes made by the project itself, with no input files (the main job's `default`).

Data form: `meshio.TriangleMesh` (positions float64 model units, metres by convention; Z up).
The default scene is a seeded city block: a tessellated ground, a grid of finely tessellated
buildings of random heights, and a sphere on each roof. Seen from the street most of it hides
behind the first row, which is the high depth complexity the occlusion-driven traversal is for.
"""
from __future__ import annotations

import numpy as np

from .meshio import TriangleMesh, merge


def grid_patch(origin, u, v, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A parallelogram origin + [0,1]u + [0,1]v tessellated into nu x nv quads (2 tris each).
    Returns positions ((nu+1)(nv+1),3) float64 and faces (2 nu nv,3) int64, counter-clockwise about u x v."""
    s, t = np.meshgrid(np.linspace(0.0, 1.0, nu + 1), np.linspace(0.0, 1.0, nv + 1), indexing="ij")
    p = np.asarray(origin, float) + s[..., None] * np.asarray(u, float) + t[..., None] * np.asarray(v, float)
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return p.reshape(-1, 3), faces


def box(lo, hi, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed axis-aligned box, each face an n x n grid, outward-facing."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    dx, dy, dz = np.diag(hi - lo)
    patches = [
        (lo, dy, dx), (lo + dz, dx, dy),                  # bottom (-z), top (+z)
        (lo, dx, dz), (lo + dy, dz, dx),                  # -y, +y
        (lo, dz, dy), (lo + dx, dy, dz),                       # -x, +x
    ]
    return _concat([grid_patch(o, u, v, n, n) for o, u, v in patches])


def uv_sphere(center, radius: float, segments: int, rings: int) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere with `segments` around and `rings` from pole to pole (pole rows are degenerate
    quads kept as thin triangles: this is real-world input too)."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    p = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], -1) * radius + np.asarray(center, float)
    idx = np.arange((rings + 1) * (segments + 1)).reshape(rings + 1, segments + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return p.reshape(-1, 3), faces


def _concat(parts) -> tuple[np.ndarray, np.ndarray]:
    offsets = np.cumsum([0] + [p.shape[0] for p, _ in parts[:-1]])
    return np.concatenate([p for p, _ in parts]), np.concatenate([f + o for (_, f), o in zip(parts, offsets)])


def default_scene(*, seed: int = 1, scale: float = 1.0) -> TriangleMesh:
    """About 220k triangles: an 8 x 8 block of buildings on a 160 m ground (scale multiplies the
    building count per side, rounded; 1.0 is the CI-sized default)."""
    rng = np.random.default_rng(seed)
    per_side = max(1, int(round(8 * scale)))
    spacing, footprint = 20.0, 12.0
    extent = per_side * spacing
    parts = [grid_patch([-10.0, -10.0, 0.0], [extent, 0, 0], [0, extent, 0], 64, 64)]
    for i in range(per_side):
        for j in range(per_side):
            x, y = i * spacing, j * spacing
            height = float(rng.uniform(10.0, 45.0))
            lo = np.array([x - footprint / 2, y - footprint / 2, 0.0])
            parts.append(box(lo, lo + [footprint, footprint, height], 12))
            parts.append(uv_sphere([x, y, height + 3.0], 3.0, 32, 24))
    positions, faces = _concat(parts)
    return merge([TriangleMesh(positions=positions, faces=faces, name=f"default scene (seed {seed})")])
