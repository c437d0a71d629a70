"""What the modes share whose occlusion tests run outside Blender's context (the private GL
context, the CPU occlusion test; docs/how-it-works.md#the-previews-modes): each frame Blender's
depth is read from the bound framebuffer in the draw handler and handed to the renderer the tests
run on, so that Blender's objects occlude the nodes there as they hide them on screen; the
traversal runs there; the nodes it chose are drawn into the bound framebuffer with Blender's gpu
module (node_batches), depth-tested against Blender's scene.

Data form: the depth is (h, w) float32 window depth, 1 the far plane, row 0 the bottom row, as
`GPUFrameBuffer.read_depth` gives it on every backend (hlod_core/render/depth_import.py). What reading
and handing it over cost is added to the frame's `depth_import_ms` and `frame_ms` (the corner text
shows both).
"""
from __future__ import annotations

import logging
import time

import numpy as np

from ...hlod_core.core.colour import modulation_colour
from ...hlod_core.model.hierarchy import Hlod
from ...hlod_core.model.view import View
from ...hlod_core.render.residency import StreamingSettings
from ...hlod_core.traversal.settings import RuntimeSettings
from ...hlod_core.traversal.stats import MS_PER_S, FrameStats
from .gl_contexts import GLContexts
from .mode import XRAY_NOTE, PreviewMode
from .node_batches import NodeBatches

log = logging.getLogger(__name__)


def read_blender_depth(size: tuple[int, int]) -> np.ndarray:
    """The bound framebuffer's depth over (width, height) pixels from its origin: (h, w) float32
    (module notes). Read into a one-dimensional gpu Buffer, which numpy takes as it is: the
    two-dimensional Buffer read_depth makes by itself states column-major strides over row-major
    data in Blender 4.2 and 5.0 (fixed by 5.2), so numpy would read it transposed. Raises what
    Blender's gpu module raises when it cannot read it. Values outside [0, 1] or NaN (a depth
    buffer nobody cleared: Vulkan leaves a new one undefined) are taken as the far plane or clamped:
    they must not turn the preview off, and the far plane hides nothing."""
    import gpu

    w, h = size
    buffer = gpu.types.Buffer("FLOAT", w * h)
    gpu.state.active_framebuffer_get().read_depth(0, 0, w, h, data=buffer)
    depth = np.asarray(buffer, np.float32).reshape(h, w)
    if not (depth.min() >= 0.0 and depth.max() <= 1.0):  # NaN fails both
        depth = np.clip(np.nan_to_num(depth, nan=1.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    return depth


class BatchDrawnMode(PreviewMode):
    """A mode whose renderer tests occlusion outside Blender's context (module notes); a subclass
    says where in `_frame`. batches: the gpu module objects that draw the chosen nodes.
    depth_unreadable: why Blender's depth could not be read at the last frame (None: it was)."""

    #: The status line's words for where the tests run.
    where = ""

    def __init__(self, hlod: Hlod, *, images: dict[int, np.ndarray]):
        super().__init__(hlod, images=images)
        self.batches = NodeBatches(hlod, images=images)
        self.depth_unreadable: str | None = None

    def draw(self, view: View, *, contexts: GLContexts, method: str, settings: RuntimeSettings,
             streaming: StreamingSettings | None, overlay: bool) -> FrameStats:
        """Blender's depth read, one frame traversed where the tests run (`_frame`), the chosen nodes
        drawn with the gpu module into the bound framebuffer (in modulation colours with `overlay`,
        else in their appearance or the default colour). Under a GPU budget a batch is kept only
        while its node is resident in the renderer's bookkeeping, a texture while a resident node
        draws with it."""
        started = time.perf_counter()
        depth = self._blender_depth((view.width, view.height))
        read_ms = (time.perf_counter() - started) * MS_PER_S
        stats, traversal = self._frame(view, depth=depth, contexts=contexts, method=method, settings=settings,
                                       streaming=streaming)
        stats.depth_import_ms += read_ms
        stats.frame_ms += read_ms
        colours = modulation_colour(traversal.modulation(stats.drawn)) if overlay else None
        self._draw_nodes(stats.drawn, colours=colours, view=view)
        residency = getattr(self.renderer, "residency", None)
        if residency is not None:
            self.batches.keep_only(residency.resident, self.renderer.texture_table.rows_resident(
                residency.texture_resident))
        return stats

    def _frame(self, view: View, *, depth: np.ndarray | None, contexts: GLContexts, method: str,
               settings: RuntimeSettings, streaming: StreamingSettings | None):
        """(stats, traversal) of one frame of `method` for `view` with Blender's `depth` (None: not
        read) as the scene depth, run where this mode's tests run."""
        raise NotImplementedError

    def _blender_depth(self, size: tuple[int, int]) -> np.ndarray | None:
        """Blender's depth (read_blender_depth), or None, with the reason kept in depth_unreadable."""
        try:
            depth = read_blender_depth(size)
        except (RuntimeError, SystemError, ValueError, TypeError, AttributeError) as exc:  # the gpu module's refusals
            if self.depth_unreadable is None:
                log.warning("HLOD preview: Blender's depth cannot be read (%s)", exc)
            self.depth_unreadable = str(exc) or "the gpu module refused"
            return None
        self.depth_unreadable = None
        return depth

    def status_line(self, file_name: str, *, xray: bool) -> str:
        line = f"on ({self.where}): {file_name}" + "".join(f" - {why}" for why in self._why())
        if self.depth_unreadable is not None:
            return line + (" - Blender's objects hide the nodes but do not occlude them: its depth could not be "
                           f"read ({self.depth_unreadable})")
        return line + (XRAY_NOTE if xray else "")

    def _why(self) -> list[str]:
        """Why the preview draws with this mode, when it was not asked for (status_line)."""
        return []

    def _draw_nodes(self, nodes, *, colours: np.ndarray | None, view: View) -> None:
        """The nodes with the gpu module, depth-tested and written; colours (n, 3) or None."""
        import gpu

        view_z = tuple(float(v) for v in view.view[2, :3])
        gpu.state.depth_test_set("LESS_EQUAL")
        gpu.state.depth_mask_set(True)
        with gpu.matrix.push_pop():
            gpu.matrix.translate(tuple(float(c) for c in self.hlod.origin))  # float32 positions are origin-relative
            if colours is None and self.hlod.has_appearance:
                self.batches.draw_looks(nodes, view_z)
            else:
                self.batches.draw_flat(nodes, colours, view_z)
        gpu.state.depth_mask_set(False)
        gpu.state.depth_test_set("NONE")

    def release(self) -> None:
        """Free everything: the renderer where it lives, then the gpu batches (Blender's context
        must be current). Idempotent."""
        self.release_renderer()
        self.batches.release()

    def hand_over(self) -> list:
        """The renderer released now (it is not in Blender's context); the gpu batches, made in
        Blender's context, handed over (a fresh, empty set stays here)."""
        self.release_renderer()
        batches, self.batches = self.batches, NodeBatches(self.hlod, images=self.batches.images)
        return [] if batches.empty else [batches]
