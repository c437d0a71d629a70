"""The bake's input as the octree and the leaves see it (an in-memory TriangleMesh): the frame
(frame.py: the origin, the lattice, the root cube), file-relative float32 positions, triangle
centroids and counted (not collapsed) triangles, and with appearance the vertices turned into
attribute rows; then each leaf's triangles.

Data form: positions (r,3) float32 relative to the origin (3,) float64 (from scratch the centre of
the used vertices' box), each a point of the bake's lattice (lattice.py, unit_length: from scratch
the box's longest extent); faces (f,3) int64; centroids (f,3) float64 of the float32 corners
(what is stored is what is split); counted (f,) bool. The streamed input (partition.py) computes
the same floats piece by piece with `triangle_centroids`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..core.arrays import compact
from ..core.errors import InputError
from ..io.meshes import TriangleMesh
from ..model import appearance
from . import frame as frames
from . import lattice
from .octree import OctreeLayout, RootCube
from .simplify import collapsed_corners

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class Prepared:
    """root_cell (octree.RootCube, model units, origin-relative) and origin (3,) f64; unit_length
    (model units) of the lattice the positions are points of (lattice.py); frame_choice: where
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


def triangle_centroids(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangles by their corners a, b, c (t,3) float32 (origin-relative): centroids (t,3) float64,
    (a + b + c) / 3 summed in this order, and counted (t,) bool, the triangles that are not
    collapsed (simplify.collapsed_corners): the only place either is computed."""
    centroids = a.astype(np.float64)
    centroids += b
    centroids += c
    centroids /= 3.0
    return centroids, ~collapsed_corners(a, b, c)


def prepare(mesh: TriangleMesh, prior: frames.Prior | None = None) -> Prepared:
    """The frame (frame.py: `prior`'s while the input fits it, else the input's own: the origin
    the centre of the used vertices' box, the lattice its longest extent, the root cube around the
    centroids); float32 positions relative to the origin, points of the lattice (lattice.py);
    triangle centroids of those positions; with appearance, the vertices become attribute rows
    (`pack_rows`). InputError for a mesh without triangles or with non-finite coordinates."""
    if mesh.tri_count == 0:
        raise InputError(f"{mesh.name}: the mesh has no triangles")
    used = np.zeros(mesh.positions.shape[0], bool)
    used[mesh.faces.ravel()] = True
    p_used = mesh.positions[used]
    if not np.all(np.isfinite(p_used)):
        raise InputError(f"{mesh.name}: vertices used by faces have NaN or infinite coordinates")
    lo, hi = p_used.min(axis=0), p_used.max(axis=0)
    del p_used
    origin, length, lattice_why = frames.choose_lattice(prior, lo, hi)
    rel = mesh.positions - origin
    rel[~used] = 0.0  # unused vertices may hold anything (even NaN); they are never stored
    positions = lattice.stored(rel, length)
    if not np.all(np.isfinite(positions)):
        raise InputError(f"{mesh.name}: coordinates exceed the float32 range after centring")
    faces = mesh.faces
    centroids, counted = triangle_centroids(*(positions[faces[:, k]] for k in range(3)))
    root_prior = prior if lattice_why is None else None
    root_cell, root_why = frames.choose_root(root_prior, centroids.min(axis=0), centroids.max(axis=0))
    choice = frames.choice_of(prior, lattice_why=lattice_why, root_why=root_why,
                              grew=len(root_cell.growths) - len(prior.frame.root.growths) if root_prior else 0)
    normals, rows, row_layout = mesh.normals, None, appearance.AttributeLayout(False, False, False)
    if mesh.has_appearance:
        row_layout, positions, faces, normals, rows = pack_rows(mesh, positions, normals)
    return Prepared(origin=origin, unit_length=length, root_cell=root_cell, positions=positions, faces=faces,
                    normals=normals, rows=rows,
                    row_layout=row_layout, centroids=centroids, counted=counted, frame_choice=choice)


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


def leaf_lods(layout: OctreeLayout, prepared: Prepared) -> list[tuple | None]:
    """Per node, None for inner nodes and for each leaf (positions (k,3) f32, faces (m,3) int32
    local to them, normals (k,3) f32 or None, rows (k,A) f32 or None) of the vertices its triangles
    use, in ascending input order (arrays.compact): leaves keep their original triangles."""
    lods: list[tuple | None] = [None] * layout.node_count
    ordered_faces = prepared.faces[layout.tri_order]
    normals, rows = prepared.normals, prepared.rows
    for node in np.flatnonzero(layout.is_leaf):
        p, f, used = compact(prepared.positions, ordered_faces[layout.tri_begin[node]:layout.tri_end[node]])
        lods[node] = (p, f, None if normals is None else normals[used], None if rows is None else rows[used])
    return lods
