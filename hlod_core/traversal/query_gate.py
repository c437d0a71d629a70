"""Whether the coherent traversals (Bool, Simp, Coh) query at all this frame (settings queries "auto"):
a scene-level decision learnt from the frames drawn. Where the queries of recent frames culled less
than they cost, the traversal draws as VFC does (no queries) and probes now and then, a few queries
in a VFC frame, to notice occlusion appearing; where the probes say queries would pay, it queries
again.

What queries culled, as a share of the triangles VFC draws for the frame (`vfc_cut`): on a frame
with queries, (VFC's triangles - the triangles drawn) / VFC's (nodes found hidden and refinements
stopped by visibility, less what was drawn on last frame's visibility and refined); on a probe
frame, the share of the probed nodes' triangles their queries found hidden. What they cost, in the
same units: the queries issued times `GateParameters.query_triangles` (a query's issue, box draw
and wait, in triangles drawn), over VFC's triangles, at most `max_cost_share`. The decision reads
only these counts, never a clock, so it is the same on every run of a path.

Data form: the frame's (n,) node-table results as arrays (in_frustum bool, sse float64 pixels);
the recent frames' culled and cost shares in fixed-length deques; `Decision` names the frame's mode
and, when queries are off, why.
Why and how: docs/how-it-works.md#no-queries-where-they-do-not-pay
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..model.hierarchy import Hlod
from ..model.view import View

#: The frame's modes: queries as the method asks them; none (VFC's walk); VFC's walk with a probe.
QUERYING, OFF, PROBING = "querying", "off", "probing"


@dataclass(frozen=True)
class GateParameters:
    """The decision's parameters, in one place.

    window_frames: frames with queries over which culled and cost shares are averaged before the
    queries may go off (the learning window, and the least a resumption lasts);
    probe_every_frames: frames between two probes while queries are off;
    probe_queries: nodes a probe queries at most, spread evenly over the farther half of last frame's
    drawn nodes, and no more than half the queries the method asked over as many frames (its last
    window);
    query_triangles: what one query costs, in triangles drawn (llvmpipe: about 80 us a query at
    about 3M triangles/s, docs/performance.md#no-queries-on-an-open-scene);
    max_cost_share: the cost share's cap: queries that cull this share of VFC's triangles pay;
    off_share: the queries go off only where their culled share is below this fraction of their
    cost share (they clearly do not pay: the cost is an estimate);
    resume_share: they resume where a probe's hidden share reaches this fraction of the cost share
    (a probe sees hidden nodes, not the refinements the bias stops, so it sees less than the
    queries would cull);
    move_radii: an eye move from one frame to the next, in root-sphere radii, that probes at once
    (a cut: a smooth path, however fast, waits for the next periodic probe);
    turn_deg: a turn of the line of sight from one frame to the next that probes at once."""

    window_frames: int = 8
    probe_every_frames: int = 4
    probe_queries: int = 8
    query_triangles: float = 250.0
    max_cost_share: float = 0.08
    off_share: float = 0.25
    resume_share: float = 0.5
    move_radii: float = 0.5
    turn_deg: float = 30.0


@dataclass(frozen=True)
class Decision:
    """The frame's mode (QUERYING, OFF, PROBING) and, when queries are off, why (`reason`, words
    for the corner text and the report)."""

    mode: str
    reason: str = ""


class QueryGate:
    """The scene-level decision of one traversal (module docstring). Per frame: `decide(frame_id,
    view)` before the walk; after it `learn_querying(...)` or `learn_probe(...)`."""

    def __init__(self, hlod: Hlod, parameters: GateParameters = GateParameters()):
        self.parameters = p = parameters
        self._tri_count = np.asarray(hlod.tri_count, np.int64)
        self._parent = np.asarray(hlod.parent, np.int64)
        self._leaf = np.asarray(hlod.is_leaf, bool)
        depth = np.asarray(hlod.depth)
        self._levels = [np.flatnonzero(depth == d) for d in range(1, int(depth.max(initial=0)) + 1)]
        self._move_units = p.move_radii * float(hlod.sphere_radius[0]) if hlod.node_count else 0.0
        self._culled: deque[float] = deque(maxlen=p.window_frames)  # culled shares, frames with queries
        self._cost: deque[float] = deque(maxlen=p.window_frames)
        self._asked: deque[tuple[int, int]] = deque(maxlen=p.window_frames)  # (queries, drawn nodes)
        self._asked_total = [0, 0]  # queries and drawn nodes over every frame with queries so far
        self._probe_size = p.probe_queries
        self.mode = QUERYING
        self.reason = ""
        self._off_since = 0  # frame the queries went off
        self._last_view: tuple[np.ndarray, np.ndarray] | None = None  # (eye, forward) of the last frame
        self._probes = 0
        self.last_probe_share: float | None = None  # culled share of the last probe
        #: a probe's (nodes, queries), read at the next frame's start
        self._pending: tuple[list[int], list] | None = None

    # --- before the walk ------------------------------------------------------------------------

    def decide(self, frame_id: int, view: View) -> Decision:
        """The frame's Decision: querying while queries pay; off, or probing every
        probe_every_frames-th frame since they went off and on a cut (a large camera move since
        the last frame)."""
        eye, forward = np.asarray(view.eye, np.float64), -np.asarray(view.view[2, :3], np.float64)
        last, self._last_view = self._last_view, (eye, forward)
        if self.mode == QUERYING:
            return Decision(QUERYING)
        due = (frame_id - self._off_since) % self.parameters.probe_every_frames == 0
        if not due and last is not None:
            turn = math.degrees(math.acos(min(1.0, max(-1.0, float(forward @ last[1])))))
            due = float(np.linalg.norm(eye - last[0])) > self._move_units or turn > self.parameters.turn_deg
        return Decision(PROBING if due else OFF, self.reason)

    def probe_picks(self, last_drawn: list[int]) -> list[int]:
        """The nodes a probe queries: the probe's size of the farther half of last frame's drawn
        nodes `last_drawn` (in draw order, front to back: the nearer ones have little in front of
        them to hide them), every stride-th from a phase that moves on with each probe, so
        successive probes ask about other nodes."""
        far = last_drawn[len(last_drawn) // 2:]
        stride = max(1, len(far) // self._probe_size)
        self._probes += 1
        return far[self._probes % stride::stride][:self._probe_size]

    # --- after the walk -------------------------------------------------------------------------

    def vfc_cut(self, in_frustum: np.ndarray, sse: np.ndarray, tau: float) -> tuple[int, int]:
        """(nodes, triangles) VFC draws for the frame: the nodes in the frustum that stop (SSE <=
        tau, leaves) under ancestors that all refine, level by level. in_frustum, sse: (n,)."""
        if self._tri_count.shape[0] == 0:
            return 0, 0
        in_frustum, sse = np.asarray(in_frustum, bool), np.asarray(sse, np.float64)
        refines = ~(sse <= tau) & ~self._leaf  # SSE inf or NaN refines, as VFC's walk
        reached = np.zeros(in_frustum.shape[0], bool)
        reached[0] = in_frustum[0]
        open_ = reached & refines
        for level in self._levels:
            up = self._parent[level]
            reached[level] = open_[up] & in_frustum[level]
            open_[level] = reached[level] & refines[level]
        cut = reached & ~refines
        return int(np.count_nonzero(cut)), int(self._tri_count[cut].sum())

    def learn_querying(self, frame_id: int, *, vfc_tris: int, drawn_tris: int, drawn_nodes: int,
                       queries: int) -> None:
        """A frame with queries: its culled and cost shares join the window; once the window is
        full, queries whose mean culled share stays below off_share of their mean cost share go off."""
        p = self.parameters
        culled = (vfc_tris - drawn_tris) / vfc_tris if vfc_tris > 0 else 0.0
        cost = min(queries * p.query_triangles / vfc_tris, p.max_cost_share) if vfc_tris > 0 else 0.0
        self._culled.append(culled)
        self._cost.append(cost)
        self._asked.append((queries, drawn_nodes))
        self._asked_total[0] += queries
        self._asked_total[1] += drawn_nodes
        if len(self._culled) < p.window_frames:
            return
        mean_culled, mean_cost = float(np.mean(self._culled)), float(np.mean(self._cost))
        if mean_culled < p.off_share * mean_cost:
            asked = sum(queries for queries, _ in self._asked)
            per_probe = asked / len(self._asked) * p.probe_every_frames / 2
            self._probe_size = max(1, min(p.probe_queries, round(per_probe)))
            self.mode, self._off_since = OFF, frame_id
            self.reason = (f"queries off: they culled {max(mean_culled, 0.0):.1%} of the triangles over "
                           f"{p.window_frames} frames, cost {mean_cost:.1%}; probing every "
                           f"{p.probe_every_frames} frames")

    def probe(self, renderer, nodes: list[int]) -> int:
        """Issue a probe's queries of `nodes` (batched where the renderer batches: one state
        change); their results are read at the next frame's start (`read_probe`), so the frame does
        not wait for them. The number of queries issued."""
        batch = getattr(renderer, "issue_queries", None)
        queries = batch(nodes, with_alpha=False) if batch is not None else [
            renderer.issue_query(node, with_alpha=False) for node in nodes]
        self._pending = (nodes, queries)
        return len(queries)

    def read_probe(self, renderer, *, drawn_nodes: int, drawn_tris: int, drawn_in) -> float:
        """The last probe's results, if one is pending, learnt (`learn_probe`) with the nodes and
        triangles its frame drew; the seconds waited for them. drawn_in(node): was the node drawn
        in the probe's frame? Only those count: a node the frame did not draw (its LOD changed, it
        left the view) may be hidden by what replaced it."""
        if self._pending is None:
            return 0.0
        (nodes, queries), self._pending = self._pending, None
        hidden = probed = 0
        waited = 0.0
        for node, query in zip(nodes, queries):
            q, _, stall = renderer.result(query)
            waited += stall
            if not drawn_in(node):
                continue
            probed += int(self._tri_count[node])
            hidden += int(self._tri_count[node]) if q == 0 else 0
        self.learn_probe(hidden_tris=hidden, probed_tris=probed, drawn_nodes=drawn_nodes, drawn_tris=drawn_tris)
        return waited

    def learn_probe(self, *, hidden_tris: int, probed_tris: int, drawn_nodes: int, drawn_tris: int) -> None:
        """A probe frame: the share of the probed nodes' triangles found hidden, against what the
        method's queries would cost for the frame (its queries per drawn node over every frame with
        queries); where it reaches resume_share of that, queries resume for a new window."""
        p = self.parameters
        share = hidden_tris / probed_tris if probed_tris > 0 else 0.0
        self.last_probe_share = share
        asked, drawn = self._asked_total
        cost = min(asked / max(drawn, 1) * drawn_nodes * p.query_triangles / drawn_tris,
                   p.max_cost_share) if drawn_tris > 0 else 0.0
        if share > 0.0 and share >= p.resume_share * cost:
            self.mode, self.reason = QUERYING, ""
            self._culled.clear()
            self._cost.clear()
            self._asked.clear()
