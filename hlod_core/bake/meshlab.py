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

from . import lattice

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
    boundary_weight: pymeshlab `boundaryweight` (only with boundary preservation, always on here)."""

    target_tris: int = 2000
    quality_threshold: float = 0.3
    preserve_normals: bool = False
    boundary_weight: float = 1.0


@dataclass(frozen=True)
class NodeFrame:
    """The unit frame pymeshlab works in: local = (x - center) * scale, with the node's box
    centred on the origin and its diagonal UNIT_DIAGONAL (scale = 1 for a node of one point).
    x is the model position, or with unit_length > 0 the canonical coordinate of a bake's stored
    position (lattice.py), so the frame and every local coordinate are the same numbers at every
    scale. It makes pymeshlab's absolute thresholds scale-free, so a model baked in millimetres
    gives the LODs of the same model in metres, scaled.
    Why: docs/how-it-works.md#the-unit-frame-of-a-node"""

    center: np.ndarray        # (3,) float64, model units (canonical units with unit_length)
    scale: float              # 1 / those units
    unit_length: float = 0.0  # the lattice's unit, model units; 0: positions are not on it

    @staticmethod
    def of(positions: np.ndarray, *, unit_length: float = 0.0) -> "NodeFrame":
        """The unit frame of positions (k,3), k >= 1, finite; with unit_length, stored lattice
        positions (lattice.py) framed by their canonical coordinates."""
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
                     vertex_ids: np.ndarray | None = None):
    """The MeshSet of positions (unit frame) and faces after a quadric edge collapse to
    settings.target_tris, with boundary preservation and planar quadrics (they keep a flat cell's
    singular quadric from placing a vertex far outside it). With vertex_ids (a node with attribute
    rows) vertices may share positions (seams), which pymeshlab's autoclean would merge: only the
    rest of its clean-up, null faces and unreferenced vertices, runs."""
    ms = mesh_set(positions, faces, vertex_ids)
    seams = vertex_ids is not None
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=max(int(settings.target_tris), MIN_DECIMATION_TRIS),
        qualitythr=float(settings.quality_threshold), preserveboundary=True,
        boundaryweight=float(settings.boundary_weight), preservenormal=bool(settings.preserve_normals),
        preservetopology=False,
        optimalplacement=optimal_placement, planarquadric=True, autoclean=not seams)
    if seams:
        ms.meshing_remove_null_faces()
        ms.meshing_remove_unreferenced_vertices()
    return ms


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

