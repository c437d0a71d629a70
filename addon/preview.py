"""Live viewport preview (DESIGN §7-8): a POST_VIEW draw handler runs the chosen traversal over the
baked hierarchy with the region's view and projection, draws the chosen nodes into Blender's
viewport framebuffer (whose depth already holds Blender's scene, so Blender's objects occlude the
nodes and take part in the occlusion queries), colours them by modulation, and outlines boxes.

GL: moderngl attaches to Blender's context (created once, reused, `gc_mode="context_gc"` so that
no GL call happens from the garbage collector). Blender caches GL state, so everything the pass
changes is saved before and restored after it (`GLState`), then `gpu.shader.unbind()`.
The handler never raises into Blender: an error turns the preview off and `status()` says why.
GL objects are released only while the context they were made in is current (in a draw call, or
when that context is current at unregister/file load); otherwise they are dropped and logged.

Private mode (DESIGN §7 fallback, used when Blender's backend is not OpenGL (Metal, Vulkan) or
when "Private Context" is set): the traversal and its queries run in a private headless context
with its own depth pass (Blender's objects then do not occlude the queries), and the chosen nodes
are drawn into the viewport with Blender's gpu module (flat colour, depth-tested against Blender's
scene). The status line says which mode is on.
"""
from __future__ import annotations

import logging
import traceback
from dataclasses import dataclass

import bpy
import numpy as np

from ..hlod_core import fileformat, metrics
from ..hlod_core.errors import HlodError
from ..hlod_core.hierarchy import node_mesh
from ..hlod_core.metrics import View
from ..hlod_core.traversal import FrameStats, RuntimeSettings
from . import glcontext

log = logging.getLogger(__name__)

BOX_COLOURS = {"box": (0.9, 0.9, 0.9, 0.6), "delayed": (1.0, 0.85, 0.1, 1.0), "rarn": (0.1, 1.0, 0.2, 1.0)}


@dataclass
class _State:
    file: str
    hlod: object
    ctx: object = None
    gl_context: int | None = None
    renderer: object = None
    traversal: object = None
    key: tuple | None = None
    stats: FrameStats | None = None
    private: object = None  # the private-mode Renderer (own context and framebuffer)
    batches: dict | None = None  # private mode: node -> gpu batch


_state: _State | None = None
_handler = None
_status = "off"


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


def current_hlod():
    return _state.hlod if _state is not None else None


def start(scene) -> None:
    """Load scene.hlod.file and install the draw handler. Raises HlodError for a missing/bad file."""
    global _state, _handler, _status
    stop()
    path = bpy.path.abspath(scene.hlod.file)
    if not scene.hlod.file:
        raise HlodError("no baked file: run Bake first or set Baked File")
    hlod = fileformat.load(path)
    _state = _State(file=path, hlod=hlod)
    if not bpy.app.background:
        _handler = bpy.types.SpaceView3D.draw_handler_add(_draw_handler, (), "WINDOW", "POST_VIEW")
    _status = f"on: {bpy.path.basename(path)} ({hlod.node_count} nodes)"
    _redraw()


def stop(reason: str | None = None) -> None:
    """Remove the handler and free GL objects (see module notes). Safe to call when off."""
    global _state, _handler, _status
    if _handler is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handler, "WINDOW")
        _handler = None
    state, _state = _state, None
    if state is not None:
        _release(state)
    _status = f"off: {reason}" if reason else "off"
    _redraw()


def _release(state: _State) -> None:
    if state.private is not None:
        with glcontext.keep_current():
            state.private.release()  # its own context: always safe to release
        state.private = None
    state.batches = None
    if state.renderer is None:
        return
    if state.gl_context is not None and glcontext.current() == state.gl_context:
        state.renderer.release()
    else:
        log.warning("HLOD preview: GL context not current at release; its GL objects are left to Blender")
    state.renderer = None


def _backend() -> str:
    import gpu

    try:
        return gpu.platform.backend_type_get()
    except (AttributeError, SystemError):
        return "OPENGL"


def _redraw() -> None:
    if bpy.app.background or bpy.context.window_manager is None:
        return
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


# --- drawing ---------------------------------------------------------------------------------------

def runtime_settings(props) -> RuntimeSettings:
    return RuntimeSettings(tau=props.tau, s=props.s, t=props.t, k=float("inf") if props.step else props.k,
                           bias=props.bias, alpha=props.alpha, overlay=props.show_modulation)


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


def safe_draw(scene, view_matrix, window_matrix, width, height, *, xray: bool = False) -> FrameStats | None:
    """The handler's body: never raises; on error the preview turns off and status() says why."""
    try:
        return draw_view(scene, view_matrix, window_matrix, width, height, xray=xray)
    except Exception as exc:  # noqa: BLE001 - nothing may escape into Blender's draw loop
        log.error("HLOD preview turned off:\n%s", traceback.format_exc())
        stop(reason=f"{type(exc).__name__}: {exc}")
        return None


def draw_view(scene, view_matrix, window_matrix, width, height, *, xray: bool = False) -> FrameStats | None:
    """Run the traversal and draw into the currently bound framebuffer (Blender's viewport, or a
    GPUOffScreen in tests), restoring Blender's GL state afterwards."""
    global _status
    state = _state
    if state is None or width < 1 or height < 1:
        return None
    import gpu

    from ..hlod_core.renderer import GLState, Renderer
    from ..hlod_core.traversal import make

    props = scene.hlod
    if props.private_context or _backend() != "OPENGL":
        return _draw_private(scene, state, view_matrix, window_matrix, int(width), int(height))
    current = glcontext.current()
    if state.ctx is None:
        import moderngl

        # get_context() attaches through moderngl's default loader, which finds the current EGL/GLX/WGL
        # context (create_context() with settings goes through glcontext's detect mode, which on
        # Linux knows GLX only and fails on the bpy module's EGL context)
        state.ctx = moderngl.get_context()
        state.ctx.gc_mode = "context_gc"
        state.gl_context = current
        state.renderer = Renderer(state.ctx, state.hlod, time_gpu=False)
    elif current != state.gl_context:
        _status = "on: drawing in the first window's context only"
        return None
    settings = runtime_settings(props)
    key = (props.method, settings)
    if state.key != key:
        state.traversal = make(props.method, state.hlod, state.renderer, settings)
        state.key = key
    view = view_from_matrices(view_matrix, window_matrix, width, height)
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

    from ..hlod_core.renderer import Renderer
    from ..hlod_core.traversal import make

    props = scene.hlod
    with glcontext.keep_current():
        if state.private is not None and state.private.fbo.size != (width, height):
            state.private.release()
            state.private, state.key = None, None
        if state.private is None:
            state.private = Renderer.create_standalone(state.hlod, (width, height))
            state.batches = {}
        settings = runtime_settings(props)
        key = ("private", props.method, settings)
        if state.key != key:
            state.traversal = make(props.method, state.hlod, state.private, settings)
            state.key = key
        view = view_from_matrices(view_matrix, window_matrix, width, height)
        with state.private.ctx:
            stats = state.traversal.frame(view)
    colours = metrics.modulation_colour(state.traversal.modulation(stats.drawn)) if props.show_modulation else None
    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    gpu.state.depth_test_set("LESS_EQUAL")
    gpu.state.depth_mask_set(True)
    with gpu.matrix.push_pop():
        gpu.matrix.translate(tuple(float(c) for c in state.hlod.origin))  # float32 positions are origin-relative
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
    edges = metrics.BOX_EDGES
    gpu.state.depth_test_set("LESS_EQUAL")
    for name, nodes in groups:
        nodes = np.asarray(nodes, np.int64)
        corners = metrics.box_corners(hlod.box_min[nodes][:, None], hlod.box_max[nodes][:, None])  # (n, 8, 3)
        lines = corners[:, edges.ravel()].reshape(-1, 3).astype(np.float32)
        batch = batch_for_shader(shader, "LINES", {"pos": lines})
        shader.uniform_float("color", BOX_COLOURS[name])
        batch.draw(shader)
    gpu.state.depth_test_set("NONE")
