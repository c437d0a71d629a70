"""One inner node's LOD and model-space error (DESIGN §4.3-4.4), with pymeshlab.

Data form: node geometry as positions (k,3) float32, in the bake's file-relative frame, and faces
(m,3) int32 local to those positions.

- The children's LODs are concatenated and welded by exact position. Seams between siblings then
  become interior edges; seams with the rest of the scene stay boundary edges, and boundary
  preservation keeps their vertices fixed, so neighbouring nodes at different levels do not crack.
  Fixed vertices come back bit-identical (pymeshlab computes in double; our inputs are float32
  values), which is what makes the exact weld one level up work.
- Quadric edge collapse (Garland & Heckbert 1997, pymeshlab
  `meshing_decimation_quadric_edge_collapse`) to `target_tris`.
- MSE = symmetric Hausdorff distance (pymeshlab `get_hausdorff_distance`, the max in both
  directions, from deterministic samples) between the LOD and the original triangles below the node. The bake takes the max
  with the children's MSE so the error is monotone.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


#: A LOD vertex this far (fraction of the node's diagonal) outside its input's box means the
#: quadric placement extrapolated; see decimate_node.
ESCAPE_FRACTION = 0.01


@dataclass(frozen=True)
class DecimationSettings:
    """target_tris: triangles per LOD; quality_threshold: pymeshlab `qualitythr` (0..1, penalises
    thin triangles); preserve_normals: pymeshlab `preservenormal` (no face flips);
    boundary_weight: pymeshlab `boundaryweight` (only with boundary preservation, always on here)."""

    target_tris: int = 2000
    quality_threshold: float = 0.3
    preserve_normals: bool = False
    boundary_weight: float = 1.0


@dataclass(frozen=True, eq=False)
class NodeLod:
    """positions (k,3) float32; faces (m,3) int32; normals (k,3) float32 or None;
    decimated: False when kept as the children's welded union; input_tris: the welded union's
    triangles; kept_in_place: optimal placement left the node's box, so vertices stayed in place."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    decimated: bool
    input_tris: int
    kept_in_place: bool = False


def weld(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-identical float32 positions; drop triangles that collapse."""
    key = np.ascontiguousarray(positions, dtype=np.float32).view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    welded = inverse.reshape(-1)[faces]
    keep = (welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 0] != welded[:, 2])
    return positions[first], welded[keep].astype(np.int32)


def collapsed(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) bool: triangles with two corners at bit-identical float32 positions, which `weld`
    drops. They do not count toward a node's triangle budget (octree and leaf budget check)."""
    p = np.asarray(positions, np.float32)
    a, b, c = p[faces[:, 0]], p[faces[:, 1]], p[faces[:, 2]]
    return np.all(a == b, axis=1) | np.all(b == c, axis=1) | np.all(a == c, axis=1)


def compact(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep only referenced vertices. Returns (positions, local faces int32, kept vertex ids)."""
    flat = np.asarray(faces).reshape(-1)
    v = positions.shape[0]
    if flat.shape[0] * 8 < v:  # few faces: sort them
        used, local = np.unique(flat, return_inverse=True)
    else:  # many faces: a mask over the vertices is linear time
        mask = np.zeros(v, bool)
        mask[flat] = True
        used = np.flatnonzero(mask)
        remap = np.cumsum(mask, dtype=np.int64) - 1
        local = remap[flat]
    return np.asarray(positions[used]), local.reshape(-1, 3).astype(np.int32), used


def decimate_node(child_lods: list[tuple[np.ndarray, np.ndarray]], settings: DecimationSettings,
                  with_normals: bool) -> NodeLod:
    """child_lods: [(positions f32, faces)] of the children. The node's error is `measure`'s job:
    it needs the original triangles, the decimation does not, so the two run as separate tasks."""
    offsets = np.cumsum([0] + [p.shape[0] for p, _ in child_lods[:-1]])
    positions = np.concatenate([p for p, _ in child_lods])
    faces = np.concatenate([f.astype(np.int64) + o for (_, f), o in zip(child_lods, offsets)])
    positions, faces = weld(positions, faces)

    welded_tris = int(faces.shape[0])
    decimated = welded_tris > settings.target_tris
    ms = _decimated(positions, faces, settings, optimal_placement=True) if decimated else _mesh_set(positions, faces)
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    lod_box = ms.current_mesh().bounding_box()
    # Optimal placement may move a vertex slightly outward on curved surfaces (that lowers the
    # error); leaving the input's box by more than ESCAPE_FRACTION of its diagonal is the
    # singular-quadric extrapolation instead, so decimate again with vertices kept in place.
    slack = ESCAPE_FRACTION * float(np.linalg.norm(hi - lo))
    kept_in_place = bool(np.any(lod_box.min() < lo - slack) or np.any(lod_box.max() > hi + slack))
    if kept_in_place:
        ms = _decimated(positions, faces, settings, optimal_placement=False)
    lod = ms.current_mesh()
    normals = None
    if with_normals:
        ms.compute_normal_per_vertex()
        normals = ms.current_mesh().vertex_normal_matrix().astype(np.float32)
    return NodeLod(positions=lod.vertex_matrix().astype(np.float32), faces=lod.face_matrix().astype(np.int32),
                   normals=normals, decimated=decimated, input_tris=welded_tris, kept_in_place=kept_in_place)


def _mesh_set(positions: np.ndarray, faces: np.ndarray):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=positions.astype(np.float64), face_matrix=faces))
    return ms


def _decimated(positions, faces, settings: DecimationSettings, *, optimal_placement: bool):
    """Quadric edge collapse with boundary preservation. planarquadric adds the planar constraints
    that keep flat regions (ground planes, walls) from being extrapolated: without them a flat
    cell's singular quadric can place a vertex tens of metres away."""
    ms = _mesh_set(positions, faces)
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(settings.target_tris), qualitythr=float(settings.quality_threshold),
        preserveboundary=True, boundaryweight=float(settings.boundary_weight),
        preservenormal=bool(settings.preserve_normals), preservetopology=False,
        optimalplacement=optimal_placement, planarquadric=True, autoclean=True)
    return ms


#: Barycentric sample points per LOD face for the LOD -> original direction: centroid, three
#: inner points and the edge midpoints. Fixed, so a bake is reproducible (pymeshlab's own face
#: sampling is Monte Carlo with a varying seed and moved node errors by up to 30% between runs).
FACE_SAMPLES = np.array([[1 / 3, 1 / 3, 1 / 3], [2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6],
                         [1 / 6, 1 / 6, 2 / 3], [0.5, 0.5, 0.0], [0.0, 0.5, 0.5], [0.5, 0.0, 0.5]])


def measure(lod: tuple[np.ndarray, np.ndarray], original: tuple[np.ndarray, np.ndarray]) -> float:
    """Symmetric Hausdorff distance between a LOD and the original triangles below its node, both
    (positions f32, faces) in the same frame: the max of (original vertices -> LOD surface) and
    (LOD vertices and FACE_SAMPLES points -> original surface). NaN if pymeshlab gives none."""
    import pymeshlab

    lod_p = lod[0].astype(np.float64)
    samples = np.concatenate([lod_p, np.einsum("sk,fkd->fsd", FACE_SAMPLES, lod_p[lod[1]]).reshape(-1, 3)])
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=lod_p, face_matrix=lod[1]))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=original[0].astype(np.float64), face_matrix=original[1]))
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=samples))
    lo = np.minimum(lod_p.min(axis=0), original[0].min(axis=0))
    hi = np.maximum(lod_p.max(axis=0), original[0].max(axis=0))
    radius = pymeshlab.PureValue(2.0 * float(np.linalg.norm(hi - lo)) + 1e-30)  # no sample is dropped
    both = [float(ms.get_hausdorff_distance(sampledmesh=sampled, targetmesh=target, samplevert=True,
                                            sampleface=False, samplenum=int(n), maxdist=radius)["max"])
            for sampled, target, n in ((1, 0, original[0].shape[0]), (2, 1, samples.shape[0]))]
    return max(both) if all(np.isfinite(both)) else float("nan")
