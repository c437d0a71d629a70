"""Camera paths: the path file (hostile input) is validated field by field before any arithmetic,
and the generated inspection path is scale-free (real bakes, real OpenGL)."""
import json

import numpy as np
import pytest

from helpers import ScriptedAvailability
from hlod_core.bake.pipeline import BakeSettings, bake
from hlod_core.core import jsonutil
from hlod_core.core.errors import InputError
from hlod_core.io import meshes
from hlod_core.model.camera_path import MAX_MAGNITUDE, inspection_path, load_path
from hlod_core.render.renderer import Renderer
from hlod_core.traversal.methods import make
from hlod_core.traversal.settings import RuntimeSettings

GOOD_FRAME = {"eye": [0.2, -3.0, 0.5], "target": [0.2, 0.0, 0.3], "up": [0, 0, 1]}


def _write(tmp_path, document) -> str:
    path = tmp_path / "path.json"
    path.write_text(document if isinstance(document, str) else json.dumps(document))
    return str(path)


def _path(**fields) -> dict:
    return {"near": 0.01, "far": 100.0, "frames": [GOOD_FRAME], **fields}


@pytest.mark.parametrize("document, expect", [
    ('{"frames": ' + "[" * 100_000 + "]" * 100_000 + "}", r"not valid JSON \(nested 100001 levels deep"),
    ('{"near": 0.01, "far": Infinity, "frames": []}', r"not valid JSON \(Infinity is not a JSON number"),
    ('{"near": 0.01, "far": 1e999, "frames": []}', r"not valid JSON \(number 1e999 is out of the float64 range"),
    (_path(far=int("1" + "0" * 400)), r"far must be a finite number of magnitude at most 1e\+30"),
    (_path(fovy_deg=None), r"fovy_deg must be a number, got null"),
    (_path(fovy_deg="60"), r'fovy_deg must be a number, got the string "60"'),
    (_path(fovy_deg=[60]), r"fovy_deg must be a number, got a list of 1"),
    (_path(ortho_height=None), r"ortho_height must be a number, got null"),
    (_path(ortho_height="2"), r'ortho_height must be a number, got the string "2"'),
    (_path(ortho_height=[1, 2]), r"ortho_height must be a number, got a list of 2"),
    (_path(ortho_height=True), r"ortho_height must be a number, got true"),
    (_path(near=False), r"near must be a number, got false"),
    (_path(near=1.0, far=0.5), r"0 < near < far, got 1, 0.5"),
    (_path(fovy_deg=180), r"fovy_deg must lie in \(0, 180\), got 180"),
    (_path(ortho_height=2.0, fovy_deg=60), r"not both"),
    (_path(fov_deg=30), r'the path has unknown key "fov_deg"; expected some of fovy_deg, ortho_height'),
    (_path(frames=[{**GOOD_FRAME, "eye": [0, "1", 0]}]), r'frames\[0\]\.eye\[1\] must be a number, got the string "1"'),
    (_path(frames=[GOOD_FRAME, {**GOOD_FRAME, "target": [0, 0]}]), r"frames\[1\]\.target must be a list of 3 numbers"),
    (_path(frames=[{"eye": [0, 0, 0]}]), r'frames\[0\] has no "target"'),
    (_path(frames=[[0, 0, 0]]), r"frames\[0\] must be an object"),
    (_path(frames=[{**GOOD_FRAME, "eye": [1e31, 0, 0]}]), r"frames\[0\]\.eye\[0\] must be a finite number"),
    (_path(frames=[]), r'"frames" must be a non-empty list'),
    ([1, 2, 3], r"a camera path is a JSON object"),
])
def test_bad_path_file_is_one_clear_error(tmp_path, document, expect):
    """Each was a traceback (RecursionError, TypeError, ValueError), or was accepted: "60" as a
    string, true as 1, a misspelt key ignored, 1e400 as infinity."""
    name = _write(tmp_path, document)
    with pytest.raises(InputError, match=expect) as info:
        load_path(name)
    assert str(info.value).startswith(f"{name}: ") and "\n" not in str(info.value)


def test_good_path_file_round_trips(tmp_path):
    path = load_path(_write(tmp_path, _path(ortho_height=1.5)))
    assert path.ortho_height == 1.5 and path.fovy_deg is None and path.frames.shape == (1, 3, 3)
    path.save(tmp_path / "again.json")
    again = load_path(tmp_path / "again.json")
    assert np.array_equal(again.frames, path.frames) and (again.near, again.far) == (0.01, 100.0)
    default_up = load_path(_write(tmp_path, _path(frames=[{"eye": [1, 2, 3], "target": [0, 0, 0]}])))
    assert default_up.frames[0, 2].tolist() == [0.0, 0.0, 1.0] and default_up.fovy_deg == 60.0
    assert MAX_MAGNITUDE < 1e150 and jsonutil.MAX_DEPTH >= 4  # squares of accepted numbers stay finite


# --- the generated inspection path is scale-free -----------------------------------------------

def _scaled(hlod, factor: float):
    """The same baked hierarchy with every length multiplied by `factor` (positions stay float32
    relative to the scaled origin)."""
    lengths = ("lod_box_min", "lod_box_max", "box_min", "box_max", "sphere_center", "sphere_radius", "error",
               "cube_side", "origin")
    scaled = {name: np.asarray(getattr(hlod, name)) * factor for name in lengths}
    return hlod.replace(positions=(hlod.positions.astype(np.float64) * factor).astype(np.float32), **scaled)


#: Coh's query results come back this many issued commands late (ScriptedAvailability), every
#: query asked: what it draws depends on the views alone, not on when llvmpipe's results are ready.
LAG = 3


def _drawn_nodes(ctx, hlod, method: str, size=(128, 96)) -> np.ndarray:
    """(frames,) nodes `method` draws in each frame of hlod's inspection path (seed 4, 12 frames)."""
    path = inspection_path(hlod, seed=4, frames=12)
    renderer = Renderer(ctx, hlod, size=size)
    try:
        lagged = ScriptedAvailability(renderer, LAG)
        traversal = make(method, hlod, lagged, settings=RuntimeSettings(skip_queries="off"))
        return np.array([traversal.frame(path.view(i, size)).dn for i in range(len(path))], float)
    finally:
        renderer.release()


@pytest.mark.gl
@pytest.mark.parametrize("factor", [1e-9, 1e9])
def test_inspection_path_is_scale_free(gl_ctx, bakes, factor):
    """A model scaled by 1e-9 or 1e9 gives the same nodes per frame as at scale 1, for VFC (no
    queries) and Coh(P) (queries). The old path clamped its radius at 1e-6 model units: at 1e-9 the
    camera orbited a thousand model sizes away and Coh drew almost nothing."""
    _, hlod = bakes.baked("cow", target_tris=400)
    other = _scaled(hlod, factor)
    base_path, path = inspection_path(hlod, seed=4, frames=12), inspection_path(other, seed=4, frames=12)
    assert np.allclose(path.frames[:, :2], base_path.frames[:, :2] * factor, rtol=1e-9, atol=0)  # eye, target
    assert np.array_equal(path.frames[:, 2], base_path.frames[:, 2])  # up
    assert path.near == pytest.approx(base_path.near * factor) and path.far == pytest.approx(base_path.far * factor)
    # Both are deterministic (Coh's results after a scripted lag): the same counts, frame by frame
    # (measured: equal at both scales). The old path drew a third of them at 1e-9.
    for method in ("vfc", "coh"):
        base, scaled = _drawn_nodes(gl_ctx, hlod, method), _drawn_nodes(gl_ctx, other, method)
        assert base.sum() > 50
        assert scaled.tolist() == base.tolist(), method


@pytest.mark.parametrize("where", [0.0, 5e6])
def test_inspection_path_of_a_model_without_extent(where):
    """Every triangle on one point: the path keeps eye and target apart (a radius relative to the
    point's distance from the origin, or 1 unit at the origin) and gives a valid frustum."""
    positions = np.full((3, 3), where)
    hlod = bake(meshes.from_arrays(positions, np.array([[0, 1, 2]]), name="point"), BakeSettings())
    path = inspection_path(hlod, seed=1, frames=8)
    assert np.all(np.isfinite(path.frames)) and np.all(np.any(path.frames[:, 0] != path.frames[:, 1], axis=1))
    assert 0 < path.near < path.far
