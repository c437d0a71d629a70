"""No queries where they do not pay (traversal.query_gate, settings queries "auto"): on an open
square the queries go off after the learning window and the picture is VFC's; on the city's street
they stay on; where occlusion appears mid-path (from an open square into a street) they come back
within 5 frames. Real GL (llvmpipe); query results after a scripted lag (traversal_runs.Scripted),
so what the gate learns is the same on every run."""
import numpy as np
import pytest

from helpers import street_path
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import procedural
from hlod_core.model.camera_path import inspection_path
from hlod_core.render.renderer import Renderer
from hlod_core.traversal.methods import make
from hlod_core.traversal.query_gate import GateParameters, QueryGate
from hlod_core.traversal.settings import RuntimeSettings
from traversal_runs import SIZE, Scripted

pytestmark = pytest.mark.gl  # these tests draw with a real OpenGL context

WINDOW = GateParameters().window_frames
#: Frames within which the queries must be back once they would cull this share of the triangles.
RESUME_FRAMES, RESUME_SHARE = 5, 0.10


@pytest.fixture(scope="module")
def square_hlod():
    """9 scanned statues standing apart on flat ground (about 35k triangles)."""
    return bake(procedural.square_scene(per_side=3, segments=64), BakeSettings(jobs=1))


@pytest.fixture(scope="module")
def square_and_street_hlod():
    """A square of 9 statues beside a 4 x 4 city block (about 96k triangles)."""
    return bake(procedural.square_and_street_scene(), BakeSettings(jobs=2))


def _renderer(gl_ctx, hlod):
    return Renderer(gl_ctx, hlod, size=SIZE)


def test_the_cut_counts_the_triangles_vfc_draws(city_renderer):
    """QueryGate.vfc_cut, vectorised level by level, against VFC's walk on the street and an
    inspection path of the city."""
    hlod = city_renderer.hlod
    gate, vfc = QueryGate(hlod), make("vfc", hlod, city_renderer)
    for path in (street_path(10), inspection_path(hlod, seed=3, frames=12)):
        for i in range(len(path)):
            stats = vfc.frame(path.view(i, SIZE))
            assert gate.vfc_cut(vfc.in_frustum, vfc.sse, vfc.settings.tau) == (stats.dn, stats.tris), i


def test_queries_go_off_on_an_open_square_and_the_picture_is_vfcs(gl_ctx, square_hlod):
    path = procedural.square_far_path(frames=30, per_side=3)
    renderer = _renderer(gl_ctx, square_hlod)
    try:
        vfc = make("vfc", square_hlod, renderer)
        coh = make("coh", square_hlod, Scripted(renderer))
        off, probes = [], 0
        for i in range(len(path)):
            view = path.view(i, SIZE)
            vfc.frame(view)
            want = renderer.read_pixels()
            stats = coh.frame(view)
            off.append(stats.queries_off)
            if stats.queries_off:
                probes += stats.probes
                assert stats.queries == stats.probes and stats.queries_note.startswith("queries off"), i
                assert np.array_equal(renderer.read_pixels(), want), f"frame {i}: not VFC's picture"
    finally:
        renderer.release()
    assert off[:WINDOW] == [0] * WINDOW and off[WINDOW:] == [1] * (len(path) - WINDOW), off
    assert probes > 0  # it kept looking


def test_queries_stay_on_in_the_citys_street(city_renderer):
    coh = make("coh", city_renderer.hlod, Scripted(city_renderer))
    path = street_path(30)
    off = [coh.frame(path.view(i, SIZE)).queries_off for i in range(len(path))]
    assert off == [0] * len(path), off


def test_queries_come_back_where_occlusion_appears_mid_path(gl_ctx, square_and_street_hlod):
    """From the first frame where Coh(P)'s queries, asked every frame (queries "always"), cull
    RESUME_SHARE of VFC's triangles (after the gate first turned the queries off), Coh(P) with the
    gate queries again within RESUME_FRAMES frames."""
    hlod = square_and_street_hlod
    path = procedural.square_to_street_path(frames=60)
    renderer = _renderer(gl_ctx, hlod)
    try:
        vfc = make("vfc", hlod, renderer)
        always = make("coh", hlod, Scripted(renderer), settings=RuntimeSettings(queries="always"))
        coh = make("coh", hlod, Scripted(renderer))
        culled, off = [], []
        for i in range(len(path)):
            view = path.view(i, SIZE)
            vfc_tris = vfc.frame(view).tris
            culled.append(1.0 - always.frame(view).tris / vfc_tris)
            off.append(coh.frame(view).queries_off)
    finally:
        renderer.release()
    went_off = off.index(1)  # raises where the queries never went off: the open square must turn them off
    assert went_off == WINDOW, off
    first = next(i for i in range(went_off, len(path)) if culled[i] >= RESUME_SHARE)
    assert 0 in off[first:first + RESUME_FRAMES + 1], (first, off, np.round(culled, 2).tolist())
    street = dict(path.parts)["street"]
    assert off[street + RESUME_FRAMES:] == [0] * (len(path) - street - RESUME_FRAMES), off
