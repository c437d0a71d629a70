"""What every way of drawing the preview shares (a mode: `live.Preview` picks one per frame).

A mode keeps a renderer and the traversal over it for one HLOD: the renderer while what it was
made for stays the same (its key: the GPU budget, and for a mode with a framebuffer of its own the
view's size), the traversal while the method and its settings stay the same. Each frame it runs
the traversal for the view and draws the chosen nodes into the bound framebuffer; `release`
frees its GL objects, `hand_over` gives up those made in Blender's context (released there later:
gl_contexts.GLContexts.hand_over). A mode says where its renderer lives: `draw` makes it with
`traversal(make_renderer=...)` in that context, and `_release_renderer` frees it there.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ...hlod_core.model.hierarchy import Hlod
from ...hlod_core.model.view import View
from ...hlod_core.render.residency import StreamingSettings
from ...hlod_core.traversal.methods import make
from ...hlod_core.traversal.settings import RuntimeSettings
from ...hlod_core.traversal.stats import FrameStats
from .gl_contexts import GLContexts

#: Said in the status line while X-ray is on (it clears the depth Blender's objects leave).
XRAY_NOTE = " - X-ray clears the depth: Blender's objects do not occlude the nodes"


class PreviewMode:
    """A renderer and the traversal over it for `hlod` (module notes). images: material row ->
    (h, w, 4) uint8 RGBA, the textures of the drawn nodes."""

    def __init__(self, hlod: Hlod, *, images: dict[int, np.ndarray]):
        self.hlod = hlod
        self.images = images
        self.renderer = None
        self._renderer_key = None  # what the renderer was made for
        self._traversal = None
        self._traversal_key = None  # (method, settings) of the traversal

    # --- what a mode does each frame ------------------------------------------------------------

    def draw(self, view: View, *, contexts: GLContexts, method: str, settings: RuntimeSettings,
             streaming: StreamingSettings | None, overlay: bool) -> FrameStats:
        """One frame of `method` for `view`, drawn into the bound framebuffer (Blender's context is
        current before and after). overlay: the nodes in their modulation colours; streaming: the
        GPU budget for node geometry and textures (None: unlimited)."""
        raise NotImplementedError

    def status_line(self, file_name: str, *, xray: bool) -> str:
        """The panel's status while this mode draws `file_name`; xray: the viewport's X-ray is on."""
        return f"on: {file_name}"

    # --- the cached renderer and traversal ------------------------------------------------------

    def keep_renderer_for(self, key) -> None:
        """Release the renderer if it was made for another `key` (hashable: the GPU budget, a
        size); the next `traversal` then makes one for `key`. Call before making the renderer's
        context current: `_release_renderer` makes it current itself where it has to."""
        if self.renderer is not None and key != self._renderer_key:
            self.release_renderer()
        self._renderer_key = key

    def traversal(self, *, method: str, settings: RuntimeSettings, make_renderer: Callable[[], object]):
        """The traversal of `method` with `settings` over the renderer (made by make_renderer()
        when there is none, with its context current), made again when either changed."""
        if self.renderer is None:
            self.renderer = make_renderer()
            self._traversal, self._traversal_key = None, None
        if self._traversal_key != (method, settings):
            self._traversal = make(method, self.hlod, self.renderer, settings=settings)
            self._traversal_key = (method, settings)
        return self._traversal

    # --- releasing ------------------------------------------------------------------------------

    def release_renderer(self) -> None:
        """Free the renderer (`_release_renderer`) and forget the traversal over it. Idempotent."""
        renderer, self.renderer = self.renderer, None
        self._traversal, self._traversal_key = None, None
        if renderer is not None:
            self._release_renderer(renderer)

    def _release_renderer(self, renderer) -> None:
        """Free `renderer` in the context that made it. Here: that context is current (Blender's,
        during a draw)."""
        renderer.release()

    def release(self) -> None:
        """Free every GL object of the mode now (Blender's context must be current). Idempotent."""
        self.release_renderer()

    def hand_over(self) -> list:
        """Forget the GL objects made in Blender's context and return them, each with an idempotent
        `release()`, for `GLContexts.hand_over`; what lives in a context of the mode's own is
        released now. The mode can draw again afterwards."""
        renderer, self.renderer = self.renderer, None
        self._traversal, self._traversal_key = None, None
        return [renderer] if renderer is not None else []
