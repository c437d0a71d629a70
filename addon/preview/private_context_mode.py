"""The preview with a private GL context, for Blender backends moderngl cannot attach to (Metal,
Vulkan) or when "Private Context" is set: the traversal and its queries run in a private headless
EGL context with its own framebuffer and depth pass (Blender's objects then do not occlude the
queries), and the chosen nodes are drawn into the viewport with Blender's gpu module,
depth-tested against Blender's scene.
"""
from __future__ import annotations

import numpy as np

from ...hlod_core.core.colour import modulation_colour
from ...hlod_core.model.hierarchy import Hlod
from ...hlod_core.model.view import View
from ...hlod_core.render.renderer import Renderer
from ...hlod_core.render.residency import StreamingSettings
from ...hlod_core.traversal.settings import RuntimeSettings
from ...hlod_core.traversal.stats import FrameStats
from . import current_context
from .gl_contexts import GLContexts
from .mode import PreviewMode
from .node_batches import NodeBatches


class PrivateContextMode(PreviewMode):
    """The private renderer (on the private context, a framebuffer of the view's size, kept while
    size and GPU budget stay), the traversal over it (mode.PreviewMode), and the gpu batches that
    draw its nodes in Blender's context."""

    def __init__(self, hlod: Hlod, *, images: dict[int, np.ndarray]):
        super().__init__(hlod, images=images)
        self.batches = NodeBatches(hlod, images=images)

    def draw(self, view: View, *, contexts: GLContexts, method: str, settings: RuntimeSettings,
             streaming: StreamingSettings | None, overlay: bool) -> FrameStats:
        """One frame traversed in the private context, the drawn nodes then drawn with the gpu
        module into the bound framebuffer (in modulation colours with `overlay`, else in their
        appearance or the default colour). The GPU budget holds in the private renderer and for
        the gpu batches alike: a batch is kept only while its node is resident there."""
        size = (view.width, view.height)
        self.keep_renderer_for((size, streaming))
        with current_context.keep_current(), contexts.private() as ctx:  # Blender's is current again after it
            traversal = self.traversal(method=method, settings=settings, make_renderer=lambda: Renderer(
                ctx, self.hlod, size=size, streaming=streaming))
            stats = traversal.frame(view)
        colours = modulation_colour(traversal.modulation(stats.drawn)) if overlay else None
        self._draw_nodes(stats.drawn, colours=colours, view=view)
        if self.renderer.residency is not None:
            self.batches.keep_only(self.renderer.residency.resident)
        return stats

    def status_line(self, file_name: str, *, xray: bool) -> str:
        return f"on (private context): {file_name} - Blender's objects hide the nodes but do not occlude the queries"

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

    def _release_renderer(self, renderer) -> None:
        """With the private context current: Renderer.release() deletes names in whichever context
        is current, and in Blender's those names are Blender's objects. Blender's context is
        current again afterwards."""
        with current_context.keep_current(), renderer.ctx:
            renderer.release()

    def release(self) -> None:
        """Free everything: the renderer in its own context, then the gpu batches (Blender's
        context must be current). Idempotent."""
        self.release_renderer()
        self.batches.release()

    def hand_over(self) -> list:
        """The renderer released now (its context is the mode's own); the gpu batches, made in
        Blender's context, handed over (a fresh, empty set stays here)."""
        self.release_renderer()
        batches, self.batches = self.batches, NodeBatches(self.hlod, images=self.batches.images)
        return [] if batches.empty else [batches]
