"""prepare.prepare makes the floats of its definition, however it gets there: the origin and lattice
of the used vertices' box, the stored positions `lattice.snap_frexp` rounds, the centroids summed
a + b + c in float64 from the float32 corners, the collapsed triangles by float32 equality, and the
root cube around the centroids' box taken as a C-ordered min(axis=0) and max(axis=0), whose zeros
keep the sign that reduction gives them (meta["frame"] records the corner). Faces in either memory
order, vertices no face uses (NaN ones included), and the chunks the positions and centroids are
made in."""
from __future__ import annotations

import numpy as np
import pytest

from hlod_core.bake import prepare
from hlod_core.bake.space import chunk_store, lattice
from hlod_core.bake.space.frame import Frame, Prior
from hlod_core.bake.space.root_cube import RootCube, tight_cube
from hlod_core.io.meshes import TriangleMesh


def _definition(mesh: TriangleMesh) -> dict[str, np.ndarray]:
    """What prepare stores and splits, written out as one whole-array pass each."""
    used = np.zeros(mesh.positions.shape[0], bool)
    used[np.unique(mesh.faces)] = True
    box = mesh.positions[used]
    lo, hi = box.min(axis=0), box.max(axis=0)
    origin, length = 0.5 * (lo + hi), lattice.unit_length(lo, hi)
    rel = mesh.positions - origin
    rel[~used] = 0.0
    positions = (lattice.snap_frexp(rel / length) * length).astype(np.float32)
    a, b, c = (positions[mesh.faces[:, k]] for k in range(3))
    centroids = ((a.astype(np.float64) + b) + c) / 3.0
    collapsed = np.all(a == b, axis=1) | np.all(b == c, axis=1) | np.all(a == c, axis=1)
    root = tight_cube(centroids.min(axis=0), centroids.max(axis=0))
    return {"origin": origin, "unit_length": np.array([length]), "positions": positions, "centroids": centroids,
            "counted": ~collapsed, "root_corner": root.corner, "root_side": np.array([root.side])}


def _made(mesh: TriangleMesh) -> dict[str, np.ndarray]:
    got = prepare.prepare(mesh)
    return {"origin": got.origin, "unit_length": np.array([got.unit_length]), "positions": got.positions,
            "centroids": np.ascontiguousarray(got.centroids), "counted": got.counted,
            "root_corner": got.root_cell.corner, "root_side": np.array([got.root_cell.side])}


def _scene(seed: int) -> TriangleMesh:
    """Objects at scales 1e-3 to 10 far apart, a few collapsed triangles (two corners at one
    position, or one vertex twice), three that are not (two corners apart on one axis only),
    vertices no face uses (one of them NaN)."""
    rng = np.random.default_rng(seed)
    parts, faces, offset = [], [], 0
    for _ in range(4):
        v = int(rng.integers(20, 400))
        parts.append(rng.normal(size=(v, 3)) * 10.0 ** rng.uniform(-3, 1) + rng.uniform(-100, 100, 3))
        faces.append(rng.integers(0, v, (int(rng.integers(30, 900)), 3)) + offset)
        offset += v
    for axis in range(3):  # two corners apart on this axis only: not collapsed
        corners = rng.normal(size=(3, 3)) * 5.0
        corners[1] = corners[0]
        corners[1, axis] += 0.25
        parts.append(corners)
        faces.append(np.arange(3)[None, :] + offset)
        offset += 3
    positions = np.concatenate(parts + [np.array([[np.nan, 0.0, 1.0], [1e9, -1e9, 3.0]])])
    faces = np.concatenate(faces)
    faces[:5, 1] = faces[:5, 0]
    positions[faces[5:9, 2]] = positions[faces[5:9, 1]]
    return TriangleMesh(positions=positions, faces=faces, name=f"scene {seed}")


@pytest.mark.parametrize("seed", range(4))
def test_prepare_makes_the_floats_of_its_definition(seed, monkeypatch):
    mesh = _scene(seed)
    if seed % 2:  # F-ordered faces, as meshes.merge concatenates pymeshlab's; chunks of a few rows
        mesh = TriangleMesh(positions=mesh.positions, faces=np.asfortranarray(mesh.faces), name=mesh.name)
        monkeypatch.setattr(prepare, "CENTROID_CHUNK", 29 + seed)
        monkeypatch.setattr(chunk_store, "TASK_ROWS", 50 + seed)  # tasks of a few chunks, the last one shorter
    want, got = _definition(mesh), _made(mesh)
    assert not want["counted"].all()
    for name, array in want.items():
        assert got[name].dtype == array.dtype and got[name].shape == array.shape, name
        assert np.array_equal(got[name].view(np.uint8), array.view(np.uint8)), name


@pytest.mark.parametrize("seed", range(8))
def test_a_zero_root_corner_keeps_the_sign_the_whole_array_reduction_gives_it(seed, monkeypatch):
    """A re-bake in a frame whose origin is 0.0: triangles at x = -0.0, 0.0, 1 or 2 (their
    centroids too), so the centroids' lowest x is a zero of either sign; the root cube is the
    input's own (the prior's lies far away). Its corner, which meta["frame"] records, is the
    C-ordered min(axis=0) of the centroids to the sign bit (taken column by column, the sign
    differs for some of these inputs)."""
    rng = np.random.default_rng(seed)
    t = int(rng.integers(8, 60))
    x = rng.choice([-0.0, 0.0, 1.0, 2.0], size=t)
    positions = np.concatenate([np.repeat(x, 3)[:, None], rng.random((3 * t, 2)) * 2.0], axis=1)
    mesh = TriangleMesh(positions=positions, faces=np.arange(3 * t).reshape(t, 3), name="signs")
    prior = Prior(Frame(origin=np.zeros(3), unit_length=3.0, root=RootCube(np.full(3, 100.0), 0.001)), "file")
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 1 + seed)  # each task's box of a few centroids
    got = prepare.prepare(mesh, prior)
    assert got.frame_choice.reason.startswith("the file frame's lattice, a new root cube")
    want = np.ascontiguousarray(got.centroids).min(axis=0)
    assert np.array_equal(got.root_cell.corner.view(np.uint64), want.view(np.uint64))
