"""CHC++'s query stream for the coherent traversals: multiqueries over nodes that stay hidden, and
batches of the queries that gate nothing (Mattausch, Bittner, Wimmer, "CHC++: Coherent
Hierarchical Culling Revisited", Eurographics 2008, §3-4).

Data form: node ids (int) and the traversal's FIFO of queries in flight, a deque of
`protocol.Pending` tuples (node, mode, query); per-node state in Python lists, one entry a node.
Why and how: docs/how-it-works.md#multiqueries-and-query-batching
"""
from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

from .base import NEVER_FRAME
from .protocol import DELAY, MULTIQUERY, NodeRenderer, QueryHandle
from .settings import RuntimeSettings

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


class QueryStream:
    """How one traversal's queries are issued: each at once, or, with the settings on and a renderer
    that can (`issue_multiquery`, `issue_queries`), through CHC++'s i-queue (`waiting_hidden`:
    nodes hidden last frame, tested together) and v-queue (`waiting_batch`, the nodes of the queries
    that gate nothing, issued together, and `waiting_modes`, their modes). When each goes out is the
    traversal's loop (coherent.CoherentLoop). Keeps per node the frames in a row its own query found
    it hidden (`hidden_frames`, up to frame `hidden_in`)."""

    #: CHC++'s i-queue batch size b: hidden nodes waiting for a multiquery, at most.
    multiquery_batch = 50
    #: Queries gating nothing that wait in the batch, at most (batch_queries).
    query_batch = 50

    def __init__(self, renderer: NodeRenderer, node_count: int, settings: RuntimeSettings):
        self.renderer = renderer
        self.query_alpha = settings.alpha == "query"
        self.grouping = settings.multiquery != "off" and hasattr(renderer, "issue_multiquery")
        self.eager_groups = settings.multiquery == "on"  # issued too when nothing is in flight
        self.batching = settings.batch_queries == "on" and hasattr(renderer, "issue_queries")
        self.hidden_frames = [0] * node_count
        self.hidden_in = [NEVER_FRAME] * node_count
        self.waiting_hidden: list[int] = []
        self.waiting_batch: list[int] = []
        self.waiting_modes: list[str] = []  # the modes of waiting_batch's queries

    def clear(self) -> None:
        """Drop what waits: a frame that raised must not hand its waiting nodes to the next."""
        self.waiting_hidden.clear()
        self.waiting_batch.clear()
        self.waiting_modes.clear()

    def issue_step(self, queue: deque, *, frame_id: int) -> Callable[[int, str], None]:
        """The frame's `issue(node, mode)` of the query of a queryable node popped in frame
        `frame_id`: it waits in the i-queue if predicted DELAY and hidden last frame (multiquery),
        in the batch otherwise (batch_queries; a DELAY query gates its subtree, so the batch goes
        out with it), or is issued now. The traversal issues the waiting ones when due."""
        grouping, batching, hidden_in, previous = self.grouping, self.batching, self.hidden_in, frame_id - 1
        wait_hidden, wait_batch = self.waiting_hidden.append, self.waiting_batch.append
        wait_mode = self.waiting_modes.append
        issue_query, query_alpha, in_flight, issue_batch = (self.renderer.issue_query, self.query_alpha, queue.append,
                                                            self.issue_batch)

        def issue(node: int, mode: str) -> None:
            if grouping and mode == DELAY and hidden_in[node] == previous:
                wait_hidden(node)
            elif batching:
                wait_batch(node)
                wait_mode(mode)
                if mode == DELAY:
                    issue_batch(queue)
            else:
                in_flight((node, mode, issue_query(node, with_alpha=query_alpha)))
        return issue

    def issue_batch(self, queue: deque) -> None:
        """Issue the waiting batch through the renderer's issue_queries."""
        nodes, modes = self.waiting_batch, self.waiting_modes
        queue.extend(zip(nodes, modes, self.renderer.issue_queries(nodes.copy(), with_alpha=self.query_alpha)))
        nodes.clear()
        modes.clear()

    def issue_hidden(self, queue: deque) -> None:
        """Issue the i-queue: its groups of several as multiqueries, then its groups of one as
        their own DELAY queries (with the waiting batch, when batching)."""
        groups = multiquery_groups(self.waiting_hidden, self.hidden_frames)
        self.waiting_hidden.clear()
        for group in groups:
            if len(group) > 1:
                queue.append((group[0], MULTIQUERY, self.renderer.issue_multiquery(group)))
        self.issue_own([group[0] for group in groups if len(group) == 1], queue)

    def issue_own(self, nodes: list[int], queue: deque) -> None:
        """Each of `nodes` (queryable, predicted DELAY) gets its own query: through the batch when
        batching, else one issue_query each."""
        if self.batching:
            self.waiting_batch.extend(nodes)
            self.waiting_modes.extend([DELAY] * len(nodes))
            if self.waiting_batch:
                self.issue_batch(queue)
            return
        for node in nodes:
            queue.append((node, DELAY, self.renderer.issue_query(node, with_alpha=self.query_alpha)))

    def multiquery_result(self, query: QueryHandle, q: int, queue: deque, *, key) -> tuple[int, ...]:
        """A multiquery's result: q = 0 says each member's own query would read 0, and the members
        are returned, hidden; q > 0 issues each member's own query now, front to back (`key`: (n,)
        eye distances), and returns ()."""
        if q == 0:
            return query.members
        self.issue_own(sorted(query.members, key=key.__getitem__), queue)
        return ()

    def found_hidden(self, node: int, frame_id: int) -> None:
        """The node's own query (or its multiquery) found it hidden in frame `frame_id`."""
        self.hidden_frames[node] = self.hidden_frames[node] + 1 if self.hidden_in[node] == frame_id - 1 else 1
        self.hidden_in[node] = frame_id
