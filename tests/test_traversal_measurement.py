"""The measurements behind docs/performance.md's traversal figures, checked: the traversal's Python
time apart from the renderer's (tests/traversal_timing.py, benchmarks/traversal_cpu.py) and the
classes of the nodes Coh draws and SW does not (tests/dn_classes.py, benchmarks/dn_excess.py)."""
import time

import numpy as np
import pytest

import dn_classes
import traversal_timing
from helpers import street_path
from hlod_core.traversal.settings import RuntimeSettings
from traversal_runs import SIZE, ScriptedLatency

pytestmark = pytest.mark.gl  # these tests draw with a real OpenGL context


def test_dn_excess_classifies_each_extra_node_once():
    """dn_classes.classify (benchmarks/dn_excess.py) puts each node Coh draws and SW does not in one
    class: finer (SW drew an ancestor), hidden (SW found it hidden), under hidden (SW found an
    ancestor hidden), coarser (SW refined it), other; and counts what SW drew that Coh did not."""
    #        0
    #   1         2        8
    # 3   4     5   6
    #                 7
    parent = np.array([-1, 0, 0, 1, 1, 2, 2, 6, 0])
    visited = np.zeros(9, bool)
    visited[[0, 1, 2, 5, 6]] = True
    visible = visited.copy()
    visible[6] = False
    got = dn_classes.classify(parent, coh_drawn=[3, 6, 2, 7, 8], sw_drawn=[1, 5], sw_visited=visited,
                              sw_visible=visible)
    assert got == {"finer": 1, "hidden": 1, "coarser": 1, "under hidden": 1, "other": 1, "missing": 2}


def test_traversal_cpu_benchmark_leaves_the_renderer_out(city_renderer):
    """traversal_timing (benchmarks/traversal_cpu.py): the traversal's Python time per visited node
    excludes the time inside the renderer. Its clock here is this thread's CPU time plus a scripted
    offset: every draw of a slow renderer (real GL, then SCRIPTED_DRAW_S on that clock, no sleep)
    moves it on, so the renderer's share grows by exactly that per draw, and the Python time per
    node stays far below what one draw adds per node, whatever the machine's load. Results are
    fetched only when the traversal runs out of other work (ScriptedLatency), so both runs visit the
    same nodes."""
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
    late = ScriptedLatency(city_renderer)
    plain = traversal_timing.measure(city_renderer.hlod, "coh", path, settings=RuntimeSettings(), size=SIZE,
                                  renderer=late, call_overhead_s=traversal_timing.proxy_overhead_s(clock=clock),
                                  clock=clock)
    slow_renderer = SlowDraws(late)
    slow = traversal_timing.measure(city_renderer.hlod, "coh", path, settings=RuntimeSettings(), size=SIZE,
                                 renderer=slow_renderer, call_overhead_s=0.0, clock=clock)
    assert plain["visited"] > 10 and slow["visited"] == plain["visited"]
    scripted_ms = 1e3 * scripted_draw_s * slow_renderer.draws / slow["frames"]  # a frame's scripted draws
    assert slow_renderer.draws > 5 * slow["frames"]  # several draws a frame
    # the rest of the renderer's share is real GL work, milliseconds against the scripted seconds
    assert slow["renderer_ms"] - plain["renderer_ms"] == pytest.approx(scripted_ms, rel=0.05), (slow, plain)
    one_draw_us_per_node = 1e6 * scripted_draw_s / slow["visited"]  # what a single draw would add if counted
    assert 0 < slow["python_us_per_node"] < 0.01 * one_draw_us_per_node, (slow, one_draw_us_per_node)


def test_traversal_cpu_null_renderer_leaves_the_python_alone(city_hlod):
    """traversal_timing's NullRenderer (benchmarks/traversal_cpu.py --renderer null): the traversals
    run without GL (every query back at once, a seeded visibility per node), so two runs visit the
    same nodes; and the time inside the renderer is a small part of the traversal's (measured: about
    a sixth, asserted: below all of it). Timing is the subject of the second part: it is measured on
    this thread's CPU clock, which leaves out the time other processes hold the core, as the median
    of five repeats that alternate the methods, so one pause (a garbage collection) inside a
    renderer call cannot decide."""
    timed = traversal_timing.run(city_hlod, street_path(8), SIZE, methods=["coh", "bool"], repeat=5,
                              settings=RuntimeSettings(), clock="thread", null_renderer=True)
    again = traversal_timing.run(city_hlod, street_path(8), SIZE, methods=["coh", "bool"], repeat=1,
                              settings=RuntimeSettings(), null_renderer=True)
    for method in ("coh", "bool"):
        first, second = timed[method], again[method]
        assert first["visited"] == second["visited"] > 10
        frame_python_ms = first["python_us_per_node"] * first["visited"] / 1e3
        assert 0 < first["renderer_ms"] < frame_python_ms, first


def test_traversal_cpu_baseline_runs_another_version_side_by_side(city_hlod):
    """traversal_timing.baseline_traversal (benchmarks/traversal_cpu.py --baseline DIR) imports DIR's
    hlod_core as a package of its own and runs its traversal next to this one's on the same
    renderer: with this checkout as the baseline, both rows visit the same nodes (null renderer: no
    timing in what is visited)."""
    from pathlib import Path

    from hlod_core.traversal import methods
    baseline = traversal_timing.baseline_traversal(str(Path(__file__).resolve().parents[1]))
    assert baseline.methods.__name__ == "hlod_core_baseline.traversal.methods" and baseline.methods is not methods
    assert baseline.settings_type.__module__ == "hlod_core_baseline.traversal.settings"
    table = traversal_timing.run(city_hlod, street_path(6), SIZE, methods=["coh"], repeat=2, settings=RuntimeSettings(),
                              null_renderer=True, baseline=baseline)
    assert set(table) == {"coh", "coh (baseline)"}
    assert table["coh"]["visited"] == table["coh (baseline)"]["visited"] > 10
