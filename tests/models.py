"""The test models, by role: every mesh file the tests, benchmarks and scene specs read, named for
what it is there for, from one of three places (tests/meshes/SOURCES.md has their sources and
licences):

- in the repository (tests/meshes/): models whose licence allows it;
- pymeshlab's wheel (pymeshlab/tests/sample_meshes/, found through `pymeshlab.__file__`);
- generated here, deterministically (seeded), into .cache/models/ on first use, again when this
  module changes (a stamp beside each file), written to a temporary name and renamed so that a
  concurrent test process never reads half a file.

    role      triangles  box diagonal  what it stands for
    cow           5,804      2.1       a small closed model (pymeshlab's cow.obj)
    spot          5,856      2.6       a small closed model with texture coordinates (Keenan Crane's Spot)
    teapot        6,320      8.2       open surfaces: 19 patches, not watertight (the Utah teapot)
    airplane     10,796      2.3       a closed model of thin parts (pymeshlab's airplane.obj)
    bunny        55,384      0.25      a range scan with five holes, a quarter unit across
                                       (pymeshlab's bunny.obj, scaled, holes cut)
    creased      13,200      7.6       a CAD part: flat faces meeting at sharp creases
    ring         20,000      4.0       a bumpy torus: genus one, smooth
    statue      270,000      0.156     the big one, a binary PLY stored as triangle strips
    bust         99,372    658         large coordinates (hundreds of units from the origin)

The scales span four orders of magnitude (the statue 0.156 to the bust 658): code that assumes
unit-sized input breaks on them, which is the point.

The scene specs of tests/scenes/ name these files where they are (`scene(NAME)` writes what a spec
reads and returns its path).

    .venv/bin/python tests/models.py     # writes every model, prints role, path, triangles
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
IN_REPOSITORY = ROOT / "tests" / "meshes"
GENERATED = ROOT / ".cache" / "models"


@dataclass(frozen=True)
class Role:
    """One test model: its file name, and where it comes from: `make` writes it (generated or
    copied) into .cache/models/, or it is a file of the repository (make None)."""

    file: str
    make: Callable[[Path], None] | None = None


def path(name: str) -> Path:
    """The file of role `name` (ROLES), written first when it is generated and missing or stale."""
    try:
        role = ROLES[name]
    except KeyError:
        raise KeyError(f"no test model {name!r}; the roles are {', '.join(ROLES)}") from None
    if role.make is None:
        target = IN_REPOSITORY / role.file
        assert target.is_file(), f"test model missing: {target}"
        return target
    target = GENERATED / role.file
    stamp = GENERATED / f"{role.file}.stamp"
    want = _stamp(name)
    try:
        if stamp.read_text() == want and target.is_file():
            return target
    except OSError:
        pass
    GENERATED.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=f".{name}-", dir=GENERATED) as scratch:
        made = Path(scratch) / role.file
        role.make(made)
        os.replace(made, target)  # the model first, then its stamp: a fresh stamp means a fresh file
        (Path(scratch) / "stamp").write_text(want)
        os.replace(Path(scratch) / "stamp", stamp)
    return target


def load(name: str):
    """Role `name` read by the core as a TriangleMesh (a new mesh each call)."""
    from hlod_core.io import meshes

    return meshes.load_mesh(path(name))


def scene(name: str) -> Path:
    """The scene spec tests/scenes/NAME.json (written by tests/scenes/generate_specs.py), every
    model it reads written first."""
    spec = ROOT / "tests" / "scenes" / f"{name}.json"
    by_file = {role.file: role_name for role_name, role in ROLES.items()}
    for entry in json.loads(spec.read_text())["models"]:
        path(by_file[Path(entry["path"]).name])
    return spec


def input_file(given: str | os.PathLike) -> Path:
    """A benchmark's input as given on its command line: a role's name (ROLES) is its file, a spec
    of tests/scenes/ comes with its models written (`scene`), any other path is itself."""
    if str(given) in ROLES:
        return path(str(given))
    given = Path(given)
    if given.suffix == ".json" and given.resolve().parent == ROOT / "tests" / "scenes":
        return scene(given.stem)
    return given


def _stamp(name: str) -> str:
    """What a generated file of role `name` depends on: this module and pymeshlab's version."""
    from importlib.metadata import version

    source = Path(__file__).read_bytes()
    return hashlib.sha256(source + name.encode() + version("pymeshlab").encode()).hexdigest()


def pymeshlab_sample(file: str) -> Path:
    """A sample mesh of the installed pymeshlab wheel."""
    import pymeshlab

    return Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / file


# --- writers --------------------------------------------------------------------------------------

def write_obj(target: Path, positions: np.ndarray, faces: np.ndarray, *, digits: int = 7) -> None:
    """(v,3) positions and (f,3) 0-based faces as OBJ text, `digits` significant digits."""
    with open(target, "w") as out:
        out.write("# generated by tests/models.py\n")
        np.savetxt(out, positions, fmt=f"v %.{digits}g %.{digits}g %.{digits}g")
        np.savetxt(out, faces + 1, fmt="f %d %d %d")


def write_ply_strips(target: Path, positions: np.ndarray, strips: list[np.ndarray]) -> None:
    """A binary little-endian PLY of float32 vertices and one `tristrips` element: the strips joined
    by -1 (a strip (a, b, c, d, ...) is the triangles abc, cbd, cde, ...)."""
    joined = np.concatenate([np.append(s, -1) for s in strips])[:-1].astype("<i4")
    header = ("ply\nformat binary_little_endian 1.0\ncomment generated by tests/models.py\n"
              f"element vertex {positions.shape[0]}\nproperty float x\nproperty float y\nproperty float z\n"
              "element tristrips 1\nproperty list int int vertex_indices\nend_header\n")
    with open(target, "wb") as out:
        out.write(header.encode("ascii"))
        out.write(positions.astype("<f4").tobytes())
        out.write(np.array([joined.size], "<i4").tobytes())
        out.write(joined.tobytes())


# --- shapes ---------------------------------------------------------------------------------------

def cube_sphere_grids(n: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """The surface of a cube divided into n x n squares a side, welded: (v,3) unit directions
    (points of the cube pushed onto the unit sphere) and six (n+1, n+1) grids of vertex rows, each
    ordered so that its squares' corners (i, j), (i+1, j), (i, j+1) wind outwards."""
    lattice = np.full((n + 1,) * 3, -1, np.int64)
    steps = np.arange(n + 1)
    faces, points = [], []
    for axis in range(3):
        for side in (0, n):
            index = [np.full((n + 1, n + 1), side)] * 3
            a, b = [k for k in range(3) if k != axis]
            index[a], index[b] = np.meshgrid(steps, steps, indexing="ij")
            index = tuple(index)
            fresh = lattice[index] < 0
            lattice[tuple(i[fresh] for i in index)] = sum(len(p) for p in points) + np.arange(int(fresh.sum()))
            points.append(np.stack([i[fresh] for i in index], 1))
            faces.append(index)
    cube = np.concatenate(points).astype(float) / n * 2.0 - 1.0
    directions = cube / np.linalg.norm(cube, axis=1, keepdims=True)
    grids = []
    for index in faces:  # outward: the first square's normal points away from the centre
        grid = lattice[index]
        p0, p1, p2 = directions[grid[0, 0]], directions[grid[1, 0]], directions[grid[0, 1]]
        grids.append(grid if np.dot(np.cross(p1 - p0, p2 - p0), p0) > 0 else grid.T)
    return directions, grids


def grid_faces(grid: np.ndarray) -> np.ndarray:
    """(2 (r-1)(c-1), 3) triangles of an (r, c) grid of vertex rows, wound as its strips wind them."""
    a, b, c, d = grid[:-1, :-1], grid[1:, :-1], grid[:-1, 1:], grid[1:, 1:]
    return np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([c, b, d], -1).reshape(-1, 3)])


def grid_strips(grid: np.ndarray) -> list[np.ndarray]:
    """One triangle strip per row of squares of an (r, c) grid: a, b, c, d, ... = grid[i, 0],
    grid[i + 1, 0], grid[i, 1], grid[i + 1, 1], ..."""
    return [np.stack([grid[i], grid[i + 1]], 1).ravel() for i in range(grid.shape[0] - 1)]


def bumps(directions: np.ndarray, *, seed: int, waves: int, amplitude: float) -> np.ndarray:
    """(v,) a smooth seeded relief over unit directions: `waves` plane waves of random direction,
    frequency 2 to 24 and amplitude falling as 1/frequency, scaled to at most `amplitude`."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(waves, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    frequency = np.exp(rng.uniform(np.log(2.0), np.log(24.0), waves))
    phase = rng.uniform(0.0, 2.0 * np.pi, waves)
    relief = np.sin((directions @ axes.T) * frequency + phase) @ (1.0 / frequency)
    return amplitude * relief / np.abs(relief).max()


def _fit(positions: np.ndarray, *, diagonal: float, centre=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Scaled so that the box diagonal is `diagonal`, its centre at `centre`."""
    low, high = positions.min(axis=0), positions.max(axis=0)
    scale = diagonal / float(np.linalg.norm(high - low))
    return (positions - 0.5 * (low + high)) * scale + np.asarray(centre, float)


def blob(n: int, *, seed: int, axes, diagonal: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """A closed, star-shaped bumpy blob on a cube sphere of n x n squares a side (12 n^2
    triangles): (v,3) positions and the six grids of cube_sphere_grids."""
    directions, grids = cube_sphere_grids(n)
    radius = 1.0 + bumps(directions, seed=seed, waves=40, amplitude=0.25)
    return _fit(directions * radius[:, None] * np.asarray(axes, float), diagonal=diagonal), grids


def make_statue(target: Path) -> None:
    """270,000 triangles (igea's size, 0.156 across), written as triangle strips."""
    positions, grids = blob(150, seed=11, axes=(0.7, 1.0, 1.0), diagonal=0.156)
    write_ply_strips(target, positions, [s for g in grids for s in grid_strips(g)])


def make_bust(target: Path) -> None:
    """99,372 triangles, 658 units across, centred on the origin (coordinates in the hundreds)."""
    positions, grids = blob(91, seed=12, axes=(0.48, 0.73, 1.0), diagonal=658.0)
    write_obj(target, positions, np.concatenate([grid_faces(g) for g in grids]), digits=9)


def make_ring(target: Path) -> None:
    """A torus (radii 1 and 0.35) with a seeded relief, 100 x 100 squares: 20,000 triangles."""
    u, v = np.meshgrid(np.arange(100) * 2 * np.pi / 100, np.arange(100) * 2 * np.pi / 100, indexing="ij")
    around = np.stack([np.cos(u) * np.cos(v), np.sin(u) * np.cos(v), np.sin(v)], -1).reshape(-1, 3)
    tube = 0.35 * (1.0 + bumps(around, seed=13, waves=24, amplitude=0.3))
    centre = np.stack([np.cos(u), np.sin(u), np.zeros_like(u)], -1).reshape(-1, 3)
    normal = np.stack([np.cos(u) * np.cos(v), np.sin(u) * np.cos(v), np.sin(v)], -1).reshape(-1, 3)
    positions = centre + tube[:, None] * normal
    grid = np.arange(100 * 100).reshape(100, 100)
    closed = np.concatenate([grid, grid[:1]], 0)
    closed = np.concatenate([closed, closed[:, :1]], 1)
    write_obj(target, positions, grid_faces(closed))


#: The creased part's profile (radius, height) from the bottom centre to the top centre: steps with
#: vertical walls, each corner a sharp crease.
CREASED_PROFILE = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.2], [2.2, 1.2], [2.2, 2.6], [1.4, 2.6], [1.4, 3.4],
                            [2.0, 3.4], [2.0, 4.0], [0.0, 4.0]])


def make_creased(target: Path) -> None:
    """A stepped solid of hexagonal section (its profile CREASED_PROFILE): flat faces meeting at
    sharp creases around it (the steps) and along it (the hexagon's corners), a closed surface of
    13,200 triangles, 7.6 units across."""
    per_side = 20
    corner = np.arange(7) * np.pi / 3
    t = np.arange(per_side) / per_side
    ring = np.concatenate([np.stack([np.cos(corner[k]) * (1 - t) + np.cos(corner[k + 1]) * t,
                                     np.sin(corner[k]) * (1 - t) + np.sin(corner[k + 1]) * t], 1) for k in range(6)])
    # the profile sampled about evenly by length, every corner kept
    samples = [CREASED_PROFILE[0]]
    for p, q in zip(CREASED_PROFILE[:-1], CREASED_PROFILE[1:]):
        pieces = max(1, int(round(np.linalg.norm(q - p) / 0.2)))
        samples.extend(p + (q - p) * (k / pieces) for k in range(1, pieces + 1))
    profile = np.array(samples)
    inner = profile[1:-1]  # the two ends are the poles
    columns = ring.shape[0]
    rings = np.concatenate([np.stack([r * ring[:, 0], r * ring[:, 1], np.full(columns, z)], 1) for r, z in inner])
    bottom, top = rings.shape[0], rings.shape[0] + 1
    positions = np.concatenate([rings, [[0.0, 0.0, profile[0, 1]], [0.0, 0.0, profile[-1, 1]]]])
    grid = np.arange(inner.shape[0] * columns).reshape(inner.shape[0], columns)
    grid = np.concatenate([grid, grid[:, :1]], 1)  # closed around
    faces = [grid_faces(grid[::-1])]
    nxt = np.roll(np.arange(columns), -1)
    faces.append(np.stack([np.full(columns, bottom), nxt, np.arange(columns)], 1))
    last = grid[-1, :-1]
    faces.append(np.stack([np.full(columns, top), last, last[nxt]], 1))
    positions = _fit(positions, diagonal=7.6)
    write_obj(target, positions, np.concatenate(faces))


#: The bunny's holes: this many, each the triangles within HOLE_RADIUS (box diagonals) of a seeded vertex.
HOLES, HOLE_RADIUS = 5, 0.025


def make_bunny(target: Path) -> None:
    """pymeshlab's bunny (56,172 triangles, closed) scaled to 0.25 across, with HOLES holes cut."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(pymeshlab_sample("bunny.obj")))
    positions = _fit(ms.current_mesh().vertex_matrix(), diagonal=0.25, centre=(0.0, 0.1, 0.0))
    faces = ms.current_mesh().face_matrix().astype(np.int64)
    rng = np.random.default_rng(14)
    centres = positions[rng.choice(positions.shape[0], HOLES, replace=False)]
    near = np.zeros(positions.shape[0], bool)
    for c in centres:
        near |= np.linalg.norm(positions - c, axis=1) < HOLE_RADIUS * 0.25
    keep = ~near[faces].any(axis=1)
    used = np.unique(faces[keep])
    rows = np.full(positions.shape[0], -1)
    rows[used] = np.arange(used.size)
    write_obj(target, positions[used], rows[faces[keep]])


def _copy_of(sample: str) -> Callable[[Path], None]:
    """A maker that copies pymeshlab's sample mesh (so that scene specs find it at a fixed path)."""
    return lambda target: shutil.copyfile(pymeshlab_sample(sample), target)


ROLES: dict[str, Role] = {
    "cow": Role("cow.obj", _copy_of("cow.obj")),
    "spot": Role("spot.obj"),
    "teapot": Role("teapot.obj"),
    "airplane": Role("airplane.obj", _copy_of("airplane.obj")),
    "bunny": Role("bunny.obj", make_bunny),
    "creased": Role("creased.obj", make_creased),
    "ring": Role("ring.obj", make_ring),
    "statue": Role("statue.ply", make_statue),
    "bust": Role("bust.obj", make_bust),
}
#: The OBJ models (the reader's checks run on every one of them).
OBJ_ROLES = tuple(name for name, role in ROLES.items() if role.file.endswith(".obj"))


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    for role in ROLES:
        print(role, path(role), load(role).tri_count)
