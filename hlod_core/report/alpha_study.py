"""The alpha estimators compared (docs/how-it-works.md#alpha-three-ways, report section "alpha estimators"): the error
of `projected` and `cube` against the exact `query` count, and each one's cost per node.

Data form: in, a renderer and a few views; out, a dict {"nodes", "views", and per estimator
{"cost_us_per_node", "median_rel_error_pct", "p90_rel_error_pct"}} (percent relative error over
boxes whose exact count is above 0; None where there are none).
"""
from __future__ import annotations

import time

import numpy as np

from ..model.hierarchy import Hlod
from ..model.view import View
from ..render.renderer import Renderer
from ..traversal import boxes
from ..traversal.alpha_estimators import alpha_cube, alpha_projected
from ..traversal.settings import ALPHA_MODES

#: Boxes sampled per view at most (seeded with SAMPLE_SEED), to bound the study's time.
MAX_NODES_PER_VIEW = 300
SAMPLE_SEED = 0
#: The `query` estimator costs one of the two GL queries issued and read per node (q and alpha).
QUERY_ESTIMATOR_SHARE = 0.5
US_PER_S = 1e6


def alpha_estimators(hlod: Hlod, renderer: Renderer, views: list[View], *,
                     max_nodes: int = MAX_NODES_PER_VIEW) -> dict:
    """Error of `projected` and `cube` against the exact `query` count, and each one's cost per
    node, over queryable boxes in the frustum at the given views (a seeded sample of max_nodes)."""
    pad = renderer.query_box_pad
    lo, hi = hlod.box_min - pad, hlod.box_max + pad
    rng = np.random.default_rng(SAMPLE_SEED)
    errors = {"query": [], "projected": [], "cube": []}
    cost_s = {mode: 0.0 for mode in ALPHA_MODES}
    count = 0
    for view in views:
        usable = (boxes.boxes_in_frustum(view, hlod.box_min, hlod.box_max)
                  & ~boxes.eye_in_boxes(view.eye, lo, hi) & ~boxes.boxes_cross_near_plane(view, lo, hi))
        nodes = np.flatnonzero(usable)
        if nodes.size > max_nodes:
            nodes = np.sort(rng.choice(nodes, max_nodes, replace=False))
        if nodes.size == 0:
            continue
        renderer.begin_frame(view, time_gpu=False)
        t0 = time.perf_counter()
        pending = [renderer.issue_query(int(n), with_alpha=True) for n in nodes]
        exact = np.array([renderer.result(p)[1] for p in pending], np.float64)
        t1 = time.perf_counter()
        projected = alpha_projected(view, lo[nodes], hi[nodes])
        t2 = time.perf_counter()
        cube = alpha_cube(view, hlod.cube_side, box_min=hlod.box_min, box_max=hlod.box_max)[nodes]
        t3 = time.perf_counter()
        renderer.end_frame()
        cost_s["query"] += QUERY_ESTIMATOR_SHARE * (t1 - t0)
        cost_s["projected"] += t2 - t1
        cost_s["cube"] += t3 - t2
        count += nodes.size
        ok = exact > 0
        errors["query"].extend([0.0] * int(ok.sum()))  # the reference itself
        errors["projected"].extend((np.abs(projected[ok] - exact[ok]) / exact[ok]).tolist())
        errors["cube"].extend((np.abs(cube[ok] - exact[ok]) / exact[ok]).tolist())
    out = {"nodes": count, "views": len(views)}
    for mode in ALPHA_MODES:
        rel = np.asarray(errors[mode], np.float64)
        out[mode] = {"cost_us_per_node": US_PER_S * cost_s[mode] / max(count, 1),
                     "median_rel_error_pct": 100 * float(np.median(rel)) if rel.size else None,
                     "p90_rel_error_pct": 100 * float(np.percentile(rel, 90)) if rel.size else None}
    return out
