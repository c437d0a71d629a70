"""Checks that run inside the real bpy module, one per subprocess (tests/blender/test_addon.py runs them):

    python tests/blender/blender_checks.py REPO_DIR CHECK WORK_DIR

REPO_DIR is an extension repository made by `blender_ext.py install-files` from the built zip; the
add-on is enabled from it as Blender does (bl_ext.r.hlod). Prints one JSON object as its last line.
The same checks run in every Blender of tests/helpers.py BLENDERS (4.2 LTS, 5.0.1, 5.2.3), each with
its own interpreter; what differs between them is handled in the add-on and in
scripts/blender_preview.py (exit_process: bpy 4.2's crash at exit), not here. With $HLOD_GPU_BACKEND
set (tests/blender_runs.py VULKAN) the bpy module starts with that GPU backend
(scripts/blender_gpu_backend.py, before `import bpy`), and the checks that draw check it is the one.
"""
from __future__ import annotations

import gc
import importlib
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import blender_gpu_backend
import blender_preview
from hlod_core.model.view import look_at, perspective

FORCED_BACKEND = blender_gpu_backend.force_from_environment()  # before `import bpy` (module notes)

import bpy  # noqa: E402 - bpy picks its GPU backend while it is imported: after the override above

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
            "cli_command": getattr(sys.modules.get(NAME + ".addon.cli"), "_cli_command", None) is not None,
            "handlers": sum(
                1 for h in bpy.app.handlers.load_pre if getattr(h, "__module__", "").startswith(NAME))}


def _dependency_files() -> dict:
    """Where the extension's dependencies import from, with the add-on enabled: Blender installs the
    wheels of its zip that match its Python into the user's extensions/.local/lib/pythonX.Y/site-packages
    and puts that folder on sys.path."""
    files = {}
    for name in ("pymeshlab", "moderngl", "glcontext", "xatlas"):
        try:
            files[name] = importlib.import_module(name).__file__
        except ImportError as exc:
            files[name] = f"ImportError: {exc}"
    return files


def check_registration(repo, work) -> dict:
    import addon_utils

    package = blender_preview.enable_from_repo(repo)
    out = {"module": package.__name__, "first": _registered(), "blender": list(bpy.app.version[:2]),
           "python": list(sys.version_info[:2]), "dependencies": _dependency_files()}
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
    gather = importlib.import_module(NAME + ".addon.scene.gather").gather
    return gather(bpy.context, [o for o in bpy.context.scene.objects]).mesh


def check_bake(repo, work) -> dict:
    from hlod_core.io import hlod_file

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
    hlod = hlod_file.load(bpy.path.abspath(props.file))
    leaves = hlod.child_count == 0  # the leaves hold the input's triangles: their boxes span its extent
    out.update(file=props.file, nodes=hlod.node_count, input_tris=int(hlod.meta["input_tris"]),
               box_min=hlod.box_min[leaves].min(axis=0).tolist(), box_max=hlod.box_max[leaves].max(axis=0).tolist())
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
    out["exported_nodes"] = hlod_file.load(exported).node_count
    out["export_3dtiles"] = sorted(bpy.ops.hlod.export(filepath=str(Path(work) / "export" / "tiles"), format="3DTILES"))
    tileset = Path(work) / "export" / "tiles" / "tileset.json"
    out["tileset_tiles"] = len(list((tileset.parent / "tiles").glob("*.glb"))) if tileset.is_file() else 0
    out["clear"] = sorted(bpy.ops.hlod.clear())
    out["file_after_clear"] = props.file
    # the modal bake's worker (UI events cannot be made here, the job they drive can): Esc cancels
    # between tasks and writes nothing; a finished job has written its file
    job_mod = importlib.import_module(NAME + ".addon.bake.job")
    scenes = importlib.import_module(NAME + ".hlod_core.io.procedural")
    settings_cls = importlib.import_module(NAME + ".hlod_core.bake.settings").BakeSettings
    city = scenes.default_scene(scale=0.5)
    target = Path(work) / "job" / "city.hlod"
    target.parent.mkdir()
    job = job_mod.BakeJob(city, settings_cls(jobs=1), str(target))
    deadline = time.monotonic() + 120.0  # a hang guard: the child reaches its simplify phase in seconds
    while job.running and job.progress[2] != "simplify" and time.monotonic() < deadline:
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
    out["collection_tris"] = int(hlod_file.load(bpy.path.abspath(props.file)).meta["input_tris"])
    return out


def _occluder_quad() -> None:
    """Blender's own drawing before the preview: a grey quad in clip space at depth -0.9 (near) over
    the left 40% of the view, depth written, so it hides and occludes the nodes behind it."""
    blender_preview.draw_clip_quad(right=-0.2, z_ndc=-0.9, colour=(0.5, 0.5, 0.5, 1.0))


def _green_triangle(shader) -> None:
    """Blender's own drawing after the preview: a green triangle in the top right corner."""
    import gpu
    from gpu_extras.batch import batch_for_shader
    from mathutils import Matrix

    with gpu.matrix.push_pop():
        gpu.matrix.load_identity()
        with gpu.matrix.push_pop_projection():
            gpu.matrix.load_projection_matrix(Matrix.Identity(4))
            tri = [(0.8, 0.8, 0.0), (0.95, 0.8, 0.0), (0.95, 0.95, 0.0)]
            batch = batch_for_shader(shader, "TRIS", {"pos": tri})
            shader.uniform_float("color", (0.0, 1.0, 0.0, 1.0))
            batch.draw(shader)


def _draw_checks(package, scene, size, occlude: bool) -> dict:
    """Draw with a grey occluder over the left 40% of the view (drawn before, with depth) and a green
    triangle after; classify the pixels."""
    import gpu

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    state = {}

    def occluder():
        state["before"] = (gpu.state.depth_mask_get(), gpu.state.depth_test_get(), tuple(gpu.state.viewport_get()))
        if occlude:
            _occluder_quad()

    def green():
        state["after"] = (gpu.state.depth_mask_get(), gpu.state.depth_test_get(), tuple(gpu.state.viewport_get()))
        _green_triangle(shader)

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


#: The panel's statistics (scene.hlod's stat_NAME, panels.STATISTICS) and the field of the preview's
#: FrameStats each shows (stat_resident_mb: resident_bytes in MB; stat_changed is not the frame's).
PANEL_STATISTICS = {"drawn": "dn", "tris": "tris", "queries": "queries", "rarn": "rarn", "d": "d",
                    "stall_ms": "stall_ms", "frame_ms": "frame_ms", "resident_mb": "resident_bytes",
                    "waiting": "waiting"}
#: Eyes (y, m) of a walk toward the row: each frame draws another front, so every counter moves.
WALK_EYES_Y = (-8.0, -6.5, -5.0, -3.5, -2.0)


def _statistics_walk(package, preview, scene, size) -> dict:
    """Frame by frame along a walk toward the row: the panel's statistics after the frame, and the
    same fields of the FrameStats the preview's draw returned for it (recorded as the draw returns
    them); {"panel": [...], "frames": [...]}, one dict per frame."""
    returned = []

    def draw_view(*args, **kwargs):
        stats = type(preview).draw_view(preview, *args, **kwargs)
        returned.append(stats)
        return stats

    preview.draw_view = draw_view  # the instance's attribute: safe_draw looks it up on each draw
    panel, frames = [], []
    try:
        for y in WALK_EYES_Y:
            blender_preview.camera(scene, eye=(1.5, y, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
            blender_preview.draw_offscreen(package, scene, size)
            panel.append({name: getattr(scene.hlod, f"stat_{name}") for name in PANEL_STATISTICS})
            stats = returned[-1]
            frames.append({name: getattr(stats, field) / (2**20 if name == "resident_mb" else 1)
                           for name, field in PANEL_STATISTICS.items()})
    finally:
        del preview.draw_view
    return {"panel": panel, "frames": frames, "draws": len(returned)}


def check_preview(repo, work) -> dict:
    import gpu

    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    blender_preview.init_gpu()
    if FORCED_BACKEND:
        blender_gpu_backend.check(FORCED_BACKEND)
    _box_row_scene()
    scene = bpy.context.scene
    props = scene.hlod
    props.output_path, props.target_tris = str(Path(work) / "row.hlod"), 300
    bpy.ops.hlod.bake()
    blender_preview.camera(scene, eye=(1.5, -8.0, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
    props.method, props.bias, props.show_modulation = "coh", "mu", True
    bpy.ops.hlod.preview_toggle()
    # the backend: OpenGL, Blender's default on Linux in 4.2, 5.0 and 5.2, or the one forced (Vulkan)
    out = {"running": preview.running(), "status_on": props.status, "backend": gpu.platform.backend_type_get()}
    size = (320, 240)
    queries = []  # per frame: Coh may skip every query of a settled frame (results kept, prediction)
    for _ in range(3):
        frame = _draw_checks(package, scene, size, occlude=True)
        queries.append(props.stat_queries)
    out["occluded"], out["mode"], out["status_drawn"] = frame, preview.session.mode, props.status
    out["materialize_front"] = sorted(bpy.ops.hlod.materialize(depth=-1))
    out["front_objects"] = len(bpy.data.collections["HLOD front"].objects)
    out["stats"] = {"drawn": props.stat_drawn, "queries": max(queries), "queries_per_frame": queries,
                    "tris": props.stat_tris, "frame_ms": props.stat_frame_ms}
    out["statistics_walk"] = _statistics_walk(package, preview, scene, size)
    blender_preview.camera(scene, eye=(1.5, -8.0, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
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
    out["benchmark_figures"] = sorted(report["figures"])
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
    offscreen = gpu.types.GPUOffScreen(*size)
    with offscreen.bind():
        preview.safe_draw(scene, preview.view_from_matrices(view, projection, size), xray=True)
    offscreen.free()
    out["status_xray"] = props.status
    # the panel's CHC++ switches (defaults: both on) and Predict New Nodes reach the traversal's settings
    settings_module = importlib.import_module(NAME + ".addon.settings")
    default = settings_module.runtime_settings(props)
    props.multiquery, props.batch_queries = "off", False
    props.predict_new = not props.predict_new
    changed = settings_module.runtime_settings(props)
    out["query_stream_frame"] = _draw_checks(package, scene, size, occlude=True)["ramp_pixels"]
    props.multiquery, props.batch_queries = "on", True
    props.predict_new = not props.predict_new
    out["query_stream"] = [default.multiquery, default.batch_queries, changed.multiquery, changed.batch_queries,
                           default.predict_new, changed.predict_new]
    # an exception inside the draw path turns the preview off and is not raised
    traversal = importlib.import_module(NAME + ".hlod_core.traversal.methods")

    def boom(self, view):
        raise RuntimeError("injected failure")

    original = traversal.Traversal.frame
    traversal.Traversal.frame = boom
    try:
        props.tau = 1.5  # a new traversal object, with the broken frame()
        view, projection = blender_preview.camera_matrices(scene, size)
        out["injected_return"] = repr(preview.safe_draw(scene, preview.view_from_matrices(view, projection, size)))
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



# --- the long session: redraws, file switches, re-bakes, toggles, every method -------------

SESSIONS = 30  # file switches, each followed by a re-bake: five periods of the configuration (6 sessions)
REDRAWS_PER_SESSION = 80  # 30 x 80 = 2,400 redraws: the growth is measured per session (tests/blender/test_addon.py)
METHOD_EVERY = REDRAWS_PER_SESSION // 4  # redraws between method changes: four methods a session
TOGGLE_AT = 3 * REDRAWS_PER_SESSION // 4  # the redraw before which the preview is toggled off and on
LONG_SIZE = (160, 120)  # offscreen pixels: small, so thousands of llvmpipe redraws fit in a minute
CENSUS_MIN_NAMES = 4096  # GL names probed at least (1..4096)


class GLCensus:
    """Counts the GL objects that exist in the current context, independently of the add-on's own
    bookkeeping: every name is probed with glIsBuffer / glIsVertexArray / glIsQuery / glIsProgram
    (and glIsFramebuffer / glIsTexture), resolved through libEGL's eglGetProcAddress and called via
    ctypes. Names run from 1 to the larger of CENSUS_MIN_NAMES and twice the name a fresh
    glGen* / glCreateProgram hands out now (deleted at once): drivers hand out names either in
    increasing order (then every live name is below the fresh one) or lowest-free first (then live
    names stay below the most ever alive at once); the range doubles while a live name lies in its
    upper half. Call inside `offscreen.bind()`, where Blender's context is current."""

    KINDS = {"buffers": ("glIsBuffer", "glGenBuffers", "glDeleteBuffers"),
             "vertex_arrays": ("glIsVertexArray", "glGenVertexArrays", "glDeleteVertexArrays"),
             "queries": ("glIsQuery", "glGenQueries", "glDeleteQueries"),
             "programs": ("glIsProgram", None, None),
             "framebuffers": ("glIsFramebuffer", "glGenFramebuffers", "glDeleteFramebuffers"),
             "textures": ("glIsTexture", "glGenTextures", "glDeleteTextures")}

    def __init__(self):
        import ctypes
        import ctypes.util

        egl = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        self._c = ctypes

        def fn(name, restype, *argtypes):
            address = egl.eglGetProcAddress(name.encode())
            if not address:
                raise RuntimeError(f"GL function {name} not found through eglGetProcAddress")
            return ctypes.CFUNCTYPE(restype, *argtypes)(address)

        u32p = ctypes.POINTER(ctypes.c_uint32)
        self._is = {}
        self._gen = {}
        for kind, (is_name, gen_name, delete_name) in self.KINDS.items():
            self._is[kind] = fn(is_name, ctypes.c_uint8, ctypes.c_uint32)
            if gen_name is not None:
                self._gen[kind] = (fn(gen_name, None, ctypes.c_int32, u32p),
                                   fn(delete_name, None, ctypes.c_int32, u32p))
        self._create_program = fn("glCreateProgram", ctypes.c_uint32)
        self._delete_program = fn("glDeleteProgram", None, ctypes.c_uint32)
        self._get_error = fn("glGetError", ctypes.c_uint32)
        self.largest_name = 0

    def _fresh_name(self, kind: str) -> int:
        if kind == "programs":
            name = int(self._create_program())
            self._delete_program(name)
            return name
        gen, delete = self._gen[kind]
        name = self._c.c_uint32(0)
        gen(1, self._c.byref(name))
        delete(1, self._c.byref(name))
        return int(name.value)

    def count(self) -> dict:
        out = {}
        for kind, is_object in self._is.items():
            limit = max(CENSUS_MIN_NAMES, 2 * self._fresh_name(kind))
            while True:
                live = [name for name in range(1, limit + 1) if is_object(name)]
                if not live or live[-1] <= limit // 2:
                    break
                limit *= 2
            self.largest_name = max(self.largest_name, limit)
            out[kind] = len(live)
        return out

    def drain_errors(self) -> list[int]:
        """Every GL error pending in the current context (glGetError until GL_NO_ERROR)."""
        errors = []
        while (code := int(self._get_error())) != 0 and len(errors) < 16:
            errors.append(code)
        return errors


def _rss_mb() -> float:
    """Resident set size of this process, MB (/proc/self/statm: pages)."""
    import resource

    return int(Path("/proc/self/statm").read_text().split()[1]) * resource.getpagesize() / 1e6


def _orbit_view(hlod, step: int, steps_per_turn: int) -> np.ndarray:
    """The camera on a circle around the baked scene's root box, a little above it, looking at its
    centre: a new view every redraw."""
    lo, hi = hlod.box_min[0], hlod.box_max[0]
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    angle = 2.0 * np.pi * step / steps_per_turn
    distance = radius * (1.1 + 0.5 * np.sin(3.0 * angle))  # moving in and out: the levels of detail change
    eye = centre + distance * np.array([np.cos(angle), np.sin(angle), 0.35])
    return look_at(eye, centre, (0.0, 0.0, 1.0))


def _monkey_scene():
    """File B of the long session: four subdivided monkeys on a plane, all selected."""
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    for i in range(4):
        bpy.ops.mesh.primitive_monkey_add(size=2.0, location=(3.0 * (i % 2), 3.0 * (i // 2), 1.0))
        bpy.context.active_object.modifiers.new("smooth", "SUBSURF").levels = 1
    bpy.ops.mesh.primitive_plane_add(size=12.0, location=(1.5, 1.5, 0.0))
    bpy.ops.object.select_all(action="SELECT")


def _toggle_in_another_context(gl_platform, other) -> bool:
    """Turn the preview off while the moderngl context `other` is current (in Blender: a second
    window's), where the preview's GL objects cannot be released; returns whether it was current."""
    blender = gl_platform.current_id()
    with gl_platform.keep_current(), other:
        was_other = gl_platform.current_id() not in (None, blender)
        bpy.ops.hlod.preview_toggle()
    return was_other


def _blender_drawing(package, scene, size) -> np.ndarray:
    """Blender's own gpu drawing around the preview's pass (the occluder before, the green triangle
    after), from the scene camera; (H, W, 4) uint8."""
    import gpu

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    pixels = None
    for _ in range(3):  # a few frames of the same view, as the viewport redraws
        pixels = blender_preview.draw_offscreen(package, scene, size, before=_occluder_quad,
                                                after=lambda: _green_triangle(shader))
    return pixels


def _drawing_kept(package, preview, scene, size) -> dict:
    """Blender's drawing with the preview off (the reference) and on: wherever Blender drew, the
    pixels with the preview equal the reference. Stop-and-wait waits for every query, so what it
    draws does not depend on timing (the coherent methods' does: they use results as they arrive)."""
    props = scene.hlod
    props.method, props.bias, props.show_modulation, props.private_context = "sw", "mu", True, False
    props.show_boxes = props.show_delayed = props.show_rarn = False
    reference = _blender_drawing(package, scene, size)
    bpy.ops.hlod.preview_toggle()
    with_preview = _blender_drawing(package, scene, size)
    bpy.ops.hlod.preview_toggle()
    blender_drew = np.any(reference[..., :3] != 255, axis=2)
    preview_drew = np.any(with_preview[..., :3] != reference[..., :3], axis=2)
    return {"reference": reference, "with_preview": with_preview,
            "blender_pixels": int(blender_drew.sum()), "preview_pixels": int(preview_drew.sum()),
            "blender_pixels_changed": int((blender_drew & preview_drew).sum())}


def _redraw(preview, scene, offscreen, census, view: np.ndarray, projection: np.ndarray) -> list[int]:
    """One redraw as Blender's viewport does it: clear, Blender's own object (the occluder, depth
    written), the add-on's draw path; returns the GL errors left pending."""
    import gpu
    from mathutils import Matrix

    with offscreen.bind():
        gpu.state.active_framebuffer_get().clear(color=(1.0, 1.0, 1.0, 1.0), depth=1.0)
        with gpu.matrix.push_pop():
            gpu.matrix.load_matrix(Matrix(view.tolist()))
            gpu.matrix.load_projection_matrix(Matrix(projection.tolist()))
            _occluder_quad()
            preview.safe_draw(scene, preview.view_from_matrices(view, projection, LONG_SIZE))
        return census.drain_errors()


def _long_session_files(work: Path) -> list[Path]:
    """The two .blend files the long session switches between (the box row, 5,028 triangles; the
    monkeys, 15,746), each with a scene camera and saved with its baked file's path."""
    files = [work / "boxes.blend", work / "monkeys.blend"]
    for blend, build, target_tris in ((files[0], _box_row_scene, 300), (files[1], _monkey_scene, 1000)):
        bpy.ops.wm.read_homefile(use_empty=True)
        build()
        scene = bpy.context.scene
        scene.hlod.output_path, scene.hlod.target_tris = str(blend.with_suffix(".hlod")), target_tris
        blender_preview.camera(scene, eye=(1.5, -8.0, 1.5), target=(0.0, 6.0, 1.0), lens_mm=30.0)
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        bpy.ops.hlod.bake()
        bpy.ops.wm.save_mainfile()
    return files


def _session(out: dict, *, session: int, blend: Path, preview, gl_platform, other, census, methods) -> None:
    """One session of the long session: load `blend` (load_pre stops a preview left on), census of
    Blender's context, re-bake, then REDRAWS_PER_SESSION redraws with the configuration of
    `session % 6`; the census again (preview on), RSS and Python's allocated blocks."""
    import gpu

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    out["running_after_load"].append(preview.running())
    scene = bpy.context.scene
    props = scene.hlod
    offscreen = gpu.types.GPUOffScreen(*LONG_SIZE)
    with offscreen.bind():
        out["census_stopped"].append(census.count())
    started = time.perf_counter()
    out["bakes"].append(sorted(bpy.ops.hlod.bake()))
    out["bake_seconds"] += time.perf_counter() - started
    props.method = methods[session % len(methods)]
    props.private_context = session % 3 == 2
    props.show_boxes = session % 2 == 1
    props.show_delayed = props.show_rarn = session % 6 == 1
    bpy.ops.hlod.preview_toggle()
    hlod = preview.current_hlod()
    projection = perspective(50.0, LONG_SIZE[0] / LONG_SIZE[1], near=0.1, far=500.0)
    for redraw in range(REDRAWS_PER_SESSION):
        if redraw and redraw % METHOD_EVERY == 0:
            props.method = methods[(session + redraw // METHOD_EVERY) % len(methods)]
        if redraw == REDRAWS_PER_SESSION // 2:
            props.private_context = not props.private_context
        if redraw == TOGGLE_AT:
            if session % 3 == 1:
                out["other_context_current"].append(_toggle_in_another_context(gl_platform, other))
            else:
                bpy.ops.hlod.preview_toggle()
            bpy.ops.hlod.preview_toggle()
        view = _orbit_view(hlod, session * REDRAWS_PER_SESSION + redraw, 240)
        errors = _redraw(preview, scene, offscreen, census, view, projection)
        out["redraws"] += 1
        out["methods_drawn"] = sorted({*out["methods_drawn"], props.method})
        out["private_redraws"] += int(props.private_context)
        if errors:
            out["gl_errors"].append([session, redraw, errors])
        if not preview.running():
            out["turned_off"].append([session, redraw, preview.status()])
            preview.start(scene)
    with offscreen.bind():
        out["census_running"].append(census.count())
    offscreen.free()
    out["rss_mb"].append(round(_rss_mb(), 2))
    gc.collect()
    out["python_blocks"].append(sys.getallocatedblocks())


def check_long_session(repo, work) -> dict:
    """SESSIONS file switches between two .blend files (load_pre stops the preview), each followed by
    a re-bake (the hlod.bake operator's execute path) and REDRAWS_PER_SESSION redraws of the draw
    path in a GPUOffScreen with an orbiting camera and Blender's own occluder; the method changes
    every METHOD_EVERY redraws (every item of scene.hlod.method), the private-context mode flips
    half-way, and the preview is toggled off and on at redraw TOGGLE_AT, every third session while
    another GL context is current. The configuration repeats every 6 sessions. Recorded: the GL
    object census of Blender's context after each load (preview stopped) and at each session's end
    (preview on), the RSS and Python's allocated blocks after each session, the GL errors left
    pending after each redraw, any unplanned stop of the preview, and Blender's own drawing with and
    without the preview at the start and at the end. test_addon runs it with LP_NUM_THREADS=0
    (llvmpipe's rasteriser threads make a one-time RSS jump at a random session): it measures leaks,
    not speed."""
    import gpu

    started = time.perf_counter()
    package = blender_preview.enable_from_repo(repo)
    preview = importlib.import_module(NAME + ".addon.preview.live").PREVIEW
    gl_platform = importlib.import_module(NAME + ".hlod_core.render.gl_platform")
    blender_preview.init_gpu()
    census = GLCensus()
    with gl_platform.keep_current():  # "another window's" context, made once (each costs moderngl ~40 KB)
        other = gl_platform.standalone_context()
    methods = [item.identifier for item in bpy.context.scene.hlod.bl_rna.properties["method"].enum_items]
    files = _long_session_files(Path(work))
    bpy.ops.wm.open_mainfile(filepath=str(files[0]))
    first = _drawing_kept(package, preview, bpy.context.scene, LONG_SIZE)
    out = {"methods": methods, "sessions": SESSIONS, "redraws": 0, "bakes": [], "bake_seconds": 0.0,
           "gl_errors": [], "turned_off": [], "running_after_load": [], "other_context_current": [],
           "census_stopped": [], "census_running": [], "rss_mb": [], "python_blocks": [], "methods_drawn": [],
           "private_redraws": 0}
    sessions_started = time.perf_counter()
    for session in range(SESSIONS):
        _session(out, session=session, blend=files[session % 2], preview=preview, gl_platform=gl_platform,
                 other=other, census=census, methods=methods)
    out["seconds"] = {"redraws_and_loads": round(time.perf_counter() - sessions_started - out["bake_seconds"], 1),
                      "bakes": round(out.pop("bake_seconds"), 1)}
    bpy.ops.wm.open_mainfile(filepath=str(files[0]))  # the same file, camera and baked output as at the start
    out["running_after_load"].append(preview.running())
    last = _drawing_kept(package, preview, bpy.context.scene, LONG_SIZE)
    out["drawing"] = {name: {k: v for k, v in kept.items() if k not in ("reference", "with_preview")}
                      for name, kept in (("first", first), ("last", last))}
    out["reference_same"] = bool(np.array_equal(first["reference"], last["reference"]))
    out["preview_same"] = bool(np.array_equal(first["with_preview"], last["with_preview"]))
    preview.shutdown()  # stop() and free private mode's context (for unregister)
    with gl_platform.keep_current():
        other.release()
    offscreen = gpu.types.GPUOffScreen(*LONG_SIZE)
    with offscreen.bind():
        out["census_end"] = census.count()
    offscreen.free()
    out["census_largest_name"] = census.largest_name
    out["status_end"] = preview.status()
    out["seconds"]["total"] = round(time.perf_counter() - started, 1)
    return out


if __name__ == "__main__":
    repo_dir, check, work_dir = sys.argv[1:4]
    sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
    result = globals()[f"check_{check}"](repo_dir, work_dir)
    print(json.dumps(result))
    blender_preview.exit_process(0)  # bpy 4.2 can crash at exit (see exit_process)
