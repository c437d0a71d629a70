"""Colours Cycles bakes where a node tree gives none to read (node_tree's `unreadable`): the
diffuse albedo of a surface without one Principled BSDF (`whole_surface`: Diffuse, Toon or Glossy
BSDFs, node groups, shader mixes), or the colour reaching a Principled BSDF's Base Color (or an
Emission shader's Color) through nodes the reader does not know (a procedural texture, two images).

One bake per object (`SurfaceBake`): a temporary object of the object's evaluated mesh in a
temporary scene, each material baked on it a copy with an active Image Texture node of its own
target image, other slots a placeholder that bakes into one pixel. The pass is Cycles' DIFFUSE bake
with only its COLOR contribution: the surface's diffuse albedo, without lighting, gloss or emission.
A Base Color socket's colour becomes a Diffuse BSDF's Color in the copy, which the same pass gives
exactly. An object without a UV map is baked into a colour attribute per face corner instead
(target VERTEX_COLORS). The artist's scene is never touched, and every temporary is removed
whatever happens.
Why: docs/how-it-works.md#base-colours-baked-by-cycles

Data form: pixels (BAKE_SIDE_PX, BAKE_SIDE_PX, 4) float32 linear RGBA (alpha 1), bottom row first;
corner colours (l, 4) float32 linear RGBA (alpha 1), one row per mesh loop (face corner).
"""
from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

import bpy
import numpy as np

from .node_tree import BaseColour, surface_shader

#: Side of a baked texture, px: enough for a procedural's features on most objects, a PNG of a few
#: hundred KiB.
BAKE_SIDE_PX = 512
#: Cycles samples per texel: a small box filter over each texel (anti-aliased procedural detail).
BAKE_SAMPLES = 4
#: Texels the bake extends each UV island by, so filtered lookups at island edges stay in colour.
BAKE_MARGIN_PX = 8
#: Cycles' bake pass and its contributions: the diffuse albedo alone.
BAKE_TYPE, BAKE_PASS_FILTER = "DIFFUSE", {"COLOR"}
#: The colour attribute an object without UV maps is baked into (on the temporary copy only).
CORNER_ATTRIBUTE = "HLOD bake"


@dataclass
class SurfaceBake:
    """One object's bake. label: the object's name (messages, the temporaries' names); mesh: a
    temporary bpy mesh of its evaluated geometry (the caller's, which removes it); matrix_world:
    (4,4) where the object is drawn (world-space textures see it there); materials: the material of
    each slot, None for an empty one; readings: slot -> node_tree.BaseColour of each slot to bake;
    uv_map: the UV map baked over, None for a colour per face corner."""

    label: str
    mesh: object
    matrix_world: object
    materials: list
    readings: dict[int, BaseColour]
    uv_map: str | None


@dataclass
class Baked:
    """What one SurfaceBake gave: slot -> pixels (with a UV map), or corner_colours (l, 4) (without);
    seconds: the bake's wall time, temporaries included."""

    textures: dict[int, np.ndarray]
    corner_colours: np.ndarray | None
    seconds: float


@dataclass(frozen=True)
class CyclesBake:
    """One object's Cycles bake as the bake reports it: the object's name, the materials baked on
    it (sorted), where their colours went ("texture" or "corner colours") and the seconds it took."""

    label: str
    materials: tuple[str, ...]
    target: str
    seconds: float

    def as_dict(self) -> dict:
        return {"object": self.label, "materials": list(self.materials), "target": self.target,
                "seconds": round(self.seconds, 3)}


def cycles_report(bakes: list[CyclesBake]) -> str:
    """The report's one line naming the materials Cycles baked, with how many objects and how long."""
    names = sorted({name for bake in bakes for name in bake.materials})
    seconds, objects = sum(bake.seconds for bake in bakes), len(bakes)
    on = f"on {objects} object{'s' if objects != 1 else ''} in {seconds:.1f} s"
    if len(names) == 1:
        return f"baked 1 material with Cycles (its node tree cannot be read) {on}: {names[0]}"
    return f"baked {len(names)} materials with Cycles (their node trees cannot be read) {on}: {', '.join(names)}"


def cycles_enabled(context) -> bool:
    """Whether Cycles is there to bake (it is an add-on that can be disabled)."""
    return hasattr(context.scene, "cycles")


def bake_surface(context, job: SurfaceBake) -> Baked:
    """Cycles' bake of the job's slots (module notes). RuntimeError (Blender's message) when
    Cycles refuses."""
    started = time.perf_counter()
    with contextlib.ExitStack() as undo:
        scene = _bake_scene(context, job.label, undo)
        obj = bpy.data.objects.new(f"{job.label} (Cycles bake)", job.mesh)
        undo.callback(bpy.data.objects.remove, obj)
        scene.collection.objects.link(obj)
        obj.matrix_world = job.matrix_world
        targets = _bake_materials(job, undo)
        layer = scene.view_layers[0]
        obj.select_set(True, view_layer=layer)
        layer.objects.active = obj
        with context.temp_override(scene=scene, view_layer=layer, active_object=obj, object=obj,
                                   selected_objects=[obj], selected_editable_objects=[obj]):
            if job.uv_map is None:
                colours = _corner_colours_baked(job.mesh)
            else:
                bpy.ops.object.bake(type=BAKE_TYPE, pass_filter=BAKE_PASS_FILTER, margin=BAKE_MARGIN_PX,
                                    use_clear=True, uv_layer=job.uv_map, target="IMAGE_TEXTURES",
                                    save_mode="INTERNAL", use_selected_to_active=False, use_cage=False)
        textures = {slot: _pixels(image) for slot, image in targets.items()}
    if job.uv_map is None:
        return Baked(textures={}, corner_colours=colours, seconds=time.perf_counter() - started)
    return Baked(textures=textures, corner_colours=None, seconds=time.perf_counter() - started)


def _corner_colours_baked(mesh) -> np.ndarray:
    """(l, 4) the bake's colour at each face corner of `mesh` (a temporary), through a float colour
    attribute per corner made active for the bake (in the operator's context)."""
    attribute = mesh.color_attributes.new(CORNER_ATTRIBUTE, "FLOAT_COLOR", "CORNER")
    mesh.color_attributes.active_color = attribute
    bpy.ops.object.bake(type=BAKE_TYPE, pass_filter=BAKE_PASS_FILTER, target="VERTEX_COLORS",
                        use_selected_to_active=False, use_cage=False)
    attribute = mesh.color_attributes[CORNER_ATTRIBUTE]
    colours = np.empty(len(mesh.loops) * 4, np.float32)
    attribute.data.foreach_get("color", colours)
    colours = colours.reshape(-1, 4)
    colours[:, 3] = 1.0
    return colours


def _pixels(image) -> np.ndarray:
    pixels = np.empty(BAKE_SIDE_PX * BAKE_SIDE_PX * 4, np.float32)
    image.pixels.foreach_get(pixels)
    pixels = pixels.reshape(BAKE_SIDE_PX, BAKE_SIDE_PX, 4)
    pixels[..., 3] = 1.0
    return pixels


def _bake_scene(context, label: str, undo: contextlib.ExitStack):
    """A temporary scene set up for the bake (Cycles on the CPU), removed when `undo` closes."""
    scene = bpy.data.scenes.new(f"{label} (Cycles bake)")
    undo.callback(bpy.data.scenes.remove, scene)
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.use_denoising = "CPU", BAKE_SAMPLES, False
    scene.frame_current = context.scene.frame_current  # animated materials as they are now
    return scene


def _bake_materials(job: SurfaceBake, undo: contextlib.ExitStack) -> dict[int, object]:
    """The temporary mesh's slots made ready: each slot to bake a copy of its material that Cycles
    bakes into a target image of its own (with a UV map), the others a placeholder; returns slot ->
    target image (empty without a UV map). Each datablock made is removed when `undo` closes."""
    mesh, targets, placeholder = job.mesh, {}, None
    mesh.materials.clear()
    for slot, material in enumerate(job.materials):
        reading = job.readings.get(slot)
        if reading is None and job.uv_map is None:
            mesh.materials.append(material)
            continue
        if reading is None:
            if placeholder is None:
                placeholder = _placeholder(job.label, undo)
            mesh.materials.append(placeholder)
            continue
        copy = material.copy()
        undo.callback(bpy.data.materials.remove, copy)
        if not reading.whole_surface:
            _diffuse_surface(copy)
        if job.uv_map is not None:
            targets[slot] = _target(copy, f"{material.name} on {job.label}", BAKE_SIDE_PX, undo)
        mesh.materials.append(copy)
    return targets


def _target(material, name: str, side_px: int, undo: contextlib.ExitStack):
    """A float image of side_px, in an Image Texture node made the active node of `material` (a
    temporary): where Cycles bakes that material's faces."""
    image = bpy.data.images.new(f"{name} (Cycles bake)", side_px, side_px, alpha=False, float_buffer=True)
    undo.callback(bpy.data.images.remove, image)
    holder = material.node_tree.nodes.new("ShaderNodeTexImage")
    holder.image = image
    material.node_tree.nodes.active = holder
    return image


def _placeholder(label: str, undo: contextlib.ExitStack):
    """The material of slots not baked: a Diffuse BSDF baked into a 1 px image."""
    material = bpy.data.materials.new(f"{label} (not baked)")
    undo.callback(bpy.data.materials.remove, material)
    if material.node_tree is None:  # Blender 4: a new material has no nodes until asked
        material.use_nodes = True
    _target(material, f"{label} (not baked)", 1, undo)
    return material


def _diffuse_surface(material) -> None:
    """In `material` (a temporary copy): the input of its base colour socket (or its value) as the
    Color of a Diffuse BSDF that is the surface, so the DIFFUSE COLOR pass gives that colour."""
    tree = material.node_tree
    node, emissive = surface_shader(material)
    socket = node.inputs["Color" if emissive else "Base Color"]
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    link = socket.links[0] if socket.is_linked else None
    if link is not None and not link.is_muted:
        tree.links.new(link.from_socket, diffuse.inputs["Color"])
    else:
        diffuse.inputs["Color"].default_value = socket.default_value
    output = tree.get_output_node("CYCLES")
    if output is None:
        output = tree.nodes.new("ShaderNodeOutputMaterial")
        output.is_active_output = True
    tree.links.new(diffuse.outputs["BSDF"], output.inputs["Surface"])
