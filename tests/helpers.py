"""Test helpers: the real meshes in ../shared/models, bakes cached for the session, and the Blenders
the extension checks run in (BLENDERS: version "X.Y" -> that environment's Python interpreter)."""
from __future__ import annotations

import functools
import re
from pathlib import Path

import numpy as np
from hlod_core import meshio
from hlod_core.bake import BakeSettings, bake

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT.parent / "shared" / "models"
SCENES = ROOT / "tests" / "scenes"
BLENDER_VENVS = ROOT / ".venv-blender"


def _blenders() -> dict[str, Path]:
    """One Blender per requirements-bpyXY.txt, where scripts/bootstrap.sh `ensure_blender_venvs` makes
    it: the bpy pin's major.minor names the folder .venv-blender/bpy-X.Y, and bin/python there is
    its interpreter (Python 3.11 or 3.13, as that Blender ships)."""
    out = {}
    for req in sorted(ROOT.glob("requirements-bpy*.txt")):
        pin = re.search(r"^bpy==(\d+\.\d+)\.\d+", req.read_text(), re.M)
        assert pin, f"{req.name}: no bpy==X.Y.Z line"
        out[pin.group(1)] = BLENDER_VENVS / f"bpy-{pin.group(1)}" / "bin" / "python"
    return out


BLENDERS = _blenders()  # {"4.2": .venv-blender/bpy-4.2/bin/python, "5.0": ..., "5.2": ...}


def blender_python(version: str) -> Path:
    """The interpreter of Blender `version`'s environment; a missing one is an error, never a skip:
    the extension checks must run in every Blender we support."""
    python = BLENDERS[version]
    assert python.is_file(), (f"Blender {version}'s environment is missing ({python}): run `bash test.sh`, "
                              f"which makes it (scripts/bootstrap.sh ensure_blender_venvs)")
    return python


def model(name: str) -> Path:
    path = MODELS / name
    assert path.is_file(), f"test model missing: {path} (tests read ../shared/models)"
    return path


@functools.lru_cache(maxsize=None)
def load_model(name: str) -> meshio.TriangleMesh:
    return meshio.load_mesh(model(name))


@functools.lru_cache(maxsize=None)
def baked(name: str, *, jobs: int = 1, offset: float = 0.0, target_tris: int = 2000):
    """Bake a shared model once per session (optionally translated by `offset` on every axis)."""
    mesh = load_model(name)
    if offset:
        mesh = meshio.transform_mesh(mesh, _translation(offset), name=f"{name}+{offset:g}")
    return mesh, bake(mesh, BakeSettings(jobs=jobs, target_tris=target_tris))


def _translation(offset: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = offset
    return m


@functools.lru_cache(maxsize=None)
def baked_city():
    """The default procedural city (about 217k triangles), baked once per session."""
    from hlod_core import scenes

    return bake(scenes.default_scene(seed=1), BakeSettings(jobs=2))


def street_path(frames: int = 30, *, static: bool = False):
    """Walk down the street between the first two columns of buildings of the default city, eye at
    1.7 m, looking along the street: most of the city hides behind the first buildings."""
    from hlod_core.camera import CameraPath

    out = []
    for i in range(frames):
        y = -5.0 if static else -5.0 + 100.0 * i / max(frames - 1, 1)
        sway = 0.0 if static else 8.0 * np.sin(i / 5.0)
        out.append(([10.0, y, 1.7], [10.0 + sway, y + 30.0, 4.0], [0.0, 0.0, 1.0]))
    return CameraPath(frames=np.array(out, float), near=0.05, far=400.0, fovy_deg=60.0)
