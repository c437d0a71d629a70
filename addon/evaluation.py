"""The Benchmark and Tune to PSNR operators' work: the scene camera's animation as a camera path,
evaluated with every method (hlod_core.report.evaluate, docs/evaluation.md), or searched for the (s, t) with the
fewest drawn nodes that keeps PSNR-Y against Bool at the scene's target (hlod_core.report.tuning), in
a standalone context of the platform's own GL (hlod_core.render.gl_platform: EGL or GLX, WGL, CGL);
Blender's own context, if any, is made current again afterwards
(docs/how-it-works.md#gl-contexts-on-every-platform). Where no context can be made the core raises
GLUnavailable, whose sentence the operators report.

The report's figures need matplotlib, which no Blender ships (4.2 to 5.2) and the extension does not
bundle (about 10 MB of wheels per Python and platform for four PNGs): without it the report is
written without figures, and the operator says so."""
from __future__ import annotations

import importlib.util
import math
import os

import bpy
import numpy as np

from ..hlod_core.core.errors import InputError
from ..hlod_core.io import hlod_file
from ..hlod_core.model.camera_path import CameraPath
from ..hlod_core.render import gl_platform
from ..hlod_core.report import evaluate, tuning
from .preview.live import PREVIEW
from .settings import runtime_settings


def camera_path(scene, depsgraph, size: tuple[int, int], *, what: str = "Benchmark") -> CameraPath:
    """Eye, target (one unit along the view direction) and up of the scene camera at every frame
    of the scene's range and step; projection from the camera at the first frame. `what` names the
    operator in errors."""
    camera = scene.camera
    if camera is None:
        raise InputError(f"{what}: the scene has no camera")
    current = scene.frame_current
    frames = []
    try:
        for f in range(scene.frame_start, scene.frame_end + 1, max(scene.frame_step, 1)):
            scene.frame_set(f)
            m = np.array(camera.matrix_world, np.float64)
            eye = m[:3, 3].copy()
            forward = -m[:3, 2] / np.linalg.norm(m[:3, 2])
            up = m[:3, 1] / np.linalg.norm(m[:3, 1])
            frames.append((eye, eye + forward, up))
        scene.frame_set(scene.frame_start)
        projection = np.array(camera.calc_matrix_camera(depsgraph, x=size[0], y=size[1]), np.float64)
    finally:
        scene.frame_set(current)
    data = camera.data
    near, far = float(data.clip_start), float(data.clip_end)
    if data.type == "ORTHO":
        return CameraPath(frames=np.array(frames), near=near, far=far, fovy_deg=None,
                          ortho_height=2.0 / projection[1, 1])
    if data.type != "PERSP":
        raise InputError(f"{what}: camera {camera.name!r} is {data.type}; use a perspective or orthographic camera")
    return CameraPath(frames=np.array(frames), near=near, far=far,
                      fovy_deg=math.degrees(2.0 * math.atan(1.0 / projection[1, 1])))


def _setup(context, what: str):
    """(hlod, size, path) of the scene: its baked file (the preview's, when running), the render
    resolution, the camera's animation. `what` names the operator in errors."""
    scene = context.scene
    props = scene.hlod
    if not props.file:
        raise InputError(f"{what}: no baked file; run Bake first")
    hlod = PREVIEW.current_hlod() or hlod_file.load(bpy.path.abspath(props.file))
    r = scene.render
    size = (max(1, r.resolution_x * r.resolution_percentage // 100),
            max(1, r.resolution_y * r.resolution_percentage // 100))
    return hlod, size, camera_path(scene, context.evaluated_depsgraph_get(), size, what=what)


def run(context, folder: str, repeat: int) -> tuple[dict, str]:
    """Benchmark: every method on the camera's animation; the report (evaluate's) and its folder."""
    hlod, size, path = _setup(context, "Benchmark")
    os.makedirs(folder, exist_ok=True)
    with gl_platform.keep_current():
        report = evaluate.evaluate(hlod, path, size, methods=list(evaluate.METHOD_SPECS),
                                   settings=runtime_settings(context.scene.hlod), repeat=repeat, out_dir=folder,
                                   psnr_frames=min(20, len(path)), figures=figures_available())
    return report, folder


def tune(context, folder: str, repeat: int) -> tuple[dict, str]:
    """Tune to PSNR: the (s, t) search (hlod_core.report.tuning.tune) at scene.hlod.psnr_target on the
    camera's animation, with the scene's other runtime settings (tau, k, alpha, skip queries); the
    report (with its "psnr_target" section) and its folder. Changes no property: the operator does."""
    props = context.scene.hlod
    target = tuning.check_target(props.psnr_target)
    hlod, size, path = _setup(context, "Tune to PSNR")
    os.makedirs(folder, exist_ok=True)
    with gl_platform.keep_current():
        report = tuning.tune(hlod, path, size, target_db=target, settings=runtime_settings(props), repeat=repeat,
                             out_dir=folder, psnr_frames=min(20, len(path)), figures=figures_available())
    return report, folder


def figures_available() -> bool:
    """Whether matplotlib can be imported in this Blender's Python (see the module notes)."""
    return importlib.util.find_spec("matplotlib") is not None
