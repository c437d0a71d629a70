"""Test helpers: the real meshes in ../shared/models, bakes cached for the session, and the Blenders
the extension checks run in (BLENDERS: version "X.Y" -> that environment's Python interpreter)."""
from __future__ import annotations

import contextlib

import functools
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from hlod_core.io import meshes
from hlod_core.bake.pipeline import BakeSettings, bake

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT.parent / "shared" / "models"
SCENES = ROOT / "tests" / "scenes"
BLENDER_VENVS = ROOT / ".venv-blender"
CACHE = ROOT / ".cache"


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
def load_model(name: str) -> meshes.TriangleMesh:
    return meshes.load_mesh(model(name))


@functools.lru_cache(maxsize=None)
def baked(name: str, *, jobs: int = 1, offset: float = 0.0, target_tris: int = 2000):
    """Bake a shared model once per session (optionally translated by `offset` on every axis)."""
    mesh = load_model(name)
    if offset:
        mesh = meshes.transform_mesh(mesh, _translation(offset), name=f"{name}+{offset:g}")
    return mesh, bake(mesh, BakeSettings(jobs=jobs, target_tris=target_tris))


def _translation(offset: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = offset
    return m


@functools.lru_cache(maxsize=None)
def baked_city():
    """The default procedural city (about 217k triangles), baked once per session."""
    from hlod_core.io import procedural

    return bake(procedural.default_scene(seed=1), BakeSettings(jobs=2))


def street_path(frames: int = 30, *, static: bool = False):
    """Walk down the street between the first two columns of buildings of the default city, eye at
    1.7 m, looking along the street: most of the city hides behind the first buildings."""
    from hlod_core.model.camera_path import CameraPath

    out = []
    for i in range(frames):
        y = -5.0 if static else -5.0 + 100.0 * i / max(frames - 1, 1)
        sway = 0.0 if static else 8.0 * np.sin(i / 5.0)
        out.append(([10.0, y, 1.7], [10.0 + sway, y + 30.0, 4.0], [0.0, 0.0, 1.0]))
    return CameraPath(frames=np.array(out, float), near=0.05, far=400.0, fovy_deg=60.0)


@functools.lru_cache(maxsize=None)
def textured_scene(scale: str = "small") -> dict:
    """The textured test scene of issue 13 (tests/scenes/textured_scene.py, run in the bpy module):
    generated once into .cache/textured_scene-<scale>/ and again when the generator changes (a hash
    stamp). Written to a temporary folder and renamed, so a concurrent test process never sees a
    half-written folder. Returns the paths: dir, blend, glb, obj, mtl, gltf (separate/textured.gltf,
    external buffer and images), json, textures (the folder), and facts (scene.json read:
    triangles, materials, ...)."""
    generator = SCENES / "textured_scene.py"
    stamp = hashlib.sha256(generator.read_bytes() + scale.encode()).hexdigest()
    folder = CACHE / f"textured_scene-{scale}"
    if not _stamped(folder, stamp):
        CACHE.mkdir(exist_ok=True)
        scratch = Path(tempfile.mkdtemp(prefix=f".textured_scene-{scale}-", dir=CACHE))
        try:
            done = subprocess.run([sys.executable, str(generator), str(scratch), "--scale", scale],
                                  capture_output=True, text=True, timeout=300)
            assert done.returncode == 0, f"{generator.name} failed:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
            (scratch / "stamp.txt").write_text(stamp)
            if folder.exists():  # stale: move it aside first (rename is atomic, rmtree is not)
                stale = Path(tempfile.mkdtemp(prefix=".stale-", dir=CACHE))
                try:
                    os.rename(folder, stale / "old")
                except OSError:
                    pass  # another process moved it
                shutil.rmtree(stale, ignore_errors=True)
            try:
                os.rename(scratch, folder)
            except OSError:  # another process put its (equal) folder there first
                assert _stamped(folder, stamp), f"{folder}: cannot replace it"
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
    facts = json.loads((folder / "scene.json").read_text())
    return {"dir": folder, "blend": folder / facts["blend"], "glb": folder / facts["glb"], "obj": folder / facts["obj"],
            "mtl": folder / facts["mtl"], "gltf": folder / facts["gltf"], "json": folder / "scene.json",
            "textures": folder / "textures", "facts": facts}


def _stamped(folder: Path, stamp: str) -> bool:
    try:
        return (folder / "stamp.txt").read_text() == stamp
    except OSError:
        return False


@contextlib.contextmanager
def standalone_gl():
    """A headless EGL context (Mesa llvmpipe where there is no GPU), garbage-collected only by its
    own gc() and released at the end: the GL tests' fixtures."""
    import moderngl

    ctx = moderngl.create_context(standalone=True, backend="egl", require=330)
    ctx.gc_mode = "context_gc"
    try:
        yield ctx
    finally:
        ctx.release()


class ScriptedAvailability:
    """Test double for when query results come back: a result is available once `lag` more draws
    or queries were issued after its query (the latency of a GPU behind the CPU), whatever the
    machine's load and however often the traversal asks. Records the renderer calls in order."""

    def __init__(self, renderer, lag):
        self._renderer = renderer
        self._lag = lag
        self._issued = 0
        self._issued_at = {}
        self.calls = []
        self.not_yet = 0  # answers "not available yet"

    #: The renderer's batched calls, which would pass the script by: behind this double a
    #: traversal queries one node at a time, as with multiquery and batch_queries off.
    _UNSCRIPTED = frozenset({"issue_queries", "issue_multiquery"})

    def __getattr__(self, name):
        if name in self._UNSCRIPTED:
            raise AttributeError(name)
        return getattr(self._renderer, name)

    def draw_node(self, node, ratio_p=1.0):
        self._issued += 1
        self.calls.append(("draw", node, float(ratio_p)))
        self._renderer.draw_node(node, ratio_p)

    def issue_query(self, node, *, with_alpha):
        query = self._renderer.issue_query(node, with_alpha=with_alpha)
        self._issued += 1
        self._issued_at[id(query)] = (self._issued, query)
        self.calls.append(("query", node))
        return query

    def available(self, query):
        back = self._issued - self._issued_at[id(query)][0] >= self._lag
        self.not_yet += not back
        return back

    def result(self, query):
        del self._issued_at[id(query)]
        out = self._renderer.result(query)
        self.calls.append(("result", query.node, out[0], out[1]))
        return out


def numeric_library_env() -> dict[str, str]:
    """The variables that choose the BLAS and OpenMP kernels (OPENBLAS_CORETYPE and the like): the
    old bake in its own process must compute with the kernels this process uses, or the floats
    differ by the kernel, not by the code (a machine that sets OPENBLAS_CORETYPE=Haswell on an AMD
    EPYC gave a different cow without it)."""
    return {k: v for k, v in os.environ.items() if k.startswith(("OPENBLAS_", "OMP_", "MKL_", "GOTO", "BLIS_"))}
