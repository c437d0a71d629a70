"""The live viewport preview (docs/how-it-works.md#the-viewport-preview): the HLOD drawn in the 3D
viewport in place of the objects it was baked from, by the chosen traversal, with Blender's objects
occluding the nodes.

`Preview` holds the running preview's state (`Session`: the file, what it hid, its drawing modes,
the last frame's statistics) and its lifecycle: start, a POST_VIEW draw handler that runs the
traversal for the region's View (built once a frame), a POST_PIXEL handler for the corner text,
stop and shutdown. The handlers never raise into Blender: an error turns the preview off and
`status()` says why. The add-on owns one Preview, `PREVIEW`, which the operators, the panels, the
registration and the tests call. Each frame draws with one mode (mode.PreviewMode;
docs/how-it-works.md#the-previews-modes): in Blender's own context where Blender draws with OpenGL
(blender_context_mode), else or when asked in a private GL context with Blender's depth imported
(private_context_mode), and where no such context can be made with the occlusion test on the CPU
(cpu_context_mode). The status line says which.
"""
from __future__ import annotations

import functools
import logging
import traceback
from dataclasses import dataclass

import bpy
import numpy as np

from ...hlod_core.core.errors import GLUnavailable, HlodError
from ...hlod_core.io import hlod_file
from ...hlod_core.model.hierarchy import Hlod
from ...hlod_core.model.view import View
from ...hlod_core.render import gl_platform
from ...hlod_core.traversal.stats import FrameStats
from ..materials.images import material_images
from ..scene import source_hiding, source_record
from ..settings import runtime_settings, streaming_settings
from . import corner_text
from .blender_context_mode import BlenderContextMode
from .box_outlines import draw_boxes
from .cpu_context_mode import CpuContextMode
from .gl_contexts import GLContexts, blender_backend
from .mode import PreviewMode
from .private_context_mode import PrivateContextMode

log = logging.getLogger(__name__)


def redraw() -> None:
    """Tag every 3D viewport for a redraw (its panels and the corner text too)."""
    if bpy.app.background or bpy.context.window_manager is None:
        return
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


BLENDER_CONTEXT, PRIVATE_CONTEXT, CPU_TEST = "blender_context", "private_context", "cpu"
#: The preview's drawing modes by name: each session makes one of each, and draws with one a frame.
MODES: dict[str, type[PreviewMode]] = {BLENDER_CONTEXT: BlenderContextMode, PRIVATE_CONTEXT: PrivateContextMode,
                                       CPU_TEST: CpuContextMode}


def mode_name(props, *, backend: str, private_unavailable: bool) -> str:
    """The mode the next frame draws with, for scene.hlod (`props`) and Blender's GPU `backend`
    (gl_contexts.blender_backend): Blender's context where it is OpenGL, unless Private Context is
    set (moderngl attaches to OpenGL contexts only); else the private context; the CPU occlusion
    test instead when no private context can be made (`private_unavailable`)."""
    if backend == "OPENGL" and not props.private_context:
        return BLENDER_CONTEXT
    return CPU_TEST if private_unavailable else PRIVATE_CONTEXT


@dataclass
class Session:
    """One running preview of `file`. images: material row -> (h, w, 4) uint8 RGBA
    (materials.images); modes: its drawing modes by name (MODES), each made once and kept."""

    file: str
    hlod: Hlod
    images: dict[int, np.ndarray]
    modes: dict[str, PreviewMode]
    source_tris: int = 0  # triangles the bake took (the file's input_tris)
    recorded: int = 0  # objects the scene's record names for this file (0: none recorded)
    hidden: int = 0  # objects hidden for the preview
    stats: FrameStats | None = None  # the last frame's
    mode: str = ""  # the name of the mode that drew the last frame (MODES)
    gl_context: int | None = None  # the native context of the first draw (gl_platform.current_id())
    context_known: bool = False  # gl_context was set (None is a valid "cannot tell")


class Preview:
    """The add-on's one preview: `session` while it runs (else None), the GL contexts it draws with
    (kept across previews) and the draw handlers it installed. forced_mode: a name of MODES every
    frame draws with, whatever the backend and the settings, for measurements and checks
    (scripts/blender_preview.py --context); None: chosen per frame (mode_name)."""

    def __init__(self):
        self.session: Session | None = None
        self.contexts = GLContexts()
        self.forced_mode: str | None = None
        self._status = "off"
        self._handlers: list = []

    # --- what the panel, the operators and the statistics read -------------------------------------

    def status(self) -> str:
        return self._status

    def running(self) -> bool:
        return self.session is not None

    def last_stats(self) -> FrameStats | None:
        return self.session.stats if self.session is not None else None

    def statistic(self, name: str) -> int | float:
        """A field of the last frame's FrameStats (0 without one); `*_ms` fields as float."""
        stats = self.last_stats()
        value = getattr(stats, name, 0) if stats is not None else 0
        return float(value) if name.endswith("_ms") else int(value)

    def sources_in_place(self) -> tuple[int, int]:
        """(objects the record names for the running preview's file, objects it hid); (0, 0) when off."""
        return (self.session.recorded, self.session.hidden) if self.session is not None else (0, 0)

    def current_hlod(self) -> Hlod | None:
        return self.session.hlod if self.session is not None else None

    # --- lifecycle ---------------------------------------------------------------------------------

    def start(self, scene) -> None:
        """Load scene.hlod.file, hide the objects its bake took (the scene's record) and install the
        draw handlers. Raises HlodError for a missing/bad file (then nothing is hidden)."""
        self.stop()
        path = bpy.path.abspath(scene.hlod.file)
        if not scene.hlod.file:
            raise HlodError("no baked file: run Bake first or set Baked File")
        hlod = hlod_file.load(path)
        self.contexts.retry_private()  # a new preview tries again to make the private context
        rows = source_record.stored(scene.hlod, path)
        view_layer, depsgraph = _view_layer_and_depsgraph(scene)
        images = material_images(hlod.materials)
        modes = {name: mode(hlod, images=images) for name, mode in MODES.items()}
        self.session = Session(file=path, hlod=hlod, images=images, modes=modes,
                               source_tris=int(hlod.meta.get("input_tris", 0)), recorded=len(rows))
        self.session.hidden = len(source_hiding.hide(scene, view_layer, [name for name, _ in rows]).entries)
        source_record.track(scene, rows, depsgraph)
        if not bpy.app.background:
            add = bpy.types.SpaceView3D.draw_handler_add
            self._handlers = [add(self._on_post_view, (), "WINDOW", "POST_VIEW"),
                              add(self._on_post_pixel, (), "WINDOW", "POST_PIXEL")]
        self._status = f"on: {bpy.path.basename(path)} ({hlod.node_count} nodes)"
        redraw()

    def stop(self, reason: str | None = None, *, defer_restore: bool = False) -> None:
        """Remove the handlers, free the GL objects (`_release`) and show the hidden sources again.
        defer_restore: from inside Blender's drawing, where data must not change: show them from a
        timer (at once in background mode, which runs no timers). Safe to call when off."""
        for handler in reversed(self._handlers):
            bpy.types.SpaceView3D.draw_handler_remove(handler, "WINDOW")
        self._handlers = []
        session, self.session = self.session, None
        if session is not None:
            self._release(session)
        self.contexts.release_orphans(gl_platform.current_id())
        if self.contexts.orphans:
            log.info("HLOD preview: %d stopped preview(s) made GL objects in a context that is not current; "
                     "they are released at the next draw in it", len(self.contexts.orphans))
        source_record.untrack()
        hidden = source_hiding.hidden()
        if hidden is not None and defer_restore and not bpy.app.background:
            bpy.app.timers.register(functools.partial(_restore_later, hidden), first_interval=0.0)
        else:
            source_hiding.restore()
        self._status = f"off: {reason}" if reason else "off"
        redraw()

    def _release(self, session: Session) -> None:
        """Free the session's GL objects: the private renderer's now (in its own context); those made
        in Blender's context when that context is current (`GLContexts.release_orphans`)."""
        made_in_blender = [resource for mode in session.modes.values() for resource in mode.hand_over()]
        self.contexts.hand_over(session.gl_context, made_in_blender)

    def shutdown(self) -> None:
        """stop(), then free the private context: for unregister, after which nothing is left."""
        self.stop()
        self.contexts.shutdown()

    # --- drawing -----------------------------------------------------------------------------------

    @staticmethod
    def view_from_matrices(view_matrix, window_matrix, size_px: tuple[int, int]) -> View:
        """The View of a region (or a camera): its view and window (projection) matrices, 4x4
        (mathutils or numpy, indexed [row][column], column vectors), and its (width, height) in pixels."""
        view = np.array(view_matrix, np.float64).reshape(4, 4)
        projection = np.array(window_matrix, np.float64).reshape(4, 4)
        eye = np.linalg.inv(view)[:3, 3]
        return View(eye=eye, view=view, projection=projection, width=int(size_px[0]), height=int(size_px[1]))

    def safe_draw(self, scene, view: View, *, xray: bool = False) -> FrameStats | None:
        """draw_view() that never raises: on error the preview turns off and status() says why."""
        return self._guarded(self.draw_view, scene, view, xray=xray)

    def draw_view(self, scene, view: View, *, xray: bool = False) -> FrameStats | None:
        """Run the traversal for `view` and draw into the bound framebuffer (Blender's viewport, or
        a GPUOffScreen in tests), restoring Blender's GL state afterwards. xray: the viewport's X-ray
        is on (said in the status). None when off, or drawing in another window's context."""
        session = self.session
        if session is None or view.width < 1 or view.height < 1:
            return None
        current = gl_platform.current_id()
        self.contexts.release_orphans(current)
        if not session.context_known:
            session.gl_context, session.context_known = current, True
        elif current != session.gl_context:
            self._status = "on: drawing in the first window's context only"
            return None
        props = scene.hlod
        chosen = self.forced_mode or mode_name(props, backend=blender_backend(),
                                               private_unavailable=self.contexts.private_unavailable is not None)
        try:
            stats = self._draw_with(chosen, view, props)
        except GLUnavailable:
            if chosen != PRIVATE_CONTEXT or self.forced_mode is not None:
                raise
            chosen = CPU_TEST  # no private context can be made: the CPU occlusion test from now on
            stats = self._draw_with(chosen, view, props)
        status = session.modes[chosen].status_line(bpy.path.basename(session.file), xray=xray)
        session.stats, session.mode = stats, chosen
        draw_boxes(props, session.hlod, stats)
        self._status = status
        return stats

    def _draw_with(self, chosen: str, view: View, props) -> FrameStats:
        """One frame with the mode named `chosen`; the other modes' objects freed first (a switch of
        modes; Blender's context is current). The CPU mode is told why it draws (the private
        context's failure), unless it was asked for."""
        session = self.session
        for name, mode in session.modes.items():
            if name != chosen:
                mode.release()
        mode = session.modes[chosen]
        if isinstance(mode, CpuContextMode):
            mode.reason = None if self.forced_mode is not None else self.contexts.private_unavailable
        return mode.draw(view, contexts=self.contexts, method=props.method, settings=runtime_settings(props),
                         streaming=streaming_settings(props), overlay=bool(props.show_modulation))

    def corner_lines(self, scene) -> list[tuple[str, bool]]:
        """The corner statistics' (text, is_warning) lines (corner_text.corner_lines); [] when off."""
        session, props = self.session, scene.hlod
        if session is None:
            return []
        tracker = source_record.tracker()
        return corner_text.corner_lines(
            label=corner_text.method_label(props.method, props.bias), stats=session.stats,
            source_tris=session.source_tris, where=getattr(session.modes.get(session.mode), "where", ""),
            changed=len(tracker.changed) if tracker is not None else None, recorded=session.recorded,
            budget_bytes=streaming_settings(props).budget_bytes)

    def draw_corner_text(self, scene, *, left_px: float = 0.0) -> int:
        """The corner statistics (corner_text) drawn into the bound pixel-space projection
        (POST_PIXEL's: region pixels, origin bottom left). Returns the number of lines drawn: 0 when
        the preview is off or scene.hlod.show_corner_text is."""
        if self.session is None or not scene.hlod.show_corner_text:
            return 0
        lines = self.corner_lines(scene)
        corner_text.draw(lines, left_px=left_px, ui_scale=corner_text.effective_ui_scale(bpy.context.preferences))
        return len(lines)

    def _on_post_view(self) -> None:
        """The POST_VIEW handler: the region's View, built once for the frame, drawn."""
        context = bpy.context
        if self.session is None or context.region is None or context.region_data is None:
            return
        self._guarded(self._draw_region, context)

    def _draw_region(self, context) -> FrameStats | None:
        region, rv3d = context.region, context.region_data
        view = self.view_from_matrices(rv3d.view_matrix, rv3d.window_matrix, (region.width, region.height))
        xray = bool(getattr(context.space_data.shading, "show_xray", False))
        return self.draw_view(context.scene, view, xray=xray)

    def _on_post_pixel(self) -> None:
        """The POST_PIXEL handler: the corner text, right of an overlapping toolbar."""
        context = bpy.context
        if self.session is None or context.region is None:
            return
        self._guarded(lambda: self.draw_corner_text(context.scene, left_px=corner_text.toolbar_width_px(context)))

    def _guarded(self, draw, *args, **kwargs):
        """draw(*args, **kwargs), or None after an error, which turns the preview off: nothing may
        escape into Blender's draw loop, and the sources are shown again from a timer."""
        try:
            return draw(*args, **kwargs)
        except HlodError as exc:  # a sentence for the artist: no OpenGL context, a bad file, ...
            log.error("HLOD preview turned off:\n%s", traceback.format_exc())
            self.stop(reason=str(exc), defer_restore=True)
            return None
        except Exception as exc:  # noqa: BLE001 - nothing may escape into Blender's draw loop
            log.error("HLOD preview turned off:\n%s", traceback.format_exc())
            self.stop(reason=f"{type(exc).__name__}: {exc}", defer_restore=True)
            return None


def _view_layer_and_depsgraph(scene):
    """The window's view layer and its evaluated depsgraph when `scene` is the context's, else the
    scene's first view layer and its depsgraph."""
    if bpy.context.scene == scene and bpy.context.view_layer is not None:
        return bpy.context.view_layer, bpy.context.evaluated_depsgraph_get()
    view_layer = scene.view_layers[0]
    return view_layer, view_layer.depsgraph


def _restore_later(hidden) -> None:
    """Timer: show the sources `hidden` holds, unless a newer preview hides its own by now."""
    source_hiding.restore(only=hidden)
    redraw()
    return None  # a timer that returns None runs once


PREVIEW = Preview()  # the add-on's one preview
