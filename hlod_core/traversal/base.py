"""The state and helpers every traversal method shares (docs/how-it-works.md#the-traversal-methods): per-node `visible`,
`last_visited`, `stop_refinement`, `ratio` (= cached P) and the frame each node was last drawn in;
the frame's node-table results (frustum test, priority key, queryable boxes, SSE, alpha estimate),
vectorised once a frame; one `frame(view)` entry point that times the walk and fills `FrameStats`.

Data form: the walk reads the frame's (n,) results through memoryviews (a Python scalar per index,
at about a list's speed, without a per-frame `tolist`) and keeps the per-node state it reads and
writes one node at a time in Python lists (a list index costs a fifth of a numpy scalar's);
`visible`, `ratio` etc. give that state as (n,) arrays for vectorised readers.
"""
from __future__ import annotations

import abc
import heapq
import time
from collections.abc import Callable

import numpy as np

from ..model.hierarchy import Hlod
from ..model.view import View
from . import alpha_estimators, boxes, metrics
from .protocol import NodeRenderer
from .settings import RuntimeSettings
from .stats import MS_PER_S, FrameStats

#: Frame id of "never": far enough below frame 1 that no "visited last frame" and no "measured
#: within measure_every frames" (RuntimeSettings.measure_every, any int64-sized period) holds for it.
NEVER_FRAME = -(1 << 40)


def state_array(values: list, dtype) -> np.ndarray:
    """A per-node state list as a new (n,) array (read-only: writing to it would change nothing)."""
    out = np.array(values, dtype)
    out.flags.writeable = False
    return out


class Traversal(abc.ABC):
    """Shared state and helpers. Subclasses implement `_traverse(stats)`."""

    name = "base"
    modulates = True  # does VMSSE decide its LOD (else it draws with P = 1: no modulation)

    def __init__(self, hlod: Hlod, renderer: NodeRenderer, settings: RuntimeSettings = RuntimeSettings()):
        self.hlod = hlod
        self.renderer = renderer
        self.settings = settings
        n = hlod.node_count
        # per-node state, one entry a node (lists: module docstring; the properties below give arrays)
        self._visible = [False] * n
        self._last_visited = [NEVER_FRAME] * n
        self._stop_refinement = [False] * n
        self._ratio = [0.0] * n
        self._rendered = [NEVER_FRAME] * n  # frame the node was last drawn in
        self.frame_id = 0
        self._is_leaf = hlod.is_leaf
        self._children = [range(first, first + count) if first >= 0 else range(0)
                          for first, count in zip(hlod.child_offset.tolist(), hlod.child_count.tolist())]
        self._parent = hlod.parent.tolist()
        self._tri_count = hlod.tri_count.tolist()
        self._leaf = self._is_leaf.tolist()
        self._sse_inputs = metrics.sse_inputs(hlod.error, self._is_leaf)
        self._box_rows: boxes.BoxRows | None = None  # made on the first frame, from the renderer's pad
        self._query_alpha = settings.alpha == "query"
        self._tau = settings.tau
        self._p = metrics.bias_function(settings.bias_s, settings.t, k=settings.k)
        #: the renderer's streamed-geometry residency (render.residency) under a GPU budget, else None
        self._residency = getattr(renderer, "residency", None)

    # (n,) arrays of the per-node state, new on each read (the walk's lists stay the state)
    visible = property(lambda self: state_array(self._visible, bool), doc="(n,) bool: visible in the last query result")
    last_visited = property(lambda self: state_array(self._last_visited, np.int64), doc="(n,) int64 frame id")
    stop_refinement = property(lambda self: state_array(self._stop_refinement, bool), doc="(n,) bool")
    ratio = property(lambda self: state_array(self._ratio, np.float64), doc="(n,) float64 P of the last result")
    rendered = property(lambda self: state_array(self._rendered, np.int64), doc="(n,) int64 frame last drawn")

    # --- per frame, vectorised ------------------------------------------------------------------

    def prepare(self, view: View) -> None:
        """The frame's node-table results, (n,) each, as memoryviews: in_frustum bool, key float64
        (eye-to-box distance, the priority), unqueryable bool (boxes.view_tests), sse float64 pixels;
        alpha_estimate (n,) float64 pixels or None (the `query` estimator). `frame` calls it first."""
        h = self.hlod
        self.view = view
        pad = self.renderer.query_box_pad
        if self._box_rows is None or self._box_rows.query_pad != pad:
            self._box_rows = boxes.BoxRows.of(h.box_min, h.box_max, query_pad=pad, centre=h.sphere_center)
        tests = boxes.view_tests(view, self._box_rows)
        in_frustum, unqueryable = tests.in_frustum, tests.unqueryable
        d = None if view.orthographic else np.subtract(tests.centre_distance, h.sphere_radius)
        error, inside = self._sse_inputs
        sse = metrics.sse_at(view, error, distance=d, inside=inside)
        self.in_frustum, self.key, self.unqueryable, self.sse = map(memoryview, (in_frustum, tests.distance,
                                                                                 unqueryable, sse))
        self.alpha_estimate = None  # (n,) pixels, for the estimators other than `query`
        if self.settings.alpha == "cube":
            self.alpha_estimate = alpha_estimators.alpha_cube(view, h.cube_side, box_min=h.box_min, box_max=h.box_max)
        elif self.settings.alpha == "projected":  # only boxes that can be queried this frame
            candidates = np.flatnonzero(in_frustum & ~unqueryable)
            self.alpha_estimate = np.zeros(h.node_count)
            self.alpha_estimate[candidates] = alpha_estimators.alpha_projected(
                view, h.box_min[candidates] - pad, h.box_max[candidates] + pad)

    def frame(self, view: View) -> FrameStats:
        """Traverse, query and draw one frame seen from `view`; its counters."""
        self.frame_id += 1
        stats = FrameStats()
        started = time.perf_counter()
        self.prepare(view)
        state_changes = getattr(self.renderer, "state_changes", 0)
        self.renderer.begin_frame(view)
        stats.depth_import_ms = getattr(self.renderer, "depth_import_ms", 0.0)
        self._traverse(stats)
        traversed_at = time.perf_counter()
        uploaded = 0 if self._residency is None else self._residency.uploaded_bytes
        stats.gpu_ms = self.renderer.end_frame()
        ended = time.perf_counter()
        if self._residency is not None:
            residency = self._residency
            stats.substitutions, stats.waiting = residency.substitutions, residency.waiting
            stats.resident_bytes, stats.upload_bytes = residency.resident_bytes, residency.uploaded_bytes - uploaded
            stats.upload_ms = residency.upload_seconds * MS_PER_S
        stats.state_changes = getattr(self.renderer, "state_changes", 0) - state_changes
        stats.frame_ms = (ended - started) * MS_PER_S
        stats.cpu_ms = (traversed_at - started) * MS_PER_S - stats.stall_ms
        return stats

    @abc.abstractmethod
    def _traverse(self, stats: FrameStats) -> None:
        """Visit, query and draw the frame's nodes, filling `stats`."""

    # --- helpers --------------------------------------------------------------------------------

    def modulation(self, nodes) -> np.ndarray:
        """m = 1 - P of `nodes` after the frame (0 for methods VMSSE does not steer)."""
        ratio = self._ratio
        p = [ratio[node] for node in np.asarray(nodes, np.int64).tolist()] if self.modulates else np.ones(len(nodes))
        return metrics.modulation(p)

    def _draw_step(self, stats: FrameStats) -> Callable[[int], bool]:
        """The frame's `render(node) -> bool`: draws the node once per frame (False if it was drawn
        already) with its ratio P (1 for methods VMSSE does not steer), counts it in `stats` and,
        under a GPU budget, marks it used. A closure over the frame's state: the walk calls it
        for every node it draws."""
        frame_id, rendered, ratio, tri_count = self.frame_id, self._rendered, self._ratio, self._tri_count
        residency, modulates, draw_node, drawn = self._residency, self.modulates, self.renderer.draw_node, stats.drawn

        def render(node: int) -> bool:
            if rendered[node] == frame_id:
                return False
            rendered[node] = frame_id
            if residency is not None:
                residency.use(node)
            stats.dn += 1
            stats.tris += tri_count[node]
            drawn.append(node)
            draw_node(node, ratio[node] if modulates else 1.0)
            return True
        return render

    def _refinable(self, node: int, *, visible: bool) -> bool:
        """May the walk descend into the node's children? Always without a GPU budget; under one,
        only when their geometry is resident: else the node is drawn in their place this frame and
        they are requested, visible ones and larger errors first (render.residency)."""
        residency = self._residency
        if residency is None:
            return True
        residency.use(node)
        sse, tau = self.sse, self._tau
        return residency.can_refine(node, visible=visible, error_over_tau=sse[node] / tau,
                                    needed=self.in_frustum.__getitem__, refines=lambda child: sse[child] > tau)

    def _vmsse_stop(self, node: int, ratio: float) -> bool:
        """Leaves stop; d <= 0 (SSE = inf) refines whatever the ratio; else ratio * SSE <= tau. One
        comparison does all three for a ratio in [0, 1]: a leaf's SSE is 0, and ratio * inf is inf
        or, for ratio 0, NaN, which compares False. Written out in the per-frame closures, and as
        SSE <= tau (ratio 1) for the methods VMSSE does not steer."""
        return ratio * self.sse[node] <= self._tau

    def _visibility_step(self) -> Callable[[int, int, int | None], float]:
        """The frame's `visibility(node, q, alpha_q) -> mu` of a query result: mu = clamp(q / alpha,
        0, 1), alpha from the node's own alpha query (alpha_q) or the frame's estimate; alpha 0 or
        NaN gives 0, q > alpha gives 1 (q >= 0)."""
        query_alpha, alpha_estimate = self._query_alpha, self.alpha_estimate

        def visibility(node: int, q: int, alpha_q: int | None) -> float:
            alpha = float(alpha_q) if query_alpha else float(alpha_estimate[node])
            if not alpha > 0:
                return 0.0
            mu = q / alpha
            return mu if mu < 1.0 else 1.0  # min(1.0, mu) without the call
        return visibility

    def _schedule(self, heap: list, nodes) -> None:
        """Push those of `nodes` that lie in the frustum on the front-to-back heap (a node outside
        would only be popped and dropped)."""
        key, in_frustum = self.key, self.in_frustum
        for node in nodes:
            if in_frustum[node]:
                heapq.heappush(heap, (key[node], node))
