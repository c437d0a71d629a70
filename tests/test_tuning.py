"""Tuning to an image-quality target (hlod_core/report/tuning.py, `evaluate --psnr-target DB`): the
(s, t) with the fewest drawn nodes whose lowest PSNR-Y against Bool over the PSNR frames reaches the
target, the curve of the candidates tried in report.json / report.md / psnr_target.png, the fallback
when nothing reaches it, and the option's bad values.

Real parts: the high-depth-complexity scene at a quarter of its towers, baked with small nodes, drawn
by the real renderer on a headless EGL context (llvmpipe where there is no GPU), 10 frames at 320x240.
Every query is issued (skip queries off): which nodes are drawn does not depend on the renderer's
measured costs."""
import json
import math
from dataclasses import replace

import pytest

from figure_checks import PNG_SIGNATURE
from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.cli import main as cli
from hlod_core.core.errors import InputError
from hlod_core.io import hlod_file, procedural
from hlod_core.model.camera_path import inspection_path
from hlod_core.report import tuning
from hlod_core.traversal.settings import RuntimeSettings
from processes import hlod, last_json, one_line_error

FRAMES, SIZE = 10, (320, 240)
#: No query skipped for its measured cost: the drawn nodes do not depend on the machine's timing.
QUERY_EVERY_NODE = RuntimeSettings(skip_queries="off")
CANDIDATE_KEYS = {"s", "t", "dn", "psnr_y", "psnr_y_mean", "frame_ms", "frame_ms_vs_bool", "round", "meets"}


@pytest.fixture(scope="module")
def downtown(tmp_path_factory):
    """(the baked file, its Hlod, the seeded 10-frame inspection path the command generates)."""
    baked_file = tmp_path_factory.mktemp("tuning") / "downtown.hlod"
    hlod_file.save(bake(procedural.high_scene(seed=1, scale=0.5), BakeSettings(target_tris=200)), baked_file)
    baked = hlod_file.load(baked_file)
    return baked_file, baked, inspection_path(baked, seed=1, frames=FRAMES)


def _candidate(s, t, dn, psnr_y):
    return tuning.Candidate(s=s, t=t, dn=dn, psnr_y=psnr_y, psnr_y_mean=psnr_y, frame_ms=1.0, frame_ms_vs_bool=1.0,
                            round=0)


def test_choose_on_literal_candidates():
    """The fewest nodes among those at or above the target (the bound is inclusive), ties to the higher
    PSNR; nothing at the target: the most conservative (1, 0), marked as not met."""
    tried = [_candidate(1.0, 0.0, 50.0, 100.0), _candidate(1.0, 0.3, 30.0, 35.0), _candidate(0.5, 0.2, 32.0, 40.0),
             _candidate(0.9, 0.1, 32.0, 41.0), _candidate(0.0, 0.0, 28.0, 30.0)]
    assert tuning.choose(tried, 40.0) == (tried[3], True)  # 32 nodes at 41 dB beats 32 at 40
    assert tuning.choose(tried, 35.0) == (tried[1], True)
    assert tuning.choose(tried, 0.0) == (tried[4], True)
    assert tuning.choose(tried[1:] + tried[:1], 100.0) == (tried[0], True)  # identical to Bool: 100 dB meets 100
    assert tuning.choose([_candidate(1.0, 0.0, 50.0, 60.0)] + tried[1:], 70.0) == (_candidate(1.0, 0.0, 50.0, 60.0),
                                                                                 False)
    with pytest.raises(ValueError, match=r"\(1.0, 0.0\) was not measured"):
        tuning.choose(tried[1:], 90.0)
    # the bisection's bound: 11 values of t and "none" are 12 gaps, 4 halvings a line
    assert tuning.STEPS_PER_LINE == 4 and tuning.MAX_CANDIDATES == 1 + 5 * 4


def _check_choice(p: dict) -> None:
    """The chosen candidate meets the target and no candidate tried that meets it draws fewer nodes;
    each line of s took at most STEPS_PER_LINE candidates, and the total stays within the bound."""
    assert p["candidates"] and all(CANDIDATE_KEYS <= x.keys() for x in p["candidates"])
    chosen = p["chosen"]
    assert chosen["psnr_y"] >= p["target_db"] and p["met"]
    meeting = [x for x in p["candidates"] if x["psnr_y"] >= p["target_db"]]
    assert all(x["meets"] == (x["psnr_y"] >= p["target_db"]) for x in p["candidates"])
    assert chosen["dn"] == min(x["dn"] for x in meeting)
    assert any((x["s"], x["t"], x["dn"]) == (chosen["s"], chosen["t"], chosen["dn"]) for x in meeting)
    for s in tuning.S_LINES:
        assert sum(x["s"] == s for x in p["candidates"]) <= tuning.STEPS_PER_LINE
    assert len(p["candidates"]) <= tuning.MAX_CANDIDATES and p["search"]["rounds"] <= tuning.MAX_ROUNDS
    assert [x for x in p["candidates"] if x["s"] == 0.0] == [p["candidates"][len(tuning.S_LINES)]]  # once, in round 1


@pytest.mark.gl
def test_evaluate_psnr_target_meets_it_with_the_fewest_nodes(downtown, tmp_path):
    """The command: the last stdout line names the chosen s and t; report.json holds the curve, and
    Bool and Coh(P) at the chosen (s, t) from the same round; report.md its table; psnr_target.png."""
    baked_file, _, _ = downtown
    out = tmp_path / "report"
    proc = hlod("-q", "evaluate", baked_file, "--out", out, "--frames", FRAMES, "--size", "320x240", "--repeat", "1",
                "--psnr-frames", FRAMES, "--psnr-target", "40", "--skip-queries", "off")
    line = last_json(proc)
    report = json.loads((out / "report.json").read_text())
    p = report["psnr_target"]
    _check_choice(p)
    assert line["psnr_target"] == {"target_db": 40.0, "met": True, "s": p["chosen"]["s"], "t": p["chosen"]["t"],
                                   "dn": p["chosen"]["dn"], "psnr_y": p["chosen"]["psnr_y"],
                                   "candidates": len(p["candidates"])}
    assert (report["settings"]["s"], report["settings"]["t"]) == (p["chosen"]["s"], p["chosen"]["t"])
    assert set(report["methods"]) == set(line["methods"]) == {"bool", "coh_p"}
    assert report["methods"]["coh_p"]["dn"] == p["chosen"]["dn"]
    assert report["methods"]["coh_p"]["psnr_y_vs_bool"] == pytest.approx(p["chosen"]["psnr_y_mean"])
    # the query gate runs in the search as in the evaluation: its share of frames without queries
    assert all(0.0 <= report["methods"][k]["queries_off"] <= 1.0 for k in ("bool", "coh_p"))
    md = (out / "report.md").read_text()
    assert "## Tuned to PSNR-Y >= 40 dB against Bool" in md
    rows = [r for r in md.splitlines() if r.startswith("| ") and r.endswith(("| yes |", "| no |", "(chosen) |"))]
    assert len(rows) == len(p["candidates"]) and sum("(chosen)" in r for r in rows) == 1
    assert (out / "psnr_target.png").read_bytes().startswith(PNG_SIGNATURE)
    assert report["figures"]["drawn nodes against PSNR-Y, tuned to a target"] == "psnr_target.png"
    assert "<td>yes (chosen)</td>" in (out / "report.html").read_text()


@pytest.mark.gl
def test_zero_db_picks_the_fewest_nodes_and_needs_no_matplotlib(downtown, tmp_path):
    """0 dB: every candidate meets it (PSNR >= 0 always); the one with the fewest nodes is chosen.
    Without figures (as in Blender) the report is complete and says why there are none."""
    _, baked, path = downtown
    report = tuning.tune(baked, path, SIZE, target_db=0.0, settings=QUERY_EVERY_NODE, out_dir=tmp_path,
                         psnr_frames=FRAMES, figures=False)
    p = report["psnr_target"]
    _check_choice(p)
    assert all(x["meets"] for x in p["candidates"])
    assert p["chosen"]["dn"] == min(x["dn"] for x in p["candidates"])
    # every line climbs to t = 1 (each halving finds the target met)
    assert {x["t"] for x in p["candidates"] if x["s"] > 0} == {0.15, 0.5, 0.7, 1.0}
    md = (tmp_path / "report.md").read_text()
    assert report["figures"] == {} and "No figures" in md and "matplotlib" in md
    assert not (tmp_path / "psnr_target.png").exists() and "## Tuned to PSNR-Y >= 0 dB" in md


@pytest.mark.gl
def test_unreachable_target_gives_the_most_conservative_setting(downtown, tmp_path):
    """A target above every candidate's PSNR: not met, and the result is (s, t) = (1, 0), the largest
    P of all (s, t), reported as such. With the logistic (k = 10) no setting draws Bool's image
    exactly, so 100 dB (identical at every PSNR frame) is above them all."""
    _, baked, path = downtown
    report = tuning.tune(baked, path, SIZE, target_db=100.0, settings=replace(QUERY_EVERY_NODE, k=10.0),
                         out_dir=tmp_path, psnr_frames=FRAMES, figures=False)
    p = report["psnr_target"]
    assert max(x["psnr_y"] for x in p["candidates"]) < 100.0, "a candidate equals Bool: the fallback is not reached"
    assert not p["met"] and (p["chosen"]["s"], p["chosen"]["t"]) == tuning.MOST_CONSERVATIVE
    assert not any(x["meets"] for x in p["candidates"])
    # every line bisects down to t = 0, where the s = 1 line is the fallback
    assert {x["t"] for x in p["candidates"]} == {0.0, 0.02, 0.15}
    assert "only Bool's own image (the reference) does" in p["note"] and "P = S_0(mu)" in p["note"]
    assert (report["settings"]["s"], report["settings"]["t"], report["settings"]["k"]) == (1.0, 0.0, 10.0)
    assert "**Target not met.**" in (tmp_path / "report.md").read_text()


@pytest.mark.parametrize("value, expect", [
    ("-1", "got -1"), ("nan", "got nan"), ("100.5", "got 100.5"), ("inf", "got inf"), ("forty", "got 'forty'"),
    ("", "got ''"),
])
def test_bad_psnr_target_is_one_line(capsys, value, expect):
    """Refused by the parser before anything is read: exit 2, one line naming the option."""
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["evaluate", "missing.hlod", "--out", "r", "--psnr-target", value])
    out, err = capsys.readouterr()
    assert exit_info.value.code == 2 and out == ""
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("hlod_core: error: argument --psnr-target: ") and expect in lines[0]
    assert "[0, 100]" in lines[0] or "a number of dB" in lines[0]


def test_psnr_target_with_methods_is_one_line(downtown, tmp_path):
    baked_file, _, _ = downtown
    line = one_line_error(hlod("evaluate", baked_file, "--out", tmp_path / "r", "--psnr-target", "40", "--methods",
                               "bool", check=False))
    assert "--psnr-target runs Bool and the Coh(P) candidates only; leave out --methods" in line
    assert not (tmp_path / "r").exists()


def test_check_target_accepts_the_range_only():
    assert tuning.check_target("0") == 0.0 and tuning.check_target(100) == 100.0
    for bad in (-1e-9, 100.000001, math.nan, "x", None):
        with pytest.raises(InputError, match="PSNR target: expected"):
            tuning.check_target(bad)
