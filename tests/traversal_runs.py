"""The traversal tests' shared machinery (tests/test_traversal_*.py): the viewport, the scripted
query latency and the fixed cost model that make what a traversal does independent of llvmpipe's
threads and the machine's load, and a run of one method over a camera path."""
from __future__ import annotations

from helpers import ScriptedAvailability
from hlod_core.traversal.methods import make
from hlod_core.traversal.query_cost import CostModel, LinearCost
from hlod_core.traversal.settings import RuntimeSettings

SIZE = (320, 240)
#: Results this many issued commands late (the latency of a GPU behind the CPU).
LAG = 3
#: A fixed cost model of llvmpipe's size (query 20 us + 2 ns a box pixel, draw 4 us + 5 ns a
#: triangle): the default skip_queries "expected" skips some nodes and not others, the same way on
#: every machine (the renderer's own model is timed).
LLVMPIPE_COSTS = CostModel(query=LinearCost(fixed_s=20e-6, per_unit_s=2e-9, residual=0.0),
                           draw=LinearCost(fixed_s=4e-6, per_unit_s=5e-9, residual=0.0), clock="wall")


class Scripted(ScriptedAvailability):
    """ScriptedAvailability for the batched and grouped queries too (each query of a batch, and a
    multiquery, counts as one issued command), with the fixed LLVMPIPE_COSTS as its cost model.
    Counts the results the traversal waited for (not back by the script) while queries of its own
    still waited to be issued (set `traversal`)."""

    def __init__(self, renderer, lag=LAG):
        super().__init__(renderer, lag)
        self.cost_model = LLVMPIPE_COSTS
        self.traversal = None
        self.waits_with_queries_waiting = 0

    def begin_frame(self, view):
        self.calls.append(("frame",))
        self._renderer.begin_frame(view)

    def queried(self) -> list[list[int]]:
        """Per frame, the nodes queried on their own (not in a multiquery), in issue order."""
        frames = []
        for call in self.calls:
            if call == ("frame",):
                frames.append([])
            elif call[0] == "query":
                frames[-1].append(call[1])
        return frames

    def _issued_now(self, query):
        self._issued += 1
        self._issued_at[id(query)] = (self._issued, query)

    def issue_queries(self, nodes, *, with_alpha):
        out = self._renderer.issue_queries(nodes, with_alpha=with_alpha)
        for query in out:
            self._issued_now(query)
            self.calls.append(("query", query.node))
        return out

    def issue_multiquery(self, nodes):
        query = self._renderer.issue_multiquery(nodes)
        self._issued_now(query)
        self.calls.append(("multiquery", query.members))
        return query

    def result(self, query):
        late = self._issued - self._issued_at[id(query)][0] < self._lag
        t = self.traversal
        if late and t is not None and (t.stream.waiting_hidden or t.stream.waiting_batch):
            self.waits_with_queries_waiting += 1
        return super().result(query)


class ScriptedLatency:
    """Test double for the one branch hardware will not hit on demand: results that are never
    available early, so every query is fetched only when the traversal has nothing else to do.
    The skip test reads LLVMPIPE_COSTS."""

    def __init__(self, renderer):
        self._renderer = renderer
        self.cost_model = LLVMPIPE_COSTS

    def __getattr__(self, name):
        return getattr(self._renderer, name)

    def available(self, query):
        return False


def frames_of(renderer, method, path, *, settings=RuntimeSettings(), size=SIZE, images=False):
    """(stats, pixels or None) of each frame of `path` drawn by a new traversal of `method`."""
    methods = make(method, renderer.hlod, renderer, settings=settings)
    out = []
    for i in range(len(path)):
        stats = methods.frame(path.view(i, size))
        out.append((stats, renderer.read_pixels() if images else None))
    return out
