"""Checks of the preview in place of its sources, inside the real bpy module, one per subprocess
(tests/blender/test_preview_in_place.py runs them):

    python tests/blender/blender_preview_checks.py REPO_DIR CHECK WORK_DIR

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.

Blender's own drawing is real: `GPUOffScreen.draw_view3d` draws the scene as the viewport does
(solid shading, flat object colours so objects can be told apart by colour), into the offscreen
whose depth then holds Blender's scene; the add-on's draw path runs after it in the same
offscreen, as its POST_VIEW handler does in the viewport.
"""
from __future__ import annotations

import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
import bpy

import blender_preview
from hlod_core.core.png import write_png

NAME = "bl_ext.r.hlod"
SIZE = (240, 180)  # offscreen pixels
# flat object colours (linear, drawn without colour management): tell the objects apart by colour
SOURCE_COLOUR = (1.0, 0.4, 0.0, 1.0)  # orange: the objects the bake takes
WALL_COLOUR = (0.0, 0.8, 0.8, 1.0)  # cyan: a wall in front of the first cube, not baked
GROUND_COLOUR = (0.25, 0.25, 0.25, 1.0)  # grey ground plane, not baked
BACKGROUND = (0.0, 0.0, 0.0)
EYE, TARGET, LENS_MM = (0.0, -12.0, 5.0), (0.0, 4.0, 0.5), 22.0
SPHERE_INSTANCE_AT = (-6.0, 0.0, 0.5)


# --- the scene ------------------------------------------------------------------------------------

def _coloured(obj, colour):
    obj.color = colour
    return obj


def row_scene() -> dict:
    """Four subdivided cubes in a row along +y, an arrayed cube, two instances of a collection
    holding a sphere (the sources, orange, all selected), a cyan wall in front of the first cube
    and a grey ground (not sources), a camera. Returns {"sources": names, "others": names}."""
    scene = bpy.context.scene
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    sources = []
    for i in range(4):
        bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.0, 4.0 * i, 1.0))
        cube = _coloured(bpy.context.active_object, SOURCE_COLOUR)
        cube.name = f"cube {i}"
        cube.modifiers.new("subdivide", "SUBSURF").levels = 2
        sources.append(cube)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(6.0, 0.0, 0.5))
    arrayed = _coloured(bpy.context.active_object, SOURCE_COLOUR)
    arrayed.name = "arrayed"
    arrayed.modifiers.new("array", "ARRAY").count = 3
    sources.append(arrayed)
    collection = bpy.data.collections.new("sphere source")
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.0, 0.0, 0.0))
    sphere = _coloured(bpy.context.active_object, SOURCE_COLOUR)
    sphere.name = "sphere"
    for c in list(sphere.users_collection):
        c.objects.unlink(sphere)
    collection.objects.link(sphere)
    for k, x in enumerate((SPHERE_INSTANCE_AT[0], -9.0)):
        # instances take its colour
        empty = _coloured(bpy.data.objects.new(f"sphere instance {k}", None), SOURCE_COLOUR)
        empty.instance_type, empty.instance_collection = "COLLECTION", collection
        empty.location = (x, 0.0, 0.5)
        scene.collection.objects.link(empty)
        sources.append(empty)
    bpy.ops.mesh.primitive_plane_add(size=3.0, location=(0.0, -2.5, 1.5), rotation=(np.pi / 2, 0.0, 0.0))
    wall = _coloured(bpy.context.active_object, WALL_COLOUR)
    wall.name = "wall"
    bpy.ops.mesh.primitive_plane_add(size=40.0, location=(0.0, 4.0, -0.01))
    ground = _coloured(bpy.context.active_object, GROUND_COLOUR)
    ground.name = "ground"
    blender_preview.camera(scene, eye=EYE, target=TARGET, lens_mm=LENS_MM)
    bpy.ops.object.select_all(action="DESELECT")
    for obj in sources:
        obj.select_set(True)
    bpy.context.view_layer.objects.active = sources[0]
    return {"sources": [o.name for o in sources], "others": [wall.name, ground.name, scene.camera.name]}


def bake(work, name: str = "row.hlod", target_tris: int = 300) -> list:
    props = bpy.context.scene.hlod
    props.output_path, props.target_tris = str(Path(work) / name), target_tris
    return sorted(bpy.ops.hlod.bake())


def visibility() -> dict:
    """Every object's viewport state: [hidden in the view layer, selected, hide_viewport, visible]."""
    layer = bpy.context.view_layer
    return {obj.name: [obj.hide_get(view_layer=layer), obj.select_get(view_layer=layer), obj.hide_viewport,
                       obj.visible_get(view_layer=layer)] for obj in layer.objects}


def set_visibility(state: dict) -> None:
    """Put back a `visibility()` state (hidden in the view layer, selected)."""
    layer = bpy.context.view_layer
    for name, (hidden, selected, _, _) in state.items():
        obj = layer.objects[name]
        obj.hide_set(hidden, view_layer=layer)
        obj.select_set(selected, view_layer=layer)


def records(scene=None) -> dict:
    props = (scene or bpy.context.scene).hlod
    return {"sources": [[item.name, item.key] for item in props.source_objects], "source_file": props.source_file,
            "hidden": [[item.name, item.selected] for item in props.hidden_objects],
            "hidden_view_layer": props.hidden_view_layer}


# --- Blender's drawing and the preview's, in an offscreen -------------------------------------------

def _view3d():
    """A 3D view and its main region from the file's screens (the bpy module opens no window),
    set to solid shading with flat object colours, no overlays, one sample (no anti-aliasing: exact
colours, and one redraw per frame)."""
    area = next(a for screen in bpy.data.screens for a in screen.areas if a.type == "VIEW_3D")
    space = area.spaces.active
    region = next(r for r in area.regions if r.type == "WINDOW")
    shading = space.shading
    shading.type, shading.light, shading.color_type = "SOLID", "FLAT", "OBJECT"
    shading.background_type, shading.background_color = "VIEWPORT", BACKGROUND
    shading.show_object_outline = shading.show_cavity = shading.show_shadows = shading.show_xray = False
    space.overlay.show_overlays = False
    bpy.context.preferences.system.viewport_aa = "OFF"  # else draw_view3d draws 8 jittered samples of a new view
    return space, region


def draw_scene(package, *, preview: bool, text: bool = False, size=SIZE) -> np.ndarray:
    """Blender's drawing of the view layer from the scene camera (draw_view3d), then, with
    `preview`, the add-on's draw path into the same offscreen (its depth holds Blender's scene), and
    with `text` the corner text in pixel space. (H, W, 4) uint8, bottom row first."""
    import gpu

    module = importlib.import_module(package.__name__ + ".addon.preview.live").PREVIEW
    scene = bpy.context.scene
    space, region = _view3d()
    view, projection = blender_preview.camera_matrices(scene, size)
    offscreen = gpu.types.GPUOffScreen(*size)
    try:
        offscreen.draw_view3d(scene, bpy.context.view_layer, space, region, view, projection,
                              do_color_management=False)
        with offscreen.bind():
            fb = gpu.state.active_framebuffer_get()
            with gpu.matrix.push_pop():
                gpu.matrix.load_matrix(view)
                gpu.matrix.load_projection_matrix(projection)
                if preview:
                    module.safe_draw(scene, module.view_from_matrices(view, projection, size))
            if text:
                with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                    gpu.matrix.load_identity()
                    gpu.matrix.load_projection_matrix(blender_preview.pixel_projection(size))
                    module.draw_corner_text(scene)
            pixels = np.array(fb.read_color(0, 0, size[0], size[1], 4, 0, "UBYTE").to_list(), np.uint8)
    finally:
        offscreen.free()
    return pixels.reshape(size[1], size[0], 4)


def classify(pixels: np.ndarray) -> dict:
    """Masks (H, W) by colour: source orange, wall cyan, ground grey, background, and the preview's
    modulation ramp (blue - magenta - red: green well below red and blue)."""
    rgb = pixels[..., :3].astype(np.int64)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return {"source": (r > 200) & (g > 60) & (g < 160) & (b < 30),
            "wall": (r < 30) & (g > 150) & (b > 150),
            "ground": (np.abs(r - 64) <= 3) & (np.abs(g - 64) <= 3) & (np.abs(b - 64) <= 3),
            "background": rgb.max(axis=2) <= 3,
            "ramp": (g <= 0.25 * np.maximum(r, b) + 3) & (np.maximum(r, b) > 40)}


def project(scene, point, size) -> tuple[int, int]:
    """Pixel (x, y) (origin bottom left) of a world point seen by the scene camera."""
    view, projection = blender_preview.camera_matrices(scene, size)
    clip = np.array(projection) @ np.array(view) @ np.array([*point, 1.0])
    ndc = clip[:3] / clip[3]
    return int((ndc[0] + 1) * 0.5 * size[0]), int((ndc[1] + 1) * 0.5 * size[1])


# --- checks ------------------------------------------------------------------------------------------

def check_in_place(repo, work) -> dict:
    """Start the preview on a baked row: the sources (and the instances they make) vanish from
    Blender's own drawing, which otherwise stays as it was, the nodes are drawn where they were and
    Blender's wall still hides them; the corner text; stopping gives back exactly the visibility and
    selection there were (an object the user had hidden stays hidden); loading another file leaves
    that file as it was saved, and the preview started there hides the objects its record names."""
    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    blender_preview.init_gpu()
    names = row_scene()
    scene = bpy.context.scene
    out = {"names": names, "bake": bake(work)}
    out["record"] = records()
    # file B: the same scene, with "cube 2" hidden by the user, saved without any preview
    layer = bpy.context.view_layer
    bpy.data.objects["cube 2"].hide_set(True)
    other = Path(work) / "other.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(other), copy=True)
    out["other_saved"] = visibility()
    bpy.data.objects["cube 2"].hide_set(False)
    # the state before the preview: "cube 1" not selected, "arrayed" hidden by the user
    bpy.data.objects["cube 1"].select_set(False)
    bpy.data.objects["arrayed"].hide_set(True)
    out["before"] = visibility()
    out["active_before"] = layer.objects.active.name
    blender_only = draw_scene(package, preview=False)
    # the reference for "sources hidden": hide them by hand (every visible source), draw, show again
    for name in names["sources"]:
        bpy.data.objects[name].hide_set(True)
    without_sources = draw_scene(package, preview=False)
    set_visibility(out["before"])
    out["reference_state_same"] = visibility() == out["before"]

    out["toggle_on"] = sorted(bpy.ops.hlod.preview_toggle())
    out["running"] = preview.running()
    out["during"] = visibility()
    out["record_during"] = records()
    out["in_place"] = list(preview.sources_in_place())
    blender_during = draw_scene(package, preview=False)  # Blender's own drawing while the preview runs
    for _ in range(3):  # coherent: the front settles over a few frames of the same view
        with_preview = draw_scene(package, preview=True)
    masks = {name: classify(image) for name, image in (("blender_only", blender_only), ("during", blender_during),
                                                      ("with_preview", with_preview))}
    x, y = project(scene, SPHERE_INSTANCE_AT, SIZE)
    out["drawing"] = {
        "source_pixels_before": int(masks["blender_only"]["source"].sum()),
        "source_pixels_during": int(masks["during"]["source"].sum()),
        "during_equals_hidden_by_hand": bool(np.array_equal(blender_during, without_sources)),
        "instance_pixel_before": blender_only[y, x, :3].tolist(),
        "instance_pixel_during": blender_during[y, x, :3].tolist(),
        "wall_pixels": int(masks["during"]["wall"].sum()),
        "ramp_pixels": int(masks["with_preview"]["ramp"].sum()),
        "ramp_on_wall": int((masks["with_preview"]["ramp"] & masks["during"]["wall"]).sum()),
        "wall_changed": int(np.any(with_preview[masks["during"]["wall"]] != blender_during[masks["during"]["wall"]],
                                   axis=-1).sum()),
        "ramp_where_sources_were": int((masks["with_preview"]["ramp"] & masks["blender_only"]["source"]).sum()),
    }
    out["stats"] = {"drawn": scene.hlod.stat_drawn, "tris": scene.hlod.stat_tris, "queries": scene.hlod.stat_queries}
    # the corner text, drawn over Blender's drawing and the preview: pixels in the bottom-left corner only
    with_text = draw_scene(package, preview=True, text=True)
    out["text_lines"] = _corner_lines(preview, scene)
    out["text"] = _text_pixels(with_text, draw_scene(package, preview=True))
    scene.hlod.show_corner_text = False
    out["text_hidden"] = _text_pixels(draw_scene(package, preview=True, text=True), draw_scene(package, preview=True))
    scene.hlod.show_corner_text = True
    write_png(Path(work) / "in_place.png", with_text[::-1, :, :3])

    out["toggle_off"] = sorted(bpy.ops.hlod.preview_toggle())
    out["after"] = visibility()
    out["active_after"] = layer.objects.active.name
    out["record_after"] = records()
    out["after_equals_before_drawing"] = bool(np.array_equal(draw_scene(package, preview=False), blender_only))
    # loading another file while the preview runs: B as it was saved; nothing of A's preview applies to it
    bpy.ops.hlod.preview_toggle()
    bpy.ops.wm.open_mainfile(filepath=str(other))
    out["running_after_load"], out["status_after_load"] = preview.running(), preview.status()
    out["other_loaded"] = visibility()
    out["other_record"] = records()
    out["in_place_after_load"] = list(preview.sources_in_place())
    # the reopened file knows what its bake took: the preview hides those objects there
    out["reopened_toggle_on"] = sorted(bpy.ops.hlod.preview_toggle())
    out["reopened_in_place"] = list(preview.sources_in_place())
    out["reopened_hidden"] = visibility()
    bpy.ops.hlod.preview_toggle()
    out["reopened_after"] = visibility()
    return out


def check_streaming(repo, work) -> dict:
    """The preview under a GPU budget smaller than the file's node geometry (room for the unlimited
    frame's nodes, 1.5 times), in the GL mode, the private-context mode and the CPU mode (the
    batches' bookkeeping under the budget), the sources hidden, the
    camera held: resident bytes within the budget every frame, the picture converging to the one
    drawn without a budget (SW, whose choice does not depend on query timing), the statistics and
    the corner text saying it."""
    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    streamed = importlib.import_module(NAME + ".hlod_core.render.streamed_geometry")
    blender_preview.init_gpu()
    names = row_scene()
    scene, props = bpy.context.scene, bpy.context.scene.hlod
    out = {"bake": bake(work, target_tris=60)}
    props.method, props.show_modulation, props.skip_queries = "sw", False, "off"
    out["toggle_on"] = sorted(bpy.ops.hlod.preview_toggle())
    hlod = preview.current_hlod()
    out["nodes"] = int(hlod.node_count)
    whole = int(streamed.node_bytes(hlod, with_uv=False, with_colour=False).sum())
    out["sources_hidden"] = all(bpy.data.objects[n].hide_get() for n in names["sources"] if n != "arrayed")
    for mode in ("gl", "private", "cpu"):
        props.private_context = mode == "private"
        preview.forced_mode = "cpu" if mode == "cpu" else None
        props.gpu_budget_mb = 0.0
        for _ in range(3):
            reference = draw_scene(package, preview=True)
        # the budget: what the unlimited frame uses (its cut and their ancestors), with room to spare
        # for the nodes that stand in first, and less than the file
        used = set()
        for node in preview.last_stats().drawn:
            while node >= 0 and node not in used:
                used.add(node)
                node = int(hlod.parent[node])
        sizes = streamed.node_bytes(hlod, with_uv=False, with_colour=False)
        props.gpu_budget_mb = min(0.75 * whole, 1.5 * int(sizes[sorted(used)].sum())) / 2**20
        budget = int(round(props.gpu_budget_mb * 2**20))
        frames = []
        for _ in range(FRAMES_TO_CONVERGE):
            image = draw_scene(package, preview=True)
            stats = preview.last_stats()
            frames.append({"differing": int(np.any(image != reference, axis=-1).sum()), "dn": stats.dn,
                           "resident": stats.resident_bytes, "waiting": stats.waiting,
                           "substitutions": stats.substitutions})
        out[mode] = {
            "budget": budget, "whole": whole, "frames": frames,
            "stat_resident_mb": props.stat_resident_mb, "stat_waiting": props.stat_waiting,
            "corner": _corner_lines(preview, scene)}
    props.private_context, preview.forced_mode = False, None
    out["toggle_off"] = sorted(bpy.ops.hlod.preview_toggle())
    return out


#: Frames a held camera is drawn under the budget in check_streaming.
FRAMES_TO_CONVERGE = 12


def _corner_lines(preview, scene) -> list[str]:
    return [line for line, _ in preview.corner_lines(scene)]


TEXT_ROWS = 60  # the corner text's lines (two or three) fit in the bottom 60 rows at UI scale 1


def _text_pixels(with_text: np.ndarray, without: np.ndarray) -> dict:
    """Pixels the text changed in the bottom TEXT_ROWS rows and above them, and the leftmost
    column it changed (-1: none)."""
    changed = np.any(with_text[..., :3] != without[..., :3], axis=2)
    columns = np.flatnonzero(changed.any(axis=0))
    return {"in_corner": int(changed[:TEXT_ROWS].sum()), "outside": int(changed[TEXT_ROWS:].sum()),
            "leftmost": int(columns[0]) if columns.size else -1}


def _state(preview) -> dict:
    rec = records()
    return {"running": preview.running(), "visibility": visibility(),
            "hidden_record": rec["hidden"], "hidden_view_layer": rec["hidden_view_layer"]}


def _open_raw(package, path) -> dict:
    """Open `path` with the add-on's load_post handler held back: what the file itself holds."""
    handler = package._on_load_post
    bpy.app.handlers.load_post.remove(handler)
    try:
        bpy.ops.wm.open_mainfile(filepath=str(path))
    finally:
        bpy.app.handlers.load_post.append(handler)
    return {"visibility": visibility(), "hidden_record": records()["hidden"]}


def check_restore_paths(repo, work) -> dict:
    """Every way out of a running preview gives back the visibility there was: saving while it runs
    (the file holds the sources visible and no record; in memory they are hidden again), undo and
    redo (the preview keeps running and its sources stay hidden; with the preview off, an undo step
    holding hidden sources is restored), disabling the extension, and a file written while it ran
    without the save handlers (as an autosave or quit.blend before a crash): it holds the record,
    and opening it shows the objects again."""
    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    names = row_scene()
    blend = Path(work) / "row.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = {"names": names, "bake": bake(work)}
    out["before"] = visibility()
    bpy.ops.ed.undo_push(message="baked")  # operators called from Python push no undo step themselves
    # saving while the preview runs
    bpy.ops.hlod.preview_toggle()
    out["running"] = _state(preview)
    bpy.ops.wm.save_mainfile()
    out["after_save"] = _state(preview)
    # undo and redo; stack: "baked" (preview off), "preview on", "ground moved"
    bpy.ops.ed.undo_push(message="preview on")
    bpy.data.objects["ground"].location.z = -0.5
    bpy.ops.ed.undo_push(message="ground moved")
    bpy.ops.ed.undo()
    out["undo_to_preview_on"] = {**_state(preview), "ground_z": bpy.data.objects["ground"].location.z}
    bpy.ops.ed.undo()  # "baked": sources visible in it, no record
    out["undo_to_baked"] = _state(preview)
    bpy.ops.ed.redo()
    bpy.ops.ed.redo()
    out["redo_to_ground_moved"] = {**_state(preview), "ground_z": bpy.data.objects["ground"].location.z}
    # the control: with the add-on's undo handler held back, the "baked" step shows the sources
    held = package._on_undo_redo
    bpy.app.handlers.undo_post.remove(held)
    try:
        bpy.ops.ed.undo()
        bpy.ops.ed.undo()
        out["undo_to_baked_unhandled"] = _state(preview)
    finally:
        bpy.app.handlers.undo_post.append(held)
    bpy.ops.ed.redo()
    bpy.ops.ed.redo()
    out["redo_handled"] = _state(preview)
    bpy.ops.hlod.preview_toggle()  # off: shown again (no undo step)
    out["stopped"] = _state(preview)
    bpy.ops.ed.undo()  # back to "preview on": a step holding hidden sources and their record, preview off
    out["undo_after_stop"] = {**_state(preview), "ground_z": bpy.data.objects["ground"].location.z}
    bpy.ops.ed.redo()
    out["redo_after_stop"] = _state(preview)
    bpy.app.handlers.undo_post.remove(held)  # the control: that step holds the sources hidden
    try:
        bpy.ops.ed.undo()
        out["undo_after_stop_unhandled"] = _state(preview)
        bpy.ops.ed.redo()
    finally:
        bpy.app.handlers.undo_post.append(held)
    bpy.data.objects["ground"].location.z = -0.01
    # disabling the extension while the preview runs
    import addon_utils

    bpy.ops.hlod.preview_toggle()
    out["hidden_before_disable"] = sum(state[0] for state in visibility().values())
    addon_utils.disable(NAME, default_set=True)
    out["disabled"] = {"visibility": visibility(),
                       "hidden_record": len(bpy.context.scene.get("hlod", {}).get("hidden_objects", []))}
    package = blender_preview.enable_from_repo(repo)
    # a file written while the preview ran, without the save handlers (an autosave, quit.blend)
    bpy.ops.hlod.preview_toggle()
    crash = Path(work) / "crash.blend"
    held = [(getattr(bpy.app.handlers, event), getattr(package, name))
            for event, name in (("save_pre", "_on_save_pre"), ("save_post", "_on_save_post"))]
    for handlers, handler in held:
        handlers.remove(handler)
    try:
        bpy.ops.wm.save_as_mainfile(filepath=str(crash), copy=True)
    finally:
        for handlers, handler in held:
            handlers.append(handler)
    out["crash_file"] = _open_raw(package, crash)
    bpy.ops.wm.open_mainfile(filepath=str(crash))
    out["crash_opened"] = _state(preview)
    out["saved_file"] = _open_raw(package, blend)  # the file saved while the preview ran
    return out


def check_stale(repo, work) -> dict:
    """While the preview runs (the sources hidden), each kind of change to a source moves the count of
    baked objects changed since the bake, through the depsgraph (and frame change) handlers: the
    animation moving a source, a transform, a modifier, a mesh edit, an edit inside an instanced
    collection (both of its instances), a transform put back exactly (the count falls: content
    keys, not dirty flags), a deletion, a rename. The panel's message and the corner text say it;
    Re-bake (hlod.bake with recorded=True) bakes the recorded objects still there, restarts the
    preview and the count is 0 again."""
    blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    source_record = importlib.import_module(NAME + ".addon.scene.source_record")
    names = row_scene()
    scene = bpy.context.scene
    animated = bpy.data.objects["cube 3"]  # still at frame 1, one unit up at frame 10
    scene.frame_set(1)
    animated.keyframe_insert("location", frame=1)
    animated.location.z += 1.0
    animated.keyframe_insert("location", frame=10)
    scene.frame_set(1)
    out = {"names": names, "bake": bake(work)}
    bpy.ops.hlod.preview_toggle()

    def changed() -> int:
        bpy.context.view_layer.update()  # runs the depsgraph_update_post handlers
        return len(source_record.tracker().changed)

    objects = bpy.data.objects
    steps = [("start", changed())]
    scene.frame_set(10)
    steps.append(("frame 10", len(source_record.tracker().changed)))
    scene.frame_set(1)
    steps.append(("frame 1", len(source_record.tracker().changed)))
    objects["cube 0"].location.x += 0.25
    steps.append(("transform", changed()))
    out["refresh_ms_one_object"] = source_record.tracker().refresh_ms
    objects["cube 1"].modifiers["subdivide"].levels = 1
    steps.append(("modifier", changed()))
    mesh = objects["arrayed"].data
    mesh.vertices[0].co.x += 0.1
    mesh.update()
    steps.append(("mesh edit", changed()))
    objects["sphere"].location.z += 0.1  # inside the instanced collection: both instances change
    steps.append(("instanced collection", changed()))
    objects["cube 0"].location.x -= 0.25
    steps.append(("transform put back", changed()))
    bpy.data.objects.remove(objects["cube 2"])
    steps.append(("deleted", changed()))
    objects["cube 3"].name = "renamed"
    steps.append(("renamed", changed()))
    out["steps"] = steps
    out["hidden_during"] = all(objects[n].hide_get() for n in names["sources"] if n in objects)
    out["renamed_hidden"] = objects["renamed"].hide_get()
    out["stat_changed"] = scene.hlod.stat_changed
    recorded, _ = preview.sources_in_place()
    text = importlib.import_module(NAME + ".addon.preview.corner_text")
    out["message"] = text.stale_message(len(source_record.tracker().changed), recorded)
    out["corner_lines"] = _corner_lines(preview, scene)
    started = time.perf_counter()
    source_record.tracker().refresh(bpy.context.evaluated_depsgraph_get())
    out["refresh_ms_all"] = 1e3 * (time.perf_counter() - started)
    # Re-bake: the recorded objects still there
    out["rebake"] = sorted(bpy.ops.hlod.bake(recorded=True))
    out["running_after_rebake"] = preview.running()
    out["record_after_rebake"] = [name for name, _ in records()["sources"]]
    out["in_place_after_rebake"] = list(preview.sources_in_place())
    out["changed_after_rebake"] = changed()
    out["renamed_after_rebake"] = objects["renamed"].hide_get()
    return out


if __name__ == "__main__":
    repo_dir, check, work_dir = sys.argv[1:4]
    result = globals()[f"check_{check}"](repo_dir, work_dir)
    print(json.dumps(result))
    blender_preview.exit_process(0)
