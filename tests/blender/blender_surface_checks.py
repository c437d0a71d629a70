"""Surfaces whatever shader draws them, inside the real bpy module, one check per subprocess
(tests/blender/test_addon_surfaces.py runs them):

    python tests/blender/blender_surface_checks.py REPO_DIR CHECK WORK_DIR

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.

Each case is an object whose surface has no Principled Base Color to read, built with bpy as an
artist or an importer builds it: the Diffuse and Glossy group glTF exporters shipped before the
Principled BSDF (inputs BaseColorFactor, BaseColor, MetallicFactor, RoughnessFactor,
MetallicRoughness, Normal; a Fresnel-weighted Mix of Diffuse and Glossy BSDFs, mixed with a
metallic Glossy BSDF by the metallic factor) with an Image Texture into BaseColor, that group
linked from a library .blend, Diffuse and Toon BSDFs, Mix and Add Shader of BSDFs, Emission mixed
with a Diffuse BSDF, a material set by geometry nodes' Set Material, a realised instance carrying
its own material, an object without UV maps, and two objects sharing one material over different
UV layouts. The reference is Blender's own: Cycles' DIFFUSE bake with only its COLOR contribution
of the same surface (into an image over the object's UVs, or a colour per face corner without UVs).
The add-on's colour, gathered as a bake gathers it (addon/scene/gather.py), is the row's texture
looked up at the reference's texel centres, or the vertex colours at each corner, compared with it
as PSNR in sRGB; beside it, the grey those surfaces gave before (Blender's default 0.8).
"""
from __future__ import annotations

import importlib
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import bpy

import blender_preview
import surface_colours as expect
from blender_material_checks import captured_warnings
from hlod_core.core.colour import srgb_from_linear, srgb_to_linear

NAME = "bl_ext.r.hlod"
SOURCE_PX = expect.SOURCE_PX  # the source image's side
REFERENCE_PX = 64  # the reference bake's side, one sample per texel (at its centre)
OURS_PX = 128  # the add-on's bake side here (cycles_bake.BAKE_SIDE_PX; 512 in a user's bake)
GREY = 0.8  # Blender's default material colour: what these surfaces gave before
#: The viewport colour (diffuse_color, linear RGBA) of the material baked with Cycles disabled.
VIEWPORT_COLOUR = (0.25, 0.5, 0.125, 1.0)
SPACING = 3.0  # metres between the cases' objects
GROUP = "glTF Metallic Roughness"
CASES = ("gltf_group", "linked_group", "diffuse", "toon", "mix_shader", "add_shader", "emission_mix",
         "set_material", "realised_instance", "no_uv", "shared_a", "shared_b")


# --- the scene ------------------------------------------------------------------------------------

def _source_image():
    """A packed 32x32 8-bit sRGB image of surface_colours.source_rgba (smooth hue ramps)."""
    image = bpy.data.images.new("source", SOURCE_PX, SOURCE_PX, alpha=True)
    image.pixels.foreach_set(expect.source_rgba().ravel())
    image.pack()
    return image


def _material(name: str):
    """(material, nodes, links, output) of a new material whose tree holds only its output."""
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # Blender 4 makes a material without nodes
        material.use_nodes = True
    nodes = material.node_tree.nodes
    for node in [n for n in nodes if n.type != "OUTPUT_MATERIAL"]:
        nodes.remove(node)
    return material, nodes, material.node_tree.links, next(n for n in nodes if n.type == "OUTPUT_MATERIAL")


def _plane(name: str, index: int, material=None, *, uvs=((0, 0), (1, 0), (1, 1), (0, 1)), grid: int = 1):
    """A 1 m plane of grid x grid quads at x = index * SPACING, its UV map "UVMap" spanning `uvs`
    (its corners' UVs, bilinear inside; None: no UV map), with `material` in its one slot."""
    mesh = bpy.data.meshes.new(name)
    k = np.arange(grid + 1) / grid
    vx, vy = np.meshgrid(k, k)
    mesh.from_pydata([(x, y, 0.0) for x, y in zip(vx.ravel(), vy.ravel())], [],
                     [(j * (grid + 1) + i, j * (grid + 1) + i + 1, (j + 1) * (grid + 1) + i + 1,
                       (j + 1) * (grid + 1) + i) for j in range(grid) for i in range(grid)])
    if uvs is not None:
        corners = np.array(uvs, np.float64)
        loops = np.array([mesh.vertices[v].co[:2] for poly in mesh.polygons for v in poly.vertices])
        s, t = loops[:, :1], loops[:, 1:]
        values = (corners[0] * (1 - s) * (1 - t) + corners[1] * s * (1 - t) + corners[2] * s * t
                  + corners[3] * (1 - s) * t)
        mesh.uv_layers.new(name="UVMap").data.foreach_set("uv", values.astype(np.float32).ravel())
    if material is not None:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = (index * SPACING, 0.0, 0.0)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _image_node(nodes, image):
    node = nodes.new("ShaderNodeTexImage")
    node.image = image
    return node


def gltf_group(name: str = GROUP):
    """The metallic-roughness node group glTF exporters shipped before the Principled BSDF: base =
    BaseColor x BaseColorFactor; metallic, roughness = the factors x MetallicRoughness's B, G;
    dielectric = Mix(Fresnel(IOR 1.5), Diffuse(base), Glossy(white)); out = Mix(metallic,
    dielectric, Glossy(base)). The Normal input is left unlinked inside (linked, an unconnected
    group input would give the shaders a zero normal)."""
    tree = bpy.data.node_groups.new(name, "ShaderNodeTree")
    for socket, kind in (("BaseColorFactor", "Color"), ("BaseColor", "Color"), ("MetallicFactor", "Float"),
                         ("RoughnessFactor", "Float"), ("MetallicRoughness", "Color"), ("Normal", "Vector")):
        item = tree.interface.new_socket(socket, in_out="INPUT", socket_type=f"NodeSocket{kind}")
        if kind != "Vector":
            item.default_value = (1.0, 1.0, 1.0, 1.0) if kind == "Color" else 1.0
    tree.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    nodes, links = tree.nodes, tree.links
    inside, outside = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    base = nodes.new("ShaderNodeMixRGB")
    base.blend_type, base.inputs["Fac"].default_value = "MULTIPLY", 1.0
    links.new(inside.outputs["BaseColorFactor"], base.inputs["Color1"])
    links.new(inside.outputs["BaseColor"], base.inputs["Color2"])
    separate = nodes.new("ShaderNodeSeparateColor")
    links.new(inside.outputs["MetallicRoughness"], separate.inputs[0])
    factors = {}
    for channel, factor in (("Green", "RoughnessFactor"), ("Blue", "MetallicFactor")):
        product = factors[factor] = nodes.new("ShaderNodeMath")
        product.operation = "MULTIPLY"
        links.new(separate.outputs[channel], product.inputs[0])
        links.new(inside.outputs[factor], product.inputs[1])
    fresnel, diffuse = nodes.new("ShaderNodeFresnel"), nodes.new("ShaderNodeBsdfDiffuse")
    fresnel.inputs["IOR"].default_value = expect.FRESNEL_IOR
    specular, metal = nodes.new("ShaderNodeBsdfGlossy"), nodes.new("ShaderNodeBsdfGlossy")
    dielectric, out = nodes.new("ShaderNodeMixShader"), nodes.new("ShaderNodeMixShader")
    links.new(base.outputs["Color"], diffuse.inputs["Color"])
    links.new(base.outputs["Color"], metal.inputs["Color"])
    for shader in (specular, metal):
        links.new(factors["RoughnessFactor"].outputs[0], shader.inputs["Roughness"])
    links.new(fresnel.outputs[0], dielectric.inputs[0])
    links.new(diffuse.outputs[0], dielectric.inputs[1])
    links.new(specular.outputs[0], dielectric.inputs[2])
    links.new(factors["MetallicFactor"].outputs[0], out.inputs[0])
    links.new(dielectric.outputs[0], out.inputs[1])
    links.new(metal.outputs[0], out.inputs[2])
    links.new(out.outputs[0], outside.inputs["Shader"])
    return tree


def _linked_group(work: Path):
    """gltf_group written into a library .blend and linked from it, as from an asset library (made
    before the file has a group of that name)."""
    local = gltf_group()
    path = work / "library.blend"
    bpy.data.libraries.write(str(path), {local}, fake_user=True)
    bpy.data.node_groups.remove(local)
    with bpy.data.libraries.load(str(path), link=True) as (_, into):
        into.node_groups = [GROUP]
    return into.node_groups[0]


def _group_material(name: str, group, image):
    material, nodes, links, output = _material(name)
    node = nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.inputs["BaseColorFactor"].default_value = expect.BASE_COLOR_FACTOR
    node.inputs["MetallicFactor"].default_value = expect.METALLIC_FACTOR
    node.inputs["RoughnessFactor"].default_value = expect.ROUGHNESS_FACTOR
    links.new(_image_node(nodes, image).outputs["Color"], node.inputs["BaseColor"])
    links.new(node.outputs[0], output.inputs["Surface"])
    return material


def _bsdf_material(name: str, kind: str, image):
    """A material whose surface is one BSDF of `kind` coloured by the image."""
    material, nodes, links, output = _material(name)
    shader = nodes.new(kind)
    links.new(_image_node(nodes, image).outputs["Color"], shader.inputs["Color"])
    links.new(shader.outputs[0], output.inputs["Surface"])
    return material


def _shader_mix(name: str, image, *, add: bool = False, second: str = "ShaderNodeBsdfGlossy",
                colour=(1.0, 1.0, 1.0, 1.0), factor: float = expect.GLOSSY_MIX):
    """Mix (factor) or Add Shader of a Diffuse BSDF coloured by the image and a `second` shader."""
    material, nodes, links, output = _material(name)
    diffuse, other = nodes.new("ShaderNodeBsdfDiffuse"), nodes.new(second)
    links.new(_image_node(nodes, image).outputs["Color"], diffuse.inputs["Color"])
    other.inputs["Color"].default_value = colour
    mix = nodes.new("ShaderNodeAddShader" if add else "ShaderNodeMixShader")
    if not add:
        mix.inputs[0].default_value = factor
    links.new(diffuse.outputs[0], mix.inputs[-2])
    links.new(other.outputs[0], mix.inputs[-1])
    links.new(mix.outputs[0], output.inputs["Surface"])
    return material


def _procedural_material(name: str):
    """A Diffuse BSDF coloured by a colour ramp over the object's Generated coordinates (no UVs)."""
    material, nodes, links, output = _material(name)
    coordinates, separate, ramp = (nodes.new("ShaderNodeTexCoord"), nodes.new("ShaderNodeSeparateXYZ"),
                                   nodes.new("ShaderNodeValToRGB"))
    links.new(coordinates.outputs["Generated"], separate.inputs[0])
    links.new(separate.outputs["X"], ramp.inputs["Fac"])
    ramp.color_ramp.elements[0].color, ramp.color_ramp.elements[1].color = expect.RAMP
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    links.new(ramp.outputs["Color"], diffuse.inputs["Color"])
    links.new(diffuse.outputs[0], output.inputs["Surface"])
    return material


def _nodes_modifier(obj, name: str, build) -> None:
    """A geometry-nodes modifier on `obj` whose tree passes its geometry through build(tree, geometry socket)."""
    tree = bpy.data.node_groups.new(name, "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    inside, outside = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    tree.links.new(build(tree, inside.outputs[0]), outside.inputs[0])
    obj.modifiers.new(name, "NODES").node_group = tree


def build_scene(work: Path) -> dict:
    """Every case's object (what the bake takes) and its reference object (what Cycles bakes for
    the reference: the object itself, or for the geometry-nodes cases a plain object drawing the
    same surface): {case: (object, reference)}."""
    image = _source_image()
    linked = _linked_group(work)
    group = gltf_group()
    made = {}

    def add(case: str, material, **plane):
        obj = _plane(case, len(made), material, **plane)
        made[case] = (obj, obj)
        return obj

    add("gltf_group", _group_material("gltf_group", group, image))
    add("linked_group", _group_material("linked_group", linked, image))
    add("diffuse", _bsdf_material("diffuse", "ShaderNodeBsdfDiffuse", image))
    add("toon", _bsdf_material("toon", "ShaderNodeBsdfToon", image))
    add("mix_shader", _shader_mix("mix_shader", image))
    add("add_shader", _shader_mix("add_shader", image, add=True, second="ShaderNodeBsdfDiffuse",
                                  colour=expect.ADD_COLOUR))
    add("emission_mix", _shader_mix("emission_mix", image, second="ShaderNodeEmission", colour=expect.EMISSION_COLOUR,
                                    factor=expect.EMISSION_MIX))
    set_by_nodes = _bsdf_material("set_material", "ShaderNodeBsdfDiffuse", image)
    obj = add("set_material", None)

    def set_material(tree, geometry):
        node = tree.nodes.new("GeometryNodeSetMaterial")
        node.inputs["Material"].default_value = set_by_nodes
        tree.links.new(geometry, node.inputs["Geometry"])
        return node.outputs[0]

    _nodes_modifier(obj, "Set Material", set_material)
    made["set_material"] = (obj, _plane("set_material reference", len(made) + 20, set_by_nodes))
    tile = _plane("tile", len(made) + 21, _bsdf_material("realised_instance", "ShaderNodeBsdfToon", image))
    obj = add("realised_instance", None)

    def realised(tree, geometry):
        info, realise = tree.nodes.new("GeometryNodeObjectInfo"), tree.nodes.new("GeometryNodeRealizeInstances")
        info.inputs["Object"].default_value = tile
        info.inputs["As Instance"].default_value = True
        tree.links.new(info.outputs["Geometry"], realise.inputs[0])
        return realise.outputs[0]

    _nodes_modifier(obj, "Realised Tile", realised)
    made["realised_instance"] = (obj, tile)
    add("no_uv", _procedural_material("no_uv"), uvs=None, grid=6)
    shared = _procedural_material("shared")  # a colour of the object's space: each UV layout its own pixels
    add("shared_a", shared)
    add("shared_b", shared, uvs=((1, 0), (1, 1), (0, 1), (0, 0)))  # its UVs turned a quarter
    return made


# --- Blender's reference: Cycles' DIFFUSE COLOR bake ------------------------------------------------

def diffuse_colour_bake(obj, *, side_px: int = REFERENCE_PX) -> np.ndarray:
    """Cycles' DIFFUSE bake (COLOR only, one sample) of `obj` as it is: (side, side, 3) float32 sRGB
    over its UV map (rows bottom first), or (l, 3) per face corner when it has none."""
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples = "CPU", 1
    bpy.ops.object.select_all(action="DESELECT")
    obj.select_set(True)
    bpy.context.view_layer.objects.active = obj
    if not obj.data.uv_layers:
        attribute = obj.data.color_attributes.new("reference", "FLOAT_COLOR", "CORNER")
        obj.data.color_attributes.active_color = attribute
        bpy.ops.object.bake(type="DIFFUSE", pass_filter={"COLOR"}, target="VERTEX_COLORS")
        values = np.empty(len(obj.data.loops) * 4, np.float32)
        obj.data.color_attributes["reference"].data.foreach_get("color", values)
        return srgb_from_linear(values.reshape(-1, 4)[:, :3])
    target = bpy.data.images.new(f"reference {obj.name}", side_px, side_px, float_buffer=True)
    material = obj.material_slots[0].material
    holder = _image_node(material.node_tree.nodes, target)
    material.node_tree.nodes.active = holder
    try:
        bpy.ops.object.bake(type="DIFFUSE", pass_filter={"COLOR"}, margin=0, use_clear=True)
    finally:
        material.node_tree.nodes.remove(holder)
    pixels = np.empty(side_px * side_px * 4, np.float32)
    target.pixels.foreach_get(pixels)
    return srgb_from_linear(pixels.reshape(side_px, side_px, 4)[..., :3])


# --- the add-on's colours ---------------------------------------------------------------------------

def _triangles_of(mesh, obj) -> np.ndarray:
    """(f,) bool: the gathered mesh's triangles inside `obj`'s 1 m square (each case has its own)."""
    centre = mesh.positions[mesh.faces].mean(axis=1)
    x0, y0 = obj.location.x, obj.location.y
    return (centre[:, 0] > x0) & (centre[:, 0] < x0 + 1) & (centre[:, 1] > y0) & (centre[:, 1] < y0 + 1)


def texture_at_texel_centres(row, side_px: int = REFERENCE_PX) -> np.ndarray:
    """(side, side, 3) sRGB of the row at the reference bake's texel centres: its texture looked up
    bilinearly (clamped, as the bake's margin extends it) times its base colour; its base colour
    alone without a texture."""
    if row.texture is None:
        return np.broadcast_to(srgb_from_linear(np.array(row.base_color[:3], np.float32)), (side_px, side_px, 3))
    image = bpy.data.images.load(row.texture, check_existing=False)
    w, h = image.size
    texels = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(texels)  # the PNG's sRGB values, bottom row first
    bpy.data.images.remove(image)
    texels = texels.reshape(h, w, 4)
    centre = (np.arange(side_px) + 0.5) / side_px
    v, u = np.meshgrid(centre, centre, indexing="ij")
    x, y = np.clip(u * w - 0.5, 0, w - 1), np.clip(v * h - 0.5, 0, h - 1)
    x0, y0 = np.minimum(np.floor(x).astype(int), w - 2), np.minimum(np.floor(y).astype(int), h - 2)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    top = texels[y0, x0] * (1 - fx) + texels[y0, x0 + 1] * fx
    bottom = texels[y0 + 1, x0] * (1 - fx) + texels[y0 + 1, x0 + 1] * fx
    linear = srgb_to_linear((top * (1 - fy) + bottom * fy).reshape(-1, 4)).reshape(side_px, side_px, 4)
    return srgb_from_linear(linear[..., :3] * np.array(row.base_color[:3], np.float32))


def corner_colours(mesh, obj) -> np.ndarray:
    """(l, 3) sRGB of the gathered mesh's vertex colours at each face corner of `obj`'s own mesh
    (the gathered vertex nearest the corner's world position)."""
    at = np.unique(mesh.faces[_triangles_of(mesh, obj)])
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    corner_vertex = np.empty(len(obj.data.loops), np.int64)
    obj.data.loops.foreach_get("vertex_index", corner_vertex)
    corners = co.reshape(-1, 3)[corner_vertex] + np.array(obj.location)
    nearest = np.argmin(np.linalg.norm(corners[:, None] - mesh.positions[at][None], axis=2), axis=1)
    return srgb_from_linear(mesh.colors[at][nearest, :3])


def psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return 99.0 if mse == 0 else round(10 * math.log10(1.0 / mse), 2)


# --- the checks ---------------------------------------------------------------------------------------

def _updated_scenes() -> set:
    """A set that gets the name of every scene Blender evaluates from now (depsgraph_update_post):
    a Cycles bake evaluates the scene it bakes in."""
    scenes: set = set()

    def note(scene, *_args):
        scenes.add(scene.name)

    bpy.app.handlers.depsgraph_update_post.append(note)
    return scenes


def _datablocks() -> dict:
    return {kind: sorted(x.name_full for x in getattr(bpy.data, kind))
            for kind in ("scenes", "objects", "meshes", "materials", "images", "node_groups")}


def _expected(case: str, obj, reference: np.ndarray) -> np.ndarray:
    """surface_colours' linear colour of `case` where `reference` was baked: at the texel centres,
    or at each face corner of `obj`'s mesh (the procedural over the plane's local x) without UVs."""
    if reference.ndim == 3:
        return expect.expected(case, reference.shape[0])
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    corner_vertex = np.empty(len(obj.data.loops), np.int64)
    obj.data.loops.foreach_get("vertex_index", corner_vertex)
    return expect.ramp_linear(co.reshape(-1, 3)[corner_vertex, 0])


def check_surfaces(repo, work) -> dict:
    """Every case gathered together, as a bake gathers them: its colour against Cycles' DIFFUSE
    COLOR bake (PSNR, dB) and the grey's; the rows (names, textures); the bakes run and reported;
    the datablocks before and after."""
    blender_preview.enable_from_repo(repo)
    gathering = importlib.import_module(NAME + ".addon.scene.gather")
    cycles_bake = importlib.import_module(NAME + ".addon.materials.cycles_bake")
    cycles_bake.BAKE_SIDE_PX = OURS_PX
    bpy.ops.wm.read_homefile(use_empty=True)
    made = build_scene(Path(work))
    before, scenes = _datablocks(), _updated_scenes()
    started = time.perf_counter()
    gathered = gathering.gather(bpy.context, [obj for obj, _ in made.values()])
    seconds = time.perf_counter() - started
    out = {"scenes_updated": sorted(scenes), "datablocks_kept": _datablocks() == before, "seconds": round(seconds, 2),
           "cycles_bakes": [b.as_dict() for b in gathered.cycles_bakes],
           "report": cycles_bake.cycles_report(gathered.cycles_bakes), "cases": {}}
    mesh = gathered.mesh
    for case, (obj, reference_obj) in made.items():
        reference = diffuse_colour_bake(reference_obj)
        rows = sorted({mesh.materials[i] for i in mesh.material_ids[_triangles_of(mesh, obj)]}, key=lambda r: r.name)
        row = rows[0]
        ours = corner_colours(mesh, obj) if reference.ndim == 2 else texture_at_texel_centres(row)
        grey = np.full_like(reference, srgb_from_linear(np.float32(GREY)))
        model = srgb_from_linear(_expected(case, obj, reference))
        out["cases"][case] = {"psnr_db": psnr_db(ours, reference), "grey_psnr_db": psnr_db(grey, reference),
                              "expected_db": psnr_db(ours, model), "reference_expected_db": psnr_db(reference, model),
                              "rows": [r.name for r in rows], "texture": row.texture is not None,
                              "base_color": list(row.base_color), "metallic": row.metallic}
    shared_a = texture_at_texel_centres(next(m for m in mesh.materials if m.name == "shared (shared_a)"))
    out["one_layout_psnr_db"] = psnr_db(shared_a, diffuse_colour_bake(made["shared_b"][0]))
    return out


def check_without_cycles_bakes(repo, work) -> dict:
    """A scene whose materials are all read from their trees (a Principled BSDF with an image, one
    with a constant colour, an unlit Emission): gathering it starts no Cycles bake and makes no
    datablock. Then, with the Cycles add-on disabled, a Diffuse BSDF's plane: what the bake says
    and the row it keeps."""
    blender_preview.enable_from_repo(repo)
    gathering = importlib.import_module(NAME + ".addon.scene.gather")
    bpy.ops.wm.read_homefile(use_empty=True)
    image = _source_image()
    objects = []
    for k, kind in enumerate(("image", "constant", "unlit")):
        material, nodes, links, output = _material(kind)
        shader = nodes.new("ShaderNodeEmission" if kind == "unlit" else "ShaderNodeBsdfPrincipled")
        if kind != "constant":
            links.new(_image_node(nodes, image).outputs["Color"], shader.inputs[0])
        links.new(shader.outputs[0], output.inputs["Surface"])
        objects.append(_plane(kind, k, material))
    before, scenes = _datablocks(), _updated_scenes()
    gathered = gathering.gather(bpy.context, objects)
    out = {"cycles_bakes": len(gathered.cycles_bakes), "datablocks_kept": _datablocks() == before,
           "scenes_updated": sorted(scenes), "textures": sorted(m.name for m in gathered.mesh.materials if m.texture)}
    import addon_utils

    addon_utils.disable("cycles", default_set=True)
    warnings = captured_warnings(NAME + ".addon")
    material = _bsdf_material("diffuse", "ShaderNodeBsdfDiffuse", image)
    material.diffuse_color = VIEWPORT_COLOUR  # not Blender's default: what the row keeps is this
    plane = _plane("diffuse", 5, material)
    gathered = gathering.gather(bpy.context, [plane])
    row = gathered.mesh.materials[0]
    out["cycles_disabled"] = {"cycles": hasattr(bpy.context.scene, "cycles"), "warnings": warnings,
                              "bakes": len(gathered.cycles_bakes), "row": [row.name, list(row.base_color), row.texture],
                              "viewport_colour": list(material.diffuse_color)}
    return out


if __name__ == "__main__":
    repo_dir, check, work_dir, *extra = sys.argv[1:]
    result = globals()[f"check_{check}"](repo_dir, work_dir, *extra)
    print(json.dumps(result))
    blender_preview.exit_process(0)
