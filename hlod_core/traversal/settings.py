"""The traversal's runtime settings (docs/how-it-works.md#vmsse-and-the-bias-p_st): one frozen `RuntimeSettings`,
validated on construction, and the tuples of the values each mode setting accepts."""
from __future__ import annotations

from dataclasses import dataclass

from ..core.errors import InputError
from . import metrics

ALPHA_MODES = ("query", "projected", "cube")
SHIFT_UP_MODES = ("measured", "children")
#: Queries of visible, stopped nodes that Bool and Coh leave out (skipping.SkippedQueries): "off"
#: none, "cheap" where drawing the node costs less than its query (the renderer's cost_model),
#: "expected" where the measured chance that such a query changes anything, times the draw cost,
#: is below the query cost ("cheap" is its case of chance 1).
SKIP_QUERY_MODES = ("off", "cheap", "expected")
#: CHC++'s multiqueries (query_stream.QueryStream): "on" tests nodes found hidden last frame
#: together, and issues the waiting ones at once when nothing is in flight; "lazy" waits for a full
#: group or an empty heap even then (fewer, larger multiqueries, the traversal may wait for them).
MULTIQUERY_MODES = ("off", "on", "lazy")
#: CHC++'s query batching (query_stream.QueryStream): "on" issues the queries that gate nothing together.
BATCH_QUERY_MODES = ("off", "on")
#: predict_new (Coh): "off" waits for the query of every node not visited last frame, "on" draws
#: those that would stop even fully visible at once while most such nodes turn out visible.
PREDICT_NEW_MODES = ("off", "on")
#: queries (Bool, Simp, Coh): "auto" leaves them all out, drawing as VFC, where over recent frames
#: they culled less than they cost, and probes to resume them (query_gate.QueryGate); "always"
#: queries every frame as the method asks.
QUERIES_MODES = ("auto", "always")


@dataclass(frozen=True)
class RuntimeSettings:
    """tau: pixels; s, t in [0, 1] and k > 0 (inf = step) for P_{s,t}; bias "P" or "mu" (s = 0);
    alpha: one of ALPHA_MODES;
    shift_up (Coh only): "measured" queries refined nodes too and moves the front up where their own
    ratio says stop, "children" is Algorithm 4 as published (the children's average ratio);
    skip_queries (Bool, Coh): one of SKIP_QUERY_MODES;
    multiquery (Bool, Simp, Coh): one of MULTIQUERY_MODES, batch_queries: one of BATCH_QUERY_MODES,
    CHC++'s multiqueries and query batching;
    predict_new (Coh): one of PREDICT_NEW_MODES;
    measure_every (Coh, shift_up "measured"): frames between two queries of a refined node;
    queries (Bool, Simp, Coh): one of QUERIES_MODES.
    The defaults are the fastest measured on every scene (docs/performance.md#traversal-and-preview)."""

    tau: float = 1.0
    s: float = 0.9
    t: float = 0.05
    k: float = float("inf")
    bias: str = "P"
    alpha: str = "query"
    shift_up: str = "measured"
    skip_queries: str = "expected"
    multiquery: str = "on"
    batch_queries: str = "on"
    # node counts within 0.5% of "off" (docs/performance.md#newly-visited-nodes-predicted-visible)
    predict_new: str = "on"
    measure_every: int = 4
    queries: str = "auto"

    def __post_init__(self):
        if not self.tau > 0:
            raise InputError(f"tau must be > 0 pixels, got {self.tau}")
        if self.bias not in ("P", "mu"):
            raise InputError(f"bias must be 'P' or 'mu', got {self.bias!r}")
        for name, allowed in (("alpha", ALPHA_MODES), ("shift_up", SHIFT_UP_MODES),
                              ("skip_queries", SKIP_QUERY_MODES), ("multiquery", MULTIQUERY_MODES),
                              ("batch_queries", BATCH_QUERY_MODES), ("predict_new", PREDICT_NEW_MODES),
                              ("queries", QUERIES_MODES)):
            if getattr(self, name) not in allowed:
                raise InputError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if isinstance(self.measure_every, bool) or not isinstance(self.measure_every, int) or self.measure_every < 1:
            raise InputError(f"measure_every must be a whole number of frames >= 1, got {self.measure_every!r}")
        try:
            metrics.bias(0.5, self.s, self.t, k=self.k)  # validates s, t, k (the messages are metrics')
        except ValueError as exc:
            raise InputError(str(exc)) from None

    @property
    def bias_s(self) -> float:
        """The s of the bias in use: 0 for bias "mu" (P = mu), else s."""
        return 0.0 if self.bias == "mu" else self.s
