"""What each traversal method draws on the default city, with real OpenGL occlusion queries
(Mesa llvmpipe through EGL without a GPU): the images and cuts they draw, their counters, the
alpha estimators, extreme and degenerate views.

Query results come back after a scripted lag (traversal_runs.Scripted: a number of issued
commands) and the skip test reads a fixed cost model (traversal_runs.LLVMPIPE_COSTS), so what a
traversal does never depends on llvmpipe's threads or the machine's load; the tests that run
the real renderer's own availability say so."""
import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from helpers import load_model, street_path
from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.io import meshes
from hlod_core.model.camera_path import CameraPath, inspection_path
from hlod_core.render.renderer import Renderer
from hlod_core.traversal import alpha_estimators, boxes, metrics
from hlod_core.traversal.methods import METHODS, make
from hlod_core.traversal.stats import COUNTERS, DEPTH_COUNTERS, QUERY_COUNTERS, STREAM_COUNTERS, FrameStats
from traversal_runs import SIZE, Scripted, ScriptedLatency, frames_of

pytestmark = pytest.mark.gl  # these tests draw with a real OpenGL context


def test_bool_draws_the_same_image_as_vfc(city_renderer):
    """Occlusion culling is conservative: Bool draws exactly VFC's pixels on a high-depth-complexity
    street walk and on an orbit-to-close-up inspection path, while drawing fewer nodes."""
    close_up = inspection_path(city_renderer.hlod, seed=3, frames=24)
    # the same path with a 6 m near plane: boxes close to the eye reach in front of it and have
    # their front faces clipped, so they must be drawn without a query (a query would read 0)
    deep_near = CameraPath(frames=close_up.frames, near=6.0, far=close_up.far, fovy_deg=60.0)
    for path in (street_path(30), close_up, deep_near):
        vfc = frames_of(city_renderer, "vfc", path, images=True)
        boolean = frames_of(Scripted(city_renderer), "bool", path, images=True)
        for i, ((vs, vimg), (bs, bimg)) in enumerate(zip(vfc, boolean)):
            assert np.array_equal(vimg, bimg), f"frame {i}: {(vimg != bimg).any(axis=2).sum()} pixels differ"
            assert set(bs.drawn) <= set(vs.drawn)
        assert sum(b.dn for b, _ in boolean) < sum(v.dn for v, _ in vfc)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_no_node_is_drawn_twice_and_counters_are_consistent(city_renderer, method):
    for stats, _ in frames_of(Scripted(city_renderer), method, street_path(20)):
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
        for stats, _ in frames_of(Scripted(city_renderer), method, street_path(10)):
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


def test_ideal_draws_the_sw_set_without_queries(city_renderer):
    path = street_path(8)
    sw = [s.drawn for s, _ in frames_of(city_renderer, "sw", path)]
    ideal = [s for s, _ in frames_of(city_renderer, "ideal", path)]
    assert [sorted(s.drawn) for s in ideal] == [sorted(d) for d in sw]
    assert all(s.queries == 0 for s in ideal)


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
                for stats, _ in frames_of(Scripted(renderer), method, path, size=size):
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
        for stats, _ in frames_of(Scripted(city_renderer), method, path):
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


def test_orthographic_path(city_renderer):
    eye = np.array([70.0, -120.0, 90.0])
    path = CameraPath(frames=np.array([[eye, [70.0, 70.0, 0.0], [0, 0, 1]]] * 4), near=1.0, far=600.0,
                      fovy_deg=None, ortho_height=160.0)
    vfc = frames_of(city_renderer, "vfc", path, images=True)
    boolean = frames_of(Scripted(city_renderer), "bool", path, images=True)
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(vfc, boolean))
    coh = frames_of(Scripted(city_renderer), "coh", path)
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
        # near 0.05: with 1e-4 the 24-bit depth steps 12 units away are ~0.09 units, where triangles of
        # neighbouring nodes tie and the draw order (VFC's and Bool's differ) picks the pixel
        path = CameraPath(frames=np.array([[centre + [0, -12, 3], centre, [0, 0, 1]]] * 3), near=0.05, far=1e5)
        vfc = frames_of(renderer, "vfc", path, images=True)
        boolean = frames_of(Scripted(renderer), "bool", path, images=True)
        assert (vfc[0][1] != 255).any(axis=2).sum() > 1000  # the cow is on screen
        assert all(np.array_equal(a[1], b[1]) for a, b in zip(vfc, boolean))
    finally:
        renderer.release()


def test_scripted_query_latency_keeps_culling_conservative(city_renderer):
    slow = ScriptedLatency(city_renderer)
    path = street_path(12)
    vfc = frames_of(city_renderer, "vfc", path, images=True)
    for method in ("bool", "coh"):
        methods = make(method, city_renderer.hlod, slow)
        for i in range(len(path)):
            stats = methods.frame(path.view(i, SIZE))
            assert len(stats.drawn) == len(set(stats.drawn))
            if method == "bool":
                assert np.array_equal(city_renderer.read_pixels(), vfc[i][1]), f"frame {i}"


def test_counters_are_the_numeric_fields_of_frame_stats_in_order():
    numeric = [f.name for f in dataclasses.fields(FrameStats) if f.type in ("int", "float")]
    assert list(COUNTERS + QUERY_COUNTERS + STREAM_COUNTERS + DEPTH_COUNTERS) == numeric
    assert not hasattr(FrameStats, "counters")


def test_the_traversal_does_not_import_the_gl_renderer():
    """The traversal is typed against the NodeRenderer protocol: importing it loads nothing of
    hlod_core.render, nor moderngl."""
    code = ("import sys, hlod_core.traversal.methods\n"
            "print(sorted(m for m in sys.modules if m.startswith('hlod_core.render') or m == 'moderngl'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
