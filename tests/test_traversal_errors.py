"""Bad settings and failures: a runtime setting out of range is the core's typed error, an unknown
method is told apart from a bug in a constructor, and a frame that raised hands nothing to the
next.

Query results come back after a scripted lag (traversal_runs.Scripted: a number of issued
commands) and the skip test reads a fixed cost model (traversal_runs.LLVMPIPE_COSTS), so what a
traversal does never depends on llvmpipe's threads or the machine's load; the tests that run
the real renderer's own availability say so."""
import numpy as np
import pytest

from helpers import street_path
from hlod_core.core.errors import InputError
from hlod_core.model.camera_path import inspection_path
from hlod_core.render.renderer import Renderer
from hlod_core.traversal.methods import METHODS, make
from hlod_core.traversal.settings import RuntimeSettings
from traversal_runs import SIZE, Scripted

pytestmark = pytest.mark.gl  # these tests draw with a real OpenGL context


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
    failing = _FailingDraw(Scripted(city_renderer))
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
