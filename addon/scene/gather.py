"""The one pass that gathers a bake's input from the artist's scene (docs/user-guide.md#what-a-bake-takes):
the evaluated triangles of the chosen objects (modifiers applied, instances from collection
instances, particles and geometry nodes realised, world transforms), read through the depsgraph
without touching the objects, as one `meshes.TriangleMesh` in world units with its appearance.

`gather` reads top to bottom, one step after another, each step's details in its own module:
1. objects: the depsgraph that evaluates the chosen objects, noting the hidden ones it leaves out
   (objects.evaluated);
2. instances: the MESH instances they make, each kind without triangles noted
   (objects.drawn_instances), in an order the view layer's order does not change (objects.instance_key);
3. parts: each instance's triangles, corner attributes and material rows (parts.PartReader);
4. surfaces: the colours no node tree reading gives, baked by Cycles on each object that draws them
   (surface_bakes.SurfaceBakes; nothing is copied or baked in a scene without such surfaces);
5. one mesh: the parts merged (meshes.merge), the material table sorted by name, and the names of
   the UV map and colour attribute carried, for the bake's meta.
A selection with no material has no UVs either (nothing it draws uses them); one with no material,
UV map or colour attribute gives a mesh without appearance. The way out, Blender objects for a set
of nodes, is addon/scene/node_objects.py.
"""
from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ...hlod_core.core.errors import InputError
from ...hlod_core.io import meshes
from ..materials.cycles_bake import CyclesBake
from .objects import NOT_FINITE, Skipped, drawn_instances, evaluated, have_materials, instance_key, owner
from .parts import Part, PartReader, part_mesh
from .surface_bakes import SurfaceBakes

#: Part names joined into the mesh's name; the rest are "...".
NAMES_IN_MESH_NAME = 3


@dataclass
class Gathered:
    """What a bake of the chosen objects takes. mesh: their triangles, world units, with
    appearance; taken: the chosen objects that gave triangles, in the order chosen; skipped: what
    was left out and why; attributes: the names of the UV map and the colour attribute carried
    ({"uv_map": ..., "color_attribute": ...}, each only when carried: the most used name when the
    objects name them differently), for the bake's meta; cycles_bakes: the Cycles bakes of colours
    no node tree reading gives, one per object, in order."""

    mesh: meshes.TriangleMesh
    taken: list
    skipped: Skipped
    attributes: dict[str, str] = field(default_factory=dict)
    cycles_bakes: list[CyclesBake] = field(default_factory=list)

    @property
    def cycles_baked(self) -> list[str]:
        """The names of the materials Cycles baked, sorted."""
        return sorted({name for bake in self.cycles_bakes for name in bake.materials})


def gather(context, objects, *, include_hidden: bool = False) -> Gathered:
    """The triangles of every object in `objects` and of every instance they make, each triangle
    Blender draws, with their appearance (module notes). include_hidden: take objects hidden in
    the viewport too. InputError when nothing gives triangles, or Blender gives no mesh for one."""
    skipped = Skipped()
    surfaces = SurfaceBakes()
    try:
        keyed, owners, reader = _parts(context, objects, skipped, surfaces, include_hidden=include_hidden)
        if not keyed:
            left_out = f" ({skipped.text()})" if skipped else ""
            raise InputError("Bake: the chosen objects have no triangles (meshes, curves or text with faces)"
                             f"{left_out}")
        keyed.sort(key=lambda item: item[0])
        parts = [part for _, part in keyed]
        cycles_bakes = surfaces.bake_into(context, parts)  # 4. surfaces
    finally:
        surfaces.release()
    return Gathered(mesh=one_mesh(parts), taken=[o for o in objects if o.name_full in owners], skipped=skipped,
                    attributes=_most_used(uv_map=reader.uv_names, color_attribute=reader.colour_names),
                    cycles_bakes=cycles_bakes)


def _parts(context, objects, skipped: Skipped, surfaces: SurfaceBakes, *, include_hidden: bool):
    """1.-3.: ([(instance key, part)], the names of the chosen objects that gave triangles, the reader)."""
    wanted = {o.name_full for o in objects}
    keyed: list[tuple[tuple, Part]] = []
    owners: set[str] = set()
    with evaluated(context, objects, skipped, include_hidden=include_hidden) as depsgraph:  # 1. objects
        reader = PartReader(read_uvs=have_materials(depsgraph, wanted), surfaces=surfaces)
        for inst in drawn_instances(depsgraph, wanted, skipped):  # 2. instances
            chosen = owner(inst)
            label = chosen.name + (f" (instance of {inst.object.original.name})" if inst.is_instance else "")
            try:
                part = reader.read(inst, depsgraph, label)  # 3. parts
            except RuntimeError as exc:  # Blender could not give the object's mesh
                raise InputError(f"Bake: object {chosen.name!r}: Blender gives no mesh for it: {exc}") from exc
            if part is None:
                continue
            if not np.isfinite(part.positions).all():
                skipped.add(NOT_FINITE, chosen.name)
                continue
            keyed.append((instance_key(inst), part))
            owners.add(chosen.name_full)
    return keyed, owners, reader


def one_mesh(parts: list[Part]) -> meshes.TriangleMesh:
    """5. The parts, in their order, as one mesh whose material table is sorted by name."""
    names = [part.label for part in parts]
    name = ", ".join(names[:NAMES_IN_MESH_NAME]) + (" ..." if len(names) > NAMES_IN_MESH_NAME else "")
    return _materials_by_name(meshes.merge([part_mesh(part) for part in parts], name=name))


def _most_used(**counted: Counter) -> dict[str, str]:
    """{key: its most used name} for each key whose Counter counted any."""
    return {key: names.most_common(1)[0][0] for key, names in counted.items() if names}


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
