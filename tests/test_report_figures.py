"""The evaluation report, legible at a glance: figure labels that do not overlap, by
matplotlib's own text extents, on the committed report's data and on literal worst cases; the
Pareto front; per-frame ratios with a colour and a line style per method and the camera path's
parts marked; the queries-pay figure; report.html as one self-contained page; the parts in the
camera path format."""
import base64
import json

import numpy as np
import pytest

from figure_checks import PNG_SIGNATURE, drawn_texts, legible
from helpers import ROOT, SCENES
from hlod_core.core.errors import InputError
from hlod_core.model.camera_path import load_path, path_from_json
from hlod_core.report import evaluate, figure_style, figures, html_page, per_frame_figure
from hlod_core.traversal.stats import COUNTERS

COMMITTED = ROOT / "docs" / "evaluation"


def _row(frame_ms: float, rmse: float) -> dict:
    return {"frame_ms": frame_ms, "rmse_y_vs_full": rmse, "dn": 1.0}


def _close(fig):
    import matplotlib.pyplot as plt

    plt.close(fig)


# --- error against frame time ---------------------------------------------------------------------

def test_error_vs_time_labels_do_not_overlap_on_the_committed_report():
    """docs/evaluation/report.json, whatever run it holds: every method and sweep point is labelled,
    no two drawn texts overlap, every label lies inside the axes, and Full (the reference, RMSE 0)
    does not set the scale: the frame-time axis ends near the slowest other point."""
    report = json.loads((COMMITTED / "report.json").read_text())
    fig = figures.error_vs_time_figure(report, labels=evaluate.LABELS)
    texts = drawn_texts(fig)
    shown = [t for t, _ in texts]
    others = {k: r for k, r in report["methods"].items() if k != "full"} | (report["sweep"] or {}).get("points", {})
    names = {figure_style.display_name(key, evaluate.LABELS) + (" (bound)" if key == "ideal" else "")
             for key in others}
    assert names <= set(shown), names - set(shown)
    assert legible(fig) == []
    ax = fig.axes[0]
    frame = ax.get_window_extent()
    for text, box in texts:
        if text in names:
            assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1, text
    slowest = max(r["frame_ms"] for r in others.values())
    fastest = min(r["frame_ms"] for r in others.values())
    assert ax.get_xlim()[1] <= slowest + 0.5 * (slowest - fastest)
    assert any(t.startswith("Full, the reference (RMSE 0)") for t in shown)
    _close(fig)


def test_error_vs_time_labels_do_not_overlap_when_points_coincide():
    """The worst case for labels: every method and four sweep values at one point (two exactly
    equal), Full far off. A fixed offset puts every label on the same spot; the placement measures
    each label and finds free room for all."""
    methods = {k: _row(20.0 + 1e-3 * i, 3.0 + 1e-3 * (i % 3)) for i, k in enumerate(evaluate.METHOD_SPECS)}
    methods["full"] = _row(100.0, 0.0)
    methods["coh_p_alg4"] = methods["coh_p"]
    sweep = {f"coh_p tau={t:g}": _row(20.0, 3.0) | {"value": t} for t in evaluate.SWEEPS["tau"]}
    report = {"methods": methods, "sweep": {"name": "tau", "points": sweep}}
    fig = figures.error_vs_time_figure(report, labels=evaluate.LABELS)
    texts = drawn_texts(fig)
    assert legible(fig) == []
    assert {"Coh(P) tau=0.5", "Coh(P) tau=4", "Bool", "Ideal (bound)"} <= {t for t, _ in texts}
    _close(fig)


def test_pareto_front_on_literal_points():
    """(time, error): b beats c on error at the same time, d ties b's error but is slower, so
    neither is on the front; a (fastest) and e (exact) are."""
    points = {"a": (1.0, 5.0), "b": (2.0, 3.0), "c": (2.0, 4.0), "d": (3.0, 3.0), "e": (4.0, 0.0)}
    assert figures.pareto_front(points) == ["a", "b", "e"]
    assert figures.pareto_front({"only": (1.0, 1.0)}) == ["only"]


# --- per frame ------------------------------------------------------------------------------------

def _literal_medians(frames: int) -> dict:
    """Per-frame counters with known ratios: SW(P) draws 10 nodes, Bool 12 (1.2 x), Coh(P) 11 (1.1 x)
    and the rest 10 + their index; Ideal takes 5 ms, Bool 10 (2 x), Coh(P) 7.5 (1.5 x)."""
    dn, ms = COUNTERS.index("dn"), COUNTERS.index("frame_ms")
    out = {}
    for i, key in enumerate(list(evaluate.METHOD_SPECS) + ["coh_p s,t=0.6,0.2", "coh_p s,t=0.7,0.15"]):
        m = np.zeros((frames, len(COUNTERS)))
        m[:, dn], m[:, ms] = 10.0 + i, 6.0 + i
        out[key] = m
    for key, nodes, time_ms in (("sw_p", 10.0, 8.0), ("bool", 12.0, 10.0), ("coh_p", 11.0, 7.5), ("ideal", 10.0, 5.0),
                                ("full", 400.0, 90.0), ("vfc", 30.0, 6.0)):
        out[key][:, dn], out[key][:, ms] = nodes, time_ms
    return out


def test_per_frame_ratios_styles_and_parts():
    """Drawn nodes / SW(P)'s and frame time / Ideal's for the methods that query (40 frames: no
    smoothing), Full and VFC only in their own panels, every curve its own colour and line style,
    the path's parts named on the frame axis, and no two texts overlapping."""
    frames = 40
    medians = _literal_medians(frames)
    report = {"methods": {k: {} for k in evaluate.METHOD_SPECS}, "frames": frames,
              "sweep": {"name": "st", "points": {"coh_p s,t=0.6,0.2": {}, "coh_p s,t=0.7,0.15": {}}},
              "parts": [{"name": "orbit", "start": 0}, {"name": "walk", "start": 10}, {"name": "turn", "start": 25},
                        {"name": "dolly", "start": 31}]}
    fig = per_frame_figure.per_frame_figure(report, medians, labels=evaluate.LABELS)
    nodes_ax, time_ax, full_nodes_ax, full_time_ax = fig.axes[:4]

    def curve(ax, key):
        colour = figure_style.style(key, list(report["sweep"]["points"]))["color"]
        found = [line.get_ydata() for line in ax.get_lines()
                 if line.get_color() == colour and len(line.get_ydata()) == frames]
        return found[0] if found else None

    assert np.allclose(curve(nodes_ax, "bool"), 1.2) and np.allclose(curve(nodes_ax, "coh_p"), 1.1)
    assert np.allclose(curve(time_ax, "bool"), 2.0) and np.allclose(curve(time_ax, "coh_p"), 1.5)
    assert np.allclose(curve(nodes_ax, "sw_p"), 1.0) and np.allclose(curve(time_ax, "ideal"), 1.0)  # the references
    for key in ("full", "vfc"):
        assert curve(nodes_ax, key) is None and curve(time_ax, key) is None, key
    assert np.allclose(curve(full_nodes_ax, "full"), 400.0) and np.allclose(curve(full_time_ax, "vfc"), 6.0)
    legend = fig.legends[0]
    names = [t.get_text() for t in legend.get_texts()]
    assert sorted(names) == sorted([evaluate.LABELS[k] for k in evaluate.METHOD_SPECS]
                                   + ["Coh(P) s,t=0.6,0.2", "Coh(P) s,t=0.7,0.15"])
    # each curve drawn in its method's style (whose colours and dashes all differ: the next test)
    sweep = list(report["sweep"]["points"])
    by_name = {figure_style.display_name(k, evaluate.LABELS): k for k in medians}
    for handle, name in zip(legend.legend_handles, names):
        assert handle.get_color() == figure_style.style(by_name[name], sweep)["color"], name
    texts = drawn_texts(fig)
    assert {"orbit", "walk", "turn", "dolly"} <= {t for t, _ in texts}
    assert legible(fig) == []
    _close(fig)


def test_every_method_and_sweep_point_has_its_own_style():
    """Colours, dash patterns and markers all differ across the 11 methods and up to 4 sweep values."""
    sweep = [f"coh_p tau={t:g}" for t in evaluate.SWEEPS["tau"]]
    styles = [figure_style.style(k, sweep) for k in list(evaluate.METHOD_SPECS) + sweep]
    for field in ("color", "linestyle", "marker"):
        values = [str(s[field]) for s in styles]
        assert len(set(values)) == len(values), field


def test_running_median_on_literal_values():
    """Window 3: a one-frame spike goes, a step stays; all-NaN windows stay NaN; window 1 is the identity."""
    values = np.array([0.0, 0.0, 9.0, 0.0, 0.0, 5.0, 5.0, 5.0])
    assert per_frame_figure.running_median(values, 3).tolist() == [0, 0, 0, 0, 0, 5, 5, 5]
    gap = np.array([1.0, np.nan, np.nan, np.nan, 3.0])
    smoothed = per_frame_figure.running_median(gap, 3)
    assert smoothed[0] == 1.0 and np.isnan(smoothed[2]) and smoothed[4] == 3.0
    assert per_frame_figure.running_median(values, 1) is values
    assert per_frame_figure.smoothing_window(1020) == 13 and per_frame_figure.smoothing_window(60) == 1


# --- when do queries pay --------------------------------------------------------------------------

def test_queries_pay_figure_on_the_committed_results():
    """docs/evaluation/queries_pay.json (benchmarks/queries_pay.py): the low, middle and high scenes
    side by side, each bar a method's frame time or drawn nodes over VFC's as the JSON records it,
    no two texts overlapping."""
    results = json.loads((COMMITTED / "queries_pay.json").read_text())
    assert list(results["scenes"]) == ["low", "middle", "high"]
    fig = figures.queries_pay_figure(results, labels=evaluate.LABELS)
    keys = [k for k in results["methods"] if k != "vfc"]
    for ax, counter in zip(fig.axes[:2], ("frame_ms", "dn")):
        heights = [p.get_height() for p in ax.patches]
        expected = [results["scenes"][n]["relative_to_vfc"][k][counter] for k in keys for n in results["scenes"]]
        assert np.allclose(heights, expected), counter
    texts = drawn_texts(fig)
    assert sum(t.startswith(("low depth", "middle depth", "high depth")) for t, _ in texts) == 3
    assert legible(fig) == []
    _close(fig)


# --- report.html ----------------------------------------------------------------------------------

def test_report_html_renders_the_markdown_subset(tmp_path):
    """Headings, a right-aligned table cell, inline code and emphasis, HTML escaped, an image line
    with its caption inlined as a data URI, and a note where a figure's file is missing."""
    png = PNG_SIGNATURE + b"not really a picture"
    (tmp_path / "a.png").write_bytes(png)
    text = ("# Title <1>\n\nSome `code` and **bold**, a < b.\n\n## Table\n\n| method | ms |\n|---|---:|\n"
            "| Coh(P) | 1.5 |\n\n![first](a.png)\n\n*What to see in it.*\n\n![second](missing.png)\n")
    page = html_page.render(text, folder=tmp_path)
    assert "<title>Title &lt;1&gt;</title>" in page and "<h2>Table</h2>" in page
    assert "<code>code</code>" in page and "<strong>bold</strong>" in page and "a &lt; b" in page
    assert '<td>Coh(P)</td><td class="num">1.5</td>' in page
    uri = "data:image/png;base64," + base64.b64encode(png).decode()
    assert f'<img src="{uri}" alt="first"><figcaption>What to see in it.</figcaption>' in page
    assert "(figure missing.png is missing from" in page
    assert "http://" not in page and "https://" not in page


# --- the camera path's parts ----------------------------------------------------------------------

def test_crowd_paths_name_their_parts():
    """The README's evaluation paths carry their four parts (tests/scenes/generate_specs.py)."""
    inspection = load_path(SCENES / "crowd_inspection_path.json")
    assert inspection.parts == (("orbit", 0), ("walk", 180), ("turn", 540), ("dolly", 780)) and len(inspection) == 1020
    walk = load_path(SCENES / "crowd_walk_path.json")
    assert walk.parts == (("orbit", 0), ("walk", 80), ("turn", 160), ("dolly", 240)) and len(walk) == 320


def test_parts_round_trip_and_old_files_load(tmp_path):
    frame = {"eye": [0, -3, 1], "target": [0, 0, 0], "up": [0, 0, 1]}
    data = {"near": 0.1, "far": 10.0, "frames": [frame] * 5,
            "parts": [{"name": "a", "start": 0}, {"name": "b", "start": 3}]}
    path = path_from_json(data, source="p.json")
    assert path.parts == (("a", 0), ("b", 3))
    path.save(tmp_path / "p.json")
    assert load_path(tmp_path / "p.json").parts == path.parts
    old = path_from_json({k: v for k, v in data.items() if k != "parts"}, source="old.json")
    assert old.parts == () and "parts" not in old.to_json()


@pytest.mark.parametrize("parts, expect", [
    ({"name": "a"}, r'"parts" must be a list of \{name, start\}, got an object'),
    (["orbit"], r'parts\[0\] must be an object with name and start, got the string "orbit"'),
    ([{"name": "a", "start": 0, "end": 2}], r'parts\[0\] has unknown key "end"'),
    ([{"name": "", "start": 0}], r"parts\[0\].name must be a string of 1 to 40 characters"),
    ([{"name": "a", "start": 1}], r"parts\[0\].start must be 0 \(the first part starts the path\), got 1"),
    ([{"name": "a", "start": 0}, {"name": "b", "start": 0}], r"parts\[1\].start must be in 1..4"),
    ([{"name": "a", "start": 0}, {"name": "b", "start": 5}], r"parts\[1\].start must be in 1..4 .*got 5"),
    ([{"name": "a", "start": 0.0}], r"parts\[0\].start must be a whole number \(a frame index\), got 0.0"),
    ([{"name": "a", "start": True}], r"parts\[0\].start must be a whole number \(a frame index\), got true"),
])
def test_bad_parts_are_one_line_input_errors(parts, expect):
    frame = {"eye": [0, -3, 1], "target": [0, 0, 0]}
    with pytest.raises(InputError, match=r"^p\.json: " + expect):
        path_from_json({"frames": [frame] * 5, "parts": parts}, source="p.json")
