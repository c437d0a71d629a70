"""HLOD traversal methods (DESIGN §6), one class each, one `frame(view)` entry point, same counters.

Papers:
- Bittner, Wimmer, Piringer, Purgathofer, "Coherent hierarchical culling" (2004,
  `../shared/papers/bittner-wimmer-piringer-purgathofer2004-chc.txt`): the priority queue
  front-to-back, the query queue, visibility pulled up, queries never stalling while work remains.
- Charalambos' dissertation (`charalambos2007-dissertation-hlod-refinement-hoq.txt`): Algorithm 1
  (Bool, after Gobbetti & Marton), Algorithm 2 (the coherent visibility-based traversal) with
  Algorithm 3 (Simp, the 2006 predictor mu_hat = 1 - pos/total) and Algorithm 4 (Coh: refine /
  stop / delay from the cached ratio of the previous frame).

Decisions on points the pseudocode leaves open (DESIGN §6): a node drawn this frame is never drawn
again; if its query later says "refine" it counts in RARN and its children are traversed. A query
result of 0 sets ratio = P(0) = 0 and leaves the node invisible. In Algorithm 4 a child not visited
in the previous frame counts as stopped with ratio 0, and the average ratio is over all children.
Leaves always stop; interior nodes with d <= 0 (eye inside the sphere) always refine.
Beyond the papers: Coh also measures the ratio of the nodes it refines, so the front can move up
where Algorithm 4's children's average cannot see it should (`Coh`, `shift_up`).

Per-frame work over the whole node table (frustum test, distances, SSE, cube alpha) is numpy; the
Python loop is the traversal itself, over the nodes it visits.
"""
from __future__ import annotations

import abc
import heapq
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from . import alpha_estimators, boxes, metrics, query_cost
from .errors import InputError
from .hierarchy import Hlod
from .view import View
from .queries import Query

# Predictions of Algorithms 1-4 for a node popped from the priority queue; also the mode of the
# query issued for it.
REFINE, STOP, DELAY = "refine", "stop", "delay"
# The mode of a query on a node that refines anyway, issued only to measure its own ratio for the
# next frame (Coh's measured shift-up): its result draws and refines nothing.
MEASURE_RATIO = "measure ratio"
ALPHA_MODES = ("query", "projected", "cube")
SHIFT_UP_MODES = ("measured", "children")
#: Queries of visible, stopped nodes that Bool and Coh leave out (CoherentLoop): "off" none,
#: "cheap" where drawing the node costs less than its query (the renderer's cost_model),
#: "expected" where the measured chance that such a query changes anything, times the draw cost,
#: is below the query cost ("cheap" is its case of chance 1).
SKIP_QUERY_MODES = ("off", "cheap", "expected")
#: Frame id of "never": far enough below frame 1 that no "visited last frame" and no "measured
#: within Coh.measure_every_frames" test holds for it.
NEVER_FRAME = -10
MS_PER_S = 1e3


@dataclass(frozen=True)
class RuntimeSettings:
    """tau: pixels; s, t in [0, 1] and k > 0 (inf = step) for P_{s,t}; bias "P" or "mu" (s = 0);
    alpha: "query" | "projected" | "cube";
    shift_up (Coh only): "measured" queries refined nodes too and moves the front up where their own
    ratio says stop, "children" is Algorithm 4 as published (the children's average ratio);
    skip_queries (Bool, Coh): one of SKIP_QUERY_MODES (CoherentLoop)."""

    tau: float = 1.0
    s: float = 0.9
    t: float = 0.05
    k: float = float("inf")
    bias: str = "P"
    alpha: str = "query"
    shift_up: str = "measured"
    skip_queries: str = "off"  # "expected" measured faster (benchmarks.traversal_table); see CoherentLoop

    def __post_init__(self):
        if not self.tau > 0:
            raise InputError(f"tau must be > 0 pixels, got {self.tau}")
        if self.bias not in ("P", "mu"):
            raise InputError(f"bias must be 'P' or 'mu', got {self.bias!r}")
        if self.alpha not in ALPHA_MODES:
            raise InputError(f"alpha must be one of {ALPHA_MODES}, got {self.alpha!r}")
        if self.shift_up not in SHIFT_UP_MODES:
            raise InputError(f"shift_up must be one of {SHIFT_UP_MODES}, got {self.shift_up!r}")
        if self.skip_queries not in SKIP_QUERY_MODES:
            raise InputError(f"skip_queries must be one of {SKIP_QUERY_MODES}, got {self.skip_queries!r}")
        try:
            metrics.bias(0.5, self.s, self.t, self.k)  # validates s, t, k (the messages are metrics')
        except ValueError as exc:
            raise InputError(str(exc)) from None

    def p(self, mu: float) -> float:
        """P_{s,t}(mu) of one node (s = 0 for bias "mu"), in plain Python: the traversal's per-node path."""
        return metrics.bias_scalar(float(mu), 0.0 if self.bias == "mu" else self.s, self.t, self.k)


#: FrameStats' counters, in the order of its fields (the columns of per-frame tables).
COUNTERS = ("dn", "rarn", "d", "tris", "queries", "traversed", "stall_ms", "cpu_ms", "gpu_ms", "frame_ms")


@dataclass
class FrameStats:
    """Counters of one frame (DESIGN §6). Times in milliseconds."""

    dn: int = 0          # drawn nodes
    rarn: int = 0        # drawn, then refined in the same frame
    d: int = 0           # drawn only after waiting for their own query
    tris: int = 0
    queries: int = 0     # node occlusion queries issued (the query alpha estimator adds one GL query each)
    traversed: int = 0   # nodes visited inside the frustum
    stall_ms: float = 0.0
    cpu_ms: float = 0.0
    gpu_ms: float = 0.0
    frame_ms: float = 0.0
    drawn: list = field(default_factory=list)       # node ids in draw order (not counters)
    delayed: list = field(default_factory=list)     # the nodes counted in d
    refined_after_draw: list = field(default_factory=list)  # the nodes counted in rarn
    skipped: list = field(default_factory=list)  # visible, stopped nodes drawn without their query (CoherentLoop)


class NodeRenderer(Protocol):
    """What a traversal needs from the drawing side (`renderer.Renderer` is one; tests wrap it).
    The traversal says which node it draws and with which ratio P; colours are the drawing side's."""

    query_box_pad: float  # model units the query boxes are enlarged by (hierarchy.query_box_pad)

    def begin_frame(self, view: View) -> None: ...

    def end_frame(self) -> float:
        """Finish the frame; GPU milliseconds (0 when not timed)."""

    def draw_node(self, node: int, ratio_p: float) -> None: ...

    def issue_query(self, node: int, *, with_alpha: bool) -> Query: ...

    def available(self, query: Query) -> bool:
        """Non-blocking: is the result back?"""

    def result(self, query: Query) -> tuple[int, int | None, float]:
        """(q, alpha or None, stall seconds), blocking if needed."""


@dataclass
class _Pending:
    """A query in flight; query None when the box cannot be queried (eye inside it, or it reaches
    in front of the near plane): visible with mu = 1."""

    node: int
    mode: str
    query: Query | None


class Traversal(abc.ABC):
    """Shared state and helpers. Subclasses implement `_traverse(stats)`."""

    name = "base"
    modulates = True  # does VMSSE decide its LOD (else it draws with P = 1: no modulation)

    def __init__(self, hlod: Hlod, renderer: NodeRenderer, settings: RuntimeSettings = RuntimeSettings()):
        self.hlod = hlod
        self.renderer = renderer
        self.settings = settings
        n = hlod.node_count
        self.visible = np.zeros(n, bool)
        self.last_visited = np.full(n, NEVER_FRAME, np.int64)
        self.stop_refinement = np.zeros(n, bool)
        self.ratio = np.zeros(n, np.float64)
        self.rendered = np.full(n, NEVER_FRAME, np.int64)  # frame the node was last drawn in
        self.frame_id = 0
        self._is_leaf = hlod.is_leaf
        self._child_offset = hlod.child_offset.tolist()
        self._child_count = hlod.child_count.tolist()
        self._parent = hlod.parent.tolist()
        self._tri_count = hlod.tri_count.tolist()
        self._leaf = self._is_leaf.tolist()

    # --- per frame, vectorised ------------------------------------------------------------------

    def _prepare(self, view: View) -> None:
        h = self.hlod
        self.view = view
        self.in_frustum = boxes.boxes_in_frustum(view, h.box_min, h.box_max).tolist()
        self.sse = metrics.sse(view, h.error, h.sphere_center, h.sphere_radius, self._is_leaf).tolist()
        self.key = boxes.box_distance(view.eye, h.box_min, h.box_max).tolist()
        pad = self.renderer.query_box_pad
        lo, hi = h.box_min - pad, h.box_max + pad
        # DESIGN §5.4 skips the query when the eye is inside the box; a box reaching in front of
        # the near plane has the same problem (its front faces are clipped), so it is skipped too.
        self.unqueryable = (boxes.eye_in_boxes(view.eye, lo, hi)
                            | boxes.boxes_cross_near_plane(view, lo, hi)).tolist()
        self.alpha_estimate = None  # (n,) pixels, for the estimators other than `query`
        if self.settings.alpha == "cube":
            self.alpha_estimate = alpha_estimators.alpha_cube(view, h.cube_side, h.box_min, h.box_max)
        elif self.settings.alpha == "projected":  # only boxes that can be queried this frame
            candidates = np.flatnonzero(np.asarray(self.in_frustum) & ~np.asarray(self.unqueryable))
            self.alpha_estimate = np.zeros(h.node_count)
            self.alpha_estimate[candidates] = alpha_estimators.alpha_projected(view, lo[candidates], hi[candidates])

    def frame(self, view: View) -> FrameStats:
        self.frame_id += 1
        stats = FrameStats()
        started = time.perf_counter()
        self._prepare(view)
        self.renderer.begin_frame(view)
        self._traverse(stats)
        traversed_at = time.perf_counter()
        stats.gpu_ms = self.renderer.end_frame()
        ended = time.perf_counter()
        stats.frame_ms = (ended - started) * MS_PER_S
        stats.cpu_ms = (traversed_at - started) * MS_PER_S - stats.stall_ms
        return stats

    @abc.abstractmethod
    def _traverse(self, stats: FrameStats) -> None:
        """Visit, query and draw the frame's nodes, filling `stats`."""

    # --- helpers --------------------------------------------------------------------------------

    def modulation(self, nodes) -> np.ndarray:
        """m = 1 - P of `nodes` after the frame (0 for methods VMSSE does not steer)."""
        p = self.ratio[np.asarray(nodes, np.int64)] if self.modulates else np.ones(len(nodes))
        return metrics.modulation(p)

    def _children(self, node: int) -> range:
        first = self._child_offset[node]
        return range(first, first + self._child_count[node]) if first >= 0 else range(0)

    def _render(self, node: int, stats: FrameStats) -> bool:
        """Draw once per frame; False if the node was already drawn."""
        if self.rendered[node] == self.frame_id:
            return False
        self.rendered[node] = self.frame_id
        stats.dn += 1
        stats.tris += self._tri_count[node]
        stats.drawn.append(node)
        self.renderer.draw_node(node, self.ratio[node] if self.modulates else 1.0)
        return True

    def _sse_stop(self, node: int) -> bool:
        return self._leaf[node] or self.sse[node] <= self.settings.tau

    def _vmsse_stop(self, node: int, ratio: float) -> bool:
        """Leaves stop; d <= 0 (SSE = inf) refines whatever the ratio; else ratio * SSE <= tau."""
        if self._leaf[node]:
            return True
        sse = self.sse[node]
        return math.isfinite(sse) and ratio * sse <= self.settings.tau

    def _issue(self, node: int, mode: str, stats: FrameStats) -> _Pending:
        if self.unqueryable[node]:
            return _Pending(node, mode, None)
        stats.queries += 1
        return _Pending(node, mode, self.renderer.issue_query(node, with_alpha=self.settings.alpha == "query"))

    def _available(self, pending: _Pending) -> bool:
        return pending.query is None or self.renderer.available(pending.query)

    def _mu(self, pending: _Pending, stats: FrameStats) -> tuple[int, float]:
        """(q, mu) of a finished query; an unqueryable box gives (1, 1.0)."""
        if pending.query is None:
            return 1, 1.0
        q, alpha_q, stall = self.renderer.result(pending.query)
        stats.stall_ms += stall * MS_PER_S
        alpha = float(alpha_q) if self.settings.alpha == "query" else float(self.alpha_estimate[pending.node])
        mu = 0.0 if not alpha > 0 else min(1.0, max(0.0, q / alpha))  # alpha 0 or NaN -> 0; q > alpha -> 1
        return q, mu

    def _walk(self, stats: FrameStats, visit) -> None:
        """Front to back from the root over nodes in the frustum; visit(node) -> True descends."""
        heap = [(self.key[0], 0)]
        while heap:
            _, node = heapq.heappop(heap)
            if not self.in_frustum[node]:
                continue
            stats.traversed += 1
            if visit(node):
                for child in self._children(node):
                    heapq.heappush(heap, (self.key[child], child))

    def _pull_up(self, node: int) -> None:
        while node >= 0 and not self.visible[node]:
            self.visible[node] = True
            node = self._parent[node]


class Full(Traversal):
    """Every leaf in the frustum, front to back: the ground-truth image."""

    name = "full"
    modulates = False

    def _traverse(self, stats):
        leaves = np.flatnonzero(self._is_leaf & np.asarray(self.in_frustum))
        order = leaves[np.argsort(np.asarray(self.key)[leaves], kind="stable")]
        stats.traversed = int(order.shape[0])
        for node in order.tolist():
            self._render(node, stats)


class VFC(Traversal):
    """View-frustum culling and SSE, no queries."""

    name = "vfc"
    modulates = False

    def _traverse(self, stats):
        def visit(node):
            if self._sse_stop(node):
                self._render(node, stats)
                return False
            return True

        self._walk(stats, visit)


class StopAndWait(Traversal):
    """SW: query every visited node and wait for it; VMSSE decides. The ideal node count."""

    name = "sw"

    def _traverse(self, stats):
        def visit(node):
            self.last_visited[node] = self.frame_id
            q, mu = self._mu(self._issue(node, DELAY, stats), stats)
            if q == 0:
                self.visible[node] = False
                self.ratio[node] = 0.0
                return False
            self.visible[node] = True
            self.ratio[node] = self.settings.p(float(mu))
            stop = self._vmsse_stop(node, self.ratio[node])
            self.stop_refinement[node] = stop
            if stop and self._render(node, stats):
                stats.d += 1
                stats.delayed.append(node)
            return not stop

        self._walk(stats, visit)


class Ideal(Traversal):
    """Draws exactly the node set SW finds for the frame, with no queries: a lower bound on time.
    SW runs first in an untimed pass into the same framebuffer, which is then cleared."""

    name = "ideal"

    def __init__(self, hlod, renderer, settings=RuntimeSettings()):
        super().__init__(hlod, renderer, settings)
        self._sw = StopAndWait(hlod, renderer, settings)

    def frame(self, view):
        chosen = self._sw.frame(view).drawn
        self.ratio = self._sw.ratio
        self._chosen = chosen
        return super().frame(view)

    def _traverse(self, stats):
        stats.traversed = len(self._chosen)
        for node in self._chosen:
            self._render(node, stats)


class CoherentLoop(Traversal):
    """Algorithm 2's loop (Algorithm 1 when `predict` and `stop_on_result` are Bool's).

    Skipped queries (issue 15; for the classes with `skips_queries`, Bool and Coh; settings
    skip_queries): a node predicted STOP (visible and stopped last frame) is drawn at once and, in
    the published loops, queried. Where the query does not pay for itself it is left out: the node
    is pulled up as visible, keeps its ratio and is drawn, as CHC (2004, §5.1 "conservative
    visibility testing") and CHC++ (Mattausch, Bittner, Wimmer 2008) assume visible nodes stay
    visible for a few frames. The test, per node and frame, vectorised in `_prepare` from the
    renderer's `cost_model` (query_cost): "cheap" skips where drawing the node's triangles costs
    less than rasterising its query box (query_cost.box_pixels, or the projected alpha where that
    estimator runs); "expected" where that draw cost times `change_rate` (the running share of
    queried stopped nodes whose result changed something: hidden, or refined) is below the query
    cost. A skipped node is queried again on its next re-check frame: every `recheck_frames`-th
    frame, at a phase drawn per node from a generator seeded with `recheck_seed`. This is CHC++'s
    randomised first re-check (after a query finds a node visible, the next one comes 1 to
    recheck_frames frames later, at random) made a fixed per-node phase, so the re-checks of nodes
    that become skippable together (the change rate falls for all at once) spread over frames too.
    A node hidden meanwhile is found within recheck_frames frames. A renderer without a cost_model
    (tests' wrappers) skips nothing.
    """

    skips_queries = False
    #: CHC++'s n_av, the frames a visible node is assumed visible between queries (MinSG's
    #: CHC++ renderer defaults to 5 skipped frames).
    recheck_frames = 5
    #: Weight of one query result in the running change_rate (about the last 64 results count).
    change_rate_weight = 1.0 / 64

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), *, recheck_seed: int = 0):
        super().__init__(hlod, renderer, settings)
        self._skip_mode = settings.skip_queries if self.skips_queries else "off"
        self.recheck_due = np.zeros(hlod.node_count, np.int64)  # frame from which a skip needs a query again
        rng = np.random.default_rng(recheck_seed)
        self._recheck_phase = rng.integers(0, self.recheck_frames, hlod.node_count).tolist()
        self.change_rate = 1.0  # nothing measured yet: every query may change something
        self.skippable: list | None = None
        self._tris = np.asarray(hlod.tri_count, np.float64)

    def _prepare(self, view):
        super()._prepare(view)
        self.skippable = None
        model = getattr(self.renderer, "cost_model", None) if self._skip_mode != "off" else None
        if model is None:
            return
        h, pad = self.hlod, self.renderer.query_box_pad
        candidates = np.flatnonzero(np.asarray(self.in_frustum) & ~np.asarray(self.unqueryable))
        if self.settings.alpha == "projected":
            pixels = self.alpha_estimate[candidates]
        else:
            pixels = query_cost.box_pixels(view, h.box_min[candidates] - pad, h.box_max[candidates] + pad)
        draw_s = model.draw_seconds(self._tris[candidates])
        if self._skip_mode == "expected":
            draw_s = draw_s * self.change_rate
        skippable = np.zeros(h.node_count, bool)
        skippable[candidates] = draw_s < model.query_seconds(pixels)
        self.skippable = skippable.tolist()

    def _skips(self, node: int) -> bool:
        """Draw this STOP-predicted node without its query?"""
        return self.skippable is not None and self.skippable[node] and self.frame_id < self.recheck_due[node]

    def _queried(self, node: int, mode: str, changed: bool) -> None:
        """Bookkeeping of a finished STOP / DELAY query: the next re-check (the node's next frame f
        with (f + its seeded phase) % recheck_frames == 0: 1 to recheck_frames frames on), the
        change rate."""
        n = self.recheck_frames
        self.recheck_due[node] = self.frame_id + 1 + (-(self.frame_id + 1) - self._recheck_phase[node]) % n
        if mode == STOP:
            self.change_rate += (float(changed) - self.change_rate) * self.change_rate_weight

    @abc.abstractmethod
    def _predict(self, node: int) -> str:
        """REFINE, STOP or DELAY for a node popped from the priority queue."""

    @abc.abstractmethod
    def _stop_on_result(self, node: int, mu: float) -> bool:
        """Stop refinement at a node whose query came back visible with visibility mu?"""

    def _push(self, heap, node):
        heapq.heappush(heap, (self.key[node], node))

    def _traverse(self, stats):
        heap: list = [(self.key[0], 0)]
        self._on_push(0)
        queue: deque[_Pending] = deque()
        skipping = self.skippable is not None

        def descend(node, stop):
            if stop:
                self._render(node, stats)
            else:
                for child in self._children(node):
                    self._on_push(child)
                    self._push(heap, child)

        while heap or queue:
            while queue and (not heap or self._available(queue[0])):
                pending = queue.popleft()
                node = pending.node
                q, mu = self._mu(pending, stats)
                if pending.mode == MEASURE_RATIO:
                    self._measured(node, q, mu)
                elif q > 0:
                    self._pull_up(node)
                    stop = self._stop_on_result(node, mu)
                    self.stop_refinement[node] = stop
                    if skipping:
                        self._queried(node, pending.mode, not stop)
                    if stop:
                        if self._render(node, stats) and pending.mode == DELAY:
                            stats.d += 1
                            stats.delayed.append(node)
                    else:
                        if self.rendered[node] == self.frame_id:
                            stats.rarn += 1
                            stats.refined_after_draw.append(node)
                        descend(node, False)
                else:
                    self.ratio[node] = 0.0  # P(0) = 0; the node stays invisible
                    if skipping:
                        self._queried(node, pending.mode, True)
            if heap:
                _, node = heapq.heappop(heap)
                if not self.in_frustum[node]:
                    continue
                stats.traversed += 1
                mode = self._predict(node)
                stop = mode != REFINE
                self.stop_refinement[node] = stop
                self.visible[node] = False
                self.last_visited[node] = self.frame_id
                if stop:
                    if mode == STOP and skipping and self._skips(node):
                        self._pull_up(node)  # assumed visible: stays so, keeps its ratio
                        stats.skipped.append(node)
                    else:
                        queue.append(self._issue(node, mode, stats))
                elif self._measures_refined(node):
                    queue.append(self._issue(node, MEASURE_RATIO, stats))
                if mode != DELAY:
                    descend(node, stop)

    def _measures_refined(self, node: int) -> bool:
        """Hook: query this node although it refines (Coh's measured shift-up)?"""
        return False

    def _measured(self, node: int, q: int, mu: float) -> None:
        """Hook: the result of a MEASURE_RATIO query; it draws and refines nothing."""

    def _on_push(self, node: int) -> None:
        """Hook: Simp records the insertion position."""


class Bool(CoherentLoop):
    """CHC adapted to HLOD (dissertation Algorithm 1, Gobbetti & Marton): queries as booleans, SSE."""

    name = "bool"
    modulates = False
    skips_queries = True

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), **kwargs):
        super().__init__(hlod, renderer, settings, **kwargs)
        self.ratio[:] = 1.0  # queries are booleans: VMSSE never lowers its LOD

    def _predict(self, node):
        was_visible = self.visible[node] and self.last_visited[node] == self.frame_id - 1
        if not was_visible:
            return DELAY
        return STOP if self._sse_stop(node) else REFINE

    def _stop_on_result(self, node, mu):
        self.ratio[node] = 1.0
        return self._sse_stop(node)


class Simp(CoherentLoop):
    """Algorithm 2 with Algorithm 3 (2006): mu_hat = 1 - insertion position / nodes scheduled,
    both from the previous frame."""

    name = "simp"

    def __init__(self, hlod, renderer, settings=RuntimeSettings()):
        super().__init__(hlod, renderer, settings)
        self._position = np.zeros(hlod.node_count, np.int64)
        self._previous_position = self._position.copy()
        self._scheduled = 0
        self._previous_scheduled = 0

    def frame(self, view):
        self._previous_position = self._position.copy()
        self._previous_scheduled, self._scheduled = self._scheduled, 0
        return super().frame(view)

    def _on_push(self, node):
        self._position[node] = self._scheduled
        self._scheduled += 1

    def _predict(self, node):
        if self.last_visited[node] != self.frame_id - 1 or not self.visible[node]:
            return DELAY
        total = max(self._previous_scheduled, 1)
        mu_hat = 1.0 - float(self._previous_position[node]) / total
        return STOP if self._vmsse_stop(node, self.settings.p(mu_hat)) else REFINE

    def _stop_on_result(self, node, mu):
        self.ratio[node] = self.settings.p(float(mu))
        return self._vmsse_stop(node, self.ratio[node])


class Coh(CoherentLoop):
    """Coh: Algorithm 2 with Algorithm 4, the cached ratio of the previous frame.

    Shift-up, "measured" (default, our extension): Algorithm 4 learns that the front may move up
    only from the children's average ratio, and only when all of them stopped. Visibility is not
    additive over the hierarchy: a node barely visible (P ~ 0) can hold a child visible well over
    t (P ~ 1), so the children keep refining where stop-and-wait, which queries the node itself,
    stops, and the front stays too deep for as long as the view lasts. So refined nodes in the
    frustum are queried too, without waiting (MEASURE_RATIO: the result only stores the node's
    ratio), each every `measure_every_frames`-th frame, staggered by node index; a refined node with
    a ratio measured that recently predicts Delay (verified by its own query, as Algorithm 4's
    shift-up is) when the ratio stops it, Refine otherwise; without one, Algorithm 4 decides as
    published. Refined nodes are the large boxes, which a CPU rasteriser pays for by area, so they
    are measured every few frames rather than every frame (the README gives the measured trade-off).
    "children" is Algorithm 4 alone (the report's Coh(P) Alg. 4 row).
    """

    measure_every_frames = 4

    name = "coh"
    skips_queries = True

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), **kwargs):
        super().__init__(hlod, renderer, settings, **kwargs)
        self.measured = np.full(hlod.node_count, NEVER_FRAME, np.int64)  # frame of the node's last query result
        self._measure = settings.shift_up == "measured"

    def _predict(self, node):
        if self.last_visited[node] != self.frame_id - 1 or not self.visible[node]:
            return DELAY
        if self._leaf[node]:
            return STOP if self.stop_refinement[node] else DELAY
        if not self.stop_refinement[node]:
            if self._measure and self.frame_id - self.measured[node] <= self.measure_every_frames:
                return DELAY if self._vmsse_stop(node, self.ratio[node]) else REFINE
            candidate = True
            ratios = []
            for child in self._children(node):
                visited = self.last_visited[child] == self.frame_id - 1
                stopped = self.stop_refinement[child] if visited else True
                ratio = self.ratio[child] if visited else 0.0
                ratios.append(ratio)
                if not stopped or not self._vmsse_stop(child, ratio):
                    candidate = False
            if candidate and self._vmsse_stop(node, sum(ratios) / len(ratios)):
                return DELAY
        elif self._vmsse_stop(node, self.ratio[node]):
            return STOP
        return REFINE

    def _stop_on_result(self, node, mu):
        self.ratio[node] = self.settings.p(float(mu))
        self.measured[node] = self.frame_id
        return self._vmsse_stop(node, self.ratio[node])

    def _measures_refined(self, node):
        return self._measure and (node + self.frame_id) % self.measure_every_frames == 0 \
            and not self.unqueryable[node] and math.isfinite(self.sse[node])

    def _measured(self, node, q, mu):
        self.ratio[node] = self.settings.p(float(mu)) if q > 0 else 0.0
        self.measured[node] = self.frame_id


METHODS = {"full": Full, "vfc": VFC, "bool": Bool, "sw": StopAndWait, "simp": Simp, "coh": Coh, "ideal": Ideal}


def make(method: str, hlod: Hlod, renderer: NodeRenderer, settings: RuntimeSettings = RuntimeSettings()) -> Traversal:
    """A new traversal of `method` (a key of METHODS) with its own per-node state."""
    cls = METHODS.get(method)
    if cls is None:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    return cls(hlod, renderer, settings)
