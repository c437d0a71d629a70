"""Viewport frame time with the HLOD preview in place of its sources, against the preview off,
measured in the bpy module, and the README's picture of it.

    .venv/bin/python scripts/preview_in_place.py [--spec tests/scenes/crowd_1m.json] [--size 960x540]
        [--blocks 3] [--frames 8] [--picture docs/preview_in_place.png] [--work DIR]

Blender objects made from a scene spec are baked with the extension's own operator, then frames are
drawn (Blender's own drawing with `GPUOffScreen.draw_view3d`, the preview's passes after it) with
the preview off, on, and on with its passes left out, alternating in blocks, one sample per frame.
Prints one JSON line of medians in milliseconds; writes the picture (preview off and on side by
side) if --picture is given. Why: docs/how-it-works.md#measuring-the-preview-in-place
"""
from __future__ import annotations

import argparse
import importlib
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import blender_preview
import models  # tests/models.py: the test models, which the scene specs read

ROOT = Path(__file__).resolve().parents[1]

EYE, TARGET, LENS_MM = (-25.0, -25.0, 18.0), (44.0, 44.0, 0.0), 35.0  # a three-quarter view over the crowd
YAW_STEP_DEG = 0.5  # the camera's turn about the target per frame (navigation)
TARGET_TRIS = 2000


def build_scene(spec_path: Path, *, unique_meshes: bool = False) -> list:
    """One mesh object per placed model of the spec (meshes shared per model, or one copy per
    object with `unique_meshes`), a ground plane and no other objects; returns the statue objects."""
    import bpy
    from mathutils import Matrix

    from hlod_core.core.errors import InputError
    from hlod_core.io import meshes

    spec = json.loads(spec_path.read_text())
    models = spec.get("models") if isinstance(spec, dict) else None
    if not isinstance(models, list) or not models:
        raise InputError(f"{spec_path}: scene spec needs a non-empty list \"models\"")
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    statues = []
    for i, model in enumerate(models):
        path = (spec_path.parent / model["path"]).resolve()
        mesh = _blender_mesh(meshes.load_mesh(path), path.stem)
        for j, transform in enumerate(model.get("transforms", [np.eye(4).ravel().tolist()])):
            obj = bpy.data.objects.new(f"{path.stem} {j:02d}", mesh.copy() if unique_meshes else mesh)
            obj.matrix_world = Matrix(np.asarray(transform, np.float64).reshape(4, 4).tolist())  # row-major, as Matrix
            bpy.context.scene.collection.objects.link(obj)
            statues.append(obj)
    corners = np.array([np.array(o.bound_box) @ np.array(o.matrix_world)[:3, :3].T + np.array(o.matrix_world)[:3, 3]
                        for o in statues]).reshape(-1, 3)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(*(0.5 * (lo[:2] + hi[:2])), float(lo[2]) - 0.01))
    ground = bpy.context.active_object
    ground.name, ground.scale = "ground", (1.4 * float(hi[0] - lo[0]), 1.4 * float(hi[1] - lo[1]), 1.0)
    bpy.ops.object.select_all(action="DESELECT")
    for obj in statues:
        obj.select_set(True)
    return statues


def _record_matches(package, scene, statues, *, baked: Path) -> bool:
    """Whether WORK/crowd.hlod was baked from these objects as they are: its record file
    (crowd.record.json, written after each bake here) holds the same names and content keys."""
    import bpy

    source_record = importlib.import_module(package.__name__ + ".addon.scene.source_record")
    saved = baked.with_suffix(".record.json")
    rows = source_record.record(statues, bpy.context.evaluated_depsgraph_get())
    if not saved.is_file() or json.loads(saved.read_text()) != [list(row) for row in rows]:
        return False
    source_record.store(scene.hlod, rows, str(baked))
    scene.hlod.file = str(baked)
    return True


def _blender_mesh(mesh, name: str):
    import bpy

    data = bpy.data.meshes.new(name)
    data.vertices.add(mesh.positions.shape[0])
    data.vertices.foreach_set("co", mesh.positions.astype(np.float32).ravel())
    faces = mesh.faces.astype(np.int32)
    data.loops.add(faces.size)
    data.loops.foreach_set("vertex_index", faces.ravel())
    data.polygons.add(faces.shape[0])
    data.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    data.update()
    return data


def _view3d():
    import bpy

    area = next(a for screen in bpy.data.screens for a in screen.areas if a.type == "VIEW_3D")
    space = area.spaces.active
    space.shading.type = "SOLID"
    return space, next(r for r in area.regions if r.type == "WINDOW")


def draw_frame(preview, scene, offscreen, *, size, with_preview: bool):
    """One viewport frame into `offscreen` (module notes); returns the pixel read back (1, 1, 4)."""
    import bpy
    import gpu

    space, region = _view3d()
    view, projection = blender_preview.camera_matrices(scene, size)
    offscreen.draw_view3d(scene, bpy.context.view_layer, space, region, view, projection, do_color_management=True)
    with offscreen.bind():
        if with_preview:
            with gpu.matrix.push_pop():
                gpu.matrix.load_matrix(view)
                gpu.matrix.load_projection_matrix(projection)
                preview.safe_draw(scene, preview.view_from_matrices(view, projection, size))
            with gpu.matrix.push_pop(), gpu.matrix.push_pop_projection():
                gpu.matrix.load_identity()
                gpu.matrix.load_projection_matrix(blender_preview.pixel_projection(size))
                preview.draw_corner_text(scene)
        return gpu.state.active_framebuffer_get().read_color(0, 0, 1, 1, 4, 0, "UBYTE")


def place_camera(camera, *, yaw_deg: float) -> None:
    """The camera at EYE turned by `yaw_deg` about the vertical through TARGET, looking at TARGET."""
    from mathutils import Matrix, Vector

    target = Vector(TARGET)
    eye = target + Matrix.Rotation(np.radians(yaw_deg), 3, "Z") @ (Vector(EYE) - target)
    rotation = (target - eye).to_track_quat("-Z", "Y").to_matrix().to_4x4()
    camera.matrix_world = Matrix.Translation(eye) @ rotation


MODES = ("off", "on", "hidden")  # preview off; on; on but its pass left out (Blender's share of "on")


def measure(preview, scene, size, *, blocks: int, frames: int) -> dict:
    """Frame milliseconds per mode, alternating blocks (module notes); "hidden" is the preview on
    with its POST_VIEW and POST_PIXEL passes left out: Blender's own drawing with the sources hidden."""
    import bpy
    import gpu

    times = {mode: [] for mode in MODES}
    first = {mode: [] for mode in MODES}
    preview_ms, drawn_tris, queries = [], [], []
    offscreen = gpu.types.GPUOffScreen(*size)
    try:
        for _ in range(blocks):
            for mode in MODES:
                if (mode != "off") != preview.running():
                    bpy.ops.hlod.preview_toggle()
                for frame in range(frames + 1):  # the first frame of a block is not measured
                    place_camera(scene.camera, yaw_deg=YAW_STEP_DEG * frame)
                    started = time.perf_counter()
                    draw_frame(preview, scene, offscreen, size=size, with_preview=mode == "on")
                    ms = 1e3 * (time.perf_counter() - started)
                    (times[mode] if frame else first[mode]).append(ms)
                    if frame and mode == "on":
                        stats = preview.last_stats()
                        preview_ms.append(stats.frame_ms)
                        drawn_tris.append(stats.tris)
                        queries.append(stats.queries)
    finally:
        offscreen.free()
    median = {mode: statistics.median(times[mode]) for mode in MODES}
    return {"frame_ms_preview_off": round(median["off"], 1), "frame_ms_preview_on": round(median["on"], 1),
            "ratio_on_over_off": round(median["on"] / median["off"], 3),
            "frame_ms_blender_sources_hidden": round(median["hidden"], 1),
            "preview_pass_ms": round(statistics.median(preview_ms), 1),
            "drawn_tris": int(statistics.median(drawn_tris)), "queries": int(statistics.median(queries)),
            "frames_per_mode": len(times["on"]),
            "first_frame_ms": {mode: [round(t) for t in first[mode]] for mode in MODES},
            "frame_ms_all": {mode: [round(t, 1) for t in times[mode]] for mode in MODES}}


def stale_costs(package, statues) -> dict:
    """Milliseconds of the stale count's work while the preview runs: after an update naming one
    object (one geometry digest, every key), all at once (every digest: an undo), and the bake's
    record of every object."""
    import bpy

    source_record = importlib.import_module(package.__name__ + ".addon.scene.source_record")
    depsgraph = bpy.context.evaluated_depsgraph_get()
    tracker = source_record.tracker()
    tracker.refresh(depsgraph, {statues[0].name_full})
    one = tracker.refresh_ms
    tracker.refresh(depsgraph)
    started = time.perf_counter()
    source_record.record(statues, depsgraph)
    return {"stale_refresh_ms_one_object": round(one, 2), "stale_refresh_ms_all": round(tracker.refresh_ms, 1),
            "record_ms": round(1e3 * (time.perf_counter() - started), 1), "changed": len(tracker.changed)}


SEPARATOR_PX = 4


def picture(preview, scene, *, size, path: Path) -> None:
    """The measured view side by side: the preview off (Blender draws the statues) and on (the
    statues hidden, the HLOD in their place in modulation colours, the corner text)."""
    import bpy
    import gpu

    from hlod_core.core.png import write_png

    place_camera(scene.camera, yaw_deg=0.0)
    halves = []
    offscreen = gpu.types.GPUOffScreen(*size)
    try:
        for on in (False, True):
            if on != preview.running():
                bpy.ops.hlod.preview_toggle()
            for _ in range(3 if on else 1):  # coherent: the front settles over a few frames of the same view
                draw_frame(preview, scene, offscreen, size=size, with_preview=on)
            with offscreen.bind():
                fb = gpu.state.active_framebuffer_get()
                pixels = np.array(fb.read_color(0, 0, size[0], size[1], 4, 0, "UBYTE").to_list(), np.uint8)
            halves.append(pixels.reshape(size[1], size[0], 4)[::-1, :, :3])
    finally:
        offscreen.free()
    separator = np.full((size[1], SEPARATOR_PX, 3), 255, np.uint8)
    write_png(str(path), np.concatenate([halves[0], separator, halves[1]], axis=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spec", type=models.input_file, default=str(ROOT / "tests/scenes/crowd_1m.json"))
    parser.add_argument("--size", default="960x540")
    parser.add_argument("--blocks", type=int, default=3)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--method", default="coh")
    parser.add_argument("--unique-meshes", action="store_true",
                        help="one mesh per object (Blender then draws 144 meshes, not 6 shared by linked duplicates)")
    parser.add_argument("--picture", type=Path)
    parser.add_argument("--work", type=Path, help="folder for the baked file (default: a temporary one)")
    parser.add_argument("--reuse", action="store_true",
                        help="use WORK/crowd.hlod if a bake of the same objects (content keys) made it")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    import bpy
    import gpu

    package = blender_preview.enable_from_source()
    preview = importlib.import_module(package.__name__ + ".addon.preview.live").PREVIEW
    blender_preview.init_gpu()
    bpy.context.preferences.system.viewport_aa = "OFF"  # one sample per frame (module notes)
    scene = bpy.context.scene
    started = time.perf_counter()
    statues = build_scene(args.spec.resolve(), unique_meshes=args.unique_meshes)
    source_tris = sum(len(o.data.polygons) for o in statues)  # the models are triangle meshes
    blender_preview.camera(scene, EYE, TARGET, lens_mm=LENS_MM, clip=(0.05, 500.0))
    work = args.work or Path(tempfile.mkdtemp(prefix="hlod_in_place_"))
    props = scene.hlod
    props.output_path, props.target_tris = str(work / "crowd.hlod"), TARGET_TRIS
    props.method = args.method
    scene_seconds = time.perf_counter() - started
    started = time.perf_counter()
    baked = work / "crowd.hlod"
    if args.reuse and baked.is_file() and _record_matches(package, scene, statues, baked=baked):
        result = ["REUSED"]
    else:
        result = sorted(bpy.ops.hlod.bake())
    bake_seconds = time.perf_counter() - started
    (work / "crowd.record.json").write_text(json.dumps([[item.name, item.key] for item in props.source_objects]))
    out = {"spec": str(args.spec), "objects": len(statues), "source_tris": source_tris, "bake": result,
           "bake_seconds": round(bake_seconds, 1), "scene_seconds": round(scene_seconds, 1), "size": list(size),
           "method": args.method, "unique_meshes": args.unique_meshes, "gpu": gpu.platform.renderer_get(),
           "blender": bpy.app.version_string}
    out.update(measure(preview, scene, size, blocks=args.blocks, frames=args.frames))
    if not preview.running():
        bpy.ops.hlod.preview_toggle()
    out["hidden"] = list(preview.sources_in_place())
    out.update(stale_costs(package, statues))
    if args.picture:
        picture(preview, scene, size=tuple(v * 2 // 3 for v in size), path=args.picture)
        out["picture"] = str(args.picture)
    preview.stop()
    package.unregister()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
    blender_preview.exit_process(0)
