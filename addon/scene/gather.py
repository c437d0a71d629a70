"""Blender meshes into hlod_core (docs/user-guide.md): the evaluated geometry of the chosen objects (modifiers
applied, instances from collection instances, particles and geometry nodes realised, world
transforms; which instances, and what is skipped and named: addon/scene/objects.py), read through
the depsgraph without touching the source objects, as one
`meshes.TriangleMesh` in world units, with its appearance (hlod_core/model/appearance.py):
- per triangle, the material: loop_triangles' material_index resolved through the evaluated
  object's material slots to the material datablock; one `Material` row per datablock (keyed by
  name_full, shared by every object and instance using it; addon/materials/rows.py), the default row
  for an empty slot;
- per corner, the active render UV map and the active colour attribute (POINT or CORNER domain,
  linear `.color`), or for a material's triangles the UV map, UV transform and colour attribute its
  nodes read (addon/materials/corner_attributes.py). Vertices are split where their corners' values
  differ: one vertex per distinct (vertex, uv, colour) (`split_corners`).
A selection with no material has no UVs either (nothing it draws uses them); one with no material,
UV map or colour attribute gives a mesh without appearance. The way out, Blender objects for a set
of nodes, is addon/scene/node_objects.py.
"""
from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass

import numpy as np

from ...hlod_core.core.errors import InputError
from ...hlod_core.io import meshes
from ...hlod_core.model.appearance import Material
from ..materials.corner_attributes import material_corners
from ..materials.rows import DEFAULT_MATERIAL, cached_material_row
from .objects import NOT_FINITE, Skipped, drawn_instances, note_hidden, owner, shown_hidden


@dataclass(eq=False)
class _Part:
    """One instance's triangles as read from Blender, before the selection-wide choices.
    positions (v,3) float64 world; corners (t*3,) int64 vertex per triangle corner; corner_uvs
    (t*3,2) float32 or None; colors (v,4) or (t*3,4) float32 linear or None (`color_domain` says
    which); tri_slot (t,) int64 rows of `slots` (the object's material rows, None for an empty
    slot), None when the object has no material."""

    label: str
    positions: np.ndarray
    corners: np.ndarray
    corner_uvs: np.ndarray | None
    colors: np.ndarray | None
    color_domain: str
    tri_slot: np.ndarray | None
    slots: list


def evaluated_mesh(context, objects, *, taken: list | None = None, attributes: dict | None = None,
                   skipped: Skipped | None = None, include_hidden: bool = False) -> meshes.TriangleMesh:
    """Triangles of every object in `objects` and of every instance they make, world space, with
    their appearance (module notes): each triangle Blender draws (addon/scene/objects.py).
    taken: if given, receives the objects of `objects` that gave triangles, in `objects`' order.
    attributes: if given, receives the names of the UV map and the colour attribute carried
    ({"uv_map": ..., "color_attribute": ...}, each only when carried: the most used name when the
    objects name them differently), for the bake's meta. skipped: if given, receives what was left
    out (kinds without triangles, hidden objects, geometry that cannot be baked). include_hidden:
    take objects hidden in the viewport too. InputError when nothing gives triangles."""
    skipped = Skipped() if skipped is None else skipped
    if include_hidden:
        with shown_hidden(context) as depsgraph:
            return _evaluated_mesh(depsgraph, objects, taken=taken, attributes=attributes, skipped=skipped)
    depsgraph = context.evaluated_depsgraph_get()
    note_hidden(objects, depsgraph, skipped)
    return _evaluated_mesh(depsgraph, objects, taken=taken, attributes=attributes, skipped=skipped)


def _evaluated_mesh(depsgraph, objects, *, taken: list | None, attributes: dict | None,
                    skipped: Skipped) -> meshes.TriangleMesh:
    wanted = {o.name_full for o in objects}
    with_materials = any(slot.material is not None for inst in drawn_instances(depsgraph, wanted)
                         for slot in inst.object.material_slots)
    rows: dict[str, Material] = {}  # material name_full -> its row, made once per datablock
    readings: dict = {}  # material name_full -> its node tree's reading (materials/node_tree.py), once per datablock
    keyed, owners, uv_names, colour_names = [], set(), Counter(), Counter()
    for inst in drawn_instances(depsgraph, wanted, skipped):
        chosen = owner(inst)
        label = f"{chosen.name}" + (f" (instance of {inst.object.original.name})" if inst.is_instance else "")
        try:
            part = _read_instance(inst, depsgraph, label, rows=rows, readings=readings,
                                  uv_names=uv_names if with_materials else None,
                                  colour_names=colour_names)
        except RuntimeError as exc:  # Blender could not give the object's mesh
            raise InputError(f"Bake: object {chosen.name!r}: Blender gives no mesh for it: {exc}") from exc
        if part is None:
            continue
        if not np.isfinite(part.positions).all():
            skipped.add(NOT_FINITE, chosen.name)
            continue
        keyed.append((_instance_key(inst, chosen), part))
        owners.add(chosen.name_full)
    keyed.sort(key=lambda item: item[0])
    parts = [part for _, part in keyed]
    if not parts:
        left_out = f" ({skipped.text()})" if skipped else ""
        raise InputError(f"Bake: the chosen objects have no triangles (meshes, curves or text with faces){left_out}")
    if taken is not None:
        taken.extend(o for o in objects if o.name_full in owners)
    part_meshes = [_part_mesh(part) for part in parts]
    if attributes is not None:
        if uv_names:
            attributes["uv_map"] = uv_names.most_common(1)[0][0]
        if colour_names:
            attributes["color_attribute"] = colour_names.most_common(1)[0][0]
    names = [part.label for part in parts]
    return _materials_by_name(meshes.merge(part_meshes, name=", ".join(names[:3]) + (" ..." if len(names) > 3 else "")))


def _instance_key(inst, owner) -> tuple:
    """Where an instance goes in the bake's input: by its chosen object's name, then the
    instanced object's name and the instance's place in its instancer (persistent_id). The
    depsgraph lists instances in the view layer's order, which linking an object again or moving
    it to another collection changes; this order does not, so neither do the triangles' order and
    the bake cache's keys ([re-bakes](docs/how-it-works.md#re-bakes-and-the-cache-keys))."""
    return (owner.name_full, inst.object.original.name_full, tuple(inst.persistent_id) if inst.is_instance else ())


def _materials_by_name(mesh: meshes.TriangleMesh) -> meshes.TriangleMesh:
    """The mesh with its material table sorted by name: a material's id (an attribute column of
    every vertex row, part of the bake cache's keys) then depends on which materials the scene has,
    not on which object came first."""
    if mesh.material_ids is None or len(mesh.materials) < 2:
        return mesh
    order = sorted(range(len(mesh.materials)), key=lambda i: (mesh.materials[i].name, repr(mesh.materials[i])))
    new_id = np.empty(len(order), np.int32)
    new_id[order] = np.arange(len(order), dtype=np.int32)
    return dataclasses.replace(mesh, material_ids=new_id[mesh.material_ids],
                               materials=tuple(mesh.materials[i] for i in order))


def _read_instance(inst, depsgraph, label: str, *, rows: dict, readings: dict, uv_names: Counter | None,
                   colour_names: Counter) -> _Part | None:
    """One instance's triangles, corner attributes and material rows (None: no triangles). The UV
    map is read only when `uv_names` is given (the selection has materials), material indices
    only when the object has a material: nothing is read that the scene does not carry."""
    obj = inst.object
    slots = [cached_material_row(slot.material, rows) if slot.material is not None else None
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
        corner_uvs, colors, domain = _corner_attributes(mesh, uv_names=uv_names, colour_names=colour_names)
        corner_uvs, colors, domain = material_corners(mesh, [s.material for s in obj.material_slots],
                                                      tri_slot=tri_slot, corner_uvs=corner_uvs, colors=colors,
                                                      domain=domain, readings=readings)
    finally:
        obj.to_mesh_clear()
    matrix = np.array(inst.matrix_world, np.float64)
    positions = positions @ matrix[:3, :3].T + matrix[:3, 3]
    if np.linalg.det(matrix[:3, :3]) < 0:  # a mirroring transform keeps faces facing out
        corners = corners.reshape(-1, 3)[:, ::-1].ravel()
        corner_uvs = None if corner_uvs is None else corner_uvs.reshape(tris, 3, 2)[:, ::-1].reshape(-1, 2)
        if domain == "CORNER":
            colors = colors.reshape(tris, 3, 4)[:, ::-1].reshape(-1, 4)
    return _Part(label=label, positions=positions, corners=corners, corner_uvs=corner_uvs, colors=colors,
                 color_domain=domain, tri_slot=tri_slot, slots=slots)


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


def _part_mesh(part: _Part) -> meshes.TriangleMesh:
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
