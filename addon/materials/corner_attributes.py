"""Per-corner attributes as each material reads them (node_tree): the UV map its image is
looked up through, with its constant Mapping applied, and the colour attribute its base colour
comes from, through its colour nodes.

Data form: one evaluated Blender mesh with its loop triangles; corner_uvs (t*3,2) float32,
colours (v,4) per vertex ("POINT") or (t*3,4) per corner ("CORNER") float32 linear RGBA;
tri_slot (t,) int64 material slot of each triangle. A mesh whose materials read only the active
UV map untransformed and no colour attribute is returned as it is, with nothing read.
"""
from __future__ import annotations

import numpy as np

from .node_tree import read_base_colour

IDENTITY_AFFINE = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


def material_corners(mesh, materials: list, *, tri_slot, corner_uvs, colors, domain: str,
                     readings: dict | None = None):
    """(corner_uvs, colors, domain) with each material's own UV map, UV transform and colour
    attribute applied to its triangles (module notes). materials: the object's slot materials
    (None for an empty slot); tri_slot None: the object has no material (nothing changes).
    readings: material name_full -> its reading, filled here (one read of each tree for a whole
    scene, not one per instance)."""
    if tri_slot is None:
        return corner_uvs, colors, domain
    readings = {} if readings is None else readings
    for m in materials:
        if m is not None and m.original.name_full not in readings:
            readings[m.original.name_full] = read_base_colour(m) if m.node_tree is not None else None
    readings = [readings[m.original.name_full] if m is not None else None for m in materials]
    sources = [(s, r) for s, r in enumerate(readings) if r is not None and r.source is not None]
    images = [(s, r.source) for s, r in sources if r.source.kind == "image"
              and (r.source.uv_map or r.source.uv_affine != IDENTITY_AFFINE)]
    attributes = [(s, r) for s, r in sources if r.source.kind == "attribute"]
    if not images and not attributes:
        return corner_uvs, colors, domain
    loops = _get(mesh.loop_triangles, "loops", np.int64, 3).ravel()
    corner_slot = np.repeat(np.asarray(tri_slot), 3)
    if corner_uvs is not None:
        corner_uvs = corner_uvs.copy()
        for slot, source in images:
            _transform_uvs(mesh, corner_uvs, loops, corner_slot == slot, source)
    if attributes:
        colors = _corner_colours(mesh, loops, colors, domain)
        domain = "CORNER"
        for slot, reading in attributes:
            at = corner_slot == slot
            values = _attribute_corners(mesh, reading.source.attribute, loops)
            colors[at] = reading.function(values[at]) if values is not None else 0.0  # Blender: black
    return corner_uvs, colors, domain


def _transform_uvs(mesh, corner_uvs: np.ndarray, loops: np.ndarray, at: np.ndarray, source) -> None:
    """corner_uvs[at] from the source's UV map (the active render one when it names none or one
    the mesh lacks), mapped by its (2,3) affine."""
    layer = mesh.uv_layers.get(source.uv_map) if source.uv_map else None
    uvs = _get(layer.data, "uv", np.float32, 2)[loops[at]] if layer is not None else corner_uvs[at]
    affine = np.asarray(source.uv_affine, np.float64)
    corner_uvs[at] = (uvs @ affine[:, :2].T + affine[:, 2]).astype(np.float32)


def _corner_colours(mesh, loops: np.ndarray, colors, domain: str) -> np.ndarray:
    """The colours per corner (t*3,4): the read ones expanded, white where none were read."""
    if colors is None:
        return np.ones((loops.size, 4), np.float32)
    if domain == "CORNER":
        return colors.copy()
    corner_vertices = _get(mesh.loop_triangles, "vertices", np.int64, 3).ravel()
    return colors[corner_vertices].copy()


def _attribute_corners(mesh, name: str, loops: np.ndarray) -> np.ndarray | None:
    """(t*3,4) float32 linear RGBA of the colour attribute `name` ("": the active one) per corner;
    None when the mesh has none of that name."""
    attribute = mesh.color_attributes.active_color if not name else mesh.color_attributes.get(name)
    if attribute is None:
        return None
    values = _get(attribute.data, "color", np.float32, 4)
    if attribute.domain == "CORNER":
        return values[loops]
    return values[_get(mesh.loop_triangles, "vertices", np.int64, 3).ravel()]


def _get(collection, attribute: str, dtype, width: int) -> np.ndarray:
    out = np.empty(len(collection) * width, dtype)
    collection.foreach_get(attribute, out)
    return out.reshape(-1, width)
