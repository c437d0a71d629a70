"""What differs by platform, from Blender's side, in the real bpy module (the extension installed
from its zip; checks in tests/blender/blender_platform_checks.py): a machine where no GL context
of the extension's own can be made (no EGL and no GLX library, as a Mac with a glcontext of another
platform or a driver that refuses), a Re-bake that replaces the .hlod the preview has open with
either reader (read into memory, as on Windows; memory-mapped, as on Linux and macOS), and paths with
spaces and non-ASCII letters through the Bake operator, the preview and the background command.
What only a real Mac or Windows machine can prove is named in docs/how-it-works.md#what-differs-by-platform.
"""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from blender_runs import all_hold, blender
from helpers import ROOT

pytestmark = [pytest.mark.blender, pytest.mark.gl]

NO_CONTEXT = "No OpenGL 3.3 context could be made (tried EGL (/nonexistent/libEGL.so.1 not loaded), GLX ("


def platform_check(installed, check: str, tmp_path, *arguments: str) -> dict:
    return blender(installed, check, tmp_path, *arguments, script="blender_platform_checks.py")


def test_without_any_gl_context_the_preview_tests_on_the_cpu_and_every_message_is_a_sentence(repo, tmp_path):
    """No standalone context can be made: Benchmark and Tune to PSNR report GLUnavailable's
    sentence (what was tried, what to install) and write nothing; the preview, asked for the
    private context, draws with the CPU occlusion test, whose tests see Blender's occluder (no
    node over it, strongly modulated nodes), and says why in the status line and where in the
    corner text; Blender's depth unreadable, it goes on and says its objects do not occlude;
    the CPU test failing too, it turns off with one sentence; no message names an exception;
    with GL back, a new preview takes the private context again. The mode rule: Blender's
    context on OpenGL unless Private Context, else the private context, else the CPU test."""
    out = platform_check(repo, "no_gl_context", tmp_path)
    expected = {}
    for backend in ("OPENGL", "METAL", "VULKAN"):
        for private in (False, True):
            for unavailable in (False, True):
                own = "cpu" if unavailable else "private_context"
                expected[f"{backend} private={private} unavailable={unavailable}"] = (
                    "blender_context" if backend == "OPENGL" and not private else own)
    cpu, unreadable, impossible = out["cpu"], out["unreadable"], out["impossible"]
    all_hold(out, rule=out["rule"] == expected,
             benchmark=out["benchmark"].startswith(NO_CONTEXT) and "install Mesa's EGL" in out["benchmark"],
             tune=out["tune"].startswith(NO_CONTEXT), nothing_written=not out["report_written"],
             cpu_mode=cpu["mode"] == "cpu" and cpu["running"]
             and cpu["status"].startswith("on (CPU occlusion test): row.hlod - " + NO_CONTEXT),
             cpu_draws=cpu["ramp_pixels"] > 1000 and cpu["green_pixels"] > 100 and cpu["other_pixels"] == 0,
             cpu_sees_the_occluder=cpu["ramp_in_occluder"] == 0 and cpu["red_pixels"] > 50
             and cpu["depth_import_ms"] > 0,
             corner=any(line.endswith("CPU occlusion test") and "(depth " in line for line in out["corner"]),
             unreadable=unreadable["running"] and unreadable["ramp_in_occluder"] == 0 and unreadable["status"].endswith(
                 "Blender's objects hide the nodes but do not occlude them: its depth could not be read "
                 "(the framebuffer has no depth attachment to read)"),
             impossible=not impossible["running"] and impossible["status"].startswith(
                 "off: No preview can be drawn here: no OpenGL 3.3 context could be made")
             and impossible["status"].endswith("the CPU occlusion test that stands in failed too (cannot allocate the "
                                               "depth buffer), the details are in Blender's console"),
             no_exception_names=out["exception_names"] == [],
             gl_back=out["after"]["mode"] == "private_context" and out["after"]["running"])


@pytest.mark.parametrize("reader", ["memory", "mapped"])
def test_a_rebake_replaces_the_file_the_preview_has_open(repo, tmp_path, reader):
    """Re-bake while the preview runs on the same file: the file is replaced (a new inode), the
    preview starts again on the new bake and draws. Read into memory (Windows' reader, which must
    leave nothing open: Windows refuses to replace a file that is open or mapped), no descriptor or
    mapping of the file is left at any time; memory-mapped (POSIX), the new file is what is mapped."""
    out = platform_check(repo, "replaced_file", tmp_path, reader)
    all_hold(out, rebake=out["rebake"] == ["FINISHED"], replaced=out["inode_after"] != out["inode_before"],
             new_bake=out["nodes_after"] == out["nodes_file"] != out["nodes_before"],
             draws=out["before"]["ramp_pixels"] > 1000 and out["after"]["ramp_pixels"] > 1000
             and out["after"]["running"],
             nothing_open=reader != "memory"
             or out["handles_before"] == out["handles_after"] == {"fds": [], "maps": []},
             mapped=reader != "mapped" or (bool(out["handles_before"]["maps"]) and bool(out["handles_after"]["maps"])
                                          and not any("(deleted)" in m for m in out["handles_after"]["maps"])),
             released=out["handles_stopped"]["fds"] == [])


def test_paths_with_spaces_and_non_ascii_letters(repo, tmp_path):
    """A .blend in "Städte und Straßen/Projekt ü é", baked by the Bake operator to "//Bake ñ/city ø.hlod"
    with its cache beside it and the temp folder (the bake's scratch) in "Temp Ünïcødé"; the preview
    draws it; then the background command bakes that .blend into "Ausgabe ß" with an ASCII-only
    console (PYTHONIOENCODING=ascii) and the same temp folder: exit status 0, the file written."""
    out = platform_check(repo, "unicode_paths", tmp_path)
    all_hold(out, bake=out["bake"] == ["FINISHED"],
             file=out["file_exists"] and out["file"].endswith("Bake ñ/city ø.hlod"),
             cache=out["cache"] == ["city ø.hlod", "city ø.hlod.cache"],
             preview=out["frame"]["running"] and out["frame"]["ramp_pixels"] > 1000,
             scratch_removed=out["temp_left"] == [])
    target = tmp_path / "Ausgabe ß"
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(repo / "user"), "PYTHONPATH": str(ROOT),
           "PYTHONIOENCODING": "ascii", "TMPDIR": str(tmp_path / "Temp Ünïcødé")}
    proc = subprocess.run([sys.executable, str(ROOT / "scripts/hlod_blender.py"),
                           "--extension-repo", str(repo / "repo"),
                           "bake", out["blend"], "-o", str(target), "--format", "hlod", "--target-tris", "300"],
                          capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["failed"] == 0 and Path(summary["files"][0]["outputs"]["hlod"]) == target / "Stadt ö.hlod", summary
    assert (target / "Stadt ö.hlod").is_file() and not os.listdir(tmp_path / "Temp Ünïcødé")
