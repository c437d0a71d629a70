"""The preview as an artist uses it: the HLOD drawn in place of the objects it was baked from. The
extension is built by Blender's tool and installed as Blender installs it (conftest.py's
fixtures); each check runs in its own bpy process (tests/blender/blender_preview_checks.py), where Blender's
own drawing is real (`GPUOffScreen.draw_view3d`). The corner text's wording is checked without Blender.
"""
import re
import sys

import pytest

from blender_runs import blender
from helpers import ROOT

sys.path.insert(0, str(ROOT))
from addon.preview import corner_text  # formatting only; blf is imported when drawing

KEY = re.compile(r"^[0-9a-f]{32}$")  # source_record.KEY_DIGEST_BYTES = 16
SOURCES = ["cube 0", "cube 1", "cube 2", "cube 3", "arrayed", "sphere instance 0", "sphere instance 1"]
OTHERS = ["wall", "ground", "HLOD test camera"]
NODES_COVER = 0.8  # share of the sources' pixels the nodes must cover (simplified nodes' outlines differ a little)


def preview_check(installed, check: str, tmp_path, *, timeout_s: float = 300) -> dict:
    """tests/blender/blender_preview_checks.py CHECK in `installed`'s Blender; its JSON result."""
    return blender(installed, check, tmp_path, timeout_s=timeout_s, script="blender_preview_checks.py")


def hidden_names(visibility: dict) -> list[str]:
    return sorted(name for name, (hidden, _selected, _hide_viewport, _visible) in visibility.items() if hidden)


@pytest.mark.gl
@pytest.mark.blender
def test_preview_draws_the_hlod_in_place_of_its_sources(versioned_repo, tmp_path):
    """On a baked row (subdivided and arrayed cubes, two collection instances of a sphere; a wall in
    front and a ground that are not baked), in every supported Blender: the bake records its seven
    objects with content keys; starting the preview hides the six that were visible (one the user
    had hidden stays as it was) through the view layer, not the objects' own hide_viewport, and
    records them with their selection; Blender's own drawing then lacks exactly the sources and the
    instances they make (pixel-equal to hiding them by hand), the nodes are drawn where the sources
    were and Blender's wall still hides them; the corner text appears in the bottom-left corner,
    and not when hidden; stopping gives back exactly the visibility, selection, active object and
    Blender's drawing there were; loading another file while the preview runs leaves that file as
    it was saved, and that file, reopened, knows the objects its bake took: the preview hides them."""
    out = preview_check(versioned_repo, "in_place", tmp_path)
    assert out["names"] == {"sources": SOURCES, "others": OTHERS} and out["bake"] == ["FINISHED"]
    assert [name for name, _ in out["record"]["sources"]] == SOURCES
    assert all(KEY.match(key) for _, key in out["record"]["sources"])
    assert len({key for _, key in out["record"]["sources"]}) == len(SOURCES)  # seven different objects
    assert out["record"]["source_file"].endswith("row.hlod") and out["record"]["hidden"] == []
    assert out["reference_state_same"]

    before, during = out["before"], out["during"]
    assert hidden_names(before) == ["arrayed"]  # hidden by the user before the preview
    assert out["toggle_on"] == ["FINISHED"] and out["running"]
    assert hidden_names(during) == sorted(SOURCES)
    for name in SOURCES:
        assert during[name] == [True, False, False, False], name  # hidden in the view layer, not hide_viewport
    assert {name: during[name] for name in OTHERS} == {name: before[name] for name in OTHERS}
    hidden_record = out["record_during"]["hidden"]
    assert hidden_record == [[name, before[name][1]] for name in SOURCES if name != "arrayed"]
    assert out["record_during"]["hidden_view_layer"] == "ViewLayer" and out["in_place"] == [7, 6]

    drawing = out["drawing"]
    assert drawing["source_pixels_before"] > 200 and drawing["source_pixels_during"] == 0
    assert drawing["during_equals_hidden_by_hand"]
    assert drawing["instance_pixel_before"] != drawing["instance_pixel_during"]  # the instance went with its empty
    assert drawing["wall_pixels"] > 500 and drawing["ramp_on_wall"] == 0 and drawing["wall_changed"] == 0
    assert drawing["ramp_pixels"] > 300
    assert drawing["ramp_where_sources_were"] >= NODES_COVER * drawing["source_pixels_before"]
    assert out["stats"]["drawn"] > 0 and out["stats"]["tris"] > 0

    assert re.fullmatch(r"HLOD Coh\(P\): \d+ nodes, [\d,]+ triangles \(\d+\.\d% of [\d,]+\)", out["text_lines"][0])
    assert re.fullmatch(r"\d+ queries, \d+\.\d ms", out["text_lines"][1])
    # the GPU budget (default 512 MB, larger than this file: every node resident)
    assert re.fullmatch(r"GPU \d+\.\d of 512 MB", out["text_lines"][2]) and len(out["text_lines"]) == 3
    assert out["text"]["in_corner"] > 500 and out["text"]["outside"] == 0
    assert 0 <= out["text"]["leftmost"] < 20  # left-aligned at the margin
    assert out["text_hidden"] == {"in_corner": 0, "outside": 0, "leftmost": -1}

    assert out["toggle_off"] == ["FINISHED"]
    assert out["after"] == before and out["active_after"] == out["active_before"]
    assert out["record_after"]["hidden"] == [] and out["record_after"]["hidden_view_layer"] == ""
    assert out["record_after"]["sources"] == out["record"]["sources"]
    assert out["after_equals_before_drawing"]
    assert not out["running_after_load"] and out["status_after_load"] == "off: a file was loaded"
    assert hidden_names(out["other_saved"]) == ["cube 2"]
    assert out["other_loaded"] == out["other_saved"] and out["other_record"]["hidden"] == []
    assert out["in_place_after_load"] == [0, 0]
    assert out["other_record"]["sources"] == out["record"]["sources"]  # saved with the .blend
    assert out["reopened_toggle_on"] == ["FINISHED"] and out["reopened_in_place"] == [7, 6]  # "cube 2" was hidden
    assert hidden_names(out["reopened_hidden"]) == sorted(SOURCES) and out["reopened_after"] == out["other_saved"]


@pytest.mark.blender
def test_every_way_out_of_the_preview_gives_the_visibility_back(repo, tmp_path):
    """Saving while the preview runs writes the sources visible with no record and hides them again
    in memory; undo and redo keep them hidden while the preview runs (the control: without the
    add-on's undo handler the step before the preview shows them), and with the preview stopped an
    undo step that holds them hidden is restored (the control: without the handler they come back
    hidden); disabling the extension shows them; a file written while the preview ran without the
    save handlers (an autosave, quit.blend before a crash) holds them hidden with the record, and
    opening it shows them again."""
    out = preview_check(repo, "restore_paths", tmp_path)
    before = out["before"]
    assert out["bake"] == ["FINISHED"] and hidden_names(before) == []
    hidden_all = sorted(SOURCES)

    def running_hidden(state):
        return state["running"] and hidden_names(state["visibility"]) == hidden_all and \
            [name for name, _ in state["hidden_record"]] == SOURCES and state["hidden_view_layer"] == "ViewLayer"

    def as_before(state):
        return state["visibility"] == before and state["hidden_record"] == [] and \
            state.get("hidden_view_layer", "") == ""

    assert running_hidden(out["running"])
    assert running_hidden(out["after_save"])  # hidden again after the write
    assert as_before(out["saved_file"])  # the file written while the preview ran
    assert running_hidden(out["undo_to_preview_on"]) and out["undo_to_preview_on"]["ground_z"] == pytest.approx(-0.01)
    assert running_hidden(out["undo_to_baked"])
    assert running_hidden(out["redo_to_ground_moved"])
    assert out["redo_to_ground_moved"]["ground_z"] == pytest.approx(-0.5)
    unhandled = out["undo_to_baked_unhandled"]
    assert unhandled["running"] and unhandled["visibility"] == before  # the step itself holds them visible
    assert running_hidden(out["redo_handled"])
    assert not out["stopped"]["running"] and as_before(out["stopped"])
    assert as_before(out["undo_after_stop"]) and out["undo_after_stop"]["ground_z"] == pytest.approx(-0.01)
    assert as_before(out["redo_after_stop"])
    control = out["undo_after_stop_unhandled"]
    assert hidden_names(control["visibility"]) == hidden_all and len(control["hidden_record"]) == len(SOURCES)
    assert out["hidden_before_disable"] == len(SOURCES)
    assert out["disabled"]["visibility"] == before and out["disabled"]["hidden_record"] == 0
    crash = out["crash_file"]
    assert hidden_names(crash["visibility"]) == hidden_all and [n for n, _ in crash["hidden_record"]] == SOURCES
    assert not out["crash_opened"]["running"] and as_before(out["crash_opened"])


@pytest.mark.blender
def test_sources_changed_since_the_bake_are_counted_and_rebaked(repo, tmp_path):
    """With the sources hidden, every kind of change moves the count the panel and the corner text
    show, and a transform put back exactly takes it down again; Re-bake bakes the recorded objects
    still there (the deleted and the renamed one are left out, the renamed one is shown again) and
    restarts the preview with nothing changed."""
    out = preview_check(repo, "stale", tmp_path)
    assert out["bake"] == ["FINISHED"]
    assert out["steps"] == [["start", 0], ["frame 10", 1], ["frame 1", 0], ["transform", 1], ["modifier", 2],
                            ["mesh edit", 3], ["instanced collection", 5], ["transform put back", 4], ["deleted", 5],
                            ["renamed", 6]]
    assert out["hidden_during"] and out["renamed_hidden"]
    assert out["stat_changed"] == 6
    assert out["message"] == "6 of 7 baked objects changed since the bake"
    assert out["corner_lines"][-1] == out["message"]
    assert out["rebake"] == ["FINISHED"] and out["running_after_rebake"]
    assert out["record_after_rebake"] == ["cube 0", "cube 1", "arrayed", "sphere instance 0", "sphere instance 1"]
    assert out["in_place_after_rebake"] == [5, 5] and out["changed_after_rebake"] == 0
    assert not out["renamed_after_rebake"]


class _Stats:
    dn, tris, queries, frame_ms, depth_import_ms = 12, 34_567, 21, 4.31, 0.0
    resident_bytes, waiting = 3 * 2**20 + 2**19, 0  # 3.5 MB on the GPU, nothing waiting
    queries_off, queries_note = 0, ""


def test_corner_text_lines():
    """Exact wording on literal inputs: the share of the sources' triangles (34,567 of 100,000 is
    34.6%), the private and CPU modes with the milliseconds of Blender's depth, and the warnings
    (changed sources; no record)."""
    assert corner_text.method_label("coh", "P") == "Coh(P)" and corner_text.method_label("vfc", "mu") == "VFC"
    lines = corner_text.corner_lines(label="Coh(P)", stats=_Stats, source_tris=100_000, where="",
                                       changed=0, recorded=144)
    assert lines == [("HLOD Coh(P): 12 nodes, 34,567 triangles (34.6% of 100,000)", False),
                     ("21 queries, 4.3 ms", False)]
    lines = corner_text.corner_lines(label="SW(mu)", stats=_Stats, source_tris=0, where="private context", changed=3,
                                     recorded=144)
    assert lines == [("HLOD SW(mu): 12 nodes, 34,567 triangles", False), ("21 queries, 4.3 ms, private context", False),
                     ("3 of 144 baked objects changed since the bake", True)]

    class Imported(_Stats):
        depth_import_ms = 1.26  # of frame_ms: Blender's depth read and handed to the CPU test

    lines = corner_text.corner_lines(label="Coh(P)", stats=Imported, source_tris=0, where="CPU occlusion test",
                                     changed=0, recorded=144)
    assert lines[1] == ("21 queries, 4.3 ms (depth 1.3 ms), CPU occlusion test", False)

    class Off(_Stats):  # the method's queries off (query_gate): why, under the timing
        queries_off, queries_note = 1, "queries off: they culled 0.8% of the triangles over 8 frames, cost 7.6%"

    lines = corner_text.corner_lines(label="Coh(P)", stats=Off, source_tris=0, where="", changed=0, recorded=144)
    assert lines[2] == (Off.queries_note, False) and len(lines) == 3
    assert corner_text.corner_lines(label="Full", stats=None, source_tris=10, where="", changed=None, recorded=0) == [
        ("HLOD Full: no frame drawn yet", False),
        ("sources not recorded for this file: they stay visible (re-bake)", True)]
    # under a GPU budget (64 MB): resident MB, and the nodes waiting when there are any
    lines = corner_text.corner_lines(label="Coh(P)", stats=_Stats, source_tris=0, where="", changed=0,
                                       recorded=144, budget_bytes=64 * 2**20)
    assert lines[-1] == ("GPU 3.5 of 64 MB", False)

    class Waiting(_Stats):
        waiting = 5

    lines = corner_text.corner_lines(label="Coh(P)", stats=Waiting, source_tris=0, where="", changed=0,
                                       recorded=144, budget_bytes=64 * 2**20)
    assert lines[-1] == ("GPU 3.5 of 64 MB, 5 nodes waiting", False)


@pytest.mark.blender
@pytest.mark.gl
def test_preview_streams_under_a_gpu_budget_and_converges(repo, tmp_path):
    """A budget below the file's node geometry, in the three drawing modes, camera held: the
    first frame already draws (coarser nodes stand in), resident bytes never exceed the budget, and
    the picture becomes the one drawn without a budget; the statistics and the corner text show the
    GPU memory."""
    out = preview_check(repo, "streaming", tmp_path)
    assert out["bake"] == ["FINISHED"] and out["toggle_on"] == ["FINISHED"] and out["sources_hidden"]
    for mode in ("gl", "private", "cpu"):
        run = out[mode]
        frames = run["frames"]
        assert 0 < run["budget"] < run["whole"], mode
        assert all(f["resident"] <= run["budget"] for f in frames), mode
        assert frames[0]["dn"] >= 1 and frames[0]["substitutions"] >= 1, mode  # held back at first
        assert frames[-1]["differing"] == 0 and frames[-1]["waiting"] == 0, (mode, frames)
        assert 0 < run["stat_resident_mb"] * 2**20 <= run["budget"] + 1, mode
        assert any(line.startswith("GPU ") and " MB" in line for line in run["corner"]), run["corner"]
