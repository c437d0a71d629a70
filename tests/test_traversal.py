"""Traversal methods with real OpenGL occlusion queries (Mesa llvmpipe through EGL without a GPU).

Query results come back after a scripted lag (`_Scripted`: a number of issued commands) and the
skip test reads a fixed cost model (LLVMPIPE_COSTS), so what a traversal does never depends on
llvmpipe's threads or the machine's load; the tests that run the real renderer's own availability
say so."""
import ctypes
import dataclasses
import heapq
import math
import subprocess
import sys
import time
from collections import deque

import moderngl
import numpy as np
import pytest

from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.core import colour as overlay
from hlod_core.core.colour import OVERLAY_RAMP_STEPS, overlay_ramp
from hlod_core.core.errors import InputError
from hlod_core.io import meshes, procedural
from hlod_core.model.camera_path import CameraPath, inspection_path
from hlod_core.render.gl_functions import GL, GLFunctions
from hlod_core.render.gl_state import GLState
from hlod_core.render.renderer import DEFAULT_COLOUR, Renderer
from hlod_core.traversal import alpha_estimators, boxes, metrics
from hlod_core.traversal.base import NEVER_FRAME
from hlod_core.traversal.methods import METHODS, make
from hlod_core.traversal.protocol import DELAY, MEASURE_RATIO, PREDICTED, REFINE, STOP
from hlod_core.traversal.query_cost import CostModel, LinearCost
from hlod_core.traversal.query_stream import keep_hidden, multiquery_groups
from hlod_core.traversal.settings import RuntimeSettings
from hlod_core.traversal.stats import COUNTERS, QUERY_COUNTERS, STREAM_COUNTERS, FrameStats

from helpers import ScriptedAvailability, load_model, street_path

pytestmark = pytest.mark.gl  # almost every test here draws with a real OpenGL context

SIZE = (320, 240)
#: Results this many issued commands late (the latency of a GPU behind the CPU).
LAG = 3
#: A fixed cost model of llvmpipe's size (query 20 us + 2 ns a box pixel, draw 4 us + 5 ns a
#: triangle): the default skip_queries "expected" skips some nodes and not others, the same way on
#: every machine (the renderer's own model is timed).
LLVMPIPE_COSTS = CostModel(query=LinearCost(fixed_s=20e-6, per_unit_s=2e-9, residual=0.0),
                           draw=LinearCost(fixed_s=4e-6, per_unit_s=5e-9, residual=0.0), clock="wall")


@pytest.fixture
def city_renderer(gl_ctx, city_hlod):
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    yield renderer
    renderer.release()


class _Scripted(ScriptedAvailability):
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


def _frames(renderer, method, path, *, settings=RuntimeSettings(), size=SIZE, images=False):
    """(stats, pixels or None) of each frame of `path` drawn by a new traversal of `method`."""
    methods = make(method, renderer.hlod, renderer, settings=settings)
    out = []
    for i in range(len(path)):
        stats = methods.frame(path.view(i, size))
        out.append((stats, renderer.read_pixels() if images else None))
    return out


def test_bool_draws_the_same_image_as_vfc(city_renderer):
    """Occlusion culling is conservative: Bool draws exactly VFC's pixels on a high-depth-complexity
    street walk and on an orbit-to-close-up inspection path, while drawing fewer nodes."""
    close_up = inspection_path(city_renderer.hlod, seed=3, frames=24)
    # the same path with a 6 m near plane: boxes close to the eye reach in front of it and have
    # their front faces clipped, so they must be drawn without a query (a query would read 0)
    deep_near = CameraPath(frames=close_up.frames, near=6.0, far=close_up.far, fovy_deg=60.0)
    for path in (street_path(30), close_up, deep_near):
        vfc = _frames(city_renderer, "vfc", path, images=True)
        boolean = _frames(_Scripted(city_renderer), "bool", path, images=True)
        for i, ((vs, vimg), (bs, bimg)) in enumerate(zip(vfc, boolean)):
            assert np.array_equal(vimg, bimg), f"frame {i}: {(vimg != bimg).any(axis=2).sum()} pixels differ"
            assert set(bs.drawn) <= set(vs.drawn)
        assert sum(b.dn for b, _ in boolean) < sum(v.dn for v, _ in vfc)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_no_node_is_drawn_twice_and_counters_are_consistent(city_renderer, method):
    for stats, _ in _frames(_Scripted(city_renderer), method, street_path(20)):
        assert len(stats.drawn) == len(set(stats.drawn)) == stats.dn
        assert stats.tris == int(city_renderer.hlod.tri_count[stats.drawn].sum())
        assert 0 <= stats.rarn <= stats.dn and 0 <= stats.d <= stats.dn
        assert all(np.isfinite([stats.stall_ms, stats.cpu_ms, stats.gpu_ms, stats.frame_ms]))
        if method in ("full", "vfc", "ideal"):
            assert stats.queries == 0 and stats.rarn == 0 and stats.d == 0
        if method == "sw":
            assert stats.d == stats.dn  # every SW node waits for its own query
        if method == "full":
            assert np.all(city_renderer.hlod.child_count[stats.drawn] == 0)


def test_drawn_nodes_form_a_cut_except_rarn_nodes(city_renderer):
    """No drawn node is an ancestor of another drawn node, except a node drawn on a STOP
    prediction whose query then said "refine" (RARN): so ancestors among the drawn <= rarn,
    and none at all for Bool and SW, which never draw before knowing."""
    parent = city_renderer.hlod.parent
    for method in ("bool", "sw", "coh", "simp"):
        for stats, _ in _frames(_Scripted(city_renderer), method, street_path(10)):
            drawn = set(stats.drawn)
            ancestors = set()
            for node in drawn:
                p = parent[node]
                while p >= 0:
                    if p in drawn:
                        ancestors.add(p)
                    p = parent[p]
            assert len(ancestors) <= stats.rarn, (method, sorted(ancestors), stats.rarn)
            if method in ("bool", "sw"):
                assert not ancestors


def test_static_camera_coh_draws_within_two_percent_of_sw(city_renderer):
    path = street_path(14, static=True)
    sw = [s.dn for s, _ in _frames(_Scripted(city_renderer), "sw", path)]
    coh = [s.dn for s, _ in _frames(_Scripted(city_renderer), "coh", path)]
    assert sw[4:] == [sw[4]] * len(sw[4:])  # a static camera: SW is stable
    assert all(c <= 1.02 * s for c, s in zip(coh[4:], sw[4:])), (coh, sw)


def test_ideal_draws_the_sw_set_without_queries(city_renderer):
    path = street_path(8)
    sw = [s.drawn for s, _ in _frames(city_renderer, "sw", path)]
    ideal = [s for s, _ in _frames(city_renderer, "ideal", path)]
    assert [sorted(s.drawn) for s in ideal] == [sorted(d) for d in sw]
    assert all(s.queries == 0 for s in ideal)


def test_modulated_methods_draw_fewer_nodes_than_bool_on_the_street(city_renderer):
    """(s, t) = (0.6, 0.2), a paper setting, every query asked (skip_queries off): SW's count, each
    node decided on its own fresh query, is the lower bound Coh's stays above. With the default
    `expected` skips Coh still draws fewer than Bool; it may draw fewer than SW, since a skipped
    node keeps its ratio for up to 5 frames (measured: Bool 1094, SW 925, Coh 935 with every query,
    908 with the skips under LLVMPIPE_COSTS). Results come back 3 commands late, one query at a
    time (ScriptedAvailability): with llvmpipe's own timing Coh's count depends on which results
    are back when it looks (1% above SW's here)."""
    path, settings = street_path(60), RuntimeSettings(s=0.6, t=0.2, skip_queries="off")
    late = ScriptedAvailability(city_renderer, LAG)
    late.cost_model = LLVMPIPE_COSTS
    dn = {m: sum(s.dn for s, _ in _frames(late, m, path, settings=settings)) for m in ("bool", "sw", "coh")}
    assert dn["sw"] <= dn["coh"] < dn["bool"], dn
    skipping = RuntimeSettings(s=0.6, t=0.2, skip_queries="expected")
    dn["coh skipping"] = sum(s.dn for s, _ in _frames(late, "coh", path, settings=skipping))
    assert dn["coh skipping"] < dn["bool"], dn


def test_alpha_estimators_against_the_query_on_boxes_fully_on_screen(city_renderer):
    """On boxes whose projection lies wholly inside the viewport, the `query` alpha is the exact
    rasterised count. Measured on the city's 121 boxes of at least 400 px from an overview:
    `projected` errs by 0.19% median, 2.2% at most (rasterisation samples pixel centres; asserted
    below 3%); `cube` (a cube of equal volume seen face-on) is off by a factor of 1.78 median, 2.9
    at most (asserted: median factor within 1..4), which is why `query` is the default."""
    hlod = city_renderer.hlod
    path = inspection_path(hlod, seed=5, frames=3)
    view = path.view(0, SIZE)
    pad = city_renderer.query_box_pad
    lo, hi = hlod.box_min - pad, hlod.box_max + pad
    clip = [(view.projection @ view.view @ np.c_[boxes.box_corners(lo[i], hi[i]), np.ones(8)].T).T
            for i in range(hlod.node_count)]
    on_screen = [i for i, c in enumerate(clip)
                 if np.all(c[:, 3] > 0) and np.all(np.abs(c[:, :2] / c[:, 3:4]) < 0.98)]
    assert len(on_screen) > 50
    city_renderer.begin_frame(view)
    exact = []
    for node in on_screen:
        q, alpha, _ = city_renderer.result(city_renderer.issue_query(node, with_alpha=True))
        assert q == alpha  # nothing drawn yet: every rasterised sample passes
        exact.append(alpha)
    city_renderer.end_frame()
    exact = np.array(exact, float)
    projected = alpha_estimators.alpha_projected(view, lo[on_screen], hi[on_screen])
    cube = alpha_estimators.alpha_cube(view, hlod.cube_side, box_min=hlod.box_min, box_max=hlod.box_max)[on_screen]
    big = exact >= 400  # boxes of at least 20 x 20 pixels
    projected_err = np.abs(projected[big] / exact[big] - 1)
    assert np.max(projected_err) < 0.03, np.max(projected_err)
    cube_factor = np.exp(np.abs(np.log(cube[big] / exact[big])))
    assert 1.0 < np.median(cube_factor) < 4.0, np.median(cube_factor)


class _RecordingResults:
    """Test double around a renderer: records each query result's q by node."""

    def __init__(self, renderer):
        self._renderer = renderer
        self.q = {}

    def __getattr__(self, name):
        return getattr(self._renderer, name)

    def result(self, query):
        out = self._renderer.result(query)
        self.q[query.node] = out[0]
        return out


def test_mu_stays_in_0_1_when_alpha_is_underestimated(city_renderer):
    """q > alpha happens with the cube estimate (it underestimates flat, wide boxes): mu clamps to 1,
    so the node's ratio is P(1) = 1 (each node is queried at most once a frame). Every query asked
    (skip_queries off: the nodes where it happens are visible and stopped, the ones skipping leaves
    unqueried)."""
    path = street_path(10)
    for alpha in ("cube", "projected"):
        recording = _RecordingResults(_Scripted(city_renderer))
        settings = RuntimeSettings(alpha=alpha, skip_queries="off")
        methods = make("coh", city_renderer.hlod, recording, settings=settings)
        seen_over = 0
        for i in range(len(path)):
            recording.q.clear()
            methods.frame(path.view(i, SIZE))
            ratio = methods.ratio
            assert np.all((ratio >= 0) & (ratio <= 1))
            for node, q in recording.q.items():
                if 0 < methods.alpha_estimate[node] < q:
                    seen_over += 1
                    assert ratio[node] == 1.0, (alpha, node, q, methods.alpha_estimate[node])
        if alpha == "cube":
            assert seen_over > 0, "the path never produced q > alpha; the clamp went untested"


@pytest.mark.slow
def test_extreme_viewports(gl_ctx, city_hlod):
    """1x1 and 8k viewports: every method's counters agree with what it drew, and the SSE follows
    the viewport height (docs/how-it-works.md#sse: SSE is proportional to H): at 1x1 only nodes whose sphere holds
    the eye (SSE = inf) refine, at 8k far more do, so every frame draws fewer nodes at 1x1."""
    hlod = city_hlod
    path = street_path(3)
    drawn = {}
    for size in ((1, 1), (7680, 4320)):
        renderer = Renderer(gl_ctx, hlod, size=size)
        try:
            for method in ("vfc", "bool", "coh", "sw"):
                for stats, _ in _frames(_Scripted(renderer), method, path, size=size):
                    assert len(stats.drawn) == len(set(stats.drawn)) == stats.dn >= 1, (size, method)
                    assert stats.tris == int(hlod.tri_count[stats.drawn].sum()) and np.isfinite(stats.frame_ms)
                    drawn.setdefault((size, method), []).append(sorted(stats.drawn))
        finally:
            renderer.release()
    for method in ("vfc", "bool", "coh", "sw"):
        for tiny, huge in zip(drawn[((1, 1), method)], drawn[((7680, 4320), method)]):
            assert 1 <= len(tiny) < len(huge), method


def test_eye_inside_boxes_and_on_a_box_face(city_renderer):
    hlod = city_renderer.hlod
    leaf = int(np.flatnonzero(hlod.child_count == 0)[0])
    centre = 0.5 * (hlod.box_min[leaf] + hlod.box_max[leaf])
    on_face = centre.copy()
    on_face[0] = hlod.box_max[leaf][0]
    path = CameraPath(frames=np.array([[centre, centre + [0, 10, 0], [0, 0, 1]],
                                       [on_face, on_face + [10, 0, 0], [0, 0, 1]]], float),
                      near=0.01, far=500.0)
    for method in ("bool", "coh", "simp", "sw"):
        for stats, _ in _frames(_Scripted(city_renderer), method, path):
            assert stats.dn > 0  # the eye inside the root box: queries skipped (mu = 1), geometry drawn


def test_frame_table_equals_the_public_box_and_sse_functions(city_hlod):
    """`prepare`'s per-frame table (one boxes.view_tests pass with the sphere centres in its rows)
    is what the separate public functions give, node for node: SSE bit for bit with metrics.sse
    (inf inside an inner node's sphere, 0 for every leaf), the key with boxes.box_distance, the
    frustum test, and unqueryable where the padded box holds the eye or crosses the near plane.
    Views from the city's inspection path, one with the eye inside a leaf's and its ancestors'
    spheres, and an orthographic one."""
    hlod = city_hlod
    pad = 0.05
    host = type("Host", (), {"query_box_pad": pad})()
    views = [inspection_path(hlod, seed=3, frames=6).view(i, SIZE) for i in range(6)]
    leaf = int(np.flatnonzero(hlod.child_count == 0)[0])
    centre = hlod.sphere_center[leaf]
    views.append(CameraPath(frames=np.array([[centre, centre + [0, 10, 0], [0, 0, 1]]]), near=0.01,
                            far=500.0).view(0, SIZE))
    views.append(CameraPath(frames=np.array([[[70.0, -120.0, 90.0], [70.0, 70.0, 0.0], [0, 0, 1]]]), near=1.0,
                            far=600.0, fovy_deg=None, ortho_height=160.0).view(0, SIZE))
    methods = make("coh", hlod, host)
    seen_inf = 0
    for view in views:
        methods.prepare(view)
        sse = np.asarray(methods.sse)
        expected = metrics.sse(view, hlod.error, center=hlod.sphere_center, radius=hlod.sphere_radius,
                               is_leaf=hlod.is_leaf)
        assert np.array_equal(sse, expected)
        assert np.all(sse[hlod.is_leaf] == 0.0)
        seen_inf += int(np.isinf(sse).sum())
        assert np.array_equal(np.asarray(methods.key), boxes.box_distance(view.eye, hlod.box_min, hlod.box_max))
        planes = boxes.frustum_planes(view)
        corners = boxes.box_corners(hlod.box_min[:, None, :], hlod.box_max[:, None, :])  # (n,8,3)
        outside_one_plane = np.any(np.all(corners @ planes[:, :3].T + planes[:, 3] < 0, axis=1), axis=1)
        assert np.array_equal(np.asarray(methods.in_frustum), ~outside_one_plane)
        lo, hi = hlod.box_min - pad, hlod.box_max + pad
        padded = boxes.box_corners(lo[:, None, :], hi[:, None, :])  # a corner of the query box behind the near plane
        behind_near = np.any(padded @ planes[4, :3] + planes[4, 3] < 0, axis=1)
        unqueryable = boxes.eye_in_boxes(view.eye, lo, hi) | behind_near
        assert np.array_equal(np.asarray(methods.unqueryable), unqueryable)
    assert seen_inf > 0  # the eye inside spheres was tested


def test_skip_candidates_are_the_nodes_visited_and_visible_last_frame(city_renderer):
    """The skip test's candidates are exactly the nodes visited in the last frame and visible at
    its end, in the frustum and queryable this frame (read from the walk's visited list, not the
    node table); a node visible from an earlier frame but not visited last frame is not one."""
    methods = make("coh", city_renderer.hlod, _Scripted(city_renderer), settings=RuntimeSettings(skip_queries="expected"))
    path = street_path(12)
    stale = 0
    for i in range(len(path)):
        view = path.view(i, SIZE)
        if i:
            methods.prepare(view)
            visible, last = methods.visible, methods.last_visited
            expected = np.flatnonzero(visible & (last == methods.frame_id) & np.asarray(methods.in_frustum)
                                      & ~np.asarray(methods.unqueryable))
            assert np.array_equal(np.sort(methods.skip_candidates()), expected)
            stale += int(np.count_nonzero(visible & (last < methods.frame_id)))
        methods.frame(view)
    assert stale > 0  # visible nodes not visited last frame occurred, and were left out


def test_dn_excess_classifies_each_extra_node_once():
    """benchmarks.dn_excess puts each node Coh draws and SW does not in one class: finer (SW drew an
    ancestor), hidden (SW found it hidden), under hidden (SW found an ancestor hidden), coarser
    (SW refined it), other; and counts what SW drew that Coh did not."""
    from benchmarks import dn_excess

    #        0
    #   1         2        8
    # 3   4     5   6
    #                 7
    parent = np.array([-1, 0, 0, 1, 1, 2, 2, 6, 0])
    visited = np.zeros(9, bool)
    visited[[0, 1, 2, 5, 6]] = True
    visible = visited.copy()
    visible[6] = False
    got = dn_excess.classify(parent, coh_drawn=[3, 6, 2, 7, 8], sw_drawn=[1, 5], sw_visited=visited, sw_visible=visible)
    assert got == {"finer": 1, "hidden": 1, "coarser": 1, "under hidden": 1, "other": 1, "missing": 2}


def test_orthographic_path(city_renderer):
    eye = np.array([70.0, -120.0, 90.0])
    path = CameraPath(frames=np.array([[eye, [70.0, 70.0, 0.0], [0, 0, 1]]] * 4), near=1.0, far=600.0,
                      fovy_deg=None, ortho_height=160.0)
    vfc = _frames(city_renderer, "vfc", path, images=True)
    boolean = _frames(_Scripted(city_renderer), "bool", path, images=True)
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(vfc, boolean))
    coh = _frames(_Scripted(city_renderer), "coh", path)
    assert all(s.dn > 0 for s, _ in coh)


def test_scene_far_from_origin(gl_ctx):
    mesh = load_model("cow")
    m = np.eye(4)
    m[:3, :3] *= 10.0
    m[:3, 3] = 1e6
    hlod = bake(meshes.transform_mesh(mesh, m, name="cow+1e6"), BakeSettings(target_tris=500))
    renderer = Renderer(gl_ctx, hlod, size=SIZE)
    try:
        centre = 0.5 * (hlod.box_min[0] + hlod.box_max[0])
        path = CameraPath(frames=np.array([[centre + [0, -12, 3], centre, [0, 0, 1]]] * 3), near=1e-4, far=1e5)
        vfc = _frames(renderer, "vfc", path, images=True)
        boolean = _frames(_Scripted(renderer), "bool", path, images=True)
        assert (vfc[0][1] != 255).any(axis=2).sum() > 1000  # the cow is on screen
        assert all(np.array_equal(a[1], b[1]) for a, b in zip(vfc, boolean))
    finally:
        renderer.release()


def test_release_frees_everything_and_is_idempotent(gl_ctx, city_hlod):
    """Frames on the real renderer (its own cost calibration included), then release, twice."""
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    _frames(renderer, "coh", street_path(3))
    ids = renderer.queries.ids
    resources = list(renderer.gl_objects)
    assert ids and resources
    renderer.release()
    renderer.release()
    gl = GLFunctions(gl_ctx)
    assert all(isinstance(r.mglo, moderngl.mgl.InvalidObject) for r in resources)
    assert not any(gl.is_query(q) for q in ids)
    assert renderer.queries.allocated == 0


@pytest.mark.parametrize("skip_queries", ["off", "expected"])
def test_draws_into_the_callers_framebuffer_and_leaves_it_bound(gl_ctx, city_hlod, skip_queries):
    """A context handed in by the caller (Blender's, later): no own framebuffer, nothing cleared,
    the caller's framebuffer still bound afterwards. With skip_queries `expected` the renderer
    calibrates its costs inside the first frame, in a framebuffer of its own, and must give back
    the framebuffer bound then, not the one bound when it was made."""
    hlod = city_hlod
    previous = gl_ctx.detect_framebuffer()
    colour = gl_ctx.renderbuffer(SIZE, components=4)
    depth = gl_ctx.depth_renderbuffer(SIZE)
    host = gl_ctx.framebuffer(color_attachments=[colour], depth_attachment=depth)
    renderer = Renderer(gl_ctx, hlod)
    try:
        host.use()
        host.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
        traversal = make("coh", hlod, renderer, settings=RuntimeSettings(skip_queries=skip_queries))
        stats = traversal.frame(street_path(2).view(0, SIZE))
        assert stats.dn > 0 and renderer.calibrated == (skip_queries == "expected")
        pixels = np.frombuffer(host.read(components=3), np.uint8).reshape(SIZE[1], SIZE[0], 3)
        assert (pixels != 0).any(axis=2).sum() > 1000
        assert np.array_equal(renderer.read_pixels(), pixels[::-1])  # reads the caller's framebuffer
        binding = ctypes.c_int32(0)
        ctypes.CFUNCTYPE(None, ctypes.c_uint32, ctypes.POINTER(ctypes.c_int32))(
            gl_ctx.mglo._context.load("glGetIntegerv"))(GL.DRAW_FRAMEBUFFER_BINDING, ctypes.byref(binding))
        assert binding.value == host.glo
    finally:
        renderer.release()
        previous.use()  # never release a bound framebuffer: moderngl would rebind it later
        for resource in (host, depth, colour):
            resource.release()


class _ScriptedLatency:
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


def test_scripted_query_latency_keeps_culling_conservative(city_renderer):
    slow = _ScriptedLatency(city_renderer)
    path = street_path(12)
    vfc = _frames(city_renderer, "vfc", path, images=True)
    for method in ("bool", "coh"):
        methods = make(method, city_renderer.hlod, slow)
        for i in range(len(path)):
            stats = methods.frame(path.view(i, SIZE))
            assert len(stats.drawn) == len(set(stats.drawn))
            if method == "bool":
                assert np.array_equal(city_renderer.read_pixels(), vfc[i][1]), f"frame {i}"


@pytest.mark.parametrize("method", ["full", "vfc", "bool"])
def test_overlay_of_methods_without_vmsse_is_all_blue(city_renderer, method):
    """Only VMSSE lowers a node's LOD; Full, VFC and Bool show no modulation (blue), even for a
    node Bool drew from last frame's visibility and then found hidden."""
    path = street_path(12)
    methods = make(method, city_renderer.hlod, _Scripted(city_renderer))
    city_renderer.overlay = True  # the drawing side's setting
    for i in range(len(path)):
        methods.frame(path.view(i, SIZE))
        image = city_renderer.read_pixels()
        drawn = image[np.any(image != 255, axis=2)].astype(np.int64)
        assert drawn.shape[0] > 1000
        assert np.all(drawn[:, 0] <= 0.11 * drawn[:, 2] + 2)


@pytest.fixture(scope="module")
def sphere_row():
    """Five tessellated spheres in a row (15k triangles, about 400 per node): looking down the row,
    each sphere hides most of the next, whose nodes show as thin crescents."""
    spheres = [meshes.TriangleMesh(*procedural.uv_sphere([12.0 * i, 0.0, 0.0], 5.0, segments=48, rings=32), name=f"sphere {i}")
               for i in range(5)]
    return bake(meshes.merge(spheres, name="sphere row"), BakeSettings(target_tris=400))


def test_measured_shift_up_reaches_the_sw_front_where_algorithm_4_stays_deep(gl_ctx, sphere_row):
    """Seen from the side the whole row refines; then the camera looks down the row and holds still.
    A hidden sphere's node is a few percent visible (P ~ 0, SW stops there) while the child holding
    the visible crescent is well over t visible, so Algorithm 4's shift-up (children's average
    ratio) keeps refining, or comes back up only to go down again. The measured shift-up queries
    the refined node itself and draws exactly SW's set.
    How deep Algorithm 4 stays depends on which query results are back in time: with results that
    come back at once (llvmpipe with LP_NUM_THREADS=0) it reaches SW's set too, with llvmpipe's
    threads it varies with the machine's load. So the results come late here, scripted
    (_ScriptedLatency, the latency of a busy GPU): measured, 88 nodes over the last 4 frames of the
    two paths where SW draws 56, every run."""
    renderer = _ScriptedLatency(Renderer(gl_ctx, sphere_row, size=SIZE))
    try:
        side = ([24.0, -30.0, 3.0], [24.0, 0.0, 0.0], [0.0, 0.0, 1.0])
        tails = {"sw": [], "alg4": [], "measured": []}
        for dy in (0.0, 1.0):
            down_the_row = ([-12.0, dy, 0.0], [48.0, 0.5 * dy, 0.0], [0.0, 0.0, 1.0])
            path = CameraPath(frames=np.array([side] * 3 + [down_the_row] * 16, float), near=0.05, far=400.0)
            for name, method, settings in (("sw", "sw", RuntimeSettings()),
                                           ("alg4", "coh", RuntimeSettings(shift_up="children")),
                                           ("measured", "coh", RuntimeSettings(shift_up="measured"))):
                tails[name] += [sorted(s.drawn) for s, _ in _frames(renderer, method, path, settings=settings)[-4:]]
        assert tails["measured"] == tails["sw"]
        assert sum(map(len, tails["alg4"])) > sum(map(len, tails["sw"])), tails
    finally:
        renderer.release()


def test_measure_every_queries_each_refined_node_that_often(gl_ctx, sphere_row):
    """RuntimeSettings.measure_every: with 1 every refined node in the frustum that can be queried
    (and whose SSE is finite: one the eye is inside refines whatever its ratio) is queried every
    frame (its ratio measured that frame); with 4, on one frame in four, staggered by node index,
    so about a quarter of them a frame."""
    renderer = Renderer(gl_ctx, sphere_row, size=SIZE)
    try:
        side = ([24.0, -30.0, 3.0], [24.0, 0.0, 0.0], [0.0, 0.0, 1.0])
        path = CameraPath(frames=np.array([side] * 8, float), near=0.05, far=400.0)
        for every in (1, 4):
            settings = RuntimeSettings(measure_every=every, skip_queries="off")
            coh = make("coh", sphere_row, _Scripted(renderer), settings=settings)
            measured_share = []
            for i in range(len(path)):
                coh.frame(path.view(i, SIZE))
                visited = np.flatnonzero(coh.last_visited == coh.frame_id)
                stop_refinement, measured = coh.stop_refinement, coh.measured
                refined = [n for n in visited if not stop_refinement[n] and coh.in_frustum[n]
                           and not coh.unqueryable[n] and np.isfinite(coh.sse[n])]  # inf: refines whatever
                assert refined, "the side view refines the row"
                measured_share.append(np.mean([measured[n] == coh.frame_id for n in refined]))
            if every == 1:
                assert all(share == 1.0 for share in measured_share[1:]), measured_share
            else:
                assert 0.1 < np.mean(measured_share[1:]) < 0.45, measured_share
    finally:
        renderer.release()


@pytest.mark.parametrize("field, value, message", [
    ("shift_up", "parents", "shift_up must be one of"), ("tau", 0.0, "tau must be > 0 pixels"),
    ("bias", "Q", "bias must be 'P' or 'mu'"), ("alpha", "exact", "alpha must be one of"),
    ("s", 1.5, "s and t must lie in"), ("t", -0.1, "s and t must lie in"), ("k", 0.0, "steepness k must be > 0"),
    ("multiquery", "yes", "multiquery must be one of"), ("batch_queries", "True", "batch_queries must be one of"),
    ("predict_new", "auto", "predict_new must be one of"), ("measure_every", 0, "measure_every must be a whole"),
    ("measure_every", 2.0, "measure_every must be a whole"), ("measure_every", True, "measure_every must be a whole")])
def test_bad_runtime_settings_raise_input_error(field, value, message):
    """The core's typed error, as BakeSettings raises (the CLI and the add-on turn it into one line)."""
    with pytest.raises(InputError, match=message):
        RuntimeSettings(**{field: value})


def test_unknown_method_and_an_error_inside_a_constructor_are_told_apart(city_renderer, monkeypatch):
    with pytest.raises(InputError, match="unknown method 'nope'; expected one of full, vfc"):
        make("nope", city_renderer.hlod, city_renderer)

    class Broken(METHODS["vfc"]):
        def __init__(self, hlod, renderer, settings=RuntimeSettings()):
            raise KeyError("a bug inside the constructor")

    monkeypatch.setitem(METHODS, "broken", Broken)
    with pytest.raises(KeyError, match="a bug inside the constructor"):
        make("broken", city_renderer.hlod, city_renderer)


def test_counters_are_the_numeric_fields_of_frame_stats_in_order():
    numeric = [f.name for f in dataclasses.fields(FrameStats) if f.type in ("int", "float")]
    assert list(COUNTERS + QUERY_COUNTERS + STREAM_COUNTERS) == numeric
    assert not hasattr(FrameStats, "counters")


def test_the_traversal_does_not_import_the_gl_renderer():
    """The traversal is typed against the NodeRenderer protocol: importing it loads nothing of
    hlod_core.render, nor moderngl."""
    code = ("import sys, hlod_core.traversal.methods\n"
            "print(sorted(m for m in sys.modules if m.startswith('hlod_core.render') or m == 'moderngl'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


class _Recording:
    """Test double around a renderer: records what the traversal asks it to draw."""

    def __init__(self, renderer):
        self._renderer = renderer
        self.draws = []

    def __getattr__(self, name):
        return getattr(self._renderer, name)

    def draw_node(self, node, ratio_p):
        self.draws.append((node, float(ratio_p)))
        self._renderer.draw_node(node, ratio_p)


@pytest.mark.parametrize("method", ["bool", "sw", "coh"])
def test_the_traversal_passes_each_drawn_node_and_its_ratio(city_renderer, method):
    """The traversal says which node it draws and with which P (1 where VMSSE does not steer the
    LOD); it picks no colour."""
    recording = _Recording(_Scripted(city_renderer))
    methods = make(method, city_renderer.hlod, recording)
    path = street_path(6)
    for i in range(len(path)):
        recording.draws.clear()
        stats = methods.frame(path.view(i, SIZE))
        assert [node for node, _ in recording.draws] == stats.drawn
        ratios = np.array([p for _, p in recording.draws])
        if method == "bool":
            assert np.all(ratios == 1.0)
        elif method == "sw":  # SW draws after its query: the ratio it drew with is the final one
            assert np.array_equal(ratios, methods.ratio[stats.drawn])
        assert np.all((ratios >= 0) & (ratios <= 1))
    assert method == "bool" or np.any(ratios < 1.0), "no modulated node drawn: the check saw nothing"


def test_overlay_ramp_table_matches_the_metrics_ramp():
    """The renderer's colour table is overlay.modulation_colour sampled at P = i / steps; between
    samples, P rounds to the nearest: within 1.7 (the ramp's steepest slope, blue of magenta ->
    red) / (2 steps), plus float32 rounding."""
    ramp = np.array(overlay_ramp())
    p = np.linspace(0.0, 1.0, OVERLAY_RAMP_STEPS + 1)
    assert np.array_equal(ramp, overlay.modulation_colour(metrics.modulation(p)).astype(np.float64))
    fine = np.random.default_rng(0).random(10_000)
    looked_up = ramp[np.round(fine * OVERLAY_RAMP_STEPS).astype(int)]
    exact = overlay.modulation_colour(metrics.modulation(fine))
    assert np.max(np.abs(looked_up - exact)) <= 1.7 / (2 * OVERLAY_RAMP_STEPS) + 1e-7


def test_overlay_draws_the_modulation_colour_of_each_node(city_renderer):
    """With the overlay on, Coh's frame equals the same nodes drawn in the exact ramp colour of
    the ratio each was drawn with (within one 8-bit level: the table rounds P); with it off, in the
    default colour."""
    path = street_path(8)
    recording = _Recording(_Scripted(city_renderer))
    methods = make("coh", city_renderer.hlod, recording, settings=RuntimeSettings(s=0.6, t=0.2))
    city_renderer.overlay = True
    modulated = 0
    for i in range(len(path)):
        view = path.view(i, SIZE)
        recording.draws.clear()
        methods.frame(view)
        overlaid = city_renderer.read_pixels().astype(np.int64)
        modulation = metrics.modulation([p for _, p in recording.draws])
        modulated += int(np.sum(modulation > 0))
        city_renderer.begin_frame(view)
        for (node, _), colour in zip(recording.draws, overlay.modulation_colour(modulation)):
            city_renderer.draw_node_coloured(node, colour)
        city_renderer.end_frame()
        assert np.max(np.abs(overlaid - city_renderer.read_pixels())) <= 1, f"frame {i}"
    assert modulated > 0, "no node was modulated: the colours went untested"
    city_renderer.overlay = False
    stats = methods.frame(path.view(0, SIZE))
    plain = city_renderer.read_pixels()
    city_renderer.begin_frame(path.view(0, SIZE))
    for node in stats.drawn:
        city_renderer.draw_node_coloured(node, DEFAULT_COLOUR)
    city_renderer.end_frame()
    assert np.array_equal(plain, city_renderer.read_pixels())


def test_gl_state_is_restored_after_a_frame(gl_ctx, city_hlod):
    """A host's state (here: blend and scissor on, a scissor box, depth writes off, another
    viewport) survives a renderer frame between GLState.save() and restore()."""
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    gl = GLFunctions(gl_ctx)
    try:
        # a host state made of live objects (0 = none): restoring a deleted name is a GL error
        gl.use_program(0)
        gl.bind_vertex_array(0)
        gl.bind_buffer(GL.ARRAY_BUFFER, 0)
        gl.enable(GL.BLEND)
        gl.enable(GL.SCISSOR_TEST)
        gl.scissor(3, 4, 50, 60)
        gl.viewport(1, 2, 70, 80)
        gl.depth_mask(0)
        before = GLState(gl).save().values
        saved = GLState(gl).save()
        make("coh", renderer.hlod, renderer).frame(street_path(2).view(0, SIZE))
        assert GLState(gl).save().values != before  # the frame did change it
        saved.restore()
        assert GLState(gl).save().values == before
    finally:
        gl.disable(GL.BLEND)
        gl.disable(GL.SCISSOR_TEST)
        gl.depth_mask(1)
        renderer.release()


def test_traversal_cpu_benchmark_leaves_the_renderer_out(city_renderer):
    """benchmarks/traversal_cpu: the traversal's Python time per visited node excludes the time inside
    the renderer. Its clock here is this thread's CPU time plus a scripted offset: every draw of a
    slow renderer (real GL, then SCRIPTED_DRAW_S on that clock, no sleep) moves it on, so the
    renderer's share grows by exactly that per draw, and the Python time per node stays far below
    what one draw adds per node, whatever the machine's load. Results are fetched only when the
    traversal runs out of other work (_ScriptedLatency), so both runs visit the same nodes."""
    from benchmarks import traversal_cpu

    scripted_draw_s = 10.0
    scripted_s = [0.0]

    def clock() -> float:
        return time.thread_time() + scripted_s[0]

    class SlowDraws:
        def __init__(self, renderer):
            self._renderer = renderer
            self.draws = 0

        def draw_node(self, node, ratio_p=1.0):
            self._renderer.draw_node(node, ratio_p)
            self.draws += 1
            scripted_s[0] += scripted_draw_s

        def __getattr__(self, name):
            return getattr(self._renderer, name)

    path = street_path(6)
    late = _ScriptedLatency(city_renderer)
    plain = traversal_cpu.measure(city_renderer.hlod, "coh", path, settings=RuntimeSettings(), size=SIZE,
                                  renderer=late, call_overhead_s=traversal_cpu.proxy_overhead_s(clock=clock),
                                  clock=clock)
    slow_renderer = SlowDraws(late)
    slow = traversal_cpu.measure(city_renderer.hlod, "coh", path, settings=RuntimeSettings(), size=SIZE,
                                 renderer=slow_renderer, call_overhead_s=0.0, clock=clock)
    assert plain["visited"] > 10 and slow["visited"] == plain["visited"]
    scripted_ms = 1e3 * scripted_draw_s * slow_renderer.draws / slow["frames"]  # a frame's scripted draws
    assert slow_renderer.draws > 5 * slow["frames"]  # several draws a frame
    # the rest of the renderer's share is real GL work, milliseconds against the scripted seconds
    assert slow["renderer_ms"] - plain["renderer_ms"] == pytest.approx(scripted_ms, rel=0.05), (slow, plain)
    one_draw_us_per_node = 1e6 * scripted_draw_s / slow["visited"]  # what a single draw would add if counted
    assert 0 < slow["python_us_per_node"] < 0.01 * one_draw_us_per_node, (slow, one_draw_us_per_node)


def test_traversal_cpu_null_renderer_leaves_the_python_alone(city_hlod):
    """benchmarks/traversal_cpu --renderer null: the traversals run without GL (every query back at
    once, a seeded visibility per node), so two runs visit the same nodes; and the time inside the
    renderer is a small part of the traversal's (measured: about a sixth, asserted: below all of
    it). Timing is the subject of the second part: it is measured on this thread's CPU clock, which
    leaves out the time other processes hold the core, as the median of five repeats that
    alternate the methods, so one pause (a garbage collection) inside a renderer call cannot decide."""
    from benchmarks import traversal_cpu

    timed = traversal_cpu.run(city_hlod, street_path(8), SIZE, methods=["coh", "bool"], repeat=5,
                              settings=RuntimeSettings(), clock="thread", null_renderer=True)
    again = traversal_cpu.run(city_hlod, street_path(8), SIZE, methods=["coh", "bool"], repeat=1,
                              settings=RuntimeSettings(), null_renderer=True)
    for method in ("coh", "bool"):
        first, second = timed[method], again[method]
        assert first["visited"] == second["visited"] > 10
        frame_python_ms = first["python_us_per_node"] * first["visited"] / 1e3
        assert 0 < first["renderer_ms"] < frame_python_ms, first


def test_traversal_cpu_baseline_runs_another_version_side_by_side(city_hlod):
    """benchmarks/traversal_cpu --baseline DIR imports DIR's hlod_core as a package of its own and
    runs its traversal next to this one's on the same renderer: with this checkout as the
    baseline, both rows visit the same nodes (null renderer: no timing in what is visited)."""
    from pathlib import Path

    from benchmarks import traversal_cpu
    from hlod_core.traversal import methods
    baseline = traversal_cpu.baseline_traversal(str(Path(__file__).resolve().parents[1]))
    assert baseline.methods.__name__ == "hlod_core_baseline.traversal.methods" and baseline.methods is not methods
    assert baseline.settings_type.__module__ == "hlod_core_baseline.traversal.settings"
    table = traversal_cpu.run(city_hlod, street_path(6), SIZE, methods=["coh"], repeat=2, settings=RuntimeSettings(),
                              null_renderer=True, baseline=baseline)
    assert set(table) == {"coh", "coh (baseline)"}
    assert table["coh"]["visited"] == table["coh (baseline)"]["visited"] > 10


class _ReferenceTraversal:
    """The traversals of docs/how-it-works.md#the-traversal-methods written plainly, without the library's speed-ups: per-node
    state in numpy arrays read one scalar at a time, the frame's box tests and SSE by the textbook
    (n,3) formulas, one helper call per step, every child pushed and the ones outside the frustum
    dropped when popped. Methods vfc, sw, bool, simp, coh (both shift-ups, predict_new on and off);
    skip_queries off, alpha "query". The library must do exactly what this does."""

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
    plain = RuntimeSettings(skip_queries="off")  # the reference asks every query
    variants = [(m, plain) for m in ("vfc", "sw", "bool", "simp", "coh")] + [
        ("coh", dataclasses.replace(plain, shift_up="children")), ("coh", dataclasses.replace(plain, bias="mu")),
        ("simp", dataclasses.replace(plain, bias="mu")), ("sw", dataclasses.replace(plain, s=0.6, t=0.2, k=30.0)),
        ("coh", dataclasses.replace(plain, s=0.6, t=0.2, k=30.0)), ("coh", dataclasses.replace(plain, predict_new="off"))]
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
    assert all(compared[c] for c in ("rarn", "d", "queries", "predicted")) and (compared["not_yet"] > 0) == (lag > 0), compared


# --- CHC++'s query stream: multiqueries and query batching -----------------------------------------

def test_multiquery_groups_follow_chcpp_value_rule():
    """CHC++ §4: p_keep(i) = 0.99 - 0.7 e^-i; nodes hidden longer first; a group grows while
    V = |M| / (1 + (1 - prod p_keep) |M|) rises, and must beat a node's own query (V = 1).
    Four nodes hidden one frame (p = 0.7325): V(2) = 1.038, V(3) = 1.064, V(4) = 1.039, so three
    and one. Hidden 5, 2 and 1 frames: V(2) = 2 / (1 + 2 (1 - 0.9853 * 0.8953)) = 1.618, V(3) =
    1.455: the two longest together. Thirty hidden ten frames (p = 0.98997): V peaks at 11 (5.108
    against 5.107 at 10 and 5.072 at 12), and the last eight still beat one each."""
    assert keep_hidden(1) == pytest.approx(0.99 - 0.7 / math.e)
    assert multiquery_groups([0, 1, 2, 3], [1] * 4) == [[0, 1, 2], [3]]
    hidden = [0] * 13
    hidden[10], hidden[11], hidden[12] = 1, 5, 2
    assert multiquery_groups([10, 11, 12], hidden) == [[11, 12], [10]]
    assert [len(g) for g in multiquery_groups(list(range(30)), [10] * 30)] == [11, 11, 8]
    assert multiquery_groups([7], [3] * 8) == [[7]] and multiquery_groups([], []) == []


def _street_depth(renderer, frame=10):
    """A street frame with everything VFC draws in the depth buffer; (view, nodes in the frustum
    that can be queried, VFC's drawn nodes). The frame is left open (end it with end_frame)."""
    path = street_path(30)
    view = path.view(frame, SIZE)
    vfc = make("vfc", renderer.hlod, renderer)
    drawn = vfc.frame(view).drawn  # its frame's table: in the frustum, queryable
    candidates = np.flatnonzero(np.asarray(vfc.in_frustum) & ~np.asarray(vfc.unqueryable)).tolist()
    renderer.begin_frame(view)
    for node in drawn:
        renderer.draw_node(node)
    return view, candidates, drawn


def test_batched_queries_count_what_single_queries_count_with_fewer_state_changes(city_renderer):
    """issue_queries gives each node the q and alpha its own issue_query gives (queries write no
    depth: the buffer is the same for both), with two state changes for the batch where the single
    queries make two a node (query, alpha, query, alpha, ...)."""
    r = city_renderer
    _, candidates, _ = _street_depth(r)
    nodes = candidates[::max(1, len(candidates) // 40)]
    before = r.state_changes
    singles = [r.result(r.issue_query(node, with_alpha=True))[:2] for node in nodes]
    single_changes = r.state_changes - before
    before = r.state_changes
    batch = [r.result(query)[:2] for query in r.issue_queries(nodes, with_alpha=True)]
    batch_changes = r.state_changes - before
    samples_only = [r.result(query)[:2] for query in r.issue_queries(nodes, with_alpha=False)]
    r.end_frame()
    assert batch == singles and samples_only == [(q, None) for q, _ in singles]
    assert any(q > 0 for q, _ in singles) and any(q == 0 for q, _ in singles)  # both kinds seen
    assert (single_changes, batch_changes) == (2 * len(nodes), 2)


def test_a_multiquery_counts_the_sum_of_its_members_queries(city_renderer):
    """One q query around several boxes counts the samples each box's own query counts, summed:
    0 exactly when each member is hidden."""
    r = city_renderer
    _, candidates, _ = _street_depth(r)
    own = {node: r.result(r.issue_query(node, with_alpha=False))[0] for node in candidates}
    hidden = [node for node in candidates if own[node] == 0]
    shown = [node for node in candidates if own[node] > 0]
    assert len(hidden) >= 10 and len(shown) >= 3, (len(hidden), len(shown))
    group = r.issue_multiquery(hidden[:10])
    assert group.members == tuple(hidden[:10]) and group.alpha_query_id is None
    assert r.result(group)[0] == 0
    mixed = hidden[:5] + shown[:3]
    assert r.result(r.issue_multiquery(mixed))[0] == sum(own[node] for node in mixed) > 0
    r.end_frame()


def _scripted_run(renderer, method, *, settings, paths, lag):
    """(calls, per-frame FrameStats) of a new traversal over `paths` behind _Scripted."""
    scripted = _Scripted(renderer, lag)
    methods = make(method, renderer.hlod, scripted, settings=settings)
    scripted.traversal = methods
    stats = [methods.frame(path.view(i, SIZE)) for path in paths for i in range(len(path))]
    return scripted, stats


def _covers(hlod, drawn, shown) -> bool:
    """Is `drawn` (a node) on the root path of a node in `shown`, or below one (the screen area
    a drawn node shows, something in `shown` shows too, at some LOD)?"""
    parent = hlod.parent
    up = drawn
    while up >= 0:
        if up in shown:
            return True
        up = int(parent[up])
    return any(_is_below(hlod, node, drawn) for node in shown)


def _is_below(hlod, node, ancestor) -> bool:
    while node >= 0:
        if node == ancestor:
            return True
        node = int(hlod.parent[node])
    return False


@pytest.mark.parametrize("method", ["bool", "simp", "coh"])
def test_multiqueries_change_nothing_where_results_come_back_at_once(city_renderer, method):
    """Results back at once (lag 0): whenever a node hidden last frame is popped nothing is in
    flight, so it is queried alone, at once: the same renderer calls in the same order, the same
    counters, as without the option (no multiquery is ever issued)."""
    hlod = city_renderer.hlod
    paths = (street_path(20), inspection_path(hlod, seed=11, frames=28))
    runs = [_scripted_run(city_renderer, method, settings=RuntimeSettings(multiquery=m, batch_queries="off"), paths=paths, lag=0)
            for m in ("off", "on")]
    (off, off_stats), (on, on_stats) = runs
    assert on.calls == off.calls
    assert [(s.dn, s.queries, s.drawn) for s in on_stats] == [(s.dn, s.queries, s.drawn) for s in off_stats]
    assert sum(s.multiqueries for s in on_stats) == 0 and sum(s.queries for s in on_stats) > 0


@pytest.mark.parametrize("method", ["bool", "coh"])
def test_multiqueries_query_less_where_nodes_stay_hidden_and_show_what_appears(city_renderer, method):
    """Down the street most of the city stays hidden behind the first buildings. With results
    three commands late, nodes hidden last frame wait and go out grouped: fewer queries; the
    traversal never waits for a result while a query of its own waits to be issued; and whatever
    the traversal without multiqueries draws in a frame, the one with them shows in that frame or
    the next (a node, an ancestor or descendants of it)."""
    hlod = city_renderer.hlod
    paths = (street_path(30),)
    (off, off_stats), (on, on_stats) = (
        _scripted_run(city_renderer, method, settings=RuntimeSettings(multiquery=m, batch_queries="off"), paths=paths, lag=LAG)
        for m in ("off", "on"))
    q_off, q_on = (sum(s.queries for s in stats) for stats in (off_stats, on_stats))
    assert sum(s.multiqueries for s in on_stats) > 0
    assert q_on < 0.9 * q_off, (q_on, q_off)
    assert on.waits_with_queries_waiting == 0 and off.waits_with_queries_waiting == 0
    for i, stats in enumerate(off_stats):
        shown = set(on_stats[i].drawn) | (set(on_stats[i + 1].drawn) if i + 1 < len(on_stats) else set())
        missing = [node for node in stats.drawn if not _covers(hlod, node, shown)]
        assert not missing, (i, missing)
    dn_off, dn_on = (np.mean([s.dn for s in stats]) for stats in (off_stats, on_stats))
    assert dn_on == pytest.approx(dn_off, rel=0.02)


@pytest.mark.parametrize("lag", [0, 3])
def test_batched_queries_change_state_less_and_query_the_same_nodes(city_renderer, lag):
    """Coh with the queries of drawn nodes batched: the same nodes queried each frame (a batched
    query comes after later draws, so its q may be lower; measured: identical sets here), fewer
    state changes, the same nodes drawn within a frame (as multiqueries)."""
    hlod = city_renderer.hlod
    paths = (street_path(20), inspection_path(hlod, seed=11, frames=28))
    (off, off_stats), (on, on_stats) = (
        _scripted_run(city_renderer, "coh", settings=RuntimeSettings(batch_queries=m, multiquery="off", skip_queries="off"),
                      paths=paths, lag=lag)
        for m in ("off", "on"))
    changes_off, changes_on = (sum(s.state_changes for s in stats) for stats in (off_stats, on_stats))
    assert changes_on < 0.5 * changes_off, (changes_on, changes_off)
    assert on.waits_with_queries_waiting == 0
    same = [sorted(a) == sorted(b) for a, b in zip(off.queried(), on.queried())]
    assert sum(same) >= 0.9 * len(same), same
    q_off, q_on = (sum(s.queries for s in stats) for stats in (off_stats, on_stats))
    assert q_on == pytest.approx(q_off, rel=0.02)
    dn_off, dn_on = (np.mean([s.dn for s in stats]) for stats in (off_stats, on_stats))
    assert dn_on == pytest.approx(dn_off, rel=0.02)


def test_coh_batches_and_groups_its_queries_by_default(city_renderer):
    """The defaults (multiquery and batch_queries on, measured faster on every scene tried) reach
    the real renderer's batched calls: fewer state changes than queries down the street (one query
    alone switches to the query state and back; every query asked, skip_queries off)."""
    hlod = city_renderer.hlod
    assert (RuntimeSettings().multiquery, RuntimeSettings().batch_queries) == ("on", "on")
    path = street_path(30)
    stats = {}
    for m in ("off", "on"):
        settings = RuntimeSettings(multiquery=m, batch_queries=m, skip_queries="off")
        methods = make("coh", hlod, _Scripted(city_renderer), settings=settings)
        stats[m] = [methods.frame(path.view(i, SIZE)) for i in range(len(path))]
    changes, queries = ({m: sum(getattr(s, c) for s in stats[m]) for m in stats} for c in ("state_changes", "queries"))
    assert changes["on"] < queries["on"] and changes["off"] >= 2 * queries["off"] > 0, (changes, queries)
    assert sum(s.multiqueries for s in stats["off"]) == 0


# --- newly visited nodes predicted visible (predict_new) ------------------------------------------

def _predicted_run(renderer, settings, *, paths, lag, scripted_cls=None, share=None, images=None):
    """(scripted renderer, per-frame stats, per-frame (predicted nodes, sse, candidates, unqueryable)) of a new Coh over
    `paths`. A frame's predicted nodes, found from outside: drawn, not visited the frame before and
    not drawn after waiting for their query (a node drawn at once otherwise was visited last frame:
    a STOP prediction). `share`: the traversal's predict_new_share instead of the class's; `images`:
    a list the frames' pixels are appended to."""
    scripted = (scripted_cls or _Scripted)(renderer, lag)
    methods = make("coh", renderer.hlod, scripted, settings=settings)
    if share is not None:
        methods.predict_new_share = share
    scripted.traversal = methods
    stats, frames = [], []
    for path in paths:
        for i in range(len(path)):
            before = methods.last_visited
            s = methods.frame(path.view(i, SIZE))
            if images is not None:
                images.append(renderer.read_pixels())
            delayed = set(s.delayed)
            predicted = [n for n in s.drawn if before[n] != methods.frame_id - 1 and n not in delayed]
            stats.append(s)
            frames.append((predicted, np.asarray(methods.sse).copy(),
                           int(np.sum(methods.candidate_in == methods.frame_id)),
                           np.asarray(methods.unqueryable).copy()))
    return scripted, stats, frames


@pytest.mark.parametrize("batch", ["on", "off"])
def test_predicted_new_nodes_would_stop_fully_visible_and_each_gets_its_own_query(city_renderer, batch):
    """predict_new on, every candidate predicted (the share's gate open: about a quarter of the
    city's candidates are hidden, which shuts it at 0.9; the next tests cover the gate), results
    three commands late: the nodes Coh draws at once without having
    visited them last frame are as many as it counts, each one's SSE is within tau (it stops at any
    ratio), and each is queried on its own in that frame (its result sets the next frame's state)
    unless its box cannot be queried (it counts as visible, as it would after waiting)."""
    hlod = city_renderer.hlod
    paths = (street_path(20), inspection_path(hlod, seed=11, frames=28))
    scripted, stats, frames = _predicted_run(city_renderer, RuntimeSettings(predict_new="on", batch_queries=batch),
                                             paths=paths, lag=LAG, share=0.0)
    assert sum(s.predicted for s in stats) > 20
    for f, (s, (predicted, sse, _, unqueryable), queried) in enumerate(zip(stats, frames, scripted.queried())):
        assert len(predicted) == s.predicted, f
        assert all(sse[n] <= 1.0 for n in predicted), f  # tau = 1 pixel
        assert {n for n in predicted if not unqueryable[n]} <= set(queried), f
    assert sum(not unqueryable[n] for predicted, _, _, unqueryable in frames for n in predicted) > 20


def test_predicting_new_nodes_waits_for_fewer_queries_and_shows_what_waiting_shows(city_renderer):
    """The same paths with and without predict_new (the share's gate open, as above), results
    three commands late: far fewer nodes drawn only after their own query (D), the same image in
    every frame (measured: the node choices differ a little, since nodes drawn earlier fill the
    depth buffer before later queries, but not a pixel), and about the same number of nodes drawn
    (a node predicted visible that its query finds hidden was drawn for nothing, that frame only:
    the city hides a quarter of its candidates, which is what the share's gate is for)."""
    hlod = city_renderer.hlod
    paths = (street_path(30), inspection_path(hlod, seed=11, frames=28))
    images = {"off": [], "on": []}
    runs = {m: _predicted_run(city_renderer, RuntimeSettings(predict_new=m), paths=paths, lag=LAG, share=0.0,
                              images=images[m])[1]
            for m in ("off", "on")}
    d_off, d_on = (sum(s.d for s in runs[m]) for m in ("off", "on"))
    assert sum(s.predicted for s in runs["off"]) == 0
    assert d_on < 0.5 * d_off, (d_on, d_off)
    differ = [int((a != b).any(axis=2).sum()) for a, b in zip(images["off"], images["on"])]
    assert differ == [0] * len(differ), differ
    dn_off, dn_on = (np.mean([s.dn for s in runs[m]]) for m in ("off", "on"))
    assert 0.95 * dn_off <= dn_on <= 1.1 * dn_off, (dn_on, dn_off)  # measured: 5% more, the gate open


class _CandidatesScripted(_Scripted):
    """Every query of a predict_new candidate (a node not visited last frame that would stop fully
    visible) comes back hidden (`shown` False: the scene where new nodes turn out occluded, made on
    demand) or wholly visible (q = alpha)."""

    shown = False

    def result(self, query):
        q, alpha, stall = super().result(query)
        t = self.traversal
        if not query.members and t.candidate_in[query.node] == t.frame_id:
            return (alpha if self.shown else 0), alpha, stall
        return q, alpha, stall


def test_candidates_found_hidden_stop_the_prediction_and_it_resumes_once_they_show(city_renderer):
    """The running share of candidates found visible decides: with every candidate hidden it drops
    below predict_new_share within the first frames and nothing more is predicted, although
    candidates keep coming; once they show again it rises back and the prediction resumes."""
    hlod = city_renderer.hlod
    paths = (inspection_path(hlod, seed=11, frames=28),)
    scripted, stats, frames = _predicted_run(city_renderer, RuntimeSettings(predict_new="on"), paths=paths, lag=0,
                                             scripted_cls=_CandidatesScripted)
    t = scripted.traversal
    assert t.new_visible_share < t.predict_new_share
    assert sum(s.predicted for s in stats[:2]) > 0 and sum(s.predicted for s in stats[4:]) == 0
    assert sum(candidates for _, _, candidates, _ in frames[4:]) > 10  # waited for instead
    scripted.shown = True  # the same traversal, its candidates now visible
    later = [t.frame(path.view(i, SIZE)) for path in (street_path(30), *paths) for i in range(len(path))]
    assert t.new_visible_share >= t.predict_new_share and sum(s.predicted for s in later) > 0


class _FailingDraw:
    """A renderer whose draw_node raises while `fail_when()` holds (a driver error mid-frame);
    records the nodes given their own query (issue_query, issue_queries)."""

    def __init__(self, renderer):
        self._renderer = renderer
        self.fail_when = lambda: False
        self.queried: list[int] = []

    def __getattr__(self, name):
        return getattr(self._renderer, name)

    def draw_node(self, node, ratio_p=1.0):
        if self.fail_when():
            raise RuntimeError("draw failed")
        self._renderer.draw_node(node, ratio_p)

    def issue_query(self, node, *, with_alpha):
        self.queried.append(node)
        return self._renderer.issue_query(node, with_alpha=with_alpha)

    def issue_queries(self, nodes, *, with_alpha):
        self.queried.extend(nodes)
        return self._renderer.issue_queries(nodes, with_alpha=with_alpha)

    def issue_multiquery(self, nodes):
        return self._renderer.issue_multiquery(nodes)


def test_a_frame_that_raised_hands_nothing_to_the_next(city_renderer):
    """The preview keeps its traversal after a failed redraw: a frame that raised with queries
    waiting in the batch must not issue them in the next frame. Every node queried on its own in
    the next frame was visited in it, and once."""
    hlod = city_renderer.hlod
    path = street_path(30)
    failing = _FailingDraw(_Scripted(city_renderer))
    methods = make("coh", hlod, failing)
    for i in range(10):
        methods.frame(path.view(i, SIZE))
    failing.fail_when = lambda: bool(methods.stream.waiting_batch)  # a draw while queries wait in the batch
    with pytest.raises(RuntimeError, match="draw failed"):
        methods.frame(path.view(10, SIZE))
    city_renderer.end_frame()
    assert methods.stream.waiting_batch  # the failed frame left queries waiting
    failing.fail_when = lambda: False
    failing.queried.clear()
    methods.frame(inspection_path(hlod, seed=11, frames=28).view(20, SIZE))  # somewhere else
    visited = set(np.flatnonzero(np.asarray(methods.last_visited) == methods.frame_id).tolist())
    assert failing.queried and set(failing.queried) <= visited
    assert len(failing.queried) == len(set(failing.queried))


def test_a_frame_begun_after_one_that_raised_times_cleanly(city_renderer):
    """A frame that raised never reached end_frame, so its GPU timer query is still active: the
    next begin_frame ends it first instead of beginning the same target again (a GL error). Its own
    framebuffer, still bound, is not taken for the caller's: after release nothing deleted is left
    bound, and the next renderer starts without a GL error."""
    r = city_renderer
    view = street_path(5).view(0, SIZE)
    assert r.ctx.error == "GL_NO_ERROR"
    r.begin_frame(view, time_gpu=True)
    r.draw_node(0)  # ... and the frame raised here
    r.begin_frame(view, time_gpu=True)
    r.draw_node(0)
    assert r.end_frame() > 0.0
    assert r.ctx.error == "GL_NO_ERROR"
    r.release()
    Renderer(r.ctx, r.hlod, size=SIZE).release()
    assert r.ctx.error == "GL_NO_ERROR"
