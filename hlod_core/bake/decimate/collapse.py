"""One inner node's collapse (docs/how-it-works.md#decimating-a-node): what stays in place, the
quadric collapse (meshlab.quadric_collapse) and the pieces the LOD drops (pieces.py).

Data form: a node's welded input, positions (k,3) float32 (the bake's frame) and the same in the
node's unit frame (k,3) float64, faces (m,3) int rows; optional vertex ids (k,) float64 (a node
with attribute rows, whose vertices split at material borders and UV seams).

What stays in place, bit-identical, with its edges:
- always: the node's cell seams, the positions it shares with the cells around it (cell_seams.py),
  so neighbouring nodes at any levels do not crack; and with attribute rows the material borders
  and UV seams, which must stay closed;
- while the budget allows: the models' own open boundaries (holes of a scan, the rim of an open
  surface, a card's edges). The collapse runs with them in place first, which keeps their
  silhouette exactly and gives the LOD the bake gave before (freeing them everywhere raised the
  bunny's root error from 0.0013 to 0.0045-0.0052 at the same 2,000 triangles, whatever the
  boundary weight: benchmarks/seam_locks.py); only where that LOD keeps more than
  OVER_BUDGET_FACTOR x target_tris triangles does it run again with them free to collapse, their
  edges weighted by DecimationSettings.boundary_weight in the quadrics.
Then pieces.choose may drop pieces below the error or over the budget, and the node is collapsed
again without them (with its rims free at once where the first collapse needed that).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..space.lattice import unique_by_first
from .cell_seams import node_borders
from .meshlab import DecimationSettings, quadric_collapse, row_keys
from .pieces import choose, pieces_of

#: A LOD vertex this far (fraction of the node's diagonal) outside its input's box means the
#: quadric placement extrapolated; see `_collapse`.
ESCAPE_FRACTION = 0.01

#: A LOD over this many times target_tris, made with the models' open boundaries in place, is
#: made again with them free (module docstring); the bake log names nodes still over it.
OVER_BUDGET_FACTOR = 1.25


@dataclass(frozen=True)
class Cut:
    """What a node's collapse kept and dropped (NodeLod's fields of the same names): locked_vertices
    (cell seams and attribute borders kept in place), open_boundaries_freed (the models' open
    boundaries collapsed to reach the budget), pieces (connected pieces of its input),
    pruned_pieces and pruned_tris (the pieces dropped and their input triangles, pieces.py)."""

    locked_vertices: int = 0
    open_boundaries_freed: bool = False
    pieces: int = 0
    pruned_pieces: int = 0
    pruned_tris: int = 0

    def fields(self) -> dict:
        return {"locked_vertices": self.locked_vertices, "open_boundaries_freed": self.open_boundaries_freed,
                "pieces": self.pieces, "pruned_pieces": self.pruned_pieces, "pruned_tris": self.pruned_tris}


def collapse_node(positions: np.ndarray, local: np.ndarray, faces: np.ndarray, settings: DecimationSettings, *,
                  seams: np.ndarray | None, vertex_ids: np.ndarray | None = None):
    """The LOD of a node's welded input (module docstring): positions (k,3) float32, local (k,3)
    float64 the same in the unit frame, faces (m,3); seams (s,3) float32, the node's cell seams
    (None: its neighbours are unknown, and every open boundary stays); vertex_ids (k,) float64: a
    node with attribute rows (vertices kept in place, ids carried as the vertex scalar). Returns
    (MeshSet, kept_in_place, Cut, the faces collapsed: the input's, or those of the pieces kept)."""
    position_ids = None
    if vertex_ids is not None:
        position_ids = unique_by_first(row_keys(np.asarray(positions, np.float64)))[1]
    locked, rim, border = node_borders(positions, faces, seams, position_ids=position_ids)
    found = pieces_of(local, faces, locked, position_ids=position_ids)
    track = found.with_faces >= 2 and bool(found.free.any())
    ids = vertex_ids if vertex_ids is not None else (np.arange(local.shape[0], dtype=np.float64) if track else None)
    rows = vertex_ids is not None
    ms, kept_in_place, freed = _within_budget(local, faces, settings, locked=locked, rim=rim, border=border,
                                              vertex_ids=ids, rows=rows)
    if not track:
        return ms, kept_in_place, Cut(locked_vertices=int(locked.sum()), open_boundaries_freed=freed,
                                      pieces=found.with_faces), faces
    lod_piece = _lod_pieces(ms, found.of_vertex)
    lod = ms.current_mesh()
    pruned = choose(found, local=local, faces=faces, lod_local=lod.vertex_matrix(),
                    lod_faces=lod.face_matrix().astype(np.int64), lod_piece=lod_piece,
                    target_tris=settings.target_tris)
    kept = np.ones(faces.shape[0], bool)
    if pruned.dropped.any():
        kept = ~pruned.dropped[found.of_vertex[faces[:, 0]]]
        ms, kept_in_place, freed = _within_budget(local, faces[kept], settings, locked=locked, rim=rim, border=border,
                                                  vertex_ids=ids, rows=rows, free_at_once=freed)
        lod_piece = _lod_pieces(ms, found.of_vertex)
    # dropped: by pieces.choose, or by the collapse itself (a free piece collapsed to nothing)
    present = np.zeros(found.count, bool)
    present[lod_piece[lod_piece >= 0]] = True
    gone = ~present & (found.input_tris > 0)
    return ms, kept_in_place, Cut(locked_vertices=int(locked.sum()), open_boundaries_freed=freed,
                                  pieces=found.with_faces, pruned_pieces=int(gone.sum()),
                                  pruned_tris=int(found.input_tris[gone].sum())), faces[kept]


def _lod_pieces(ms, piece_of_input: np.ndarray) -> np.ndarray:
    """(j,) int64: the piece (pieces.Pieces.of_vertex) of each vertex of the MeshSet's LOD, from the
    input vertex ids it carries as its vertex scalar (-1: a vertex without one)."""
    survivor = ms.current_mesh().vertex_scalar_array().round().astype(np.int64)
    inside = (survivor >= 0) & (survivor < piece_of_input.shape[0])
    return np.where(inside, piece_of_input[np.where(inside, survivor, 0)], -1)


def _within_budget(local: np.ndarray, faces: np.ndarray, settings: DecimationSettings, *, locked: np.ndarray,
                   rim: np.ndarray, border: np.ndarray, vertex_ids: np.ndarray | None, rows: bool,
                   free_at_once: bool = False):
    """(MeshSet, kept_in_place, freed): the collapse with the models' open boundaries (rim (k,)
    bool) in place, or where that LOD is over OVER_BUDGET_FACTOR x target_tris and the collapse with
    them free is within it, that one (freed True): where what is locked holds the node over the
    budget anyway, freeing the rims would buy only error (a flat open ground collapses to nothing).
    border (k,) bool: the vertices on open edges of the node's whole input (faces may be a part of
    it: whole pieces dropped); where the vertices kept are just those, pymeshlab's boundary
    preservation keeps them (meshlab.quadric_collapse). free_at_once: the rims are free from the
    start (the node's collapse with all its pieces needed that)."""
    used = np.zeros(local.shape[0], bool)
    used[faces.ravel()] = True
    if free_at_once and (rim & used).any():
        ms, kept_in_place = _collapse(local, faces, settings, locked=locked & used, vertex_ids=vertex_ids, rows=rows)
        return ms, kept_in_place, True
    kept = (locked | rim) & used
    ms, kept_in_place = _collapse(local, faces, settings, vertex_ids=vertex_ids, rows=rows,
                                  locked=None if np.array_equal(kept, border & used) else kept)
    in_place = ms.current_mesh().face_number()
    if not (rim & used).any() or in_place <= OVER_BUDGET_FACTOR * settings.target_tris:
        return ms, kept_in_place, False
    free, free_kept = _collapse(local, faces, settings, locked=locked & used, vertex_ids=vertex_ids, rows=rows)
    if free.current_mesh().face_number() > OVER_BUDGET_FACTOR * settings.target_tris:
        return ms, kept_in_place, False  # freeing bought no budget (what holds it is locked): keep the rims
    return free, free_kept, True


def _collapse(local: np.ndarray, faces: np.ndarray, settings: DecimationSettings, *, locked: np.ndarray | None,
              vertex_ids: np.ndarray | None, rows: bool):
    """(MeshSet, kept_in_place) of one quadric collapse (meshlab.quadric_collapse; locked None: the
    vertices on open edges). Without rows,
    with optimal placement, which may move a vertex slightly outward on curved surfaces (that
    lowers the error); leaving the input's box by more than ESCAPE_FRACTION of its diagonal is the
    singular-quadric extrapolation instead, so the collapse runs again with vertices kept in place.
    With rows (vertex_ids are attribute rows' ids): vertices kept in place."""
    if rows:
        return quadric_collapse(local, faces, settings, optimal_placement=False, vertex_ids=vertex_ids,
                                locked=locked, coincident=True), False
    ms = quadric_collapse(local, faces, settings, optimal_placement=True, vertex_ids=vertex_ids, locked=locked)
    lo, hi = local.min(axis=0), local.max(axis=0)
    lod_box = ms.current_mesh().bounding_box()
    slack = ESCAPE_FRACTION * float(np.linalg.norm(hi - lo))
    escaped = bool(ms.current_mesh().face_number() > 0
                   and (np.any(lod_box.min() < lo - slack) or np.any(lod_box.max() > hi + slack)))
    if escaped:
        ms = quadric_collapse(local, faces, settings, optimal_placement=False, vertex_ids=vertex_ids, locked=locked)
    return ms, escaped
