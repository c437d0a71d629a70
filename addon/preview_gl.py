"""The preview's GL mode: moderngl attached to Blender's own context, the traversal and its
occlusion queries drawn straight into the bound framebuffer (the viewport's, whose depth already
holds Blender's scene, so Blender's objects occlude the nodes and take part in the queries).
Blender caches GL state: everything the pass changes is saved before and restored after it.
"""
from __future__ import annotations

import numpy as np

from ..hlod_core.model.hierarchy import Hlod
from ..hlod_core.model.view import View
from ..hlod_core.render.gl_state import GLState
from ..hlod_core.render.renderer import Renderer
from ..hlod_core.render.residency import StreamingSettings
from ..hlod_core.traversal.methods import make
from ..hlod_core.traversal.settings import RuntimeSettings
from ..hlod_core.traversal.stats import FrameStats


class GLMode:
    """The renderer (made in Blender's context at the first draw) and the traversal over it, made
    again when the method or its settings change. `images`: material row -> (h, w, 4) uint8 RGBA."""

    def __init__(self, hlod: Hlod, *, images: dict[int, np.ndarray]):
        self.hlod = hlod
        self.images = images
        self.renderer = None
        self._streaming = None
        self._traversal = None
        self._key = None

    def draw(self, view: View, *, ctx, method: str, settings: RuntimeSettings, overlay: bool,
             streaming: StreamingSettings | None = None) -> FrameStats:
        """One frame of `method` for `view` into the bound framebuffer, with `ctx` (the moderngl
        context attached to the current one) and Blender's GL state restored afterwards.
        overlay: nodes in their modulation colours; streaming: the GPU budget for node geometry (a
        change makes the renderer again)."""
        import gpu

        if self.renderer is not None and self._streaming != streaming:
            self.release()  # Blender's context, which made it, is current
        if self.renderer is None:
            self.renderer = Renderer(ctx, self.hlod, time_gpu=False, images=self.images, streaming=streaming)
            self._streaming = streaming
            self._traversal, self._key = None, None
        if self._key != (method, settings):
            self._traversal = make(method, self.hlod, self.renderer, settings=settings)
            self._key = (method, settings)
        self.renderer.overlay = overlay  # colour is the drawing side's choice
        saved = GLState(self.renderer.gl).save()
        try:
            return self._traversal.frame(view)
        finally:
            saved.restore()
            gpu.shader.unbind()

    def release(self) -> None:
        """Free the renderer now: Blender's context that made it must be current. Idempotent."""
        renderer, self.renderer = self.renderer, None
        self._traversal, self._key = None, None
        if renderer is not None:
            renderer.release()

    def hand_over(self) -> list:
        """The GL objects made in Blender's context, forgotten here (for `GLContexts.hand_over`)."""
        renderer, self.renderer = self.renderer, None
        self._traversal, self._key = None, None
        return [renderer] if renderer is not None else []
