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
Python loop is the traversal itself, over the nodes it visits. Data form: the walk reads the frame's
(n,) results through memoryviews (a Python scalar per index, at about a list's speed, without a
per-frame `tolist`) and keeps the per-node state it reads and writes one node at a time in Python
lists (a list index costs a fifth of a numpy scalar's); `visible`, `ratio` etc. give that state as
(n,) arrays for vectorised readers.
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
from ..core.errors import InputError
from ..model.hierarchy import Hlod
from ..model.view import View
from ..render.queries import Query

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
#: CHC++'s multiqueries (CoherentLoop): "on" tests nodes found hidden last frame together, and
#: issues the waiting ones at once when nothing is in flight; "lazy" waits for a full group or an
#: empty heap even then (fewer, larger multiqueries, the traversal may wait for them).
MULTIQUERY_MODES = ("off", "on", "lazy")
#: CHC++'s query batching (CoherentLoop): "on" issues the queries that gate nothing together.
BATCH_QUERY_MODES = ("off", "on")
#: The mode of one query over the boxes of several nodes hidden last frame (CHC++'s multiquery):
#: q = 0 keeps them all hidden, q > 0 issues each one's own query.
MULTIQUERY = "multiquery"
#: The prediction and query mode of a node not visited last frame that Coh draws at once, assumed
#: visible (settings predict_new "on", CoherentLoop): verified by its own query, as a STOP node is.
PREDICTED = "predicted"
#: predict_new (Coh): "off" waits for the query of every node not visited last frame, "on" draws
#: those that would stop even fully visible at once while most such nodes turn out visible.
PREDICT_NEW_MODES = ("off", "on")
#: Frame id of "never": far enough below frame 1 that no "visited last frame" and no "measured
#: within Coh.measure_every_frames" (RuntimeSettings.measure_every, any int64-sized period) test
#: holds for it.
NEVER_FRAME = -(1 << 40)
MS_PER_S = 1e3


@dataclass(frozen=True)
class RuntimeSettings:
    """tau: pixels; s, t in [0, 1] and k > 0 (inf = step) for P_{s,t}; bias "P" or "mu" (s = 0);
    alpha: "query" | "projected" | "cube";
    shift_up (Coh only): "measured" queries refined nodes too and moves the front up where their own
    ratio says stop, "children" is Algorithm 4 as published (the children's average ratio);
    skip_queries (Bool, Coh): one of SKIP_QUERY_MODES (CoherentLoop);
    multiquery (Bool, Simp, Coh): one of MULTIQUERY_MODES, batch_queries: one of BATCH_QUERY_MODES,
    CHC++'s multiqueries and query batching (CoherentLoop);
    predict_new (Coh): one of PREDICT_NEW_MODES (CoherentLoop);
    measure_every (Coh, shift_up "measured"): frames between two queries of a refined node."""

    tau: float = 1.0
    s: float = 0.9
    t: float = 0.05
    k: float = float("inf")
    bias: str = "P"
    alpha: str = "query"
    shift_up: str = "measured"
    skip_queries: str = "expected"  # measured faster on every scene (README "Queries that cannot pay"); see CoherentLoop
    multiquery: str = "on"  # on and batch_queries on: measured faster on every scene (README, CHC++)
    batch_queries: str = "on"
    predict_new: str = "on"  # measured faster or equal on every scene, node counts within 0.5% (README)
    measure_every: int = 4  # Coh's measured shift-up: each refined node queried every this many frames

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
        if self.multiquery not in MULTIQUERY_MODES:
            raise InputError(f"multiquery must be one of {MULTIQUERY_MODES}, got {self.multiquery!r}")
        if self.batch_queries not in BATCH_QUERY_MODES:
            raise InputError(f"batch_queries must be one of {BATCH_QUERY_MODES}, got {self.batch_queries!r}")
        if self.predict_new not in PREDICT_NEW_MODES:
            raise InputError(f"predict_new must be one of {PREDICT_NEW_MODES}, got {self.predict_new!r}")
        if isinstance(self.measure_every, bool) or not isinstance(self.measure_every, int) or self.measure_every < 1:
            raise InputError(f"measure_every must be a whole number of frames >= 1, got {self.measure_every!r}")
        try:
            metrics.bias(0.5, self.s, self.t, self.k)  # validates s, t, k (the messages are metrics')
        except ValueError as exc:
            raise InputError(str(exc)) from None

    def p(self, mu: float) -> float:
        """P_{s,t}(mu) of one node (s = 0 for bias "mu"), in plain Python: the traversal's per-node path."""
        return metrics.bias_scalar(float(mu), 0.0 if self.bias == "mu" else self.s, self.t, self.k)


#: FrameStats' counters, in the order of its fields (the columns of per-frame tables).
COUNTERS = ("dn", "rarn", "d", "tris", "queries", "traversed", "stall_ms", "cpu_ms", "gpu_ms", "frame_ms")
#: FrameStats' counters of the query stream (issue 15, CHC++), after COUNTERS: not columns of the
#: evaluation's per-frame files, which keep the counters they were saved with.
QUERY_COUNTERS = ("multiqueries", "state_changes", "predicted")


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
    multiqueries: int = 0   # of `queries`, those over several nodes' boxes (CHC++)
    state_changes: int = 0  # the renderer's switches between drawing and querying (its `state_changes`)
    predicted: int = 0      # nodes not visited last frame drawn at once, assumed visible (predict_new)
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

    # Only with the settings batch_queries / multiquery on (CHC++, CoherentLoop):
    # issue_queries(nodes, *, with_alpha) -> list[Query], issue_query of each, batched;
    # issue_multiquery(nodes) -> Query, one q query (no alpha) over all their boxes.

    def available(self, query: Query) -> bool:
        """Non-blocking: is the result back?"""

    def result(self, query: Query) -> tuple[int, int | None, float]:
        """(q, alpha or None, stall seconds), blocking if needed."""


#: A query in flight, as the tuple (node, mode, query) (a tuple: one is made per query); query is
#: None when the box cannot be queried (eye inside it, or it reaches in front of the near plane):
#: visible with mu = 1.
Pending = tuple[int, str, "Query | None"]


#: CHC++'s estimate (§4.1, fitted there on several scenes) that a node hidden in each of the last i
#: frames is hidden in this one: p_keep(i) = KEEP_LIMIT - KEEP_SPREAD exp(-i).
KEEP_LIMIT, KEEP_SPREAD = 0.99, 0.7


def keep_hidden(frames: int) -> float:
    """p_keep(i) of a node hidden in each of the last `frames` (>= 1) frames (CHC++ §4.1)."""
    return KEEP_LIMIT - KEEP_SPREAD * math.exp(-frames)


def multiquery_groups(nodes: list[int], hidden_frames: list[int]) -> list[list[int]]:
    """CHC++'s multiquery groups (§4.2) of `nodes`, each hidden in the last hidden_frames[node]
    frames: nodes hidden longer first (ties in the given order), each group grown while its value
    V(M) = |M| / C(M) rises, C(M) = 1 + (1 - prod p_keep) |M| the queries it is expected to cost
    (itself and, with probability 1 - prod p_keep that some member shows, each member's own query).
    A group of one is the node's own query, V = 1: a group of two or more must beat it."""
    order = sorted(nodes, key=hidden_frames.__getitem__, reverse=True)
    groups, start = [], 0
    while start < len(order):
        size, best, keep = 1, 1.0, keep_hidden(hidden_frames[order[start]])
        for m in range(2, len(order) - start + 1):
            keep *= keep_hidden(hidden_frames[order[start + m - 1]])
            value = m / (1.0 + (1.0 - keep) * m)
            if value <= best:
                break
            size, best = m, value
        groups.append(order[start:start + size])
        start += size
    return groups


def _array(values: list, dtype) -> np.ndarray:
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
        self._p = metrics.bias_function(0.0 if settings.bias == "mu" else settings.s, settings.t, settings.k)

    # (n,) arrays of the per-node state, new on each read (the walk's lists stay the state)
    visible = property(lambda self: _array(self._visible, bool), doc="(n,) bool: visible in the last query result")
    last_visited = property(lambda self: _array(self._last_visited, np.int64), doc="(n,) int64 frame id")
    stop_refinement = property(lambda self: _array(self._stop_refinement, bool), doc="(n,) bool")
    ratio = property(lambda self: _array(self._ratio, np.float64), doc="(n,) float64 P of the last result")
    rendered = property(lambda self: _array(self._rendered, np.int64), doc="(n,) int64 frame last drawn")

    # --- per frame, vectorised ------------------------------------------------------------------

    def _prepare(self, view: View) -> None:
        """The frame's node-table results, (n,) each, as memoryviews: in_frustum bool, key float64
        (eye-to-box distance, the priority), unqueryable bool (boxes.view_tests), sse float64 pixels;
        alpha_estimate (n,) float64 pixels or None (the `query` estimator)."""
        h = self.hlod
        self.view = view
        pad = self.renderer.query_box_pad
        if self._box_rows is None or self._box_rows.query_pad != pad:
            self._box_rows = boxes.BoxRows.of(h.box_min, h.box_max, pad, h.sphere_center)
        tests = boxes.view_tests(view, self._box_rows)
        in_frustum, unqueryable = tests.in_frustum, tests.unqueryable
        d = None if view.orthographic else np.subtract(tests.centre_distance, h.sphere_radius)
        error, inside = self._sse_inputs
        sse = metrics.sse_at(view, error, d, inside)
        self.in_frustum, self.key, self.unqueryable, self.sse = map(memoryview, (in_frustum, tests.distance,
                                                                                 unqueryable, sse))
        self.alpha_estimate = None  # (n,) pixels, for the estimators other than `query`
        if self.settings.alpha == "cube":
            self.alpha_estimate = alpha_estimators.alpha_cube(view, h.cube_side, h.box_min, h.box_max)
        elif self.settings.alpha == "projected":  # only boxes that can be queried this frame
            candidates = np.flatnonzero(in_frustum & ~unqueryable)
            self.alpha_estimate = np.zeros(h.node_count)
            self.alpha_estimate[candidates] = alpha_estimators.alpha_projected(
                view, h.box_min[candidates] - pad, h.box_max[candidates] + pad)

    def frame(self, view: View) -> FrameStats:
        self.frame_id += 1
        stats = FrameStats()
        started = time.perf_counter()
        self._prepare(view)
        state_changes = getattr(self.renderer, "state_changes", 0)
        self.renderer.begin_frame(view)
        self._traverse(stats)
        traversed_at = time.perf_counter()
        stats.gpu_ms = self.renderer.end_frame()
        ended = time.perf_counter()
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

    def _render(self, node: int, stats: FrameStats) -> bool:
        """Draw once per frame; False if the node was already drawn."""
        if self._rendered[node] == self.frame_id:
            return False
        self._rendered[node] = self.frame_id
        stats.dn += 1
        stats.tris += self._tri_count[node]
        stats.drawn.append(node)
        self.renderer.draw_node(node, self._ratio[node] if self.modulates else 1.0)
        return True

    def _sse_stop(self, node: int) -> bool:
        """Leaves stop; else SSE <= tau (a leaf's SSE is 0)."""
        return self.sse[node] <= self._tau

    def _vmsse_stop(self, node: int, ratio: float) -> bool:
        """Leaves stop; d <= 0 (SSE = inf) refines whatever the ratio; else ratio * SSE <= tau. One
        comparison does all three for a ratio in [0, 1]: a leaf's SSE is 0, and ratio * inf is inf
        or, for ratio 0, NaN, which compares False."""
        return ratio * self.sse[node] <= self._tau

    def _issue(self, node: int, stats: FrameStats) -> Query | None:
        """The node's query, or None where its box cannot be queried (`unqueryable`)."""
        if self.unqueryable[node]:
            return None
        stats.queries += 1
        return self.renderer.issue_query(node, with_alpha=self._query_alpha)

    def _mu(self, node: int, query: Query | None, stats: FrameStats) -> tuple[int, float]:
        """(q, mu) of a finished query; an unqueryable box (query None) gives (1, 1.0)."""
        if query is None:
            return 1, 1.0
        q, alpha_q, stall = self.renderer.result(query)
        stats.stall_ms += stall * MS_PER_S
        alpha = float(alpha_q) if self._query_alpha else float(self.alpha_estimate[node])
        mu = 0.0 if not alpha > 0 else min(1.0, q / alpha)  # alpha 0 or NaN -> 0; q > alpha -> 1 (q >= 0)
        return q, mu

    def _schedule(self, heap: list, nodes) -> None:
        """Push those of `nodes` that lie in the frustum on the front-to-back heap (a node outside
        would only be popped and dropped)."""
        key, in_frustum = self.key, self.in_frustum
        for node in nodes:
            if in_frustum[node]:
                heapq.heappush(heap, (key[node], node))


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
        heap: list = []
        self._schedule(heap, (0,))
        children, heappop = self._children, heapq.heappop
        traversed = 0
        while heap:
            node = heappop(heap)[1]
            traversed += 1
            if self._sse_stop(node):
                self._render(node, stats)
            else:
                self._schedule(heap, children[node])
        stats.traversed += traversed


class StopAndWait(Traversal):
    """SW: query every visited node and wait for it; VMSSE decides. The ideal node count."""

    name = "sw"

    def _traverse(self, stats):
        heap: list = []
        self._schedule(heap, (0,))
        frame_id, children, heappop = self.frame_id, self._children, heapq.heappop
        visible, last_visited, stop_refinement, ratio = (self._visible, self._last_visited, self._stop_refinement,
                                                         self._ratio)
        traversed = 0
        while heap:
            node = heappop(heap)[1]
            traversed += 1
            last_visited[node] = frame_id
            q, mu = self._mu(node, self._issue(node, stats), stats)
            if q == 0:
                visible[node] = False
                ratio[node] = 0.0
                continue
            visible[node] = True
            ratio[node] = p = self._p(mu)
            stop = self._vmsse_stop(node, p)
            stop_refinement[node] = stop
            if not stop:
                self._schedule(heap, children[node])
            elif self._render(node, stats):
                stats.d += 1
                stats.delayed.append(node)
        stats.traversed += traversed


class Ideal(Traversal):
    """Draws exactly the node set SW finds for the frame, with no queries: a lower bound on time.
    SW runs first in an untimed pass into the same framebuffer, which is then cleared."""

    name = "ideal"

    def __init__(self, hlod, renderer, settings=RuntimeSettings()):
        super().__init__(hlod, renderer, settings)
        self._sw = StopAndWait(hlod, renderer, settings)

    def frame(self, view):
        chosen = self._sw.frame(view).drawn
        self._ratio = self._sw._ratio
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
    visible for a few frames. The test, per node and frame, in `_prepare` (in Python for up to
    `python_skip_test_nodes` candidates, vectorised above that) from the renderer's `cost_model`
    (query_cost): "cheap" skips where drawing the node's triangles costs less than rasterising its
    query box (query_cost.box_pixels, or the projected alpha where that estimator runs); "expected"
    where that draw cost times `change_rate` (the running share of queried stopped nodes whose
    result changed something: hidden, or refined) is below the query cost. The change rate is an
    exponentially weighted mean whose weights are normalised over the results seen so far (weight
    max(change_rate_weight, 1 / results)), so its start value, 1, stops counting at the first result
    instead of holding the rate up over the first hundred or so (on an 80-frame path over the `low`
    scene that start held its mean at 0.14 against a settled 0.01). A skipped node is queried again
    on its next re-check frame: every `recheck_frames`-th frame, at a phase drawn per node from a
    generator seeded with `recheck_seed`. This is CHC++'s randomised first re-check (after a query
    finds a node visible, the next one comes 1 to recheck_frames frames later, at random) made a
    fixed per-node phase, so the re-checks of nodes that become skippable together (the change rate
    falls for all at once) spread over frames too. A node hidden meanwhile is found within
    recheck_frames frames. A renderer without a cost_model (tests' wrappers) skips nothing.

    Multiqueries (settings multiquery "on"; CHC++ §4): a node whose own query found it hidden
    (q = 0) last frame and that is predicted DELAY waits in the i-queue instead of being queried at
    once. The i-queue is issued when it holds `multiquery_batch` nodes, when nothing is in flight
    (the results would otherwise run dry: a node popped then is queried alone, at once, as without
    the option; not with "lazy") and before the traversal would wait for a result (the heap is empty), so the loop
    never blocks while a query it could issue waits. Issued, it is split into groups by CHC++'s
    rule (`multiquery_groups`): nodes hidden longer first, a group grown while its value, the
    queries it saves per query it is expected to cost, rises. A group of one is the node's own
    query; a larger one is one q query over all its boxes, no alpha (MULTIQUERY). q = 0 says what
    each node's own query would have said (a sum of counts is 0 only when each count is), and each
    stays hidden with P(0) = 0; q > 0 issues each member's own query (q and alpha: VMSSE needs the
    node's own ratio), whose result is then used as a DELAY result in the same frame.

    Query batching (settings batch_queries "on"; CHC++ §3): the queries whose results gate no
    traversal, those of nodes predicted STOP (drawn at once) and Coh's MEASURE_RATIO queries, wait
    in a batch (CHC++'s v-queue) and are issued together through the renderer's `issue_queries`,
    every q query, then every alpha query, one state change each; a DELAY query is issued at once
    with the waiting batch. The batch is issued when it holds `query_batch` queries, with the
    i-queue, with a DELAY query, and before the traversal would wait. A batched query is issued
    after draws that followed its node's own draw: its q counts what those draws leave visible.

    Newly visited nodes predicted visible (settings predict_new "on"; for the classes with
    `predicts_new`, Coh): Algorithms 1-4 predict DELAY for a node not visited last frame (the front
    moved down, the node came into the frustum, its parent reappeared), and its query result gates
    its subtree, so the walk waits for it once the heap runs dry. Such a node that would stop even
    fully visible (ratio * SSE <= tau for every ratio: leaves, and nodes with SSE <= tau), a
    "candidate", is instead predicted PREDICTED while `new_visible_share`, the running share of
    candidates whose query found them visible, is at least `predict_new_share`: it is drawn at once
    with P(1) = 1 and queried (batched, gating nothing) as a STOP node is, so its result sets its
    ratio and visibility for the next frame; one found hidden was drawn for nothing this frame only.
    A candidate that refines at full visibility would need its ratio to choose between stopping and
    refining, and keeps waiting. Every queried candidate's result, waited for or not, updates the
    share (one whose box cannot be queried counts as visible without a result, and not in it), so
    where occlusion appears the prediction stops within a few dozen results.
    """

    skips_queries = False
    predicts_new = False
    #: Weight of one candidate's result in the running new_visible_share (about the last 32 count).
    new_share_weight = 1.0 / 32
    #: new_visible_share from which candidates are predicted visible (a candidate found hidden costs
    #: its draw, one waited for costs a stall).
    predict_new_share = 0.9
    #: CHC++'s n_av, the frames a visible node is assumed visible between queries (MinSG's
    #: CHC++ renderer defaults to 5 skipped frames).
    recheck_frames = 5
    #: Weight of one query result in the running change_rate (about the last 64 results count;
    #: 1 / results before the 64th, the mean of those so far).
    change_rate_weight = 1.0 / 64
    #: CHC++'s i-queue batch size b: hidden nodes waiting for a multiquery, at most.
    multiquery_batch = 50
    #: Queries gating nothing that wait in the batch, at most (batch_queries).
    query_batch = 50
    #: Skip-test candidates up to which `_prepare` tests them in Python, node by node (above, with
    #: numpy): the crossover measured on this project's scenes (README "The skip test's start and its small fronts").
    python_skip_test_nodes = 64

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), *, recheck_seed: int = 0):
        super().__init__(hlod, renderer, settings)
        self._skip_mode = settings.skip_queries if self.skips_queries else "off"
        self._recheck_due = [0] * hlod.node_count  # frame from which a skip needs a query again
        rng = np.random.default_rng(recheck_seed)
        self._recheck_phase = rng.integers(0, self.recheck_frames, hlod.node_count).tolist()
        self.change_rate = 1.0  # nothing measured yet: every query may change something
        self._change_results = 0  # STOP results the change rate has counted
        self.skippable: memoryview | None = None  # (n,) bool or 0/1 bytes, per frame
        self._tris = np.asarray(hlod.tri_count, np.float64)
        self._box_areas: query_cost.BoxAreas | None = None  # the query boxes' areas' fixed terms (skip test)
        self._box_areas_pad = None
        self._box_lists: tuple[list, list] | None = None  # _box_areas' faces and centres as lists
        # a renderer without issue_multiquery / issue_queries (tests' wrappers, benchmarks' proxies)
        # gets each query on its own, as with the settings off
        self._grouping = settings.multiquery != "off" and hasattr(renderer, "issue_multiquery")
        self._eager_groups = settings.multiquery == "on"  # issued too when nothing is in flight
        self._batching = settings.batch_queries == "on" and hasattr(renderer, "issue_queries")
        n = hlod.node_count
        self._hidden_frames = [0] * n  # frames in a row, up to _hidden_in, the node's own query found it hidden
        self._hidden_in = [NEVER_FRAME] * n  # frame of the last of them
        self._waiting_hidden: list[int] = []  # CHC++'s i-queue (multiquery): not yet queried
        self._waiting_batch: list[tuple[int, str]] = []  # (node, mode) of the batch (batch_queries): not yet issued
        self._predicting_new = self.predicts_new and settings.predict_new == "on"
        self._visited: list[int] = []  # the nodes the last (or current) walk visited, in order
        self._candidate_in = [NEVER_FRAME] * n  # frame the node was a candidate of predict_new
        self.new_visible_share = 1.0  # nothing measured yet: candidates are predicted visible

    hidden_frames = property(lambda self: _array(self._hidden_frames, np.int64),
                             doc="(n,) int64 frames in a row the node was found hidden, up to hidden_in")
    hidden_in = property(lambda self: _array(self._hidden_in, np.int64), doc="(n,) int64 frame id")

    recheck_due = property(lambda self: _array(self._recheck_due, np.int64), doc="(n,) int64 frame id")
    candidate_in = property(lambda self: _array(self._candidate_in, np.int64), doc="(n,) int64 frame id")

    def _prepare(self, view):
        super()._prepare(view)
        self.skippable = None
        model = getattr(self.renderer, "cost_model", None) if self._skip_mode != "off" else None
        if model is None:
            return
        h, pad = self.hlod, self.renderer.query_box_pad
        candidates = self._skip_candidates()
        rate = self.change_rate if self._skip_mode == "expected" else 1.0
        projected = self.alpha_estimate if self.settings.alpha == "projected" else None
        if projected is None and (self._box_areas is None or self._box_areas_pad != pad):
            self._box_areas = query_cost.BoxAreas.of(np.asarray(h.box_min) - pad, np.asarray(h.box_max) + pad)
            self._box_areas_pad = pad
            self._box_lists = (self._box_areas.faces.tolist(), self._box_areas.centre.tolist())
        if len(candidates) <= self.python_skip_test_nodes:  # in Python, node by node
            faces, centres = self._box_lists if projected is None else (None, None)
            cheaper = query_cost.draw_is_cheaper(view, model, self._tri_count, faces, centres, projected)
            skippable = bytearray(h.node_count)
            for node in candidates:
                if cheaper(node, rate):
                    skippable[node] = 1
            self.skippable = memoryview(skippable)
            return
        candidates = np.array(candidates, np.int64)
        if projected is not None:
            pixels = projected[candidates]
        else:
            pixels = self._box_areas.pixels_outside(view, candidates)  # candidates' boxes do not hold the eye
        # draw seconds (times the change rate for "expected") < query seconds, the cost model's
        # linear costs written out with Python scalars (the same operations, fewer numpy calls)
        draw, query = model.draw, model.query
        draw_s = self._tris[candidates] * draw.per_unit_s
        draw_s += draw.fixed_s
        draw_s *= rate
        query_s = pixels * query.per_unit_s
        query_s += query.fixed_s
        skippable = np.zeros(h.node_count, bool)
        skippable[candidates] = draw_s < query_s
        self.skippable = memoryview(skippable)

    def _skip_candidates(self) -> list[int]:
        """The nodes `_prepare` tests for skipping: visited in the last frame and visible at its end,
        in the frustum and queryable. Only a node predicted STOP is ever skipped, and every class
        predicts STOP only for such a node (about the nodes drawn then: 85 of the crowd's 1,674
        queryable boxes in the frustum a frame), so the others' box areas are not computed, and
        the node table is not read: the walk keeps the list of the nodes it visits."""
        visible, in_frustum, unqueryable = self._visible, self.in_frustum, self.unqueryable
        return [node for node in self._visited if visible[node] and in_frustum[node] and not unqueryable[node]]

    def _queried(self, node: int, mode: str, changed: bool) -> None:
        """Bookkeeping of a finished STOP / DELAY / PREDICTED query (the change rate counts STOP
        results only): the next re-check (the node's next frame f
        with (f + its seeded phase) % recheck_frames == 0: 1 to recheck_frames frames on), the
        change rate."""
        n = self.recheck_frames
        self._recheck_due[node] = self.frame_id + 1 + (-(self.frame_id + 1) - self._recheck_phase[node]) % n
        if mode == STOP:
            self._change_results += 1
            weight = max(self.change_rate_weight, 1.0 / self._change_results)
            self.change_rate += (float(changed) - self.change_rate) * weight

    @abc.abstractmethod
    def _predict(self, node: int) -> str:
        """REFINE, STOP, DELAY or PREDICTED for a node popped from the priority queue."""

    def _predict_unvisited(self, node: int) -> str:
        """DELAY or PREDICTED for a node not visited last frame (predict_new on; class docstring)."""
        if not self.sse[node] <= self._tau:  # refines at full visibility (SSE inf or NaN too): wait
            return DELAY
        self._candidate_in[node] = self.frame_id
        if self.new_visible_share < self.predict_new_share:
            return DELAY
        self._ratio[node] = 1.0  # P(1), until its result
        return PREDICTED

    @abc.abstractmethod
    def _stop_on_result(self, node: int, mu: float) -> bool:
        """Stop refinement at a node whose query came back visible with visibility mu?"""

    def _traverse(self, stats):
        """Algorithm 2's loop. The per-node helpers (`_issue`, `_mu`, `_render`, the pull-up of
        visibility, the skip test and `_queried`) are written out here, with the state bound to locals: this loop is the traversal's Python cost
        per node (issue 15). With multiquery or batch_queries on, queries may wait in the i-queue or
        the batch before they are issued (class docstring)."""
        heap: list = []
        self._schedule(heap, (0,))
        queue: deque[Pending] = deque()
        # empty after every frame that ended; a frame that raised (the preview keeps its traversal)
        # must not hand its waiting nodes to this one
        self._waiting_hidden.clear()
        self._waiting_batch.clear()
        skipping = self.skippable is not None
        frame_id, children, parent, tri_count = self.frame_id, self._children, self._parent, self._tri_count
        visible, last_visited, stop_refinement = self._visible, self._last_visited, self._stop_refinement
        rendered, ratio, unqueryable = self._rendered, self._ratio, self.unqueryable
        predict, stop_on_result, schedule = self._predict, self._stop_on_result, self._schedule
        renderer = self.renderer
        available, issue_query, result, draw_node = (renderer.available, renderer.issue_query, renderer.result,
                                                     renderer.draw_node)
        query_alpha, alpha_estimate, modulates = self._query_alpha, self.alpha_estimate, self.modulates
        drawn, heappop = stats.drawn, heapq.heappop
        grouping, batching = self._grouping, self._batching
        waiting_hidden, waiting_batch = self._waiting_hidden, self._waiting_batch
        hidden_frames, hidden_in, previous = self._hidden_frames, self._hidden_in, frame_id - 1
        multiquery_batch, query_batch = self.multiquery_batch, self.query_batch
        eager_groups = self._eager_groups
        predicting_new, candidate_in = self._predicting_new, self._candidate_in
        # the skip test and the re-check bookkeeping (`_queried`) written out; the change rate is
        # stored at the end of the walk (a frame that raises loses its updates, not its re-checks)
        skippable, recheck_due, recheck_phase = self.skippable, self._recheck_due, self._recheck_phase
        recheck_frames, change_rate, change_weight = self.recheck_frames, self.change_rate, self.change_rate_weight
        next_recheck = frame_id + 1
        change_results = self._change_results
        queries = dn = tris = predicted = 0
        stall_s = 0.0
        self._visited = visited = []
        visit = visited.append
        while heap or queue or waiting_hidden or waiting_batch:
            # results in the order issued, as long as they are back (all of them once the heap is empty)
            while queue and (not heap or queue[0][2] is None or available(queue[0][2])):
                node, mode, query = queue.popleft()
                if query is None:  # a box that cannot be queried counts as visible, mu = 1
                    q, mu = 1, 1.0
                else:
                    queries += 1
                    q, alpha_q, stall = result(query)
                    stall_s += stall
                    if mode == MULTIQUERY:
                        stats.multiqueries += 1
                        self._multiquery_result(query.members, q, queue)
                        continue
                    alpha = float(alpha_q) if query_alpha else float(alpha_estimate[node])
                    mu = 0.0 if not alpha > 0 else min(1.0, q / alpha)  # as in _mu
                    if predicting_new and candidate_in[node] == frame_id:
                        self.new_visible_share += (float(q > 0) - self.new_visible_share) * self.new_share_weight
                if mode == MEASURE_RATIO:
                    self._measured_ratio(node, q, mu)
                elif q > 0:
                    up = node  # pull visibility up
                    while up >= 0 and not visible[up]:
                        visible[up] = True
                        up = parent[up]
                    stop = stop_on_result(node, mu)
                    stop_refinement[node] = stop
                    if skipping:  # _queried(node, mode, not stop)
                        recheck_due[node] = next_recheck + (-next_recheck - recheck_phase[node]) % recheck_frames
                        if mode == STOP:
                            change_results += 1
                            change_rate += (float(not stop) - change_rate) * max(change_weight, 1.0 / change_results)
                    if not stop:
                        if rendered[node] == frame_id:
                            stats.rarn += 1
                            stats.refined_after_draw.append(node)
                        schedule(heap, children[node])
                    elif rendered[node] != frame_id:  # drawn once a frame
                        rendered[node] = frame_id
                        dn += 1
                        tris += tri_count[node]
                        drawn.append(node)
                        draw_node(node, ratio[node] if modulates else 1.0)
                        if mode == DELAY:
                            stats.d += 1
                            stats.delayed.append(node)
                else:
                    ratio[node] = 0.0  # P(0) = 0; the node stays invisible
                    if skipping:  # _queried(node, mode, True)
                        recheck_due[node] = next_recheck + (-next_recheck - recheck_phase[node]) % recheck_frames
                        if mode == STOP:
                            change_results += 1
                            change_rate += (1.0 - change_rate) * max(change_weight, 1.0 / change_results)
                    if grouping:
                        hidden_frames[node] = hidden_frames[node] + 1 if hidden_in[node] == previous else 1
                        hidden_in[node] = frame_id
            if heap:
                node = heappop(heap)[1]
                visit(node)
                mode = predict(node)
                stop = mode != REFINE
                stop_refinement[node] = stop
                visible[node] = False
                last_visited[node] = frame_id
                if mode == STOP and skipping and skippable[node] and frame_id < recheck_due[node]:
                    up = node  # assumed visible: pulled up, stays so, keeps its ratio
                    while up >= 0 and not visible[up]:
                        visible[up] = True
                        up = parent[up]
                    stats.skipped.append(node)
                elif stop or self._measures_refined(node):
                    if unqueryable[node]:
                        queue.append((node, mode if stop else MEASURE_RATIO, None))
                    elif grouping and mode == DELAY and hidden_in[node] == previous:
                        waiting_hidden.append(node)  # hidden last frame: CHC++'s i-queue
                    elif batching:
                        waiting_batch.append((node, mode if stop else MEASURE_RATIO))
                        if mode == DELAY:  # it gates its subtree: issued now, with the batch
                            self._issue_batch(queue)
                    else:
                        queue.append((node, mode if stop else MEASURE_RATIO, issue_query(node, with_alpha=query_alpha)))
                if mode == REFINE:
                    schedule(heap, children[node])
                elif mode != DELAY and rendered[node] != frame_id:  # STOP or PREDICTED
                    rendered[node] = frame_id
                    dn += 1
                    tris += tri_count[node]
                    drawn.append(node)
                    draw_node(node, ratio[node] if modulates else 1.0)
                    if mode == PREDICTED:
                        predicted += 1
            if waiting_hidden and (not heap or (eager_groups and not queue) or len(waiting_hidden) >= multiquery_batch):
                self._issue_hidden(queue)
            elif waiting_batch and (not heap or len(waiting_batch) >= query_batch):
                self._issue_batch(queue)
        self.change_rate, self._change_results = change_rate, change_results
        stats.traversed += len(visited)
        stats.queries += queries
        stats.dn += dn
        stats.tris += tris
        stats.predicted += predicted
        stats.stall_ms += stall_s * MS_PER_S

    def _issue_batch(self, queue: deque) -> None:
        """Issue the waiting batch (batch_queries) through the renderer's issue_queries."""
        batch = self._waiting_batch
        issued = self.renderer.issue_queries([node for node, _ in batch], with_alpha=self._query_alpha)
        queue.extend((node, mode, query) for (node, mode), query in zip(batch, issued))
        batch.clear()

    def _issue_hidden(self, queue: deque) -> None:
        """Issue the i-queue (multiquery): its groups of several as multiqueries, then its groups of
        one as their own DELAY queries (with the waiting batch, when batching)."""
        hidden = self._waiting_hidden
        groups = multiquery_groups(hidden, self._hidden_frames)
        hidden.clear()
        for group in groups:
            if len(group) > 1:
                queue.append((group[0], MULTIQUERY, self.renderer.issue_multiquery(group)))
        self._issue_own([group[0] for group in groups if len(group) == 1], queue)

    def _issue_own(self, nodes: list[int], queue: deque) -> None:
        """Each of `nodes` (queryable, predicted DELAY) gets its own query: through the batch when
        batching, else one issue_query each."""
        if self._batching:
            self._waiting_batch.extend((node, DELAY) for node in nodes)
            if self._waiting_batch:
                self._issue_batch(queue)
            return
        for node in nodes:
            queue.append((node, DELAY, self.renderer.issue_query(node, with_alpha=self._query_alpha)))

    def _multiquery_result(self, members: tuple[int, ...], q: int, queue: deque) -> None:
        """A multiquery's result: q = 0, every member stays hidden (its own query's q = 0 result);
        else each member gets its own query now, front to back."""
        if q > 0:
            key = self.key
            self._issue_own(sorted(members, key=key.__getitem__), queue)
            return
        ratio, hidden_frames, hidden_in, frame_id = self._ratio, self._hidden_frames, self._hidden_in, self.frame_id
        skipping = self.skippable is not None
        for node in members:
            ratio[node] = 0.0
            if skipping:
                self._queried(node, DELAY, True)
            hidden_frames[node] = hidden_frames[node] + 1 if hidden_in[node] == frame_id - 1 else 1
            hidden_in[node] = frame_id

    def _measures_refined(self, node: int) -> bool:
        """Hook: query this node although it refines (Coh's measured shift-up)?"""
        return False

    def _measured_ratio(self, node: int, q: int, mu: float) -> None:
        """Hook: the result of a MEASURE_RATIO query; it draws and refines nothing."""


class Bool(CoherentLoop):
    """CHC adapted to HLOD (dissertation Algorithm 1, Gobbetti & Marton): queries as booleans, SSE."""

    name = "bool"
    modulates = False
    skips_queries = True

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), **kwargs):
        super().__init__(hlod, renderer, settings, **kwargs)
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

    def __init__(self, hlod, renderer, settings=RuntimeSettings()):
        super().__init__(hlod, renderer, settings)
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
    """Coh: Algorithm 2 with Algorithm 4, the cached ratio of the previous frame.

    Shift-up, "measured" (default, our extension): Algorithm 4 learns that the front may move up
    only from the children's average ratio, and only when all of them stopped. Visibility is not
    additive over the hierarchy: a node barely visible (P ~ 0) can hold a child visible well over
    t (P ~ 1), so the children keep refining where stop-and-wait, which queries the node itself,
    stops, and the front stays too deep for as long as the view lasts. So refined nodes in the
    frustum are queried too, without waiting (MEASURE_RATIO: the result only stores the node's
    ratio), each every `measure_every`-th frame (RuntimeSettings), staggered by node index; a refined node with
    a ratio measured that recently predicts Delay (verified by its own query, as Algorithm 4's
    shift-up is) when the ratio stops it, Refine otherwise; without one, Algorithm 4 decides as
    published. Refined nodes are the large boxes, which a CPU rasteriser pays for by area, so they
    are measured every few frames rather than every frame (the README gives the measured trade-off).
    "children" is Algorithm 4 alone (the report's Coh(P) Alg. 4 row).
    """

    name = "coh"
    skips_queries = True
    predicts_new = True

    def __init__(self, hlod, renderer, settings=RuntimeSettings(), **kwargs):
        super().__init__(hlod, renderer, settings, **kwargs)
        self._measured = [NEVER_FRAME] * hlod.node_count  # frame of the node's last query result
        self._measure = settings.shift_up == "measured"
        self.measure_every_frames = settings.measure_every

    measured = property(lambda self: _array(self._measured, np.int64), doc="(n,) int64 frame id")

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
        if not stop_refinement[node]:
            if self._measure and self.frame_id - self._measured[node] <= self.measure_every_frames:
                return DELAY if ratio[node] * sse[node] <= tau else REFINE
            # Algorithm 4's shift-up: all children stopped last frame (one not visited counts as
            # stopped with ratio 0), and the node stops at their average ratio
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
            if candidate and total / count * sse[node] <= tau:
                return DELAY
        elif ratio[node] * sse[node] <= tau:
            return STOP
        return REFINE

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


METHODS = {"full": Full, "vfc": VFC, "bool": Bool, "sw": StopAndWait, "simp": Simp, "coh": Coh, "ideal": Ideal}


def make(method: str, hlod: Hlod, renderer: NodeRenderer, settings: RuntimeSettings = RuntimeSettings()) -> Traversal:
    """A new traversal of `method` (a key of METHODS) with its own per-node state."""
    cls = METHODS.get(method)
    if cls is None:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    return cls(hlod, renderer, settings)
