"""Live viewport preview (DESIGN §7-8): a POST_VIEW draw handler runs the chosen traversal over the
baked hierarchy with the region's view and projection, draws the chosen nodes into Blender's
viewport framebuffer (whose depth already holds Blender's scene, so Blender's objects occlude the
nodes and take part in the occlusion queries), colours them by modulation, and outlines boxes.

GL: moderngl attaches to Blender's context once per native context (`_contexts`, reused across
file loads and previews, `gc_mode="context_gc"` so that no GL call happens from the garbage
collector). Blender caches GL state, so everything the pass changes is saved before and restored
after it (`GLState`), then `gpu.shader.unbind()`. The handler never raises into Blender: an error
turns the preview off and `status()` says why.

GL objects are deleted only in the context they were made in (a GL delete acts on the current
context's names): the private renderer's with its own context made current; the renderer and the
gpu batches made in Blender's context at once when that context is current (stop, file load,
unregister), otherwise they wait in `_orphans` and are released at the next draw in that context.
Private mode's standalone context is made once and reused (`shutdown()` frees it): moderngl keeps
about 40 KB of every context it creates. tests/test_addon.py's long-session test counts the GL
objects with glIs* probes, RSS and Python's allocated blocks over 10,000 redraws to show this.

Private mode (DESIGN §7 fallback, used when Blender's backend is not OpenGL (Metal, Vulkan) or
when "Private Context" is set): the traversal and its queries run in a private headless context
with its own depth pass (Blender's objects then do not occlude the queries), and the chosen nodes
are drawn into the viewport with Blender's gpu module (depth-tested against Blender's scene). The
status line says which mode is on.

Appearance (issue 13): start() reads the image of every material that names one (the datablock of
the material's Image Texture node, `Material.image`) from bpy.data.images once, as the renderer
takes it (`material_images`: (h, w, 4) uint8 RGBA, sRGB-encoded, top row first); the GL mode's
renderer draws base colour x vertex colour x texture per (node, material). Private mode draws
each node with the gpu module in base colour x vertex colour per vertex, lit as the renderer lights,
and the texture where the material has one (`_look_shader`). The modulation overlay replaces
the colours in both modes.

In place of the sources (issue 20): while the preview runs, the objects the bake took (the scene's
record, addon/source_record.py) are hidden in the viewport (addon/source_hiding.py says how, and how
every way out gives the visibility back), so the HLOD is drawn in their place while Blender's other
objects still draw, occlude the nodes and take part in the queries. A StaleTracker counts the
sources changed since the bake. A POST_PIXEL handler writes the statistics in the viewport's corner
(addon/viewport_text.py; `scene.hlod.show_corner_text`). An error in the draw path stops the
preview there; the sources are then shown again from a timer, outside Blender's drawing.
"""
from __future__ import annotations

import functools
import logging
import traceback
from dataclasses import dataclass

import bpy
import numpy as np

from ..hlod_core.traversal import boxes
from ..hlod_core.io import hlod_file
from ..hlod_core.core import colour as overlay
from ..hlod_core.core.colour import srgb_from_linear
from ..hlod_core.core.errors import HlodError
from ..hlod_core.render.glsl import FLAT_LIGHT, SRGB_FROM_LINEAR
from ..hlod_core.model.hierarchy import node_geometry, node_mesh
from ..hlod_core.model.view import View
from ..hlod_core.traversal.stats import FrameStats
from . import glcontext, source_hiding, source_record, viewport_text
from .settings import runtime_settings

log = logging.getLogger(__name__)

BOX_COLOURS = {"box": (0.9, 0.9, 0.9, 0.6), "delayed": (1.0, 0.85, 0.1, 1.0), "rarn": (0.1, 1.0, 0.2, 1.0)}


@dataclass
class _State:
    file: str
    hlod: object
    ctx: object = None
    gl_context: int | None = None  # the native context of the first draw (glcontext.current())
    context_known: bool = False  # gl_context was set (None is a valid "cannot tell")
    renderer: object = None
    traversal: object = None
    key: tuple | None = None
    stats: FrameStats | None = None
    private: object = None  # the private-mode Renderer (on _private_ctx, own framebuffer)
    batches: dict | None = None  # private mode: node -> gpu batch
    source_tris: int = 0  # triangles the bake took (the file's input_tris)
    recorded: int = 0  # objects the scene's record names for this file (0: none recorded)
    hidden: int = 0  # objects hidden for the preview
    images: dict | None = None  # material row -> (h, w, 4) uint8 RGBA for the renderer (material_images)


@dataclass
class _Orphan:
    """GL objects a stopped preview made in Blender's context `gl_context`, stopped while another
    context was current: released at the next draw (or stop) with `gl_context` current."""

    gl_context: int | None
    renderer: object = None
    batches: dict | None = None


_state: _State | None = None
_handler = None
_text_handler = None
_status = "off"
_contexts: dict = {}  # native GL context id -> the moderngl context attached to it (made once, reused)
_orphans: list[_Orphan] = []
_private_ctx = None  # private mode's standalone context, made once and reused: moderngl never frees
# about 40 KB of every context it creates, so one per start or per viewport size would pile up


def status() -> str:
    return _status


def running() -> bool:
    return _state is not None


def last_stats() -> FrameStats | None:
    return _state.stats if _state is not None else None


def statistic(name: str):
    stats = last_stats()
    value = getattr(stats, name, 0) if stats is not None else 0
    return float(value) if name.endswith("_ms") else int(value)


def sources_in_place() -> tuple[int, int]:
    """(objects the record names for the running preview's file, objects it hid); (0, 0) when off."""
    return (_state.recorded, _state.hidden) if _state is not None else (0, 0)


def current_hlod():
    return _state.hlod if _state is not None else None


def start(scene) -> None:
    """Load scene.hlod.file, hide the objects its bake took (the scene's record) and install the
    draw handlers. Raises HlodError for a missing/bad file (then nothing is hidden)."""
    global _state, _handler, _text_handler, _status
    stop()
    path = bpy.path.abspath(scene.hlod.file)
    if not scene.hlod.file:
        raise HlodError("no baked file: run Bake first or set Baked File")
    hlod = hlod_file.load(path)
    rows = source_record.stored(scene.hlod, path)
    view_layer, depsgraph = _view_layer_and_depsgraph(scene)
    _state = _State(file=path, hlod=hlod, source_tris=int(hlod.meta.get("input_tris", 0)), recorded=len(rows),
                    images=material_images(hlod.materials))
    _state.hidden = len(source_hiding.hide(scene, view_layer, [name for name, _ in rows]).entries)
    source_record.track(scene, rows, depsgraph)
    if not bpy.app.background:
        _handler = bpy.types.SpaceView3D.draw_handler_add(_draw_handler, (), "WINDOW", "POST_VIEW")
        _text_handler = bpy.types.SpaceView3D.draw_handler_add(_draw_text_handler, (), "WINDOW", "POST_PIXEL")
    _status = f"on: {bpy.path.basename(path)} ({hlod.node_count} nodes)"
    redraw()


def _view_layer_and_depsgraph(scene):
    """The window's view layer and its evaluated depsgraph when `scene` is the context's, else the
    scene's first view layer and its depsgraph."""
    if bpy.context.scene == scene and bpy.context.view_layer is not None:
        return bpy.context.view_layer, bpy.context.evaluated_depsgraph_get()
    view_layer = scene.view_layers[0]
    return view_layer, view_layer.depsgraph


def stop(reason: str | None = None, *, defer_restore: bool = False) -> None:
    """Remove the handlers, free GL objects (see module notes) and show the hidden sources again.
    defer_restore: from inside Blender's drawing, where data must not change: show them from a
    timer (at once in background mode, which runs no timers). Safe to call when off."""
    global _state, _handler, _text_handler, _status
    for handler in (_handler, _text_handler):
        if handler is not None:
            bpy.types.SpaceView3D.draw_handler_remove(handler, "WINDOW")
    _handler = _text_handler = None
    state, _state = _state, None
    if state is not None:
        _release(state)
    _release_orphans(glcontext.current())
    if _orphans:
        log.info("HLOD preview: %d stopped preview(s) made GL objects in a context that is not current; "
                 "they are released at the next draw in it", len(_orphans))
    source_record.untrack()
    hidden = source_hiding.hidden()
    if hidden is not None and defer_restore and not bpy.app.background:
        bpy.app.timers.register(functools.partial(_restore_later, hidden), first_interval=0.0)
    else:
        source_hiding.restore()
    _status = f"off: {reason}" if reason else "off"
    redraw()


def _restore_later(hidden) -> None:
    """Timer: show the sources `hidden` holds, unless a newer preview hides its own by now."""
    source_hiding.restore(only=hidden)
    redraw()
    return None  # a timer that returns None runs once


def _release(state: _State) -> None:
    """Free the state's GL objects: the private renderer's now (in its own context); those made in
    Blender's context now if it is current, else at the next draw in it (`_orphans`)."""
    _release_private(state)
    if state.renderer is not None or state.batches:
        _orphans.append(_Orphan(state.gl_context, state.renderer, state.batches))
    state.renderer, state.batches, state.traversal, state.key = None, None, None, None


def shutdown() -> None:
    """stop(), then free private mode's context: for unregister, after which nothing is left."""
    global _private_ctx
    stop()
    if _orphans:
        log.warning("HLOD preview: %d stopped preview(s) left GL objects in a context that is not current",
                    len(_orphans))
    _orphans.clear()
    if _private_ctx is not None:
        with glcontext.keep_current():
            _private_ctx.release()
        _private_ctx = None


def _private_context():
    """Private mode's standalone context (as Renderer.create_standalone makes it), made once."""
    global _private_ctx
    if _private_ctx is None:
        import moderngl

        with glcontext.keep_current():  # a new context is current once made
            _private_ctx = moderngl.create_context(standalone=True, backend="egl", require=330)
    return _private_ctx


def _release_private(state: _State) -> None:
    """Release the private-mode renderer with its own context current: Renderer.release() deletes
    names in whichever context is current, and in Blender's those names are Blender's objects."""
    private, state.private = state.private, None
    if private is None:
        return
    state.traversal, state.key = None, None
    with glcontext.keep_current(), private.ctx:  # Blender's context is current again afterwards
        private.release()


def _release_orphans(current: int | None) -> None:
    """Release the stopped previews' GL objects made in `current`, the context current now, and drop
    moderngl's records of objects already released there (they pile up under "context_gc")."""
    kept = []
    for orphan in _orphans:
        if orphan.gl_context != current:
            kept.append(orphan)
            continue
        if orphan.renderer is not None:
            orphan.renderer.release()
        orphan.renderer, orphan.batches = None, None  # Blender frees the batches' buffers here, now
    _orphans[:] = kept
    ctx = _contexts.get(current)
    if ctx is not None and ctx.objects:
        import moderngl

        unreleased = [obj for obj in ctx.objects if not isinstance(obj, moderngl.InvalidObject)]
        ctx.objects.clear()
        ctx.objects.extend(unreleased)
        ctx.gc()  # objects dropped without release(), made in this context: released here


def _attach(current: int | None):
    """The moderngl context on the native context current now, made once per native context. Not
    `moderngl.get_context()` alone: that is moderngl's process-wide default, which every standalone
    context (private mode, the benchmark) replaces while it lives."""
    ctx = _contexts.get(current)
    if ctx is None:
        import moderngl

        # init_context() attaches through moderngl's default loader, which finds the current
        # EGL/GLX/WGL context (create_context() with settings goes through glcontext's detect
        # mode, which on Linux knows GLX only and fails on the bpy module's EGL context)
        moderngl.init_context()
        ctx = moderngl.get_context()
        ctx.gc_mode = "context_gc"
        _contexts[current] = ctx
    return ctx


def _backend() -> str:
    import gpu

    try:
        return gpu.platform.backend_type_get()
    except (AttributeError, SystemError):
        return "OPENGL"


def redraw() -> None:
    """Tag every 3D viewport for a redraw (its panels and the corner text too)."""
    if bpy.app.background or bpy.context.window_manager is None:
        return
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


# --- images ----------------------------------------------------------------------------------------

def material_images(materials) -> dict[int, np.ndarray]:
    """material row -> its image (`Material.image`, a bpy.data.images name) as the renderer takes
    it: (h, w, 4) uint8 RGBA, sRGB-encoded, top row first. Each datablock is read once; materials
    sharing it share the array (one texture). A name that is not in bpy.data.images, or an image
    without pixels (a missing file), logs a warning: the material draws in its base colour."""
    out, read = {}, {}
    for row, material in enumerate(materials):
        if not material.image:
            continue
        if material.image not in read:
            image = bpy.data.images.get(material.image)
            read[material.image] = image_rgba8(image) if image is not None else None
            if read[material.image] is None:
                log.warning("HLOD preview: material %r: image %r %s; drawn in its base colour", material.name,
                            material.image, "is not in this .blend" if image is None else "has no pixels")
        if read[material.image] is not None:
            out[row] = read[material.image]
    return out


def image_rgba8(image) -> np.ndarray | None:
    """A bpy image's pixels as (h, w, 4) uint8 RGBA, sRGB-encoded, top row first (Blender's rows are
    bottom row first); None when it has none. Byte images hold their file's (sRGB) values, float
    images (is_float) linear ones, which are encoded here."""
    width, height = (int(v) for v in image.size)
    channels = int(image.channels)
    if width < 1 or height < 1 or channels not in (1, 2, 3, 4):
        return None
    values = np.empty(width * height * channels, np.float32)
    image.pixels.foreach_get(values)
    values = values.reshape(height, width, channels)
    rgba = np.ones((height, width, 4), np.float32)
    if channels >= 3:
        rgba[..., :channels] = values
    else:  # grey, grey + alpha
        rgba[..., :3] = values[..., :1]
        rgba[..., 3] = values[..., -1] if channels == 2 else 1.0
    if image.is_float:
        rgba[..., :3] = srgb_from_linear(rgba[..., :3])
    return np.ascontiguousarray(np.round(np.clip(rgba[::-1], 0.0, 1.0) * 255.0).astype(np.uint8))




# --- drawing ---------------------------------------------------------------------------------------

def view_from_matrices(view_matrix, window_matrix, width: int, height: int) -> View:
    view = np.array(view_matrix, np.float64).reshape(4, 4)
    projection = np.array(window_matrix, np.float64).reshape(4, 4)
    eye = np.linalg.inv(view)[:3, 3]
    return View(eye=eye, view=view, projection=projection, width=int(width), height=int(height))


def _draw_handler() -> None:
    context = bpy.context
    region, rv3d = context.region, context.region_data
    if _state is None or region is None or rv3d is None:
        return
    xray = bool(getattr(context.space_data.shading, "show_xray", False))
    safe_draw(context.scene, rv3d.view_matrix, rv3d.window_matrix, region.width, region.height, xray=xray)


def _draw_text_handler() -> None:
    context = bpy.context
    if _state is None or context.region is None:
        return
    try:
        draw_corner_text(context.scene, left_px=_toolbar_px(context))
    except Exception as exc:  # noqa: BLE001 - nothing may escape into Blender's draw loop
        log.error("HLOD preview turned off:\n%s", traceback.format_exc())
        stop(reason=f"{type(exc).__name__}: {exc}", defer_restore=True)


def _toolbar_px(context) -> float:
    """Width of the toolbar where it overlaps the region (Region Overlap on), else 0."""
    if context.area is None or not context.preferences.system.use_region_overlap:
        return 0.0
    return float(next((r.width for r in context.area.regions if r.type == "TOOLS"), 0))


def draw_corner_text(scene, *, left_px: float = 0.0) -> int:
    """The corner statistics (viewport_text), drawn into the bound pixel-space projection (POST_PIXEL's:
    region pixels, origin bottom left). Returns the number of lines drawn: 0 when the preview is
    off or scene.hlod.show_corner_text is."""
    state, props = _state, scene.hlod
    if state is None or not props.show_corner_text:
        return 0
    tracker = source_record.tracker()
    lines = viewport_text.corner_lines(
        label=viewport_text.method_label(props.method, props.bias), stats=state.stats, source_tris=state.source_tris,
        private=bool(props.private_context) or _backend() != "OPENGL",
        changed=len(tracker.changed) if tracker is not None else None, recorded=state.recorded)
    viewport_text.draw(lines, left_px=left_px, ui_scale=_ui_scale())
    return len(lines)


def _ui_scale() -> float:
    """The effective UI scale (display DPI and the Resolution Scale preference); the bpy module,
    with no window, leaves the effective one at 0: then the preference alone."""
    prefs = bpy.context.preferences
    return float(prefs.system.ui_scale or prefs.view.ui_scale or 1.0)


def safe_draw(scene, view_matrix, window_matrix, width, height, *, xray: bool = False) -> FrameStats | None:
    """The handler's body: never raises; on error the preview turns off and status() says why."""
    try:
        return draw_view(scene, view_matrix, window_matrix, width, height, xray=xray)
    except Exception as exc:  # noqa: BLE001 - nothing may escape into Blender's draw loop
        log.error("HLOD preview turned off:\n%s", traceback.format_exc())
        stop(reason=f"{type(exc).__name__}: {exc}", defer_restore=True)
        return None


def draw_view(scene, view_matrix, window_matrix, width, height, *, xray: bool = False) -> FrameStats | None:
    """Run the traversal and draw into the currently bound framebuffer (Blender's viewport, or a
    GPUOffScreen in tests), restoring Blender's GL state afterwards."""
    global _status
    state = _state
    if state is None or width < 1 or height < 1:
        return None
    import gpu

    from ..hlod_core.render.gl_state import GLState
    from ..hlod_core.render.renderer import Renderer
    from ..hlod_core.traversal.methods import make

    props = scene.hlod
    current = glcontext.current()
    _release_orphans(current)
    if not state.context_known:
        state.gl_context, state.context_known = current, True
    elif current != state.gl_context:
        _status = "on: drawing in the first window's context only"
        return None
    if props.private_context or _backend() != "OPENGL":
        if state.renderer is not None:  # switched modes: free the other mode's objects (current here)
            state.renderer.release()
            state.renderer, state.traversal, state.key = None, None, None
        return _draw_private(scene, state, view_matrix, window_matrix, int(width), int(height))
    _release_private(state)
    state.batches = None
    if state.renderer is None:
        state.ctx = _attach(current)
        state.renderer = Renderer(state.ctx, state.hlod, time_gpu=False, images=state.images)
        state.traversal, state.key = None, None
    settings = runtime_settings(props)
    key = (props.method, settings)
    if state.key != key:
        state.traversal = make(props.method, state.hlod, state.renderer, settings)
        state.key = key
    view = view_from_matrices(view_matrix, window_matrix, width, height)
    state.renderer.overlay = bool(props.show_modulation)  # colour is the drawing side's choice
    saved = GLState(state.renderer.gl).save()
    try:
        stats = state.traversal.frame(view)
    finally:
        saved.restore()
        gpu.shader.unbind()
    state.stats = stats
    _draw_boxes(props, state, stats)
    _status = (f"on: {bpy.path.basename(state.file)}" +
               (" - X-ray clears the depth: Blender's objects do not occlude the nodes" if xray else ""))
    return stats


def _draw_private(scene, state, view_matrix, window_matrix, width: int, height: int) -> FrameStats:
    """The fallback: traverse in a private context, draw the chosen nodes with the gpu module."""
    global _status
    import gpu

    from ..hlod_core.render.renderer import Renderer
    from ..hlod_core.traversal.methods import make

    props = scene.hlod
    if state.private is not None and state.private.fbo.size != (width, height):
        _release_private(state)
    with glcontext.keep_current(), _private_context() as ctx:  # Blender's is current again after it
        if state.private is None:
            state.private = Renderer(ctx, state.hlod, size=(width, height))
        settings = runtime_settings(props)
        key = ("private", props.method, settings)
        if state.key != key:
            state.traversal = make(props.method, state.hlod, state.private, settings)
            state.key = key
        stats = state.traversal.frame(view_from_matrices(view_matrix, window_matrix, width, height))
    if state.batches is None:
        state.batches = {}
    colours = overlay.modulation_colour(state.traversal.modulation(stats.drawn)) if props.show_modulation else None
    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.depth_mask_set(True)
    with gpu.matrix.push_pop():
        gpu.matrix.translate(tuple(float(c) for c in state.hlod.origin))  # float32 positions are origin-relative
        if colours is None and state.hlod.has_appearance:
            _draw_looks(state, stats.drawn, view_matrix)
        else:
            shader = gpu.shader.from_builtin("UNIFORM_COLOR")
            for i, node in enumerate(stats.drawn):
                batch = state.batches.get(node) or state.batches.setdefault(node, _node_batch(shader, state.hlod, node))
                colour = tuple(colours[i]) if colours is not None else (0.82, 0.80, 0.76)
                shader.uniform_float("color", (*colour, 1.0))
                batch.draw(shader)
    gpu.state.depth_mask_set(False)
    gpu.state.depth_test_set("NONE")
    state.stats = stats
    _draw_boxes(props, state, stats)
    _status = (f"on (private context): {bpy.path.basename(state.file)} - "
               "Blender's objects hide the nodes but do not occlude the queries")
    return stats


def _node_batch(shader, hlod, node: int):
    from gpu_extras.batch import batch_for_shader

    positions, faces, _ = node_mesh(hlod, node)
    return batch_for_shader(shader, "TRIS", {"pos": positions}, indices=faces.astype(np.int32))


# Private mode's appearance shader: colour = base colour x vertex colour (per vertex, linear) x the
# material's texture (a white texel without one), lit by the renderer's flat term 0.25 + 0.75 |n_z|
# (n in view space: the face normal in world space dotted with the view's z axis), written
# sRGB-encoded unless the framebuffer encodes itself (srgbTarget: set by Blender for every shader
# that declares it, as its own shaders do).
_LOOK_VS = """
void main() {
    v_pos = pos;
    v_color = color;
    v_uv = uv;
    gl_Position = ModelViewProjectionMatrix * vec4(pos, 1.0);
}
"""
_LOOK_FS = SRGB_FROM_LINEAR + FLAT_LIGHT + """
void main() {
    vec3 lit = (v_color * texture(u_image, v_uv)).rgb * flat_light(v_pos, u_view_z);
    FragColor = vec4(srgbTarget ? lit : srgb_from_linear(lit), 1.0);
}
"""


def _look_shader():
    """(shader, white 1x1 texture) of private mode's appearance drawing (the notes above)."""
    import gpu

    info = gpu.types.GPUShaderCreateInfo()
    info.push_constant("MAT4", "ModelViewProjectionMatrix")
    info.push_constant("VEC3", "u_view_z")
    info.push_constant("BOOL", "srgbTarget")
    info.sampler(0, "FLOAT_2D", "u_image")
    for slot, (kind, name) in enumerate((("VEC3", "pos"), ("VEC4", "color"), ("VEC2", "uv"))):
        info.vertex_in(slot, kind, name)
    varyings = gpu.types.GPUStageInterfaceInfo("hlod_look")
    for kind, name in (("VEC3", "v_pos"), ("VEC4", "v_color"), ("VEC2", "v_uv")):
        varyings.smooth(kind, name)
    info.vertex_out(varyings)
    info.fragment_out(0, "VEC4", "FragColor")
    info.vertex_source(_LOOK_VS)
    info.fragment_source(_LOOK_FS)
    white = gpu.types.GPUTexture((1, 1), format="RGBA8", data=gpu.types.Buffer("FLOAT", 4, [1.0, 1.0, 1.0, 1.0]))
    return gpu.shader.create_from_info(info), white


def _draw_looks(state, nodes, view_matrix) -> None:
    """Private mode: the nodes in their materials, vertex colours and textures (_look_shader). The
    shader, the textures and each node's batches are made at first use and kept in state.batches
    (released with them)."""
    import gpu

    batches = state.batches
    if "look" not in batches:
        batches["look"] = _look_shader()
        batches["look textures"] = {row: gpu.texture.from_image(bpy.data.images[material.image])
                                    for row, material in enumerate(state.hlod.materials)
                                    if row in (state.images or {})}
    shader, white = batches["look"]
    textures = batches["look textures"]
    shader.bind()
    shader.uniform_float("u_view_z", tuple(float(v) for v in np.array(view_matrix, np.float64).reshape(4, 4)[2, :3]))
    for node in nodes:
        key = ("look", int(node))
        if key not in batches:
            batches[key] = _look_batches(shader, state.hlod, int(node))
        for material, batch in batches[key]:
            shader.uniform_sampler("u_image", textures.get(material, white))
            batch.draw(shader)


def _look_batches(shader, hlod, node: int) -> list:
    """[(material row or -1, batch)] of one node: its triangles per material, each vertex coloured
    base colour x vertex colour (linear), with its UVs (0 without)."""
    from gpu_extras.batch import batch_for_shader

    from ..hlod_core.render.renderer import NO_MATERIAL_BASE_COLOR

    g = node_geometry(hlod, node)
    face_material = g.face_material if g.face_material is not None else np.full(g.faces.shape[0], -1, np.int32)
    bases = np.array([m.base_color for m in hlod.materials] + [NO_MATERIAL_BASE_COLOR], np.float32)  # row -1: none
    out = []
    for material in np.unique(face_material).tolist():
        used, faces = np.unique(g.faces[face_material == material], return_inverse=True)
        colour = np.broadcast_to(bases[material], (used.size, 4))
        if g.colors is not None:
            colour = colour * g.colors[used]
        uvs = g.uvs[used] if g.uvs is not None else np.zeros((used.size, 2), np.float32)
        content = {"pos": g.positions[used], "color": np.ascontiguousarray(colour, np.float32), "uv": uvs}
        out.append((material, batch_for_shader(shader, "TRIS", content, indices=faces.reshape(-1, 3).astype(np.int32))))
    return out


def _draw_boxes(props, state, stats: FrameStats) -> None:
    """Node box outlines with Blender's own gpu module (after the GL state is restored)."""
    groups = []
    if props.show_boxes:
        groups.append(("box", stats.drawn))
    if props.show_delayed:
        groups.append(("delayed", stats.delayed))
    if props.show_rarn:
        groups.append(("rarn", stats.refined_after_draw))
    groups = [(name, nodes) for name, nodes in groups if nodes]
    if not groups:
        return
    import gpu
    from gpu_extras.batch import batch_for_shader

    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    hlod = state.hlod
    edges = boxes.BOX_EDGES
    gpu.state.depth_test_set("LESS_EQUAL")
    for name, nodes in groups:
        nodes = np.asarray(nodes, np.int64)
        corners = boxes.box_corners(hlod.box_min[nodes][:, None], hlod.box_max[nodes][:, None])  # (n, 8, 3)
        lines = corners[:, edges.ravel()].reshape(-1, 3).astype(np.float32)
        batch = batch_for_shader(shader, "LINES", {"pos": lines})
        shader.uniform_float("color", BOX_COLOURS[name])
        batch.draw(shader)
    gpu.state.depth_test_set("NONE")
