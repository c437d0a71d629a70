"""CHC++'s query stream (docs/how-it-works.md#multiqueries-and-query-batching): multiquery groups
by CHC++'s value rule, batched queries, and what they change and do not change in what is drawn.

Query results come back after a scripted lag (traversal_runs.Scripted: a number of issued
commands) and the skip test reads a fixed cost model (traversal_runs.LLVMPIPE_COSTS), so what a
traversal does never depends on llvmpipe's threads or the machine's load; the tests that run
the real renderer's own availability say so."""
import math

import numpy as np
import pytest

from helpers import street_path
from hlod_core.model.camera_path import inspection_path
from hlod_core.traversal.methods import make
from hlod_core.traversal.query_stream import keep_hidden, multiquery_groups
from hlod_core.traversal.settings import RuntimeSettings
from traversal_runs import LAG, SIZE, Scripted

pytestmark = pytest.mark.gl  # these tests draw with a real OpenGL context


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
    """(calls, per-frame FrameStats) of a new traversal over `paths` behind Scripted."""
    scripted = Scripted(renderer, lag)
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
    runs = [_scripted_run(city_renderer, method, settings=RuntimeSettings(multiquery=m, batch_queries="off"),
                          paths=paths, lag=0)
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
        _scripted_run(city_renderer, method, settings=RuntimeSettings(multiquery=m, batch_queries="off"),
                      paths=paths, lag=LAG)
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
        _scripted_run(city_renderer, "coh",
                      settings=RuntimeSettings(batch_queries=m, multiquery="off", skip_queries="off"),
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
        methods = make("coh", hlod, Scripted(city_renderer), settings=settings)
        stats[m] = [methods.frame(path.view(i, SIZE)) for i in range(len(path))]
    changes, queries = ({m: sum(getattr(s, c) for s in stats[m]) for m in stats} for c in ("state_changes", "queries"))
    assert changes["on"] < queries["on"] and changes["off"] >= 2 * queries["off"] > 0, (changes, queries)
    assert sum(s.multiqueries for s in stats["off"]) == 0
