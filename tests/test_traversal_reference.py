"""Every method call for call against a plain reference (docs/how-it-works.md#the-traversal-methods
written without the library's speed-ups): the same draws, queries and results in the same order,
with results scripted to come back after a fixed lag."""
import dataclasses
import heapq
import math
from collections import deque

import numpy as np
import pytest

from helpers import ScriptedAvailability, street_path
from hlod_core.model.camera_path import inspection_path
from hlod_core.traversal import boxes
from hlod_core.traversal.base import NEVER_FRAME
from hlod_core.traversal.methods import make
from hlod_core.traversal.protocol import DELAY, MEASURE_RATIO, PREDICTED, REFINE, STOP
from hlod_core.traversal.settings import RuntimeSettings
from hlod_core.traversal.stats import COUNTERS, FrameStats
from traversal_runs import SIZE

pytestmark = pytest.mark.gl  # these tests draw with a real OpenGL context


class _ReferenceTraversal:
    """The traversals of docs/how-it-works.md#the-traversal-methods written plainly, without the library's speed-ups:
    per-node state in numpy arrays read one scalar at a time, the frame's box tests and SSE by the textbook
    (n,3) formulas, one helper call per step, every child pushed and the ones outside the frustum
    dropped when popped. Methods vfc, sw, bool, simp, coh (both shift-ups, predict_new on and off);
    skip_queries off, queries "always" (the gate that turns queries off is its own module's, tested in
    test_query_gate.py), alpha "query". The library must do exactly what this does."""

    def __init__(self, method, hlod, renderer, *, settings, gate=0.9):
        self.method, self.hlod, self.renderer, self.settings = method, hlod, renderer, settings
        self.gate = gate  # the share of candidates found visible from which they are predicted
        n = hlod.node_count
        self.visible = np.zeros(n, bool)
        self.last_visited = np.full(n, NEVER_FRAME, np.int64)
        self.stop_refinement = np.zeros(n, bool)
        self.ratio = np.full(n, 1.0 if method == "bool" else 0.0)
        self.rendered = np.full(n, NEVER_FRAME, np.int64)
        self.measured = np.full(n, NEVER_FRAME, np.int64)
        self.position, self.previous_position = np.zeros(n, np.int64), np.zeros(n, np.int64)
        self.scheduled = self.previous_scheduled = 0
        self.frame_id = 0
        self.candidate_in = np.full(n, NEVER_FRAME, np.int64)
        self.share = 1.0  # of candidates found visible, weight 1/32; predicted from 0.9

    def prepare(self, view):
        h, pad, eye = self.hlod, self.renderer.query_box_pad, view.eye
        planes = boxes.frustum_planes(view)
        normals = planes[:, :3]
        reach = np.maximum(normals, 0.0) @ h.box_max.T + np.minimum(normals, 0.0) @ h.box_min.T
        self.in_frustum = np.all(reach + planes[:, 3:] >= 0, axis=0)
        self.key = np.linalg.norm(np.maximum(np.maximum(h.box_min - eye, eye - h.box_max), 0.0), axis=1)
        d = np.linalg.norm(h.sphere_center - eye, axis=1) - h.sphere_radius
        self.sse = np.full(h.node_count, np.inf)
        self.sse[d > 0] = h.error[d > 0] * view.pixels_per_unit_y / d[d > 0]
        self.sse[h.is_leaf] = 0.0
        lo, hi = h.box_min - pad, h.box_max + pad
        near = planes[4]
        behind = np.where(near[:3] >= 0, lo, hi) @ near[:3] + near[3] < 0
        self.unqueryable = np.all((eye >= lo) & (eye <= hi), axis=1) | behind

    def frame(self, view):
        self.frame_id += 1
        self.previous_position = self.position.copy()
        self.previous_scheduled, self.scheduled = self.scheduled, 0
        self.stats = FrameStats()
        self.prepare(view)
        self.renderer.begin_frame(view)
        {"vfc": self.vfc, "sw": self.sw}.get(self.method, self.coherent)()
        self.renderer.end_frame()
        return self.stats

    def children(self, node):
        first = self.hlod.child_offset[node]
        return range(first, first + self.hlod.child_count[node]) if first >= 0 else range(0)

    def push(self, heap, node):
        self.position[node] = self.scheduled
        self.scheduled += 1
        heapq.heappush(heap, (float(self.key[node]), node))

    def render(self, node):
        if self.rendered[node] == self.frame_id:
            return False
        self.rendered[node] = self.frame_id
        self.stats.dn += 1
        self.stats.tris += int(self.hlod.tri_count[node])
        self.stats.drawn.append(node)
        self.renderer.draw_node(node, float(self.ratio[node]) if self.method not in ("vfc", "bool") else 1.0)
        return True

    def vmsse_stop(self, node, ratio):
        sse = float(self.sse[node])
        return bool(self.hlod.is_leaf[node]) or (math.isfinite(sse) and ratio * sse <= self.settings.tau)

    def sse_stop(self, node):
        return bool(self.hlod.is_leaf[node]) or self.sse[node] <= self.settings.tau

    def p(self, mu):
        """P_{s,t}(mu) as the traversal first computed it, scalar by scalar (metrics.bias, the
        vectorised one, may differ in the last bit for finite k)."""
        s, t, k = 0.0 if self.settings.bias == "mu" else self.settings.s, self.settings.t, self.settings.k
        if not mu > 0.0:
            return 0.0
        if mu >= 1.0:
            return 1.0
        if math.isinf(k):
            step = 1.0 if mu >= t else 0.0
        else:
            lo = 0.5 * (1.0 + math.tanh(-0.5 * k * t))
            den = 0.5 * (1.0 + math.tanh(0.5 * k * (1.0 - t))) - lo
            step = min(1.0, max(0.0, (0.5 * (1.0 + math.tanh(0.5 * k * (mu - t))) - lo) / den))
        return min(1.0, max(0.0, (1.0 - s) * mu + s * step))

    def issue(self, node):
        if self.unqueryable[node]:
            return None
        self.stats.queries += 1
        return self.renderer.issue_query(node, with_alpha=True)

    def mu(self, query):
        if query is None:
            return 1, 1.0
        q, alpha, _ = self.renderer.result(query)
        return q, 0.0 if not alpha > 0 else min(1.0, max(0.0, q / alpha))

    def pull_up(self, node):
        while node >= 0 and not self.visible[node]:
            self.visible[node] = True
            node = self.hlod.parent[node]

    def vfc(self):
        heap = [(float(self.key[0]), 0)]
        while heap:
            node = heapq.heappop(heap)[1]
            if self.in_frustum[node]:
                self.stats.traversed += 1
                if self.sse_stop(node):
                    self.render(node)
                else:
                    for child in self.children(node):
                        self.push(heap, child)

    def sw(self):
        heap = [(float(self.key[0]), 0)]
        while heap:
            node = heapq.heappop(heap)[1]
            if not self.in_frustum[node]:
                continue
            self.stats.traversed += 1
            self.last_visited[node] = self.frame_id
            q, mu = self.mu(self.issue(node))
            self.visible[node] = q > 0
            self.ratio[node] = self.p(mu) if q > 0 else 0.0
            stop = q == 0 or self.vmsse_stop(node, self.ratio[node])
            self.stop_refinement[node] = stop if q > 0 else self.stop_refinement[node]
            if q > 0 and stop and self.render(node):
                self.stats.d += 1
                self.stats.delayed.append(node)
            if not stop:
                for child in self.children(node):
                    self.push(heap, child)

    def predict(self, node):
        seen = self.last_visited[node] == self.frame_id - 1 and self.visible[node]
        leaf = bool(self.hlod.is_leaf[node])
        if self.method == "coh" and self.settings.predict_new == "on" and self.last_visited[node] != self.frame_id - 1 \
                and self.vmsse_stop(node, 1.0):
            self.candidate_in[node] = self.frame_id
            if self.share >= self.gate:
                self.ratio[node] = 1.0
                return PREDICTED
        if not seen:
            return DELAY
        if self.method == "bool":
            return STOP if self.sse_stop(node) else REFINE
        if self.method == "simp":
            mu_hat = 1.0 - float(self.previous_position[node]) / max(self.previous_scheduled, 1)
            return STOP if self.vmsse_stop(node, self.p(mu_hat)) else REFINE
        if leaf:
            return STOP if self.stop_refinement[node] else DELAY
        if self.stop_refinement[node]:
            return STOP if self.vmsse_stop(node, self.ratio[node]) else REFINE
        if self.settings.shift_up == "measured" and self.frame_id - self.measured[node] <= 4:
            return DELAY if self.vmsse_stop(node, self.ratio[node]) else REFINE
        kids = list(self.children(node))
        visited = [self.last_visited[c] == self.frame_id - 1 for c in kids]
        ratios = [self.ratio[c] if v else 0.0 for c, v in zip(kids, visited)]
        stopped = [bool(self.stop_refinement[c]) if v else True for c, v in zip(kids, visited)]
        if all(s and self.vmsse_stop(c, r) for c, s, r in zip(kids, stopped, ratios)) \
                and self.vmsse_stop(node, sum(ratios) / len(ratios)):
            return DELAY
        return REFINE

    def coherent(self):
        heap, queue = [], deque()
        self.push(heap, 0)
        while heap or queue:
            while queue and (not heap or queue[0][2] is None or self.renderer.available(queue[0][2])):
                node, mode, query = queue.popleft()
                q, mu = self.mu(query)
                if query is not None and self.candidate_in[node] == self.frame_id:
                    self.share += ((1.0 if q > 0 else 0.0) - self.share) / 32
                if mode == MEASURE_RATIO:
                    self.ratio[node] = self.p(mu) if q > 0 else 0.0
                    self.measured[node] = self.frame_id
                elif q > 0:
                    self.pull_up(node)
                    self.ratio[node] = 1.0 if self.method == "bool" else self.p(mu)
                    self.measured[node] = self.frame_id
                    stop = self.sse_stop(node) if self.method == "bool" else self.vmsse_stop(node, self.ratio[node])
                    self.stop_refinement[node] = stop
                    if stop and self.render(node) and mode == DELAY:
                        self.stats.d += 1
                        self.stats.delayed.append(node)
                    elif not stop:
                        if self.rendered[node] == self.frame_id:
                            self.stats.rarn += 1
                            self.stats.refined_after_draw.append(node)
                        for child in self.children(node):
                            self.push(heap, child)
                else:
                    self.ratio[node] = 0.0
            if heap:
                node = heapq.heappop(heap)[1]
                if not self.in_frustum[node]:
                    continue
                self.stats.traversed += 1
                mode = self.predict(node)
                self.stop_refinement[node] = mode != REFINE
                self.visible[node] = False
                self.last_visited[node] = self.frame_id
                if mode != REFINE:
                    queue.append((node, mode, self.issue(node)))
                elif self.method == "coh" and self.settings.shift_up == "measured" \
                        and (node + self.frame_id) % 4 == 0 and not self.unqueryable[node] \
                        and math.isfinite(self.sse[node]):
                    queue.append((node, MEASURE_RATIO, self.issue(node)))
                if mode in (STOP, PREDICTED):
                    self.render(node)
                    self.stats.predicted += mode == PREDICTED
                elif mode == REFINE:
                    for child in self.children(node):
                        self.push(heap, child)


@pytest.mark.parametrize("lag", [0, 3])
def test_every_method_does_exactly_what_the_plain_reference_does(city_renderer, lag):
    """The library's traversal is written for speed (state in lists, the frame's box tests in one
    pass, the per-node work in a few methods); it must do what the plain reference above does: the
    same renderer calls in the same order (queries, draws and the ratio each node is drawn with,
    results), the same counters and drawn nodes every frame, the same state after the path, as the
    plain reference above. Results come back after a scripted lag (none, or 3 issued commands), so
    both see the same availability; the street walk and an inspection path (orbit, fly-through,
    close-up) both."""
    hlod = city_renderer.hlod
    paths = (street_path(20), inspection_path(hlod, seed=11, frames=28))
    plain = RuntimeSettings(skip_queries="off", queries="always")  # the reference asks every query, every frame
    variants = [(m, plain) for m in ("vfc", "sw", "bool", "simp", "coh")] + [
        ("coh", dataclasses.replace(plain, shift_up="children")), ("coh", dataclasses.replace(plain, bias="mu")),
        ("simp", dataclasses.replace(plain, bias="mu")), ("sw", dataclasses.replace(plain, s=0.6, t=0.2, k=30.0)),
        ("coh", dataclasses.replace(plain, s=0.6, t=0.2, k=30.0)),
        ("coh", dataclasses.replace(plain, predict_new="off"))]
    variants = [(method, settings, 0.9) for method, settings in variants] + [("coh", plain, 0.0)]  # gate open too
    compared = {"rarn": 0, "d": 0, "queries": 0, "not_yet": 0, "predicted": 0}

    def library(r, method, *, settings, gate):
        methods = make(method, hlod, r, settings=settings)
        methods.predict_new_share = gate
        return methods

    for method, settings, gate in variants:
        runs = []
        for make_traversal in (lambda r: library(r, method, settings=settings, gate=gate),
                               lambda r: _ReferenceTraversal(method, hlod, r, settings=settings, gate=gate)):
            scripted = ScriptedAvailability(city_renderer, lag)
            methods = make_traversal(scripted)
            frames = []
            for path in paths:
                for i in range(len(path)):
                    s = methods.frame(path.view(i, SIZE))
                    frames.append((s.dn, s.rarn, s.d, s.tris, s.queries, s.traversed, s.drawn, s.delayed,
                                   s.refined_after_draw, s.predicted))
            state = [np.asarray(getattr(methods, a)).tolist() for a in ("visible", "stop_refinement", "ratio",
                                                                          "last_visited", "rendered")]
            runs.append((scripted.calls, frames, state))
            compared["not_yet"] += scripted.not_yet
        (calls, frames, state), (ref_calls, ref_frames, ref_state) = runs
        for i, (got, want) in enumerate(zip(frames, ref_frames)):
            assert got == want, (method, settings, lag, "frame", i, got[:6], want[:6])
        assert calls == ref_calls, (method, settings, lag)
        assert state == ref_state, (method, settings, lag)
        for c in ("rarn", "d", "queries"):
            compared[c] += sum(f[COUNTERS.index(c)] for f in frames)
        compared["predicted"] += sum(f[-1] for f in frames)
    # the paths drew nodes that then refined, waited for results, queried, predicted new nodes
    # visible; with a lag, results were late
    assert all(compared[c] for c in ("rarn", "d", "queries", "predicted")), compared
    assert (compared["not_yet"] > 0) == (lag > 0), compared
