"""Crossing UV seams: the LOD of a node with attribute rows whose seams would keep it too big
(simplify.decimate_node, SEAM_CROSSING_FACTOR), decimated across its UV seams while material
borders stay put, and each LOD face's rows taken from one UV island.

Data form: a node's input welded by (position, material, UV): positions (k,3) float32 (and the
same in the unit frame, (k,3) float64), attribute rows (k,A) float32 (appearance.pack's columns),
faces (f,3) int rows. Vertices stay in place (no optimal placement), so every LOD vertex sits on
an input position and takes an input row (`row_sources`).
Why: docs/how-it-works.md#materials-uvs-and-colours-in-the-lods
"""
from __future__ import annotations

import numpy as np

from ...core.arrays import distinct_corners, segment_ranges
from ..space.lattice import unique_by_first
from .cell_seams import node_borders
from .meshlab import DecimationSettings, quadric_collapse, row_keys


def decimate_across_uv_seams(positions: np.ndarray, local: np.ndarray, rows: np.ndarray, *, faces: np.ndarray,
                             settings: DecimationSettings, material: slice | None, uv: slice,
                             seams: np.ndarray | None = None):
    """The LOD of a node welded by (position, material) only: UV seams become interior edges that
    the collapse crosses, material borders stay open boundaries and stay put. Vertices stay in
    place, so each LOD vertex sits on a (position, material) of the input, where one input row per
    UV island meets; every LOD face takes its corners' rows from one island (`_rows_per_face`), and
    a LOD vertex is split once per row its faces take.

    positions (k,3) float32, local (k,3) float64 (the same in the unit frame), rows (k,A), faces
    (f,3): the node's input welded by (position, material, UV); seams: the node's cell seams
    (cell_seams.node_borders), kept in place as material borders and open boundaries are. Returns (local_out (j,3)
    float64, faces_out (m,3) int32, source (j,) int64 input rows, island_spanning_faces), or None where
    there is no UV seam or the collapse leaves no triangle."""
    keyed = np.ascontiguousarray(positions, np.float32).view(np.uint8).reshape(-1, 12)
    if material is not None:
        material_bytes = np.ascontiguousarray(rows[:, material]).view(np.uint8).reshape(-1, 4)
        keyed = np.concatenate([keyed, material_bytes], axis=1)
    key = np.ascontiguousarray(keyed).view(np.dtype((np.void, keyed.shape[1]))).ravel()
    first, coarse_of = unique_by_first(key)
    if first.shape[0] == local.shape[0]:
        return None  # no UV seam: the same mesh as the one that kept them
    coarse_faces = coarse_of[faces]
    coarse_faces = coarse_faces[distinct_corners(coarse_faces)].astype(np.int32)
    coarse_ids = np.arange(first.shape[0], dtype=np.float64)
    position_ids = unique_by_first(row_keys(positions[first].astype(np.float64)))[1]
    locked, rim, border = node_borders(positions[first], coarse_faces, seams, position_ids=position_ids)
    kept = locked | rim  # the models' open boundaries stay too, as in the LOD that kept the UV seams
    ms = quadric_collapse(local[first], coarse_faces, settings, optimal_placement=False, vertex_ids=coarse_ids,
                          locked=None if np.array_equal(kept, border) else kept, coincident=True)
    lod = ms.current_mesh()
    if lod.face_number() == 0:
        return None
    local_out = lod.vertex_matrix()
    coarse_source = row_sources(local_out, lod.vertex_scalar_array().round().astype(np.int64), local[first],
                                rows=rows[first])
    corner_rows, spanning = _rows_per_face(lod.face_matrix().astype(np.int64), coarse_source, coarse_of,
                                           faces_in=faces, uvs=rows[:, uv].astype(np.float64), fallback_row=first)
    pair = lod.face_matrix().astype(np.int64).ravel() * rows.shape[0] + corner_rows.ravel()  # (LOD vertex, row)
    unique_pairs, split_faces = np.unique(pair, return_inverse=True)
    return (local_out[unique_pairs // rows.shape[0]], split_faces.reshape(-1, 3).astype(np.int32),
            unique_pairs % rows.shape[0], int(spanning.sum()))


def uv_islands(faces: np.ndarray) -> np.ndarray:
    """(f,) int64 UV island of each face of a mesh welded by (position, material, UV): faces that
    share an edge (both vertex ids) share an island, labelled by its lowest face id. Faces that only
    touch at a vertex are different islands, so a LOD face that already spans two islands (two
    corners in one, one in the other) joins the first without merging the two.

    Min-label propagation with root hooking and pointer jumping (Shiloach & Vishkin 1982), repeated
    until no label changes: each round every edge takes the least label of its faces, each face and
    its label's face take the least label of their edges."""
    f = faces.shape[0]
    if f == 0:
        return np.zeros(0, np.int64)
    ends = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2).astype(np.int64), axis=1)
    _, edge = np.unique(ends[:, 0] * (int(ends.max()) + 1) + ends[:, 1], return_inverse=True)
    edge = edge.reshape(-1)
    owner = np.repeat(np.arange(f, dtype=np.int64), 3)
    label = np.arange(f, dtype=np.int64)
    while True:
        edge_least = np.full(int(edge.max()) + 1, f, np.int64)
        np.minimum.at(edge_least, edge, label[owner])
        new = label.copy()
        np.minimum.at(new, owner, edge_least[edge])
        np.minimum.at(new, label[owner], edge_least[edge])  # hook the old label's face too
        new = new[new]
        if np.array_equal(new, label):
            return label
        label = new


def _rows_per_face(faces_out: np.ndarray, vertex_source: np.ndarray, group_of_row: np.ndarray, *,
                   faces_in: np.ndarray, uvs: np.ndarray, fallback_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The input row each corner of each LOD face takes, after a collapse across UV seams.

    faces_out (m,3): LOD faces; vertex_source (j,): the (position, material) group each LOD vertex
    sits on; group_of_row (k,): each input row's group; faces_in (f,3) and uvs (k,2) float64: the
    input faces and rows' UVs. A corner's candidates are the (row, island) pairs of its group
    (uv_islands: one row per island meeting there; a row is in two islands where they touch at it
    without sharing an edge). Each face takes the island that most of its corners have a candidate in (then the
    lowest label); each corner its candidate in that island whose UV is nearest the mean UV of the
    other corners' candidates there (then the lowest row). A corner with none there takes, by the
    same rule, its candidate nearest those UVs: the face spans two islands, and nearest keeps the
    stretch of its texture smallest. A corner whose group no input face uses (only collapsed faces
    did; not expected) takes fallback_row (groups,) of its group. Returns ((m,3) int64 rows, (m,)
    bool spanning faces)."""
    island = uv_islands(faces_in)
    pair_row = faces_in.ravel().astype(np.int64)
    pair_island = np.repeat(island, 3)
    pair_group = group_of_row[pair_row]
    order = np.lexsort((pair_row, pair_island, pair_group))
    keep = np.ones(order.size, bool)
    keep[1:] = (np.diff(pair_row[order]) != 0) | (np.diff(pair_island[order]) != 0)
    order = order[keep]  # unique (row, island) pairs by group
    pair_row, pair_island, pair_group = pair_row[order], pair_island[order], pair_group[order]
    groups = int(group_of_row.max()) + 1
    pair_count = np.bincount(pair_group, minlength=groups)
    pair_start = np.cumsum(pair_count) - pair_count

    corner_group = vertex_source.astype(np.int64)[faces_out.ravel()]  # (3m,): corner = 3 face + k
    count = pair_count[corner_group]
    candidate = segment_ranges(pair_start[corner_group], count)
    corner = np.repeat(np.arange(corner_group.size, dtype=np.int64), count)
    face = corner // 3
    cand_island = pair_island[candidate]

    # the island most corners of each face have a candidate in (a corner counted once per island)
    by = np.lexsort((corner, cand_island, face))
    new_group = np.ones(by.size, bool)
    new_group[1:] = (np.diff(face[by]) != 0) | (np.diff(cand_island[by]) != 0)
    new_corner = new_group.copy()
    new_corner[1:] |= np.diff(corner[by]) != 0
    group_id = np.cumsum(new_group) - 1
    corners_in = np.bincount(group_id, weights=new_corner).astype(np.int64)
    group_face, group_island = face[by][new_group], cand_island[by][new_group]
    best = np.lexsort((group_island, -corners_in, group_face))
    first_of_face = np.ones(best.size, bool)
    first_of_face[1:] = np.diff(group_face[best]) != 0
    chosen = np.full(faces_out.shape[0], -1, np.int64)
    chosen[group_face[best][first_of_face]] = group_island[best][first_of_face]
    spanning = np.ones(faces_out.shape[0], bool)
    spanning[group_face[best][first_of_face]] = corners_in[best][first_of_face] < 3

    # each corner: its candidate in the island nearest the other corners' candidates there
    inside = cand_island == chosen[face]
    cand_uv = uvs[pair_row[candidate]]
    corner_sum = np.stack([np.bincount(corner, weights=cand_uv[:, c] * inside, minlength=corner_group.size)
                           for c in range(2)], axis=1)
    corner_n = np.bincount(corner, weights=inside, minlength=corner_group.size)
    others_sum = np.repeat(corner_sum.reshape(-1, 3, 2).sum(axis=1), 3, axis=0) - corner_sum
    others_n = np.repeat(corner_n.reshape(-1, 3).sum(axis=1), 3) - corner_n
    anchor = others_sum / np.maximum(others_n, 1)[:, None]
    gap = cand_uv - anchor[corner]
    distance = np.where(others_n[corner] > 0, np.einsum("ij,ij->i", gap, gap), 0.0)
    pick = np.lexsort((pair_row[candidate], distance, ~inside, corner))
    first_of_corner = np.ones(pick.size, bool)
    first_of_corner[1:] = np.diff(corner[pick]) != 0
    rows_out = np.asarray(fallback_row, np.int64)[corner_group]
    rows_out[corner[pick][first_of_corner]] = pair_row[candidate][pick][first_of_corner]
    return rows_out.reshape(-1, 3), spanning


def row_sources(local_out: np.ndarray, survivor: np.ndarray, local_in: np.ndarray, *, rows: np.ndarray) -> np.ndarray:
    """(j,) int64: the input vertex whose attribute row each LOD vertex takes.

    local_out (j,3) float64: LOD positions, each bit-identical to some input position (collapse
    without optimal placement); survivor (j,) int64: the input vertex each LOD vertex was (its
    pymeshlab vertex scalar); local_in (k,3) float64 and rows (k,A): the welded input. A survivor
    at its own input position keeps its own row; one moved onto another input vertex's position
    takes that vertex's row (of several there, the row nearest the survivor's, then the lowest
    id); one on no input position (not expected) keeps its own.
    Why: docs/how-it-works.md#materials-uvs-and-colours-in-the-lods"""
    keys_in, keys_out = row_keys(local_in), row_keys(local_out)
    source = survivor.copy()
    moved = np.flatnonzero(keys_out != keys_in[survivor])
    if moved.size == 0:
        return source
    order = np.argsort(keys_in, kind="stable")
    sorted_keys = keys_in[order]
    first = np.searchsorted(sorted_keys, keys_out[moved], side="left")
    count = np.searchsorted(sorted_keys, keys_out[moved], side="right") - first
    moved, first, count = moved[count > 0], first[count > 0], count[count > 0]
    candidate = order[segment_ranges(first, count)]
    owner = np.repeat(np.arange(moved.size), count)
    gap = rows[candidate].astype(np.float64) - rows[survivor[moved]][owner]
    best = np.lexsort((candidate, np.einsum("ij,ij->i", gap, gap), owner))  # by owner, then distance, then id
    source[moved] = candidate[best[np.cumsum(count) - count]]
    return source

