"""Node geometry streamed under a GPU budget (render.residency, render.streamed_geometry): the
budget holds, nodes drawn in a frame stay, an ancestor stands in for children not resident yet, a
budget of one node still draws, a budget larger than the file draws the frames of no budget, and
the buffers are released. Real OpenGL (llvmpipe where there is no GPU); deterministic: VFC and SW
need no query timing, and Coh's results come after a scripted lag."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import ScriptedAvailability
from hlod_core.core.errors import InputError
from hlod_core.model.camera_path import inspection_path
from hlod_core.render.renderer import Renderer
from hlod_core.render.residency import Residency, StreamingSettings
from hlod_core.render.streamed_geometry import node_bytes
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

SIZE = (320, 240)
FRAMES = 30
#: Coh's query results come back this many issued commands late (helpers.ScriptedAvailability).
LAG = 3


def _frames(hlod, renderer, method: str, path, *, lag: int | None = None):
    """[(FrameStats, pixels, resident copy)] of `method` over `path` on `renderer`."""
    target = renderer if lag is None else ScriptedAvailability(renderer, lag)
    traversal = make(method, hlod, target, settings=RuntimeSettings(skip_queries="off"))
    out = []
    for i in range(len(path)):
        stats = traversal.frame(path.view(i, SIZE))
        resident = None if renderer.residency is None else renderer.residency.resident.copy()
        out.append((stats, renderer.read_pixels(), resident))
    return out


def _run(gl_ctx, hlod, method, path, *, streaming=None, lag=None):
    renderer = Renderer(gl_ctx, hlod, size=SIZE, streaming=streaming)
    try:
        return _frames(hlod, renderer, method, path, lag=lag), renderer.gpu_bytes
    finally:
        renderer.release()


@pytest.fixture(scope="module")
def path(city_hlod):
    return inspection_path(city_hlod, seed=3, frames=FRAMES)


def _file_bytes(hlod) -> int:
    return int(node_bytes(hlod, with_uv=False, with_colour=False).sum())


# --- the bookkeeping alone (no GL) -----------------------------------------------------------------

def _chain(n: int) -> dict:
    """A root with n children, each 100 bytes; the root 50 bytes."""
    return dict(child_offset=np.array([1] + [-1] * n), child_count=np.array([n] + [0] * n),
                depth=np.array([0] + [1] * n), node_bytes=np.array([50] + [100] * n))


def test_residency_plans_within_the_budget_and_the_frame_cap():
    """Budget 350: the root (pinned, 50) and three 100-byte children fit; the cap of 150 bytes a
    frame lets one child in per frame (the first upload of a frame always goes)."""
    residency = Residency(**_chain(4), settings=StreamingSettings(budget_bytes=350, upload_bytes_per_frame=150))
    assert residency.initial_uploads() == (0,)
    residency.uploaded(0)
    uploads = []
    for _ in range(6):
        residency.begin_frame()
        residency.use(0)
        if not residency.can_refine(0, visible=True, error_over_tau=5.0):
            assert residency.substitutions == 1
        plan = residency.plan()
        for node in plan.evict:
            residency.evicted(node)
        for node in plan.upload:
            residency.uploaded(node)
        assert residency.resident_bytes <= 350
        uploads.append(plan.upload)
    assert [len(u) for u in uploads] == [1, 1, 1, 0, 0, 0]  # three fit; the fourth never does
    assert residency.resident.sum() == 4 and residency.resident_bytes == 350


def test_residency_evicts_the_least_recently_used_and_never_what_this_frame_used():
    """Root 0 -> 1, 2; 1 -> 3. All but 3 resident and the budget full: refining 1 needs 3, and 2,
    which this frame did not use, makes room (0 is pinned, 1 was used)."""
    residency = Residency(child_offset=np.array([1, 3, -1, -1]), child_count=np.array([2, 1, 0, 0]),
                          depth=np.array([0, 1, 1, 2]), node_bytes=np.array([50, 100, 100, 100]),
                          settings=StreamingSettings(budget_bytes=250, upload_bytes_per_frame=1000))
    for node in (0, 1, 2):
        residency.uploaded(node)
    residency.begin_frame()
    residency.use(0)
    residency.use(1)
    assert not residency.can_refine(1, visible=True, error_over_tau=2.0)
    plan = residency.plan()
    assert plan.evict == (2,) and plan.upload == (3,)


def test_visible_requests_come_before_hidden_ones_and_larger_errors_first():
    residency = Residency(child_offset=np.array([1, 3, 5, -1, -1, -1, -1]), child_count=np.array([2, 2, 2, 0, 0, 0, 0]),
                          depth=np.array([0, 1, 1, 2, 2, 2, 2]), node_bytes=np.array([10, 10, 10, 10, 10, 10, 10]),
                          settings=StreamingSettings(budget_bytes=40, upload_bytes_per_frame=1000))
    for node in (0, 1, 2):
        residency.uploaded(node)
    residency.begin_frame()
    for node in (0, 1, 2):
        residency.use(node)
    residency.can_refine(1, visible=False, error_over_tau=9.0)
    residency.can_refine(2, visible=True, error_over_tau=2.0)
    assert residency.plan().upload == (5,)  # room for one: a visible node's child, not the hidden one's


def test_streaming_settings_refuse_bad_budgets():
    for bad in (-1, 1.5, True):
        with pytest.raises(InputError):
            StreamingSettings(budget_bytes=bad)
    with pytest.raises(InputError):
        StreamingSettings.from_megabytes(float("nan"))
    assert StreamingSettings.from_megabytes(0).unlimited
    assert StreamingSettings.from_megabytes(2).budget_bytes == 2 << 20


# --- on the GPU --------------------------------------------------------------------------------------

@pytest.mark.gl
def test_budget_larger_than_the_file_draws_todays_frames(gl_ctx, city_hlod, path):
    """Counters and pixels equal to no budget, frame by frame: VFC, SW and Coh (scripted lag)."""
    whole = _file_bytes(city_hlod)
    for method, lag in (("vfc", None), ("sw", None), ("coh", LAG)):
        unlimited, _ = _run(gl_ctx, city_hlod, method, path, lag=lag)
        budgeted, _ = _run(gl_ctx, city_hlod, method, path, streaming=StreamingSettings(budget_bytes=2 * whole),
                           lag=lag)
        for (a, pixels_a, _), (b, pixels_b, resident) in zip(unlimited, budgeted):
            assert (a.dn, a.tris, a.queries, a.traversed, a.drawn) == (b.dn, b.tris, b.queries, b.traversed, b.drawn)
            assert np.array_equal(pixels_a, pixels_b), method
            assert b.substitutions == 0 and resident.all()


@pytest.mark.gl
@pytest.mark.parametrize("share", [8, 4])
def test_a_small_budget_holds_keeps_drawn_nodes_and_substitutes_ancestors(gl_ctx, city_hlod, path, share):
    """Under 1/share of the file: resident bytes never above the budget; every node drawn in a
    frame is resident after it (eviction never drops one); VFC's cut is the unlimited cut with some
    nodes replaced by an ancestor (never a finer node, never two overlapping nodes)."""
    budget = _file_bytes(city_hlod) // share
    unlimited, _ = _run(gl_ctx, city_hlod, "vfc", path)
    budgeted, _ = _run(gl_ctx, city_hlod, "vfc", path,
                       streaming=StreamingSettings(budget_bytes=budget, upload_bytes_per_frame=budget // 4))
    parent = city_hlod.parent
    substituted = 0
    for (full, _, _), (stats, _, resident) in zip(unlimited, budgeted):
        assert stats.resident_bytes <= budget
        assert resident[stats.drawn].all()
        drawn = set(stats.drawn)
        for node in full.drawn:  # each node of the full cut: drawn, or an ancestor stands in for it
            chain = [node]
            while chain[-1] > 0:
                chain.append(int(parent[chain[-1]]))
            assert len(drawn.intersection(chain)) == 1, node
        substituted += stats.substitutions
    assert substituted > 0  # the budget did hold something back
    assert budgeted[-1][0].dn >= 1


@pytest.mark.gl
def test_a_budget_of_one_node_still_draws_every_frame(gl_ctx, city_hlod, path):
    root_bytes = int(node_bytes(city_hlod, with_uv=False, with_colour=False)[0])
    frames, _ = _run(gl_ctx, city_hlod, "coh", path, streaming=StreamingSettings(budget_bytes=root_bytes), lag=LAG)
    background = np.full(3, 255, np.uint8)
    for stats, pixels, resident in frames:
        assert resident.sum() == 1 and resident[0]
        assert stats.resident_bytes == root_bytes
        if stats.dn:
            assert stats.drawn == [0] and (pixels != background).any()
    assert any(stats.dn for stats, _, _ in frames)


@pytest.mark.gl
def test_streamed_buffers_are_released_with_the_renderer(gl_ctx, city_hlod, path):
    budget = _file_bytes(city_hlod) // 4
    renderer = Renderer(gl_ctx, city_hlod, size=SIZE, streaming=StreamingSettings(budget_bytes=budget))
    try:
        _frames(city_hlod, renderer, "vfc", path)
        resident = int(renderer.residency.resident.sum())
        assert resident > 1 and len(renderer.streamed.gl_objects) >= 3 * resident - 3
    finally:
        renderer.release()
    assert renderer.streamed.gl_objects == () and not renderer.residency.resident.any()
    renderer.release()  # idempotent
