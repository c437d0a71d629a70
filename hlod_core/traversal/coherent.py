"""The coherent traversals (docs/how-it-works.md#the-traversal-methods): Algorithm 2's loop of Charalambos' dissertation
(`charalambos2007-dissertation-hlod-refinement-hoq.txt`), after CHC (Bittner, Wimmer, Piringer,
Purgathofer 2004: the front-to-back priority queue, the FIFO query queue, visibility pulled up,
queries never stalling while work remains), and its three predictors: Bool (Algorithm 1, after
Gobbetti & Marton), Simp (Algorithm 3, the 2006 predictor) and Coh (Algorithm 4: refine / stop /
delay from the previous frame's cached ratio).

Decisions on points the pseudocode leaves open (docs/how-it-works.md#the-traversal-methods): a node drawn this frame is never drawn
again; if its query later says "refine" it counts in RARN and its children are traversed. A query
result of 0 sets ratio = P(0) = 0 and leaves the node invisible. In Algorithm 4 a child not visited
in the previous frame counts as stopped with ratio 0, and the average ratio is over all children.
Why and how: docs/how-it-works.md#the-coherent-loop
"""
from __future__ import annotations

import abc
import heapq
import math
from collections import deque

import numpy as np

from .base import NEVER_FRAME, Traversal, state_array
from .protocol import DELAY, MEASURE_RATIO, MULTIQUERY, PREDICTED, REFINE, STOP, Pending, QueryHandle
from .query_stream import QueryStream
from .settings import RuntimeSettings
from .skipping import SkippedQueries
from .stats import MS_PER_S


class CoherentLoop(Traversal):
    """Algorithm 2's loop (Algorithm 1 when `_predict` and `_stop_on_result` are Bool's), with
    CHC++'s query stream (`stream`: multiqueries and batches), skipped queries (`skips`, for the
    classes with `skips_queries`: None otherwise or with skip_queries "off") and, for the classes
    with `predicts_new`, nodes not visited last frame predicted visible (settings predict_new).
    During a frame the walk's heap, query queue and stats are `_heap`, `_queue`, `_stats`."""

    skips_queries = False
    predicts_new = False
    #: Weight of one candidate's result in the running new_visible_share (about the last 32 count).
    new_share_weight = 1.0 / 32
    #: new_visible_share from which candidates are predicted visible (a candidate found hidden costs
    #: its draw, one waited for costs a stall).
    predict_new_share = 0.9

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), *, recheck_seed: int = 0):
        super().__init__(hlod, renderer, settings)
        n = hlod.node_count
        self.skips: SkippedQueries | None = None
        if self.skips_queries and settings.skip_queries != "off":
            self.skips = SkippedQueries(hlod, mode=settings.skip_queries, recheck_seed=recheck_seed,
                                        box_pixels_given=settings.alpha == "projected")
        self._skipping = False  # this frame: `skips` and a renderer with a cost model
        self.stream = QueryStream(renderer, n, settings)
        self._predicting_new = self.predicts_new and settings.predict_new == "on"
        self._visited: list[int] = []  # the nodes the last (or current) walk visited, in order
        self._candidate_in = [NEVER_FRAME] * n  # frame the node was a candidate of predict_new
        self.new_visible_share = 1.0  # nothing measured yet: candidates are predicted visible

    candidate_in = property(lambda self: state_array(self._candidate_in, np.int64), doc="(n,) int64 frame id")

    def prepare(self, view):
        super().prepare(view)
        skips = self.skips
        model = getattr(self.renderer, "cost_model", None) if skips is not None else None
        self._skipping = model is not None  # a renderer without a cost model (tests' wrappers) skips nothing
        if model is not None:
            pixels = self.alpha_estimate if self.settings.alpha == "projected" else None
            skips.prepare(view, model, self.skip_candidates(), pad=self.renderer.query_box_pad, pixels=pixels)

    def skip_candidates(self) -> list[int]:
        """The nodes the skip test asks about: visited in the last frame and visible at its end, in
        the frustum and queryable. Only a node predicted STOP is ever skipped, and every class
        predicts STOP only for such a node; read from the walk's list of the nodes it visited, not
        from the node table."""
        visible, in_frustum, unqueryable = self._visible, self.in_frustum, self.unqueryable
        return [node for node in self._visited if visible[node] and in_frustum[node] and not unqueryable[node]]

    @abc.abstractmethod
    def _predict(self, node: int) -> str:
        """REFINE, STOP, DELAY or PREDICTED for a node popped from the priority queue."""

    @abc.abstractmethod
    def _stop_on_result(self, node: int, mu: float) -> bool:
        """Stop refinement at a node whose query came back visible with visibility mu?"""

    def _measures_refined(self, node: int) -> bool:
        """Hook: query this node although it refines (Coh's measured shift-up)?"""
        return False

    def _measured_ratio(self, node: int, q: int, mu: float) -> None:
        """Hook: the result of a MEASURE_RATIO query; it draws and refines nothing."""

    def _predict_unvisited(self, node: int) -> str:
        """DELAY or PREDICTED for a node not visited last frame (predict_new on): a candidate, one
        that would stop even fully visible, is PREDICTED while new_visible_share, the running share
        of candidates whose query found them visible, is at least predict_new_share.
        Why: docs/how-it-works.md#newly-visited-nodes-predicted-visible"""
        if not self.sse[node] <= self._tau:  # refines at full visibility (SSE inf or NaN too): wait
            return DELAY
        self._candidate_in[node] = self.frame_id
        if self.new_visible_share < self.predict_new_share:
            return DELAY
        self._ratio[node] = 1.0  # P(1), until its result
        return PREDICTED

    # --- the walk -------------------------------------------------------------------------------

    def _traverse(self, stats):
        """Results taken in the order issued while they are back (all of them once the heap is
        empty), then the nearest node popped and visited; queries waiting in the stream go out
        when due."""
        heap: list = []
        self._schedule(heap, (0,))
        queue: deque[Pending] = deque()
        self._heap, self._queue, self._stats = heap, queue, stats
        stream = self.stream
        stream.clear()
        self._visited = []
        waiting_hidden, waiting_batch = stream.waiting_hidden, stream.waiting_batch
        available, heappop, take_result, visit = self.renderer.available, heapq.heappop, self._take_result, self._visit
        while heap or queue or waiting_hidden or waiting_batch:
            while queue and (not heap or queue[0][2] is None or available(queue[0][2])):
                take_result(*queue.popleft())
            if heap:
                visit(heappop(heap)[1])
            if waiting_hidden or waiting_batch:
                stream.issue_due(queue, heap_empty=not heap)
        stats.traversed += len(self._visited)

    def _visit(self, node: int) -> None:
        """A node popped from the heap: predicted, then skipped (assumed visible), queried (or
        queued to be), refined or drawn as its prediction says."""
        self._visited.append(node)
        mode = self._predict(node)
        stop = mode != REFINE
        self._stop_refinement[node] = stop
        self._visible[node] = False
        self._last_visited[node] = self.frame_id
        if mode == STOP and self._skipping and self.skips.skips(node, self.frame_id):
            self._pull_up(node)  # assumed visible: pulled up, stays so, keeps its ratio
            self._stats.skipped.append(node)
        elif stop or self._measures_refined(node):
            self._query(node, mode if stop else MEASURE_RATIO)
        if mode == REFINE:
            if self._residency is None or self._refinable(node, visible=True):
                self._schedule(self._heap, self._children[node])
            else:
                self._render(node, self._stats)
        elif mode != DELAY and self._render(node, self._stats) and mode == PREDICTED:
            self._stats.predicted += 1

    def _query(self, node: int, mode: str) -> None:
        """The node's query in `mode`: queued without one where its box cannot be queried (visible,
        mu = 1), else through the stream."""
        if self.unqueryable[node]:
            self._queue.append((node, mode, None))
        else:
            self.stream.issue(node, mode, self._queue, frame_id=self.frame_id)

    def _take_result(self, node: int, mode: str, query: QueryHandle | None) -> None:
        """The result of a query in flight (query None: an unqueryable box, visible with mu = 1)."""
        if query is None:
            q, mu = 1, 1.0
        else:
            stats = self._stats
            stats.queries += 1
            q, alpha_q, stall = self.renderer.result(query)
            stats.stall_ms += stall * MS_PER_S
            if mode == MULTIQUERY:
                stats.multiqueries += 1
                for member in self.stream.multiquery_result(query, q, self._queue, key=self.key):
                    self._found_hidden(member, DELAY)
                return
            mu = self._visibility(node, q, alpha_q)
            if self._predicting_new and self._candidate_in[node] == self.frame_id:
                self.new_visible_share += (float(q > 0) - self.new_visible_share) * self.new_share_weight
        if mode == MEASURE_RATIO:
            self._measured_ratio(node, q, mu)
        elif q > 0:
            self._found_visible(node, mode, mu)
        else:
            self._found_hidden(node, mode)

    def _found_visible(self, node: int, mode: str, mu: float) -> None:
        """A query in `mode` found the node visible with visibility mu: visibility pulled up, then
        refine (RARN if drawn already) or stop (drawn, once; D if it waited for this result)."""
        self._pull_up(node)
        stop = self._stop_on_result(node, mu)
        self._stop_refinement[node] = stop
        if self._skipping:
            self.skips.queried(node, mode, changed=not stop, frame_id=self.frame_id)
        stats = self._stats
        if not stop:
            if self._residency is not None and not self._refinable(node, visible=True):
                self._render(node, stats)
                return
            if self._rendered[node] == self.frame_id:
                stats.rarn += 1
                stats.refined_after_draw.append(node)
            self._schedule(self._heap, self._children[node])
        elif self._render(node, stats) and mode == DELAY:
            stats.d += 1
            stats.delayed.append(node)

    def _found_hidden(self, node: int, mode: str) -> None:
        """A query in `mode` (or a multiquery) found the node hidden: P(0) = 0, it stays invisible."""
        self._ratio[node] = 0.0
        if self._skipping:
            self.skips.queried(node, mode, changed=True, frame_id=self.frame_id)
        if self.stream.grouping:
            self.stream.found_hidden(node, self.frame_id)

    def _pull_up(self, node: int) -> None:
        """The node and its ancestors up to the first visible one become visible (CHC)."""
        visible, parent = self._visible, self._parent
        while node >= 0 and not visible[node]:
            visible[node] = True
            node = parent[node]


class Bool(CoherentLoop):
    """CHC adapted to HLOD (dissertation Algorithm 1, Gobbetti & Marton): queries as booleans, SSE."""

    name = "bool"
    modulates = False
    skips_queries = True

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), *, recheck_seed: int = 0):
        super().__init__(hlod, renderer, settings, recheck_seed=recheck_seed)
        self._ratio = [1.0] * hlod.node_count  # queries are booleans: VMSSE never lowers its LOD

    def _predict(self, node):
        was_visible = self._visible[node] and self._last_visited[node] == self.frame_id - 1
        if not was_visible:
            return DELAY
        return STOP if self._sse_stop(node) else REFINE

    def _stop_on_result(self, node, mu):
        self._ratio[node] = 1.0
        return self._sse_stop(node)


class Simp(CoherentLoop):
    """Algorithm 2 with Algorithm 3 (2006): mu_hat = 1 - insertion position / nodes scheduled,
    both from the previous frame."""

    name = "simp"

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), *, recheck_seed: int = 0):
        super().__init__(hlod, renderer, settings, recheck_seed=recheck_seed)
        self._position = [0] * hlod.node_count  # insertion position this frame
        self._previous_position = self._position.copy()
        self._scheduled = 0
        self._previous_scheduled = 0

    def frame(self, view):
        self._previous_position = self._position.copy()
        self._previous_scheduled, self._scheduled = self._scheduled, 0
        return super().frame(view)

    def _schedule(self, heap, nodes):
        """Every node inserted counts in the positions, the ones outside the frustum too."""
        position = self._position
        for node in nodes:
            position[node] = self._scheduled
            self._scheduled += 1
        super()._schedule(heap, nodes)

    def _predict(self, node):
        if self._last_visited[node] != self.frame_id - 1 or not self._visible[node]:
            return DELAY
        total = max(self._previous_scheduled, 1)
        mu_hat = 1.0 - self._previous_position[node] / total
        return STOP if self._vmsse_stop(node, self._p(mu_hat)) else REFINE

    def _stop_on_result(self, node, mu):
        self._ratio[node] = ratio = self._p(mu)
        return self._vmsse_stop(node, ratio)


class Coh(CoherentLoop):
    """Coh: Algorithm 2 with Algorithm 4, the cached ratio of the previous frame. Shift-up (settings
    shift_up): "children" is Algorithm 4 as published (the children's average ratio); "measured"
    (default) also queries refined nodes in the frustum, each every `measure_every`-th frame
    (staggered by node index), and lets a recently measured ratio move the front up.
    Why: docs/how-it-works.md#cohs-measured-shift-up"""

    name = "coh"
    skips_queries = True
    predicts_new = True

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), *, recheck_seed: int = 0):
        super().__init__(hlod, renderer, settings, recheck_seed=recheck_seed)
        self._measured = [NEVER_FRAME] * hlod.node_count  # frame of the node's last query result
        self._measure = settings.shift_up == "measured"
        self.measure_every_frames = settings.measure_every

    measured = property(lambda self: state_array(self._measured, np.int64), doc="(n,) int64 frame id")

    def _predict(self, node):
        previous = self.frame_id - 1
        last_visited, stop_refinement, ratio = self._last_visited, self._stop_refinement, self._ratio
        if last_visited[node] != previous:
            return self._predict_unvisited(node) if self._predicting_new else DELAY
        if not self._visible[node]:
            return DELAY
        if self._leaf[node]:
            return STOP if stop_refinement[node] else DELAY
        sse, tau = self.sse, self._tau  # ratio * sse <= tau below is _vmsse_stop, written out
        if stop_refinement[node]:
            return STOP if ratio[node] * sse[node] <= tau else REFINE
        if self._measure and self.frame_id - self._measured[node] <= self.measure_every_frames:
            return DELAY if ratio[node] * sse[node] <= tau else REFINE
        return DELAY if self._children_stop(node) else REFINE

    def _children_stop(self, node: int) -> bool:
        """Algorithm 4's shift-up: all children stopped last frame (one not visited counts as
        stopped with ratio 0), and the node stops at their average ratio."""
        previous, sse, tau = self.frame_id - 1, self.sse, self._tau
        last_visited, stop_refinement, ratio = self._last_visited, self._stop_refinement, self._ratio
        candidate = True
        total, count = 0.0, 0
        for child in self._children[node]:
            visited = last_visited[child] == previous
            stopped = stop_refinement[child] if visited else True
            child_ratio = ratio[child] if visited else 0.0
            total += child_ratio  # summed in order, as the published average
            count += 1
            if not stopped or not child_ratio * sse[child] <= tau:
                candidate = False
        return candidate and total / count * sse[node] <= tau

    def _stop_on_result(self, node, mu):
        self._ratio[node] = ratio = self._p(mu)
        self._measured[node] = self.frame_id
        return ratio * self.sse[node] <= self._tau  # _vmsse_stop

    def _measures_refined(self, node):
        return self._measure and (node + self.frame_id) % self.measure_every_frames == 0 \
            and not self.unqueryable[node] and math.isfinite(self.sse[node])

    def _measured_ratio(self, node, q, mu):
        self._ratio[node] = self._p(mu) if q > 0 else 0.0
        self._measured[node] = self.frame_id
