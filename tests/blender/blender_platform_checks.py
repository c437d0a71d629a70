"""Checks of what differs by platform, from Blender's side, one per subprocess
(tests/blender/test_addon_platforms.py runs them):

    python tests/blender/blender_platform_checks.py REPO_DIR CHECK WORK_DIR [ARGUMENTS]

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.

- no_gl_context: a machine where no GL context of the extension's own can be made, made here by
  pointing glcontext at libraries that do not exist ($GLCONTEXT_LINUX_LIBEGL and _LIBX11, which
  the core's gl_platform passes on at every try): Benchmark and Tune to PSNR say so in one
  sentence; the preview, asked for the private context, tests on the CPU and says why; the mode
  rule for every backend (Metal named, as on a Mac); Blender's depth unreadable and the CPU test
  failing too (the gpu module's and numpy's refusals stood in for).
- replaced_file READER: a Re-bake that replaces the .hlod the running preview has open, with the
  file read into memory (READER "memory": the reader Windows uses, hlod_file.maps_files' other
  branch) or memory-mapped ("mapped", POSIX's).
- unicode_paths: a .blend, the output, its bake cache and the temp folder (the bake's scratch) in
  folders whose names have spaces and non-ASCII letters, through the Bake operator and the preview.
"""
from __future__ import annotations

import importlib
import json
import os
import re
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_checks  # it sets $HLOD_GPU_BACKEND's backend, before `import bpy`
import blender_preview

# isort: split
import bpy

NAME = "bl_ext.r.hlod"
SIZE = (320, 240)
#: glcontext's library overrides pointed at nothing: no EGL and no GLX library can be loaded.
NO_GL_LIBRARIES = {"GLCONTEXT_LINUX_LIBEGL": "/nonexistent/libEGL.so.1",
                   "GLCONTEXT_LINUX_LIBX11": "/nonexistent/libX11.so.6"}
#: A Python exception's name in a message (what the artist must never be shown for these cases).
EXCEPTION_NAME = re.compile(r"\b[A-Z]\w*(Error|Exception|Unavailable)\b|Traceback")


def _baked_row(work, *, target_tris: int = 300) -> tuple:
    """The box row of blender_checks baked into WORK/row.hlod, the camera of check_preview: (scene, props)."""
    blender_checks._box_row_scene()
    scene = bpy.context.scene
    props = scene.hlod
    props.output_path, props.target_tris = str(Path(work) / "row.hlod"), target_tris
    assert sorted(bpy.ops.hlod.bake()) == ["FINISHED"]
    blender_preview.camera(scene, eye=(1.5, -8.0, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
    props.method, props.bias, props.show_modulation = "sw", "mu", True
    return scene, props


def _operator_message(operator, **kwargs) -> str:
    """What an operator that reports an error says (bpy.ops raises it as RuntimeError "Error: ..."),
    or "returned: [...]" when it did not fail."""
    try:
        return f"returned: {sorted(operator(**kwargs))}"
    except RuntimeError as exc:
        return str(exc).strip().removeprefix("Error:").strip()


def _frame(package, scene, preview) -> dict:
    frame = blender_checks._draw_checks(package, scene, SIZE, occlude=True)
    stats = preview.last_stats()
    frame.update(running=preview.running(), status=bpy.context.scene.hlod.status,
                 mode=preview.session.mode if preview.session else None,
                 depth_import_ms=stats.depth_import_ms if stats else None)
    return frame


def check_no_gl_context(repo, work) -> dict:
    package = blender_preview.enable_from_repo(repo)
    live = importlib.import_module(NAME + ".addon.preview.live")
    preview = live.PREVIEW
    blender_preview.init_gpu()
    scene, props = _baked_row(work)
    out = {"rule": {f"{backend} private={private} unavailable={unavailable}": live.mode_name(
        SimpleNamespace(private_context=private), backend=backend, private_unavailable=unavailable)
        for backend in ("OPENGL", "METAL", "VULKAN") for private in (False, True) for unavailable in (False, True)}}
    camera = scene.camera
    scene.frame_start, scene.frame_end = 1, 2
    for frame, y in ((1, -8.0), (2, -6.0)):
        camera.location = (1.5, y, 1.5)
        camera.keyframe_insert("location", frame=frame)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 160, 120, 100
    saved = {name: os.environ.get(name) for name in NO_GL_LIBRARIES}
    os.environ.update(NO_GL_LIBRARIES)
    try:
        out["benchmark"] = _operator_message(bpy.ops.hlod.benchmark, directory=str(Path(work) / "report"), repeat=1)
        out["tune"] = _operator_message(bpy.ops.hlod.tune_psnr, directory=str(Path(work) / "tuning"), repeat=1)
        out["report_written"] = (Path(work) / "report" / "report.json").exists()
        props.private_context = True  # on OpenGL the private context is asked for; on Metal and Vulkan it is the rule
        bpy.ops.hlod.preview_toggle()
        for _ in range(2):
            out["cpu"] = _frame(package, scene, preview)
        out["corner"] = [line for line, _ in preview.corner_lines(scene)]
        # Blender's depth cannot be read (the gpu module refusing, stood in for): the preview goes on
        batch_drawn = importlib.import_module(NAME + ".addon.preview.batch_drawn_mode")
        original_read = batch_drawn.read_blender_depth

        def refuse(size):
            raise RuntimeError("the framebuffer has no depth attachment to read")

        batch_drawn.read_blender_depth = refuse
        try:
            out["unreadable"] = _frame(package, scene, preview)
        finally:
            batch_drawn.read_blender_depth = original_read
        # the CPU test failing too (stood in for): no way left, one sentence
        cpu_mode = importlib.import_module(NAME + ".addon.preview.cpu_context_mode")
        original_begin = cpu_mode.BudgetedCpuOcclusion.begin_frame

        def fail(self, view):
            raise MemoryError("cannot allocate the depth buffer")

        cpu_mode.BudgetedCpuOcclusion.begin_frame = fail
        try:
            out["impossible"] = _frame(package, scene, preview)
        finally:
            cpu_mode.BudgetedCpuOcclusion.begin_frame = original_begin
    finally:
        for name, value in saved.items():
            os.environ.pop(name, None) if value is None else os.environ.__setitem__(name, value)
    # GL back: a new preview tries the private context again
    bpy.ops.hlod.preview_toggle()
    out["after"] = _frame(package, scene, preview)
    out["exception_names"] = [text for text in (out["benchmark"], out["tune"], out["cpu"]["status"],
                                                out["unreadable"]["status"], out["impossible"]["status"])
                              if EXCEPTION_NAME.search(text)]
    return out


def _handles(path: Path) -> dict:
    """This process's open descriptors and memory mappings of `path` (or of a file replaced there:
    "path (deleted)"), from /proc/self."""
    target = os.path.realpath(path)
    fds = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            link = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if link.startswith(target):
            fds.append(link)
    with open("/proc/self/maps") as maps:
        mapped = sorted({line.split(maxsplit=5)[5].strip() for line in maps
                         if len(line.split(maxsplit=5)) == 6 and line.split(maxsplit=5)[5].startswith(target)})
    return {"fds": sorted(fds), "maps": mapped}


def check_replaced_file(repo, work, reader: str) -> dict:
    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    hlod_file = importlib.import_module(NAME + ".hlod_core.io.hlod_file")
    if reader == "memory":
        hlod_file.maps_files = lambda platform=None: False  # the branch Windows takes (hlod_file.maps_files)
    blender_preview.init_gpu()
    scene, props = _baked_row(work, target_tris=300)
    path = Path(work) / "row.hlod"
    bpy.ops.hlod.preview_toggle()
    out = {"before": _frame(package, scene, preview), "nodes_before": int(preview.current_hlod().node_count),
           "inode_before": os.stat(path).st_ino, "handles_before": _handles(path)}
    props.target_tris = 120
    out["rebake"] = sorted(bpy.ops.hlod.bake(recorded=True))  # Re-bake: the same file, replaced
    out["inode_after"] = os.stat(path).st_ino
    out["nodes_file"] = int(hlod_file.load(path, mmap=False).node_count)
    out["nodes_after"] = int(preview.current_hlod().node_count) if preview.running() else None
    out["after"] = _frame(package, scene, preview)
    out["handles_after"] = _handles(path)
    bpy.ops.hlod.preview_toggle()
    out["handles_stopped"] = _handles(path)
    return out


def check_unicode_paths(repo, work) -> dict:
    project = Path(work) / "Städte und Straßen" / "Projekt ü é"
    (project / "Bake ñ").mkdir(parents=True)
    temp = Path(work) / "Temp Ünïcødé"
    temp.mkdir()
    tempfile.tempdir = str(temp)  # the bake's scratch folder is made in it (as under a user's name on Windows)
    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    blender_preview.init_gpu()
    blender_checks._box_row_scene()
    blend = project / "Stadt ö.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    props = scene.hlod
    props.output_path, props.target_tris, props.use_cache = "//Bake ñ/city ø.hlod", 300, True
    out = {"blend": str(blend), "bake": sorted(bpy.ops.hlod.bake()), "file": bpy.path.abspath(props.file)}
    out["file_exists"] = Path(out["file"]).is_file()
    out["cache"] = sorted(p.name for p in (project / "Bake ñ").iterdir())
    blender_preview.camera(scene, eye=(1.5, -8.0, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
    props.method, props.bias, props.show_modulation = "sw", "mu", True
    bpy.ops.hlod.preview_toggle()
    out["frame"] = _frame(package, scene, preview)
    bpy.ops.hlod.preview_toggle()
    bpy.ops.wm.save_mainfile()
    out["temp_left"] = sorted(p.name for p in temp.iterdir())
    return out


if __name__ == "__main__":
    repo_dir, check, work_dir, *arguments = sys.argv[1:]
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    result = globals()[f"check_{check}"](repo_dir, work_dir, *arguments)
    print(json.dumps(result, default=str))
    blender_preview.exit_process(0)
