"""Benchmark (not a test: a timing target, measured on request): the moved re-bake of a mixed scene
in Blender against its full bake (target: at least 4x), in the bpy module with the extension
installed as Blender installs it:

    .venv/bin/python -m pytest -q -s -p no:cacheprovider benchmarks/bench_blender_mixed_rebake.py

Sixteen statues, a UV sphere with a material and UVs alternating with an ico sphere with neither
(HLOD_MIXED_DETAIL=8, the default: 8 x 101,440 + 8 x 81,920 = 1,469,440 triangles; 4: 366,080), baked through the
background command with --jobs 2 and the cache; one interior statue moved by 0.05; the re-bake
timed against the full bake of the same run, and its arrays held equal to a bake from scratch
(tests/blender_bake_checks.py check_mixed_rebake_speed). Prints the figures; fails below the target.
"""
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from blender_runs import blender, build_extension_zips, install_extension, line_of

SPEEDUP_MOVED = 4.0  # the moved re-bake against the full bake, same run


@pytest.fixture
def repo(tmp_path_factory) -> Path:
    """The extension built and installed for the main .venv's bpy (tests/conftest.py's `repo`)."""
    return install_extension(build_extension_zips(tmp_path_factory.mktemp("dist"))[line_of("5.0").python_tag],
                             Path(sys.executable), tmp_path_factory.mktemp("extension"))


def test_the_moved_rebake_of_a_mixed_scene_is_at_least_4x_the_full_bake(repo, tmp_path):
    out = blender(repo, "mixed_rebake_speed", tmp_path, os.environ.get("HLOD_MIXED_DETAIL", "8"),
                  timeout_s=1800, script="blender_bake_checks.py")
    cache = out["cache"] or {}
    print(f"\nmixed scene of {out['tris']:,} triangles, jobs 2: full {out['full_s']:.2f} s, moved re-bake "
          f"{out['moved_s']:.2f} s ({out['full_s'] / out['moved_s']:.2f}x; {cache.get('rebuilt_nodes')} of "
          f"{cache.get('nodes')} inner nodes rebuilt), from scratch {out['fresh_s']:.2f} s, identical "
          f"{out['identical']} (load {out['load_1min']:.2f})")
    assert out["identical"]
    assert out["full_s"] / out["moved_s"] >= SPEEDUP_MOVED, out
