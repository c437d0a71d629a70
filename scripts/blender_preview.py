"""Drive the add-on in the bpy module, headless (docs/how-it-works.md#the-viewport-preview): enable it
(from an installed extension repository, as Blender does, or from this source folder), initialise
the GPU with a 16x16 Workbench render, and draw the preview through the add-on's own draw path into
a gpu.types.GPUOffScreen.

    .venv/bin/python scripts/blender_preview.py FILE.hlod OUT.png [--size 640x480]
        [--context auto|blender|private|cpu] [--occluder] [--path CAMERA_PATH.json] [--frames N]
        [--compare-to blender|DIR] [--save-frames DIR] [--method coh] [--bias mu] [--skip-queries MODE]
        [--gpu-backend opengl|vulkan] [--extension-repo REPO_DIR]

draws FILE.hlod with the modulation overlay (Coh(mu) by default, so occlusion visibly changes the
level of detail) and writes the last frame to OUT.png. The views: without --path, N frames (3) of a
street-level camera at a corner of the file's box (a coherent method settles over them); with
--path, the first N frames of a camera path file (the format `hlod_core run` reads; all by default).

- --context: the preview's mode (docs/how-it-works.md#the-previews-modes): `blender`, Blender's own
  OpenGL context (the direct path); `private`, a GL context of the extension's own with Blender's
  depth imported; `cpu`, the CPU occlusion test; `auto` (default), what the preview picks itself
  for this Blender's backend.
- --occluder: a wall drawn into the offscreen's colour and depth before the preview draws, as
  Blender's own objects would be: facing the camera at OCCLUDER_SHARE of the file's box diagonal in
  front of the eye (in front of most of the scene), over the left half of the view.
- --compare-to blender: the same frames drawn again in the blender context (and, with --occluder,
  without it too); DIR: against the frames an earlier run saved with --save-frames DIR (a Blender
  whose backend has no blender context compares with one that has).
- --gpu-backend: start the bpy module with that GPU backend (scripts/blender_gpu_backend.py; checked).

The last stdout line is one JSON object: context (the mode that drew), backend (Blender's), frames,
drawn_nodes_mean, occlusion_tests_mean (queries, or tests on the CPU), depth_import_ms_median
(reading and importing Blender's depth; 0 in the blender context), frame_ms_median, status; with
--compare-to, drawn_nodes_ratio_vs_blender (the mean over frames of nodes drawn here over nodes
drawn there), psnr_y_vs_blender_median and _min, blender_drawn_nodes_mean (and with --occluder and
the blender context run here, blender_no_occluder_drawn_nodes_mean). Exit status 2 for a context
this Blender cannot draw with, 1 when the preview turned off (its status on stderr).
The functions are also what the checks in tests/blender/ run in their Blender processes.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_gpu_backend

ROOT = Path(__file__).resolve().parents[1]

#: --context's names -> the preview's mode names (addon/preview/live.py MODES); auto: its own choice.
CONTEXTS = {"auto": None, "blender": "blender_context", "private": "private_context", "cpu": "cpu"}
#: --occluder: the wall's distance from the eye over the file's root box diagonal, and its colour
#: (linear RGBA, cyan: no node colour of the overlay ramp).
OCCLUDER_SHARE = 0.05
OCCLUDER_COLOUR = (0.0, 0.8, 0.8, 1.0)
FRAMES_WITHOUT_PATH = 3


def enable_from_repo(repo_dir: str, module: str = "r"):
    """Register `repo_dir` (made by `blender_ext.py install-files`) as an extension repository and
    enable the add-on in it under its real package name bl_ext.<module>.hlod."""
    import bpy  # first: importing bpy puts Blender's scripts/modules (addon_utils) on sys.path

    # isort: split
    import addon_utils

    prefs = bpy.context.preferences.extensions
    if not any(r.module == module for r in prefs.repos):
        prefs.repos.new(name=module, module=module, custom_directory=repo_dir, source="USER")
    name = f"bl_ext.{module}.hlod"
    if addon_utils.enable(name, default_set=True, handle_error=_raise) is None:
        raise RuntimeError(f"could not enable {name}")
    return sys.modules[name]


def _raise(exc):
    raise exc


def exit_process(status: int) -> None:
    """End a bpy-module process with `status`. The bpy 4.2 module (4.2.23 LTS, not 5.0.1 or 5.2.3)
    can crash with a segmentation fault after Python has finalised: a C++ static destructor of a
    space type frees a Python-registered class and calls into the finalised interpreter
    (PyGILState_Ensure from bpy_class_free). Which scripts trigger it depends on their handler lists,
    not on their work (removing a load_pre handler is enough), so before 5.0 the process ends here,
    with its output flushed, before those destructors run; 5.0 and later exit normally."""
    import bpy

    if bpy.app.version >= (5, 0, 0):
        sys.exit(status)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


def enable_from_source(name: str = "hlod_source"):
    """Import this folder as a package and register it (for the main job's picture)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    package = importlib.util.module_from_spec(spec)
    sys.modules[name] = package
    spec.loader.exec_module(package)
    package.register()
    return package


def init_gpu() -> None:
    """GPU functions of the bpy module work only after a render has run once (docs/how-it-works.md#gl-queries)."""
    import bpy

    scene = bpy.context.scene
    engine, x, y = scene.render.engine, scene.render.resolution_x, scene.render.resolution_y
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x = scene.render.resolution_y = 16
    bpy.ops.render.render()
    scene.render.engine, scene.render.resolution_x, scene.render.resolution_y = engine, x, y


def camera(scene, eye, target, *, lens_mm: float = 24.0, clip=(0.1, 2000.0)):
    """A scene camera at eye looking at target (Z up), made active."""
    import bpy
    from mathutils import Vector

    data = bpy.data.cameras.new("HLOD test camera")
    data.lens, data.clip_start, data.clip_end = lens_mm, clip[0], clip[1]
    obj = bpy.data.objects.new("HLOD test camera", data)
    scene.collection.objects.link(obj)
    obj.location = Vector(eye)
    obj.rotation_euler = (Vector(target) - Vector(eye)).to_track_quat("-Z", "Y").to_euler()
    scene.camera = obj
    bpy.context.view_layer.update()
    return obj


def camera_matrices(scene, size):
    import bpy

    cam = scene.camera
    view = cam.matrix_world.inverted()
    projection = cam.calc_matrix_camera(bpy.context.evaluated_depsgraph_get(), x=size[0], y=size[1])
    return view, projection


def pixel_projection(size):
    """POST_PIXEL's projection for a region of `size` (width, height): region pixels, origin bottom left."""
    from mathutils import Matrix

    m = Matrix.Identity(4)
    m[0][0], m[1][1], m[0][3], m[1][3] = 2.0 / size[0], 2.0 / size[1], -1.0, -1.0
    return m


def draw_offscreen(package, scene, size, *, before=None, after=None, matrices=None) -> np.ndarray:
    """Clear a GPUOffScreen (white, depth 1), run before() (Blender-side drawing whose depth the
    preview must respect), the add-on's draw path with the scene camera (or `matrices`: view and
    projection, 4x4 numpy or mathutils), then after(); returns the pixels (H, W, 4) uint8, bottom
    row first."""
    import gpu
    from mathutils import Matrix

    preview = importlib.import_module(package.__name__ + ".addon.preview.live").PREVIEW
    view, projection = camera_matrices(scene, size) if matrices is None else matrices
    view = Matrix(np.asarray(view, np.float64).tolist())
    projection = Matrix(np.asarray(projection, np.float64).tolist())
    offscreen = gpu.types.GPUOffScreen(*size)
    try:
        with offscreen.bind():
            fb = gpu.state.active_framebuffer_get()
            fb.clear(color=(1.0, 1.0, 1.0, 1.0), depth=1.0)
            with gpu.matrix.push_pop():
                gpu.matrix.load_matrix(view)
                gpu.matrix.load_projection_matrix(projection)
                if before is not None:
                    before()
                preview.safe_draw(scene, preview.view_from_matrices(view, projection, size))
                if after is not None:
                    after()
            pixels = np.array(fb.read_color(0, 0, size[0], size[1], 4, 0, "UBYTE").to_list(), np.uint8)
    finally:
        offscreen.free()
    return pixels.reshape(size[1], size[0], 4)


def draw_wall(projection, distance: float, *, covered: float = 0.5, colour=OCCLUDER_COLOUR) -> None:
    """Blender-side drawing: a wall facing the camera `distance` model units in front of it, over
    the left `covered` share of the view, into the bound framebuffer's colour and depth (depth test
    and writes on for it). Drawn in clip space: x from -1 to 2 covered - 1, z_ndc of view-space
    z = -distance under `projection` (4x4), the depth hlod_core's depth_import.wall_depth gives."""
    p = np.asarray(projection, np.float64)
    z = -float(distance)
    draw_clip_quad(right=2.0 * covered - 1.0, z_ndc=float((p[2, 2] * z + p[2, 3]) / (p[3, 2] * z + p[3, 3])),
                   colour=colour)


def draw_clip_quad(*, right: float, z_ndc: float, colour) -> None:
    """A quad in clip space from x = -1 to `right`, the whole height, at depth `z_ndc`, in `colour`
    (linear RGBA), into the bound framebuffer's colour and depth (depth test LESS_EQUAL and writes on
    for it, both off after)."""
    import gpu
    from gpu_extras.batch import batch_for_shader
    from mathutils import Matrix

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    with gpu.matrix.push_pop():
        gpu.matrix.load_identity()
        with gpu.matrix.push_pop_projection():
            gpu.matrix.load_projection_matrix(Matrix.Identity(4))
            gpu.state.depth_test_set("LESS_EQUAL")
            gpu.state.depth_mask_set(True)
            quad = [(-1.0, -1.0, z_ndc), (right, -1.0, z_ndc), (right, 1.0, z_ndc), (-1.0, 1.0, z_ndc)]
            batch = batch_for_shader(shader, "TRI_FAN", {"pos": quad})
            shader.uniform_float("color", colour)
            batch.draw(shader)
            gpu.state.depth_mask_set(False)
            gpu.state.depth_test_set("NONE")


class PreviewOff(RuntimeError):
    """The preview turned itself off during a run (the message: its status)."""


def run_frames(package, scene, size, views, *, context: str, wall_m: float | None) -> dict:
    """A fresh preview of scene.hlod.file in `context` (CONTEXTS) over `views` ([(view, projection)]
    numpy 4x4), with the wall `wall_m` in front of the eye (None: none): {"mode", "status",
    "frames": [{"dn", "queries", "depth_import_ms", "frame_ms"}], "pictures": (F, H, W, 3) uint8
    top row first}. PreviewOff when the preview turned itself off."""
    preview = importlib.import_module(package.__name__ + ".addon.preview.live").PREVIEW
    preview.forced_mode = CONTEXTS[context]
    frames, pictures = [], []
    try:
        preview.start(scene)
        for view, projection in views:
            before = None if wall_m is None else (lambda p=projection: draw_wall(p, wall_m))
            pixels = draw_offscreen(package, scene, size, matrices=(view, projection), before=before)
            if not preview.running():
                raise PreviewOff(preview.status())
            stats = preview.last_stats()
            frames.append({"dn": stats.dn, "queries": stats.queries, "depth_import_ms": stats.depth_import_ms,
                           "frame_ms": stats.frame_ms})
            pictures.append(pixels[::-1, :, :3])
        mode, status = preview.session.mode, preview.status()
    finally:
        preview.stop()
        preview.forced_mode = None
    return {"mode": mode, "status": status, "frames": frames, "pictures": np.stack(pictures)}


def summary(run: dict) -> dict:
    """The JSON summary's fields of one run (module notes)."""
    frames = run["frames"]
    names = {mode: name for name, mode in CONTEXTS.items() if mode is not None}
    return {"context": names[run["mode"]], "frames": len(frames),
            "drawn_nodes_mean": statistics.fmean(f["dn"] for f in frames),
            "occlusion_tests_mean": statistics.fmean(f["queries"] for f in frames),
            "depth_import_ms_median": statistics.median(f["depth_import_ms"] for f in frames),
            "frame_ms_median": statistics.median(f["frame_ms"] for f in frames),
            "drawn_nodes": [f["dn"] for f in frames], "status": run["status"]}


def compared(run: dict, reference_dn: list[int], reference_pictures: np.ndarray) -> dict:
    """drawn_nodes_ratio_vs_blender (mean over the frames where the reference drew any of nodes
    here over nodes there), psnr_y_vs_blender_median and _min, blender_drawn_nodes_mean."""
    from hlod_core.report import image_error

    here = [f["dn"] for f in run["frames"]]
    if len(reference_dn) != len(here) or reference_pictures.shape != run["pictures"].shape:
        raise ValueError(f"the reference has {len(reference_dn)} frames of {reference_pictures.shape[1:3]} pixels, "
                         f"this run {len(here)} of {run['pictures'].shape[1:3]}")
    ratios = [a / b for a, b in zip(here, reference_dn) if b > 0]
    psnr_y = [float(image_error.psnr(a, b)[0]) for a, b in zip(run["pictures"], reference_pictures)]
    return {"drawn_nodes_ratio_vs_blender": statistics.fmean(ratios) if ratios else float("nan"),
            "psnr_y_vs_blender_median": statistics.median(psnr_y), "psnr_y_vs_blender_min": min(psnr_y),
            "blender_drawn_nodes_mean": statistics.fmean(reference_dn), "blender_drawn_nodes": list(reference_dn)}


def save_frames(folder: str, run: dict, *, backend: str) -> None:
    """The run's pictures and node counts (frames.npz) and its summary (summary.json) in `folder`."""
    os.makedirs(folder, exist_ok=True)
    np.savez_compressed(Path(folder) / "frames.npz", pictures=run["pictures"],
                        dn=np.array([f["dn"] for f in run["frames"]], np.int64))
    (Path(folder) / "summary.json").write_text(json.dumps({**summary(run), "backend": backend}))


def load_frames(folder: str) -> tuple[list[int], np.ndarray, dict]:
    """(node counts, pictures, summary) that save_frames wrote in `folder`."""
    with np.load(Path(folder) / "frames.npz") as data:
        dn, pictures = data["dn"].tolist(), data["pictures"]
    return dn, pictures, json.loads((Path(folder) / "summary.json").read_text())


def default_views(scene, hlod, size, frames: int) -> list:
    """`frames` copies of the street-level camera at a corner of the file's root box (made the
    scene camera), as (view, projection) numpy 4x4."""
    lo, hi = hlod.box_min[0], hlod.box_max[0]
    centre = 0.5 * (lo + hi)
    eye = [lo[0] - 0.15 * (hi[0] - lo[0]), lo[1] - 0.1 * (hi[1] - lo[1]), lo[2] + 0.2 * (hi[2] - lo[2])]
    camera(scene, eye, [centre[0], centre[1], lo[2] + 0.1 * (hi[2] - lo[2])])
    view, projection = camera_matrices(scene, size)
    return [(np.array(view, np.float64), np.array(projection, np.float64))] * frames


def path_views(path_file: str, size, frames: int | None) -> list:
    """The first `frames` views (all: None) of a camera path file, as (view, projection) numpy 4x4."""
    from hlod_core.model.camera_path import load_path

    path = load_path(path_file)
    views = [path.view(i, size) for i in range(len(path) if frames is None else min(frames, len(path)))]
    return [(v.view, v.projection) for v in views]


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("out")
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--context", choices=list(CONTEXTS), default="auto")
    parser.add_argument("--occluder", action="store_true")
    parser.add_argument("--path", metavar="CAMERA_PATH.json")
    parser.add_argument("--frames", type=int, default=None)
    parser.add_argument("--compare-to", metavar="blender|DIR")
    parser.add_argument("--save-frames", metavar="DIR")
    parser.add_argument("--method", default="coh")
    parser.add_argument("--bias", default="mu", choices=["P", "mu"])
    parser.add_argument("--skip-queries", choices=["off", "cheap", "expected"])
    parser.add_argument("--gpu-backend", choices=list(blender_gpu_backend.BACKENDS))
    parser.add_argument("--extension-repo", metavar="REPO_DIR")
    args = parser.parse_args(argv)
    if args.frames is not None and args.frames < 1:
        parser.error("--frames: expected a whole number >= 1")
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    if args.gpu_backend:
        blender_gpu_backend.force(args.gpu_backend)
    import bpy
    import gpu

    sys.path.insert(0, str(ROOT))
    from hlod_core.core.png import write_png
    from hlod_core.io import hlod_file

    package = enable_from_repo(args.extension_repo) if args.extension_repo else enable_from_source()
    init_gpu()
    if args.gpu_backend:
        blender_gpu_backend.check(args.gpu_backend)
    backend = gpu.platform.backend_type_get()
    if backend != "OPENGL" and "blender" in (args.context, args.compare_to):
        print(f"blender_preview: the blender context needs Blender's OpenGL backend; this Blender draws with "
              f"{backend} (compare with --compare-to DIR, saved by a run with OpenGL)", file=sys.stderr)
        return 2
    scene = bpy.context.scene
    hlod = hlod_file.load(args.file)
    views = (path_views(args.path, size, args.frames) if args.path
             else default_views(scene, hlod, size, args.frames or FRAMES_WITHOUT_PATH))
    wall_m = OCCLUDER_SHARE * float(np.linalg.norm(hlod.box_max[0] - hlod.box_min[0])) if args.occluder else None
    props = scene.hlod
    props.file, props.method, props.bias = str(Path(args.file).resolve()), args.method, args.bias
    props.show_modulation = True
    if args.skip_queries:
        props.skip_queries = args.skip_queries
    try:
        run = run_frames(package, scene, size, views, context=args.context, wall_m=wall_m)
        out = {"picture": str(args.out), "backend": backend, "size": list(size), "method": args.method,
               "occluder": args.occluder, **summary(run)}
        if args.compare_to == "blender":
            reference = run_frames(package, scene, size, views, context="blender", wall_m=wall_m)
            out.update(compared(run, [f["dn"] for f in reference["frames"]], reference["pictures"]))
            if wall_m is not None:
                without = run_frames(package, scene, size, views, context="blender", wall_m=None)
                out["blender_no_occluder_drawn_nodes_mean"] = summary(without)["drawn_nodes_mean"]
        elif args.compare_to:
            dn, pictures, saved = load_frames(args.compare_to)
            out.update(compared(run, dn, pictures), compared_to=args.compare_to, reference_context=saved["context"],
                       reference_backend=saved["backend"])
    except PreviewOff as exc:
        print(f"blender_preview: the preview turned off: {exc}", file=sys.stderr)
        return 1
    finally:
        package.unregister()
    if args.save_frames:
        save_frames(args.save_frames, run, backend=backend)
    write_png(args.out, run["pictures"][-1])
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    exit_process(main())
