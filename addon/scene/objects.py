"""Which objects and instances a bake from Blender takes, and what it leaves out (docs/user-guide.md#what-a-bake-takes).

The objects: those the Source setting names (`source_objects`), or those the scene's record of the
last bake names (`recorded_objects`, Re-bake).

Blender draws a scene's triangles from the evaluated depsgraph's instances of type MESH: a mesh
object's own geometry, and the evaluated mesh of a curve, text, surface or metaball (an instance
whose parent is that object), of collection instances and of geometry-nodes instances. The
curve-like object's own entry (type CURVE, FONT, SURFACE, META) is its curve data, which Blender
does not draw as faces: reading it too would give every such triangle twice.

What a bake leaves out it names once (`Skipped`): kinds that draw no triangles (point clouds,
volumes, grease pencil, hair curves, lights, cameras...), objects hidden in the viewport (an
object whose eye or monitor icon is off, or in an excluded or hidden collection: the depsgraph
does not evaluate them; `shown_hidden` takes them too), and objects whose geometry cannot be
baked (vertex positions that are not finite numbers).
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass, field

import bpy

from ...hlod_core.core.errors import InputError

#: Object types that draw no triangles and are named when skipped: type -> (one, many).
SKIPPED_KINDS = {
    "POINTCLOUD": ("point cloud", "point clouds"),
    "VOLUME": ("volume", "volumes"),
    "GPENCIL": ("grease pencil", "grease pencils"),  # Blender 4.2
    "GREASEPENCIL": ("grease pencil", "grease pencils"),  # Blender 4.3+
    "CURVES": ("hair curves object", "hair curves objects"),
    "LIGHT": ("light", "lights"),
    "CAMERA": ("camera", "cameras"),
    "LIGHT_PROBE": ("light probe", "light probes"),
    "SPEAKER": ("speaker", "speakers"),
}
HIDDEN = ("hidden object", "hidden objects")
NOT_FINITE = ("object with vertex positions that are not finite numbers",
              "objects with vertex positions that are not finite numbers")
#: Names listed per kind in a message; the rest are counted.
NAMES_SHOWN = 8
#: The view layer `shown_hidden` adds while it reads (removed after).
TEMPORARY_VIEW_LAYER = "HLOD bake: hidden objects shown"


# --- the objects ------------------------------------------------------------------------------------

def source_objects(context, props) -> list:
    """The objects the Source setting names (`props`: scene.hlod): the selected objects, or every
    object of the chosen collection with its children collections. InputError when there are none."""
    if props.source == "COLLECTION":
        if props.collection is None:
            raise InputError("Bake: choose a collection (Source: Collection)")
        objects = list(props.collection.all_objects)
        where = f"collection {props.collection.name!r}"
    else:
        # a timer's context (the panel's count, addon/bake/plan.py) has the view layer, not selected_objects
        selected = (context.selected_objects if hasattr(context, "selected_objects")
                    else context.view_layer.objects.selected)
        objects = list(selected)
        where = "the selection"
    if not objects:
        raise InputError(f"Bake: {where} has no objects")
    return objects


def recorded_objects(context, props) -> tuple[list, list[str]]:
    """The objects the scene's record names (the last bake's sources, addon/scene/source_record.py) that
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


@dataclass
class Skipped:
    """What a bake left out: kind (one, many) -> object names, in the order met, each once."""

    kinds: dict[tuple[str, str], list[str]] = field(default_factory=dict)

    def add(self, kind: tuple[str, str], name: str) -> None:
        names = self.kinds.setdefault(kind, [])
        if name not in names:
            names.append(name)

    def __bool__(self) -> bool:
        return any(self.kinds.values())

    def as_dict(self) -> dict[str, list[str]]:
        """{"point clouds": ["Points", ...], ...} for a JSON summary."""
        return {many: list(names) for (_, many), names in self.kinds.items() if names}

    def text(self) -> str:
        """One line: "skipped 2 point clouds: Points, Cloud; 1 light: Sun" ("" when nothing)."""
        parts = []
        for (one, many), names in self.kinds.items():
            if not names:
                continue
            shown = ", ".join(names[:NAMES_SHOWN]) + (f" and {len(names) - NAMES_SHOWN} more"
                                                      if len(names) > NAMES_SHOWN else "")
            parts.append(f"{len(names)} {one if len(names) == 1 else many}: {shown}")
        return "skipped " + "; ".join(parts) if parts else ""


# --- the depsgraph that evaluates them ------------------------------------------------------------

@contextlib.contextmanager
def evaluated(context, objects, skipped: Skipped, *, include_hidden: bool = False):
    """The depsgraph a bake of `objects` reads, for the block: the view layer's, with the objects
    it does not evaluate (hidden) added to `skipped`; with include_hidden, one that evaluates the
    hidden objects too (`shown_hidden`)."""
    if include_hidden:
        with shown_hidden(context) as depsgraph:
            yield depsgraph
        return
    depsgraph = context.evaluated_depsgraph_get()
    note_hidden(objects, depsgraph, skipped)
    yield depsgraph


def note_hidden(objects, depsgraph, skipped: Skipped) -> None:
    """Add to `skipped` the objects of `objects` the depsgraph does not evaluate (hidden in the
    viewport, disabled, or in an excluded or hidden collection) that would give triangles if shown:
    meshes, curves, text, surfaces and metaballs, and empties that instance a collection."""
    evaluated = {obj.original.name_full for obj in depsgraph.objects}
    for obj in objects:
        if obj.name_full in evaluated:
            continue
        if obj.type in {"MESH", "CURVE", "SURFACE", "FONT", "META"} or (
                obj.type == "EMPTY" and obj.instance_type == "COLLECTION" and obj.instance_collection is not None):
            skipped.add(HIDDEN, obj.name)


@contextlib.contextmanager
def shown_hidden(context):
    """A depsgraph in which every object of the scene is evaluated, hidden ones too: a temporary view
    layer (every collection included and shown, no object hidden in it), with the objects' and
    collections' Disable in Viewports switched off while it is read. Everything is put back as it
    was when the block ends, whatever ends it."""
    scene = context.scene
    layer = scene.view_layers.new(TEMPORARY_VIEW_LAYER)
    switched = [item for item in (*scene.objects, *bpy.data.collections) if item.hide_viewport]
    try:
        for item in switched:
            item.hide_viewport = False
        layer.update()  # makes and evaluates the layer's depsgraph
        yield layer.depsgraph
    finally:
        for item in switched:
            item.hide_viewport = True
        scene.view_layers.remove(layer)


# --- the instances they make -----------------------------------------------------------------------

def owner(inst):
    """The chosen object an instance belongs to: its instancer, else itself."""
    return inst.parent.original if inst.is_instance and inst.parent is not None else inst.object.original


def drawn_instances(depsgraph, wanted: set, skipped: Skipped | None = None):
    """The depsgraph's MESH instances of the objects named in `wanted` (name_full), each valid only
    until the next one is taken (module notes). Instances of a skipped kind are added to `skipped`
    under their chosen object's name."""
    for inst in depsgraph.object_instances:
        kind = inst.object.type
        if kind != "MESH" and kind not in SKIPPED_KINDS:
            continue
        chosen = owner(inst)
        if chosen.name_full not in wanted:
            continue
        if kind == "MESH":
            yield inst
        elif skipped is not None:
            skipped.add(SKIPPED_KINDS[kind], chosen.name)


def have_materials(depsgraph, wanted: set) -> bool:
    """Whether any MESH instance of the objects named in `wanted` has a material in a slot."""
    return any(slot.material is not None for inst in drawn_instances(depsgraph, wanted)
               for slot in inst.object.material_slots)


def instance_key(inst) -> tuple:
    """Where an instance goes in the bake's input: by its chosen object's name, then the
    instanced object's name and the instance's place in its instancer (persistent_id). The
    depsgraph lists instances in the view layer's order, which linking an object again or moving
    it to another collection changes; this order does not, so neither do the triangles' order and
    the bake cache's keys ([re-bakes](docs/how-it-works.md#re-bakes-and-the-cache-keys))."""
    return (owner(inst).name_full, inst.object.original.name_full,
            tuple(inst.persistent_id) if inst.is_instance else ())


# --- the count before a bake ------------------------------------------------------------------------

def planned_count(depsgraph, objects, skipped: Skipped | None = None) -> tuple[int, int]:
    """(objects that give triangles, triangles) a bake of `objects` would take: the same instances
    as the bake, each polygon of n corners n - 2 triangles (as Blender's loop triangles), read
    without copying a mesh. skipped: if given, receives the kinds the bake would skip."""
    wanted = {o.name_full for o in objects}
    givers, triangles = set(), 0
    for inst in drawn_instances(depsgraph, wanted, skipped):
        mesh = inst.object.data
        count = len(mesh.loops) - 2 * len(mesh.polygons)
        if count > 0:
            triangles += count
            givers.add(owner(inst).name_full)
    return len(givers), triangles
