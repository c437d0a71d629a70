"""Checks of appearance from Blender (materials, UVs, colours) inside the real bpy module, one per subprocess
(tests/blender/test_addon_appearance.py runs them):

    python tests/blender/blender_appearance_checks.py REPO_DIR CHECK WORK_DIR [ARGUMENT]

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.

The scene (`textured_scene`) is made here with bpy: a checker image generated in Blender and saved
as PNG, two materials (one textured through an Image Texture node into Base Color, one plain), a
two-material house with the default UV map and a corner-domain byte colour attribute, a linked
duplicate of it (mirrored: its winding flips), and two collection instances of a ball with a
point-domain float colour attribute. What the bake must keep is read from the same evaluated
data independently of the add-on (`source_corners`): per material, every triangle corner's world
position, UV and colour.
"""
from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import bpy

import blender_preview
from hlod_core.io import hlod_file
from hlod_core.model.view import View
from hlod_core.report import image_error
from hlod_core.traversal.metrics import sse

NAME = "bl_ext.r.hlod"
CHECKER_PX = 64  # the generated texture's side; 8 x 8 squares of red and blue
CHECKER_SQUARES = 8
RED, BLUE = (1.0, 0.0, 0.0, 1.0), (0.0, 0.0, 1.0, 1.0)  # the same in sRGB and linear
GREEN_BASE = (0.05, 0.55, 0.1, 1.0)  # linear base colour of the plain material
COLOUR_NAME, UV_NAME = "Paint", "UVMap"  # the colour attribute every object has; primitives' UV map
CORNER_TOLERANCE = 1e-4  # world units / UV units / colour: float32 storage relative to the file's origin
CORNER_GRID = 1e-3  # grid on which corners are paired before the tolerance is checked
SIZE = (200, 150)  # offscreen pixels of the preview check
EYE, TARGET = (0.0, -11.0, 6.0), (0.0, 0.0, 0.8)


# --- the scene ------------------------------------------------------------------------------------

def _checker_image(folder: Path):
    """An RGBA checker made in Blender, saved as PNG, and loaded back from that file (source FILE)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "checker.png"
    generated = bpy.data.images.new("checker generated", CHECKER_PX, CHECKER_PX, alpha=True)
    ij = np.indices((CHECKER_PX, CHECKER_PX)) // (CHECKER_PX // CHECKER_SQUARES)
    red = ((ij[0] + ij[1]) % 2 == 0)[..., None]
    pixels = np.where(red, np.array(RED, np.float32), np.array(BLUE, np.float32))
    generated.pixels.foreach_set(pixels.astype(np.float32).ravel())
    generated.filepath_raw, generated.file_format = str(path), "PNG"
    generated.save()
    bpy.data.images.remove(generated)
    image = bpy.data.images.load(str(path))
    image.name = "checker"
    return image


def _principled_material(name: str, *, base=(0.8, 0.8, 0.8, 1.0), metallic=0.0, roughness=0.5, image=None):
    material = bpy.data.materials.new(name)
    if material.node_tree is None:  # Blender 4 makes a material without nodes
        material.use_nodes = True
    principled = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    principled.inputs["Base Color"].default_value = base
    principled.inputs["Metallic"].default_value = metallic
    principled.inputs["Roughness"].default_value = roughness
    if image is not None:
        node = material.node_tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        material.node_tree.links.new(node.outputs["Color"], principled.inputs["Base Color"])
    return material


def _paint(mesh, domain: str, data_type: str, seed: int) -> None:
    """A colour attribute COLOUR_NAME with light random colours (the texture stays visible), active."""
    attribute = mesh.color_attributes.new(COLOUR_NAME, data_type, domain)
    rng = np.random.default_rng(seed)
    colours = np.ones((len(attribute.data), 4), np.float32)
    colours[:, :3] = rng.uniform(0.6, 1.0, (len(attribute.data), 3))
    attribute.data.foreach_set("color", colours.ravel())
    mesh.color_attributes.active_color = attribute


def textured_scene(work: Path) -> dict:
    """The scene of the module notes, all its objects selected; returns their names and materials."""
    bpy.ops.wm.read_homefile(use_empty=True)
    image = _checker_image(work / "textures")
    checker = _principled_material("Checker", roughness=0.6, image=image)
    green = _principled_material("Green", base=GREEN_BASE, metallic=0.3, roughness=0.4)
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(-2.0, 0.0, 1.0))
    house = bpy.context.active_object
    house.name = "house"
    house.data.materials.append(checker)
    house.data.materials.append(green)
    top = np.array([p.normal.z > 0.5 for p in house.data.polygons])
    house.data.polygons.foreach_set("material_index", top.astype(np.int32))  # a green roof
    house.modifiers.new("bevel", "BEVEL").width = 0.1  # a modifier: the evaluated mesh is read
    _paint(house.data, "CORNER", "BYTE_COLOR", seed=1)
    twin = house.copy()  # a linked duplicate: the same mesh data, mirrored
    twin.name = "house twin"
    twin.location, twin.scale = (2.5, 0.0, 1.0), (-1.0, 1.0, 1.0)
    bpy.context.scene.collection.objects.link(twin)
    props = bpy.data.collections.new("props")
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.0, 0.0, 0.0))
    ball = bpy.context.active_object
    ball.name = "ball"
    ball.data.materials.append(green)
    _paint(ball.data, "POINT", "FLOAT_COLOR", seed=2)
    for collection in list(ball.users_collection):
        collection.objects.unlink(ball)
    props.objects.link(ball)
    made = [house, twin]
    for k, x in enumerate((-1.0, 1.0)):
        empty = bpy.data.objects.new(f"ball instance {k}", None)
        empty.instance_type, empty.instance_collection = "COLLECTION", props
        empty.location = (x, -2.5, 0.6)
        bpy.context.scene.collection.objects.link(empty)
        made.append(empty)
    bpy.ops.object.select_all(action="DESELECT")
    for obj in made:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = house
    return {"objects": [o.name for o in made], "materials": ["Checker", "Green"], "image": image.name,
            "texture": bpy.path.abspath(image.filepath)}


# --- what the bake must keep, read independently of the add-on -------------------------------------

def source_corners(objects) -> dict[str, np.ndarray]:
    """Per material name, every triangle corner of the evaluated objects (and their instances):
    (c, 9) float64 rows x, y, z (world), u, v (the active render UV map; 0 without one), r, g, b, a
    (the active colour attribute, linear; white without one). An empty slot counts as "default"."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    wanted = {o.name for o in objects}
    rows: dict[str, list] = {}
    for inst in depsgraph.object_instances:
        owner = inst.parent.original if inst.is_instance and inst.parent is not None else inst.object.original
        if owner.name not in wanted or inst.object.type != "MESH":
            continue
        mesh = inst.object.to_mesh()
        matrix = np.array(inst.matrix_world)
        slots = [slot.material.name if slot.material else "default" for slot in inst.object.material_slots]
        uv_layer = next((layer for layer in mesh.uv_layers if layer.active_render), None)
        colour = mesh.color_attributes.active_color
        for tri in mesh.loop_triangles:
            corners = rows.setdefault(slots[min(tri.material_index, len(slots) - 1)], [])
            for vertex, loop in zip(tri.vertices, tri.loops):
                position = matrix[:3, :3] @ np.array(mesh.vertices[vertex].co) + matrix[:3, 3]
                uv = uv_layer.data[loop].uv if uv_layer is not None else (0.0, 0.0)
                rgba = colour.data[vertex if colour.domain == "POINT" else loop].color if colour else (1.0,) * 4
                corners.append([*position, *uv, *rgba])
        inst.object.to_mesh_clear()
    return {name: np.array(r, np.float64) for name, r in rows.items()}


def hlod_leaf_corners(hlod) -> dict[str, np.ndarray]:
    """The same rows of the baked file's leaves (every source triangle is in exactly one leaf)."""
    from hlod_core.model.hierarchy import node_geometry

    rows: dict[str, list] = {}
    for node in np.flatnonzero(hlod.child_count == 0):
        g = node_geometry(hlod, int(node))
        corners = np.concatenate([g.positions[g.faces].astype(np.float64) + hlod.origin, g.uvs[g.faces],
                                  g.colors[g.faces]], axis=2)
        for material in np.unique(g.face_material):
            name = hlod.materials[material].name
            rows.setdefault(name, []).append(corners[g.face_material == material].reshape(-1, 9))
    return {name: np.concatenate(r) for name, r in rows.items()}


def corners_match(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict:
    """Per material: the same number of corners, and every corner of each set has one in the other
    within CORNER_TOLERANCE in every column (position, UV and colour together, so a UV or colour
    moved to another corner is found). Rows are paired by their values on a CORNER_GRID grid; the
    few a grid line separates from their partner are compared one by one."""
    out = {}
    for name in sorted(set(a) | set(b)):
        x, y = a.get(name, np.zeros((0, 9))), b.get(name, np.zeros((0, 9)))
        x_left, y_left = _unpaired(x, y), _unpaired(y, x)
        worst = max(_farthest(x_left, y_left), _farthest(y_left, x_left))
        out[name] = {"corners": [int(x.shape[0]), int(y.shape[0])], "unpaired": [len(x_left), len(y_left)],
                     "max_difference": worst, "same": bool(x.shape == y.shape and x.size and worst <= CORNER_TOLERANCE)}
    return out


def _grid_keys(rows: np.ndarray) -> np.ndarray:
    cells = np.ascontiguousarray(np.round(rows / CORNER_GRID).astype(np.int64))
    return cells.view(np.dtype((np.void, 8 * rows.shape[1]))).ravel()


def _unpaired(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The rows of x whose grid cell does not hold as many rows of y as of x."""
    kx, ky = _grid_keys(x), _grid_keys(y)
    cells, inverse, counts = np.unique(kx, return_inverse=True, return_counts=True)
    y_cells, y_counts = np.unique(ky, return_counts=True)
    at = np.searchsorted(y_cells, cells).clip(0, max(len(y_cells) - 1, 0))
    same = (y_cells[at] == cells) & (y_counts[at] == counts) if len(y_cells) else np.zeros(len(cells), bool)
    return x[~same[inverse.ravel()]]


def _farthest(x: np.ndarray, y: np.ndarray, chunk: int = 256) -> float:
    """Largest over the rows of x of the distance (max over columns) to the nearest row of y; 0
    without rows in x, inf when y has none for them."""
    if not len(x):
        return 0.0
    if not len(y):
        return float("inf")
    worst = 0.0
    for start in range(0, x.shape[0], chunk):
        rows = x[start:start + chunk]
        distance = np.zeros((rows.shape[0], y.shape[0]))
        for column in range(x.shape[1]):
            np.maximum(distance, np.abs(rows[:, column, None] - y[None, :, column]), out=distance)
        worst = max(worst, float(distance.min(axis=1).max()))
    return worst


def mesh_corners(mesh) -> dict[str, np.ndarray]:
    """The same rows of an extracted TriangleMesh (scene/gather.py gather's mesh)."""
    corners = np.concatenate([mesh.positions[mesh.faces], mesh.uvs[mesh.faces], mesh.colors[mesh.faces]], axis=2)
    return {m.name: corners[mesh.material_ids == i].reshape(-1, 9) for i, m in enumerate(mesh.materials)}


def _vertices(obj) -> int:
    """Vertices of the object's evaluated mesh."""
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    count = len(evaluated.to_mesh().vertices)
    evaluated.to_mesh_clear()
    return count


# --- checks ---------------------------------------------------------------------------------------

def check_extraction(repo, work) -> dict:
    """gather on the textured scene, on a scene without appearance, and on an empty slot."""
    blender_preview.enable_from_repo(repo)
    gather = importlib.import_module(NAME + ".addon.scene.gather").gather
    names = textured_scene(Path(work))
    objects = [bpy.data.objects[name] for name in names["objects"]]
    gathered = gather(bpy.context, objects)
    mesh, attributes = gathered.mesh, gathered.attributes
    out = {"names": names, "attributes": attributes, "tris": mesh.tri_count,
           "materials": [[m.name, list(m.base_color), m.metallic, m.roughness, m.texture, m.image]
                         for m in mesh.materials],
           "corners": corners_match(source_corners(objects), mesh_corners(mesh))}
    # the house's corner colours split vertices: more vertices than the evaluated meshes have
    out["source_vertices"] = sum(_vertices(obj) for obj in objects[:2]) + 2 * _vertices(bpy.data.objects["ball"])
    out["vertices"] = int(mesh.positions.shape[0])
    # two triangles sharing the edge 0-2; vertex 0 has another UV in the second one (a seam), vertex 2
    # has (1, 0.0) and (1, -0.0), which count as one: 4 vertices + 1 for the seam
    uv = np.array([[0, 0], [1, 0], [1, 0.0], [0.5, 0], [1, -0.0], [0, 1]], np.float32)
    parts = importlib.import_module(NAME + ".addon.scene.parts")
    vertex, faces, (split_uv,) = parts.split_corners(np.array([0, 1, 2, 0, 2, 3]), [uv])
    out["split"] = {"vertex": vertex.tolist(), "faces": faces.tolist(), "uv": split_uv.tolist()}
    # images as the preview gives them to the renderer: top row first, a float image's linear 0.5
    # sRGB-encoded (188), a byte image's values as they are
    material_images = importlib.import_module(NAME + ".addon.materials.images")
    rows = {}
    for name, float_buffer in (("byte", False), ("float", True)):
        image = bpy.data.images.new(name, 1, 2, float_buffer=float_buffer)
        image.pixels.foreach_set(np.array([1, 0, 0, 1, 0.5, 0.5, 0.5, 1], np.float32))  # bottom row first
        rows[name] = material_images.image_rgba8(image)[:, 0].tolist()
    out["image_rows"] = rows
    # a plain cube (Blender's default UV map, no material, no colour attribute): no appearance at all
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    plain = bpy.context.active_object
    gathered = gather(bpy.context, [plain])
    bare, attributes = gathered.mesh, gathered.attributes
    out["plain"] = {"appearance": bare.has_appearance, "attributes": attributes,
                    "vertices": int(bare.positions.shape[0]), "uv_layers": len(plain.data.uv_layers)}
    # one material slot empty: its triangles get the default row
    plain.data.materials.append(None)
    plain.data.materials.append(_principled_material("Only", base=(0.2, 0.3, 0.4, 1.0)))
    plain.data.polygons.foreach_set("material_index", np.array([0, 1, 0, 1, 0, 1], np.int32))
    slotted = gather(bpy.context, [plain]).mesh
    out["slotted"] = {"materials": [m.name for m in slotted.materials],
                      "tris_per_material": np.bincount(slotted.material_ids).tolist(),
                      "uvs": slotted.uvs is not None, "colors": slotted.colors is not None}
    return out


def _classify(pixels: np.ndarray) -> dict[str, np.ndarray]:
    """Masks of an offscreen picture (H, W, 4) uint8: the white background, the checker's red and
    blue (the texture), the green material, and grey (an untextured node's default colour)."""
    rgb = pixels[..., :3].astype(np.int64)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return {"background": np.all(rgb >= 250, axis=2),
            "red": (r > 60) & (r > 2 * g) & (r > 2 * b), "blue": (b > 60) & (b > 2 * r) & (b > 2 * g),
            "green": (g > 40) & (g > 1.5 * r) & (g > 1.5 * b),
            "grey": ~np.all(rgb >= 250, axis=2) & (np.abs(r - g) < 8) & (np.abs(g - b) < 12)}


def _screen_boxes(scene, objects, size) -> np.ndarray:
    """(H, W) bool: inside the screen rectangles of the objects' world bounding boxes (scene camera)."""
    from mathutils import Vector

    view, projection = blender_preview.camera_matrices(scene, size)
    mvp = np.array(projection @ view)
    inside = np.zeros((size[1], size[0]), bool)
    for obj in objects:
        corners = np.array([list(obj.matrix_world @ Vector(c)) + [1.0] for c in obj.bound_box])
        clip = corners @ mvp.T
        ndc = clip[:, :2] / clip[:, 3:4]
        x = np.clip(((ndc[:, 0] + 1) * 0.5 * size[0]).round().astype(int), 0, size[0])
        y = np.clip(((ndc[:, 1] + 1) * 0.5 * size[1]).round().astype(int), 0, size[1])
        inside[y.min():y.max() + 1, x.min():x.max() + 1] = True  # rows bottom first, as read_color gives
    return inside


def _preview_picture(package, scene, houses) -> dict:
    """The preview drawn in a GPUOffScreen from the scene camera; its pixel classes."""
    pixels = None
    for _ in range(3):  # the coherent traversal settles on its cut over a few frames
        pixels = blender_preview.draw_offscreen(package, scene, SIZE)
    masks = _classify(pixels)
    textured = masks["red"] | masks["blue"]
    on_houses = _screen_boxes(scene, houses, SIZE)
    drawn = ~masks["background"]
    return {"drawn": int(drawn.sum()), "red": int(masks["red"].sum()), "blue": int(masks["blue"].sum()),
            "green": int(masks["green"].sum()), "grey": int(masks["grey"].sum()),
            "texture_off_houses": int((textured & ~on_houses).sum())}


def check_appearance(repo, work) -> dict:
    """The textured scene baked by the Bake operator; the file's leaves against the source; the
    preview in both modes; Materialize of the root node, in this file and in an empty one."""
    package = blender_preview.enable_from_repo(repo)
    work = Path(work)
    names = textured_scene(work)
    objects = [bpy.data.objects[name] for name in names["objects"]]
    scene = bpy.context.scene
    props = scene.hlod
    props.output_path, props.target_tris = str(work / "textured.hlod"), 300
    props.proxy_materials = False  # the root keeps the source's materials (Materialize's datablocks)
    out = {"bake": sorted(bpy.ops.hlod.bake())}
    hlod = hlod_file.load(bpy.path.abspath(props.file))
    out["file"] = {"nodes": hlod.node_count, "depth": int(hlod.depth.max()), "input_tris": int(hlod.meta["input_tris"]),
                   "uv_map": hlod.meta.get("uv_map"), "color_attribute": hlod.meta.get("color_attribute"),
                   "materials": [[m.name, m.texture, m.image] for m in hlod.materials],
                   "inner_materials": _node_materials(hlod, 0)}
    out["leaves"] = corners_match(source_corners(objects), hlod_leaf_corners(hlod))
    # the preview: GL mode (the renderer, with the images read from bpy) and private mode (gpu module)
    blender_preview.camera(scene, eye=EYE, target=TARGET, lens_mm=35.0)
    blender_preview.init_gpu()
    props.method, props.show_modulation = "coh", False
    bpy.ops.hlod.preview_toggle()
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    houses = [bpy.data.objects["house"], bpy.data.objects["house twin"]]
    out["images"] = {str(k): list(v.shape) for k, v in preview.session.images.items()}
    out["gl"] = _preview_picture(package, scene, houses)
    props.private_context = True
    out["private"] = _preview_picture(package, scene, houses)
    out["private_status"] = props.status
    props.private_context = False
    bpy.ops.hlod.preview_toggle()
    # Materialize of the root node: the source's materials by name, the UV map and the colour attribute
    materials_before = len(bpy.data.materials)
    out["materialize"] = sorted(bpy.ops.hlod.materialize(depth=0))
    out["materialized"] = _materialized("HLOD depth 0")
    out["materials_made"] = len(bpy.data.materials) - materials_before  # 0: the source's own datablocks
    # in an empty file: new Principled materials made from the file's table, the texture from its path
    baked = props.file
    bpy.ops.wm.read_homefile(use_empty=True)  # no "checker" image, no "Checker" or "Green" material
    bpy.context.scene.hlod.file = baked
    out["materialize_empty_file"] = sorted(bpy.ops.hlod.materialize(depth=0))
    out["materialized_new"] = _materialized("HLOD depth 0")
    return out


def _node_materials(hlod, node: int) -> list[str]:
    """Names of the materials of a node's triangles."""
    first, count = int(hlod.tri_offset[node]), int(hlod.tri_count[node])
    return sorted({hlod.materials[int(m)].name for m in np.unique(hlod.tri_material[first:first + count])})


def _materialized(collection: str) -> dict:
    """Slots, UV maps, colour attributes and the materials' Principled inputs of a Materialize result."""
    objects = list(bpy.data.collections[collection].objects)
    materials = {}
    for obj in objects:
        for slot in obj.material_slots:
            material = slot.material
            principled = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
            base = principled.inputs["Base Color"]
            source = base.links[0].from_node if base.is_linked else None
            image = source.image if source is not None and source.type == "TEX_IMAGE" else None
            materials[material.name] = {
                "base_color": [round(c, 4) for c in base.default_value],
                "metallic": round(principled.inputs["Metallic"].default_value, 4),
                "roughness": round(principled.inputs["Roughness"].default_value, 4),
                "texture": bpy.path.abspath(image.filepath) if image is not None else None}
    return {"objects": len(objects),
            "slots": [[s.material.name for s in obj.material_slots] for obj in objects],
            "uv_maps": [[layer.name for layer in obj.data.uv_layers] for obj in objects],
            "colour_attributes": [[(a.name, a.domain, a.data_type) for a in obj.data.color_attributes]
                                  for obj in objects],
            "render_colour": [obj.data.color_attributes.render_color_index for obj in objects],
            "material_index_used": [sorted({p.material_index for p in obj.data.polygons}) for obj in objects],
            "materials": materials}


RENDER_SIZE = (160, 120)  # Cycles on the CPU: a second or two per picture here
RENDER_SAMPLES = 32  # with one seed for both renders; 128 samples moved the PSNR by 0.1 dB
RENDER_TARGET_TRIS = 700  # the root keeps 700 of the scene's 2,008 triangles
# the far view: the whole scene in 160 px; the root node's screen-space error there is below 1 px
FAR_EYE, FAR_TARGET, FAR_LENS_MM = (9.0, -22.0, 11.0), (0.25, -0.6, 0.8), 50.0


BACKGROUND_LEVELS = 8  # a pixel differing from the corner's (the world colour) by more is the scene's


def _render(scene, path: Path) -> np.ndarray:
    """The scene camera's Cycles render (CPU, RENDER_SAMPLES, fixed seed) as (H, W, 3) uint8 sRGB."""
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(str(path))
    values = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(values)  # a PNG: its sRGB bytes / 255
    rgb = values.reshape(image.size[1], image.size[0], -1)[::-1, :, :3]
    bpy.data.images.remove(image)
    return np.round(rgb * 255.0).astype(np.uint8)


def _show(objects, shown: bool) -> None:
    for obj in objects:
        obj.hide_render = not shown


def check_render(repo, work) -> dict:
    """A far view of the textured scene rendered with Cycles from the source objects and from the
    objects Materialize makes of the root node (the source hidden), then again with those objects'
    material slots emptied (what Materialize made before it kept materials: grey objects); PSNR of Y, Cb, Cr
    (hlod_core.report.image_error, the evaluation's measure) of each against the source's render."""
    blender_preview.enable_from_repo(repo)
    work = Path(work)
    names = textured_scene(work)
    scene = bpy.context.scene
    sources = [bpy.data.objects[name] for name in names["objects"]]
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy, sun.rotation_euler = 3.0, (0.6, 0.2, 0.8)
    scene.collection.objects.link(sun)
    if scene.world is None:
        scene.world = bpy.data.worlds.new("world")
    scene.world.color = (0.4, 0.45, 0.5)
    if scene.world.node_tree is not None:  # Blender 5 worlds use nodes: the Background's colour
        background = next(n for n in scene.world.node_tree.nodes if n.type == "BACKGROUND")
        background.inputs["Color"].default_value = (0.4, 0.45, 0.5, 1.0)
    props = scene.hlod
    props.output_path, props.target_tris = str(work / "textured.hlod"), RENDER_TARGET_TRIS
    props.proxy_materials = False  # the far view is the sources' materials on the root's LOD
    out = {"bake": sorted(bpy.ops.hlod.bake())}
    hlod = hlod_file.load(bpy.path.abspath(props.file))
    out["root_tris"], out["input_tris"] = int(hlod.tri_count[0]), int(hlod.meta["input_tris"])
    out["materialize"] = sorted(bpy.ops.hlod.materialize(depth=0))
    materialized = list(bpy.data.collections["HLOD depth 0"].objects)
    blender_preview.camera(scene, eye=FAR_EYE, target=FAR_TARGET, lens_mm=FAR_LENS_MM)
    scene.render.engine = "CYCLES"
    scene.cycles.device, scene.cycles.samples, scene.cycles.seed = "CPU", RENDER_SAMPLES, 0
    scene.render.resolution_x, scene.render.resolution_y = RENDER_SIZE
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    _show(materialized, False)
    source = _render(scene, work / "source.png")
    _show(sources, False)
    _show(materialized, True)
    hlod_render = _render(scene, work / "materialized.png")
    for obj in materialized:
        obj.data.materials.clear()
    grey = _render(scene, work / "grey.png")
    out["psnr"] = image_error.psnr(source, hlod_render).round(2).tolist()
    out["psnr_grey"] = image_error.psnr(source, grey).round(2).tolist()
    out["root_error"] = float(hlod.error[0])
    view, projection = (np.array(m, np.float64) for m in blender_preview.camera_matrices(scene, RENDER_SIZE))
    camera = View(eye=np.array(FAR_EYE, np.float64), view=view, projection=projection, width=RENDER_SIZE[0],
                  height=RENDER_SIZE[1])
    out["root_sse_px"] = float(sse(camera, hlod.error[:1], center=hlod.sphere_center[:1], radius=hlod.sphere_radius[:1],
                                   is_leaf=np.zeros(1, bool))[0])
    scene_pixels = np.any(np.abs(source.astype(int) - source[0, 0].astype(int)) > BACKGROUND_LEVELS, axis=2)
    rows, cols = np.flatnonzero(scene_pixels.any(axis=1)), np.flatnonzero(scene_pixels.any(axis=0))
    crop = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))  # the scene's rectangle
    out["scene_pixels"] = int(scene_pixels.sum())
    out["crop"] = [int(rows[-1] - rows[0] + 1), int(cols[-1] - cols[0] + 1)]
    out["psnr_crop"] = image_error.psnr(source[crop], hlod_render[crop]).round(2).tolist()
    out["psnr_grey_crop"] = image_error.psnr(source[crop], grey[crop]).round(2).tolist()
    return out


def check_shared_scene(repo, work, blend) -> dict:
    """The shared textured scene (tests/scenes/textured_scene.py's .blend: a textured ground with a
    corner colour attribute, 16 linked duplicates of a two-material house under a turned parent, one
    mirrored, monkeys with a modifier and a point colour attribute) baked from Blender with every
    mesh object selected: the file against the source's evaluated data."""
    import time

    blender_preview.enable_from_repo(repo)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    bpy.ops.object.select_all(action="DESELECT")
    for obj in objects:
        obj.select_set(True)
    props = bpy.context.scene.hlod
    props.output_path = str(Path(work) / "shared.hlod")
    started = time.perf_counter()
    out = {"bake": sorted(bpy.ops.hlod.bake()), "bake_seconds": round(time.perf_counter() - started, 2)}
    hlod = hlod_file.load(bpy.path.abspath(props.file))  # stored relative to the .blend where it can be
    leaves = hlod.child_count == 0
    per_material = {}
    for node in np.flatnonzero(leaves):
        first, count = int(hlod.tri_offset[node]), int(hlod.tri_count[node])
        for row, n in zip(*np.unique(hlod.tri_material[first:first + count], return_counts=True)):
            per_material[hlod.materials[int(row)].name] = per_material.get(hlod.materials[int(row)].name, 0) + int(n)
    inner = np.flatnonzero(~leaves)
    out.update(input_tris=int(hlod.meta["input_tris"]), nodes=hlod.node_count, depth=int(hlod.depth.max()),
               materials=sorted(m.name for m in hlod.materials),
               textures=sorted(Path(m.texture).name for m in hlod.materials if m.texture),
               uv_map=hlod.meta.get("uv_map"), color_attribute=hlod.meta.get("color_attribute"),
               leaf_tris_per_material=per_material,
               root_materials=_node_materials(hlod, 0),
               inner_nodes=len(inner), has_uvs=hlod.uvs is not None, has_colors=hlod.colors is not None,
               inner_parts_max=max(len(_node_materials(hlod, int(node))) for node in inner),
               proxy_textures=sorted(Path(m.texture).name for m in hlod.materials
                                     if m.texture and m.name.startswith("HLOD proxy") and Path(m.texture).is_file()))
    out["leaves"] = corners_match(source_corners(objects), hlod_leaf_corners(hlod))
    # the preview's images of the proxies: each the pixels of its own texture file
    images = importlib.import_module(NAME + ".addon.materials.images").material_images(hlod.materials)
    proxies = [row for row, m in enumerate(hlod.materials) if m.name.startswith("HLOD proxy")]
    out["proxy_images_match"] = bool(proxies) and all(
        row in images and np.array_equal(images[row], _png_pixels(hlod.materials[row].texture)) for row in proxies)
    return out


def _png_pixels(path: str) -> np.ndarray:
    """(h,w,4) uint8 RGBA, top row first, of a PNG, read by Blender itself."""
    image = bpy.data.images.load(path, check_existing=False)
    try:
        pixels = np.empty(image.size[0] * image.size[1] * 4, np.float32)
        image.pixels.foreach_get(pixels)
        rgba = pixels.reshape(image.size[1], image.size[0], 4)[::-1]
        return np.round(rgba * 255.0).astype(np.uint8)
    finally:
        bpy.data.images.remove(image)


if __name__ == "__main__":
    repo_dir, check, work_dir, *extra = sys.argv[1:]
    result = globals()[f"check_{check}"](repo_dir, work_dir, *extra)
    print(json.dumps(result))
    blender_preview.exit_process(0)
