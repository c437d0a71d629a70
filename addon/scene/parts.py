"""One instance's triangles as read from Blender (the bake's parts, scene/gather.py): the
evaluated mesh of a depsgraph instance in world units, with its appearance (hlod_core/model/appearance.py):
- per triangle, the material: loop_triangles' material_index resolved through the evaluated
  object's material slots to the material datablock; one `Material` row per datablock (keyed by
  name_full, shared by every object and instance using it; addon/materials/rows.py), the default row
  for an empty slot;
- per corner, the active render UV map and the active colour attribute (POINT or CORNER domain,
  linear `.color`), or for a material's triangles the UV map, UV transform and colour attribute its
  nodes read (addon/materials/corner_attributes.py). Vertices are split where their corners' values
  differ: one vertex per distinct (vertex, uv, colour) (`split_corners`).
A mirroring transform keeps faces facing out. `PartReader` reads each material's row and node tree
once for a whole scene, not once per instance. A part drawn with a material whose colour Cycles
bakes (node_tree's `unreadable`) notes its evaluated mesh for the bake (scene/surface_bakes.py)
and keeps the mesh loop of each triangle corner.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ...hlod_core.io import meshes
from ...hlod_core.model.appearance import Material
from ..materials.corner_attributes import material_corners
from ..materials.rows import DEFAULT_MATERIAL, cached_material_row, uses_nodes
from .objects import instance_key
from .surface_bakes import SurfaceBakes


@dataclass(eq=False)
class Part:
    """One instance's triangles as read from Blender, before the selection-wide choices.
    positions (v,3) float64 world; corners (t*3,) int64 vertex per triangle corner; corner_uvs
    (t*3,2) float32 or None; colors (v,4) or (t*3,4) float32 linear or None (`color_domain` says
    which); tri_slot (t,) int64 rows of `slots` (the object's material rows, None for an empty
    slot), None when the object has no material. bake_key: its evaluated mesh's key in the
    gathering's SurfaceBakes when Cycles bakes a material it draws, with corner_loops (t*3,) int64
    the mesh loop of each triangle corner; None otherwise."""

    label: str
    positions: np.ndarray
    corners: np.ndarray
    corner_uvs: np.ndarray | None
    colors: np.ndarray | None
    color_domain: str
    tri_slot: np.ndarray | None
    slots: list
    bake_key: tuple | None = None
    corner_loops: np.ndarray | None = None


@dataclass
class PartReader:
    """Reads the parts of one gathering. read_uvs: read the active render UV map (the selection has
    materials: nothing else uses UVs); rows: material name_full -> its row, and readings: material
    name_full -> its node tree's reading (materials/node_tree.py), each made once per datablock;
    uv_names / colour_names: how many parts carried each UV map's / colour attribute's name;
    surfaces: where the evaluated meshes Cycles bakes are noted (None: nothing is noted)."""

    read_uvs: bool
    surfaces: SurfaceBakes | None = None
    rows: dict[str, Material] = field(default_factory=dict)
    readings: dict = field(default_factory=dict)
    uv_names: Counter = field(default_factory=Counter)
    colour_names: Counter = field(default_factory=Counter)

    def read(self, inst, depsgraph, label: str) -> Part | None:
        """One instance's triangles, corner attributes and material rows (None: no triangles). The
        UV map is read only with `read_uvs`, material indices only when the object has a material:
        nothing is read that the scene does not carry. RuntimeError: Blender gives no mesh for it."""
        obj = inst.object
        slots = [cached_material_row(slot.material, self.rows) if slot.material is not None else None
                 for slot in obj.material_slots]
        mesh = obj.to_mesh(preserve_all_data_layers=False, depsgraph=depsgraph)
        try:
            if mesh is None or len(mesh.loop_triangles) == 0 and not _triangulate(mesh):
                return None
            tris = len(mesh.loop_triangles)
            positions = _get(mesh.vertices, "co", dtype=np.float64, width=3)
            corners = _get(mesh.loop_triangles, "vertices", dtype=np.int64, width=3).ravel()
            tri_slot = None
            if any(row is not None for row in slots):
                slot = _get(mesh.loop_triangles, "material_index", dtype=np.int64, width=1).ravel()
                tri_slot = np.clip(slot, 0, len(slots) - 1)
            corner_uvs, colors, domain = _corner_attributes(mesh, uv_names=self.uv_names if self.read_uvs else None,
                                                            colour_names=self.colour_names)
            corner_uvs, colors, domain = material_corners(mesh, [s.material for s in obj.material_slots],
                                                          tri_slot=tri_slot, corner_uvs=corner_uvs, colors=colors,
                                                          domain=domain, readings=self.readings)
            bake_key, corner_loops = self._note_bake(inst, depsgraph, mesh, tri_slot)
        finally:
            obj.to_mesh_clear()
        matrix = np.array(inst.matrix_world, np.float64)
        positions = positions @ matrix[:3, :3].T + matrix[:3, 3]
        if np.linalg.det(matrix[:3, :3]) < 0:  # a mirroring transform keeps faces facing out
            corners = corners.reshape(-1, 3)[:, ::-1].ravel()
            corner_loops = None if corner_loops is None else corner_loops.reshape(-1, 3)[:, ::-1].ravel()
            corner_uvs = None if corner_uvs is None else corner_uvs.reshape(tris, 3, 2)[:, ::-1].reshape(-1, 2)
            if domain == "CORNER":
                colors = colors.reshape(tris, 3, 4)[:, ::-1].reshape(-1, 4)
        return Part(label=label, positions=positions, corners=corners, corner_uvs=corner_uvs, colors=colors,
                    color_domain=domain, tri_slot=tri_slot, slots=slots, bake_key=bake_key, corner_loops=corner_loops)

    def _note_bake(self, inst, depsgraph, mesh, tri_slot) -> tuple:
        """(bake key, corner loops (t*3,) int64) when a slot the instance's triangles use has a
        material whose colour Cycles bakes (its evaluated mesh noted in `surfaces`), else (None, None)."""
        if self.surfaces is None or tri_slot is None:
            return None, None
        readings = {}
        for slot, held in enumerate(inst.object.material_slots):
            material = held.material
            reading = self.readings.get(material.original.name_full) if material is not None else None
            if reading is not None and reading.unreadable and uses_nodes(material):
                readings[slot] = reading
        if readings:  # only the slots its triangles use
            used = np.unique(tri_slot).tolist()
            readings = {slot: reading for slot, reading in readings.items() if slot in used}
        if not readings:
            return None, None
        uv_layer = next((layer for layer in mesh.uv_layers if layer.active_render), None) if self.read_uvs else None
        key = self.surfaces.take(inst, depsgraph, readings=readings, order=instance_key(inst),
                                 uv_map=uv_layer.name if uv_layer is not None else None)
        return key, _get(mesh.loop_triangles, "loops", dtype=np.int64, width=3).ravel()


def _corner_attributes(mesh, *, uv_names: Counter | None, colour_names: Counter):
    """(corner_uvs (t*3,2) or None, colours (v,4) or (t*3,4) or None, their domain "POINT", "CORNER"
    or ""): the active render UV map (read only when `uv_names` is given) and the active colour
    attribute, per triangle corner; the names read are counted in `uv_names` / `colour_names`."""
    uv_layer = None if uv_names is None else next((layer for layer in mesh.uv_layers if layer.active_render), None)
    colour = mesh.color_attributes.active_color
    corner_loops = None
    if uv_layer is not None or colour is not None and colour.domain == "CORNER":
        corner_loops = _get(mesh.loop_triangles, "loops", dtype=np.int64, width=3).ravel()
    corner_uvs = None
    if uv_layer is not None:
        corner_uvs = _get(uv_layer.data, "uv", dtype=np.float32, width=2)[corner_loops]
        uv_names[uv_layer.name] += 1
    colors, domain = None, ""
    if colour is not None:
        colors, domain = _get(colour.data, "color", dtype=np.float32, width=4), colour.domain
        if domain == "CORNER":
            colors = colors[corner_loops]
        colour_names[colour.name] += 1
    return corner_uvs, colors, domain


def _get(collection, attribute: str, *, dtype, width: int) -> np.ndarray:
    """collection's `attribute` for every item, (n, width) through foreach_get."""
    out = np.empty(len(collection) * width, dtype)
    collection.foreach_get(attribute, out)
    return out.reshape(-1, width)


def part_mesh(part: Part) -> meshes.TriangleMesh:
    """The part as a TriangleMesh: vertices split where corner values differ; material ids when
    this object has a material (meshes.merge gives the others the default row)."""
    corner_colours = part.colors if part.color_domain == "CORNER" else None
    split = [a for a in (part.corner_uvs, corner_colours) if a is not None]
    vertex, faces, uvs, colors = None, part.corners.reshape(-1, 3), None, None
    if split:
        vertex, faces, values = split_corners(part.corners, split)
        uvs = values[0] if part.corner_uvs is not None else None
        colors = values[-1] if corner_colours is not None else None
    if part.color_domain == "POINT":
        colors = part.colors if vertex is None else part.colors[vertex]
    positions = part.positions if vertex is None else part.positions[vertex]
    materials, material_ids = (), None
    if part.tri_slot is not None:
        table = list(dict.fromkeys(row or DEFAULT_MATERIAL for row in part.slots))
        slot_row = np.array([table.index(row or DEFAULT_MATERIAL) for row in part.slots], np.int32)
        materials, material_ids = tuple(table), slot_row[part.tri_slot]
    return meshes.from_arrays(positions, faces, name=part.label, uvs=uvs, colors=colors,
                              material_ids=material_ids, materials=materials)


def split_corners(corners: np.ndarray, values: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """One vertex per distinct (vertex, corner values): corners (c,) int vertex of each triangle
    corner, values: per-corner float32 arrays (c, k). Returns (vertex (n,) int64: the source vertex
    of each new vertex, faces (c/3, 3) int64 new vertices, the values per new vertex). Equal means
    bit-equal (after -0.0 -> 0.0). Most corners hold their vertex's first corner's values (no seam
    there): they keep the vertex; only the others are sorted out (np.unique on their bytes)."""
    corners = np.asarray(corners, np.int64)
    bits = np.ascontiguousarray(np.concatenate([(np.asarray(v, np.float32) + np.float32(0.0)).view(np.uint32)
                                                for v in values], axis=1))
    first = np.empty(int(corners.max()) + 1, np.int64)
    first[corners[::-1]] = np.arange(corners.size - 1, -1, -1)  # the first corner of every used vertex
    seam = np.flatnonzero(np.any(bits != bits[first[corners]], axis=1))
    used = np.unique(corners)
    new_id = np.zeros(first.size, np.int64)
    new_id[used] = np.arange(used.size)
    ids = new_id[corners]
    keep = first[used]  # the corner whose values each kept vertex takes
    if seam.size:
        key = np.ascontiguousarray(np.concatenate([corners[seam, None].astype(np.uint32), bits[seam]], axis=1))
        key = key.view(np.dtype((np.void, 4 * key.shape[1]))).ravel()
        _, at, inverse = np.unique(key, return_index=True, return_inverse=True)
        ids[seam] = used.size + inverse.ravel()
        keep = np.concatenate([keep, seam[at]])
    return corners[keep], ids.reshape(-1, 3), [np.asarray(v, np.float32)[keep] for v in values]


def _triangulate(mesh) -> bool:
    mesh.calc_loop_triangles()
    return len(mesh.loop_triangles) > 0
