"""The preview's private-context mode, for Blender backends moderngl cannot attach to (Metal,
Vulkan) or when "Private Context" is set: the traversal and its queries run in a private headless
EGL context with its own framebuffer and depth pass (Blender's objects then do not occlude the
queries), and the chosen nodes are drawn into the viewport with Blender's gpu module,
depth-tested against Blender's scene.
"""
from __future__ import annotations

import numpy as np

from ..hlod_core.core.colour import modulation_colour
from ..hlod_core.model.hierarchy import Hlod
from ..hlod_core.model.view import View
from ..hlod_core.render.renderer import Renderer
from ..hlod_core.render.residency import StreamingSettings
from ..hlod_core.traversal.methods import make
from ..hlod_core.traversal.settings import RuntimeSettings
from ..hlod_core.traversal.stats import FrameStats
from . import glcontext
from .preview_contexts import GLContexts
from .preview_gpu import NodeBatches


class PrivateMode:
    """The private renderer (on the private context, a framebuffer of the view's size), the
    traversal over it, and the gpu batches that draw its nodes in Blender's context."""

    def __init__(self, hlod: Hlod, *, images: dict[int, np.ndarray]):
        self.hlod = hlod
        self.renderer = None
        self._streaming = None
        self._traversal = None
        self._key = None
        self.batches = NodeBatches(hlod, images=images)

    def draw(self, view: View, *, contexts: GLContexts, method: str, settings: RuntimeSettings,
             modulation: bool, streaming: StreamingSettings | None = None) -> FrameStats:
        """One frame of `method` for `view`: traversed in the private context, the drawn nodes then
        drawn with the gpu module into the bound framebuffer (in modulation colours with
        `modulation`, else in their appearance or the default colour). streaming: the GPU budget
        for node geometry, in the private renderer and for the gpu batches alike (a batch is kept
        only while its node is resident there)."""
        size = (view.width, view.height)
        if self.renderer is not None and (self.renderer.fbo.size != size or self._streaming != streaming):
            self.release_renderer()
        with glcontext.keep_current(), contexts.private() as ctx:  # Blender's is current again after it
            if self.renderer is None:
                self.renderer = Renderer(ctx, self.hlod, size=size, streaming=streaming)
                self._streaming = streaming
            if self._key != (method, settings):
                self._traversal = make(method, self.hlod, self.renderer, settings=settings)
                self._key = (method, settings)
            stats = self._traversal.frame(view)
        colours = modulation_colour(self._traversal.modulation(stats.drawn)) if modulation else None
        self._draw_nodes(stats.drawn, colours=colours, view=view)
        if self.renderer.residency is not None:
            self.batches.keep_only(self.renderer.residency.resident)
        return stats

    def _draw_nodes(self, nodes, *, colours: np.ndarray | None, view: View) -> None:
        """The nodes with the gpu module, depth-tested and written; colours (n, 3) or None."""
        import gpu

        gpu.state.depth_test_set("LESS_EQUAL")
        gpu.state.depth_mask_set(True)
        with gpu.matrix.push_pop():
            gpu.matrix.translate(tuple(float(c) for c in self.hlod.origin))  # float32 positions are origin-relative
            if colours is None and self.hlod.has_appearance:
                self.batches.draw_looks(nodes, tuple(float(v) for v in view.view[2, :3]))
            else:
                self.batches.draw_flat(nodes, colours)
        gpu.state.depth_mask_set(False)
        gpu.state.depth_test_set("NONE")

    def release_renderer(self) -> None:
        """Release the private renderer with its own context current: Renderer.release() deletes
        names in whichever context is current, and in Blender's those names are Blender's objects.
        Blender's context is current again afterwards. Idempotent."""
        renderer, self.renderer = self.renderer, None
        if renderer is None:
            return
        self._traversal, self._key = None, None
        with glcontext.keep_current(), renderer.ctx:
            renderer.release()

    def release(self) -> None:
        """Free everything: the renderer in its own context, then the gpu batches (Blender's
        context must be current). Idempotent."""
        self.release_renderer()
        self.batches.release()

    def hand_over(self) -> list:
        """The renderer released now; the objects made in Blender's context, handed over for
        `GLContexts.hand_over` (a fresh, empty set of batches stays here)."""
        self.release_renderer()
        batches, self.batches = self.batches, NodeBatches(self.hlod, images=self.batches.images)
        return [] if batches.empty else [batches]
