"""The renderer's cost model (query_cost, Renderer.cost_model) and the queries Bool and Coh leave
out with it (traversal.skipping, settings skip_queries), with real OpenGL (llvmpipe here).

Only the calibration tests time anything; the traversals read a fixed cost model (LLVMPIPE_COSTS,
or one a test scripts) and get their query results after a scripted lag (ScriptedAvailability), so
what they skip never depends on the machine's load. The traversals here query every frame (queries
"always"): the gate that turns all queries off where they do not pay is test_query_gate.py's."""
import numpy as np
import pytest

from helpers import ScriptedAvailability, street_path
from hlod_core.core.errors import InputError
from hlod_core.model.camera_path import CameraPath
from hlod_core.model.view import View, look_at, orthographic, perspective
from hlod_core.render import calibration
from hlod_core.render.gl_functions import GLFunctions
from hlod_core.render.renderer import Renderer
from hlod_core.traversal import alpha_estimators, query_cost
from hlod_core.traversal.coherent import Coh
from hlod_core.traversal.methods import METHODS, make
from hlod_core.traversal.protocol import STOP
from hlod_core.traversal.query_cost import CostModel, LinearCost, fit_linear
from hlod_core.traversal.settings import RuntimeSettings

SIZE = (320, 240)
#: Results this many issued commands late (the latency of a GPU behind the CPU).
LAG = 3
#: A fixed cost model of llvmpipe's size (query 20 us + 2 ns a box pixel, draw 4 us + 5 ns a
#: triangle): some nodes skip, some do not.
LLVMPIPE_COSTS = CostModel(query=LinearCost(fixed_s=20e-6, per_unit_s=2e-9, residual=0.0),
                           draw=LinearCost(fixed_s=4e-6, per_unit_s=5e-9, residual=0.0), clock="wall")
#: Frames before the comparisons start: the change rate has to fall from its prior of 1.
WARM_UP_FRAMES = 15
#: Queries per frame with skipping on, at most this share of those with it off, where nothing
#: hides anything (measured: about 0.25 on the overview orbit below).
VANISHED_SHARE = 0.5


@pytest.fixture
def city_renderer(gl_ctx, city_hlod):
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    yield renderer
    renderer.release()


def _overview(h, frames: int, *, static: bool = False) -> CameraPath:
    """A slow orbit high above `h` (the city) looking down at its centre: every building in view, few
    hiding others (nothing that changes what is drawn)."""
    lo, hi = h.box_min[0], h.box_max[0]
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    out = []
    for i in range(frames):
        angle = 0.6 + (0.0 if static else 0.01 * i)
        eye = centre + radius * np.array([1.6 * np.cos(angle), 1.6 * np.sin(angle), 1.2])
        out.append((eye, centre, [0.0, 0.0, 1.0]))
    return CameraPath(frames=np.array(out), near=0.01 * radius, far=10.0 * radius, fovy_deg=50.0)


def _run(traversal, path):
    return [traversal.frame(path.view(i, SIZE)) for i in range(len(path))]


def _lagged(renderer, cost_model=LLVMPIPE_COSTS):
    """The renderer with results LAG commands late and a fixed cost model."""
    lagged = ScriptedAvailability(renderer, LAG)
    lagged.cost_model = cost_model
    return lagged


# --- the model ------------------------------------------------------------------------------------

def test_fit_recovers_known_costs_and_keeps_them_positive():
    count = np.array([1, 4, 4, 8, 16])
    units = np.array([100, 50, 5000, 20, 90000])
    fit = fit_linear(count, units, count * 30e-6 + units * 2e-9)
    assert fit.fixed_s == pytest.approx(30e-6, rel=1e-6) and fit.per_unit_s == pytest.approx(2e-9, rel=1e-6)
    assert fit.residual < 1e-9
    # a per-unit cost too small to see (here: times that fall with units) is clamped, not negative
    fit = fit_linear([4, 4, 4], [10, 1000, 100000], [41e-6, 40e-6, 39e-6])
    assert fit.per_unit_s == query_cost.MIN_COST_S and fit.fixed_s == pytest.approx(10e-6, rel=0.05)


def test_box_areas_are_within_a_factor_of_two_of_the_exact_silhouette():
    rng = np.random.default_rng(3)
    view = View(eye=np.zeros(3), view=look_at([0, 0, 0], [0, 0, -1], [0, 1, 0]),
                projection=perspective(60.0, 4 / 3, near=0.1, far=1000.0), width=640, height=480)
    centres = np.c_[rng.uniform(-2, 2, (200, 2)), rng.uniform(-40, -10, 200)]
    half = rng.uniform(0.05, 2.0, (200, 3)) * rng.choice([1.0, 0.1], (200, 3))  # flat boxes among them
    lo, hi = centres - half, centres + half
    exact = alpha_estimators.alpha_projected(view, lo, hi)
    estimate = query_cost.BoxAreas.of(lo, hi).pixels_outside(view)  # the eye is outside every box
    inside = exact > 0
    ratio = estimate[inside] / exact[inside]
    assert inside.sum() > 150 and ratio.min() > 0.5 and ratio.max() < 2.0, (ratio.min(), ratio.max())
    # the cube of equal volume misses flat boxes by far more
    cube = alpha_estimators.alpha_cube(view, np.cbrt(np.prod(hi - lo, axis=1)), box_min=lo, box_max=hi)
    assert (cube[inside] / exact[inside]).min() < 0.5


def test_settings_refuse_an_unknown_skip_mode():
    with pytest.raises(InputError, match="skip_queries"):
        RuntimeSettings(skip_queries="sometimes")


@pytest.mark.gl
def test_calibration_gives_positive_costs_that_grow_with_the_work(city_renderer, monkeypatch):
    """The fit has every cost > 0, so a bigger box or more triangles never costs less; the samples
    it is fitted to count the pixels each box size rasterises exactly, growing with the size. No
    time is compared with a band: llvmpipe's times on a loaded machine vary by more than any."""
    r = city_renderer
    samples = []

    def recording_fit(count, units, seconds):
        samples.append((list(count), list(units), list(seconds)))
        return fit_linear(count, units, seconds)

    monkeypatch.setattr(calibration, "fit_linear", recording_fit)
    assert not r.calibrated
    model = r.cost_model
    assert r.cost_model is model and r.calibrated  # calibrated once, then kept
    (queries, pixels, query_s), (calls, triangles, draw_s) = samples
    for cost in (model.query, model.draw):
        assert cost.fixed_s > 0 and cost.per_unit_s > 0 and np.isfinite(cost.residual), model.describe()
    assert model.query.seconds(4, 100) < model.query.seconds(4, 10_000)
    assert model.draw.seconds(1, 100) < model.draw.seconds(1, 10_000)
    # boxes: centred squares of these half-sides in clip space, CALIBRATION_QUERIES queries each
    assert queries == [calibration.CALIBRATION_QUERIES] * len(calibration.CALIBRATION_BOX_HALF_SIDES)
    assert all(small < big for small, big in zip(pixels, pixels[1:]))
    for half, covered in zip(calibration.CALIBRATION_BOX_HALF_SIDES, pixels):
        width, height = half * SIZE[0], half * SIZE[1]  # pixels; whole numbers: edges on pixel borders
        if width == int(width) and height == int(height):
            assert covered == calibration.CALIBRATION_QUERIES * int(width) * int(height), half
    tris = np.asarray(r.hlod.tri_count)
    assert all(c >= 1 and t >= c for c, t in zip(calls, triangles)) and set(triangles) - {0}
    assert all(t % c == 0 and tris[tris > 0].min() <= t // c <= tris.max() for c, t in zip(calls, triangles))
    assert all(s > 0 for s in query_s + draw_s)
    pixels = np.array([1, 100, 10_000, SIZE[0] * SIZE[1]])
    tris = np.sort(np.asarray(r.hlod.tri_count))
    for seconds in (model.query_seconds(pixels), model.draw_seconds(tris)):
        assert np.all(np.isfinite(seconds)) and np.all(seconds > 0) and np.all(np.diff(seconds) >= 0)


# --- skipping in the traversals -------------------------------------------------------------------

def _skipping(mode: str) -> RuntimeSettings:
    """skip_queries `mode`, queries every frame (module docstring)."""
    return RuntimeSettings(queries="always", skip_queries=mode)


@pytest.mark.gl
def test_queries_all_but_vanish_where_nothing_hides(city_renderer):
    """Overview orbit: Coh with skip_queries "expected" issues a fraction of the queries of Coh
    without, drawing the same nodes except where a skipped node's stale ratio holds back a change
    of LOD, which its re-check catches within recheck_frames frames. Bool likewise. `expected` is
    the default."""
    assert RuntimeSettings().skip_queries == "expected"
    r = city_renderer
    path = _overview(r.hlod, 45)
    off = _run(make("coh", r.hlod, _lagged(r), settings=_skipping("off")), path)
    on_traversal = make("coh", r.hlod, _lagged(r), settings=_skipping("expected"))
    on = _run(on_traversal, path)
    later = slice(WARM_UP_FRAMES, None)
    q_off, q_on = (np.mean([s.queries for s in stats[later]]) for stats in (off, on))
    assert q_on < VANISHED_SHARE * q_off, (q_on, q_off)
    assert sum(len(s.skipped) for s in on[later]) > 0 and all(not s.skipped for s in off)
    differing = [i for i in range(WARM_UP_FRAMES, len(path)) if set(off[i].drawn) != set(on[i].drawn)]
    runs, start = [], None  # consecutive frames whose drawn sets differ
    for i in range(WARM_UP_FRAMES, len(path) + 1):
        if i in differing and start is None:
            start = i
        elif i not in differing and start is not None:
            runs.append(i - start)
            start = None
    assert max(runs, default=0) <= on_traversal.skips.recheck_frames, (differing, runs)
    dn_off, dn_on = (np.mean([s.dn for s in stats[later]]) for stats in (off, on))
    assert dn_on == pytest.approx(dn_off, rel=0.03)
    b_off, b_on = (_run(make("bool", r.hlod, _lagged(r), settings=_skipping(m)), path)
                   for m in ("off", "expected"))
    assert np.mean([s.queries for s in b_on[later]]) < VANISHED_SHARE * np.mean([s.queries for s in b_off[later]])


class _Hider:
    """The real renderer; from frame `hide_from` on, each frame's depth buffer is cleared to 0 after
    begin_frame, so every query box and every node fails the depth test: everything is hidden."""

    def __init__(self, renderer, hide_from):
        self._renderer, self.hide_from, self.frame = renderer, hide_from, 0

    def __getattr__(self, name):
        return getattr(self._renderer, name)

    def begin_frame(self, view):
        self._renderer.begin_frame(view)
        if self.frame >= self.hide_from:
            self._renderer.fbo.clear(depth=0.0)
            self._renderer.forget_mode()  # moderngl's clear puts its own depth mask back
        self.frame += 1


@pytest.mark.gl
@pytest.mark.parametrize("method", ["coh", "bool"])
def test_a_node_that_becomes_hidden_is_found_within_the_recheck_interval(city_renderer, method):
    path, hide_from = _overview(city_renderer.hlod, 40, static=True), 25
    hider = _lagged(_Hider(city_renderer, hide_from))
    traversal = make(method, city_renderer.hlod, hider, settings=_skipping("expected"))
    stats = _run(traversal, path)
    assert stats[hide_from - 1].skipped  # nodes were assumed visible when the occluder came
    assert stats[hide_from].dn > 0  # ...and are still drawn in its first frame, unqueried
    n = traversal.skips.recheck_frames
    # a skipped node is re-checked within n frames; its parent learns it is invisible one frame on
    for i in range(hide_from + n + 1, len(path)):
        assert stats[i].dn == 0, (i, [s.dn for s in stats])
    hider = _lagged(_Hider(city_renderer, hide_from))
    off = _run(make(method, city_renderer.hlod, hider, settings=_skipping("off")), path)
    assert all(s.dn == 0 for s in off[hide_from + 2:])


@pytest.mark.gl
def test_a_scripted_cost_model_pins_both_branches(city_renderer):
    """Test double only for what hardware cannot be made to do on demand: a model where every
    query costs a second skips every stopped node not due for its re-check ("cheap"); one where
    every draw costs a second skips none, and draws what skipping off draws."""
    path = street_path(30)
    r = city_renderer
    free = LinearCost(fixed_s=query_cost.MIN_COST_S, per_unit_s=query_cost.MIN_COST_S, residual=0.0)
    second = LinearCost(fixed_s=1.0, per_unit_s=0.0, residual=0.0)

    def run(skip_queries, model=None):
        # results come back after a scripted lag, not when llvmpipe's threads finish them, so runs
        # that should do the same work do exactly the same
        lagged = _lagged(r, model)
        return _run(make("coh", r.hlod, lagged, settings=_skipping(skip_queries)), path)

    off = run("off")
    never = run("cheap", CostModel(query=free, draw=second, clock="wall"))
    always = run("cheap", CostModel(query=second, draw=free, clock="wall"))
    assert all(not s.skipped for s in never)
    assert [s.drawn for s in never] == [s.drawn for s in off] and [s.queries for s in never] == [s.queries for s in off]
    assert sum(len(s.skipped) for s in always) > 0
    assert sum(s.queries for s in always) < sum(s.queries for s in off)


@pytest.mark.gl
@pytest.mark.parametrize("method", ["bool", "coh"])
@pytest.mark.parametrize("mode", ["cheap", "expected"])
def test_skipping_tests_only_the_nodes_visible_last_frame_and_changes_nothing(city_renderer, method, mode):
    """`prepare` computes box areas and the skip test only for the nodes visible at the end of the
    last frame (the only ones predicted STOP): the same draws, skips and queries every frame as the
    test over every queryable box in the frustum, under a fixed cost model of llvmpipe's size where
    some nodes skip and some do not (results after a scripted lag, so both see the same timing)."""
    r = city_renderer
    cls = METHODS[method]

    class EveryCandidate(cls):
        def skip_candidates(self):
            return np.flatnonzero(np.asarray(self.in_frustum) & ~np.asarray(self.unqueryable)).tolist()

    runs = []
    for traversal_class in (cls, EveryCandidate):
        traversal = traversal_class(r.hlod, _lagged(r), _skipping(mode))
        stats = _run(traversal, street_path(30)) + _run(traversal, _overview(r.hlod, 30))
        runs.append([(s.drawn, s.skipped, s.queries) for s in stats])
    assert runs[0] == runs[1]
    skipped = sum(len(skips) for _, skips, _ in runs[0])
    queried = sum(q for _, _, q in runs[0])
    assert skipped > 20 and queried > 20, (skipped, queried)  # both branches taken


@pytest.mark.parametrize("projection", ["perspective", "orthographic"])
def test_the_skip_test_decides_the_same_in_python_and_numpy(projection):
    """query_cost.draw_is_cheaper, node by node in Python (python_nodes above the count) and
    vectorised (python_nodes 0), against the cost model's own terms (CostModel.draw_seconds times
    the rate < query_seconds of BoxAreas.pixels_outside) on 400 random boxes, some flat, and with
    the box pixels given; nodes not asked about are false; the eye at a box's centre gets the
    viewport, as numpy's inf clipped to it."""
    rng = np.random.default_rng(5)
    centres = np.c_[rng.uniform(-3, 3, (400, 2)), rng.uniform(-40, -2, 400)]
    half = rng.uniform(0.05, 2.0, (400, 3)) * rng.choice([1.0, 0.1], (400, 3))
    centres[7] = 0.0  # the eye at this box's centre
    lo, hi = centres - half, centres + half
    tris = rng.integers(2, 4000, 400)
    projection_matrix = perspective(60.0, 4 / 3, near=0.1, far=1000.0) if projection == "perspective" \
        else orthographic(8.0, 4 / 3, near=0.1, far=1000.0)
    view = View(eye=np.zeros(3), view=look_at([0, 0, 0], [0.2, -0.1, -1], [0, 1, 0]), projection=projection_matrix,
                width=640, height=480)
    model = CostModel(query=LinearCost(fixed_s=20e-6, per_unit_s=2e-9, residual=0.0),
                      draw=LinearCost(fixed_s=4e-6, per_unit_s=20e-9, residual=0.0), clock="wall")
    costs = query_cost.NodeCosts.of(tris, lo, hi)
    pixels = costs.boxes.pixels_outside(view)
    given = rng.uniform(0, 20000, 400)
    asked = list(range(0, 400, 3))
    for rate in (1.0, 0.3, 0.01):
        for box_pixels, given_pixels in ((pixels, None), (given, given)):
            expected = np.zeros(400, bool)
            expected[asked] = (model.draw_seconds(tris) * rate < model.query_seconds(box_pixels))[asked]
            for python_nodes in (0, 10**9):
                mask = query_cost.draw_is_cheaper(view, model, asked, costs=costs, rate=rate, pixels=given_pixels,
                                                  python_nodes=python_nodes)
                assert [bool(x) for x in mask] == expected.tolist(), (rate, python_nodes)
            if rate == 1.0:
                assert 15 < expected.sum() < 120, expected.sum()  # both answers occur
    if projection == "perspective":
        assert pixels[7] == 640 * 480


@pytest.mark.gl
@pytest.mark.parametrize("method", ["bool", "coh"])
def test_skip_tests_in_python_and_numpy_give_the_same_frames(city_renderer, method):
    """`prepare` tests up to python_test_nodes candidates in Python, more with numpy: forced to
    either, the same draws, skips and queries every frame (fixed cost model, scripted lag)."""
    r = city_renderer
    runs = []
    for limit in (0, 10**9):
        traversal = make(method, r.hlod, _lagged(r), settings=_skipping("expected"))
        traversal.skips.python_test_nodes = limit
        stats = _run(traversal, street_path(30)) + _run(traversal, _overview(r.hlod, 30))
        runs.append([(s.drawn, s.skipped, s.queries) for s in stats])
    assert runs[0] == runs[1]
    assert sum(len(skips) for _, skips, _ in runs[0]) > 20 and sum(q for _, _, q in runs[0]) > 20


@pytest.mark.gl
def test_the_change_rate_is_the_mean_of_its_results_until_its_weight_takes_over(city_renderer):
    """The running change rate (STOP results that changed something) starts at 1 and is the plain
    mean of the results seen while there are fewer than 1 / change_rate_weight, then an exponential
    mean of that weight: its start counts only until the first result. Through `queried` and the
    walk: on a static view nothing changes, so after the first frames with STOP results it is 0,
    where a start of 1 decaying by 1/64 a result would still hold it above 0.1."""
    traversal = make("coh", city_renderer.hlod, _lagged(city_renderer),
                     settings=_skipping("expected"))
    skips = traversal.skips
    assert skips.change_rate == 1.0
    results = [True, False, False, True, False] + [False] * 100
    for k, changed in enumerate(results, start=1):
        before = skips.change_rate
        skips.queried_step(1)(0, STOP, changed)
        if k <= 64:
            assert skips.change_rate == pytest.approx(np.mean(results[:k]), abs=1e-12)
        else:
            assert skips.change_rate == pytest.approx(before + (float(changed) - before) / 64, abs=1e-15)
    still = make("coh", city_renderer.hlod, _lagged(city_renderer), settings=_skipping("expected"))
    stats = _run(still, _overview(city_renderer.hlod, 4, static=True))
    assert stats[1].dn > 5 and still.skips.change_results > 5  # STOP results were counted
    assert still.skips.change_rate == 0.0
    assert (1 - skips.change_rate_weight) ** still.skips.change_results > 0.1  # the old start would still count


@pytest.mark.gl
def test_recheck_frames_follow_the_seed(city_renderer):
    """Same seed, same phases and the same frames' work; another seed, other phases, and no node
    is ever skipped on its own re-check frame."""
    r = city_renderer
    path = _overview(r.hlod, 30)
    settings = _skipping("expected")
    first, again, other = (Coh(r.hlod, _lagged(r), settings, recheck_seed=seed) for seed in (7, 7, 8))
    phase, n = first.skips.recheck_phase, first.skips.recheck_frames
    assert phase == again.skips.recheck_phase != other.skips.recheck_phase
    assert set(phase) == set(range(n))
    runs = [[(s.drawn, s.skipped, s.queries) for s in _run(t, path)] for t in (first, again, other)]
    assert runs[0] == runs[1] and runs[0] != runs[2]
    for frame_id, (_, skipped, _) in enumerate(runs[0], start=1):
        assert all((frame_id + phase[node]) % n != 0 for node in skipped), frame_id
    assert sum(len(skipped) for _, skipped, _ in runs[0]) > 0


@pytest.mark.gl
def test_a_frame_timer_after_calibration_raises_no_gl_error(city_renderer):
    """The calibration's occlusion queries take ids from the renderer's pool; a later frame's GPU
    timer must not get one of them (GL: an id keeps the target it was first begun with)."""
    r = city_renderer
    gl = GLFunctions(r.ctx)
    r.calibrate_costs(clock="wall")
    r.begin_frame(_overview(r.hlod, 1).view(0, SIZE), time_gpu=True)
    r.draw_node(0)
    assert r.end_frame() > 0
    assert gl.get_error() == 0
