"""The command-line contract: last stdout line is one JSON object; bad input exits non-zero with
one line naming the file; an interrupted bake leaves nothing behind."""
import json
import os
import signal
import subprocess
import sys

import pytest

import models
from helpers import ROOT, model
from hlod_core.bake import settings as bake_settings_module
from hlod_core.cli.main import build_parser
from hlod_core.cli.options import bake_settings_of
from hlod_core.core.errors import InputError
from processes import hlod, last_json, one_line_error, write_text

BAKE_KEYS = {"nodes", "leaves", "depth", "input_tris", "leaf_tris", "root_tris", "max_error", "seconds",
             "tris_per_second"}
ALL_TRUE = {"leaf_tris_equal_input": True, "nested_bounds": True, "monotone_error": True, "leaf_budget": True}


def test_help_names_the_program_as_it_was_run_and_the_docs_page(tmp_path):
    """`python -m hlod_core --help` and the installed script (here a copy of pip's entry-point
    script under its name) each say their own name in the usage; the help points to the page that
    holds every option."""
    module = subprocess.run([sys.executable, "-m", "hlod_core", "--help"], capture_output=True, text=True, check=True)
    assert module.stdout.startswith("usage: python -m hlod_core [-h]")
    assert "docs/command-line.md" in module.stdout and "README" not in module.stdout
    script = write_text(tmp_path / "hlod-core", "import sys\nfrom hlod_core.cli.main import main\nsys.exit(main())\n")
    run = subprocess.run([sys.executable, str(script), "evaluate", "--help"], capture_output=True, text=True,
                         check=True)
    assert run.stdout.startswith("usage: hlod-core evaluate [-h]")
    assert "README" not in run.stdout and "docs/command-line.md#camera-paths" in run.stdout
    bad = subprocess.run([sys.executable, str(script), "run"], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.strip().endswith("(see hlod-core run --help)")


@pytest.mark.parametrize("cores, expected", [(1, 1), (2, 1), (8, 7)])
def test_jobs_0_is_all_cores_but_one(monkeypatch, cores, expected):
    """One rule for every front end (bake.settings.resolve_jobs, which the extension's settings
    and its background command call too): 0 = the cores this process may use but one, at least 1;
    any other count is kept; a negative one is refused."""
    monkeypatch.setattr(bake_settings_module, "usable_cores", lambda: cores)
    assert bake_settings_module.resolve_jobs(0) == expected and bake_settings_module.resolve_jobs(3) == 3
    args = build_parser().parse_args(["bake", "a.obj", "-o", "x.hlod", "--jobs", "0"])
    assert bake_settings_of(args).jobs == expected
    with pytest.raises(InputError, match="all cores but one"):
        bake_settings_module.resolve_jobs(-1)


def test_bake_scene_spec_and_info(tmp_path):
    spec = tmp_path / "spec.json"
    rel = os.path.relpath(model("cow"), tmp_path)
    spec.write_text(json.dumps({"models": [
        {"path": rel, "transforms": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1],
                                     [-1, 0, 0, 5, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]]},
        {"path": str(model("teapot"))}]}))
    out = tmp_path / "scene.hlod"
    summary = last_json(hlod("bake", spec, "-o", out, "--target-tris", "1000", "--jobs", "2"))
    assert BAKE_KEYS <= summary.keys()
    assert summary["input_tris"] == 2 * 5804 + 6320 == summary["leaf_tris"]
    info = last_json(hlod("info", out))
    assert info["checks"] == ALL_TRUE
    keys = ("nodes", "leaves", "input_tris")
    assert {k: info[k] for k in keys} == {k: summary[k] for k in keys}


def test_several_inputs_merge_into_one_scene(tmp_path):
    out = tmp_path / "two.hlod"
    summary = last_json(hlod("bake", model("cow"), model("spot"), "-o", out))
    assert summary["input_tris"] == 5804 + 5856


@pytest.mark.slow
def test_million_triangle_instanced_spec_passes_every_check(tmp_path):
    out = tmp_path / "gallery.hlod"
    summary = last_json(hlod("-q", "bake", models.scene("gallery_1m"), "-o", out, "--jobs", "2"))
    assert summary["input_tris"] >= 1_000_000
    info = last_json(hlod("info", out))
    assert info["checks"] == ALL_TRUE, info


def test_default_scene_command(tmp_path):
    summary = last_json(hlod("-q", "scene", "default", "-o", tmp_path / "d.hlod", "--scale", "0.5"))
    assert summary["input_tris"] > 0 and summary["scene"] == "default"
    assert last_json(hlod("info", tmp_path / "d.hlod"))["checks"] == ALL_TRUE


@pytest.mark.parametrize("make, expect", [
    (lambda d: d / "missing.obj", r"missing\.obj: no such file"),
    (lambda d: write_text(d / "garbage.obj", "this is not a mesh\n"),
     r"garbage\.obj: (cannot read mesh|the mesh has no triangles)"),
    (lambda d: write_text(d / "nan.obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n"), r"nan\.obj: 1 of 3 vertices .*NaN"),
    (lambda d: write_text(d / "inf.obj", "v 0 0 0\nv 1 0 0\nv inf 1 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n"),
     r"inf\.obj: 1 of 4 vertices could not be read"),
    (lambda d: write_text(d / "bad.json", "{not json"), r"bad\.json: scene spec is not valid JSON"),
    (lambda d: write_text(d / "spec.json", json.dumps({"models": [{"path": "x.obj"}]})), r"x\.obj: no such file"),
    (lambda d: write_text(d / "spec2.json",
                          json.dumps({"models": [{"path": str(model("cow")), "transforms": [[1, 2, 3]]}]})),
     r"spec2\.json: models\[0\]\.transforms\[0\] must have 16 numbers"),
    (lambda d: write_text(d / "notes.txt", "hello"), r"notes\.txt: unsupported file type"),
])
def test_bad_input_is_one_line_naming_the_file(tmp_path, make, expect):
    import re
    bad = make(tmp_path)
    proc = hlod("bake", bad, "-o", tmp_path / "out.hlod", check=False)
    line = one_line_error(proc)
    assert re.search(expect, line), line
    assert not (tmp_path / "out.hlod").exists()


def test_info_on_foreign_file_is_one_line(tmp_path):
    bad = write_text(tmp_path / "x.hlod", "v 0 0 0\n")
    assert "x.hlod: not a .hlod file" in one_line_error(hlod("info", bad, check=False))


def test_unwritable_output_is_one_line(tmp_path):
    blocker = write_text(tmp_path / "file", "")
    proc = hlod("bake", model("cow"), "-o", blocker / "out.hlod", check=False)
    assert f"{blocker} is a file" in one_line_error(proc)
    assert "bake" not in proc.stderr  # refused before baking


def test_interrupted_bake_leaves_no_output_and_keeps_the_old_file(tmp_path):
    out = tmp_path / "statue.hlod"
    out.write_bytes(b"previous result")
    proc = subprocess.Popen([sys.executable, "-m", "hlod_core", "bake", str(model("statue")), "-o", str(out),
                             "--jobs", "2"], cwd=ROOT, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT), "TMPDIR": str(tmp_path)})
    for line in proc.stderr:  # decimation is under way: the signal comes mid-bake (no sleep: any moment will do)
        if "bake simplify" in line:
            break
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=120)
    assert proc.returncode != 0
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["statue.hlod"]


RUN_KEYS = {"dn", "rarn", "d", "tris", "queries", "traversed", "stall_ms", "cpu_ms", "gpu_ms", "frame_ms", "frames"}


@pytest.mark.gl
@pytest.mark.parametrize("method", ["full", "vfc", "bool", "sw", "simp", "coh", "ideal"])
def test_run_every_method(cow_file, method):
    out = last_json(hlod("-q", "run", cow_file, "--method", method, "--frames", "6", "--size", "160x120"))
    assert RUN_KEYS <= out.keys() and out["frames"] == 6 and out["dn"] > 0


@pytest.mark.gl
def test_run_with_a_path_file_orthographic_and_saved_frames(cow_file, tmp_path):
    path = tmp_path / "path.json"
    path.write_text(json.dumps({"ortho_height": 1.5, "near": 0.01, "far": 100, "frames": [
        {"eye": [0.2, -3, 0.5], "target": [0.2, 0, 0.3], "up": [0, 0, 1]},
        {"eye": [0.3, -3, 0.5], "target": [0.2, 0, 0.3], "up": [0, 0, 1]}]}))
    out = last_json(hlod("-q", "run", cow_file, "--method", "coh", "--bias", "mu", "--alpha", "projected",
                         "--shift-up", "children", "--path", path, "--save-frames", tmp_path / "frames",
                         "--size", "64x48"))
    assert out["frames"] == 2
    pngs = sorted((tmp_path / "frames").glob("*.png"))
    assert len(pngs) == 2 and pngs[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("args, expect", [
    (["--size", "big"], "expected WxH"),
    (["--s", "2"], "s and t must lie in [0, 1]"),
    (["--k", "0"], "steepness k must be > 0"),
])
def test_run_bad_options_are_one_line(cow_file, args, expect):
    assert expect in one_line_error(hlod("run", cow_file, "--method", "coh", *args, check=False))


def test_run_bad_path_file_is_one_line(cow_file, tmp_path):
    bad = write_text(tmp_path / "p.json", json.dumps({"frames": [{"eye": [0, 0, 0], "target": [0, 0, 0]}]}))
    assert "p.json: a frame's eye equals its target" in one_line_error(
        hlod("run", cow_file, "--method", "coh", "--path", bad, check=False))
