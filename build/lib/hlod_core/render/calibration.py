"""The renderer's cost calibration: time query boxes and node draws, fit query_cost's linear costs
(Bool and Coh leave out the queries that do not pay, CHC++'s skipped queries).

Data form: samples as three equal-length lists (count, units, seconds): for queries (queries,
pixels rasterised, seconds), for draws (draw calls, triangles, seconds); query_cost.fit_linear
turns each into a LinearCost, the two into a CostModel. The renderer sets up the framebuffer
(`Renderer.calibrate_costs`); this module draws, queries and times, as the traversal does.
Why and what: docs/how-it-works.md#the-renderers-cost-calibration
"""
from __future__ import annotations

import time

import numpy as np

from ..core.colour import DEFAULT_COLOUR
from ..core.errors import InputError
from ..model.view import look_at, perspective
from ..traversal.query_cost import CostModel, fit_linear
from .gl_functions import GL
from .queries import Query

#: NDC half-sides of the calibration's query boxes (centred squares).
CALIBRATION_BOX_HALF_SIDES = (0.01, 0.1, 0.25, 0.5)
#: Queries per timed batch of one box size.
CALIBRATION_QUERIES = 4
#: Times each sample is taken; the median is kept.
CALIBRATION_ROUNDS = 3
#: Real nodes drawn, of spread triangle counts.
CALIBRATION_DRAW_NODES = 4
#: Triangles a node's timed draws aim at, in at most CALIBRATION_MAX_REPEATS draws.
CALIBRATION_DRAW_TRIANGLES = 4_000
#: Nodes drawn to calibrate have at most this many triangles where the file has such nodes.
CALIBRATION_MAX_NODE_TRIANGLES = 16_000
CALIBRATION_MAX_REPEATS = 16
#: Framebuffer (width, height) pixels of a renderer without an own framebuffer.
CALIBRATION_SIZE = (256, 256)
#: Distance of the calibration eye from the root box's centre, in root-box diagonals.
CALIBRATION_EYE_DIAGONALS = 1.2
#: The clocks: "wall" (seconds between two glFinish: what a frame pays, the Python and driver work
#: of each call included), "gpu" (GL_TIME_ELAPSED; not inside a host whose own timer query may be
#: running). "wall" is the default: llvmpipe's GL_TIME_ELAPSED leaves the rasterisation of draws out
#: (measured: 0-3 us for batches of 10,000 triangles that take 2 ms between two glFinish).
CLOCKS = ("gpu", "wall")
CALIBRATION_CLOCK = "wall"


def check_clock(clock: str) -> str:
    """`clock` if it is one of CLOCKS; InputError otherwise."""
    if clock not in CLOCKS:
        raise InputError(f"clock must be 'gpu' or 'wall', got {clock!r}")
    return clock


def calibrate(renderer, fbo, *, clock: str) -> CostModel:
    """The fitted CostModel of `renderer` (a Renderer), timed in `fbo`, which is bound with the
    viewport covering it."""
    queries = time_queries(renderer, fbo, clock=clock)
    draws = time_draws(renderer, fbo, clock=clock)
    return CostModel(query=fit_linear(*queries), draw=fit_linear(*draws), clock=clock)


def timed_seconds(renderer, work, *, clock: str) -> float:
    """Seconds `work()` takes on `clock` ("wall": between two glFinish; "gpu": GL_TIME_ELAPSED)."""
    if clock == "gpu":
        timer = renderer.queries.acquire(GL.TIME_ELAPSED)
        renderer.gl.begin_query(GL.TIME_ELAPSED, timer)
        work()
        renderer.gl.end_query(GL.TIME_ELAPSED)
        seconds = renderer.queries.elapsed_ms(timer) / 1e3
        renderer.queries.give_back(timer, GL.TIME_ELAPSED)
        return seconds
    renderer.ctx.finish()
    started = time.perf_counter()
    work()
    renderer.ctx.finish()
    return time.perf_counter() - started


def time_queries(renderer, fbo, *, clock: str) -> tuple[list, list, list]:
    """(queries, pixels, seconds) per box size: CALIBRATION_QUERIES boxes of one size, each in its
    own occlusion query with the depth test on against a cleared depth buffer (every pixel passes:
    the pixels counted are the pixels rasterised), results read as the traversal reads them."""
    boxes, pool, gl = renderer.boxes, renderer.queries, renderer.gl
    boxes.set_matrix(np.eye(4, dtype=np.float32).tobytes())  # corners in clip space
    counts, pixels, seconds = [], [], []
    for half in CALIBRATION_BOX_HALF_SIDES:
        boxes.set_corners((-half, -half, -0.5), (half, half, 0.5))
        rounds, covered = [], []

        def work():
            renderer.set_mode("query")
            issued = []
            for _ in range(CALIBRATION_QUERIES):
                query_id = pool.acquire()
                gl.begin_query(GL.SAMPLES_PASSED, query_id)
                boxes.draw()
                gl.end_query(GL.SAMPLES_PASSED)
                issued.append(query_id)
            covered.append(sum(pool.result(Query(-1, query_id, None))[0] for query_id in issued))

        for _ in range(CALIBRATION_ROUNDS):
            renderer.clear_framebuffer(fbo)
            rounds.append(timed_seconds(renderer, work, clock=clock))
        counts.append(CALIBRATION_QUERIES)
        pixels.append(covered[-1])
        seconds.append(float(np.median(rounds)))
    return counts, pixels, seconds


def draw_picks(tri_count: np.ndarray, *, among: np.ndarray | None = None) -> np.ndarray:
    """Up to CALIBRATION_DRAW_NODES node rows with triangles, spread over the triangle counts
    (tri_count: (n,) per node) up to CALIBRATION_MAX_NODE_TRIANGLES (the smallest nodes when none
    is that small: the cost is linear, and the largest nodes of a huge file would make calibrating
    grow with it), in ascending order of row. among: (n,) bool, the nodes that may be drawn (the
    resident ones under a GPU budget); None: all."""
    tris = np.asarray(tri_count, np.int64)
    drawable = np.flatnonzero((tris > 0) if among is None else (tris > 0) & np.asarray(among, bool))
    if drawable.size == 0:
        raise InputError("the HLOD has no triangles: no draw cost to calibrate")
    small = drawable[tris[drawable] <= CALIBRATION_MAX_NODE_TRIANGLES]
    drawable = small if small.size else drawable[np.argsort(tris[drawable], kind="stable")[:CALIBRATION_DRAW_NODES]]
    by_count = drawable[np.argsort(tris[drawable], kind="stable")]
    spread = np.linspace(0, by_count.size - 1, CALIBRATION_DRAW_NODES).round().astype(int)
    return np.unique(by_count[spread])


def time_draws(renderer, fbo, *, clock: str) -> tuple[list, list, list]:
    """(draw calls, triangles, seconds) per sample: one real node drawn repeatedly, seen from
    outside the root box, for nodes of spread triangle counts, each at two repeat counts."""
    h = renderer.hlod
    lo, hi = h.box_min[0] - h.origin, h.box_max[0] - h.origin
    centre, diagonal = 0.5 * (lo + hi), max(float(np.linalg.norm(hi - lo)), 1e-30)
    eye = centre + CALIBRATION_EYE_DIAGONALS * diagonal * np.array([0.6, -0.7, 0.4])
    width, height = fbo.size
    mv = look_at(eye, centre, [0.0, 0.0, 1.0])
    mvp = perspective(60.0, width / height, near=0.05 * diagonal, far=4.0 * diagonal) @ mv
    renderer.set_node_matrices(mvp=mvp, mv=mv)
    tris = np.asarray(h.tri_count, np.int64)
    picks = draw_picks(tris, among=None if renderer.residency is None else renderer.residency.resident)
    calls, triangles, seconds = [], [], []
    for divisor in (2, 1):
        for node in picks.tolist():
            full = int(np.clip(CALIBRATION_DRAW_TRIANGLES // int(tris[node]), 1, CALIBRATION_MAX_REPEATS))
            repeats = max(1, full // divisor)

            def work():
                for _ in range(repeats):
                    renderer.draw_node_coloured(node, DEFAULT_COLOUR)

            rounds = []
            for _ in range(CALIBRATION_ROUNDS):
                renderer.clear_framebuffer(fbo)
                rounds.append(timed_seconds(renderer, work, clock=clock))
            calls.append(repeats)
            triangles.append(repeats * int(tris[node]))
            seconds.append(float(np.median(rounds)))
    return calls, triangles, seconds
