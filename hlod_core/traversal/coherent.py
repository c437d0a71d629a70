"""The coherent traversals (docs/how-it-works.md#the-traversal-methods): Algorithm 2's loop of J. P.
Charalambos' dissertation ("HLOD Refinement Driven by Hardware Occlusion Queries", 2007;
docs/how-it-works.md#papers), after CHC (Bittner, Wimmer, Piringer, Purgathofer 2004: the
front-to-back priority queue, the FIFO query queue, visibility pulled up, queries never stalling
while work remains), and its three predictors: Bool (Algorithm 1, after Gobbetti & Marton), Simp
(Algorithm 3, the 2006 predictor) and Coh (Algorithm 4: refine / stop / delay from the previous
frame's cached ratio).

Decisions on points the pseudocode leaves open (docs/how-it-works.md#the-traversal-methods): a node drawn this frame is
never drawn again; if its query later says "refine" it counts in RARN and its children are traversed. A query
result of 0 sets ratio = P(0) = 0 and leaves the node invisible. In Algorithm 4 a child not visited
in the previous frame counts as stopped with ratio 0, and the average ratio is over all children.
Why and how: docs/how-it-works.md#the-coherent-loop
"""
from __future__ import annotations

import abc
import heapq
import math
from collections import deque
from collections.abc import Callable

import numpy as np

from .base import NEVER_FRAME, Traversal, state_array
from .protocol import DELAY, MEASURE_RATIO, MULTIQUERY, PREDICTED, REFINE, STOP, Pending, QueryHandle
from .query_gate import PROBING, QUERYING, Decision, QueryGate
from .query_stream import QueryStream
from .settings import RuntimeSettings
from .skipping import SkippedQueries
from .stats import MS_PER_S


class CoherentLoop(Traversal):
    """Algorithm 2's loop (Algorithm 1 with Bool's `_predict_step` and `_stop_step`), with
    CHC++'s query stream (`stream`: multiqueries and batches), skipped queries (`skips`, for the
    classes with `skips_queries`: None otherwise or with skip_queries "off"), for the classes
    with `predicts_new`, nodes not visited last frame predicted visible (settings predict_new),
    and with settings queries "auto" no queries where they do not pay (`gate`, else None)."""

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
        self.gate = QueryGate(hlod) if settings.queries == "auto" else None
        self._decision = Decision(QUERYING)  # this frame's
        self._last_drawn: list[int] = []  # the nodes drawn last frame, in draw order
        self._last_tris = 0  # and their triangles

    candidate_in = property(lambda self: state_array(self._candidate_in, np.int64), doc="(n,) int64 frame id")

    def prepare(self, view):
        super().prepare(view)
        rendered, probed_in = self._rendered, self.frame_id - 1
        self._probe_wait_s = 0.0 if self.gate is None else self.gate.read_probe(  # last frame's probe
            self.renderer, drawn_nodes=len(self._last_drawn), drawn_tris=self._last_tris,
            drawn_in=lambda node: rendered[node] == probed_in)
        self._decision = Decision(QUERYING) if self.gate is None else self.gate.decide(self.frame_id, view)
        skips = self.skips if self._decision.mode == QUERYING else None
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

    # The per-node hooks of the classes, each made once a frame as a closure over the frame's state
    # (the walk calls them for every node it visits or gets a result of).

    @abc.abstractmethod
    def _predict_step(self) -> Callable[[int], str]:
        """The frame's `predict(node)`: REFINE, STOP, DELAY or PREDICTED for a node popped from the
        priority queue."""

    @abc.abstractmethod
    def _stop_step(self) -> Callable[[int, float], bool]:
        """The frame's `stop_on_result(node, mu)`: stop refinement at a node whose query came back
        visible with visibility mu?"""

    def _measure_steps(self) -> tuple[Callable[[int], bool], Callable[[int, int, float], None]] | None:
        """Hook: the frame's `measures_refined(node)`, query this node although it refines, and
        `measured_ratio(node, q, mu)`, the result of such a MEASURE_RATIO query, which draws and
        refines nothing (Coh's measured shift-up); None: no node is measured."""
        return None

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
        """The frame's walk: with queries (`_walk`), then what they culled and cost told the gate;
        or, with the queries off, VFC's (`_walk_without_queries`)."""
        decision, gate = self._decision, self.gate
        stats.stall_ms += self._probe_wait_s * MS_PER_S
        if decision.mode == QUERYING:
            self._walk(stats)
            if gate is not None:
                _, vfc_tris = gate.vfc_cut(self.in_frustum, self.sse, self._tau)
                gate.learn_querying(self.frame_id, vfc_tris=vfc_tris, drawn_tris=stats.tris, drawn_nodes=stats.dn,
                                    queries=stats.queries)
        else:
            self._walk_without_queries(stats, probe=decision.mode == PROBING)
            stats.queries_off, stats.queries_note = 1, decision.reason
        self._last_drawn, self._last_tris = stats.drawn, stats.tris

    def _walk_without_queries(self, stats, *, probe: bool) -> None:
        """VFC's walk (methods.VFC), keeping the state the method reads next frame: every visited
        node visible, a drawn one stopped at ratio 1. A probe queries a few of last frame's farther
        drawn nodes (gate.probe_picks) together, once the nearer half is drawn (their boxes against
        what is in front of them); the gate reads their results at the next frame's start."""
        heap: list = []
        self._schedule(heap, (0,))
        frame_id, children, schedule, render = self.frame_id, self._children, self._schedule, self._draw_step(stats)
        visible, last_visited, stop_refinement, ratio = (self._visible, self._last_visited, self._stop_refinement,
                                                         self._ratio)
        sse, tau, residency, in_frustum, unqueryable = self.sse, self._tau, self._residency, self.in_frustum, \
            self.unqueryable
        heappop = heapq.heappop
        picks = [n for n in self.gate.probe_picks(self._last_drawn) if in_frustum[n] and not unqueryable[n]] \
            if probe else []
        probe_at = len(self._last_drawn) // 2 if picks else -1
        self._visited = visited = []
        drawn = 0
        while heap:
            node = heappop(heap)[1]
            visited.append(node)
            visible[node], last_visited[node] = True, frame_id
            stop = sse[node] <= tau or (residency is not None and not self._refinable(node, visible=True))
            stop_refinement[node] = stop
            if not stop:
                schedule(heap, children[node])
                continue
            ratio[node] = 1.0
            if drawn == probe_at:  # the nearer half drawn: the picks' boxes against it
                stats.probes = self.gate.probe(self.renderer, picks)
            drawn += 1
            render(node)
        stats.traversed += len(visited)
        if picks and not stats.probes:  # fewer nodes drawn than the probe waited for
            stats.probes = self.gate.probe(self.renderer, picks)
        stats.queries += stats.probes

    def _walk(self, stats):
        """Results taken in the order issued while they are back (all of them once the heap is
        empty), then the nearest node popped and visited. Queries waiting in the stream go out
        when due (CHC++): the i-queue when full, when nothing is in flight (multiquery "on") or
        before the walk would wait (the heap empty); else the batch, when full or before the walk
        would wait. The per-node steps are closures over the frame's state (`_visit_step`,
        `_result_step`): this loop is the traversal's Python cost per node."""
        heap: list = []
        self._schedule(heap, (0,))
        queue: deque[Pending] = deque()
        stream = self.stream
        stream.clear()
        self._visited = visited = []
        render = self._draw_step(stats)
        visit = self._visit_step(heap, queue, visited, render=render, stats=stats)
        take_result = self._result_step(heap, queue, render=render, stats=stats)
        waiting_hidden, waiting_batch, heappop = stream.waiting_hidden, stream.waiting_batch, heapq.heappop
        eager, hidden_full, batch_full = stream.eager_groups, stream.multiquery_batch, stream.query_batch
        available, popleft = self.renderer.available, queue.popleft
        while heap or queue or waiting_hidden or waiting_batch:
            while queue and (not heap or queue[0][2] is None or available(queue[0][2])):
                take_result(*popleft())
            if heap:
                visit(heappop(heap)[1])
            if waiting_hidden and (not heap or (eager and not queue) or len(waiting_hidden) >= hidden_full):
                stream.issue_hidden(queue)
            elif waiting_batch and (not heap or len(waiting_batch) >= batch_full):
                stream.issue_batch(queue)
        stats.traversed += len(visited)

    def _visit_step(self, heap: list, queue: deque, visited: list, *, render, stats) -> Callable[[int], None]:
        """The frame's `visit(node)` of a node popped from the heap: predicted, then skipped
        (assumed visible), queried (or queued to be: an unqueryable box without a query, visible
        with mu = 1), refined or drawn as its prediction says."""
        frame_id, children, parent, unqueryable = self.frame_id, self._children, self._parent, self.unqueryable
        visible, last_visited, stop_refinement = self._visible, self._last_visited, self._stop_refinement
        predict, measure, schedule = self._predict_step(), self._measure_steps(), self._schedule
        measures_refined = None if measure is None else measure[0]
        skips = self.skips.skip_step(frame_id) if self._skipping else None
        residency, refinable = self._residency, self._refinable
        issue, in_flight = self.stream.issue_step(queue, frame_id=frame_id), queue.append
        mark_visited, mark_skipped = visited.append, stats.skipped.append

        def visit(node: int) -> None:
            mark_visited(node)
            mode = predict(node)
            stop = mode != REFINE
            stop_refinement[node] = stop
            visible[node] = False
            last_visited[node] = frame_id
            if mode == STOP and skips is not None and skips(node):
                pull_up(node, visible, parent)  # assumed visible: pulled up, stays so, keeps its ratio
                mark_skipped(node)
            elif stop or (measures_refined is not None and measures_refined(node)):
                if unqueryable[node]:
                    in_flight((node, mode if stop else MEASURE_RATIO, None))
                else:
                    issue(node, mode if stop else MEASURE_RATIO)
            if mode == REFINE:
                if residency is None or refinable(node, visible=True):
                    schedule(heap, children[node])
                else:
                    render(node)
            elif mode != DELAY and render(node) and mode == PREDICTED:
                stats.predicted += 1
        return visit

    def _result_step(self, heap: list, queue: deque, *, render,
                     stats) -> Callable[[int, str, QueryHandle | None], None]:
        """The frame's `take_result(node, mode, query)` of a query in flight, taken off `queue` in
        the order issued. Query None: an unqueryable box, visible with mu = 1."""
        frame_id, candidate_in, predicting_new = self.frame_id, self._candidate_in, self._predicting_new
        result = self.renderer.result
        visibility, measure, key = self._visibility_step(), self._measure_steps(), self.key
        measured_ratio = None if measure is None else measure[1]  # MEASURE_RATIO queries only where measured
        multiquery_result = self.stream.multiquery_result
        found_visible, found_hidden = self._found_steps(heap, render=render, stats=stats)

        def take_result(node: int, mode: str, query: QueryHandle | None) -> None:
            if query is None:
                q, mu = 1, 1.0
            else:
                stats.queries += 1
                q, alpha_q, stall = result(query)
                stats.stall_ms += stall * MS_PER_S
                if mode == MULTIQUERY:
                    stats.multiqueries += 1
                    for member in multiquery_result(query, q, queue, key=key):
                        found_hidden(member, DELAY)
                    return
                mu = visibility(node, q, alpha_q)
                if predicting_new and candidate_in[node] == frame_id:
                    self.new_visible_share += (float(q > 0) - self.new_visible_share) * self.new_share_weight
            if mode == MEASURE_RATIO:
                measured_ratio(node, q, mu)
            elif q > 0:
                found_visible(node, mode, mu)
            else:
                found_hidden(node, mode)
        return take_result

    def _found_steps(self, heap: list, *, render, stats) -> tuple[Callable, Callable]:
        """The frame's `found_visible(node, mode, mu)` and `found_hidden(node, mode)`, what a query
        result in `mode` does. Visible with visibility mu: visibility pulled up, then refine (RARN
        if drawn already) or stop (drawn, once; D if it waited for this result). Hidden (its own
        query or a multiquery): P(0) = 0, it stays invisible."""
        frame_id, children, parent, rendered = self.frame_id, self._children, self._parent, self._rendered
        visible, stop_refinement, ratio = self._visible, self._stop_refinement, self._ratio
        stop_on_result, schedule = self._stop_step(), self._schedule
        residency, refinable = self._residency, self._refinable
        queried = self.skips.queried_step(frame_id) if self._skipping else None
        hidden = self.stream.found_hidden if self.stream.grouping else None

        def found_visible(node: int, mode: str, mu: float) -> None:
            pull_up(node, visible, parent)
            stop = stop_on_result(node, mu)
            stop_refinement[node] = stop
            if queried is not None:
                queried(node, mode, not stop)
            if not stop:
                if residency is not None and not refinable(node, visible=True):
                    render(node)
                    return
                if rendered[node] == frame_id:
                    stats.rarn += 1
                    stats.refined_after_draw.append(node)
                schedule(heap, children[node])
            elif render(node) and mode == DELAY:
                stats.d += 1
                stats.delayed.append(node)

        def found_hidden(node: int, mode: str) -> None:
            ratio[node] = 0.0
            if queried is not None:
                queried(node, mode, True)
            if hidden is not None:
                hidden(node, frame_id)
        return found_visible, found_hidden


def pull_up(node: int, visible: list, parent: list) -> None:
    """The node and its ancestors up to the first visible one become visible (CHC)."""
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

    def _predict_step(self):
        previous, visible, last_visited = self.frame_id - 1, self._visible, self._last_visited
        sse, tau = self.sse, self._tau

        def predict(node: int) -> str:
            if not (visible[node] and last_visited[node] == previous):  # not visible last frame
                return DELAY
            return STOP if sse[node] <= tau else REFINE  # _vmsse_stop at ratio 1
        return predict

    def _stop_step(self):
        ratio, sse, tau = self._ratio, self.sse, self._tau

        def stop_on_result(node: int, mu: float) -> bool:
            ratio[node] = 1.0
            return sse[node] <= tau  # _vmsse_stop at ratio 1
        return stop_on_result


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

    def _predict_step(self):
        previous, last_visited, visible = self.frame_id - 1, self._last_visited, self._visible
        position = self._previous_position
        total, p, sse, tau = max(self._previous_scheduled, 1), self._p, self.sse, self._tau

        def predict(node: int) -> str:
            if last_visited[node] != previous or not visible[node]:
                return DELAY
            mu_hat = 1.0 - position[node] / total
            return STOP if p(mu_hat) * sse[node] <= tau else REFINE  # _vmsse_stop
        return predict

    def _stop_step(self):
        ratio, p, sse, tau = self._ratio, self._p, self.sse, self._tau

        def stop_on_result(node: int, mu: float) -> bool:
            ratio[node] = node_ratio = p(mu)
            return node_ratio * sse[node] <= tau  # _vmsse_stop
        return stop_on_result


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

    def _predict_step(self):
        frame_id, previous, measured = self.frame_id, self.frame_id - 1, self._measured
        every = self.measure_every_frames
        last_visited, stop_refinement, ratio = self._last_visited, self._stop_refinement, self._ratio
        visible, leaf, sse, tau, measure = self._visible, self._leaf, self.sse, self._tau, self._measure
        unvisited, children_stop = self._predict_unvisited if self._predicting_new else None, self._children_stop

        def predict(node: int) -> str:
            if last_visited[node] != previous:
                return DELAY if unvisited is None else unvisited(node)
            if not visible[node]:
                return DELAY
            if leaf[node]:
                return STOP if stop_refinement[node] else DELAY
            # ratio * sse <= tau below is _vmsse_stop, written out
            if stop_refinement[node]:
                return STOP if ratio[node] * sse[node] <= tau else REFINE
            if measure and frame_id - measured[node] <= every:
                return DELAY if ratio[node] * sse[node] <= tau else REFINE
            return DELAY if children_stop(node) else REFINE
        return predict

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

    def _stop_step(self):
        frame_id, ratio, measured = self.frame_id, self._ratio, self._measured
        p, sse, tau = self._p, self.sse, self._tau

        def stop_on_result(node: int, mu: float) -> bool:
            ratio[node] = node_ratio = p(mu)
            measured[node] = frame_id
            return node_ratio * sse[node] <= tau  # _vmsse_stop
        return stop_on_result

    def _measure_steps(self):
        if not self._measure:
            return None
        frame_id, every, unqueryable, sse = self.frame_id, self.measure_every_frames, self.unqueryable, self.sse
        ratio, measured, p = self._ratio, self._measured, self._p

        def measures_refined(node: int) -> bool:  # every measure_every-th frame, staggered by node index
            return (node + frame_id) % every == 0 and not unqueryable[node] and math.isfinite(sse[node])

        def measured_ratio(node: int, q: int, mu: float) -> None:
            ratio[node] = p(mu) if q > 0 else 0.0
            measured[node] = frame_id
        return measures_refined, measured_ratio
