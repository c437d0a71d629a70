"""Blender material datablocks and the core's material table (model.appearance.Material), both ways:
a row from a material's Principled BSDF (or its viewport values), and a material for a row
(the source's datablock by name where it exists, else a new Principled material, its image's alpha
cut out or blended as the row's alpha mode says).

Data form: a Material row holds linear RGBA base colour, metallic, roughness, the base-colour
texture's file (`texture`) and the image datablock name the preview draws (`image`), and glTF's
alpha mode.
"""
from __future__ import annotations

import logging
import os

import bpy
import numpy as np

from ...hlod_core.model.appearance import DEFAULT_BASE_COLOR, Material
from .node_tree import read_base_colour, surface_shader
from .textures import base_colour_texture

log = logging.getLogger(__name__)

#: The material row of a triangle whose slot is empty or whose object has no material (meshes.merge's).
DEFAULT_MATERIAL = Material("default", DEFAULT_BASE_COLOR)
#: How far left of the Principled BSDF a new Image Texture node goes, in node-editor units.
TEXTURE_NODE_OFFSET_X = 300.0


def cached_material_row(material, rows: dict) -> Material:
    """The table row of a material datablock (evaluated or original), made once per datablock:
    `rows` maps name_full -> row and is filled here."""
    material = material.original
    row = rows.get(material.name_full)
    if row is None:
        row = rows[material.name_full] = material_row(material)
    return row


def material_row(material) -> Material:
    """Base colour (linear RGBA), metallic, roughness, base-colour texture and alpha mode of a
    material: its node tree's surface as the viewport draws it (node_tree) when the material
    uses nodes, its viewport values otherwise. An image used as it is (a file on disk, sRGB, no
    colour node on the way) gives its own file; an image processed by colour nodes, packed or
    generated gives a PNG of the processed pixels (textures.base_colour_texture). Either way
    `image` names what the preview draws and the base colour is white. A tree that cannot be read
    gives the Base Color value here (metallic 0 for a surface without one Principled BSDF, whose
    albedo Cycles bakes); gathering the scene replaces it with Cycles' bake on each object that
    uses it (scene/surface_bakes.py)."""
    base, metallic, roughness = tuple(material.diffuse_color), material.metallic, material.roughness
    texture = image = None
    alpha_mode, alpha_cutoff = "OPAQUE", 0.5
    principled = principled_node(material)
    if principled is not None:
        base = tuple(principled.inputs["Base Color"].default_value)
        metallic, roughness = principled.inputs["Metallic"].default_value, principled.inputs["Roughness"].default_value
    reading = read_base_colour(material) if uses_nodes(material) else None
    if reading is not None and reading.unreadable:
        log.info("HLOD bake: material %r: its base colour cannot be read from its nodes (%s); Cycles bakes it "
                 "on the objects that use it", material.name_full, reading.unreadable)
        if reading.whole_surface:  # the baked albedo is the colour drawn; nothing metallic stays
            metallic = 0.0
    elif reading is not None and reading.source is None:
        base = reading.constant
        alpha_mode = "OPAQUE" if base[3] >= 1.0 else "BLEND"
    elif reading is not None and reading.source.kind == "image":
        found = base_colour_texture(material, reading)
        if found is not None:
            base, (texture, image, alpha_mode, alpha_cutoff) = (1.0, 1.0, 1.0, 1.0), found
    elif reading is not None:  # a colour attribute: the vertex colours carry it (scene/parts.py)
        base = (1.0, 1.0, 1.0, 1.0)
    if reading is not None and reading.emissive:
        metallic, roughness = 0.0, 1.0
    return Material(name=material.name_full, base_color=tuple(float(np.clip(c, 0.0, 1.0)) for c in base),
                    metallic=float(np.clip(metallic, 0.0, 1.0)), roughness=float(np.clip(roughness, 0.0, 1.0)),
                    texture=texture, image=image, alpha_mode=alpha_mode, alpha_cutoff=float(alpha_cutoff),
                    double_sided=not material.use_backface_culling)


def uses_nodes(material) -> bool:
    """Blender 5 always draws a material's node tree (use_nodes is deprecated there)."""
    return material.node_tree is not None and (bpy.app.version >= (5, 0, 0) or material.use_nodes)


def principled_node(material):
    """The Principled BSDF the active output's Surface draws (through Mix/Add Shader nodes), else the
    tree's first one, else None."""
    if not uses_nodes(material):
        return None
    node, emissive = surface_shader(material)
    if node is not None and not emissive:
        return node
    return next((node for node in material.node_tree.nodes if node.type == "BSDF_PRINCIPLED"), None)


def material_from_row(row: Material):
    """The source's material datablock of that name, else a new Principled material from the row
    (with an Image Texture node into Base Color when the row's image or texture file exists, and its
    alpha into Alpha for a MASK or BLEND row), Backface Culling on for a one-sided row."""
    material = bpy.data.materials.get(row.name)
    if material is not None:
        return material
    material = bpy.data.materials.new(row.name)
    material.diffuse_color, material.metallic, material.roughness = row.base_color, row.metallic, row.roughness
    material.use_backface_culling = not row.double_sided
    if material.node_tree is None:  # Blender 4: a new material has no nodes until asked
        material.use_nodes = True
    principled = principled_node(material)
    if principled is None:
        return material
    principled.inputs["Base Color"].default_value = row.base_color
    principled.inputs["Metallic"].default_value = row.metallic
    principled.inputs["Roughness"].default_value = row.roughness
    image = bpy.data.images.get(row.image) if row.image else None
    if image is None and row.texture and os.path.isfile(row.texture):
        image = bpy.data.images.load(row.texture, check_existing=True)
    principled.inputs["Alpha"].default_value = row.base_color[3]
    if image is not None:
        node = material.node_tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        node.location = (principled.location.x - TEXTURE_NODE_OFFSET_X, principled.location.y)
        material.node_tree.links.new(node.outputs["Color"], principled.inputs["Base Color"])
        if row.alpha_mode != "OPAQUE":
            _link_alpha(material, node, principled, row)
    if row.alpha_mode == "BLEND" and hasattr(material, "surface_render_method"):
        material.surface_render_method = "BLENDED"
    return material


def _link_alpha(material, image_node, principled, row: Material) -> None:
    """The image's alpha into the Principled BSDF's Alpha: through alpha > cutoff for MASK (glTF's
    cut-out, as the add-on reads a clipped alpha back), as it is for BLEND."""
    alpha = image_node.outputs["Alpha"]
    if row.alpha_mode == "MASK":
        step = material.node_tree.nodes.new("ShaderNodeMath")
        step.operation = "GREATER_THAN"
        step.inputs[1].default_value = row.alpha_cutoff
        step.location = (principled.location.x - TEXTURE_NODE_OFFSET_X / 2, principled.location.y - 300.0)
        material.node_tree.links.new(alpha, step.inputs[0])
        alpha = step.outputs[0]
    material.node_tree.links.new(alpha, principled.inputs["Alpha"])
