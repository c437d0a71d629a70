"""The bake's input as the octree and the leaves see it (an in-memory TriangleMesh): the frame
(bake/space/frame.py: the origin, the lattice, the root cube), file-relative float32 positions, triangle
centroids and counted (not collapsed) triangles, and with appearance the vertices turned into
attribute rows; then each leaf's triangles.

Data form: positions (r,3) float32 relative to the origin (3,) float64 (from scratch the centre of
the used vertices' box), each a point of the bake's lattice (bake/space/lattice.py, unit_length: from scratch
the box's longest extent); faces (f,3) int64; centroids (f,3) float64 of the float32 corners
(what is stored is what is split); counted (f,) bool. The streamed input (bake/space/partition.py) computes
the same floats piece by piece with `triangle_centroids`.

The passes over every vertex and triangle (the used vertices, their box, the stored positions, the
centroids; the leaves' compaction) are tasks over index chunks (`*_task`), run by a chunk store
(bake/space/chunk_store.py) on the bake's workers or inline; this process takes the regions' boxes'
minimum and maximum and raises the input's errors. The same floats wherever they run.
Why: docs/how-it-works.md#the-early-phases-as-chunk-tasks
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..core.arrays import compact
from ..core.errors import InputError
from ..io.meshes import TriangleMesh
from ..model import appearance
from .decimate.simplify import collapsed_corners
from .space import chunk_store, lattice
from .space import frame as frames
from .space.octree import OctreeLayout, RootCube

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Prepared:
    """root_cell (octree.RootCube, model units, origin-relative) and origin (3,) f64; unit_length
    (model units) of the lattice the positions are points of (bake/space/lattice.py); frame_choice: where
    that frame came from (frame.FrameChoice); positions
    (r,3) f32 relative to the origin, faces (f,3) int64, normals (r,3) f32 or None and attribute
    rows (r,A) f32 or None (with appearance the rows of appearance.pack, else the vertices);
    row_layout: the rows' columns (empty without); centroids (f,3) f64 origin-relative (None once
    the octree is built); counted (f,) bool (not simplify.collapsed)."""

    origin: np.ndarray
    unit_length: float
    root_cell: RootCube
    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    rows: np.ndarray | None
    row_layout: appearance.AttributeLayout
    centroids: np.ndarray | None
    counted: np.ndarray
    frame_choice: frames.FrameChoice

    @property
    def frame(self) -> frames.Frame:
        return frames.Frame(origin=self.origin, unit_length=self.unit_length, root=self.root_cell)


def triangle_centroids(a: np.ndarray, b: np.ndarray, c: np.ndarray, *,
                       out: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangles by their corners a, b, c (t,3) float32 (origin-relative, any strides): centroids
    (t,3) float64, (a + b + c) / 3 summed in this order, and counted (t,) bool, the triangles that
    are not collapsed (simplify.collapsed_corners): the only place either is computed. out: (3,t)
    float64 to write the centroids into, axis by axis (returned as its (t,3) transpose)."""
    if out is None:
        out = np.empty((3, a.shape[0]), np.float64)
    for axis in range(3):
        column = out[axis]
        np.add(a[:, axis], b[:, axis], out=column, dtype=np.float64)
        column += c[:, axis]
        column /= 3.0
    return out.T, ~collapsed_corners(a, b, c)


def prepare(mesh: TriangleMesh, prior: frames.Prior | None = None, *,
            store: chunk_store.ChunkStore | None = None) -> Prepared:
    """The frame (bake/space/frame.py: `prior`'s while the input fits it, else the input's own: the origin
    the centre of the used vertices' box, the lattice its longest extent, the root cube around the
    centroids); float32 positions relative to the origin, points of the lattice (bake/space/lattice.py);
    triangle centroids of those positions; with appearance, the vertices become attribute rows
    (`pack_rows`). InputError for a mesh without triangles or with non-finite coordinates.
    The positions and centroids are made CENTROID_CHUNK rows at a time; store: where the octree's
    tasks read the centroids (bake/space/chunk_store.py: its "centroids" array, written in place)."""
    if mesh.tri_count == 0:
        raise InputError(f"{mesh.name}: the mesh has no triangles")
    store = chunk_store.ChunkStore() if store is None else store
    faces = mesh.faces
    store.put("faces", faces)
    store.put("source", mesh.positions)
    store.create("used", (mesh.positions.shape[0],), bool, zeros=True)
    store.run(mark_used_task, store.regions(faces.shape[0]))
    every = bool(store.get("used").all())
    vertices = store.regions(mesh.positions.shape[0])
    boxes = store.run(used_box_task, [(start, end, every) for start, end in vertices])
    if not all(finite for finite, _, _ in boxes):
        raise InputError(f"{mesh.name}: vertices used by faces have NaN or infinite coordinates")
    lo = np.min([b for _, b, _ in boxes if b is not None], axis=0)
    hi = np.max([b for _, _, b in boxes if b is not None], axis=0)
    if np.any(lo == 0.0) or np.any(hi == 0.0):  # a zero's sign depends on the reduction's order
        lo, hi = box(mesh.positions if every else mesh.positions[np.asarray(store.get("used"))])
    origin, length, lattice_why = frames.choose_lattice(prior, lo, hi)
    corners = store.create("corners", (mesh.positions.shape[0], 4), np.float32, zeros=True)
    finite = store.run(position_task, [(start, end, origin, length, every) for start, end in vertices])
    for name in ("source", "used"):
        store.drop(name)
    if not all(finite):
        raise InputError(f"{mesh.name}: coordinates exceed the float32 range after centring")
    positions = np.ascontiguousarray(corners[:, :3])
    centroids, counted, (lo, hi) = face_centroids(positions, faces, store=store)
    root_prior = prior if lattice_why is None else None
    root_cell, root_why = frames.choose_root(root_prior, lo, hi)
    choice = frames.choice_of(prior, lattice_why=lattice_why, root_why=root_why,
                              grew=len(root_cell.growths) - len(prior.frame.root.growths) if root_prior else 0)
    normals, rows, row_layout = mesh.normals, None, appearance.AttributeLayout(False, False, False)
    if mesh.has_appearance:
        row_layout, positions, faces, normals, rows = pack_rows(mesh, positions, normals)
    return Prepared(origin=origin, unit_length=length, root_cell=root_cell, positions=positions, faces=faces,
                    normals=normals, rows=rows,
                    row_layout=row_layout, centroids=centroids, counted=counted, frame_choice=choice)


def mark_used_task(store: chunk_store.ChunkStore, start: int, end: int) -> None:
    """prepare's task over the triangles start..end-1: the vertices they use marked in the store's
    "used" (every task writes only True: tasks that share a vertex write the same byte)."""
    used, faces = store.get("used"), store.get("faces")
    for begin in range(start, end, CENTROID_CHUNK):
        used[np.asarray(faces[begin:min(end, begin + CENTROID_CHUNK)]).ravel(order="K")] = True


def used_box_task(store: chunk_store.ChunkStore, start: int, end: int, every: bool):
    """prepare's task over the vertices start..end-1 of the store's "source" (the input's positions):
    (whether the used ones are finite, their box's lo and hi (3,) float64 per axis, None for none)."""
    points = np.asarray(store.get("source")[start:end])
    if not every:
        points = points[np.asarray(store.get("used")[start:end])]
    if points.shape[0] == 0:
        return True, None, None
    if not np.all(np.isfinite(points)):
        return False, None, None
    return (True, np.array([points[:, k].min() for k in range(3)], np.float64),
            np.array([points[:, k].max() for k in range(3)], np.float64))


def position_task(store: chunk_store.ChunkStore, start: int, end: int, origin: np.ndarray, length: float,
                  every: bool) -> bool:
    """prepare's task over the vertices start..end-1: their stored positions (float32, origin-relative,
    lattice points: lattice.stored) written into the store's "corners" (padded to 4 floats), an unused
    vertex at the origin, CENTROID_CHUNK at a time; returns whether all are finite."""
    source, corners = store.get("source"), store.get("corners")
    used = None if every else store.get("used")
    finite = True
    for begin in range(start, end, CENTROID_CHUNK):  # small temporaries, reused
        stop = min(end, begin + CENTROID_CHUNK)
        rel = np.empty((stop - begin, 3), np.float64)
        np.subtract(source[begin:stop], origin, out=rel)
        if used is not None:
            rel[~np.asarray(used[begin:stop])] = 0.0  # unused vertices may hold anything (even NaN); never stored
        stored = lattice.stored(rel, length, overwrite=True)
        finite = finite and bool(np.all(np.isfinite(stored)))
        corners[begin:stop, :3] = stored
    return finite


def box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) float64 of finite points (n,3): points.min(axis=0) and .max(axis=0) of their
    C-ordered copy, as prepare always took them, column by column (several times faster on rows of
    three). Where a bound is a zero, which of -0.0 and 0.0 comes back depends on the reduction's
    order, so that box is taken the old way."""
    lo = np.array([points[:, k].min() for k in range(3)], np.float64)
    hi = np.array([points[:, k].max() for k in range(3)], np.float64)
    if np.any(lo == 0.0) or np.any(hi == 0.0):
        rows = np.ascontiguousarray(points)
        return rows.min(axis=0).astype(np.float64), rows.max(axis=0).astype(np.float64)
    return lo, hi


#: Vertices `prepare` stores and triangles `face_centroids` gathers at a time (temporaries of at
#: most 64 bytes a row, reused from chunk to chunk instead of new arrays of the input's length).
CENTROID_CHUNK = 1 << 18


def face_centroids(positions: np.ndarray, faces: np.ndarray, *, store: chunk_store.ChunkStore | None = None):
    """triangle_centroids of the triangles faces (f,3) of positions (r,3) float32: centroids (f,3)
    float64 (a transposed (3,f): each axis contiguous, as the octree reads them), counted (f,)
    bool and the centroids' box (lo, hi) (3,) float64 (`box`'s). As tasks over index chunks of the
    triangles (`centroid_task`, chunk_store.regions) on the store's workers (None: inline, here),
    which write the store's "centroids" and "counted"; the faces and the padded positions are
    shared with them (copied into the store's files for workers: 16 bytes a vertex, 24 a triangle),
    and stay there for the leaves (`leaf_lods`)."""
    store = chunk_store.ChunkStore() if store is None else store
    if "corners" not in store:  # prepare's position tasks made them
        padded = np.zeros((positions.shape[0], 4), np.float32)
        padded[:, :3] = positions
        store.put("corners", padded)
    if "faces" not in store:
        store.put("faces", faces)
    f = faces.shape[0]
    centroids = store.create("centroids", (3, f), np.float64)
    counted = store.create("counted", (f,), bool)
    bounds = [b for b in store.run(centroid_task, store.regions(f)) if b is not None]
    lo = np.min([b[0] for b in bounds], axis=0)
    hi = np.max([b[1] for b in bounds], axis=0)
    if np.any(lo == 0.0) or np.any(hi == 0.0):  # a zero's sign depends on the reduction's order
        lo, hi = box(centroids.T)
    return centroids.T, (np.array(counted) if store.folder else counted), (lo, hi)


def centroid_task(store: chunk_store.ChunkStore, start: int, end: int) -> tuple[np.ndarray, np.ndarray] | None:
    """face_centroids' task over the triangles start..end-1: their centroids and counted written,
    CENTROID_CHUNK triangles at a time, the corners gathered as one 16-byte item a vertex (the
    store's "corners", positions padded to 4 floats: a 1-D gather about 3x faster than rows of 3
    floats); returns their centroids' (lo, hi) (3,) float64 per axis (None for no triangles)."""
    items = store.get("corners").view(np.complex128).reshape(-1)
    faces, centroids, counted = store.get("faces"), store.get("centroids"), store.get("counted")
    for begin in range(start, end, CENTROID_CHUNK):
        stop = min(end, begin + CENTROID_CHUNK)
        a, b, c = (items[faces[begin:stop, k]].view(np.float32).reshape(-1, 4) for k in range(3))
        counted[begin:stop] = triangle_centroids(a, b, c, out=centroids[:, begin:stop])[1]
    if end == start:
        return None
    return (np.array([centroids[k, start:end].min() for k in range(3)], np.float64),
            np.array([centroids[k, start:end].max() for k in range(3)], np.float64))


def pack_rows(mesh: TriangleMesh, positions: np.ndarray, normals: np.ndarray | None):
    """The bake's vertices as attribute rows (appearance.pack): (layout, positions (r,3) f32,
    faces (f,3) int64 rows, normals (r,3) f32 or None, rows (r,A) f32). A vertex used by
    triangles of several materials becomes one row per material, at the vertex's position."""
    layout, vertex, rows, faces = appearance.pack(positions.shape[0], mesh.faces, material_ids=mesh.material_ids,
                                                  uvs=mesh.uvs, colors=mesh.colors)
    rows = rows + np.float32(0.0)  # -0.0 -> 0.0: the weld compares bytes
    log.info("appearance: %d attribute rows of %d columns for %d vertices", rows.shape[0], layout.width,
             positions.shape[0])
    return layout, positions[vertex], faces, None if normals is None else normals[vertex], rows


def leaf_lods(layout: OctreeLayout, prepared: Prepared,
              store: chunk_store.ChunkStore | None = None) -> list[tuple | None]:
    """Per node, None for inner nodes and for each leaf (positions (k,3) f32, faces (m,3) int32
    local to them, normals (k,3) f32 or None, rows (k,A) f32 or None) of the vertices its triangles
    use, in ascending input order (arrays.compact): leaves keep their original triangles.
    store: the one prepare and the octree used; on workers (its folder set) and without attribute
    rows, the leaves are made by tasks over runs of whole leaves (`leaf_task`: the leaves whose
    first triangle lies in one of the store's regions) from its "faces", "corners" and "tri_order",
    each run's arrays sent back once and each leaf a view of them; else here, leaf by leaf."""
    if store is not None and store.folder and prepared.rows is None and "tri_order" in store:
        return _leaf_lods_of_tasks(layout, prepared, store)
    lods: list[tuple | None] = [None] * layout.node_count
    ordered_faces = prepared.faces[layout.tri_order]
    normals, rows = prepared.normals, prepared.rows
    for node in np.flatnonzero(layout.is_leaf):
        p, f, used = compact(prepared.positions, ordered_faces[layout.tri_begin[node]:layout.tri_end[node]])
        lods[node] = (p, f, None if normals is None else normals[used], None if rows is None else rows[used])
    return lods


def _leaf_lods_of_tasks(layout: OctreeLayout, prepared: Prepared, store: chunk_store.ChunkStore) -> list:
    """leaf_lods as tasks on the store's workers (its docstring)."""
    lods: list[tuple | None] = [None] * layout.node_count
    leaves = np.flatnonzero(layout.is_leaf)
    leaves = leaves[np.argsort(layout.tri_begin[leaves], kind="stable")]
    begin, end = layout.tri_begin[leaves], layout.tri_end[leaves]
    starts = np.array([start for start, _ in store.regions(int(layout.tri_order.shape[0]))])
    run_of = np.searchsorted(starts, begin, side="right") - 1
    cuts = np.flatnonzero(np.diff(run_of)) + 1
    runs = np.split(np.arange(leaves.size), cuts)
    with_normals = prepared.normals is not None
    if with_normals:
        store.put("normals", prepared.normals)
    made = store.run(leaf_task, [(begin[run], end[run], with_normals) for run in runs])
    for run, (positions, faces, normals, vertices) in zip(runs, made):
        v_end, f_end = np.cumsum(vertices), np.cumsum(end[run] - begin[run])
        for leaf, v1, v0, f1, f0 in zip(leaves[run], v_end, v_end - vertices, f_end, f_end - (end[run] - begin[run])):
            lods[leaf] = (positions[v0:v1], faces[f0:f1], None if normals is None else normals[v0:v1], None)
    return lods


def leaf_task(store: chunk_store.ChunkStore, begin: np.ndarray, end: np.ndarray, with_normals: bool):
    """The leaves of one run, each of the triangles tri_order[begin:end] ((k,) int64 each) of the
    store's "tri_order", "faces" and "corners" (and "normals"), compacted as leaf_lods does: their
    positions (V,3) f32, faces (F,3) int32 local to each leaf, normals (V,3) f32 or None, leaf
    after leaf, and vertices (k,) int64, each leaf's."""
    order, faces, corners = store.get("tri_order"), store.get("faces"), store.get("corners")
    normals = store.get("normals") if with_normals else None
    points, local, kept, vertices = [], [], [], np.zeros(begin.shape[0], np.int64)
    for i, (b, e) in enumerate(zip(begin, end)):
        p, f, used = compact(corners, faces[np.asarray(order[b:e])])
        points.append(p[:, :3])
        local.append(f)
        vertices[i] = used.shape[0]
        if normals is not None:
            kept.append(normals[used])
    return (np.concatenate(points) if points else np.zeros((0, 3), np.float32),
            np.concatenate(local) if local else np.zeros((0, 3), np.int32),
            np.concatenate(kept) if kept else (np.zeros((0, 3), np.float32) if with_normals else None), vertices)
