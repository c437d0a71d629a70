"""Builds the textured, multi-material test scene in the bpy module and writes it with Blender's own
exporters (issue 13). Run: `.venv/bin/python tests/scenes/textured_scene.py OUTDIR [--scale small|full]`.

The scene, made with Blender's own tools (operators, modifiers, node materials), deterministic:
- a ground grid (material "Ground": a checker PNG into Base Color; the grid primitive's UVs) with
  an active corner-domain byte colour attribute "Tint" of varying colours;
- 16 linked duplicates of one two-material house mesh (walls: "Wall", a brick PNG; roof: "Roof",
  a plain base colour, metallic 0.1, roughness 0.7), UVs from `uv.smart_project`, parented to an
  empty "Village" (turned and moved, so parents must be applied) and one of them mirrored (scale
  x = -1, so a reader must flip its winding);
- a few monkeys sharing a material ("Monkey": Blender's generated colour-grid image saved as PNG,
  into Base Color; the primitive's UVs) with a Subdivision Surface modifier and an active
  point-domain float colour attribute "Paint".

Written to OUTDIR: textures/{checker,bricks,color_grid}.png; textured.blend (images referenced by
relative path); textured.glb (bpy.ops.export_scene.gltf, GLB, modifiers applied, images embedded,
active colour attribute as COLOR_0); separate/textured.gltf + .bin + textures/*.png (the same
export as glTF with external buffer and images); textured.obj + textured.mtl (bpy.ops.wm.obj_export, UVs and
materials, map_Kd relative to the OBJ); scene.json: the facts from Blender's evaluated depsgraph
(triangles, per material too, world bounding box in Blender's Z-up axes, triangle area, counts of
objects, meshes, materials, textures). Scales: `small` (~50k triangles, the tests'), `full`
(~280k triangles: several octree levels at 2000 triangles per node).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import bpy
import numpy as np

#: Per scale: ground grid subdivisions per side, cuts per house edge, monkeys, subdivision levels.
SCALES = {
    "small": {"ground_cuts": 100, "house_cuts": 6, "monkeys": 4, "monkey_levels": 1},
    "full": {"ground_cuts": 250, "house_cuts": 12, "monkeys": 7, "monkey_levels": 2},
}
HOUSES = 16
TEXTURE_PIXELS = 256
SEED = 13


def main(argv: list[str]) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outdir", type=Path)
    parser.add_argument("--scale", choices=sorted(SCALES), default="small")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    out = args.outdir.resolve()
    (out / "textures").mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    rng = np.random.default_rng(SEED)
    build_scene(out, rng, **SCALES[args.scale])
    blend, glb, obj = out / "textured.blend", out / "textured.glb", out / "textured.obj"
    gltf = out / "separate" / "textured.gltf"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), relative_remap=True, compress=False)
    bpy.ops.export_scene.gltf(filepath=str(glb), export_format="GLB", export_apply=True,
                              export_vertex_color="ACTIVE", export_yup=True)
    bpy.ops.export_scene.gltf(filepath=str(gltf), export_format="GLTF_SEPARATE", export_apply=True,
                              export_vertex_color="ACTIVE", export_yup=True, export_texture_dir="textures")
    bpy.ops.wm.obj_export(filepath=str(obj), export_uv=True, export_materials=True, export_normals=True,
                          apply_modifiers=True, path_mode="RELATIVE")
    facts = scene_facts()
    facts.update(scale=args.scale, seed=SEED, blend=blend.name, glb=glb.name, obj=obj.name, mtl="textured.mtl",
                 gltf=str(gltf.relative_to(out)),
                 textures=sorted(p.name for p in (out / "textures").glob("*.png")))
    (out / "scene.json").write_text(json.dumps(facts, indent=1) + "\n")
    print(json.dumps({"outdir": str(out), "triangles": facts["triangles"],
                      "seconds": round(time.perf_counter() - started, 2)}))
    return facts


# --- images and materials ------------------------------------------------------------------------

def save_png(out: Path, name: str, rgba: np.ndarray) -> bpy.types.Image:
    """Write (h, w, 4) float pixels (sRGB-encoded, bottom row first as Blender stores them) as
    out/textures/NAME.png through a Blender image, and return the PNG loaded as a file image."""
    h, w = rgba.shape[:2]
    image = bpy.data.images.new(name + "_pixels", w, h, alpha=True)
    image.pixels.foreach_set(np.ascontiguousarray(rgba, np.float32).ravel())
    path = out / "textures" / f"{name}.png"
    image.filepath_raw = str(path)
    image.file_format = "PNG"
    image.save()
    bpy.data.images.remove(image)
    return bpy.data.images.load(str(path), check_existing=False)


def checker_pixels(rng: np.random.Generator) -> np.ndarray:
    n = TEXTURE_PIXELS
    y, x = np.mgrid[0:n, 0:n] / n
    cell = ((x * 8).astype(int) + (y * 8).astype(int)) % 2
    a, b = np.array([0.85, 0.82, 0.7]), np.array([0.25, 0.45, 0.2])
    rgb = np.where(cell[..., None] == 1, a, b) * (0.85 + 0.15 * x[..., None])
    rgb += rng.normal(0.0, 0.02, rgb.shape)
    return np.dstack([np.clip(rgb, 0, 1), np.ones((n, n))])


def brick_pixels(rng: np.random.Generator) -> np.ndarray:
    n, rows = TEXTURE_PIXELS, 8
    y, x = np.mgrid[0:n, 0:n] / n
    row = (y * rows).astype(int)
    shifted = (x * 4 + 0.5 * (row % 2)) % 1.0
    mortar = ((y * rows) % 1.0 < 0.08) | (shifted < 0.04)
    shade = rng.uniform(0.8, 1.1, (rows, 8))[row, ((x * 4 + 0.5 * (row % 2)) * 2).astype(int) % 8]
    brick = np.array([0.62, 0.25, 0.16]) * shade[..., None]
    rgb = np.where(mortar[..., None], np.array([0.8, 0.78, 0.74]), brick)
    return np.dstack([np.clip(rgb, 0, 1), np.ones((n, n))])


def color_grid_image(out: Path) -> bpy.types.Image:
    """Blender's own generated colour grid, saved as PNG and loaded back as a file image."""
    image = bpy.data.images.new("color_grid_generated", TEXTURE_PIXELS, TEXTURE_PIXELS)
    image.generated_type = "COLOR_GRID"
    pixels = np.empty(TEXTURE_PIXELS * TEXTURE_PIXELS * 4, np.float32)
    image.pixels.foreach_get(pixels)
    bpy.data.images.remove(image)
    return save_png(out, "color_grid", pixels.reshape(TEXTURE_PIXELS, TEXTURE_PIXELS, 4))


def principled_material(name: str, *, base_color=(0.8, 0.8, 0.8, 1.0), image=None, metallic=0.0,
                        roughness=0.5) -> bpy.types.Material:
    """A node material: Principled BSDF, an Image Texture node into Base Color when `image` is given."""
    material = bpy.data.materials.new(name)
    if material.node_tree is None:
        material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    bsdf = next(n for n in nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = base_color
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    material.diffuse_color = base_color
    if image is not None:
        texture = nodes.new("ShaderNodeTexImage")
        texture.image = image
        texture.location = (bsdf.location.x - 300, bsdf.location.y)
        links.new(texture.outputs["Color"], bsdf.inputs["Base Color"])
    return material


# --- objects -------------------------------------------------------------------------------------

def build_scene(out: Path, rng: np.random.Generator, *, ground_cuts: int, house_cuts: int, monkeys: int,
                monkey_levels: int) -> None:
    ground_mat = principled_material("Ground", image=save_png(out, "checker", checker_pixels(rng)), roughness=0.9)
    wall_mat = principled_material("Wall", image=save_png(out, "bricks", brick_pixels(rng)), roughness=0.8)
    roof_mat = principled_material("Roof", base_color=(0.45, 0.08, 0.05, 1.0), metallic=0.1, roughness=0.7)
    monkey_mat = principled_material("Monkey", image=color_grid_image(out), roughness=0.4)

    bpy.ops.mesh.primitive_grid_add(x_subdivisions=ground_cuts, y_subdivisions=ground_cuts, size=80.0,
                                    calc_uvs=True)
    ground = bpy.context.active_object
    ground.name = ground.data.name = "Ground"
    ground.data.materials.append(ground_mat)
    fill_colors(ground.data, rng, name="Tint", domain="CORNER", kind="BYTE_COLOR")

    house_mesh = make_house(house_cuts, wall_mat, roof_mat)
    village = bpy.data.objects.new("Village", None)
    bpy.context.scene.collection.objects.link(village)
    village.location = (-6.0, 4.0, 0.0)
    village.rotation_euler = (0.0, 0.0, math.radians(20.0))
    for i in range(HOUSES):
        house = bpy.data.objects.new(f"House.{i:02d}", house_mesh)  # linked duplicate: one mesh
        bpy.context.scene.collection.objects.link(house)
        house.parent = village
        house.location = (-24.0 + 12.0 * (i % 4), -24.0 + 12.0 * (i // 4), 1.0)
        house.rotation_euler = (0.0, 0.0, math.radians(float(rng.uniform(0.0, 360.0))))
        house.scale = (-1.0 if i == 5 else 1.0, 1.0, 1.0)  # one mirrored instance

    for i in range(monkeys):
        bpy.ops.mesh.primitive_monkey_add(size=3.0, location=(-30.0 + 60.0 * i / max(monkeys - 1, 1), 30.0, 2.5),
                                          rotation=(0.0, 0.0, math.radians(180.0)), calc_uvs=True)
        monkey = bpy.context.active_object
        monkey.name = monkey.data.name = f"Monkey.{i}"
        monkey.data.materials.append(monkey_mat)
        fill_colors(monkey.data, rng, name="Paint", domain="POINT", kind="FLOAT_COLOR")
        modifier = monkey.modifiers.new("Subdivision", "SUBSURF")
        modifier.levels = modifier.render_levels = monkey_levels
        bpy.ops.object.shade_smooth()


def make_house(cuts: int, wall_mat, roof_mat) -> bpy.types.Mesh:
    """One mesh, two materials: subdivided box walls and a four-sided pyramid roof, joined, then
    UV-unwrapped with Smart UV Project. Made from a temporary object, which is removed."""
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 1.5), scale=(6.0, 6.0, 3.0))
    walls = bpy.context.active_object
    walls.data.materials.append(wall_mat)
    subdivide(walls, cuts)
    bpy.ops.mesh.primitive_cone_add(vertices=4, radius1=5.0, radius2=0.0, depth=3.0, location=(0.0, 0.0, 4.5),
                                    rotation=(0.0, 0.0, math.radians(45.0)))
    roof = bpy.context.active_object
    roof.data.materials.append(roof_mat)
    subdivide(roof, cuts)
    bpy.ops.object.select_all(action="DESELECT")
    roof.select_set(True)
    walls.select_set(True)
    bpy.context.view_layer.objects.active = walls
    bpy.ops.object.join()
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.uv.smart_project(angle_limit=math.radians(66.0), island_margin=0.02)
    bpy.ops.object.mode_set(mode="OBJECT")
    mesh = walls.data
    mesh.name = "House"
    bpy.data.objects.remove(walls)
    return mesh


def subdivide(obj, cuts: int) -> None:
    bpy.context.view_layer.objects.active = obj
    bpy.ops.object.mode_set(mode="EDIT")
    bpy.ops.mesh.select_all(action="SELECT")
    bpy.ops.mesh.subdivide(number_cuts=cuts)
    bpy.ops.object.mode_set(mode="OBJECT")


def fill_colors(mesh, rng: np.random.Generator, *, name: str, domain: str, kind: str) -> None:
    """An active colour attribute of smoothly varying colours (from the positions) plus a little noise."""
    attr = mesh.color_attributes.new(name, kind, domain)
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    if domain == "CORNER":
        index = np.empty(len(mesh.loops), np.int32)
        mesh.loops.foreach_get("vertex_index", index)
        co = co[index]
    span = np.ptp(co, axis=0) + 1e-9
    t = (co - co.min(axis=0)) / span
    rgb = 0.55 + 0.45 * np.stack([np.sin(6.0 * t[:, 0]), np.cos(5.0 * t[:, 1]), np.sin(4.0 * (t[:, 0] + t[:, 1]))], 1)
    rgb = np.clip(rgb + rng.normal(0.0, 0.03, rgb.shape), 0.0, 1.0)
    rgba = np.concatenate([rgb, np.ones((rgb.shape[0], 1))], axis=1).astype(np.float32)
    attr.data.foreach_set("color", rgba.ravel())
    mesh.color_attributes.active_color = attr
    mesh.color_attributes.render_color_index = mesh.color_attributes.active_color_index


# --- facts ---------------------------------------------------------------------------------------

def scene_facts() -> dict:
    """Counts from the evaluated depsgraph (modifiers applied): what every reader must find."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    triangles, per_material, area, lows, highs = 0, {}, 0.0, [], []
    mesh_objects = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    for obj in mesh_objects:
        evaluated = obj.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        tris = len(mesh.loop_triangles)
        co = np.empty(len(mesh.vertices) * 3, np.float64)
        mesh.vertices.foreach_get("co", co)
        corners = np.empty(tris * 3, np.int32)
        mesh.loop_triangles.foreach_get("vertices", corners)
        slots = np.empty(tris, np.int32)
        mesh.loop_triangles.foreach_get("material_index", slots)
        world = np.array(evaluated.matrix_world, np.float64)
        p = co.reshape(-1, 3) @ world[:3, :3].T + world[:3, 3]
        t = p[corners.reshape(-1, 3)]
        area += float(0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum())
        lows.append(p.min(axis=0))
        highs.append(p.max(axis=0))
        names = [m.name if m is not None else "" for m in mesh.materials]
        for slot, count in zip(*np.unique(slots, return_counts=True)):
            per_material[names[slot]] = per_material.get(names[slot], 0) + int(count)
        triangles += tris
        evaluated.to_mesh_clear()
    return {"triangles": triangles, "triangles_per_material": dict(sorted(per_material.items())),
            "materials": len(per_material), "objects": len(mesh_objects),
            "meshes": len({o.data.name for o in mesh_objects}),
            "textured_materials": sorted(m.name for m in bpy.data.materials
                                         if any(n.type == "TEX_IMAGE" for n in m.node_tree.nodes)),
            "bbox_min_zup": np.min(lows, axis=0).round(6).tolist(),
            "bbox_max_zup": np.max(highs, axis=0).round(6).tolist(),
            "area": round(area, 6)}


if __name__ == "__main__":
    main(sys.argv[1:])
