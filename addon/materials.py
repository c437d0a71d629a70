"""Blender material datablocks and the core's material table (model.appearance.Material), both ways:
a row from a material's Principled BSDF (or its viewport values), and a material for a row
(the source's datablock by name where it exists, else a new Principled material).

Data form: a Material row holds linear RGBA base colour, metallic, roughness, the base-colour
texture's file (`texture`, for files on disk) and image datablock name (`image`).
"""
from __future__ import annotations

import logging
import os

import bpy
import numpy as np

from ..hlod_core.model.appearance import DEFAULT_BASE_COLOR, Material

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
    """Base colour (linear RGBA), metallic, roughness and base-colour texture of a material: the
    Principled BSDF's inputs when the material uses nodes, its viewport values otherwise. An Image
    Texture node linked directly into Base Color gives `image` (the datablock's name, which the
    preview draws) and `texture` (its file, for files on disk; None for packed or generated images)
    and a white base colour (Blender ignores the socket's own value then)."""
    base, metallic, roughness = tuple(material.diffuse_color), material.metallic, material.roughness
    texture = image = None
    principled = principled_node(material)
    if principled is not None:
        base_in = principled.inputs["Base Color"]
        base = tuple(base_in.default_value)
        metallic, roughness = principled.inputs["Metallic"].default_value, principled.inputs["Roughness"].default_value
        source = base_in.links[0].from_node if base_in.is_linked else None
        if source is not None and source.type == "TEX_IMAGE" and source.image is not None:
            base, image, texture = (1.0, 1.0, 1.0, 1.0), source.image.name, _image_file(source.image, material)
    return Material(name=material.name_full, base_color=tuple(float(np.clip(c, 0.0, 1.0)) for c in base),
                    metallic=float(np.clip(metallic, 0.0, 1.0)), roughness=float(np.clip(roughness, 0.0, 1.0)),
                    texture=texture, image=image)


def _uses_nodes(material) -> bool:
    """Blender 5 always draws a material's node tree (use_nodes is deprecated there)."""
    return material.node_tree is not None and (bpy.app.version >= (5, 0, 0) or material.use_nodes)


def principled_node(material):
    """The Principled BSDF feeding the active output's Surface, else the tree's first one, else None."""
    if not _uses_nodes(material):
        return None
    output = material.node_tree.get_output_node("ALL")
    surface = output.inputs["Surface"] if output is not None else None
    if surface is not None and surface.is_linked and surface.links[0].from_node.type == "BSDF_PRINCIPLED":
        return surface.links[0].from_node
    return next((node for node in material.node_tree.nodes if node.type == "BSDF_PRINCIPLED"), None)


def _image_file(image, material) -> str | None:
    """The image's file on disk, absolute; None (with a warning) when it has none there."""
    if image.source == "FILE" and image.packed_file is None:
        path = os.path.normpath(bpy.path.abspath(image.filepath, library=image.library))
        if os.path.isfile(path):
            return path
        why = f"its file {path} does not exist"
    else:
        why = ("it is packed into the .blend" if image.packed_file is not None
               else f"it is a {image.source.lower()} image")
    log.warning("HLOD bake: material %r: image %r has no file on disk (%s); the preview draws it, the "
                ".hlod file refers to no texture for it", material.name_full, image.name, why)
    return None


def material_from_row(row: Material):
    """The source's material datablock of that name, else a new Principled material from the row
    (with an Image Texture node into Base Color when the row's image or texture file exists)."""
    material = bpy.data.materials.get(row.name)
    if material is not None:
        return material
    material = bpy.data.materials.new(row.name)
    material.diffuse_color, material.metallic, material.roughness = row.base_color, row.metallic, row.roughness
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
    if image is not None:
        node = material.node_tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        node.location = (principled.location.x - TEXTURE_NODE_OFFSET_X, principled.location.y)
        material.node_tree.links.new(node.outputs["Color"], principled.inputs["Base Color"])
    return material
