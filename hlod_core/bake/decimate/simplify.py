"""One inner node's LOD (docs/how-it-works.md#decimating-a-node), with pymeshlab: the children's LODs concatenated,
welded and decimated by quadric edge collapse (collapse.py, meshlab.py) to `target_tris`.

Data form: node geometry as positions (k,3) float32, in the bake's file-relative frame, faces
(m,3) int32 local to those positions and, when the scene has appearance, attribute rows (k,A)
float32 (appearance.pack: [material, u, v, r, g, b, a], the columns the scene has), one per
vertex. pymeshlab only ever sees a node in its own unit frame (meshlab.NodeFrame).

- The weld is by exact float32 position, so seams between siblings become interior edges; the
  node's seams with the rest of the scene (cell_seams.py) stay in place and come back
  bit-identical (NodeFrame.to_model), so neighbouring nodes do not crack and the weld one level
  up still works. The models' own open boundaries stay while the budget allows, and pieces below
  the error go (collapse.py, pieces.py).
- With attribute rows the weld is by (position, material, UV): material borders and UV seams stay
  open boundaries, kept in place; colours are averaged. Such nodes collapse with vertices kept in
  place and each LOD vertex takes the row of the input vertex it sits on (seams.row_sources). A
  LOD whose seams keep it above SEAM_CROSSING_FACTOR x target_tris is made again across its UV
  seams (seams.py).
- The error (MSE, and the bound's h) is bake/measure/hausdorff.py's, in the same unit frame.
Why: docs/how-it-works.md#decimating-a-node
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.arrays import compact, concat_indexed, distinct_corners
from ...model.appearance import AttributeLayout
from ..space.lattice import unique_by_first
from .collapse import Cut, collapse_node
from .meshlab import DecimationSettings, NodeFrame, mesh_set, row_keys, unit_normals
from .seams import decimate_across_uv_seams, row_sources

#: A node with attribute rows whose LOD, keeping its UV seams, has more than this many times
#: target_tris triangles is decimated again across them (decimate_node).
SEAM_CROSSING_FACTOR = 2


@dataclass(frozen=True, eq=False)
class NodeLod:
    """positions (k,3) float32; faces (m,3) int32; normals (k,3) float32 or None; attributes (k,A)
    float32 attribute rows or None (a scene without appearance);
    decimated: False when kept as the children's welded union; input_tris: the welded union's
    triangles; kept_in_place: optimal placement left the node's box, so vertices stayed in place;
    zero_area: every triangle had zero area (pymeshlab removes them all), so the LOD is a sample
    of the welded union's triangles (see decimate_node); uv_seams_crossed: the LOD keeping its UV
    seams had seam_kept_tris > SEAM_CROSSING_FACTOR x target_tris triangles, so it was decimated
    again across them, and island_spanning_faces of its faces span two UV islands (their texture
    is stretched; see seams.decimate_across_uv_seams); locked_vertices: input vertices kept in
    place (cell seams, attribute borders); open_boundaries_freed: the models' open boundaries
    collapsed to reach the budget (collapse.py); pieces: connected pieces of the input;
    pruned_pieces, pruned_tris: the pieces the LOD dropped and their input triangles (pieces.py)."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    decimated: bool
    input_tris: int
    kept_in_place: bool = False
    zero_area: bool = False
    attributes: np.ndarray | None = None
    uv_seams_crossed: bool = False
    seam_kept_tris: int = 0
    island_spanning_faces: int = 0
    locked_vertices: int = 0
    open_boundaries_freed: bool = False
    pieces: int = 0
    pruned_pieces: int = 0
    pruned_tris: int = 0


def weld(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-identical float32 positions, numbered in order of first appearance
    (lattice.unique_by_first); drop triangles that collapse."""
    key = np.ascontiguousarray(positions, dtype=np.float32).view(np.dtype((np.void, 12))).ravel()
    first, inverse = unique_by_first(key)
    welded = inverse[faces]
    return positions[first], welded[distinct_corners(welded)].astype(np.int32)


def weld_rows(positions: np.ndarray, rows: np.ndarray, faces: np.ndarray, *,
              key_columns: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`weld` for vertices with attribute rows (k,A) float32: merge vertices whose float32 position
    AND first `key_columns` row columns (all by default) are bit-identical; the other columns of a
    merged vertex are the mean of its vertices'; numbered in order of first appearance. Drops
    triangles that collapse. Returns
    (positions, rows (float32), faces int32)."""
    p = np.ascontiguousarray(positions, dtype=np.float32)
    r = np.ascontiguousarray(rows, dtype=np.float32)
    keyed = r.shape[1] if key_columns is None else key_columns
    both = np.concatenate([p.view(np.uint8).reshape(-1, 12),
                           np.ascontiguousarray(r[:, :keyed]).view(np.uint8).reshape(p.shape[0], -1)], axis=1)
    key = np.ascontiguousarray(both).view(np.dtype((np.void, 4 * (3 + keyed)))).ravel()
    first, inverse = unique_by_first(key)
    welded_rows = r[first]
    if keyed < r.shape[1]:
        members = np.bincount(inverse, minlength=first.shape[0]).astype(np.float64)
        for column in range(keyed, r.shape[1]):
            welded_rows[:, column] = np.bincount(inverse, weights=r[:, column], minlength=first.shape[0]) / members
    welded = inverse[faces]
    return positions[first], welded_rows, welded[distinct_corners(welded)].astype(np.int32)


def collapsed(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) bool: triangles with two corners at bit-identical float32 positions, which `weld`
    drops. They do not count toward a node's triangle budget (octree and leaf budget check)."""
    p = np.asarray(positions, np.float32)
    return collapsed_corners(p[faces[:, 0]], p[faces[:, 1]], p[faces[:, 2]])


def collapsed_corners(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """`collapsed` of the triangles with corners a, b, c (f,3) float32 (any strides): column by
    column, as (a == b).all(axis=1) is several times slower on rows of three."""
    def same(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        equal = p[:, 0] == q[:, 0]
        equal &= p[:, 1] == q[:, 1]
        equal &= p[:, 2] == q[:, 2]
        return equal

    collapsed_tris = same(a, b)
    collapsed_tris |= same(b, c)
    collapsed_tris |= same(a, c)
    return collapsed_tris


def decimate_node(child_lods: list[tuple], settings: DecimationSettings, *, with_normals: bool,
                  layout: AttributeLayout | None = None, unit_length: float = 0.0,
                  seams: np.ndarray | None = None) -> NodeLod:
    """child_lods: [(positions f32, faces)] or [(positions f32, faces, attribute rows (k,A) f32 or
    None)] of the children, all with rows or all without; layout: the rows' columns (None: every
    column is kept exact, as a UV); unit_length: the bake's lattice unit (bake/space/lattice.py; the children's
    positions are its points and so is the LOD's every vertex), 0 for positions off any lattice;
    seams (s,3) float32: the positions the node shares with the cells around it
    (cell_seams.CellSeams.locked), kept in place; None: its neighbours are unknown, and every
    vertex on an open edge is kept.
    The node's error is `measure`'s job: it needs the original
    triangles, the decimation does not, so the two run as separate tasks."""
    rows = _child_rows(child_lods)
    if rows is not None:
        return _decimate_with_rows(child_lods, rows, settings, with_normals=with_normals, layout=layout,
                                   unit_length=unit_length, seams=seams)
    positions, faces = concat_indexed((child[0], child[1]) for child in child_lods)
    positions, faces = weld(positions, faces)

    welded_tris = int(faces.shape[0])
    decimated = welded_tris > settings.target_tris
    frame = NodeFrame.of(positions, unit_length=unit_length)
    local = frame.to_local(positions)
    cut = Cut()
    if not decimated:
        ms = mesh_set(local, faces)
        kept_in_place = False
    else:
        ms, kept_in_place, cut, _ = collapse_node(positions, local, faces, settings, seams=seams)
    zero_area = ms.current_mesh().face_number() == 0
    if zero_area:
        # Every triangle had zero area, and pymeshlab's clean-up removes such triangles: keep
        # target_tris of the union's, evenly spaced (they draw nothing; the error measures the rest).
        kept_p, kept_f, _ = compact(local, faces[_evenly_spaced(welded_tris, settings.target_tris)])
        ms = mesh_set(kept_p, kept_f)
    lod = ms.current_mesh()
    normals = None
    if with_normals:
        ms.compute_normal_per_vertex()
        normals = unit_normals(ms.current_mesh().vertex_normal_matrix(), lod.vertex_matrix(), lod.face_matrix())
    return NodeLod(positions=frame.to_model(lod.vertex_matrix(), local, positions),
                   faces=lod.face_matrix().astype(np.int32), normals=normals, decimated=decimated,
                   input_tris=welded_tris, kept_in_place=kept_in_place, zero_area=zero_area, **cut.fields())


def _child_rows(child_lods: list[tuple]) -> np.ndarray | None:
    """The children's attribute rows, concatenated, or None when they have none."""
    rows = [child[2] if len(child) > 2 else None for child in child_lods]
    if all(r is None for r in rows):
        return None
    if any(r is None for r in rows):
        raise ValueError("decimate_node: some children have attribute rows and some do not")
    return np.concatenate(rows)


def _evenly_spaced(count: int, wanted: int) -> np.ndarray:
    """Up to `wanted` distinct indices into range(count), evenly spaced, ascending."""
    return np.unique(np.linspace(0, count - 1, wanted).round().astype(np.int64))


def _decimate_with_rows(child_lods: list[tuple], rows: np.ndarray, settings: DecimationSettings, *,
                        with_normals: bool, layout: AttributeLayout | None, unit_length: float,
                        seams: np.ndarray | None) -> NodeLod:
    """decimate_node for children with attribute rows (module docstring): weld by (position,
    material, UV), colours averaged, collapse with vertices kept in place, and give every LOD
    vertex the row of the input vertex it sits on. pymeshlab carries each input vertex's id
    through the collapse as its vertex scalar. A LOD that keeps its UV seams but stays above
    SEAM_CROSSING_FACTOR x target_tris is made again across them (seams.decimate_across_uv_seams)."""
    positions, faces = concat_indexed((child[0], child[1]) for child in child_lods)
    columns = layout.columns() if layout is not None else {}
    positions, rows, faces = weld_rows(positions, rows, faces,
                                       key_columns=columns["color"].start if "color" in columns else None)
    welded_tris = int(faces.shape[0])
    decimated = welded_tris > settings.target_tris
    frame = NodeFrame.of(positions, unit_length=unit_length)
    local = frame.to_local(positions)
    ids = np.arange(local.shape[0], dtype=np.float64)  # exact: far fewer than 2**53 vertices
    cut, kept = Cut(), faces
    if decimated:
        ms, _, cut, kept = collapse_node(positions, local, faces, settings, seams=seams, vertex_ids=ids)
    else:
        ms = mesh_set(local, faces, vertex_ids=ids)
    zero_area = ms.current_mesh().face_number() == 0
    if zero_area:  # as in decimate_node
        kept_p, kept_f, used = compact(local, faces[_evenly_spaced(welded_tris, settings.target_tris)])
        ms = mesh_set(kept_p, kept_f, vertex_ids=ids[used])
    lod = ms.current_mesh()
    local_out = lod.vertex_matrix()
    faces_out = lod.face_matrix().astype(np.int32)
    source = row_sources(local_out, lod.vertex_scalar_array().round().astype(np.int64), local, rows=rows)
    seam_kept_tris, spanning = int(faces_out.shape[0]), 0
    too_many = seam_kept_tris > SEAM_CROSSING_FACTOR * settings.target_tris
    if decimated and not zero_area and "uv" in columns and too_many:
        crossed = decimate_across_uv_seams(positions, local, rows, faces=kept, settings=settings,
                                           material=columns.get("material"), uv=columns["uv"], seams=seams)
        if crossed is not None and crossed[1].shape[0] < seam_kept_tris:
            local_out, faces_out, source, spanning = crossed
    normals = _normals_by_position(local_out, faces_out) if with_normals else None
    return NodeLod(positions=frame.to_model(local_out, local, positions), faces=faces_out, normals=normals,
                   decimated=decimated, input_tris=welded_tris, zero_area=zero_area,
                   attributes=np.ascontiguousarray(rows[source], np.float32),
                   uv_seams_crossed=faces_out.shape[0] < seam_kept_tris, seam_kept_tris=seam_kept_tris,
                   island_spanning_faces=spanning, **cut.fields())


def _normals_by_position(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k,3) float32 unit vertex normals of a LOD split at attribute seams, computed on the LOD
    welded by position only, so a UV seam or material border shades like the same surface
    without attributes (and like the bake without attributes)."""
    _, first, inverse = np.unique(row_keys(positions), return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    welded = inverse[faces]
    welded = welded[distinct_corners(welded)]
    welded = welded.astype(np.int32)
    ms = mesh_set(positions[first], welded)
    ms.compute_normal_per_vertex()
    return unit_normals(ms.current_mesh().vertex_normal_matrix(), positions[first], welded)[inverse]

