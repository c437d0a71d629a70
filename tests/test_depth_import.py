"""hlod_core/render/depth_import.py and Renderer.set_scene_depth: a host's depth in the renderer's
depth buffer before the frame's queries, at full or reduced resolution (real GL: Mesa llvmpipe)."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import street_path
from hlod_core.core.errors import InputError
from hlod_core.model.view import View, look_at, perspective
from hlod_core.render.depth_import import check_depth, reduce_depth, wall_depth
from hlod_core.render.renderer import Renderer
from hlod_core.traversal import boxes
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

SIZE = (64, 48)
#: DEPTH_COMPONENT24 keeps 24 bits of a float written to gl_FragDepth.
DEPTH_24_BITS = 2.0 ** -23


def test_reduce_depth_keeps_the_farthest_depth_of_each_block():
    """3 x 5 by 2: blocks of rows {0, 1}, {2} and columns {0, 1}, {2, 3}, {4}; the maximum of each."""
    depth = np.array([[0.1, 0.2, 0.3, 0.9, 0.5],
                      [0.4, 0.0, 0.2, 0.1, 0.6],
                      [0.7, 0.3, 0.8, 0.2, 0.25]], np.float32)
    assert reduce_depth(depth, 2).tolist() == np.float32([[0.4, 0.9, 0.6], [0.7, 0.8, 0.25]]).tolist()
    assert reduce_depth(depth, 1) is depth
    assert reduce_depth(depth, 8).tolist() == [[np.float32(0.9)]]


@pytest.mark.parametrize("bad, why", [
    (np.zeros((4, 4, 1), np.float32), "expected a (height, width) depth image, got shape (4, 4, 1)"),
    (np.full((2, 2), np.nan, np.float32), "depth values must be window depth in [0, 1]"),
    (np.full((2, 2), 1.5, np.float32), "depth values must be window depth in [0, 1]"),
])
def test_a_depth_image_of_another_form_is_refused_naming_it(bad, why):
    with pytest.raises(InputError) as err:
        check_depth(bad, where="Blender's depth")
    assert str(err.value).startswith(f"Blender's depth: {why}")


def test_the_wall_lies_at_its_distance():
    """A point `distance` in front of the eye along the view direction, through the view's own
    matrices, has the wall's window depth; the wall covers the left columns only."""
    view = View(eye=np.zeros(3), view=look_at([0, 0, 0], [0, 1, 0], [0, 0, 1]),
                projection=perspective(60.0, 4 / 3, near=0.05, far=400.0), width=64, height=48)
    depth = wall_depth(view, distance=5.0, covered=0.25)
    clip = view.projection @ view.view @ np.array([0.0, 5.0, 0.0, 1.0])
    assert depth[0, 0] == pytest.approx(0.5 * (clip[2] / clip[3] + 1.0), abs=1e-7)
    assert (depth[:, :16] == depth[0, 0]).all() and (depth[:, 16:] == 1.0).all()


def _depth_pattern() -> np.ndarray:
    """(48, 64): 0.25 over the bottom-left quarter (rows 0..23 are the bottom half), a ramp elsewhere."""
    depth = np.tile(np.linspace(0.3, 0.99, SIZE[0], dtype=np.float32), (SIZE[1], 1))
    depth[:24, :32] = 0.25
    return depth


@pytest.mark.gl
@pytest.mark.parametrize("factor", [1, 4, 5])
def test_the_scene_depth_is_in_the_depth_buffer_bottom_row_first(gl_ctx, city_hlod, factor):
    """After begin_frame the renderer's depth buffer holds the scene depth (row 0 at the bottom, as
    glReadPixels reads it), or at a reduced resolution each block's farthest depth."""
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    try:
        depth = _depth_pattern()
        renderer.set_scene_depth(depth, reduce=factor)
        renderer.begin_frame(street_path(1).view(0, SIZE))
        held = np.frombuffer(renderer.fbo.read(components=1, attachment=-1, dtype="f4"),
                             np.float32).reshape(SIZE[1], SIZE[0])
        renderer.end_frame()
    finally:
        renderer.release()
    blocks = np.kron(reduce_depth(depth, factor), np.ones((factor, factor), np.float32))[:SIZE[1], :SIZE[0]]
    assert np.abs(held - blocks).max() <= DEPTH_24_BITS
    assert held[0, 0] == pytest.approx(0.25, abs=DEPTH_24_BITS) and held[-1, 0] > 0.29  # bottom left, top left


def _queryable(view, hlod, pad):
    rows = boxes.BoxRows.of(hlod.box_min, hlod.box_max, query_pad=pad, centre=hlod.sphere_center)
    tests = boxes.view_tests(view, rows)
    return np.flatnonzero(tests.in_frustum & ~tests.unqueryable).tolist()


@pytest.mark.gl
def test_queries_count_only_what_the_scene_depth_leaves_visible(gl_ctx, city_hlod):
    """The street view with a wall over the left half at 5 m: no box counts more pixels than
    without it, some count fewer and some behind the wall count none; reduced 4 times, the
    wall's edge blocks keep the farthest depth, so no box counts fewer pixels than at full size."""
    view = street_path(1).view(0, SIZE)
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    try:
        nodes = _queryable(view, city_hlod, renderer.query_box_pad)
        counts = {}
        for name, depth, factor in (("none", None, 1), ("wall", wall_depth(view, distance=5.0), 1),
                                    ("wall / 4", wall_depth(view, distance=5.0), 4)):
            renderer.set_scene_depth(depth, reduce=factor)
            renderer.begin_frame(view, time_gpu=False)
            queries = renderer.issue_queries(nodes, with_alpha=True)
            counts[name] = np.array([renderer.result(q)[:2] for q in queries])
            renderer.end_frame()
    finally:
        renderer.release()
    free, wall, reduced = counts["none"], counts["wall"], counts["wall / 4"]
    assert (free[:, 1] == wall[:, 1]).all()  # alpha: the depth test off sees no wall
    assert (wall[:, 0] <= free[:, 0]).all() and (wall[:, 0] < free[:, 0]).any()
    assert ((wall[:, 0] == 0) & (free[:, 0] > 0)).any()
    assert (reduced[:, 0] >= wall[:, 0]).all() and (reduced[:, 0] <= free[:, 0]).all()


@pytest.mark.gl
def test_the_traversal_sees_the_scene_depth_and_its_cost(gl_ctx, city_hlod):
    """Coh down the street draws fewer nodes with the wall than without (the queries see it), and
    the frame's counters carry the import's milliseconds only when a depth image is set."""
    size, path = (160, 120), street_path(12)
    renderer = Renderer(gl_ctx, city_hlod, size=size)
    try:
        drawn, import_ms = {}, {}
        for wall in (False, True):
            traversal = make("coh", city_hlod, renderer, settings=RuntimeSettings())
            stats = []
            for i in range(len(path)):
                view = path.view(i, size)
                renderer.set_scene_depth(wall_depth(view, distance=5.0) if wall else None)
                stats.append(traversal.frame(view))
            drawn[wall] = np.mean([s.dn for s in stats])
            import_ms[wall] = [s.depth_import_ms for s in stats]
    finally:
        renderer.release()
    assert drawn[True] < 0.85 * drawn[False], drawn
    assert all(ms > 0.0 for ms in import_ms[True]) and all(ms == 0.0 for ms in import_ms[False])


@pytest.mark.gl
def test_a_scene_depth_of_another_size_or_reduction_is_refused(gl_ctx, city_hlod):
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    try:
        with pytest.raises(InputError, match="the reduction must be a whole number >= 1, got 0"):
            renderer.set_scene_depth(_depth_pattern(), reduce=0)
        renderer.set_scene_depth(np.ones((10, 10), np.float32))
        with pytest.raises(InputError, match=r"scene depth: 10x10 pixels for a 64x48 frame"):
            renderer.begin_frame(street_path(1).view(0, SIZE))
        renderer.set_scene_depth(None)
        renderer.begin_frame(street_path(1).view(0, SIZE))
        renderer.end_frame()
    finally:
        renderer.release()
