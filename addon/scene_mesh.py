"""Blender meshes in and out of hlod_core (DESIGN §8).

In: the evaluated geometry of the chosen objects (modifiers applied, instances from collection
instances, particles and geometry nodes realised, world transforms), read through the depsgraph
without touching the source objects, as one `meshio.TriangleMesh` in world units.
Out: Blender mesh objects for a set of nodes (Materialize), in a collection of their own.
"""
from __future__ import annotations

import bpy
import numpy as np

from ..hlod_core import meshio
from ..hlod_core.hierarchy import node_mesh
from ..hlod_core.errors import InputError


def source_objects(context, props) -> list:
    if props.source == "COLLECTION":
        if props.collection is None:
            raise InputError("Bake: choose a collection (Source: Collection)")
        objects = list(props.collection.all_objects)
        where = f"collection {props.collection.name!r}"
    else:
        objects = list(context.selected_objects)
        where = "the selection"
    if not objects:
        raise InputError(f"Bake: {where} has no objects")
    return objects


def recorded_objects(context, props) -> tuple[list, list[str]]:
    """The objects the scene's record names (the last bake's sources, addon/source_record.py) that
    the scene still has, and the names it has no object for (renamed or deleted since)."""
    names = [item.name for item in props.source_objects]
    if not names:
        raise InputError("Re-bake: the scene has no record of the objects a bake took; bake them first")
    found = [context.scene.objects.get(name) for name in names]
    missing = [name for name, obj in zip(names, found) if obj is None]
    objects = [obj for obj in found if obj is not None]
    if not objects:
        raise InputError(f"Re-bake: none of the {len(names)} recorded objects is in the scene any more "
                         "(renamed or deleted); choose the sources and Bake")
    return objects, missing


def evaluated_mesh(context, objects, *, taken: list | None = None) -> meshio.TriangleMesh:
    """Triangles of every object in `objects` and of every instance they make, world space.
    taken: if given, receives the objects of `objects` that gave triangles, in `objects`' order."""
    depsgraph = context.evaluated_depsgraph_get()
    wanted = {o.name_full for o in objects}
    parts, names, owners = [], [], set()
    for inst in depsgraph.object_instances:
        owner = inst.parent.original if inst.is_instance and inst.parent is not None else inst.object.original
        if owner.name_full not in wanted:
            continue
        obj = inst.object
        if obj.type not in {"MESH", "CURVE", "SURFACE", "FONT", "META"}:
            continue
        mesh = obj.to_mesh(preserve_all_data_layers=False, depsgraph=depsgraph)
        try:
            if mesh is None or len(mesh.loop_triangles) == 0 and not _triangulate(mesh):
                continue
            count = len(mesh.vertices)
            positions = np.empty(count * 3, np.float64)
            mesh.vertices.foreach_get("co", positions)
            faces = np.empty(len(mesh.loop_triangles) * 3, np.int64)
            mesh.loop_triangles.foreach_get("vertices", faces)
        finally:
            obj.to_mesh_clear()
        matrix = np.array(inst.matrix_world, np.float64)
        positions = positions.reshape(-1, 3) @ matrix[:3, :3].T + matrix[:3, 3]
        faces = faces.reshape(-1, 3)
        if np.linalg.det(matrix[:3, :3]) < 0:
            faces = faces[:, ::-1]  # a mirroring transform keeps faces facing out
        label = f"{owner.name}" + (f" (instance of {obj.original.name})" if inst.is_instance else "")
        parts.append(meshio.from_arrays(positions, faces, name=label))
        names.append(label)
        owners.add(owner.name_full)
    if not parts:
        raise InputError("Bake: the chosen objects have no triangles (meshes, curves or text with faces)")
    if taken is not None:
        taken.extend(o for o in objects if o.name_full in owners)
    return meshio.merge(parts, name=", ".join(names[:3]) + (" ..." if len(names) > 3 else ""))


def _triangulate(mesh) -> bool:
    mesh.calc_loop_triangles()
    return len(mesh.loop_triangles) > 0


def materialize(hlod, nodes, name: str) -> bpy.types.Collection:
    """One mesh object per node, world positions (file origin added back), in a new collection
    linked to the scene. Returns the collection."""
    collection = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(collection)
    for node in nodes:
        node = int(node)
        local, faces, _ = node_mesh(hlod, node)
        positions = local.astype(np.float64) + hlod.origin
        mesh = bpy.data.meshes.new(f"{name} node {node}")
        mesh.vertices.add(positions.shape[0])
        mesh.vertices.foreach_set("co", positions.astype(np.float32).ravel())
        mesh.loops.add(faces.size)
        mesh.loops.foreach_set("vertex_index", faces.ravel().astype(np.int32))
        mesh.polygons.add(faces.shape[0])
        mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
        mesh.update()
        mesh.validate()
        obj = bpy.data.objects.new(f"{name} node {node}", mesh)
        obj["hlod_node"] = node
        obj["hlod_depth"] = int(hlod.depth[node])
        collection.objects.link(obj)
    return collection


def nodes_at_depth(hlod, depth: int) -> np.ndarray:
    """The cut at `depth`: nodes at that level, plus leaves above it."""
    level = np.asarray(hlod.depth)
    return np.flatnonzero((level == depth) | ((hlod.child_count == 0) & (level < depth)))
