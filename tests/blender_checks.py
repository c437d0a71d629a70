"""Checks that run inside the real bpy module, one per subprocess (tests/test_addon.py runs them):

    python tests/blender_checks.py REPO_DIR CHECK WORK_DIR

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.
"""
from __future__ import annotations

import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import blender_preview  # noqa: E402

import bpy  # noqa: E402

NAME = "bl_ext.r.hlod"
OPERATORS = ["bake", "clear", "preview_toggle", "materialize", "export", "benchmark"]


def _registered() -> dict:
    ops = {}
    for op in OPERATORS:
        try:
            getattr(bpy.ops.hlod, op).get_rna_type()
            ops[op] = True
        except KeyError:
            ops[op] = False
    return {"scene_hlod": hasattr(bpy.types.Scene, "hlod"), "operators": ops,
            "panel": hasattr(bpy.types, "HLOD_PT_main"),
            "cli_command": getattr(sys.modules.get(NAME + ".addon"), "_cli_command", None) is not None,
            "handlers": sum(
                1 for h in bpy.app.handlers.load_pre if getattr(h, "__module__", "").startswith(NAME))}


def check_registration(repo, work) -> dict:
    import addon_utils

    package = blender_preview.enable_from_repo(repo)
    out = {"module": package.__name__, "first": _registered()}
    addon_utils.disable(NAME, default_set=True)
    out["disabled"] = _registered()
    package = blender_preview.enable_from_repo(repo)
    out["second"] = _registered()
    package.register()  # registering a registered add-on is safe
    out["register_again"] = _registered()
    addon_utils.disable(NAME, default_set=True)
    package.unregister()  # and so is unregistering an unregistered one
    out["disabled_twice"] = _registered()
    return out


def _box_row_scene():
    """Four subdivided cubes in a row along +y (behind each other seen from -y), an array of two
    more cubes to the side (modifier stack), and two instances of a collection holding a sphere."""
    scene = bpy.context.scene
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    made = []
    for i in range(4):
        bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.0, 4.0 * i, 1.0))
        cube = bpy.context.active_object
        cube.name = f"cube {i}"
        cube.modifiers.new("subdivide", "SUBSURF").levels = 3
        made.append(cube)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(6.0, 0.0, 0.5))
    arrayed = bpy.context.active_object
    arrayed.name = "arrayed"
    arrayed.modifiers.new("array", "ARRAY").count = 3
    made.append(arrayed)
    source = bpy.data.collections.new("sphere source")
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.0, 0.0, 0.0))
    sphere = bpy.context.active_object
    for c in list(sphere.users_collection):
        c.objects.unlink(sphere)
    source.objects.link(sphere)
    for k, x in enumerate((-6.0, -9.0)):
        empty = bpy.data.objects.new(f"sphere instance {k}", None)
        empty.instance_type, empty.instance_collection = "COLLECTION", source
        empty.location = (x, 0.0, 0.5)
        scene.collection.objects.link(empty)
        made.append(empty)
    bpy.ops.object.select_all(action="DESELECT")
    for obj in made:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = made[0]
    # expected triangles: subsurf level 3 of a cube: 6 * 4^3 quads; array of 3 cubes: 3 * 12;
    # UV sphere (32 segments, 16 rings): 32 * 14 quads + 64 triangles, twice
    expected = 4 * 6 * 64 * 2 + 3 * 12 + 2 * (32 * 14 * 2 + 64)
    return made, expected


def _box_row_mesh():
    scene_mesh = importlib.import_module(NAME + ".addon.scene_mesh")
    return scene_mesh.evaluated_mesh(bpy.context, [o for o in bpy.context.scene.objects])


def check_bake(repo, work) -> dict:
    from hlod_core import fileformat

    blender_preview.enable_from_repo(repo)
    made, expected = _box_row_scene()
    before = {o.name: (len(o.data.vertices) if o.type == "MESH" else None, len(o.modifiers)) for o in made}
    props = bpy.context.scene.hlod
    out = {"expected_tris": expected}
    try:
        bpy.ops.hlod.bake()
    except RuntimeError as exc:
        out["unsaved_error"] = str(exc)  # no .blend saved and no output path
    props.output_path = str(Path(work) / "scene.hlod")
    props.target_tris = 400
    out["result"] = sorted(bpy.ops.hlod.bake())
    hlod = fileformat.load(props.file)
    out.update(file=props.file, nodes=hlod.node_count, input_tris=int(hlod.meta["input_tris"]),
               box_min=hlod.box_min[0].tolist(), box_max=hlod.box_max[0].tolist())
    out["sources_untouched"] = before == {o.name: (len(o.data.vertices) if o.type == "MESH" else None, len(o.modifiers))
                                          for o in made}
    bpy.ops.object.select_all(action="DESELECT")
    try:
        bpy.ops.hlod.bake()
    except RuntimeError as exc:
        out["empty_selection_error"] = str(exc)
    out["materialize"] = sorted(bpy.ops.hlod.materialize(depth=1))
    materialized = [c for c in bpy.data.collections if c.name.startswith("HLOD depth 1")]
    out["materialized_objects"] = len(materialized[0].objects) if materialized else 0
    out["materialized_tris"] = int(sum(len(o.data.polygons) for o in materialized[0].objects)) if materialized else 0
    level = hlod.depth
    cut = np.flatnonzero((level == 1) | ((hlod.child_count == 0) & (level < 1)))
    out["cut_tris"] = int(hlod.tri_count[cut].sum())
    exported = Path(work) / "export" / "copy.hlod"
    exported.parent.mkdir()
    out["export"] = sorted(bpy.ops.hlod.export(filepath=str(exported)))
    out["exported_nodes"] = fileformat.load(exported).node_count
    out["export_3dtiles"] = sorted(bpy.ops.hlod.export(filepath=str(Path(work) / "export" / "tiles"), format="3DTILES"))
    tileset = Path(work) / "export" / "tiles" / "tileset.json"
    out["tileset_tiles"] = len(list((tileset.parent / "tiles").glob("*.glb"))) if tileset.is_file() else 0
    out["clear"] = sorted(bpy.ops.hlod.clear())
    out["file_after_clear"] = props.file
    # the modal bake's worker (UI events cannot be made here, the job they drive can): Esc cancels
    # between tasks and writes nothing; a finished job has written its file
    job_mod = importlib.import_module(NAME + ".addon.bake_job")
    scenes = importlib.import_module(NAME + ".hlod_core.scenes")
    settings_cls = importlib.import_module(NAME + ".hlod_core.bake").BakeSettings
    city = scenes.default_scene(scale=0.5)
    target = Path(work) / "job" / "city.hlod"
    target.parent.mkdir()
    job = job_mod.BakeJob(city, settings_cls(jobs=1), str(target))
    while job.running and job.progress[2] != "simplify":
        time.sleep(0.01)
    job.cancel()
    job.wait(120)
    out["job_cancelled"] = type(job.error).__name__
    out["job_cancelled_file"] = target.exists()
    job = job_mod.BakeJob(_box_row_mesh(), settings_cls(jobs=1, target_tris=400), str(target))
    job.wait(120)
    out["job_done"] = (job.error is None, job.percent, target.is_file(), job.result.node_count if job.result else 0)
    # a collection as the source, and the default output next to the saved .blend
    chosen = bpy.data.collections.new("chosen")
    bpy.context.scene.collection.children.link(chosen)
    cube = bpy.data.objects["cube 0"]
    chosen.objects.link(cube)
    props.source, props.collection, props.output_path = "COLLECTION", chosen, ""
    blend = Path(work) / "project" / "city.blend"
    blend.parent.mkdir()
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out["collection_result"] = sorted(bpy.ops.hlod.bake())
    out["collection_file"] = bpy.path.abspath(props.file)
    out["collection_tris"] = int(fileformat.load(bpy.path.abspath(props.file)).meta["input_tris"])
    return out


def _draw_checks(package, scene, size, occlude: bool) -> dict:
    """Draw with a grey occluder over the left 40% of the view (drawn before, with depth) and a green
    triangle after; classify the pixels."""
    import gpu
    from gpu_extras.batch import batch_for_shader
    from mathutils import Matrix

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    state = {}

    def occluder():
        state["before"] = (gpu.state.depth_mask_get(), gpu.state.depth_test_get(), tuple(gpu.state.viewport_get()))
        if not occlude:
            return
        with gpu.matrix.push_pop():  # a quad in clip space at depth -0.9 (near), left 40% of the view
            gpu.matrix.load_identity()
            with gpu.matrix.push_pop_projection():
                gpu.matrix.load_projection_matrix(Matrix.Identity(4))
                gpu.state.depth_test_set("LESS_EQUAL")
                gpu.state.depth_mask_set(True)
                quad = [(-1, -1, -0.9), (-0.2, -1, -0.9), (-0.2, 1, -0.9), (-1, 1, -0.9)]
                batch = batch_for_shader(shader, "TRI_FAN", {"pos": quad})
                shader.uniform_float("color", (0.5, 0.5, 0.5, 1.0))
                batch.draw(shader)
                gpu.state.depth_test_set("NONE")
                gpu.state.depth_mask_set(False)

    def green():
        state["after"] = (gpu.state.depth_mask_get(), gpu.state.depth_test_get(), tuple(gpu.state.viewport_get()))
        with gpu.matrix.push_pop():
            gpu.matrix.load_identity()
            with gpu.matrix.push_pop_projection():
                gpu.matrix.load_projection_matrix(Matrix.Identity(4))
                tri = [(0.8, 0.8, 0.0), (0.95, 0.8, 0.0), (0.95, 0.95, 0.0)]
                batch = batch_for_shader(shader, "TRIS", {"pos": tri})
                shader.uniform_float("color", (0.0, 1.0, 0.0, 1.0))
                batch.draw(shader)

    pixels = blender_preview.draw_offscreen(package, scene, size, before=occluder, after=green)
    rgb = pixels[..., :3].astype(np.int64)
    white = np.all(rgb == 255, axis=2)
    grey = np.all(np.abs(rgb - 128) <= 2, axis=2)
    greenish = (rgb[..., 1] > 200) & (rgb[..., 0] < 40) & (rgb[..., 2] < 40)
    ramp = ~white & ~grey & ~greenish & (rgb[..., 1] <= 0.25 * np.maximum(rgb[..., 0], rgb[..., 2]) + 3)
    w = size[0]
    left = np.zeros_like(white)
    left[:, : int(0.4 * w) - 2] = True
    return {"ramp_pixels": int(ramp.sum()), "red_pixels": int((ramp & (rgb[..., 0] > rgb[..., 2])).sum()),
            "ramp_in_occluder": int((ramp & left).sum()), "grey_in_occluder": int((grey & left).sum()),
            "occluder_pixels": int(left.sum()), "green_pixels": int(greenish.sum()),
            "other_pixels": int((~white & ~grey & ~greenish & ~ramp).sum()),
            "state_before": state.get("before"), "state_after": state.get("after")}


def check_preview(repo, work) -> dict:
    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview")
    blender_preview.init_gpu()
    _box_row_scene()
    scene = bpy.context.scene
    props = scene.hlod
    props.output_path, props.target_tris = str(Path(work) / "row.hlod"), 300
    bpy.ops.hlod.bake()
    blender_preview.camera(scene, eye=(1.5, -8.0, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
    props.method, props.bias, props.show_modulation = "coh", "mu", True
    bpy.ops.hlod.preview_toggle()
    out = {"running": preview.running(), "status_on": props.status}
    size = (320, 240)
    for _ in range(3):
        frame = _draw_checks(package, scene, size, occlude=True)
    out["occluded"] = frame
    out["materialize_front"] = sorted(bpy.ops.hlod.materialize(depth=-1))
    out["front_objects"] = len(bpy.data.collections["HLOD front"].objects)
    out["stats"] = {"drawn": props.stat_drawn, "queries": props.stat_queries, "tris": props.stat_tris,
                    "frame_ms": props.stat_frame_ms}
    # overlay boxes with Blender's gpu module
    props.show_boxes = True
    out["with_boxes"] = _draw_checks(package, scene, size, occlude=False)["other_pixels"]
    props.show_boxes = False
    # the benchmark's private EGL context must leave Blender's current again
    anim = scene.camera
    scene.frame_start, scene.frame_end = 1, 4
    anim.location = (1.5, -8.0, 1.5)
    anim.keyframe_insert("location", frame=1)
    anim.location = (1.5, -5.0, 1.5)
    anim.keyframe_insert("location", frame=4)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 160, 120, 100
    out["benchmark"] = sorted(bpy.ops.hlod.benchmark(directory=str(Path(work) / "report"), repeat=1))
    report = json.loads((Path(work) / "report" / "report.json").read_text())
    out["benchmark_frames"], out["benchmark_methods"] = report["frames"], sorted(report["methods"])
    out["after_benchmark"] = _draw_checks(package, scene, size, occlude=True)
    # the fallback for backends moderngl cannot attach to: a private context, drawn with the gpu module
    props.private_context = True
    for _ in range(3):
        out["private"] = _draw_checks(package, scene, size, occlude=True)
    out["status_private"] = props.status
    out["private_drawn"] = props.stat_drawn
    props.private_context = False
    # orthographic camera view, and the X-ray message (X-ray clears the depth Blender's objects leave)
    scene.camera.data.type, scene.camera.data.ortho_scale = "ORTHO", 14.0
    out["ortho"] = _draw_checks(package, scene, size, occlude=False)["ramp_pixels"]
    scene.camera.data.type = "PERSP"
    view, projection = blender_preview.camera_matrices(scene, size)
    import gpu

    offscreen = gpu.types.GPUOffScreen(*size)
    with offscreen.bind():
        preview.safe_draw(scene, view, projection, *size, xray=True)
    offscreen.free()
    out["status_xray"] = props.status
    # an exception inside the draw path turns the preview off and is not raised
    traversal = importlib.import_module(NAME + ".hlod_core.traversal")

    def boom(self, view):
        raise RuntimeError("injected failure")

    original = traversal.Traversal.frame
    traversal.Traversal.frame = boom
    try:
        props.tau = 1.5  # a new traversal object, with the broken frame()
        view, projection = blender_preview.camera_matrices(scene, size)
        out["injected_return"] = repr(preview.safe_draw(scene, view, projection, *size))
    finally:
        traversal.Traversal.frame = original
    out["running_after_error"] = preview.running()
    out["status_after_error"] = props.status
    bpy.ops.hlod.preview_toggle()
    out["running_after_toggle"] = preview.running()
    bpy.ops.wm.read_homefile(use_empty=True)  # load_pre stops the preview and frees it
    out["running_after_load"], out["status_after_load"] = preview.running(), preview.status()
    return out


def check_make_blends(repo, work) -> dict:
    """Two .blend files for the batch test: the box row (modifiers, instances) and a field of
    monkeys in a collection named "props" beside a plane outside it."""
    out = {}
    bpy.ops.wm.read_homefile(use_empty=True)
    _box_row_scene()
    a = Path(work) / "boxes.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(a))
    out["boxes"] = str(a)
    bpy.ops.wm.read_homefile(use_empty=True)
    props = bpy.data.collections.new("props")
    bpy.context.scene.collection.children.link(props)
    for i in range(3):
        bpy.ops.mesh.primitive_monkey_add(size=2.0, location=(3.0 * i, 0.0, 1.0))
        monkey = bpy.context.active_object
        monkey.modifiers.new("smooth", "SUBSURF").levels = 1
        for c in list(monkey.users_collection):
            c.objects.unlink(monkey)
        props.objects.link(monkey)
    bpy.ops.mesh.primitive_plane_add(size=20.0)
    b = Path(work) / "monkeys.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(b))
    out["monkeys"] = str(b)
    # expected triangles of the collection: the monkey (500 faces: 468 quads?) counted by Blender
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out["monkeys_tris"] = sum(len(o.evaluated_get(depsgraph).to_mesh().loop_triangles) for o in props.objects)
    return out


if __name__ == "__main__":
    repo_dir, check, work_dir = sys.argv[1:4]
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    result = globals()[f"check_{check}"](repo_dir, work_dir)
    print(json.dumps(result))
