"""pymeshlab as the bake uses it: the unit frame every node is decimated and measured in
(`NodeFrame`), MeshSets, the quadric edge collapse (Garland & Heckbert 1997, pymeshlab
`meshing_decimation_quadric_edge_collapse`) and unit vertex normals.

Data form: positions (k,3) float64 in the node's unit frame (`NodeFrame.to_local`), faces (m,3)
int32 local to them; optional vertex ids (k,) float64 carried through a collapse as pymeshlab's
vertex scalar.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..space import lattice

#: Fewest triangles asked of pymeshlab. An edge collapse removes the edge's two triangles, so a
#: closed surface decimated to 1 triangle goes from 2 to 0 and pymeshlab returns an empty mesh.
MIN_DECIMATION_TRIS = 2

#: Box diagonal of a node in the frame pymeshlab decimates and measures it in (NodeFrame). With 1,
#: every edge is shorter than 1, so vcglib's tie rule (1e-15 x edge length) ranks exactly planar
#: collapses before all others, as it does for the unit-sized models it was tuned on.
UNIT_DIAGONAL = 1.0


@dataclass(frozen=True)
class DecimationSettings:
    """target_tris: triangles per LOD; quality_threshold: pymeshlab `qualitythr` (0..1, penalises
    thin triangles); preserve_normals: pymeshlab `preservenormal` (no face flips);
    boundary_weight: pymeshlab `boundaryweight`, the weight of the planes along open boundary edges
    in the quadrics (1: as much as the surface; more keeps a model's open boundaries, its
    silhouette there, longer)."""

    target_tris: int = 2000
    quality_threshold: float = 0.3
    preserve_normals: bool = False
    boundary_weight: float = 1.0


@dataclass(frozen=True)
class NodeFrame:
    """The unit frame pymeshlab works in: local = (x - center) * scale, with the node's box
    centred on the origin and its diagonal UNIT_DIAGONAL (scale = 1 for a node of one point).
    x is the model position, or with unit_length > 0 the canonical coordinate of a bake's stored
    position (bake/space/lattice.py), so the frame and every local coordinate are the same numbers at every
    scale. It makes pymeshlab's absolute thresholds scale-free, so a model baked in millimetres
    gives the LODs of the same model in metres, scaled.
    Why: docs/how-it-works.md#the-unit-frame-of-a-node"""

    center: np.ndarray        # (3,) float64, model units (canonical units with unit_length)
    scale: float              # 1 / those units
    unit_length: float = 0.0  # the lattice's unit, model units; 0: positions are not on it

    @staticmethod
    def of(positions: np.ndarray, *, unit_length: float = 0.0) -> "NodeFrame":
        """The unit frame of positions (k,3), k >= 1, finite; with unit_length, stored lattice
        positions (bake/space/lattice.py) framed by their canonical coordinates."""
        p = lattice.canonical(positions, unit_length) if unit_length > 0 else np.asarray(positions, np.float64)
        frame = NodeFrame.of_box(p.min(axis=0), p.max(axis=0))
        return NodeFrame(center=frame.center, scale=frame.scale, unit_length=unit_length)

    @staticmethod
    def of_box(lo: np.ndarray, hi: np.ndarray) -> "NodeFrame":
        """The unit frame of the box lo..hi (3,) float64 (`of` of positions whose box it is)."""
        diagonal = float(np.linalg.norm(hi - lo))
        return NodeFrame(center=0.5 * (lo + hi), scale=UNIT_DIAGONAL / diagonal if diagonal > 0 else 1.0)

    def to_local(self, positions: np.ndarray) -> np.ndarray:
        """(k,3) model units -> (k,3) float64 in the unit frame."""
        if self.unit_length > 0:
            return (lattice.canonical(positions, self.unit_length) - self.center) * self.scale
        return (np.asarray(positions, np.float64) - self.center) * self.scale

    def to_model(self, local_out: np.ndarray, local_in: np.ndarray, model_in: np.ndarray) -> np.ndarray:
        """(j,3) float64 pymeshlab output -> (j,3) float32 model units (lattice points with
        unit_length). A vertex bit-identical to an input `local_in` row was not moved: it gets
        that row's exact `model_in` (float32) position, which the inverse transform would only
        round to."""
        back = np.asarray(local_out, np.float64) / self.scale + self.center
        if self.unit_length > 0:
            out = lattice.from_canonical(back, self.unit_length)
        else:
            out = back.astype(np.float32)
        if local_out.shape[0] == 0 or local_in.shape[0] == 0:
            return out
        keys_in = row_keys(local_in)
        order = np.argsort(keys_in, kind="stable")
        sorted_in = keys_in[order]
        keys_out = row_keys(local_out)
        at = np.minimum(np.searchsorted(sorted_in, keys_out), sorted_in.shape[0] - 1)
        unmoved = sorted_in[at] == keys_out
        out[unmoved] = np.asarray(model_in, np.float32)[order[at[unmoved]]]
        return out


def row_keys(rows: np.ndarray) -> np.ndarray:
    """(k,3) float64 rows as (k,) 24-byte keys, equal exactly when the rows are bit-identical."""
    return np.ascontiguousarray(rows, dtype=np.float64).view(np.dtype((np.void, 24))).ravel()


def mesh_set(positions: np.ndarray, faces: np.ndarray, vertex_ids: np.ndarray | None = None):
    """A pymeshlab MeshSet of one mesh; vertex_ids (k,) float64, when given, as its vertex scalar."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    if vertex_ids is None:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=positions.astype(np.float64), face_matrix=faces))
    else:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=positions.astype(np.float64), face_matrix=faces,
                                   v_scalar_array=np.asarray(vertex_ids, np.float64)))
    return ms


def quadric_collapse(positions, faces, settings: DecimationSettings, *, optimal_placement: bool,
                     vertex_ids: np.ndarray | None = None, locked: np.ndarray | None = None,
                     coincident: bool = False):
    """The MeshSet of positions (unit frame) and faces after a quadric edge collapse to
    settings.target_tris, with planar quadrics (they keep a flat cell's singular quadric from
    placing a vertex far outside it). locked (k,) bool: vertices that stay where they are,
    bit-identical, and keep their edges; every other vertex may collapse, open boundaries
    included, whose edges add planes weighted by settings.boundary_weight to the quadrics
    (`lock_by_selection` says how). None: the vertices on open edges, with pymeshlab's boundary
    preservation (the same LOD, bit for bit, and about 3% faster than a selection:
    benchmarks/seam_locks.py). vertex_ids (k,) float64:
    carried through the collapse as the vertex scalar. coincident: vertices may share positions
    (a node with attribute rows: its seams), which pymeshlab's autoclean would merge: only the rest
    of its clean-up, null faces and unreferenced vertices, runs."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    if locked is None:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(positions, np.float64), face_matrix=faces,
                                   v_scalar_array=np.zeros(0) if vertex_ids is None else vertex_ids))
    else:
        positions, faces, face_flag, vertex_ids = lock_by_selection(positions, faces, np.asarray(locked, bool),
                                                                    vertex_ids=vertex_ids)
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=positions, face_matrix=faces, v_scalar_array=vertex_ids,
                                   f_scalar_array=face_flag))
        ms.compute_selection_by_condition_per_face(condselect="fq > 0.5")
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=max(int(settings.target_tris), MIN_DECIMATION_TRIS),
        qualitythr=float(settings.quality_threshold), preserveboundary=locked is None,
        boundaryweight=float(settings.boundary_weight), preservenormal=bool(settings.preserve_normals),
        preservetopology=False, optimalplacement=optimal_placement, planarquadric=True, autoclean=not coincident,
        selected=locked is not None)
    if coincident:
        ms.meshing_remove_null_faces()
        ms.meshing_remove_unreferenced_vertices()
    return ms


def lock_by_selection(positions: np.ndarray, faces: np.ndarray, locked: np.ndarray, *,
                      vertex_ids: np.ndarray | None) -> tuple:
    """The mesh pymeshlab collapses with `selected=True` so that exactly the `locked` (k,) bool
    vertices stay put. pymeshlab has no per-vertex lock: with `selected` it moves only vertices
    whose faces are all selected (and collapses only edges between such vertices), and counts the
    target in selected faces. Each locked vertex gets one unselected face of zero area (the vertex
    and two copies of it, which nothing else uses); every real face is selected. The collapse
    cannot touch a locked vertex or its edges, their neighbours stay free (unselecting the real
    faces around a seam would freeze its whole one-ring), and the clean-up after it removes the
    zero-area faces and the copies. Returns (positions (k+2s,3), faces (m+s,3) int32, face flags
    (m+s,) float64: 1 selected, 0 not, vertex ids (k+2s,) float64 with -1 for the copies, or an
    empty array without vertex_ids)."""
    k = positions.shape[0]
    ids = np.flatnonzero(locked)
    copies = k + np.arange(2 * ids.size, dtype=np.int64).reshape(-1, 2)
    out_p = np.concatenate([np.asarray(positions, np.float64), np.repeat(np.asarray(positions, np.float64)[ids], 2,
                                                                          axis=0)])
    out_f = np.concatenate([np.asarray(faces, np.int64), np.column_stack([ids, copies])]).astype(np.int32)
    flags = np.concatenate([np.ones(faces.shape[0]), np.zeros(ids.size)])
    out_ids = np.zeros(0) if vertex_ids is None else np.concatenate([np.asarray(vertex_ids, np.float64),
                                                                      np.full(2 * ids.size, -1.0)])
    return out_p, out_f, flags, out_ids


def unit_normals(normals: np.ndarray, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k,3) float32 unit vertex normals. pymeshlab's area-weighted normal is zero where a
    vertex's faces cancel (a decimated fin: two triangles back to back); such a vertex takes the
    normal of its largest face, and a vertex of zero-area faces only takes +z."""
    normals = np.asarray(normals, np.float64)
    length = np.linalg.norm(normals, axis=1)
    lost = length < 0.5  # pymeshlab's normals are unit or zero
    if lost.any():
        corners = positions[faces]
        face_normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        area = np.linalg.norm(face_normal, axis=1)
        order = np.argsort(area, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        best = np.full(positions.shape[0], -1, np.int64)  # rank of each vertex's largest face
        np.maximum.at(best, faces.ravel(), np.repeat(rank, 3))
        largest = order[np.maximum(best, 0)]
        fallback = np.tile([0.0, 0.0, 1.0], (positions.shape[0], 1))
        has = (best >= 0) & (area[largest] > 0)
        fallback[has] = face_normal[largest[has]] / area[largest[has], None]
        normals[lost] = fallback[lost]
        length[lost] = 1.0
    return (normals / length[:, None]).astype(np.float32)



def point_distances(points: np.ndarray, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(q,) float64: each of points (q,3)'s distance to the surface of (positions (k,3), faces
    (m,3)), all in one unit frame (distances of 2 x UNIT_DIAGONAL or more are not found: inf)."""
    import pymeshlab

    if points.shape[0] == 0:
        return np.zeros(0)
    if faces.shape[0] == 0:
        return np.full(points.shape[0], np.inf)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(positions, np.float64), face_matrix=faces.astype(np.int32)))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(points, np.float64)))
    reach = 2.0 * UNIT_DIAGONAL
    ms.get_hausdorff_distance(sampledmesh=1, targetmesh=0, samplevert=True, sampleface=False,
                              samplenum=int(points.shape[0]), maxdist=pymeshlab.PureValue(reach), savesample=True)
    found = np.asarray(ms.mesh(1).vertex_scalar_array(), np.float64)
    return np.where(found < reach, found, np.inf)
