"""Checks of what a bake from Blender takes, in the real bpy module, one per subprocess
(tests/blender/test_addon_scenes.py runs them):

    python tests/blender/blender_scene_checks.py REPO_DIR CHECK WORK_DIR

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.

Blender's own count, read here independently of the add-on: the loop triangles of every instance of
type MESH the evaluated depsgraph lists (what the viewport draws), and for curves, text, surfaces
and metaballs also the object's own evaluated mesh (`to_mesh`), which must count them once.
"""
from __future__ import annotations

import contextlib
import importlib
import io
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import bpy

import blender_preview

NAME = "bl_ext.r.hlod"
CURVE_LIKE = ("Ring", "Text", "Surface", "Meta")  # objects whose mesh Blender makes from curve data
HIDDEN = ("HiddenEye", "HiddenViewport", "InHiddenCollection")


def _add(operator: str, name: str, **options):
    """Run bpy.ops.<operator> (e.g. "mesh.primitive_cube_add") and name the object it made."""
    group, op = operator.split(".")
    getattr(getattr(bpy.ops, group), op)(**options)
    obj = bpy.context.active_object
    obj.name = name
    return obj


def _link(name: str, data, location=(0.0, 0.0, 0.0), collection=None):
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def _mesh(name: str, vertices, faces, edges=()):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(vertices, list(edges), faces)
    return mesh


def _library_collection(work: Path):
    """A collection "LibRock" (a cube) written to WORK/library.blend and linked from it."""
    rock = bpy.data.collections.new("LibRock")
    _link("Rock", _mesh("Rock", [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)],
                        [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]),
          collection=rock)
    path = work / "library.blend"
    bpy.data.libraries.write(str(path), {rock})
    for obj in list(rock.objects):
        bpy.data.objects.remove(obj)
    bpy.data.collections.remove(rock)
    with bpy.data.libraries.load(str(path), link=True) as (_, linked):
        linked.collections = ["LibRock"]
    return linked.collections[0]


def _geometry_nodes(obj, *, realize: bool) -> None:
    """A modifier that puts an ico sphere on every point of `obj` (instances, or realised)."""
    tree = bpy.data.node_groups.new(obj.name + " tree", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = tree.nodes, tree.links
    given, out = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    on_points, ico = nodes.new("GeometryNodeInstanceOnPoints"), nodes.new("GeometryNodeMeshIcoSphere")
    ico.inputs["Radius"].default_value = 0.2
    links.new(given.outputs[0], on_points.inputs["Points"])
    links.new(ico.outputs["Mesh"], on_points.inputs["Instance"])
    made = on_points.outputs["Instances"]
    if realize:
        realized = nodes.new("GeometryNodeRealizeInstances")
        links.new(made, realized.inputs[0])
        made = realized.outputs[0]
    join = nodes.new("GeometryNodeJoinGeometry")
    links.new(made, join.inputs[0])
    links.new(given.outputs[0], join.inputs[0])
    links.new(join.outputs[0], out.inputs[0])
    obj.modifiers.new("points", "NODES").node_group = tree


def _kinds_scene(work: Path) -> dict:
    """Every kind of geometry the bake takes, every kind it skips, and hidden objects; returns the
    triangle counts known by construction."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    cube = _add("mesh.primitive_cube_add", "ArrayMirrorSub")  # 6 quads x3 (array) x2 (mirror) x4 (subdivision)
    cube.shape_key_add(name="Basis")
    key = cube.shape_key_add(name="Lean")
    key.data[0].co = (1.5, 1.5, 1.5)
    key.value = 0.5
    cube.modifiers.new("array", "ARRAY").count = 3
    cube.modifiers.new("mirror", "MIRROR")
    cube.modifiers.new("smooth", "SUBSURF").levels = 1
    _add("mesh.primitive_cube_add", "MirroredCube", location=(8, 0, 0)).scale = (-1.0, 1.0, 1.0)
    _add("curve.primitive_bezier_circle_add", "Ring", location=(0, 6, 0)).data.bevel_depth = 0.1
    _add("curve.primitive_bezier_curve_add", "BareCurve", location=(0, 8, 0))  # a line: no faces
    _add("object.text_add", "Text", location=(0, 10, 0)).data.body = "Hi"
    _add("surface.primitive_nurbs_surface_sphere_add", "Surface", location=(4, 6, 0))
    for name, x in (("Meta", 8.0), ("Meta.001", 8.6)):  # one family: Meta's mesh holds both balls
        ball = bpy.data.metaballs.new(name)
        ball.elements.new()
        _link(name, ball, (x, 6.0, 0.0))
    rig = _add("object.armature_add", "Rig", location=(12, 0, 0))
    skinned = _add("mesh.primitive_cylinder_add", "Skinned", location=(12, 0, 1))
    skinned.modifiers.new("pose", "ARMATURE").object = rig
    skinned.vertex_groups.new(name="Bone").add(list(range(len(skinned.data.vertices))), 1.0, "REPLACE")
    rig.pose.bones["Bone"].rotation_mode = "XYZ"
    rig.pose.bones["Bone"].rotation_euler = (0.6, 0.0, 0.0)
    _link("Loose", _mesh("Loose", [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0), (1, 1, 0), (5, 5, 0)],
                         [(0, 1, 3), (1, 2, 4)], edges=[(0, 1), (3, 5)]), (0, -5, 0))
    _link("ZeroArea", _mesh("ZeroArea", [(0, 0, 0), (1, 0, 0), (2, 0, 0), (0, 1, 0)], [(0, 1, 2), (0, 1, 3)]),
          (3, -5, 0))
    _link("EmptyMesh", bpy.data.meshes.new("EmptyMesh"), (0, -8, 0))
    _add("mesh.primitive_grid_add", "BigGrid", x_subdivisions=257, y_subdivisions=257, size=4, location=(0, -14, 0))
    inner = bpy.data.collections.new("Inner")  # nested collection instances: Outer holds two of Inner
    _link("InnerCube", _mesh("InnerCube", [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)], [(0, 1, 3, 2)]),
          collection=inner)
    outer = bpy.data.collections.new("Outer")
    for i in range(2):
        _link(f"InnerInstance{i}", None, (2.0 * i, 0.0, 0.0), outer).instance_collection = inner
        outer.objects[f"InnerInstance{i}"].instance_type = "COLLECTION"
    top = _link("OuterInstance", None, (0.0, 16.0, 0.0))
    top.instance_type, top.instance_collection = "COLLECTION", outer
    rock = _link("LibraryInstance", None, (6.0, 16.0, 0.0))
    rock.instance_type, rock.instance_collection = "COLLECTION", _library_collection(work)
    for name, x, realize in (("NodesInstances", 16.0, False), ("NodesRealized", 19.0, True)):
        _geometry_nodes(_add("mesh.primitive_plane_add", name, location=(x, 0, 0)), realize=realize)
    _link("Points", bpy.data.pointclouds.new("Points"))
    _link("Fog", bpy.data.volumes.new("Fog"))
    _link("Sun", bpy.data.lights.new("Sun", "SUN"))
    _link("Cam", bpy.data.cameras.new("Cam"))
    _add("object.grease_pencil_add" if bpy.app.version >= (4, 3, 0) else "object.gpencil_add", "Sketch", type="EMPTY")
    _add("mesh.primitive_cube_add", "HiddenEye", location=(20, 5, 0)).hide_set(True)
    _add("mesh.primitive_cube_add", "HiddenViewport", location=(22, 5, 0)).hide_viewport = True
    hidden = bpy.data.collections.new("HiddenCollection")
    scene.collection.children.link(hidden)
    _link("InHiddenCollection", _mesh("Tri", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)]), (24, 5, 0), hidden)
    bpy.context.view_layer.layer_collection.children["HiddenCollection"].exclude = True
    bpy.context.view_layer.update()
    return {"ArrayMirrorSub": 6 * 3 * 2 * 4 * 2, "MirroredCube": 12, "Loose": 2, "ZeroArea": 2, "EmptyMesh": 0,
            "BigGrid": 2 * 257 * 257, "OuterInstance": 2 * 2, "LibraryInstance": 12,
            "NodesInstances": 2 + 4 * 20, "NodesRealized": 2 + 4 * 20, "BareCurve": 0}


def _blender_counts() -> tuple[dict[str, int], dict[str, int]]:
    """Per chosen object (instancer, else itself): the loop triangles of its MESH instances in the
    evaluated depsgraph; and, for CURVE_LIKE, its own evaluated mesh's loop triangles."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    drawn: dict[str, int] = {}
    for inst in depsgraph.object_instances:
        owner = inst.parent.original if inst.is_instance and inst.parent is not None else inst.object.original
        drawn.setdefault(owner.name, 0)
        if inst.object.type == "MESH":
            drawn[owner.name] += len(inst.object.to_mesh().loop_triangles)
            inst.object.to_mesh_clear()
    converted = {}
    for name in CURVE_LIKE:
        evaluated = bpy.data.objects[name].evaluated_get(depsgraph)
        converted[name] = len(evaluated.to_mesh().loop_triangles)
        evaluated.to_mesh_clear()
    return drawn, converted


def _outward(mesh, centre) -> bool:
    """Every face of a convex mesh faces away from its centre (3,)."""
    p = mesh.positions[mesh.faces].astype(np.float64)
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return bool(np.all(np.einsum("ij,ij->i", normal, p.mean(axis=1) - centre) > 0))


def _cli(cli, *argv: str) -> tuple[int, dict, list[str]]:
    """The background command in this process: (status, JSON summary, stderr lines)."""
    with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.redirect_stderr(io.StringIO()) as err:
        status = cli.execute(list(argv))
    return status, json.loads(out.getvalue().strip().splitlines()[-1]), err.getvalue().splitlines()


def check_kinds(repo, work) -> dict:
    """Each kind against Blender's count (module notes), per object through gather and in
    all through the background command's bake (its input_tris), what it skips and names, hidden
    objects with and without --include-hidden, and the panel's count of what a bake would take."""
    work = Path(work)
    known = _kinds_scene(work)  # factory settings first: they would disable the add-on
    blender_preview.enable_from_repo(repo)
    gathering = importlib.import_module(NAME + ".addon.scene.gather")
    bake_plan = importlib.import_module(NAME + ".addon.bake.plan")
    cli = importlib.import_module(NAME + ".addon.cli")
    drawn, converted = _blender_counts()
    ours = {}
    for name in sorted(drawn):
        try:
            ours[name] = int(gathering.gather(bpy.context, [bpy.data.objects[name]]).mesh.faces.shape[0])
        except Exception as exc:  # noqa: BLE001 - the message is part of the result
            ours[name] = f"{type(exc).__name__}: {exc}"
    mirrored = gathering.gather(bpy.context, [bpy.data.objects["MirroredCube"]]).mesh
    every = list(bpy.context.scene.objects)
    bpy.ops.object.select_all(action="SELECT")
    bpy.context.scene.hlod.source = "SELECTED"
    plan = bake_plan.count_line(bpy.context)
    layers_before = [layer.name for layer in bpy.context.scene.view_layers]
    # what is gathered, counted and named is checked, not the levels: one node (a target over the scene's
    # triangles), baked in this process (--jobs 1)
    bake = ("bake", "--target-tris", str(10 * sum(drawn.values())), "--jobs", "1")
    status, summary, stderr = _cli(cli, *bake, "-o", str(work / "kinds.hlod"))
    status_h, summary_h, stderr_h = _cli(cli, *bake, "--include-hidden", "-o", str(work / "hidden.hlod"))
    return {"known": known, "drawn": drawn, "converted": converted, "ours": ours, "objects": len(every),
            "mirrored_outward": _outward(mirrored, np.array([8.0, 0.0, 0.0])),
            "plan": plan, "cli": {"status": status, "summary": summary, "stderr": stderr},
            "cli_hidden": {"status": status_h, "summary": summary_h, "stderr": stderr_h},
            "layers_before": layers_before, "layers_after": [layer.name for layer in bpy.context.scene.view_layers],
            "still_hidden": [bpy.data.objects["HiddenEye"].hide_get(), bpy.data.objects["HiddenViewport"].hide_viewport,
                             bpy.context.view_layer.layer_collection.children["HiddenCollection"].exclude]}


def check_uv_maps(repo, work) -> dict:
    """A textured quad with two UV maps, the first active in the editor, the second the active
    render map (what Blender renders and the viewport's texture shows): the bake's UVs and the
    meta's map name are the render map's."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender_preview.enable_from_repo(repo)
    gathering = importlib.import_module(NAME + ".addon.scene.gather")
    quad = _link("Quad", _mesh("Quad", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)]))
    material = bpy.data.materials.new("Paint")
    quad.data.materials.append(material)
    for name, uv in (("Edit", (0.125, 0.25)), ("Render", (0.75, 0.5))):
        layer = quad.data.uv_layers.new(name=name)
        for loop in layer.data:
            loop.uv = uv
    quad.data.uv_layers["Edit"].active = True
    quad.data.uv_layers["Render"].active_render = True
    gathered = gathering.gather(bpy.context, [quad])
    mesh, attributes = gathered.mesh, gathered.attributes
    return {"uvs": np.unique(mesh.uvs, axis=0).tolist(), "attributes": attributes,
            "active": quad.data.uv_layers.active.name}


def check_textures_beside(repo, work) -> dict:
    """A quad whose Base Color is a generated image through a Hue/Saturation node, baked by the
    background command with --format hlod 3dtiles: the texture is written beside the .hlod
    (OUT.textures/), the file's material refers to it, and the tileset carries it."""
    work = Path(work)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender_preview.enable_from_repo(repo)
    cli = importlib.import_module(NAME + ".addon.cli")
    hlod_file = importlib.import_module(NAME + ".hlod_core.io.hlod_file")
    quad = _link("Quad", _mesh("Quad", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)]))
    quad.data.uv_layers.new(name="UVMap")
    image = bpy.data.images.new("Grid", 16, 16)
    image.generated_type = "COLOR_GRID"
    material = bpy.data.materials.new("Shifted")
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    texture, hue = nodes.new("ShaderNodeTexImage"), nodes.new("ShaderNodeHueSaturation")
    texture.image = image
    hue.inputs["Hue"].default_value = 0.3
    links.new(texture.outputs["Color"], hue.inputs["Color"])
    links.new(hue.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
    quad.data.materials.append(material)
    status, summary, stderr = _cli(cli, "bake", "--format", "hlod", "3dtiles", "-o", str(work / "quad.hlod"))
    textures = sorted(p.name for p in (work / "quad.textures").iterdir()) if (work / "quad.textures").is_dir() else []
    baked = hlod_file.load(work / "quad.hlod") if status == 0 else None
    tiles = work / "quad_3dtiles"
    material_images = importlib.import_module(NAME + ".addon.materials.images").material_images
    first = material_images(baked.materials)[0] if baked is not None else None
    hue.inputs["Hue"].default_value = 0.7  # the same material re-baked: new pixels under the same name
    status_again = _cli(cli, "bake", "-o", str(work / "quad.hlod"))[0]
    again = material_images(hlod_file.load(work / "quad.hlod").materials)[0]
    published = {p.name: p.read_bytes() for p in (work / "quad.textures").iterdir()} if textures else {}
    # a bake that fails after its textures are made (its cache folder is a file) leaves OUT.textures as it was
    hue.inputs["Hue"].default_value = 0.2
    (work / "quad.hlod.cache").rename(work / "cache.moved")
    (work / "quad.hlod.cache").write_text("not a folder")
    failed = _cli(cli, "bake", "-o", str(work / "quad.hlod"))
    return {"status": status, "stderr": stderr, "textures": textures,
            "material_texture": baked.materials[0].texture if baked is not None else None,
            "tile_images": sorted(p.name for p in tiles.rglob("*.png")) if tiles.is_dir() else [],
            "status_again": status_again, "preview_changed": first is not None and not np.array_equal(first, again),
            "preview_again_equals_file": bool(np.array_equal(again, _png_rgba(work / "quad.textures" / textures[0])))
            if textures else False,
            "failed_status": failed[0], "failed_error": failed[1]["files"][0].get("error"),
            "textures_kept": published != {} and published == {p.name: p.read_bytes()
                                                                for p in (work / "quad.textures").iterdir()},
            "leftovers": sorted(p.name for p in work.iterdir() if p.name.startswith("."))}


def _png_rgba(path: Path) -> np.ndarray:
    """A PNG's pixels as (h, w, 4) uint8 RGBA, top row first (the extension's own reader)."""
    image_rgba8 = importlib.import_module(NAME + ".addon.materials.images").image_rgba8
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        return image_rgba8(image)
    finally:
        bpy.data.images.remove(image)


def check_udim(repo, work) -> dict:
    """A quad whose Image Texture is a UDIM image of two tiles (1001 red, 1002 green, files on
    disk), baked by the background command: one warning naming the material, the image and its
    tiles, and the texture written from tile 1001."""
    work = Path(work)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender_preview.enable_from_repo(repo)
    cli = importlib.import_module(NAME + ".addon.cli")
    hlod_file = importlib.import_module(NAME + ".hlod_core.io.hlod_file")
    for number, colour in ((1001, (1.0, 0.0, 0.0, 1.0)), (1002, (0.0, 1.0, 0.0, 1.0))):
        tile = bpy.data.images.new(f"tile {number}", 4, 4)
        tile.pixels.foreach_set(np.tile(np.array(colour, np.float32), 16))
        tile.filepath_raw, tile.file_format = str(work / f"paint.{number}.png"), "PNG"
        tile.save()
        bpy.data.images.remove(tile)
    image = bpy.data.images.load(str(work / "paint.1001.png"))
    image.source = "TILED"
    quad = _link("Quad", _mesh("Quad", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)]))
    quad.data.uv_layers.new(name="UVMap")
    material = bpy.data.materials.new("Painted")
    material.use_nodes = True
    texture = material.node_tree.nodes.new("ShaderNodeTexImage")
    texture.image = image
    base_colour = material.node_tree.nodes["Principled BSDF"].inputs["Base Color"]
    material.node_tree.links.new(texture.outputs["Color"], base_colour)
    quad.data.materials.append(material)
    status, _, stderr = _cli(cli, "bake", "-o", str(work / "quad.hlod"))
    baked = hlod_file.load(work / "quad.hlod") if status == 0 else None
    texture_file = baked.materials[0].texture if baked is not None else None
    return {"status": status, "stderr": stderr, "tiles": [t.number for t in image.tiles],
            "texture": texture_file,
            "texture_rgba": np.unique(_png_rgba(Path(texture_file)).reshape(-1, 4), axis=0).tolist()
            if texture_file else None}


def check_colour_attributes(repo, work) -> dict:
    """Four quads, each with one colour attribute of another domain and type (POINT and CORNER, FLOAT
    and BYTE colour), set from known linear colours: per quad, the colours the bake reads against
    the set ones (a byte colour is stored as 8-bit sRGB, so it comes back within its step)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    blender_preview.enable_from_repo(repo)
    gathering = importlib.import_module(NAME + ".addon.scene.gather")
    rng = np.random.default_rng(7)
    out = {}
    for i, (domain, kind) in enumerate((("POINT", "FLOAT_COLOR"), ("POINT", "BYTE_COLOR"),
                                        ("CORNER", "FLOAT_COLOR"), ("CORNER", "BYTE_COLOR"))):
        quad = _link(f"{domain} {kind}", _mesh("Quad", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)]),
                     (2.0 * i, 0.0, 0.0))
        attribute = quad.data.color_attributes.new("Paint", kind, domain)
        colours = np.ones((len(attribute.data), 4), np.float32)
        colours[:, :3] = rng.uniform(0.05, 1.0, (len(attribute.data), 3))
        attribute.data.foreach_set("color", colours.ravel())
        quad.data.color_attributes.active_color = attribute
        mesh = gathering.gather(bpy.context, [quad]).mesh
        # what the bake holds per triangle corner, against the set colour of that corner's loop / vertex
        loops = np.empty(len(quad.data.loop_triangles) * 3, np.int64)
        quad.data.loop_triangles.foreach_get("loops" if domain == "CORNER" else "vertices", loops)
        got = mesh.colors[mesh.faces.ravel()]
        out[f"{domain} {kind}"] = float(np.abs(got - colours[loops]).max()) if mesh.colors is not None else None
    return out


def check_batch(repo, work) -> dict:
    """A batch of files where some cannot bake: one stderr line each naming the file and the reason,
    no traceback, and the files after them still bake."""
    work = Path(work)
    bpy.ops.wm.read_factory_settings(use_empty=True)  # first: it would disable the add-on
    blender_preview.enable_from_repo(repo)
    cli = importlib.import_module(NAME + ".addon.cli")
    _link("Light", bpy.data.lights.new("Light", "POINT"))
    bpy.ops.wm.save_as_mainfile(filepath=str(work / "lights_only.blend"))
    _add("mesh.primitive_ico_sphere_add", "Ball")
    bpy.ops.wm.save_as_mainfile(filepath=str(work / "good.blend"))
    (work / "not_a_blend.blend").write_text("this is not a .blend file\n")
    files = [str(work / name) for name in ("not_a_blend.blend", "lights_only.blend", "missing.blend", "good.blend")]
    status, summary, stderr = _cli(cli, "bake", *files, "-o", str(work / "out"))
    return {"status": status, "summary": summary, "stderr": stderr,
            "good_written": (work / "out" / "good.hlod").is_file()}


def _run_cli(cli, *argv: str) -> tuple[int, list[str], list[str]]:
    """The background command in this process: (status, stdout lines, stderr lines)."""
    with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.redirect_stderr(io.StringIO()) as err:
        status = cli.execute(list(argv))
    return status, out.getvalue().splitlines(), err.getvalue().splitlines()


def _tileset_place(folder: Path):
    """(extras.place or None, the root transform's translation) of an export, or None without one."""
    file = folder / "tileset.json"
    if not file.is_file():
        return None
    document = json.loads(file.read_text())
    return document.get("extras", {}).get("place"), document["root"]["transform"][12:15]


def check_place(repo, work) -> dict:
    """Where a 3D Tiles export from Blender stands: a scene with BlenderGIS's latitude/longitude is
    placed by the background bake and by the Export button; --place wins; the panel's typed place
    (text: double precision) and its Local Frame; a projected CRS refused with one line and nothing
    written, by the button and by the background export."""
    work = Path(work)
    bpy.ops.wm.read_factory_settings(use_empty=True)  # first: it would disable the add-on
    blender_preview.enable_from_repo(repo)
    cli = importlib.import_module(NAME + ".addon.cli")
    place_line = importlib.import_module(NAME + ".addon.scene.place").place_line
    _add("mesh.primitive_ico_sphere_add", "Ball", location=(3.0, 4.0, 5.0))
    scene = bpy.context.scene
    out = {"line_unplaced": place_line(scene)}
    scene["latitude"], scene["longitude"] = 47.3769, 8.5417  # BlenderGIS's keys (degrees)
    scene["SRID"], scene["crs x"], scene["crs y"] = "EPSG:2056", 2683000.0, 1248000.0
    out["line_scene"] = place_line(scene)
    status, stdout, stderr = _run_cli(cli, "bake", "-o", str(work / "ball.hlod"), "--format", "hlod", "3dtiles",
                                      "--target-tris", "64")
    out["bake"] = (status, stderr)
    out["bake_place"] = _tileset_place(work / "ball_3dtiles")
    status, stdout, stderr = _run_cli(cli, "export", str(work / "ball.hlod"), "--format", "3dtiles", "-o",
                                      str(work / "given"), "--place=-122.4194,37.7749,16,30")
    out["given_place"] = (status, _tileset_place(work / "given"))
    props = scene.hlod
    props.file = str(work / "ball.hlod")

    def button(folder: str):
        try:
            result = sorted(bpy.ops.hlod.export(filepath=str(work / folder), format="3DTILES"))
        except RuntimeError as exc:
            result = [" ".join(str(exc).split())]
        return result, _tileset_place(work / folder)

    out["button_scene"] = button("button_scene")
    props.place_mode = "MANUAL"
    props.place_longitude, props.place_latitude = "-73.98513", "40.75890"
    props.place_height, props.place_heading = 12.5, 90
    out["line_manual"] = place_line(scene)
    out["button_manual"] = button("button_manual")
    props.place_mode = "NONE"
    out["button_none"] = button("button_none")
    props.place_mode = "SCENE"
    del scene["latitude"], scene["longitude"]  # BlenderGIS's projected CRS alone: cannot be read
    out["line_projected"] = place_line(scene)
    out["button_projected"] = button("button_projected")
    status, stdout, stderr = _run_cli(cli, "export", str(work / "ball.hlod"), "--format", "3dtiles", "-o",
                                      str(work / "projected"))
    out["cli_projected"] = (status, stderr, (work / "projected").exists())
    status, stdout, stderr = _run_cli(cli, "export", str(work / "ball.hlod"), "--format", "3dtiles", "-o",
                                      str(work / "bad"), "--place=0,95,0")
    out["cli_bad_latitude"] = (status, stderr, (work / "bad").exists())
    # quantized tile content, from the background command and from the button
    status, stdout, stderr = _run_cli(cli, "export", str(work / "ball.hlod"), "--format", "3dtiles", "-o",
                                      str(work / "quantized"), "--place=none", "--mesh", "quantized")
    props.place_mode = "NONE"
    bpy.ops.hlod.export(filepath=str(work / "button_quantized"), format="3DTILES", mesh="quantized")
    out["quantized"] = [status, *(_required_extensions(work / name) for name in ("quantized", "button_quantized"))]
    # a node's leaves in one tile, from the background command and from the button
    status, stdout, stderr = _run_cli(cli, "export", str(work / "ball.hlod"), "--format", "3dtiles", "-o",
                                      str(work / "merged"), "--place=none", "--merge-leaves")
    bpy.ops.hlod.export(filepath=str(work / "button_merged"), format="3DTILES", merge_leaves=True)
    out["merged"] = [status, *(sorted(p.name for p in (work / name / "tiles").glob("*.glb"))
                               for name in ("merged", "button_merged", "button_quantized"))]
    return out


def _required_extensions(folder: Path) -> list:
    """The root tile GLB's extensionsRequired (empty for a plain one, None without an export)."""
    glb = folder / "tiles" / "0.glb"
    if not glb.is_file():
        return None
    data = glb.read_bytes()
    return json.loads(data[20:20 + int.from_bytes(data[12:16], "little")]).get("extensionsRequired", [])


if __name__ == "__main__":
    repo_dir, check, work_dir = sys.argv[1:4]
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    result = globals()[f"check_{check}"](repo_dir, work_dir, *sys.argv[4:])
    print("\n" + json.dumps(result, default=str))  # on a line of its own: Blender may leave a report unterminated
    blender_preview.exit_process(0)  # bpy 4.2 can crash at exit (see blender_preview.exit_process)
