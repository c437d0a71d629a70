"""Drive the add-on in the bpy module, headless (docs/how-it-works.md#the-viewport-preview): enable it (from an installed extension
repository, as Blender does, or from this source folder), initialise the GPU with a 16x16 Workbench
render, and draw the preview through the add-on's own draw path into a gpu.types.GPUOffScreen.

    .venv/bin/python scripts/blender_preview.py FILE.hlod OUT.png [--size 640x480]

draws FILE.hlod from a street-level camera with the modulation overlay (Coh(mu), so occlusion
visibly changes the level of detail) and writes OUT.png; the last stdout line is a JSON summary.
The functions are also what tests/blender/test_addon.py runs in its Blender subprocesses.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.util
import json
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def enable_from_repo(repo_dir: str, module: str = "r"):
    """Register `repo_dir` (made by `blender_ext.py install-files`) as an extension repository and
    enable the add-on in it under its real package name bl_ext.<module>.hlod."""
    import bpy  # first: importing bpy puts Blender's scripts/modules (addon_utils) on sys.path

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


def draw_offscreen(package, scene, size, *, before=None, after=None) -> np.ndarray:
    """Clear a GPUOffScreen (white, depth 1), run before() (Blender-side drawing whose depth the
    preview must respect), the add-on's draw path with the scene camera, then after(); returns the
    pixels (H, W, 4) uint8, bottom row first."""
    import gpu

    preview = importlib.import_module(package.__name__ + ".addon.preview.live").PREVIEW
    view, projection = camera_matrices(scene, size)
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("out")
    parser.add_argument("--size", default="640x480")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    import bpy

    sys.path.insert(0, str(ROOT))
    from hlod_core.io import hlod_file
    from hlod_core.core.png import write_png

    package = enable_from_source()
    preview = importlib.import_module(package.__name__ + ".addon.preview.live").PREVIEW
    init_gpu()
    scene = bpy.context.scene
    hlod = hlod_file.load(args.file)
    lo, hi = hlod.box_min[0], hlod.box_max[0]
    centre = 0.5 * (lo + hi)
    eye = [lo[0] - 0.15 * (hi[0] - lo[0]), lo[1] - 0.1 * (hi[1] - lo[1]), lo[2] + 0.2 * (hi[2] - lo[2])]
    camera(scene, eye, [centre[0], centre[1], lo[2] + 0.1 * (hi[2] - lo[2])])
    props = scene.hlod
    props.file, props.method, props.bias, props.show_modulation = str(Path(args.file).resolve()), "coh", "mu", True
    preview.start(scene)
    pixels = None
    for _ in range(3):  # coherent: let the front settle over a few frames of the same view
        pixels = draw_offscreen(package, scene, size)
    stats = preview.last_stats()
    write_png(args.out, pixels[::-1, :, :3])
    status = preview.status()
    preview.stop()
    package.unregister()
    print(json.dumps({"picture": str(args.out), "drawn_nodes": stats.dn if stats else 0,
                      "queries": stats.queries if stats else 0, "status": status}))


if __name__ == "__main__":
    main()
    exit_process(0)
