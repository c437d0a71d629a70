"""The Blender extension with the real bpy module: built into a zip by Blender's own extension tool,
installed into a temporary extension repository and enabled as Blender does (bl_ext.r.hlod).
Each check runs in its own Python process (tests/blender/blender_checks.py): bpy keeps global state, and
the user's Blender configuration is kept out of it (BLENDER_USER_RESOURCES points at a temp dir).

The fixtures are conftest.py's: the zip is built once per test run (the linux one: cp311 and cp313
wheels, the same zip for every Blender). `versioned_repo` installs it in each Blender of BLENDERS
(4.2 LTS, 5.0.1, 5.2.3), each in its own environment holding only bpy and numpy, as a Blender
install does: the extension's dependencies come from its own wheels. `repo` installs it for the
main .venv's bpy 5.0.1, for the checks that do not depend on the version (the long session)."""
import statistics
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from blender_runs import BLENDERS, VULKAN, all_hold, blender, blender_python
from helpers import ROOT
from hlod_core.report.evaluate import METHOD_SPECS
from hlod_core.traversal.settings import RuntimeSettings

sys.path.insert(0, str(ROOT / "scripts"))
import build_extension

PREDICT_NEW = RuntimeSettings().predict_new  # the panel's default is the core's
TOGGLED = {"on": "off", "off": "on"}

pytestmark = pytest.mark.blender  # the extension in the real bpy module (or Blender's own extension tool)

BLENDER_EXT = Path(sysconfig.get_paths()["platlib"]) / "bpy/5.0/scripts/addons_core/bl_pkg/cli/blender_ext.py"
DEPENDENCIES = ("pymeshlab", "moderngl", "glcontext", "xatlas")
BLENDER_PYTHON = {"4.2": (3, 11), "5.0": (3, 11), "5.2": (3, 13)}  # the Python each Blender ships


def test_manifest_validates_with_blenders_tool():
    proc = subprocess.run([sys.executable, str(BLENDER_EXT), "validate", str(ROOT)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_each_zip_holds_the_package_and_its_blender_lines_wheels(extension_zips):
    """One zip per Blender line: 4.2 to 5.0 (cp311 wheels, blender_version_max 5.1.0, exclusive),
    5.1 and later (cp313 wheels, blender_version_min 5.1.0); the package in each, no tests."""
    expected = {"cp311": ('"4.2.0"', '"5.1.0"'), "cp313": ('"5.1.0"', None)}
    assert sorted(extension_zips) == sorted(expected)
    for tag, zip_path in extension_zips.items():
        names = zipfile.ZipFile(zip_path).namelist()
        assert "blender_manifest.toml" in names and "hlod_core/traversal/methods.py" in names
        assert not any(n.startswith("tests/") for n in names)
        wheels = [n for n in names if n.startswith("wheels/") and n.endswith(".whl")]
        assert sorted(build_extension.wheel_tags(w) for w in wheels) == sorted((name, tag) for name in DEPENDENCIES)
        assert all(w.endswith("_x86_64.whl") for w in wheels), wheels
        manifest = zipfile.ZipFile(zip_path).read("blender_manifest.toml").decode()
        low, high = expected[tag]
        assert f"blender_version_min = {low}" in manifest
        assert ("blender_version_max" not in manifest) if high is None else f"blender_version_max = {high}" in manifest


def test_blender_offers_each_blender_only_its_lines_zip(extension_zips):
    """Blender's own compatibility filter (blender_ext.py's repository_filter_skip, which Install
    from Disk and the extension listing apply) takes each zip in its line's Blenders only."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("blender_ext_tool", BLENDER_EXT)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    blenders = {(4, 2, 0): (3, 11, 7), (5, 0, 1): (3, 11, 7), (5, 1, 0): (3, 13, 1), (5, 2, 0): (3, 13, 1)}
    for tag, zip_path in extension_zips.items():
        item = tool.toml_from_bytes_or_error(zipfile.ZipFile(zip_path).read("blender_manifest.toml"))
        assert isinstance(item, dict), item
        taken = [blender for blender, python in blenders.items()
                 if not tool.repository_filter_skip(item, filter_blender_version=blender, filter_platform="linux-x64",
                                                    filter_python_version=python, skip_message_fn=lambda _: None,
                                                    error_fn=lambda exc: (_ for _ in ()).throw(exc))]
        assert taken == ([(4, 2, 0), (5, 0, 1)] if tag == "cp311" else [(5, 1, 0), (5, 2, 0)]), (tag, taken)


def test_the_checks_run_in_blender_4_2_5_0_and_5_2_and_a_missing_environment_is_an_error(monkeypatch, tmp_path):
    assert sorted(BLENDERS) == ["4.2", "5.0", "5.2"]  # requirements-bpy42/50/52.txt
    monkeypatch.setitem(BLENDERS, "4.2", tmp_path / "bin" / "python")
    with pytest.raises(AssertionError, match=r"Blender 4\.2's environment is missing .*: run `bash test.sh`"):
        blender_python("4.2")


def test_enable_disable_twice_under_the_real_package_name(versioned_repo, tmp_path):
    """In each Blender: enabled from the installed zip under its real name, registered twice,
    disabled twice; the dependencies come from the zip's wheels for that Blender's Python (its
    environment has none of them), installed where Blender installs extension wheels."""
    out = blender(versioned_repo, "registration", tmp_path, quiet=True)
    assert out["module"] == "bl_ext.r.hlod"
    version = versioned_repo.version
    assert out["blender"] == [int(v) for v in version.split(".")]
    assert tuple(out["python"]) == BLENDER_PYTHON[version]
    python_dir = "python{}.{}".format(*BLENDER_PYTHON[version])
    site = versioned_repo / "user" / "extensions" / ".local" / "lib" / python_dir / "site-packages"
    for name in DEPENDENCIES:
        assert Path(out["dependencies"][name]).is_relative_to(site), (name, out["dependencies"][name])
    # the environment itself has none of them (as Blender), or the check above would not test the wheels
    own = subprocess.run([str(versioned_repo.python), "-c", "import importlib.util, sys; "
                          f"sys.exit(any(importlib.util.find_spec(n) for n in {DEPENDENCIES!r}))"])
    assert own.returncode == 0, f"{versioned_repo.python} has its own copy of one of {DEPENDENCIES}"
    on = {"scene_hlod": True, "operators": dict.fromkeys(["bake", "clear", "preview_toggle", "materialize", "export",
                                                          "benchmark"], True),
          "panel": True, "cli_command": True, "handlers": 1}
    off = {"scene_hlod": False, "operators": dict.fromkeys(on["operators"], False), "panel": False,
           "cli_command": False, "handlers": 0}
    assert out["first"] == out["second"] == out["register_again"] == on
    assert out["disabled"] == out["disabled_twice"] == off


def test_bake_operator_on_modifiers_and_instances(versioned_repo, tmp_path):
    """Bake, Materialize, export (.hlod and 3D Tiles), clear and the modal bake's job, in each Blender,
    without a warning (5.0 and later warned about paths without blend-relative support)."""
    out = blender(versioned_repo, "bake", tmp_path, quiet=True)
    all_hold(out,
             unsaved_refused="the .blend is not saved" in out["unsaved_error"],
             baked=out["result"] == ["FINISHED"] and Path(out["file"]).is_file(),
             # evaluated geometry: subdivision and array modifiers applied, collection instances realised
             evaluated_triangles=out["input_tris"] == out["expected_tris"],
             evaluated_extent=out["box_min"][0] == pytest.approx(-9.5, abs=1e-5)
             and out["box_max"][0] == pytest.approx(8.5, abs=1e-5),
             sources_untouched=out["sources_untouched"],
             empty_selection_refused="the selection has no objects" in out["empty_selection_error"],
             materialized=out["materialize"] == ["FINISHED"] and out["materialized_objects"] > 1,
             materialized_the_cut=out["materialized_tris"] == out["cut_tris"],
             exported=out["export"] == ["FINISHED"] and out["exported_nodes"] == out["nodes"],
             exported_3dtiles=out["export_3dtiles"] == ["FINISHED"] and out["tileset_tiles"] == out["nodes"],
             cleared=out["clear"] == ["FINISHED"] and out["file_after_clear"] == "",
             cancelled_job_wrote_nothing=out["job_cancelled"] == "BakeCancelled" and not out["job_cancelled_file"],
             finished_job=bool(out["job_done"][0]) and out["job_done"][1] == 100.0 and bool(out["job_done"][2])
             and out["job_done"][3] > 1,
             collection_baked=out["collection_result"] == ["FINISHED"] and out["collection_tris"] == 6 * 64 * 2,
             collection_output_next_to_blend=Path(out["collection_file"]) == tmp_path / "project" / "city.hlod")

@pytest.mark.gl  # the preview draws in a GPUOffScreen; the benchmark in a standalone EGL context
def test_preview_draw_path_in_an_offscreen(versioned_repo, tmp_path):
    """The add-on's draw path inside a GPUOffScreen with a scene camera's matrices: nodes drawn in
    modulation colours, none over Blender's own occluder (its depth hides them), strongly modulated
    (red) nodes where occlusion lowered their LOD, Blender's gpu drawing after the pass still shows,
    its GL state is as before, the panel's statistics are the last frame's, frame by frame along a
    walk that moves each of them; the private-context fallback draws through
    Blender's gpu module; the benchmark's standalone EGL context leaves
    Blender's drawing working; an exception in the draw path turns the preview off, not raised.
    In each Blender, on its default GPU backend (OpenGL in all three): the preview draws in
    Blender's context."""
    out = blender(versioned_repo, "preview", tmp_path)
    _draw_path_holds(out, backend="OPENGL", mode="blender_context", status="on: ")


@pytest.mark.gl  # the private context and the benchmark draw with EGL beside Blender's Vulkan
def test_preview_draw_path_under_vulkan(vulkan_repo, tmp_path):
    """The same draw path with Blender's Vulkan backend (lavapipe), to which moderngl cannot attach:
    the preview takes the private context by itself and says so, and the same checks hold there,
    the occluder's depth imported (no node over it) and the benchmark's EGL context beside Vulkan."""
    out = blender(vulkan_repo, "preview", tmp_path, env=VULKAN)
    _draw_path_holds(out, backend="VULKAN", mode="private_context", status="on (private context): ")


def _panel_shows_each_frame(walk: dict) -> bool:
    frames, panel = walk["frames"], walk["panel"]
    moving = all(len({frame[name] for frame in frames}) > 1 for name in ("drawn", "tris", "queries", "frame_ms"))
    return walk["draws"] == len(frames) == len(panel) == 5 and moving and all(
        shown == pytest.approx(frame, rel=1e-6, abs=1e-6) for shown, frame in zip(panel, frames))


def _draw_path_holds(out: dict, *, backend: str, mode: str, status: str) -> None:
    """check_preview's result: drawn by `mode` on `backend`, its status line starting with `status`."""
    frames = {"occluded": out["occluded"], "after_benchmark": out["after_benchmark"]}
    private = out["private"]  # Private Context ticked: traversal in a private context, nodes drawn with the gpu module
    checks = {"backend": out["backend"] == backend, "mode": out["mode"] == mode,
              "running": out["running"] and out["status_on"].startswith("on:")
              and out["status_drawn"].startswith(status)}
    for name, frame in frames.items():
        checks |= {f"{name}_modulation_colours": frame["ramp_pixels"] > 1000 and frame["red_pixels"] > 50,
                   f"{name}_occluder_hides_nodes": frame["ramp_in_occluder"] == 0
                   and frame["grey_in_occluder"] == frame["occluder_pixels"],
                   f"{name}_blender_draws_after": frame["green_pixels"] > 100 and frame["other_pixels"] == 0,
                   f"{name}_gl_state_restored": frame["state_after"] == frame["state_before"]}
    all_hold(out, **checks,
             private_draws=private["ramp_pixels"] > 1000 and private["ramp_in_occluder"] == 0
             and private["green_pixels"] > 100 and private["red_pixels"] > 50,
             private_gl_state_restored=private["state_after"] == private["state_before"] and out["private_drawn"] > 0,
             private_status=out["status_private"].startswith("on (private context)"),
             orthographic_and_xray=out["ortho"] > 1000 and "X-ray clears the depth" in out["status_xray"],
             materialize_front=out["materialize_front"] == ["FINISHED"]
             and out["front_objects"] == out["stats"]["drawn"],
             # the last frame's nodes and triangles; queries in one of the three frames (the first
             # always queries; a settled Coh frame may skip them all, as under load its results wait)
             statistics=out["stats"]["drawn"] > 0 and out["stats"]["queries"] > 0 and out["stats"]["tris"] > 0,
             # frame by frame along a walk, the panel shows the frame's own statistics (float
             # properties hold float32); the walk moves each counter, so a frozen one cannot pass
             panel_statistics=_panel_shows_each_frame(out["statistics_walk"]),
             box_outlines=out["with_boxes"] > 200,  # drawn with Blender's gpu module
             query_stream_switches=out["query_stream"] == ["on", "on", "off", "off", PREDICT_NEW, TOGGLED[PREDICT_NEW]]
             and out["query_stream_frame"] > 1000,  # and it still draws with both off, Predict New Nodes toggled
             benchmark=out["benchmark"] == ["FINISHED"] and out["benchmark_frames"] == 4
             and out["benchmark_methods"] == sorted(METHOD_SPECS),
             # no Blender ships matplotlib: the report is written without figures
             benchmark_without_figures=out["benchmark_figures"] == [],
             error_turns_preview_off=out["injected_return"] == "None" and not out["running_after_error"]
             and out["status_after_error"] == "off: RuntimeError: injected failure",
             file_load_stops_preview=out["running_after_toggle"] and not out["running_after_load"]
             and out["status_after_load"] == "off: a file was loaded")

WARMUP_SESSIONS = 6  # one period of the long session's configuration (file, method, private mode, toggles)
RSS_GROWTH_MB = 8.0  # median RSS of the last 10 sessions over that of the 10 after warm-up (measured 0.7 to
# 4.4 MB over four runs of 200 redraws a session, 3.6 with 80; single sessions swing by 5 MB as malloc returns
# memory, hence medians). A leaked renderer or traversal per redraw would grow it by far more; Python objects
# are held to the blocks limit below
PYTHON_BLOCKS_PER_SESSION = 50.0  # growth of Python's allocated blocks after warm-up, per session (a re-bake,
# a file load and blender_checks.REDRAWS_PER_SESSION redraws): measured 26 (with 200 redraws a session, 0.13 a
# redraw; the growth slows from session to session, so it comes with the sessions, not the redraws). An object
# kept per redraw adds at least REDRAWS_PER_SESSION: moderngl's detect_framebuffer() called every frame (408 B
# a call, never freed) added 0.51 a redraw, 41 a session of 80
QUERY_POOL_BLOCK = 64  # QueryPool generates query names 64 at a time


@pytest.mark.slow
@pytest.mark.gl
def test_preview_long_session_is_flat(repo, tmp_path):
    """2,400 redraws of the draw path with an orbiting camera, 30 file switches (load_pre stops the
    preview) each with a re-bake, every method, the private-context mode flipped in every session,
    the preview toggled off and on (every third time while another GL context is current, as with a
    second window): after warm-up the GL objects in Blender's context (counted with glIs* probes,
    not our bookkeeping) are the same after every load and at the end, the same configuration holds
    the same objects, RSS and Python's allocated blocks stay flat, no GL error is left pending after
    any redraw, the preview never turns itself off, and Blender's own drawing with the preview
    equals its drawing without it, at the start and at the end.
    The test is about leaks, not speed: Blender runs with LP_NUM_THREADS=0 (llvmpipe without its
    rasteriser threads), since with them its RSS jumps once by 20 to 75 MB at a random session and
    then stays flat; without them it stays flat throughout."""
    out = blender(repo, "long_session", tmp_path, timeout_s=1500, env={"LP_NUM_THREADS": "0"})
    sessions = out["sessions"]  # five periods of WARMUP_SESSIONS: the growth after warm-up over 24 sessions
    assert sessions == 5 * WARMUP_SESSIONS and out["redraws"] == 80 * sessions
    assert out["bakes"] == [["FINISHED"]] * sessions
    assert out["methods_drawn"] == sorted(out["methods"]) and len(out["methods"]) == 6
    assert 0.2 * out["redraws"] < out["private_redraws"] < 0.8 * out["redraws"]  # both modes, flipped in every session
    assert out["gl_errors"] == [] and out["turned_off"] == [], (out["gl_errors"], out["turned_off"])
    assert not any(out["running_after_load"])
    # every third session toggles while another context is current
    assert len(out["other_context_current"]) == len(range(1, sessions, 3)) and all(out["other_context_current"])
    stopped, running = out["census_stopped"], out["census_running"]
    # with the preview stopped, only Blender's own objects remain: the same after every load
    assert all(census == stopped[0] for census in stopped) and out["census_end"] == stopped[0], stopped
    for i in range(WARMUP_SESSIONS, len(running)):
        same = {kind: n for kind, n in running[i].items() if kind != "queries"}
        assert same == {kind: n for kind, n in running[i - WARMUP_SESSIONS].items() if kind != "queries"}, (i, running)
        # query names become objects when first begun: how many depends on how many were in flight
        # at once (result timing); the pool reuses them, so they stay within its first block
        assert running[i]["queries"] <= QUERY_POOL_BLOCK, (i, running[i])
    rss, blocks = out["rss_mb"], out["python_blocks"]
    after = slice(WARMUP_SESSIONS, WARMUP_SESSIONS + 10)
    assert statistics.median(rss[-10:]) - statistics.median(rss[after]) < RSS_GROWTH_MB, rss
    sessions_after_warmup = len(blocks) - WARMUP_SESSIONS
    assert (blocks[-1] - blocks[WARMUP_SESSIONS - 1]) / sessions_after_warmup < PYTHON_BLOCKS_PER_SESSION, blocks
    for kept in out["drawing"].values():
        assert kept["blender_pixels"] > 5000 and kept["preview_pixels"] > 300
        assert kept["blender_pixels_changed"] == 0
    assert out["reference_same"] and out["preview_same"]


def test_panels_refer_only_to_existing_properties_and_operators():
    """Panel draw() runs only in Blender's UI, which these tests cannot open: check statically that
    every property a panel shows exists on scene.hlod and every operator button exists."""
    import ast
    import re

    source = (ROOT / "panels/__init__.py").read_text()
    props_src = (ROOT / "addon/properties.py").read_text()
    declared = {node.target.id for node in ast.walk(ast.parse(props_src))
                if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)}
    shown = set(re.findall(r'\.prop\(props, "(\w+)"', source))
    shown |= set(re.findall(r'"(stat_\w+)"', source))  # the statistics loop
    assert shown and shown <= declared, shown - declared
    operators_src = "".join(p.read_text() for p in sorted((ROOT / "operators").glob("*.py")))
    ids = set(re.findall(r'bl_idname = "(hlod\.\w+)"', operators_src))
    buttons = set(re.findall(r'operator\("(hlod\.\w+)"', source))
    assert buttons and buttons <= ids, buttons - ids
