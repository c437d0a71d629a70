"""What a traversal and its drawing side exchange (docs/how-it-works.md#the-traversal-methods): the `NodeRenderer`
protocol it draws and queries through (`render.renderer.Renderer` is one, Blender's preview another, tests wrap
them), the `QueryHandle` a query comes back as, and a query in flight (`Pending`) with its mode,
the prediction it was issued for."""
from __future__ import annotations

from typing import Protocol

from ..model.view import View

# Predictions of Algorithms 1-4 for a node popped from the priority queue; also the mode of the
# query issued for it.
REFINE, STOP, DELAY = "refine", "stop", "delay"
#: The mode of a query on a node that refines anyway, issued only to measure its own ratio for the
#: next frame (Coh's measured shift-up): its result draws and refines nothing.
MEASURE_RATIO = "measure ratio"
#: The mode of one query over the boxes of several nodes hidden last frame (CHC++'s multiquery):
#: q = 0 keeps them all hidden, q > 0 issues each one's own query.
MULTIQUERY = "multiquery"
#: The prediction and query mode of a node not visited last frame that Coh draws at once, assumed
#: visible (settings predict_new "on"): verified by its own query, as a STOP node is.
PREDICTED = "predicted"


class QueryHandle(Protocol):
    """A query the renderer issued (`render.queries.Query` is one): the node it tests and, for a
    multiquery, the nodes whose boxes it covers (empty for a node's own query)."""

    node: int
    members: tuple[int, ...]


class NodeRenderer(Protocol):
    """What a traversal needs from the drawing side. The traversal says which node it draws and
    with which ratio P; colours are the drawing side's."""

    query_box_pad: float  # model units the query boxes are enlarged by (hierarchy.query_box_pad)

    def begin_frame(self, view: View) -> None: ...

    def end_frame(self) -> float:
        """Finish the frame; GPU milliseconds (0 when not timed)."""

    def draw_node(self, node: int, ratio_p: float) -> None: ...

    def issue_query(self, node: int, *, with_alpha: bool) -> QueryHandle: ...

    # Optional, used where present (query_stream.QueryStream, with batch_queries / multiquery on):
    # issue_queries(nodes, *, with_alpha) -> list[QueryHandle], issue_query of each, batched;
    # issue_multiquery(nodes) -> QueryHandle, one q query (no alpha) over all their boxes;
    # cost_model -> query_cost.CostModel, for skipping queries (skipping.SkippedQueries);
    # state_changes: int, switches between drawing and querying so far (FrameStats).

    def available(self, query: QueryHandle) -> bool:
        """Non-blocking: is the result back?"""

    def result(self, query: QueryHandle) -> tuple[int, int | None, float]:
        """(q, alpha or None, stall seconds), blocking if needed."""


#: A query in flight, as the tuple (node, mode, query) (a tuple: one is made per query); query is
#: None when the box cannot be queried (eye inside it, or it reaches in front of the near plane):
#: visible with mu = 1.
Pending = tuple[int, str, "QueryHandle | None"]
