"""Meshes built in numpy for tests whose expected values follow from how the mesh is built.

The textured sphere: a closed unit sphere at SPHERE_CENTER whose attributes are functions of
position, so what a LOD vertex should carry is known from its position alone:
  - two materials, split by the plane x = 0.2 (relative to the centre: a material border);
  - UV = planar projection (u, v) = (x, y) / 2 + 0.5, plus 1 on u for the faces behind the centre's
    z (a UV seam: the vertices there are split in two, one per side), expected_uv;
  - colour = (p / 2 + 0.5, 1), inverted (1 - c) on the faces above y = 0.35 (a colour jump, split the
    same way), expected_rgb.
The herd: nine copies of the cow test model on a 3 x 3 grid, the middle one optionally moved.
"""
from __future__ import annotations

import numpy as np

from helpers import load_model
from hlod_core.io import meshes
from hlod_core.model.appearance import Material

#: Away from the origin: the bake stores positions relative to its own origin.
SPHERE_CENTER = np.array([3.0, -2.0, 1.0])
SPHERE_MATERIALS = (Material("red", base_color=(0.8, 0.1, 0.1, 1.0)),
                    Material("blue", base_color=(0.1, 0.1, 0.8, 1.0)))
#: The bake target the textured-sphere tests use (its 2,208 triangles down to about 200 at the root).
SPHERE_TARGET_TRIS = 200
#: The 3 x 3 herd: cows (about 10 units long) 12 units apart; the one in the middle (index 4) moves.
HERD_SPACING, HERD_MOVER = 12.0, 4


def sphere(rings: int = 24, segments: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """A closed unit sphere at SPHERE_CENTER, welded (one vertex per position): (v, 3) float64
    positions (poles, then rings x segments) and (f, 3) int64 faces."""
    theta = np.pi * np.arange(1, rings) / rings
    phi = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.sin(theta)[:, None] * np.cos(phi), np.sin(theta)[:, None] * np.sin(phi),
                     np.repeat(np.cos(theta)[:, None], segments, 1)], -1).reshape(-1, 3)
    positions = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]) + SPHERE_CENTER
    grid = 1 + np.arange((rings - 1) * segments).reshape(rings - 1, segments)
    nxt = np.roll(grid, -1, axis=1)
    quads_a = np.stack([grid[:-1], grid[1:], nxt[1:]], -1).reshape(-1, 3)
    quads_b = np.stack([grid[:-1], nxt[1:], nxt[:-1]], -1).reshape(-1, 3)
    south = positions.shape[0] - 1
    caps = np.concatenate([np.stack([np.zeros(segments, int), grid[0], nxt[0]], -1),
                           np.stack([np.full(segments, south), nxt[-1], grid[-1]], -1)])
    return positions, np.concatenate([caps, quads_a, quads_b]).astype(np.int64)


def split_vertices(faces: np.ndarray, side: np.ndarray, vertex_count: int):
    """Duplicate every vertex used by faces on both sides of `side` (f,) bool; the `side` faces use
    the copies. Returns (source (v',) rows of the old vertices, faces (f, 3), on_side (v',) bool)."""
    used_side = np.zeros(vertex_count, bool)
    used_side[faces[side].ravel()] = True
    used_other = np.zeros(vertex_count, bool)
    used_other[faces[~side].ravel()] = True
    shared = used_side & used_other
    copy = np.full(vertex_count, -1)
    copy[shared] = vertex_count + np.arange(int(shared.sum()))
    out = faces.copy()
    sub = out[side]
    sub[shared[sub]] = copy[sub[shared[sub]]]
    out[side] = sub
    source = np.concatenate([np.arange(vertex_count), np.flatnonzero(shared)])
    return source, out, np.concatenate([used_side & ~shared, np.ones(int(shared.sum()), bool)])


def expected_uv(positions: np.ndarray) -> np.ndarray:
    """(k, 2) the planar projection of (k, 3) world positions, before the seam's offset."""
    return (positions[:, :2] - SPHERE_CENTER[:2]) * 0.5 + 0.5


def expected_rgb(positions: np.ndarray) -> np.ndarray:
    """(k, 3) the colour of (k, 3) world positions, before the colour jump's inversion."""
    return np.clip((positions - SPHERE_CENTER) * 0.5 + 0.5, 0.0, 1.0)


def textured_sphere(*, uvs: bool = True, colors: bool = True, materials: bool = True) -> meshes.TriangleMesh:
    """The textured sphere (module docstring), with or without each attribute; a new mesh each call."""
    positions, faces = sphere()
    centroid = positions[faces].mean(axis=1)
    source, faces, back = split_vertices(faces, centroid[:, 2] < SPHERE_CENTER[2], positions.shape[0])  # UV seam
    positions = positions[source]
    source, faces, top = split_vertices(faces, centroid[:, 1] > SPHERE_CENTER[1] + 0.35, positions.shape[0])
    positions, back = positions[source], back[source]  # (the second split is the colour jump)
    uv = expected_uv(positions) + np.stack([back, np.zeros_like(back)], 1)
    rgb = expected_rgb(positions)
    rgb[top] = 1.0 - rgb[top]
    material = (centroid[:, 0] > SPHERE_CENTER[0] + 0.2).astype(np.int32)
    return meshes.from_arrays(positions, faces, name="textured sphere", uvs=uv if uvs else None,
                              colors=np.concatenate([rgb, np.ones((rgb.shape[0], 1))], 1) if colors else None,
                              material_ids=material if materials else None,
                              materials=SPHERE_MATERIALS if materials else ())


#: The herd's cow: the test model (its length along z) turned to lie along x and scaled to 10 units long.
HERD_COW = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
HERD_COW_LENGTH = 10.0


def herd_cow() -> meshes.TriangleMesh:
    """The cow test model turned and scaled as HERD_COW and HERD_COW_LENGTH say (a new mesh each call)."""
    cow = load_model("cow")
    length = float(np.ptp(cow.positions[:, 2]))
    return meshes.transform_mesh(cow, np.diag([HERD_COW_LENGTH / length] * 3 + [1.0]) @ HERD_COW, name="cow")


def herd(moved_by=(0.0, 0.0, 0.0)) -> tuple[meshes.TriangleMesh, np.ndarray]:
    """Nine cows (herd_cow) on a grid HERD_SPACING apart, the middle one moved by `moved_by` (model
    units); and the (f,) bool mask of the moved cow's triangles."""
    cow = herd_cow()
    parts = []
    for k in range(9):
        offset = np.array([HERD_SPACING * (k % 3), HERD_SPACING * (k // 3), 0.0])
        if k == HERD_MOVER:
            offset = offset + np.asarray(moved_by)
        translation = np.eye(4)
        translation[:3, 3] = offset
        parts.append(meshes.transform_mesh(cow, translation, name=f"cow{k}"))
    mover = np.repeat(np.arange(9) == HERD_MOVER, cow.tri_count)
    return meshes.merge(parts, name="herd"), mover
