"""Occlusion tested on the CPU, for when no GL context can be made: a `NodeRenderer` whose
queries rasterise the node's query box with numpy against a small depth buffer, and whose draws
rasterise the node's triangles into it (docs/how-it-works.md#the-cpu-occlusion-test).

Data form: the depth buffer is (ceil(H / factor), ceil(W / factor)) float32 window depth, row 0 the
bottom row, for a frame of W x H pixels reduced by the integer `factor`; at each frame's start it
holds the host's depth (`set_scene_depth`, reduced keeping each block's farthest depth, as
depth_import.reduce_depth does) or the far plane. A query's q and alpha are its front faces'
pixels with the depth test on and off in that buffer, times factor^2: pixels of the full frame,
as a GL query would count them (mu = q / alpha does not depend on the scale). Results are
available at once. Nothing here draws the picture: the host draws the nodes the traversal chose
(Blender's gpu module, in the extension).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..core import cpu_raster
from ..core.errors import InputError
from ..model.hierarchy import Hlod, query_box_pad
from ..model.view import View
from .depth_import import check_depth, reduce_depth
from .query_boxes import CUBE_CORNERS, CUBE_TRIS

#: The depth buffer's default width in pixels: the reduction factor is the frame's width over it,
#: rounded up (640x480 tests in 160x120, 1920x1080 in 160x90; measured in
#: docs/performance.md#the-cpu-occlusion-test: node counts and PSNR-Y against GL queries, and time).
TEST_WIDTH = 160


def default_factor(width: int) -> int:
    """The reduction factor for frames `width` pixels wide: ceil(width / TEST_WIDTH), at least 1."""
    return max(1, -(-int(width) // TEST_WIDTH))


@dataclass(frozen=True)
class CpuQuery:
    """A CPU query's result (protocol.QueryHandle): node, multiquery members, q and alpha in
    full-frame pixels (alpha None when not asked for)."""

    node: int
    q: int
    alpha: int | None
    members: tuple[int, ...] = ()


class CpuOcclusion:
    """NodeRenderer (traversal/protocol.py) testing occlusion on the CPU for frames of `size`
    (width, height) pixels, in a depth buffer reduced by `factor` (module notes; None:
    `default_factor`)."""

    def __init__(self, hlod: Hlod, size: tuple[int, int], *, factor: int | None = None):
        factor = default_factor(size[0]) if factor is None else factor
        if type(factor) is not int or factor < 1:
            raise InputError(f"CPU occlusion: the reduction must be a whole number >= 1, got {factor!r}")
        self.hlod = hlod
        self.size = (int(size[0]), int(size[1]))
        self.factor = factor
        self.query_box_pad = query_box_pad(hlod.box_min, hlod.box_max)  # as the GL renderer's query boxes
        self._box_lo = np.asarray(hlod.box_min, np.float64) - self.query_box_pad - hlod.origin
        self._box_hi = np.asarray(hlod.box_max, np.float64) + self.query_box_pad - hlod.origin
        self._positions = hlod.positions  # (v, 3) float32 and (t, 3) uint32 as the file holds them (views:
        self._indices = np.asarray(hlod.indices).reshape(-1, 3)  # the drawn triangles are gathered per flush)
        self._tri_offset = np.asarray(hlod.tri_offset, np.int64)
        self._tri_count = np.asarray(hlod.tri_count, np.int64)
        self._viewport = (self.size[0] / factor, self.size[1] / factor)
        self._limits = cpu_raster.pixel_limits(self._viewport)
        self._scale = factor * factor
        self._scene = np.ones((-(-self.size[1] // factor), -(-self.size[0] // factor)), np.float32)
        self.depth = self._scene.copy()  # the frame's depth buffer (module notes)
        self._mvp = np.eye(4)
        self._pending: list[int] = []  # nodes drawn, not yet rasterised (draw_node)
        self.depth_import_ms = 0.0  # the last begin_frame's copy of the scene depth
        self.draw_ms = self.query_ms = 0.0  # the last frame's rasterising of draws and of queries

    def set_scene_depth(self, depth: np.ndarray | None) -> None:
        """The host's depth (H, W) float32 window depth, row 0 the bottom row, for the frames from
        the next on (None: the far plane); reduced now. InputError for another form or size."""
        if depth is None:
            self._scene = np.ones_like(self._scene)
            return
        depth = check_depth(depth, where="scene depth")
        if depth.shape != (self.size[1], self.size[0]):
            raise InputError(f"scene depth: {depth.shape[1]}x{depth.shape[0]} pixels for "
                             f"{self.size[0]}x{self.size[1]} frames")
        self._scene = reduce_depth(depth, self.factor)

    # --- NodeRenderer ------------------------------------------------------------------------------

    def begin_frame(self, view: View) -> None:
        """The frame's matrix (the file's origin folded in) and a depth buffer holding the scene depth."""
        if (view.width, view.height) != self.size:
            raise InputError(f"CPU occlusion: a {view.width}x{view.height} frame for {self.size[0]}x{self.size[1]}")
        started = time.perf_counter()
        to_origin = np.eye(4)
        to_origin[:3, 3] = self.hlod.origin
        self._mvp = view.projection @ view.view @ to_origin
        self._pending.clear()
        np.copyto(self.depth, self._scene)
        self.depth_import_ms = (time.perf_counter() - started) * 1e3
        self.draw_ms = self.query_ms = 0.0

    def end_frame(self) -> float:
        """The last draws rasterised (the depth buffer is the frame's); 0 GPU milliseconds."""
        self._flush_draws()
        return 0.0

    def draw_node(self, node: int, ratio_p: float = 1.0) -> None:
        """Rasterise the node's triangles into the depth buffer (its colour is the host's affair).
        Deferred to the next query or the frame's end, all the nodes drawn since in one pass: the
        depth test's minimum does not depend on the order of the draws."""
        self._pending.append(int(node))

    def _flush_draws(self) -> None:
        """Rasterise the triangles of the nodes drawn since the last flush (draw_node)."""
        if not self._pending:
            return
        started = time.perf_counter()
        offsets, counts = self._tri_offset[self._pending], self._tri_count[self._pending]
        self._pending.clear()
        rows = np.repeat(offsets - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
        corners = self._positions[self._indices[rows]].astype(np.float64)  # (t, 3, 3)
        clip = corners @ self._mvp[:3, :3].T + self._mvp[:3, 3]
        clip = np.concatenate([clip, (corners @ self._mvp[3, :3] + self._mvp[3, 3])[..., None]], axis=2)
        window = cpu_raster.to_window(cpu_raster.clip_near(clip), self._viewport)
        cpu_raster.draw(window, self.depth, limits=self._limits)
        self.draw_ms += (time.perf_counter() - started) * 1e3

    def issue_query(self, node: int, *, with_alpha: bool) -> CpuQuery:
        return self.issue_queries([node], with_alpha=with_alpha)[0]

    def issue_queries(self, nodes, *, with_alpha: bool) -> list[CpuQuery]:
        """The queries of `nodes` against the depth buffer as it is now, all boxes in one pass."""
        nodes = [int(node) for node in nodes]
        q, alpha = self._box_pixels(nodes)
        return [CpuQuery(node, int(qi), int(ai) if with_alpha else None) for node, qi, ai in zip(nodes, q, alpha)]

    def issue_multiquery(self, nodes) -> CpuQuery:
        """One q over the boxes of all `nodes`: the sum of theirs (as a GL multiquery counts)."""
        members = tuple(int(node) for node in nodes)
        q, _ = self._box_pixels(list(members))
        return CpuQuery(members[0], int(q.sum()), None, members)

    def available(self, query: CpuQuery) -> bool:
        return True

    def result(self, query: CpuQuery) -> tuple[int, int | None, float]:
        return query.q, query.alpha, 0.0

    def _box_pixels(self, nodes: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(q, alpha) (len(nodes),) int64 full-frame pixels of the nodes' query boxes. The boxes
        lie in front of the near plane (the traversal queries no other), so no clipping is needed."""
        self._flush_draws()
        started = time.perf_counter()
        rows = np.asarray(nodes, np.int64)
        lo, hi = self._box_lo[rows], self._box_hi[rows]
        corners = lo[:, None, :] + (hi - lo)[:, None, :] * CUBE_CORNERS[None, :, :]  # (k, 8, 3)
        clip = corners @ self._mvp[:3, :3].T + self._mvp[:3, 3]
        clip = np.concatenate([clip, (corners @ self._mvp[3, :3] + self._mvp[3, 3])[..., None]], axis=2)
        triangles = clip[:, CUBE_TRIS].reshape(-1, 3, 4)  # (12 k, 3, 4)
        groups = np.repeat(np.arange(len(nodes)), len(CUBE_TRIS))
        window = cpu_raster.to_window(triangles, self._viewport)
        q, alpha = cpu_raster.count(window, self.depth, groups=groups, group_count=len(nodes), limits=self._limits)
        self.query_ms += (time.perf_counter() - started) * 1e3
        return q * self._scale, alpha * self._scale


def query_renderer(hlod: Hlod, size: tuple[int, int], *, context: str = "private",
                   images: dict[int, np.ndarray] | None = None):
    """The renderer a preview's queries run on, and why it is not the one asked for: `context`
    "private", a standalone GL context of the platform's own (Renderer.create_standalone, with the
    material `images`), or CpuOcclusion when no context can be made, the reason being then
    GLUnavailable's sentence; "cpu", CpuOcclusion. Returns (renderer, reason or None)."""
    if context not in ("private", "cpu"):
        raise InputError(f"query context {context!r}: one of private, cpu")
    if context == "private":
        from ..core.errors import GLUnavailable
        from .renderer import Renderer

        try:
            return Renderer.create_standalone(hlod, size, images=images), None
        except GLUnavailable as exc:
            return CpuOcclusion(hlod, size), str(exc)
    return CpuOcclusion(hlod, size), None
