"""HLOD traversal methods (docs/how-it-works.md#the-traversal-methods), one class each, one `frame(view)` entry point,
the same counters (`stats.FrameStats`): Full, VFC, SW and Ideal here; Bool, Simp and Coh, the coherent
loop's, in `coherent`. `make` builds one by name.

Papers (docs/how-it-works.md#papers): J. P. Charalambos, "HLOD Refinement Driven by Hardware
Occlusion Queries", dissertation, 2007: stop-and-wait (SW, the ideal node count) and Algorithms
1-4; J. Bittner, M. Wimmer, H. Piringer, W. Purgathofer, "Coherent Hierarchical Culling: Hardware
Occlusion Queries Made Useful", Eurographics 2004, for the front-to-back priority queue all of
them share.
"""
from __future__ import annotations

import heapq

import numpy as np

from ..core.errors import InputError
from ..model.hierarchy import Hlod
from .base import Traversal
from .coherent import Bool, Coh, Simp
from .protocol import NodeRenderer
from .settings import RuntimeSettings
from .stats import MS_PER_S


class Full(Traversal):
    """Every leaf in the frustum, front to back: the ground-truth image."""

    name = "full"
    modulates = False

    def _traverse(self, stats):
        leaves = np.flatnonzero(self._is_leaf & np.asarray(self.in_frustum))
        order = leaves[np.argsort(np.asarray(self.key)[leaves], kind="stable")]
        stats.traversed = int(order.shape[0])
        residency, render = self._residency, self._draw_step(stats)
        for node in order.tolist():
            if residency is not None and not residency.resident[node]:
                node = self._resident_ancestor(node)
            render(node)

    def _resident_ancestor(self, node: int) -> int:
        """Under a GPU budget: the nearest resident ancestor of a leaf not resident yet, drawn in its
        place; the leaf's path is requested one level a frame (`_refinable` of that ancestor)."""
        parent, resident = self._parent, self._residency.resident
        while not resident[node]:
            node = parent[node]
        self._refinable(node, visible=True)
        return node


class VFC(Traversal):
    """View-frustum culling and SSE, no queries."""

    name = "vfc"
    modulates = False

    def _traverse(self, stats):
        heap: list = []
        self._schedule(heap, (0,))
        children, heappop, schedule, render = self._children, heapq.heappop, self._schedule, self._draw_step(stats)
        sse, tau, residency = self.sse, self._tau, self._residency
        traversed = 0
        while heap:
            node = heappop(heap)[1]
            traversed += 1
            # _vmsse_stop at ratio 1
            if sse[node] <= tau or (residency is not None and not self._refinable(node, visible=True)):
                render(node)
            else:
                schedule(heap, children[node])
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
        unqueryable, issue_query, result = self.unqueryable, self.renderer.issue_query, self.renderer.result
        render, visibility, query_alpha = self._draw_step(stats), self._visibility_step(), self._query_alpha
        traversed = 0
        while heap:
            node = heappop(heap)[1]
            traversed += 1
            last_visited[node] = frame_id
            if unqueryable[node]:  # its box cannot be queried: visible, mu = 1
                q, mu = 1, 1.0
            else:
                stats.queries += 1
                q, alpha_q, stall = result(issue_query(node, with_alpha=query_alpha))
                stats.stall_ms += stall * MS_PER_S
                mu = visibility(node, q, alpha_q)
            if q == 0:
                visible[node] = False
                ratio[node] = 0.0
                continue
            visible[node] = True
            ratio[node] = p = self._p(mu)
            stop = self._vmsse_stop(node, p)
            stop_refinement[node] = stop
            if not stop:
                if self._refinable(node, visible=True):
                    self._schedule(heap, children[node])
                else:
                    render(node)
            elif render(node):
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
        self._chosen: list[int] = []

    def frame(self, view):
        self._chosen = self._sw.frame(view).drawn
        self._ratio = self._sw._ratio
        return super().frame(view)

    def _traverse(self, stats):
        stats.traversed = len(self._chosen)
        render = self._draw_step(stats)
        for node in self._chosen:
            render(node)


METHODS = {"full": Full, "vfc": VFC, "bool": Bool, "sw": StopAndWait, "simp": Simp, "coh": Coh, "ideal": Ideal}


def make(method: str, hlod: Hlod, renderer: NodeRenderer, *,
         settings: RuntimeSettings = RuntimeSettings()) -> Traversal:
    """A new traversal of `method` (a key of METHODS) with its own per-node state."""
    cls = METHODS.get(method)
    if cls is None:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    return cls(hlod, renderer, settings)
