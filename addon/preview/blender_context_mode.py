"""The preview drawn in Blender's own GL context: moderngl attached to it, the traversal and its
occlusion queries drawn straight into the bound framebuffer (the viewport's, whose depth already
holds Blender's scene, so Blender's objects occlude the nodes and take part in the queries).
Blender caches GL state: everything the pass changes is saved before and restored after it.
"""
from __future__ import annotations

from ...hlod_core.model.view import View
from ...hlod_core.render import gl_platform
from ...hlod_core.render.gl_state import GLState
from ...hlod_core.render.renderer import Renderer
from ...hlod_core.render.residency import StreamingSettings
from ...hlod_core.traversal.settings import RuntimeSettings
from ...hlod_core.traversal.stats import FrameStats
from .gl_contexts import GLContexts
from .mode import XRAY_NOTE, PreviewMode


class BlenderContextMode(PreviewMode):
    """The renderer made in Blender's context at the first draw (kept while the GPU budget stays),
    the traversal over it (mode.PreviewMode)."""

    def draw(self, view: View, *, contexts: GLContexts, method: str, settings: RuntimeSettings,
             streaming: StreamingSettings | None, overlay: bool) -> FrameStats:
        """One frame into the bound framebuffer with the moderngl context attached to the current
        one, Blender's GL state restored afterwards (mode.PreviewMode.draw)."""
        import gpu

        self.keep_renderer_for(streaming)  # Blender's context, which made it, is current
        ctx = contexts.attach(gl_platform.current_id())
        traversal = self.traversal(method=method, settings=settings, make_renderer=lambda: Renderer(
            ctx, self.hlod, time_gpu=False, images=self.images, streaming=streaming))
        self.renderer.overlay = overlay  # colour is the drawing side's choice
        saved = GLState(self.renderer.gl).save()
        try:
            return traversal.frame(view)
        finally:
            saved.restore()
            gpu.shader.unbind()

    def status_line(self, file_name: str, *, xray: bool) -> str:
        return f"on: {file_name}" + (XRAY_NOTE if xray else "")
