"""The preview when no GL context of its own can be made (a platform without OpenGL, a driver that
refuses) on a Blender backend moderngl cannot attach to: the same traversal, its occlusion tested
on the CPU (hlod_core.render.cpu_occlusion.CpuOcclusion: the query boxes rasterised with numpy
against Blender's depth reduced to about 160 pixels wide), the chosen nodes drawn with Blender's
gpu module (batch_drawn_mode). No GL call is made here.

Where even this fails (the last way the preview has), the frame's error becomes one sentence for
the status line: why there is no GL context, that the CPU test failed too and with what (the
traceback goes to Blender's console).
"""
from __future__ import annotations

import time

import numpy as np

from ...hlod_core.core.errors import HlodError
from ...hlod_core.model.hierarchy import Hlod
from ...hlod_core.model.view import View
from ...hlod_core.render.cpu_occlusion import CpuOcclusion
from ...hlod_core.render.residency import StreamingSettings
from ...hlod_core.render.streamed_geometry import node_residency
from ...hlod_core.render.texture_table import TextureTable
from ...hlod_core.traversal.settings import RuntimeSettings
from ...hlod_core.traversal.stats import MS_PER_S
from .batch_drawn_mode import BatchDrawnMode
from .gl_contexts import GLContexts


class BudgetedCpuOcclusion(CpuOcclusion):
    """CpuOcclusion for frames of `size` with the GPU budget's bookkeeping for the gpu batches that
    draw the nodes: under a budget (`streaming`, not unlimited) `residency` says which nodes may
    have batches, and which of `images`' textures (`texture_table`) are in use, and the traversal
    holds back where they may not, as with the private renderer's streamed geometry
    (render.residency); a node becomes resident when the plan after a frame says so (its batch is
    made when it is first drawn). Without a budget, `residency` is None."""

    def __init__(self, hlod: Hlod, size: tuple[int, int], *, streaming: StreamingSettings | None,
                 images: dict[int, np.ndarray]):
        super().__init__(hlod, size)
        self.residency = None
        self.texture_table = TextureTable.of(hlod, images) if hlod.materials else TextureTable.none(hlod)
        if streaming is not None and not streaming.unlimited:
            self.residency = node_residency(hlod, textures=self.texture_table, with_uv=hlod.uvs is not None,
                                            with_colour=hlod.colors is not None, settings=streaming)
            for node in self.residency.initial_uploads():
                self.residency.uploaded(node)

    def begin_frame(self, view: View) -> None:
        if self.residency is not None:
            self.residency.begin_frame()
        super().begin_frame(view)

    def end_frame(self) -> float:
        gpu_ms = super().end_frame()
        if self.residency is not None:
            started = time.perf_counter()
            plan = self.residency.plan()
            for node in plan.evict:
                self.residency.evicted(node)
            for node in plan.upload:
                self.residency.uploaded(node)
            self.residency.upload_seconds = time.perf_counter() - started
        return gpu_ms

    def release(self) -> None:
        """Nothing to free (no GL objects): for PreviewMode's release."""


class CpuContextMode(BatchDrawnMode):
    """The CPU occlusion test for the view's size (kept while size and GPU budget stay), the
    traversal over it, and the gpu batches that draw its nodes (batch_drawn_mode.BatchDrawnMode).
    reason: why the preview tests on the CPU (the private context's GLUnavailable sentence), said
    in the status line; None when asked for."""

    where = "CPU occlusion test"

    def __init__(self, hlod: Hlod, *, images: dict[int, np.ndarray]):
        super().__init__(hlod, images=images)
        self.reason: str | None = None

    def draw(self, view: View, **kwargs):
        """batch_drawn_mode.BatchDrawnMode.draw; an error other than the core's typed ones becomes an
        HlodError saying in one sentence that no preview can be drawn here and why (module notes)."""
        try:
            return super().draw(view, **kwargs)
        except HlodError:
            raise
        except Exception as exc:  # the last way to draw: say so in words (chained for the console)
            why = self.reason.rstrip(".") if self.reason else "the CPU occlusion test was asked for"
            why = why[:1].lower() + why[1:]
            raise HlodError(f"No preview can be drawn here: {why}; and the CPU occlusion test that stands in "
                            f"failed too ({exc or 'without a message'}), the details are in Blender's console") from exc

    def _frame(self, view: View, *, depth: np.ndarray | None, contexts: GLContexts, method: str,
               settings: RuntimeSettings, streaming: StreamingSettings | None):
        size = (view.width, view.height)
        self.keep_renderer_for((size, streaming))
        traversal = self.traversal(method=method, settings=settings, make_renderer=lambda: BudgetedCpuOcclusion(
            self.hlod, size, streaming=streaming, images=self.images))
        started = time.perf_counter()
        self.renderer.set_scene_depth(depth)  # reduced here to the test's resolution
        handed_ms = (time.perf_counter() - started) * MS_PER_S
        stats = traversal.frame(view)
        stats.depth_import_ms += handed_ms
        stats.frame_ms += handed_ms
        return stats, traversal

    def _why(self) -> list[str]:
        return [] if self.reason is None else [self.reason]
