"""Base colours that cannot be read from a node tree (node_tree's `unreadable`: a procedural
texture, two images, a node the reader does not know), baked by Cycles into a texture per material:
a copy of one mesh object using it (with a UV map, the most faces of the material) in a temporary
scene, with a copy of the material whose base colour socket feeds an Emission shader, baked as the
EMIT pass over its active render UV map. The artist's scene is never touched and the temporaries
are removed whatever happens. The pixels become a written texture (textures.written_texture,
moved beside the .hlod by place_textures) and the row gets it with a white base colour; a material
no object with a UV map uses keeps its Base Color value, with a warning.
Why: docs/how-it-works.md#base-colours-baked-by-cycles

Data form: in and out, a meshes.TriangleMesh whose `materials` rows are replaced by name;
pixels (BAKE_SIDE_PX, BAKE_SIDE_PX, 4) float32 linear RGBA, bottom row first.
"""
from __future__ import annotations

import contextlib
import dataclasses
import logging

import bpy
import numpy as np

from ...hlod_core.io import meshes
from .node_tree import read_base_colour, surface_shader
from .textures import texture_image_name, written_texture

log = logging.getLogger(__name__)

#: Side of the baked texture, px: enough for a procedural's features on most objects, a PNG of a
#: few hundred KiB.
BAKE_SIDE_PX = 512
#: Cycles samples per texel: a small box filter over each texel (anti-aliased procedural detail).
BAKE_SAMPLES = 4
#: Texels the bake extends each UV island by, so filtered lookups at island edges stay in colour.
BAKE_MARGIN_PX = 8


def bake_unreadable_materials(context, mesh: meshes.TriangleMesh) -> tuple[meshes.TriangleMesh, list[str]]:
    """(the mesh with each unreadable material's row given its Cycles-baked texture and a white
    base colour, the names of the materials baked so, sorted). Materials that cannot be baked
    keep their row, with a warning naming the material and why."""
    by_name = {m.name_full: m for m in bpy.data.materials}
    rows, baked = list(mesh.materials), []
    for k, row in enumerate(rows):
        material = by_name.get(row.name)
        reading = read_base_colour(material) if material is not None and material.node_tree is not None else None
        if reading is None or not reading.unreadable:
            continue
        texture = _baked_texture(context, material, reading.unreadable)
        if texture is not None:
            rows[k] = dataclasses.replace(row, base_color=(1.0, 1.0, 1.0, 1.0), texture=texture,
                                          image=texture_image_name(material))
            baked.append(material.name_full)
    if not baked:
        return mesh, []
    log.info("HLOD bake: %s", cycles_report(baked))
    return dataclasses.replace(mesh, materials=tuple(rows)), sorted(baked)


def cycles_report(names: list[str]) -> str:
    """The report's line naming the materials baked with Cycles."""
    if len(names) == 1:
        return f"baked 1 material with Cycles (its node tree cannot be read): {names[0]}"
    return f"baked {len(names)} materials with Cycles (their node trees cannot be read): {', '.join(names)}"


def _baked_texture(context, material, why: str) -> str | None:
    """The written texture file of the material's baked base colour; None (with a warning) when no
    object with a UV map uses it or Cycles cannot bake it."""
    obj = bake_object(material)
    if obj is None:
        log.warning("HLOD bake: material %r: its node tree cannot be read (%s) and no mesh object using it has a "
                    "UV map to bake its colour over; baked with the Base Color value", material.name_full, why)
        return None
    if not hasattr(context.scene, "cycles"):
        log.warning("HLOD bake: material %r: its node tree cannot be read (%s) and Cycles, which would bake it, "
                    "is not enabled; baked with the Base Color value", material.name_full, why)
        return None
    try:
        pixels = bake_base_colour(context, obj, material)
    except RuntimeError as exc:  # the bake refused (Blender's message)
        log.warning("HLOD bake: material %r: its node tree cannot be read (%s) and Cycles could not bake it on "
                    "object %r: %s; baked with the Base Color value", material.name_full, why, obj.name,
                    " ".join(str(exc).split()))
        return None
    return written_texture(pixels)


def bake_object(material):
    """The mesh object whose base colour bake stands for the material: of the mesh objects with a
    UV map that use it, the one with the most faces in its slots (then the first by name); None
    when there is none."""
    best, best_key = None, None
    for obj in bpy.data.objects:
        if obj.type != "MESH" or not obj.data.uv_layers:
            continue
        slots = [k for k, slot in enumerate(obj.material_slots) if slot.material == material]
        if not slots:
            continue
        index = np.empty(len(obj.data.polygons), np.int32)
        obj.data.polygons.foreach_get("material_index", index)
        faces = int(np.isin(np.clip(index, 0, len(obj.material_slots) - 1), slots).sum())
        key = (-faces, obj.name_full)
        if faces > 0 and (best_key is None or key < best_key):
            best, best_key = obj, key
    return best


def bake_base_colour(context, obj, material) -> np.ndarray:
    """(BAKE_SIDE_PX, BAKE_SIDE_PX, 4) float32 linear RGBA (alpha 1, bottom row first): the colour
    reaching the material's base colour socket on `obj`, baked by Cycles (EMIT) over its active render
    UV map, in a temporary scene (module notes). RuntimeError when Cycles refuses."""
    uv_map = next((layer.name for layer in obj.data.uv_layers if layer.active_render), obj.data.uv_layers[0].name)
    with contextlib.ExitStack() as undo:
        scene, copy, target = _bake_scene(context, obj, material, undo)
        with context.temp_override(scene=scene, view_layer=scene.view_layers[0], active_object=copy, object=copy,
                                   selected_objects=[copy], selected_editable_objects=[copy]):
            bpy.ops.object.bake(type="EMIT", margin=BAKE_MARGIN_PX, use_clear=True, uv_layer=uv_map,
                                target="IMAGE_TEXTURES", save_mode="INTERNAL", use_selected_to_active=False,
                                use_cage=False)
        pixels = np.empty(BAKE_SIDE_PX * BAKE_SIDE_PX * 4, np.float32)
        target.pixels.foreach_get(pixels)
    pixels = pixels.reshape(BAKE_SIDE_PX, BAKE_SIDE_PX, 4)
    pixels[..., 3] = 1.0
    return pixels


def _bake_scene(context, obj, material, undo: contextlib.ExitStack):
    """(a temporary scene set up for the bake, the object's copy in it, the target image); each
    datablock made is removed when `undo` closes."""
    scene = bpy.data.scenes.new(f"{material.name} (Cycles bake)")
    undo.callback(bpy.data.scenes.remove, scene)
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", BAKE_SAMPLES, False
    scene.frame_current = context.scene.frame_current  # animated materials and modifiers as they are now
    target = bpy.data.images.new(f"{material.name} (Cycles bake)", BAKE_SIDE_PX, BAKE_SIDE_PX, alpha=False,
                                 float_buffer=True)
    undo.callback(bpy.data.images.remove, target)
    copy_material = material.copy()
    undo.callback(bpy.data.materials.remove, copy_material)
    _emission_surface(copy_material, target)
    copy = obj.copy()
    undo.callback(bpy.data.objects.remove, copy)
    scene.collection.objects.link(copy)
    copy.hide_viewport = copy.hide_render = False
    for slot in copy.material_slots:
        used = slot.material == material
        slot.link = "OBJECT"
        slot.material = copy_material if used else None
    layer = scene.view_layers[0]
    copy.select_set(True, view_layer=layer)
    layer.objects.active = copy
    return scene, copy, target


def _emission_surface(material, target) -> None:
    """In `material` (a temporary copy): the base colour socket's input (or its value) into an
    Emission shader as the surface, and an Image Texture node of `target`, active (where the bake
    writes)."""
    tree = material.node_tree
    node, emissive = surface_shader(material)
    socket = node.inputs["Color" if emissive else "Base Color"]
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    link = socket.links[0] if socket.is_linked else None
    if link is not None and not link.is_muted:
        tree.links.new(link.from_socket, emission.inputs["Color"])
    else:
        emission.inputs["Color"].default_value = socket.default_value
    output = tree.get_output_node("CYCLES")
    if output is None:
        output = tree.nodes.new("ShaderNodeOutputMaterial")
        output.is_active_output = True
    tree.links.new(emission.outputs["Emission"], output.inputs["Surface"])
    holder = tree.nodes.new("ShaderNodeTexImage")
    holder.image = target
    tree.nodes.active = holder
