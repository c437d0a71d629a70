"""Test helpers: the real meshes in ../shared/models, and bakes cached for the session."""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
from hlod_core import meshio
from hlod_core.bake import BakeSettings, bake

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT.parent / "shared" / "models"
SCENES = ROOT / "tests" / "scenes"


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
