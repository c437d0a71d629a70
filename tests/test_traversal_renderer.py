"""The traversal and the renderer together: GL objects released, the caller's framebuffer and GL
state left as they were, each drawn node passed with its ratio, and the modulation overlay drawn
in the colours of docs/how-it-works.md#the-runtime.

Query results come back after a scripted lag (traversal_runs.Scripted: a number of issued
commands) and the skip test reads a fixed cost model (traversal_runs.LLVMPIPE_COSTS), so what a
traversal does never depends on llvmpipe's threads or the machine's load; the tests that run
the real renderer's own availability say so."""
import ctypes

import moderngl
import numpy as np
import pytest

from helpers import street_path
from hlod_core.core import colour as overlay
from hlod_core.core.colour import OVERLAY_RAMP_STEPS, overlay_ramp
from hlod_core.render.gl_functions import GL, GLFunctions
from hlod_core.render.gl_state import GLState
from hlod_core.render.renderer import DEFAULT_COLOUR, Renderer
from hlod_core.traversal import metrics
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings
from traversal_runs import SIZE, Scripted, frames_of

pytestmark = pytest.mark.gl  # these tests draw with a real OpenGL context


def test_release_frees_everything_and_is_idempotent(gl_ctx, city_hlod):
    """Frames on the real renderer (its own cost calibration included), then release, twice."""
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    frames_of(renderer, "coh", street_path(3))
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


@pytest.mark.parametrize("method", ["full", "vfc", "bool"])
def test_overlay_of_methods_without_vmsse_is_all_blue(city_renderer, method):
    """Only VMSSE lowers a node's LOD; Full, VFC and Bool show no modulation (blue), even for a
    node Bool drew from last frame's visibility and then found hidden."""
    path = street_path(12)
    methods = make(method, city_renderer.hlod, Scripted(city_renderer))
    city_renderer.overlay = True  # the drawing side's setting
    for i in range(len(path)):
        methods.frame(path.view(i, SIZE))
        image = city_renderer.read_pixels()
        drawn = image[np.any(image != 255, axis=2)].astype(np.int64)
        assert drawn.shape[0] > 1000
        assert np.all(drawn[:, 0] <= 0.11 * drawn[:, 2] + 2)


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
    recording = _Recording(Scripted(city_renderer))
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
    recording = _Recording(Scripted(city_renderer))
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
