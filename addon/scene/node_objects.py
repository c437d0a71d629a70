"""Materialize: Blender mesh objects for a set of HLOD nodes, in a collection of their own, with the
source materials in their slots (addon/materials/rows.py), the UV map and the colour attribute by the
names the bake recorded.

Data form: in, an Hlod (positions float32 relative to its float64 origin) and node ids; out, one
mesh object per node in world positions, tagged with its node id and depth.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...hlod_core.model.hierarchy import node_geometry
from ..materials.rows import material_from_row

#: Names Materialize gives the UV map and the colour attribute when the bake did not record them.
DEFAULT_UV_MAP, DEFAULT_COLOR_ATTRIBUTE = "UVMap", "Color"


def materialize(hlod, nodes, name: str) -> bpy.types.Collection:
    """One mesh object per node, world positions (file origin added back), in a new collection
    named `name` linked to the scene: the materials the node uses in its slots, the UV map and the
    colour attribute (per vertex: POINT domain). Returns the collection."""
    collection = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(collection)
    made: dict[int, object] = {}  # table row -> material datablock, shared by the objects
    uv_name = str(hlod.meta.get("uv_map") or DEFAULT_UV_MAP)
    colour_name = str(hlod.meta.get("color_attribute") or DEFAULT_COLOR_ATTRIBUTE)
    for node in nodes:
        node = int(node)
        geometry = node_geometry(hlod, node)
        mesh = _node_mesh_data(f"{name} node {node}", geometry, hlod.origin)
        _add_attributes(mesh, geometry, uv_name=uv_name, colour_name=colour_name)
        if geometry.face_material is not None:
            used, local = np.unique(geometry.face_material, return_inverse=True)
            for row in used.tolist():
                if row not in made:
                    made[row] = material_from_row(hlod.materials[row])
                mesh.materials.append(made[row])
            mesh.polygons.foreach_set("material_index", local.astype(np.int32))
        mesh.update()
        mesh.validate()
        obj = bpy.data.objects.new(f"{name} node {node}", mesh)
        obj["hlod_node"] = node
        obj["hlod_depth"] = int(hlod.depth[node])
        collection.objects.link(obj)
    return collection


def _node_mesh_data(name: str, geometry, origin: np.ndarray):
    """A Blender mesh of one node's triangles, world positions."""
    positions = geometry.positions.astype(np.float64) + origin
    faces = geometry.faces
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(positions.shape[0])
    mesh.vertices.foreach_set("co", positions.astype(np.float32).ravel())
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.ravel().astype(np.int32))
    mesh.polygons.add(faces.shape[0])
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    return mesh


def _add_attributes(mesh, geometry, *, uv_name: str, colour_name: str) -> None:
    """The node's UVs as a UV map (per corner) and its colours as the active, rendered colour
    attribute (per vertex), where it has them."""
    if geometry.uvs is not None:
        layer = mesh.uv_layers.new(name=uv_name)
        layer.data.foreach_set("uv", geometry.uvs[geometry.faces.ravel()].ravel())
    if geometry.colors is not None:
        colour = mesh.color_attributes.new(colour_name, "FLOAT_COLOR", "POINT")
        colour.data.foreach_set("color", geometry.colors.ravel())
        mesh.color_attributes.active_color = colour
        mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index


def nodes_at_depth(hlod, depth: int) -> np.ndarray:
    """The cut at `depth`: nodes at that level, plus leaves above it."""
    level = np.asarray(hlod.depth)
    return np.flatnonzero((level == depth) | ((hlod.child_count == 0) & (level < depth)))
