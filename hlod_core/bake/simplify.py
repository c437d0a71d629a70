"""One inner node's LOD and model-space error (DESIGN §4.3-4.4), with pymeshlab.

Data form: node geometry as positions (k,3) float32, in the bake's file-relative frame, faces
(m,3) int32 local to those positions and, when the scene has appearance, attribute rows (k,A)
float32 (appearance.pack: [material, u, v, r, g, b, a], the columns the scene has), one per
vertex. pymeshlab only ever sees a node in its own unit frame (`NodeFrame`: centred on the
node's box, scaled to a box diagonal of 1), so a model baked in millimetres gives the LODs of the
same model in metres, scaled (see `NodeFrame` for why).

- The children's LODs are concatenated and welded by exact position. Seams between siblings then
  become interior edges; seams with the rest of the scene stay boundary edges, and boundary
  preservation keeps their vertices fixed, so neighbouring nodes at different levels do not crack.
  Fixed vertices come back bit-identical: pymeshlab returns them unmoved (it computes in double) and
  `NodeFrame.to_model` maps every unmoved vertex back to its exact float32 input, which is what
  makes the exact weld one level up work.
- Quadric edge collapse (Garland & Heckbert 1997, pymeshlab
  `meshing_decimation_quadric_edge_collapse`) to `target_tris`.
- With attribute rows (issue 13) the weld is by exact (position, material, UV) bytes, so vertices
  that share a position but differ in material or UV stay distinct: material borders and UV seams
  become open boundaries, which boundary preservation keeps where they are, while seams between
  siblings (same position, same row) still weld. Colours do not split vertices: a welded vertex
  takes the mean colour of the vertices it merges, so a colour jump (corner-domain colours) becomes
  a blend across the triangles beside it one level up, instead of a seam no level could simplify.
  Such nodes decimate with vertices kept in place (no optimal placement): every LOD vertex then
  sits exactly on an input vertex and takes that vertex's row (`_row_sources`), so UVs stay the
  input's function of position (no texture sliding) and colours are the (welded) input vertices'
  colours: with kept positions there is nothing between vertices to interpolate. The costs: kept
  placement raises node errors (about 1.5x), and every material-border and UV-seam vertex is kept
  at every level, so nodes rich in seams decimate less (benchmarks/appearance_overhead.py --errors
  measures both). pymeshlab's texture-aware collapse (`..._with_texture`, on the mesh welded by
  position) simplifies seams instead, but lets material borders drift and extrapolates UVs past them.
- Crossing UV seams: where that LOD keeps more than SEAM_CROSSING_FACTOR x target_tris triangles
  (a scene unwrapped into many UV islands, e.g. Blender's smart project, froze a quarter of its
  triangles into the root), the node is decimated again from the same input welded by (position,
  material) only: UV seams become interior edges, material borders stay frozen, vertices still
  stay at input positions. A LOD vertex on a seam then has one input row per UV island there;
  each LOD face takes all its corners' rows from the island most of them are in (`uv_islands`,
  `_rows_per_face`), so faces inside one island keep exact UVs, and only faces that span two
  islands (a few percent) get a stretched texture. The LOD is split again per (vertex, row).
- The error (MSE, and the bound's h) is hausdorff.py's: it measures in the same NodeFrame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.appearance import AttributeLayout
from ..core.arrays import concat_indexed, segment_ranges


#: A LOD vertex this far (fraction of the node's diagonal) outside its input's box means the
#: quadric placement extrapolated; see decimate_node.
ESCAPE_FRACTION = 0.01

#: Fewest triangles asked of pymeshlab. An edge collapse removes the edge's two triangles, so a
#: closed surface decimated to 1 triangle goes from 2 to 0 and pymeshlab returns an empty mesh.
MIN_DECIMATION_TRIS = 2

#: A node with attribute rows whose LOD, keeping its UV seams, has more than this many times
#: target_tris triangles is decimated again across them (decimate_node).
SEAM_CROSSING_FACTOR = 2

#: Box diagonal of a node in the frame pymeshlab decimates and measures it in (NodeFrame). With 1,
#: every edge is shorter than 1, so vcglib's tie rule below (1e-15 x edge length) ranks exactly
#: planar collapses before all others, as it does for the unit-sized models it was tuned on.
UNIT_DIAGONAL = 1.0


@dataclass(frozen=True)
class NodeFrame:
    """The unit frame pymeshlab works in: local = (model - center) * scale, with the node's box
    centred on the origin and its diagonal UNIT_DIAGONAL (scale = 1 for a node of one point).

    pymeshlab's quadric collapse (vcglib `TriEdgeCollapseQuadric`) is not unit-free: it places a
    collapse's vertex optimally only where the raw, area-weighted quadric error (units length^6)
    exceeds an absolute 2e-15, and ranks collapses whose normalised error falls below 1e-15 by
    that constant times the edge length in model units, so the same model baked in metres and in
    millimetres gave different LODs (README, "Unit-free bakes"). In the unit frame those
    thresholds mean the same fraction of every node at every scale, and centring keeps the
    quadrics' offset terms from cancelling for nodes far from the bake's origin."""

    center: np.ndarray  # (3,) float64, model units
    scale: float        # 1 / model units

    @staticmethod
    def of(positions: np.ndarray) -> "NodeFrame":
        """The unit frame of positions (k,3), k >= 1, finite."""
        p = np.asarray(positions, np.float64)
        return NodeFrame.of_box(p.min(axis=0), p.max(axis=0))

    @staticmethod
    def of_box(lo: np.ndarray, hi: np.ndarray) -> "NodeFrame":
        """The unit frame of the box lo..hi (3,) float64 (`of` of positions whose box it is)."""
        diagonal = float(np.linalg.norm(hi - lo))
        return NodeFrame(center=0.5 * (lo + hi), scale=UNIT_DIAGONAL / diagonal if diagonal > 0 else 1.0)

    def to_local(self, positions: np.ndarray) -> np.ndarray:
        """(k,3) model units -> (k,3) float64 in the unit frame."""
        return (np.asarray(positions, np.float64) - self.center) * self.scale

    def to_model(self, local_out: np.ndarray, local_in: np.ndarray, model_in: np.ndarray) -> np.ndarray:
        """(j,3) float64 pymeshlab output -> (j,3) float32 model units. A vertex bit-identical to
        an input `local_in` row was not moved: it gets that row's exact `model_in` (float32)
        position, which the inverse transform would only round to."""
        out = (np.asarray(local_out, np.float64) / self.scale + self.center).astype(np.float32)
        if local_out.shape[0] == 0 or local_in.shape[0] == 0:
            return out
        keys_in = _row_keys(local_in)
        order = np.argsort(keys_in, kind="stable")
        sorted_in = keys_in[order]
        keys_out = _row_keys(local_out)
        at = np.minimum(np.searchsorted(sorted_in, keys_out), sorted_in.shape[0] - 1)
        unmoved = sorted_in[at] == keys_out
        out[unmoved] = np.asarray(model_in, np.float32)[order[at[unmoved]]]
        return out


def _row_keys(rows: np.ndarray) -> np.ndarray:
    """(k,3) float64 rows as (k,) 24-byte keys, equal exactly when the rows are bit-identical."""
    return np.ascontiguousarray(rows, dtype=np.float64).view(np.dtype((np.void, 24))).ravel()


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
    """positions (k,3) float32; faces (m,3) int32; normals (k,3) float32 or None; attributes (k,A)
    float32 attribute rows or None (a scene without appearance);
    decimated: False when kept as the children's welded union; input_tris: the welded union's
    triangles; kept_in_place: optimal placement left the node's box, so vertices stayed in place;
    zero_area: every triangle had zero area (pymeshlab removes them all), so the LOD is a sample
    of the welded union's triangles (see decimate_node); uv_seams_crossed: the LOD keeping its UV
    seams had seam_kept_tris > SEAM_CROSSING_FACTOR x target_tris triangles, so it was decimated
    again across them, and island_spanning_faces of its faces span two UV islands (their texture
    is stretched; see _decimate_across_uv_seams)."""

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


def weld(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices with bit-identical float32 positions; drop triangles that collapse."""
    key = np.ascontiguousarray(positions, dtype=np.float32).view(np.dtype((np.void, 12))).ravel()
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    welded = inverse.reshape(-1)[faces]
    keep = (welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 0] != welded[:, 2])
    return positions[first], welded[keep].astype(np.int32)


def weld_rows(positions: np.ndarray, rows: np.ndarray, faces: np.ndarray,
              key_columns: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`weld` for vertices with attribute rows (k,A) float32: merge vertices whose float32 position
    AND first `key_columns` row columns (all by default) are bit-identical; the other columns of a
    merged vertex are the mean of its vertices'. Drops triangles that collapse. Returns
    (positions, rows (float32), faces int32)."""
    p = np.ascontiguousarray(positions, dtype=np.float32)
    r = np.ascontiguousarray(rows, dtype=np.float32)
    keyed = r.shape[1] if key_columns is None else key_columns
    both = np.concatenate([p.view(np.uint8).reshape(-1, 12),
                           np.ascontiguousarray(r[:, :keyed]).view(np.uint8).reshape(p.shape[0], -1)], axis=1)
    key = np.ascontiguousarray(both).view(np.dtype((np.void, 4 * (3 + keyed)))).ravel()
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    welded_rows = r[first]
    if keyed < r.shape[1]:
        members = np.bincount(inverse, minlength=first.shape[0]).astype(np.float64)
        for column in range(keyed, r.shape[1]):
            welded_rows[:, column] = np.bincount(inverse, weights=r[:, column], minlength=first.shape[0]) / members
    welded = inverse[faces]
    keep = (welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 0] != welded[:, 2])
    return positions[first], welded_rows, welded[keep].astype(np.int32)


def collapsed(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(f,) bool: triangles with two corners at bit-identical float32 positions, which `weld`
    drops. They do not count toward a node's triangle budget (octree and leaf budget check)."""
    p = np.asarray(positions, np.float32)
    return collapsed_corners(p[faces[:, 0]], p[faces[:, 1]], p[faces[:, 2]])


def collapsed_corners(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """`collapsed` of the triangles with corners a, b, c (f,3) float32."""
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


def decimate_node(child_lods: list[tuple], settings: DecimationSettings, with_normals: bool,
                  layout: AttributeLayout | None = None) -> NodeLod:
    """child_lods: [(positions f32, faces)] or [(positions f32, faces, attribute rows (k,A) f32 or
    None)] of the children, all with rows or all without; layout: the rows' columns (None: every
    column is kept exact, as a UV). The node's error is `measure`'s job: it needs the original
    triangles, the decimation does not, so the two run as separate tasks."""
    rows = _child_rows(child_lods)
    if rows is not None:
        return _decimate_with_rows(child_lods, rows, settings, with_normals, layout)
    positions, faces = concat_indexed((child[0], child[1]) for child in child_lods)
    positions, faces = weld(positions, faces)

    welded_tris = int(faces.shape[0])
    decimated = welded_tris > settings.target_tris
    frame = NodeFrame.of(positions)
    local = frame.to_local(positions)
    if not decimated:
        ms = _mesh_set(local, faces)
    else:
        ms = _decimated(local, faces, settings, optimal_placement=True)
    lo, hi = local.min(axis=0), local.max(axis=0)
    lod_box = ms.current_mesh().bounding_box()
    # Optimal placement may move a vertex slightly outward on curved surfaces (that lowers the
    # error); leaving the input's box by more than ESCAPE_FRACTION of its diagonal is the
    # singular-quadric extrapolation instead, so decimate again with vertices kept in place.
    slack = ESCAPE_FRACTION * float(np.linalg.norm(hi - lo))
    kept_in_place = bool(ms.current_mesh().face_number() > 0
                         and (np.any(lod_box.min() < lo - slack) or np.any(lod_box.max() > hi + slack)))
    if kept_in_place:
        ms = _decimated(local, faces, settings, optimal_placement=False)
    zero_area = ms.current_mesh().face_number() == 0
    if zero_area:
        # Every triangle had zero area, and pymeshlab's clean-up removes such triangles: keep
        # target_tris of the union's, evenly spaced (they draw nothing; the error measures the rest).
        kept_p, kept_f, _ = compact(local, faces[_evenly_spaced(welded_tris, settings.target_tris)])
        ms = _mesh_set(kept_p, kept_f)
    lod = ms.current_mesh()
    normals = None
    if with_normals:
        ms.compute_normal_per_vertex()
        normals = _unit_normals(ms.current_mesh().vertex_normal_matrix(), lod.vertex_matrix(), lod.face_matrix())
    return NodeLod(positions=frame.to_model(lod.vertex_matrix(), local, positions),
                   faces=lod.face_matrix().astype(np.int32), normals=normals, decimated=decimated,
                   input_tris=welded_tris, kept_in_place=kept_in_place, zero_area=zero_area)


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


def _decimate_with_rows(child_lods: list[tuple], rows: np.ndarray, settings: DecimationSettings,
                        with_normals: bool, layout: AttributeLayout | None) -> NodeLod:
    """decimate_node for children with attribute rows (module docstring): weld by (position,
    material, UV), colours averaged, collapse with vertices kept in place, and give every LOD
    vertex the row of the input vertex it sits on. pymeshlab carries each input vertex's id
    through the collapse as its vertex scalar. A LOD that keeps its UV seams but stays above
    SEAM_CROSSING_FACTOR x target_tris is made again across them (_decimate_across_uv_seams)."""
    positions, faces = concat_indexed((child[0], child[1]) for child in child_lods)
    columns = layout.columns() if layout is not None else {}
    positions, rows, faces = weld_rows(positions, rows, faces,
                                       key_columns=columns["color"].start if "color" in columns else None)
    welded_tris = int(faces.shape[0])
    decimated = welded_tris > settings.target_tris
    frame = NodeFrame.of(positions)
    local = frame.to_local(positions)
    ids = np.arange(local.shape[0], dtype=np.float64)  # exact: far fewer than 2**53 vertices
    if decimated:
        ms = _decimated(local, faces, settings, optimal_placement=False, vertex_ids=ids)
    else:
        ms = _mesh_set(local, faces, vertex_ids=ids)
    zero_area = ms.current_mesh().face_number() == 0
    if zero_area:  # as in decimate_node
        kept_p, kept_f, used = compact(local, faces[_evenly_spaced(welded_tris, settings.target_tris)])
        ms = _mesh_set(kept_p, kept_f, vertex_ids=ids[used])
    lod = ms.current_mesh()
    local_out = lod.vertex_matrix()
    faces_out = lod.face_matrix().astype(np.int32)
    source = _row_sources(local_out, lod.vertex_scalar_array().round().astype(np.int64), local, rows)
    seam_kept_tris, spanning = int(faces_out.shape[0]), 0
    too_many = seam_kept_tris > SEAM_CROSSING_FACTOR * settings.target_tris
    if decimated and not zero_area and "uv" in columns and too_many:
        crossed = _decimate_across_uv_seams(positions, local, rows, faces, settings,
                                            material=columns.get("material"), uv=columns["uv"])
        if crossed is not None and crossed[1].shape[0] < seam_kept_tris:
            local_out, faces_out, source, spanning = crossed
    normals = _normals_by_position(local_out, faces_out) if with_normals else None
    return NodeLod(positions=frame.to_model(local_out, local, positions), faces=faces_out, normals=normals,
                   decimated=decimated, input_tris=welded_tris, zero_area=zero_area,
                   attributes=np.ascontiguousarray(rows[source], np.float32),
                   uv_seams_crossed=faces_out.shape[0] < seam_kept_tris, seam_kept_tris=seam_kept_tris,
                   island_spanning_faces=spanning)


def _decimate_across_uv_seams(positions: np.ndarray, local: np.ndarray, rows: np.ndarray, faces: np.ndarray,
                              settings: DecimationSettings, *, material: slice | None, uv: slice):
    """The LOD of a node welded by (position, material) only: UV seams become interior edges that
    the collapse crosses, material borders stay open boundaries and stay put. Vertices stay in
    place, so each LOD vertex sits on a (position, material) of the input, where one input row per
    UV island meets; every LOD face takes its corners' rows from one island (_rows_per_face), and
    a LOD vertex is split once per row its faces take.

    positions (k,3) float32, local (k,3) float64 (the same in the unit frame), rows (k,A), faces
    (f,3): the node's input welded by (position, material, UV). Returns (local_out (j,3) float64,
    faces_out (m,3) int32, source (j,) int64 input rows, island_spanning_faces), or None where
    there is no UV seam or the collapse leaves no triangle."""
    keyed = np.ascontiguousarray(positions, np.float32).view(np.uint8).reshape(-1, 12)
    if material is not None:
        material_bytes = np.ascontiguousarray(rows[:, material]).view(np.uint8).reshape(-1, 4)
        keyed = np.concatenate([keyed, material_bytes], axis=1)
    key = np.ascontiguousarray(keyed).view(np.dtype((np.void, keyed.shape[1]))).ravel()
    _, first, coarse_of = np.unique(key, return_index=True, return_inverse=True)
    if first.shape[0] == local.shape[0]:
        return None  # no UV seam: the same mesh as the one that kept them
    coarse_of = coarse_of.reshape(-1)
    coarse_faces = coarse_of[faces]
    coarse_faces = coarse_faces[(coarse_faces[:, 0] != coarse_faces[:, 1]) & (coarse_faces[:, 1] != coarse_faces[:, 2])
                                & (coarse_faces[:, 0] != coarse_faces[:, 2])].astype(np.int32)
    coarse_ids = np.arange(first.shape[0], dtype=np.float64)
    ms = _decimated(local[first], coarse_faces, settings, optimal_placement=False, vertex_ids=coarse_ids)
    lod = ms.current_mesh()
    if lod.face_number() == 0:
        return None
    local_out = lod.vertex_matrix()
    coarse_source = _row_sources(local_out, lod.vertex_scalar_array().round().astype(np.int64), local[first],
                                 rows[first])
    corner_rows, spanning = _rows_per_face(lod.face_matrix().astype(np.int64), coarse_source, coarse_of,
                                           faces, rows[:, uv].astype(np.float64), fallback_row=first)
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


def _rows_per_face(faces_out: np.ndarray, vertex_source: np.ndarray, group_of_row: np.ndarray,
                   faces_in: np.ndarray, uvs: np.ndarray, *, fallback_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


def _row_sources(local_out: np.ndarray, survivor: np.ndarray, local_in: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """(j,) int64: the input vertex whose attribute row each LOD vertex takes.

    local_out (j,3) float64: LOD positions, each bit-identical to some input position (collapse
    without optimal placement); survivor (j,) int64: the input vertex each LOD vertex was (its
    pymeshlab vertex scalar); local_in (k,3) float64 and rows (k,A): the welded input.
    A survivor at its own input position keeps its own row (pymeshlab 2025.7 always keeps the
    survivor where it was). One moved onto another input vertex's position takes that vertex's
    row: boundary vertices (every seam and border) never move and after the (position, row) weld
    interior positions are unique, so that vertex is unique, except where input vertices share a
    position without being on a boundary (two surfaces touching at a point): then the one whose
    row is nearest the survivor's (Euclidean, then the lowest id) decides, deterministically. A
    vertex on no input position (not expected) keeps its survivor's row."""
    keys_in, keys_out = _row_keys(local_in), _row_keys(local_out)
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


def _normals_by_position(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k,3) float32 unit vertex normals of a LOD split at attribute seams, computed on the LOD
    welded by position only, so a UV seam or material border shades like the same surface
    without attributes (and like the bake without attributes)."""
    _, first, inverse = np.unique(_row_keys(positions), return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    welded = inverse[faces]
    welded = welded[(welded[:, 0] != welded[:, 1]) & (welded[:, 1] != welded[:, 2]) & (welded[:, 0] != welded[:, 2])]
    welded = welded.astype(np.int32)
    ms = _mesh_set(positions[first], welded)
    ms.compute_normal_per_vertex()
    return _unit_normals(ms.current_mesh().vertex_normal_matrix(), positions[first], welded)[inverse]


def _unit_normals(normals: np.ndarray, positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
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


def _mesh_set(positions: np.ndarray, faces: np.ndarray, vertex_ids: np.ndarray | None = None):
    """A pymeshlab MeshSet of one mesh; vertex_ids (k,) float64, when given, as its vertex scalar."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    if vertex_ids is None:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=positions.astype(np.float64), face_matrix=faces))
    else:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=positions.astype(np.float64), face_matrix=faces,
                                   v_scalar_array=np.asarray(vertex_ids, np.float64)))
    return ms


def _decimated(positions, faces, settings: DecimationSettings, *, optimal_placement: bool,
               vertex_ids: np.ndarray | None = None):
    """Quadric edge collapse with boundary preservation, on positions in the node's unit frame.
    planarquadric adds the planar constraints that keep flat regions (ground planes, walls) from
    being extrapolated: without them a flat cell's singular quadric can place a vertex tens of
    metres away. With vertex_ids (a node with attribute rows) the vertices may share positions
    (seams), and pymeshlab's autoclean would merge them (it removes duplicate vertices): the rest
    of its clean-up, null faces and unreferenced vertices, runs alone."""
    ms = _mesh_set(positions, faces, vertex_ids)
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
