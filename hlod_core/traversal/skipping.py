"""Skipped queries for the coherent traversals (Bool, Coh; settings skip_queries): a node predicted
STOP, visible and stopped last frame, is drawn at once and, in the published loops, queried; where
that query does not pay for itself it is left out and the node assumed visible, as CHC (Bittner et
al. 2004, §5.1) and CHC++ (Mattausch, Bittner, Wimmer 2008) assume visible nodes stay visible for a
few frames. A skipped node is queried again on its next re-check frame.

Data form: per-node state in Python lists (`recheck_due`, `recheck_phase`), one entry a node; the
frame's decisions as an (n,) mask read per node (`skippable`).
Why and how: docs/how-it-works.md#skipped-queries
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..model.hierarchy import Hlod
from ..model.view import View
from . import query_cost
from .protocol import STOP


class SkippedQueries:
    """Which visible, stopped nodes one traversal draws without their query this frame.

    mode "cheap": where drawing the node costs less than its query (query_cost.draw_is_cheaper);
    "expected": where that draw cost times `change_rate`, the running share of queried STOP nodes
    whose result changed something (hidden, or refined), is below the query cost. A skipped node
    is queried again from frame `recheck_due[node]` on: its next frame f with (f + its phase) %
    recheck_frames == 0, the phase drawn per node from a generator seeded with `recheck_seed`."""

    #: CHC++'s n_av, the frames a visible node is assumed visible between queries (MinSG's CHC++
    #: renderer defaults to 5 skipped frames).
    recheck_frames = 5
    #: Weight of one query result in the running change_rate (about the last 64 results count;
    #: 1 / results before the 64th, the mean of those so far).
    change_rate_weight = 1.0 / 64

    def __init__(self, hlod: Hlod, *, mode: str, recheck_seed: int = 0, box_pixels_given: bool = False):
        self.mode = mode
        self.python_test_nodes = query_cost.PYTHON_TEST_NODES
        self._hlod = hlod
        self._box_pixels_given = box_pixels_given  # the projected alpha estimate serves as box pixels
        n = hlod.node_count
        self.recheck_due = [0] * n  # frame from which a skip needs a query again
        self.recheck_phase = np.random.default_rng(recheck_seed).integers(0, self.recheck_frames, n).tolist()
        self.change_rate = 1.0  # nothing measured yet: every query may change something
        self.change_results = 0  # STOP results the change rate has counted
        self.skippable: memoryview | None = None  # (n,) mask, this frame's decisions
        self._costs: query_cost.NodeCosts | None = None
        self._costs_pad: float | None = None

    def prepare(self, view: View, model: query_cost.CostModel, candidates: list[int], *, pad: float,
                pixels: np.ndarray | None) -> None:
        """This frame's `skippable` among `candidates` (queryable nodes visible at the end of the
        last frame), from the renderer's cost `model`, its query boxes' `pad` (model units) and,
        where the projected alpha runs, its (n,) pixels."""
        if self._costs is None or (not self._box_pixels_given and self._costs_pad != pad):
            h = self._hlod
            bounds = () if self._box_pixels_given else (np.asarray(h.box_min) - pad, np.asarray(h.box_max) + pad)
            self._costs, self._costs_pad = query_cost.NodeCosts.of(h.tri_count, *bounds), pad
        rate = self.change_rate if self.mode == "expected" else 1.0
        self.skippable = query_cost.draw_is_cheaper(view, model, candidates, costs=self._costs, rate=rate,
                                                    pixels=pixels, python_nodes=self.python_test_nodes)

    def skip_step(self, frame_id: int) -> Callable[[int], bool]:
        """Frame `frame_id`'s `skips(node)`: is the node, predicted STOP, drawn without its query?
        A closure over this frame's `skippable` (made after `prepare`)."""
        skippable, recheck_due = self.skippable, self.recheck_due

        def skips(node: int) -> bool:
            return bool(skippable[node]) and frame_id < recheck_due[node]
        return skips

    def queried_step(self, frame_id: int) -> Callable[[int, str, bool], None]:
        """Frame `frame_id`'s `queried(node, mode, changed)`, the bookkeeping of a finished STOP /
        DELAY / PREDICTED query: the node's next re-check (1 to recheck_frames frames on) and, for
        a STOP result, the change rate: an exponential mean of weight max(change_rate_weight,
        1 / results), so its start value stops counting at the first result."""
        after, recheck_due, phase, frames = frame_id + 1, self.recheck_due, self.recheck_phase, self.recheck_frames

        def queried(node: int, mode: str, changed: bool) -> None:
            recheck_due[node] = after + (-after - phase[node]) % frames
            if mode == STOP:
                self.change_results += 1
                weight = max(self.change_rate_weight, 1.0 / self.change_results)
                self.change_rate += (float(changed) - self.change_rate) * weight
        return queried
