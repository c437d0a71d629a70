"""Procedural scenes made by the project itself, with no input files (the main job's `default`,
and `pieces`: open boundaries and many small pieces), and two that measure when queries pay, with
their camera paths: `square_scene` (scanned statues standing apart on flat ground: nothing hides
much) and `square_and_street_scene` (such a square beside a city block, the path walking from one
into the other).

Data form: `meshes.TriangleMesh` (positions float64 model units, metres by convention; Z up).
The default scene is a seeded city block: a tessellated ground, a grid of finely tessellated
buildings of random heights, and a sphere on each roof. Seen from the street most of it hides
behind the first row, which is the high depth complexity the occlusion-driven traversal is for.
"""
from __future__ import annotations

import numpy as np

from ..core.arrays import concat_indexed
from ..model.camera_path import CameraPath
from .meshes import TriangleMesh


def grid_patch(origin, u, v, *, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A parallelogram origin + [0,1]u + [0,1]v tessellated into nu x nv quads (2 tris each).
    Returns positions ((nu+1)(nv+1),3) float64 and faces (2 nu nv,3) int64, counter-clockwise about u x v."""
    s, t = np.meshgrid(np.linspace(0.0, 1.0, nu + 1), np.linspace(0.0, 1.0, nv + 1), indexing="ij")
    p = np.asarray(origin, float) + s[..., None] * np.asarray(u, float) + t[..., None] * np.asarray(v, float)
    return p.reshape(-1, 3), _grid_faces(nu + 1, nv + 1)


def _grid_faces(rows: int, cols: int) -> np.ndarray:
    """Two triangles per quad of a rows x cols vertex grid (row-major vertex ids), (2 (rows-1)(cols-1), 3)
    int64, counter-clockwise in (row, column) order."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def box(lo, hi, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed axis-aligned box, each face an n x n grid, outward-facing."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    dx, dy, dz = np.diag(hi - lo)
    patches = [
        (lo, dy, dx), (lo + dz, dx, dy),                  # bottom (-z), top (+z)
        (lo, dx, dz), (lo + dy, dz, dx),                  # -y, +y
        (lo, dz, dy), (lo + dx, dy, dz),                       # -x, +x
    ]
    return concat_indexed([grid_patch(o, u, v, nu=n, nv=n) for o, u, v in patches])


def uv_sphere(center, radius: float, *, segments: int, rings: int) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere with `segments` around and `rings` from pole to pole (pole rows are degenerate
    quads kept as thin triangles: this is real-world input too)."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    p = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], -1) * radius + np.asarray(center, float)
    return p.reshape(-1, 3), _grid_faces(rings + 1, segments + 1)


def default_scene(*, seed: int = 1, scale: float = 1.0) -> TriangleMesh:
    """About 220k triangles: an 8 x 8 block of buildings on a 160 m ground (scale multiplies the
    building count per side, rounded; 1.0 is the CI-sized default)."""
    return _city(seed=seed, per_side=max(1, int(round(8 * scale))), spacing=20.0, footprint=12.0,
                 heights=(10.0, 45.0), box_cells=12, sphere=(32, 24), name=f"default scene (seed {seed})")


def low_scene(*, seed: int = 1, scale: float = 1.0) -> TriangleMesh:
    """Low depth complexity, about 180k triangles: a rolling terrain (a 300 x 300 quad heightfield
    of seeded sine waves, 200 m across, hills up to about 12 m). Seen from any point above it,
    little of it hides behind other parts (scale multiplies the cells per side)."""
    rng = np.random.default_rng(seed)
    cells = max(2, int(round(300 * np.sqrt(scale))))
    size = 200.0
    positions, faces = grid_patch([-size / 2, -size / 2, 0.0], [size, 0, 0], [0, size, 0], nu=cells, nv=cells)
    height = np.zeros(positions.shape[0])
    for _ in range(6):
        direction = rng.normal(size=2)
        direction /= np.linalg.norm(direction)
        wavelength = rng.uniform(25.0, 120.0)
        phase = rng.uniform(0, 2 * np.pi)
        height += rng.uniform(0.5, 2.5) * np.sin(2 * np.pi * (positions[:, :2] @ direction) / wavelength + phase)
    positions[:, 2] = height - height.min()
    return TriangleMesh(positions=positions, faces=faces, name=f"low scene (seed {seed})")


def middle_scene(*, seed: int = 1, scale: float = 1.0) -> TriangleMesh:
    """Middle depth complexity, about 210k triangles: a sparse town, 6 x 6 low houses (5-16 m) on
    30 m plots, each with a dome; from street level the nearer rows hide part of the farther ones,
    from above little is hidden."""
    return _city(seed=seed, per_side=max(1, int(round(6 * scale))), spacing=30.0, footprint=12.0,
                 heights=(5.0, 16.0), box_cells=16, sphere=(40, 30), name=f"middle scene (seed {seed})")


def high_scene(*, seed: int = 1, scale: float = 1.0) -> TriangleMesh:
    """High depth complexity, about 220k triangles: a dense downtown, 10 x 10 towers of 20-60 m on
    a 14 m grid with 3 m alleys; from street level or any oblique view most towers hide behind
    the first rows and are seen only through alleys, as slivers."""
    return _city(seed=seed, per_side=max(1, int(round(10 * scale))), spacing=14.0, footprint=11.0,
                 heights=(20.0, 60.0), box_cells=10, sphere=(24, 16), name=f"high scene (seed {seed})")


def _city(*, seed: int, per_side: int, spacing: float, footprint: float, heights: tuple[float, float],
          box_cells: int, sphere: tuple[int, int], name: str) -> TriangleMesh:
    """Seeded towers of random heights (box_cells x box_cells quads per face) with a sphere on each
    roof (segments, rings), on a 64 x 64 quad ground."""
    rng = np.random.default_rng(seed)
    extent = per_side * spacing
    margin = spacing / 2
    parts = [grid_patch([-margin, -margin, 0.0], [extent, 0, 0], [0, extent, 0], nu=64, nv=64)]
    radius = 0.25 * footprint
    for i in range(per_side):
        for j in range(per_side):
            x, y = i * spacing, j * spacing
            height = float(rng.uniform(*heights))
            lo = np.array([x - footprint / 2, y - footprint / 2, 0.0])
            parts.append(box(lo, lo + [footprint, footprint, height], box_cells))
            parts.append(uv_sphere([x, y, height + radius], radius, segments=sphere[0], rings=sphere[1]))
    positions, faces = concat_indexed(parts)
    return TriangleMesh(positions=positions, faces=faces, name=name)


def pieces_scene(*, seed: int = 1, scale: float = 1.0) -> TriangleMesh:
    """Open boundaries and many small pieces, about 81k triangles: a row of 6 scanned statues (noisy
    blobs with an open base and holes, as a range scan leaves them; 8k triangles each), a field of
    10,000 foliage cards (one quad each) and a machine made of many parts (a shell of 60 separate
    patches that touch without sharing vertices, and 400 small boxes bolted onto it). scale
    multiplies the statues, the cards and the bolts."""
    rng = np.random.default_rng(seed)
    parts = []
    for i in range(max(1, int(round(6 * scale)))):
        parts.append(open_scan([6.0 * i, 0.0, 2.0], 2.0, rng=rng, segments=96, rings=64, holes=6))
    parts.append(foliage_cards([-2.0, 6.0, 0.0], [34.0, 24.0], count=max(1, int(round(10_000 * scale))),
                               card=0.3, rng=rng))
    parts.extend(machine([16.0, -8.0, 2.5], 2.5, patches=(6, 10), bolts=max(1, int(round(400 * scale))), rng=rng))
    positions, faces = concat_indexed(parts)
    return TriangleMesh(positions=positions, faces=faces, name=f"pieces scene (seed {seed})")


def open_scan(center, radius: float, *, rng: np.random.Generator, segments: int, rings: int,
              holes: int) -> tuple[np.ndarray, np.ndarray]:
    """A scanned statue: a UV sphere displaced by seeded bumps, its lowest rings cut off (the
    open base a scan on a turntable leaves) and `holes` round holes punched where the scanner did
    not see (faces whose centroid lies within 0.2 radius of a random surface point go)."""
    p, f = uv_sphere([0.0, 0.0, 0.0], 1.0, segments=segments, rings=rings)
    direction = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-12)
    bumps = np.zeros(p.shape[0])
    for _ in range(8):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        bumps += rng.uniform(0.03, 0.12) * np.exp(-np.sum((direction - axis) ** 2, axis=1) / rng.uniform(0.05, 0.4))
    p = direction * (1.0 + bumps[:, None])
    centroid = p[f].mean(axis=1)
    keep = centroid[:, 2] > -0.6  # the base
    for _ in range(holes):
        spot = rng.normal(size=3)
        spot /= np.linalg.norm(spot)
        keep &= np.linalg.norm(centroid - spot, axis=1) > 0.2
    return p * radius + np.asarray(center, float), f[keep]


def foliage_cards(corner, size, *, count: int, card: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`count` foliage cards: single quads of side `card`, each its own piece, on a jittered grid
    over the rectangle corner (3,) + [0, size[0]] x [0, size[1]], at heights up to 1.5 m, turned
    and tilted at random."""
    side = int(np.ceil(np.sqrt(count * size[0] / size[1])))
    grid = np.stack(np.meshgrid(np.arange(side), np.arange(int(np.ceil(count / side))), indexing="ij"), -1)
    cell = np.array([size[0] / side, size[1] / grid.shape[1]])
    xy = (grid.reshape(-1, 2)[:count] + rng.uniform(0.1, 0.9, (count, 2))) * cell
    centre = np.column_stack([xy, rng.uniform(0.2, 1.5, count)]) + np.asarray(corner, float)
    turn, tilt = rng.uniform(0, 2 * np.pi, count), rng.uniform(-0.5, 0.5, count)
    u = np.column_stack([np.cos(turn), np.sin(turn), np.zeros(count)]) * card / 2
    v = np.column_stack([-np.sin(turn) * np.sin(tilt), np.cos(turn) * np.sin(tilt), np.cos(tilt)]) * card / 2
    corners = np.stack([centre - u - v, centre + u - v, centre + u + v, centre - u + v], axis=1)
    quads = np.arange(4 * count).reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return corners.reshape(-1, 3), faces


def machine(center, radius: float, *, patches: tuple[int, int], bolts: int,
            rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """A model in many parts: a sphere's shell cut into patches (rings x segments of them, each
    with its own vertices, so neighbouring patches touch along open boundaries) and `bolts`
    closed boxes of 4 cm to 12 cm on its surface."""
    rows, columns = patches
    out = []
    for i in range(rows):
        for j in range(columns):
            theta = np.linspace(np.pi * i / rows, np.pi * (i + 1) / rows, 9)
            phi = np.linspace(2 * np.pi * j / columns, 2 * np.pi * (j + 1) / columns, 9)
            t, q = np.meshgrid(theta, phi, indexing="ij")
            p = np.stack([np.sin(t) * np.cos(q), np.sin(t) * np.sin(q), np.cos(t)], -1).reshape(-1, 3)
            out.append((p * radius + np.asarray(center, float), _grid_faces(9, 9)))
    normal = rng.normal(size=(bolts, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    for n, half in zip(normal, rng.uniform(0.02, 0.06, bolts)):
        lo = np.asarray(center, float) + n * radius - half
        out.append(box(lo, lo + 2 * half, 1))
    return out


def _square(rng: np.random.Generator, *, corner, per_side: int, spacing: float,
            segments: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """per_side x per_side scanned statues (2 m radius, standing on z = 0) `spacing` apart from
    `corner` (x, y), on a 32 x 32 quad flat ground reaching a spacing beyond them."""
    x0, y0 = corner
    side = (per_side - 1) * spacing
    parts = [grid_patch([x0 - spacing, y0 - spacing, 0.0], [side + 2 * spacing, 0, 0], [0, side + 2 * spacing, 0],
                        nu=32, nv=32)]
    for i in range(per_side):
        for j in range(per_side):
            parts.append(open_scan([x0 + i * spacing, y0 + j * spacing, 1.6], 2.0, rng=rng, segments=segments,
                                   rings=segments * 2 // 3, holes=2))
    return parts


def square_scene(*, seed: int = 1, per_side: int = 6, spacing: float = 12.0, segments: int = 96) -> TriangleMesh:
    """An open square: per_side^2 scanned statues (about 8k triangles each at 96 segments)
    standing `spacing` apart on flat ground, from (0, 0) along +x and +y. Seen along
    `square_far_path`, a statue hides little of the others."""
    positions, faces = concat_indexed(_square(np.random.default_rng(seed), corner=(0.0, 0.0), per_side=per_side,
                                              spacing=spacing, segments=segments))
    return TriangleMesh(positions=positions, faces=faces, name=f"square scene (seed {seed})")


def square_far_path(*, frames: int, per_side: int = 6, spacing: float = 12.0) -> CameraPath:
    """From far to near: the eye 8 m up, approaching the square of `square_scene` along its diagonal
    from 4 times its side away to its first statue, looking at its centre."""
    side = (per_side - 1) * spacing
    centre = np.array([side / 2, side / 2, 1.6])
    t = np.linspace(0.0, 1.0, frames)[:, None]
    away = np.array([-1.0, -0.35, 0.0]) / np.hypot(1.0, 0.35)
    eye = centre + away * (4.0 * side * (1.0 - t) + 0.75 * side * t) + [0.0, 0.0, 6.4]
    out = np.stack([eye, np.broadcast_to(centre, eye.shape), np.broadcast_to([0.0, 0.0, 1.0], eye.shape)], axis=1)
    return CameraPath(frames=out, near=0.1, far=8.0 * side, fovy_deg=60.0)


def square_and_street_scene(*, seed: int = 1, per_side: int = 3, blocks: int = 4, segments: int = 64) -> TriangleMesh:
    """A square of per_side^2 scanned statues 12 m apart (x from -60 m) beside a city block of blocks x
    blocks buildings 20 m apart (x from 0, as the default scene's), their streets along +y."""
    rng = np.random.default_rng(seed)
    parts = _square(rng, corner=(-60.0, 0.0), per_side=per_side, spacing=12.0, segments=segments)
    city = _city(seed=seed, per_side=blocks, spacing=20.0, footprint=12.0, heights=(15.0, 45.0), box_cells=12,
                 sphere=(32, 24), name="")
    positions, faces = concat_indexed(parts + [(city.positions, city.faces)])
    return TriangleMesh(positions=positions, faces=faces, name=f"square and street scene (seed {seed})")


def square_to_street_path(*, frames: int) -> CameraPath:
    """Along `square_and_street_scene`, eye 1.7 m up: a third of the frames in the square looking
    away from the block (-x), a third turning to +y while walking to the street between the block's
    first two columns (x = 10 m), a third down that street. Parts "square", "turn", "street"."""
    n = frames // 3
    a = np.linspace(0.0, 1.0, n, endpoint=False)
    b = np.linspace(0.0, 1.0, n, endpoint=False)
    c = np.linspace(0.0, 1.0, frames - 2 * n)
    eye = np.concatenate([np.column_stack([-30.0 + 0.0 * a, -14.0 + 6.0 * a, 1.7 + 0.0 * a]),
                          np.column_stack([-30.0 + 40.0 * b, -8.0 + 0.0 * b, 1.7 + 0.0 * b]),
                          np.column_stack([10.0 + 0.0 * c, -8.0 + 60.0 * c, 1.7 + 0.0 * c])])
    heading = np.concatenate([np.full(n, np.pi), np.pi - np.pi / 2 * b, np.full(frames - 2 * n, np.pi / 2)])
    target = eye + np.column_stack([30.0 * np.cos(heading), 30.0 * np.sin(heading), np.full(frames, 2.3)])
    out = np.stack([eye, target, np.broadcast_to([0.0, 0.0, 1.0], eye.shape)], axis=1)
    return CameraPath(frames=out, near=0.05, far=400.0, fovy_deg=60.0,
                      parts=(("square", 0), ("turn", n), ("street", 2 * n)))


SCENES = {"low": low_scene, "middle": middle_scene, "high": high_scene, "default": default_scene,
          "pieces": pieces_scene}
