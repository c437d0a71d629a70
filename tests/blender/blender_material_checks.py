"""Checks of materials read from their node trees inside the real bpy module, one per subprocess
(tests/blender/test_addon_materials.py runs them):

    python tests/blender/blender_material_checks.py REPO_DIR CHECK WORK_DIR

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.

Each case is a plane with UVs over [0, 1] and a material whose Base Color is built here with bpy
from a small packed image and colour nodes. The reference is Blender's own: Cycles bakes the colour
reaching Base Color (the same upstream socket linked into an Emission shader, EMIT pass: the base
colour itself, without the diffuse lobe's layering) into a float image over the plane's UVs. The
add-on's reading (addon/materials/rows.py material_row: the row's texture file or base colour) is looked
up at the same UVs (through the UV transform it carries) and compared as PSNR in sRGB.
"""
from __future__ import annotations

import contextlib
import dataclasses
import importlib
import io
import json
import logging
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import bpy

import blender_preview
from hlod_core.core.colour import srgb_from_linear, srgb_to_linear

NAME = "bl_ext.r.hlod"
SIDE_PX = 32  # source image and bake image side
BAKE_SAMPLES = 1  # one sample: at the pixel centre (more jitter across the wrapped edge)


# --- the scene ------------------------------------------------------------------------------------

def _source_image() -> object:
    """A packed 32x32 sRGB image: smooth hue ramps with a dark corner (every channel varies)."""
    y, x = np.mgrid[0:SIDE_PX, 0:SIDE_PX] / (SIDE_PX - 1)
    rgba = np.stack([x, y, 0.5 + 0.5 * np.sin(6 * x * y), np.ones_like(x)], axis=-1).astype(np.float32)
    image = bpy.data.images.new("source", SIDE_PX, SIDE_PX, alpha=True)
    image.pixels.foreach_set(rgba.ravel())
    image.pack()
    return image


def _plane(name: str, material):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    uv = mesh.uv_layers.new(name="UVMap")
    uv.data.foreach_set("uv", [0, 0, 1, 0, 1, 1, 0, 1])
    second = mesh.uv_layers.new(name="Flipped")  # a second map: u and v swapped
    second.data.foreach_set("uv", [0, 0, 0, 1, 1, 1, 1, 0])
    mesh.uv_layers.active = uv
    uv.active_render = True
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _material(name: str):
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # Blender 4 makes a material without nodes
        material.use_nodes = True
    nodes = material.node_tree.nodes
    return material, nodes, material.node_tree.links, next(n for n in nodes if n.type == "BSDF_PRINCIPLED")


def _image_node(nodes, image):
    node = nodes.new("ShaderNodeTexImage")
    node.image = image
    return node


def _mix(nodes, mode: str, factor: float, *, legacy: bool = False):
    """(node, factor input, A input, B input, result output) of a colour Mix (or legacy MixRGB) node."""
    if legacy:
        node = nodes.new("ShaderNodeMixRGB")
        node.blend_type = mode
        node.inputs["Fac"].default_value = factor
        return node, node.inputs["Color1"], node.inputs["Color2"], node.outputs["Color"]
    node = nodes.new("ShaderNodeMix")
    node.data_type, node.blend_type = "RGBA", mode
    pick = {s.identifier: s for s in node.inputs}
    pick["Factor_Float"].default_value = factor
    return node, pick["A_Color"], pick["B_Color"], next(s for s in node.outputs if s.identifier == "Result_Color")


def _between(nodes, links, kind: str, upstream, downstream, **inputs):
    """A colour node of `kind` linked from `upstream` (an output) into `downstream` (an input)."""
    node = nodes.new(kind)
    for key, value in inputs.items():
        node.inputs[key].default_value = value
    links.new(upstream, node.inputs["Color"])
    links.new(node.outputs["Color"], downstream)
    return node


def build_case(case: str, image):
    """One material of the case `case`, on a plane of its own; returns the plane."""
    material, nodes, links, principled = _material(case)
    base = principled.inputs["Base Color"]
    tex = _image_node(nodes, image)
    if case == "direct":
        links.new(tex.outputs["Color"], base)
    elif case.startswith(("mix_", "mixrgb_")):
        legacy, mode = case.startswith("mixrgb_"), case.split("_", 1)[1].upper()
        _, a, b, out = _mix(nodes, mode, 0.7, legacy=legacy)
        links.new(tex.outputs["Color"], a)
        b.default_value = (0.9, 0.35, 0.1, 1.0)
        links.new(out, base)
    elif case == "hue_saturation":
        _between(nodes, links, "ShaderNodeHueSaturation", tex.outputs["Color"], base, Hue=0.62, Saturation=1.4,
                 Value=0.8, Fac=0.9)
    elif case == "gamma":
        _between(nodes, links, "ShaderNodeGamma", tex.outputs["Color"], base, Gamma=1.8)
    elif case == "bright_contrast":
        _between(nodes, links, "ShaderNodeBrightContrast", tex.outputs["Color"], base, Bright=0.1, Contrast=0.3)
    elif case == "invert":
        _between(nodes, links, "ShaderNodeInvert", tex.outputs["Color"], base, Fac=0.8)
    elif case == "curves":
        node = _between(nodes, links, "ShaderNodeRGBCurve", tex.outputs["Color"], base)
        node.mapping.curves[3].points[1].location = (1.0, 0.7)  # combined: a darker top
        node.mapping.curves[0].points.new(0.5, 0.8)  # red: lifted mid-tones
        node.mapping.update()
    elif case == "mapping":
        _mapping(nodes, links, tex)
        links.new(tex.outputs["Color"], base)
    elif case == "uv_map":
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = "Flipped"
        links.new(uv.outputs["UV"], tex.inputs["Vector"])
        links.new(tex.outputs["Color"], base)
    elif case == "group":
        _group(nodes, links, tex, base)
    elif case == "constant":
        nodes.remove(tex)
        _, a, b, out = _mix(nodes, "OVERLAY", 0.6)
        a.default_value, b.default_value = (0.2, 0.5, 0.7, 1.0), (0.9, 0.2, 0.3, 1.0)
        links.new(out, base)
    elif case == "unlit":  # as the glTF importer builds KHR_materials_unlit: camera rays see the emission
        nodes.remove(principled)
        emission, transparent = nodes.new("ShaderNodeEmission"), nodes.new("ShaderNodeBsdfTransparent")
        light_path, mix = nodes.new("ShaderNodeLightPath"), nodes.new("ShaderNodeMixShader")
        _, a, b, out = _mix(nodes, "MULTIPLY", 1.0)
        links.new(tex.outputs["Color"], a)
        b.default_value = (0.5, 0.9, 0.7, 1.0)
        links.new(out, emission.inputs["Color"])
        links.new(light_path.outputs["Is Camera Ray"], mix.inputs["Fac"])
        links.new(transparent.outputs[0], mix.inputs[1])
        links.new(emission.outputs[0], mix.inputs[2])
        output = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
        links.new(mix.outputs[0], output.inputs["Surface"])
    elif case == "noise":  # a procedural texture: not read
        noise = nodes.new("ShaderNodeTexNoise")
        _, a, b, out = _mix(nodes, "MULTIPLY", 1.0)
        links.new(tex.outputs["Color"], a)
        links.new(noise.outputs["Color"], b)
        links.new(out, base)
    elif case == "voronoi":  # a procedural texture alone, with sharp cell edges
        nodes.remove(tex)
        voronoi = nodes.new("ShaderNodeTexVoronoi")
        voronoi.inputs["Scale"].default_value = 4.0
        links.new(voronoi.outputs["Color"], base)
    elif case == "two_images":  # two sources: the image through each UV map, mixed
        uv = nodes.new("ShaderNodeUVMap")
        uv.uv_map = "Flipped"
        second = _image_node(nodes, image)
        links.new(uv.outputs["UV"], second.inputs["Vector"])
        _, a, b, out = _mix(nodes, "MIX", 0.5)
        links.new(tex.outputs["Color"], a)
        links.new(second.outputs["Color"], b)
        links.new(out, base)
    elif case == "unlit_noise":  # an Emission-only surface coloured by a procedural texture
        nodes.remove(tex)
        nodes.remove(principled)
        emission, noise = nodes.new("ShaderNodeEmission"), nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = 3.0
        links.new(noise.outputs["Color"], emission.inputs["Color"])
        links.new(emission.outputs[0], next(n for n in nodes if n.type == "OUTPUT_MATERIAL").inputs["Surface"])
    else:
        raise ValueError(case)
    return _plane(case, material)


def _mapping(nodes, links, tex) -> None:
    mapping = nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Location"].default_value = (0.25, -0.1, 0.0)
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(30.0))
    mapping.inputs["Scale"].default_value = (1.5, 0.8, 1.0)
    coordinates = nodes.new("ShaderNodeTexCoord")
    links.new(coordinates.outputs["UV"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], tex.inputs["Vector"])


def _group(nodes, links, tex, base) -> None:
    """A node group (as the glTF importer and artists make): Gamma then a Multiply by a tint inside."""
    tree = bpy.data.node_groups.new("Tinted", "ShaderNodeTree")
    if hasattr(tree, "interface"):
        tree.interface.new_socket("Color", in_out="INPUT", socket_type="NodeSocketColor")
        tree.interface.new_socket("Color", in_out="OUTPUT", socket_type="NodeSocketColor")
    else:  # Blender 3
        tree.inputs.new("NodeSocketColor", "Color")
        tree.outputs.new("NodeSocketColor", "Color")
    inside_in, inside_out = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    gamma = tree.nodes.new("ShaderNodeGamma")
    gamma.inputs["Gamma"].default_value = 0.7
    _, a, b, out = _mix(tree.nodes, "MULTIPLY", 1.0)
    b.default_value = (0.3, 0.8, 0.6, 1.0)
    tree.links.new(inside_in.outputs[0], gamma.inputs["Color"])
    tree.links.new(gamma.outputs["Color"], a)
    tree.links.new(out, inside_out.inputs[0])
    group = nodes.new("ShaderNodeGroup")
    group.node_tree = tree
    links.new(tex.outputs["Color"], group.inputs[0])
    links.new(group.outputs[0], base)


# --- Blender's reference: a Cycles bake of the colour reaching Base Color ---------------------------

def cycles_base_colour(obj) -> np.ndarray:
    """(SIDE, SIDE, 3) float32 sRGB of what reaches the material's Base Color, baked by Cycles over
    the active render UV map (rows bottom first, as Blender stores images)."""
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples = "CPU", BAKE_SAMPLES
    material = obj.material_slots[0].material
    nodes, links = material.node_tree.nodes, material.node_tree.links
    shader = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
    base = (shader.inputs["Base Color"] if shader is not None
            else next(n for n in nodes if n.type == "EMISSION").inputs[0])
    output = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
    emission = nodes.new("ShaderNodeEmission")
    if base.is_linked:
        links.new(base.links[0].from_socket, emission.inputs["Color"])
    else:
        emission.inputs["Color"].default_value = base.default_value
    surface = output.inputs["Surface"].links[0].from_socket
    links.new(emission.outputs[0], output.inputs["Surface"])
    target = bpy.data.images.new(f"bake {obj.name}", SIDE_PX, SIDE_PX, float_buffer=True)
    holder = _image_node(nodes, target)
    nodes.active = holder
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    try:
        bpy.ops.object.bake(type="EMIT", margin=0, use_clear=True)
    finally:
        links.new(surface, output.inputs["Surface"])
        nodes.remove(emission)
        nodes.remove(holder)
    pixels = np.empty(SIDE_PX * SIDE_PX * 4, np.float32)
    target.pixels.foreach_get(pixels)
    return srgb_from_linear(pixels.reshape(SIDE_PX, SIDE_PX, 4)[..., :3])


def reader_base_colour(row, affine: np.ndarray, uv_swap: bool) -> np.ndarray:
    """(SIDE, SIDE, 3) sRGB the add-on's material row gives at the bake's pixel centres: its texture
    looked up (bilinear, repeat, as Cycles' Linear interpolation) at the UV transform of each UV, times
    its base colour; its base colour alone without a texture."""
    centre = (np.arange(SIDE_PX) + 0.5) / SIDE_PX
    v, u = np.meshgrid(centre, centre, indexing="ij")  # rows bottom first
    if uv_swap:
        u, v = v, u
    if row.texture is None:
        return np.broadcast_to(srgb_from_linear(np.array(row.base_color[:3], np.float32)), (SIDE_PX, SIDE_PX, 3))
    image = bpy.data.images.load(row.texture, check_existing=False)
    w, h = image.size
    texels = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(texels)  # the file's (sRGB) values, bottom row first
    texels = texels.reshape(h, w, 4)
    bpy.data.images.remove(image)
    tu = affine[0, 0] * u + affine[0, 1] * v + affine[0, 2]
    tv = affine[1, 0] * u + affine[1, 1] * v + affine[1, 2]
    linear = srgb_to_linear(_bilinear(texels, tu, tv).reshape(-1, 4)).reshape(SIDE_PX, SIDE_PX, 4)
    return srgb_from_linear(linear[..., :3] * np.array(row.base_color[:3], np.float32))


def _bilinear(texels: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Texels (h, w, 4) bottom row first, looked up at (u, v) with texel centres at (k + 0.5) / n,
    wrapping (repeat)."""
    h, w, _ = texels.shape
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]

    def at(yy, xx):
        return texels[yy % h, xx % w]

    top = at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx
    bottom = at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    return top * (1 - fy) + bottom * fy


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return 99.0 if mse == 0 else round(10 * math.log10(1.0 / mse), 2)


CASES = ("direct", "mix_multiply", "mix_screen", "mix_overlay", "mix_soft_light", "mix_hue", "mixrgb_mix",
         "mixrgb_dodge", "mixrgb_linear_light", "hue_saturation", "gamma", "bright_contrast", "invert", "curves",
         "mapping", "uv_map", "group", "constant", "unlit", "noise")


def check_node_trees(repo, work) -> dict:
    """Every case's reading against Cycles' bake of its base colour (PSNR, dB), and a grey material's
    PSNR (what a material whose colour is not read gives) for scale."""
    blender_preview.enable_from_repo(repo)
    materials = importlib.import_module(NAME + ".addon.materials.rows")
    material_nodes = importlib.import_module(NAME + ".addon.materials.node_tree")
    bpy.ops.wm.read_homefile(use_empty=True)
    image = _source_image()
    out = {}
    for case in CASES:
        obj = build_case(case, image)
        material = obj.material_slots[0].material
        row = materials.material_row(material)
        reading = material_nodes.read_base_colour(material)
        reference = cycles_base_colour(obj)
        source = reading.source if reading is not None else None
        affine = np.array(source.uv_affine if source is not None else np.eye(3)[:2], np.float64)
        uv_swap = source is not None and source.uv_map == "Flipped"
        ours = reader_base_colour(row, affine, uv_swap)
        grey = np.full_like(reference, srgb_from_linear(np.float32(0.8)))
        out[case] = {"psnr_db": psnr_db(ours, reference), "grey_psnr_db": psnr_db(grey, reference),
                     "texture": row.texture is not None, "unreadable": bool(reading and reading.unreadable),
                     "uv_map": source.uv_map if source is not None else None}
        if case == "mapping":
            bpy.data.objects.remove(obj)
            obj = _gltf_round_trip(image, Path(work))
            material = obj.material_slots[0].material
            row, source = materials.material_row(material), material_nodes.read_base_colour(material).source
            ours = reader_base_colour(row, np.array(source.uv_affine, np.float64), False)
            reference = cycles_base_colour(obj)
            out["gltf_import"] = {"psnr_db": psnr_db(ours, reference), "grey_psnr_db": psnr_db(grey, reference),
                                  "texture": row.texture is not None, "unreadable": False, "uv_map": source.uv_map,
                                  "nodes": sorted({n.type for n in material.node_tree.nodes})}
    return out


def _gltf_round_trip(image, work: Path):
    """A plane whose image is tinted (Multiply by a colour) and transformed (Mapping), written by
    Blender's glTF exporter (baseColorFactor, KHR_texture_transform) and read back by its importer,
    which builds its own nodes (Mix, Mapping, UV Map)."""
    obj = build_case("mix_multiply", image)
    material = obj.material_slots[0].material
    mix = next(n for n in material.node_tree.nodes if n.type == "MIX")
    next(s for s in mix.inputs if s.identifier == "Factor_Float").default_value = 1.0  # a glTF factor
    _mapping(material.node_tree.nodes, material.node_tree.links,
             next(n for n in material.node_tree.nodes if n.type == "TEX_IMAGE"))
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    path = work / "tinted.glb"
    bpy.ops.export_scene.gltf(filepath=str(path), use_selection=True)
    bpy.data.objects.remove(obj)
    before = set(bpy.context.scene.objects)
    bpy.ops.import_scene.gltf(filepath=str(path))
    return next(o for o in bpy.context.scene.objects if o not in before and o.type == "MESH")


def _alpha_material(name: str, image, *, clip: bool):
    """Image colour into Base Color, its alpha into Alpha (through Greater Than 0.5 when `clip`)."""
    material, nodes, links, principled = _material(name)
    tex = _image_node(nodes, image)
    links.new(tex.outputs["Color"], principled.inputs["Base Color"])
    alpha = tex.outputs["Alpha"]
    if clip:
        step = nodes.new("ShaderNodeMath")
        step.operation = "GREATER_THAN"
        step.inputs[1].default_value = 0.5
        links.new(alpha, step.inputs[0])
        alpha = step.outputs[0]
    links.new(alpha, principled.inputs["Alpha"])
    return material


def _attribute_plane(tint):
    """A plane with two colour attributes (the active one "Other", and "Tint" that its material's
    Color Attribute node reads, multiplied by `tint`)."""
    material, nodes, links, principled = _material("painted")
    attribute = nodes.new("ShaderNodeVertexColor")
    attribute.layer_name = "Tint"
    _, a, b, out = _mix(nodes, "MULTIPLY", 1.0)
    links.new(attribute.outputs["Color"], a)
    b.default_value = tint
    links.new(out, principled.inputs["Base Color"])
    obj = _plane("painted", material)
    mesh = obj.data
    tint_values = np.array([[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1], [1, 1, 1, 1]], np.float32)
    for name, values in (("Tint", tint_values), ("Other", np.full((4, 4), 0.5, np.float32))):
        layer = mesh.color_attributes.new(name, "FLOAT_COLOR", "POINT")
        layer.data.foreach_set("color", values.ravel())
    mesh.color_attributes.active_color = mesh.color_attributes["Other"]
    return obj, tint_values


def check_scene_reading(repo, work) -> dict:
    """Through the bake's reading of the scene (scene/gather.py gather): the UV map and UV
    transform a material's image is looked up through, applied to its triangles' UVs; a colour
    attribute named by a Color Attribute node becoming the vertex colours through the colour nodes;
    the alpha mode of a clipped and of a blended image alpha; the written textures placed beside
    the output."""
    blender_preview.enable_from_repo(repo)
    gathering = importlib.import_module(NAME + ".addon.scene.gather")
    materials = importlib.import_module(NAME + ".addon.materials.rows")
    material_texture = importlib.import_module(NAME + ".addon.materials.textures")
    bpy.ops.wm.read_homefile(use_empty=True)
    image = _source_image()
    out = {}
    for case in ("mapping", "uv_map"):
        obj = build_case(case, image)
        mesh = gathering.gather(bpy.context, [obj]).mesh
        source = importlib.import_module(NAME + ".addon.materials.node_tree").read_base_colour(
            obj.material_slots[0].material).source
        corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64)  # the plane's UVMap, per vertex
        if source.uv_map == "Flipped":
            corners = corners[:, ::-1]
        affine = np.array(source.uv_affine)
        expected = corners @ affine[:, :2].T + affine[:, 2]
        got = mesh.uvs[np.argsort(mesh.positions[:, 0] * 2 + mesh.positions[:, 1])]  # vertices (0,0),(0,1),(1,0),(1,1)
        want = expected[[0, 3, 1, 2]]
        out[case] = {"uv_error": float(np.abs(got - want).max()), "identity": bool(np.allclose(affine, np.eye(3)[:2]))}
        bpy.data.objects.remove(obj)
    tint = (0.5, 0.25, 1.0, 1.0)
    obj, tint_values = _attribute_plane(tint)
    mesh = gathering.gather(bpy.context, [obj]).mesh
    order = np.argsort(mesh.positions[:, 0] * 2 + mesh.positions[:, 1])  # (0,0),(0,1),(1,0),(1,1)
    want = tint_values[[0, 3, 1, 2]] * np.array([*tint[:3], 1.0], np.float32)
    out["attribute"] = {"colour_error": float(np.abs(mesh.colors[order] - want).max()),
                        "base_color": list(mesh.materials[0].base_color)}
    alpha_image = bpy.data.images.new("alpha", SIDE_PX, SIDE_PX, alpha=True)
    ramp = np.ones((SIDE_PX, SIDE_PX, 4), np.float32)
    ramp[..., 3] = np.linspace(0.0, 1.0, SIDE_PX)[None, :]
    alpha_image.pixels.foreach_set(ramp.ravel())
    alpha_materials = {clip: _alpha_material(f"alpha {clip}", alpha_image, clip=clip) for clip in (True, False)}
    alpha_materials[True].use_backface_culling = True  # one face drawn
    rows = {clip: materials.material_row(material) for clip, material in alpha_materials.items()}
    out["alpha_modes"] = {"clip": rows[True].alpha_mode, "blend": rows[False].alpha_mode}
    made = {sided: materials.material_from_row(dataclasses.replace(rows[True], name=f"made {sided}",
                                                                   double_sided=sided)) for sided in (True, False)}
    out["double_sided"] = {"read": {"clip": rows[True].double_sided, "blend": rows[False].double_sided},
                           "made_culls": {str(k): m.use_backface_culling for k, m in made.items()}}
    out["made_alpha_mode"] = materials.material_row(made[True]).alpha_mode  # Materialize's cut-out read back
    placed = _placed(material_texture, dataclasses.replace(mesh, materials=(rows[True], rows[False])),
                     Path(work) / "out.hlod")
    out["placed"] = sorted(str(Path(m.texture).relative_to(Path(work).resolve())) for m in placed.materials)
    return out


def _placed(material_texture, mesh, output: Path):
    """The mesh's written textures placed for a bake into `output` and published, as a bake does
    once its .hlod is written (material_texture.place_textures, texture_folder.EmbeddedTextures)."""
    texture_folder = importlib.import_module(NAME + ".hlod_core.io.texture_folder")
    with texture_folder.EmbeddedTextures(output) as textures:
        placed = material_texture.place_textures(mesh, textures)
        textures.publish()
    return placed


# --- materials whose tree cannot be read, baked by Cycles (addon/scene/surface_bakes.py) -------------

FALLBACK_CASES = ("noise", "voronoi", "two_images", "unlit_noise")


def check_cycles_fallback(repo, work) -> dict:
    """Through the bake's path (scene/gather.py gather, which has Cycles bake what the trees do not
    give: scene/surface_bakes.py, materials/cycles_bake.py; materials/textures.py place_textures):
    each unreadable case's baked texture looked up at the reference bake's texel centres against
    Cycles' bake of its base colour (PSNR, dB; and the Base Color value's PSNR, what the row held
    before); the scene's state before and after (render, Cycles and bake settings, selection, active
    object, datablocks, node trees, the image's pixels); the bakes made; a plane without UVs (its
    corner colours); a second gathering's files; the background command's bake and 3D Tiles export
    and the Bake operator's bake of the same objects."""
    blender_preview.enable_from_repo(repo)
    gathering = importlib.import_module(NAME + ".addon.scene.gather")
    material_bake = importlib.import_module(NAME + ".addon.materials.cycles_bake")
    material_texture = importlib.import_module(NAME + ".addon.materials.textures")
    materials = importlib.import_module(NAME + ".addon.materials.rows")
    bpy.ops.wm.read_homefile(use_empty=True)
    image = _source_image()
    planes = [build_case(case, image) for case in FALLBACK_CASES]
    for obj in planes:  # an artist's last click: an image node, which the bake must not write into
        tree = obj.material_slots[0].material.node_tree
        tree.nodes.active = next((n for n in tree.nodes if n.type == "TEX_IMAGE"), tree.nodes.active)
    bare = _bare_plane(planes[0].material_slots[0].material)
    bystander = _plane("bystander", bpy.data.materials.new("bystander"))
    bystander.select_set(True)
    bpy.context.view_layer.objects.active = bystander
    bpy.context.scene.cycles.samples, bpy.context.scene.render.bake.margin = 37, 3  # not Cycles' defaults
    warnings = captured_warnings(NAME + ".addon")
    before = _scene_state()
    started = time.perf_counter()
    gathered = gathering.gather(bpy.context, [*planes, bare])
    seconds = time.perf_counter() - started
    after, warned = _scene_state(), list(warnings)
    again = gathering.gather(bpy.context, [*planes, bare]).mesh
    baked_mesh = gathered.mesh
    placed = _placed(material_texture, baked_mesh, Path(work) / "out.hlod")
    rows = {row.name: row for row in placed.materials}
    bare_faces = baked_mesh.faces[baked_mesh.positions[baked_mesh.faces].mean(axis=1)[:, 0] > 1.5]
    out = {"names": gathered.cycles_baked, "bakes": [b.as_dict() for b in gathered.cycles_bakes],
           "report": material_bake.cycles_report(gathered.cycles_bakes), "seconds": round(seconds, 2),
           "state_changed": sorted(k for k in before if before[k] != after[k]),
           "same_files": [m.texture for m in again.materials] == [m.texture for m in baked_mesh.materials],
           "warnings": warned,
           "no_uv": {"texture": rows["no_uv"].texture, "base_color": list(rows["no_uv"].base_color),
                     "colour_spread": float(np.ptp(baked_mesh.colors[np.unique(bare_faces)][:, :3]))},
           "cases": {}}
    for obj in planes:
        row, unread = rows[obj.name], materials.material_row(obj.material_slots[0].material)
        reference = cycles_base_colour(obj)
        out["cases"][obj.name] = {
            "psnr_db": psnr_db(reader_base_colour(row, np.eye(3)[:2], False), reference),
            "base_color_psnr_db": psnr_db(reader_base_colour(unread, np.eye(3)[:2], False), reference),
            "texture": str(Path(row.texture).relative_to(Path(work).resolve())) if row.texture else None,
            "base_color": list(row.base_color), "side_px": list(bpy.data.images.load(row.texture).size)}
    out["cli"] = _cli_bake(importlib.import_module(NAME + ".addon.cli"), Path(work))
    out["operator"] = _operator_bake([*planes, bare], Path(work))
    return out


def _operator_bake(objects, work: Path) -> dict:
    """The Bake operator on `objects` (selected): its result, the lines Blender printed while it ran
    (its reports among them) and the textures beside its output."""
    props = bpy.context.scene.hlod
    props.source, props.output_path, props.target_tris = "SELECTED", str(work / "op.hlod"), 64
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in objects)
    printed = work / "operator.txt"
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(printed, "wb") as sink:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            result = sorted(bpy.ops.hlod.bake())
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
    return {"result": result, "printed": printed.read_text(errors="replace").splitlines(),
            "textures": sorted(p.name for p in (work / "op.textures").glob("*.png"))}


def _cli_bake(cli, work: Path) -> dict:
    """The background command's bake of the open scene into .hlod and 3D Tiles: its status, its
    JSON summary's Cycles bakes, its stderr lines, the textures beside its output, and per material
    whose texture the bake wrote, whether a tile's GLB material of that name refers to those very
    bytes."""
    with contextlib.redirect_stdout(io.StringIO()) as printed, contextlib.redirect_stderr(io.StringIO()) as err:
        status = cli.execute(["bake", "--target-tris", "64", "--max-depth", "1", "-o", str(work / "cli.hlod"),
                              "--format", "hlod", "3dtiles"])
    summary = json.loads(printed.getvalue().strip().splitlines()[-1]) if status == 0 else {}
    textures = {p.stem: p.read_bytes() for p in (work / "cli.textures").glob("*.png")}
    in_tiles = {}
    for glb in sorted((work / "cli_3dtiles" / "tiles").glob("*.glb")):
        data = glb.read_bytes()
        document = json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])
        for material in document.get("materials", []):
            texture = material["pbrMetallicRoughness"].get("baseColorTexture")
            if texture is not None and material["name"] in textures:
                uri = document["images"][document["textures"][texture["index"]]["source"]]["uri"]
                same = (glb.parent / uri).read_bytes() == textures[material["name"]]
                in_tiles[material["name"]] = in_tiles.get(material["name"], True) and same
    return {"status": status, "stderr": err.getvalue().splitlines(), "textures": sorted(f"{n}.png" for n in textures),
            "in_tiles": in_tiles, "cycles_bakes": summary.get("files", [{}])[0].get("cycles_bakes")}


def _bare_plane(material):
    """A plane without UV maps, with a copy (named no_uv) of `material`."""
    mesh = bpy.data.meshes.new("no_uv")
    mesh.from_pydata([(2, 0, 0), (3, 0, 0), (3, 1, 0), (2, 1, 0)], [], [(0, 1, 2, 3)])
    copy = material.copy()
    copy.name = "no_uv"
    mesh.materials.append(copy)
    obj = bpy.data.objects.new("no_uv", mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def captured_warnings(logger_name: str) -> list[str]:
    """A list that receives the messages of every warning `logger_name` (and below) logs from now."""
    messages: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record):
            messages.append(record.getMessage())

    handler = Keep(logging.WARNING)
    logging.getLogger(logger_name).addHandler(handler)
    return messages


def _scene_state() -> dict:
    """What the bake must leave as it found it, as comparable values."""
    scene, layer = bpy.context.scene, bpy.context.view_layer
    state = {f"{name} settings": _rna_values(owner) for name, owner in
             (("render", scene.render), ("bake", scene.render.bake), ("cycles", scene.cycles))}
    state["selected"] = sorted(o.name for o in layer.objects if o.select_get())
    state["active"] = layer.objects.active.name if layer.objects.active else None
    state["datablocks"] = {kind: sorted(x.name for x in getattr(bpy.data, kind))
                           for kind in ("scenes", "objects", "meshes", "materials", "images", "node_groups")}
    state["slots"] = {o.name: [(s.link, s.material.name if s.material else None) for s in o.material_slots]
                      for o in bpy.data.objects}
    state["trees"] = {m.name: _tree(m.node_tree) for m in bpy.data.materials if m.node_tree is not None}
    state["pixels"] = {i.name: float(np.asarray(i.pixels[:], np.float64).sum()) for i in bpy.data.images}
    return state


def _rna_values(owner) -> dict:
    return {p.identifier: repr(getattr(owner, p.identifier)) for p in owner.bl_rna.properties
            if p.identifier != "rna_type" and p.type not in ("POINTER", "COLLECTION")}


def _tree(tree) -> dict:
    """A node tree's nodes (with their inputs' values), links and active node."""
    def value(socket):
        v = getattr(socket, "default_value", None)
        return repr(tuple(v) if hasattr(v, "__len__") and not isinstance(v, str) else v)

    return {"nodes": sorted((n.name, n.bl_idname, tuple(value(s) for s in n.inputs)) for n in tree.nodes),
            "links": sorted((k.from_node.name, k.from_socket.identifier, k.to_node.name, k.to_socket.identifier)
                            for k in tree.links),
            "active": tree.nodes.active.name if tree.nodes.active else None}


if __name__ == "__main__":
    repo_dir, check, work_dir, *extra = sys.argv[1:]
    result = globals()[f"check_{check}"](repo_dir, work_dir, *extra)
    print(json.dumps(result))
    blender_preview.exit_process(0)
