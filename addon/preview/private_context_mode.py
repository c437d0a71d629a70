"""The preview with a private GL context, for Blender backends moderngl cannot attach to (Metal,
Vulkan) or when "Private Context" is set: the traversal and its occlusion queries run in a
standalone context of the platform's own GL (gl_contexts.GLContexts.private: EGL or GLX, WGL,
CGL) with its own framebuffer, into whose depth Blender's depth is imported at each frame's start
(Renderer.set_scene_depth, at full size), so Blender's objects occlude the queries; the chosen
nodes are drawn into the viewport with Blender's gpu module (batch_drawn_mode).
"""
from __future__ import annotations

import time

import numpy as np

from ...hlod_core.model.view import View
from ...hlod_core.render import gl_platform
from ...hlod_core.render.renderer import Renderer
from ...hlod_core.render.residency import StreamingSettings
from ...hlod_core.traversal.settings import RuntimeSettings
from ...hlod_core.traversal.stats import MS_PER_S
from .batch_drawn_mode import BatchDrawnMode
from .gl_contexts import GLContexts


class PrivateContextMode(BatchDrawnMode):
    """The private renderer (on the private context, a framebuffer of the view's size, kept while
    size and GPU budget stay), the traversal over it, and the gpu batches that draw its nodes in
    Blender's context (batch_drawn_mode.BatchDrawnMode)."""

    where = "private context"

    def _frame(self, view: View, *, depth: np.ndarray | None, contexts: GLContexts, method: str,
               settings: RuntimeSettings, streaming: StreamingSettings | None):
        """The frame in the private context, Blender's depth its scene depth; Blender's context is
        current again after it. GLUnavailable when no private context can be made."""
        size = (view.width, view.height)
        self.keep_renderer_for((size, streaming))
        ctx = contexts.private()
        with gl_platform.keep_current(), ctx:
            traversal = self.traversal(method=method, settings=settings, make_renderer=lambda: Renderer(
                ctx, self.hlod, size=size, streaming=streaming, counted_images=self.images))  # the batches draw them
            started = time.perf_counter()
            self.renderer.set_scene_depth(depth)  # checked here, uploaded and written at the frame's start
            handed_ms = (time.perf_counter() - started) * MS_PER_S
            stats = traversal.frame(view)
        stats.depth_import_ms += handed_ms
        stats.frame_ms += handed_ms
        return stats, traversal

    def _release_renderer(self, renderer) -> None:
        """With the private context current: Renderer.release() deletes names in whichever context
        is current, and in Blender's those names are Blender's objects. Blender's context is
        current again afterwards."""
        with gl_platform.keep_current(), renderer.ctx:
            renderer.release()
