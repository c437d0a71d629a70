"""Test inputs shared by the test modules: where things are, the test models (models.py: by role)
and their bakes, the street walk through the default city, the textured scene made with bpy, the
comparable bytes of a .hlod file, a scripted query-availability double, and the extension imported
as a package outside Blender (for its modules that import no Blender module).

Nothing is cached at module level: what a test run shares (the bakes, the GL context) is a fixture in
conftest.py, made once and dropped by pytest at the end. The core is imported inside the functions:
conftest.py imports this module, and a core module that fails to import should fail the tests that
use it, not the collection of every test.
"""
from __future__ import annotations

import contextlib
import ctypes
import hashlib
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import models

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "tests" / "scenes"
CACHE = ROOT / ".cache"
#: The target of a test model's bake unless a test asks for another (SharedBakes.baked, bake_model).
DEFAULT_TARGET_TRIS = 2000


def model(name: str) -> Path:
    """The file of the test model of role `name` (models.ROLES: "cow", "bunny", "statue", ...)."""
    return models.path(name)


def load_model(name: str):
    """The test model of role `name` read as a TriangleMesh (a fresh mesh each call: 20-300 ms)."""
    return models.load(name)


def bake_model(name: str, *, jobs: int = 1, offset: float = 0.0, target_tris: int = DEFAULT_TARGET_TRIS):
    """(TriangleMesh, Hlod) of a test model, optionally translated by `offset` model units on every axis."""
    from hlod_core.bake.pipeline import bake
    from hlod_core.bake.settings import BakeSettings
    from hlod_core.io import meshes

    mesh = load_model(name)
    if offset:
        translation = np.eye(4)
        translation[:3, 3] = offset
        mesh = meshes.transform_mesh(mesh, translation, name=f"{name}+{offset:g}")
    return mesh, bake(mesh, BakeSettings(jobs=jobs, target_tris=target_tris))


def bake_city():
    """The default procedural city (about 217k triangles), baked with 2 jobs: about 10 s."""
    from hlod_core.bake.pipeline import bake
    from hlod_core.bake.settings import BakeSettings
    from hlod_core.io import procedural

    return bake(procedural.default_scene(seed=1), BakeSettings(jobs=2))


class SharedBakes:
    """Bakes made once and kept by their owner (conftest's fixture `bakes`, one per test run): the same
    arguments give the same (mesh, Hlod) objects. Tests must not modify what they get."""

    def __init__(self):
        self._models: dict[tuple, tuple] = {}
        self._city = None

    def baked(self, name: str, *, jobs: int = 1, offset: float = 0.0, target_tris: int = DEFAULT_TARGET_TRIS):
        """(mesh, Hlod) of bake_model(name, ...), baked on first use."""
        key = (name, jobs, offset, target_tris)
        if key not in self._models:
            self._models[key] = bake_model(name, jobs=jobs, offset=offset, target_tris=target_tris)
        return self._models[key]

    def city(self):
        """bake_city(), baked on first use."""
        if self._city is None:
            self._city = bake_city()
        return self._city


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


def without_frame_meta(hlod):
    """`hlod` without the meta entries that record its frame ("frame", "frame_source"): what a bake
    wrote before the frame was recorded, for the tests that compare with an older commit's file."""
    return hlod.replace(meta={k: v for k, v in hlod.meta.items() if k not in ("frame", "frame_source")})


def file_bytes(hlod, path: Path) -> bytes:
    """The .hlod file of `hlod` saved at `path`, with the volatile meta (timings, cache statistics)
    removed: the bytes two equal bakes must share."""
    from hlod_core.bake.pipeline import stable_meta
    from hlod_core.io import hlod_file

    return hlod_file.save(hlod.replace(meta=stable_meta(hlod.meta)), path).read_bytes()


def textured_scene(scale: str = "small") -> dict:
    """The textured test scene (tests/scenes/textured_scene.py, run in the bpy module), generated
    into .cache/textured_scene-<scale>/ when missing or when the generator changed (a hash stamp).
    Written to a temporary folder and renamed, so a concurrent test process never sees a half-written
    folder. Returns the paths: dir, blend, glb, obj, mtl, gltf (separate/textured.gltf, external
    buffer and images), json, textures (the folder), and facts (scene.json read: triangles, ...)."""
    generator = SCENES / "textured_scene.py"
    stamp = hashlib.sha256(generator.read_bytes() + scale.encode()).hexdigest()
    folder = CACHE / f"textured_scene-{scale}"
    if not _stamped(folder, stamp):
        _generate_textured_scene(generator, scale, stamp, folder)
    facts = json.loads((folder / "scene.json").read_text())
    return {"dir": folder, "blend": folder / facts["blend"], "glb": folder / facts["glb"], "obj": folder / facts["obj"],
            "mtl": folder / facts["mtl"], "gltf": folder / facts["gltf"], "json": folder / "scene.json",
            "textures": folder / "textures", "facts": facts}


def _generate_textured_scene(generator: Path, scale: str, stamp: str, folder: Path) -> None:
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


def _stamped(folder: Path, stamp: str) -> bool:
    try:
        return (folder / "stamp.txt").read_text() == stamp
    except OSError:
        return False


@contextlib.contextmanager
def standalone_gl():
    """A headless context as the renderer makes one (gl_platform.standalone_context: EGL here, Mesa
    llvmpipe where there is no GPU), garbage-collected only by its own gc() and released at the
    end. Its one user is conftest's fixture `gl_ctx`."""
    from hlod_core.render.gl_platform import standalone_context

    ctx = standalone_context()
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


def extension_package(name: str = "hlod_extension"):
    """The repository imported as the package `name`, as Blender imports the extension (its
    modules import one another relatively), for the add-on's modules that import no Blender module
    (addon.bake.job) in tests outside Blender. Its hlod_core is a second copy of the core (its
    errors are its own classes). Imported once a process (sys.modules keeps it)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, ROOT / "__init__.py", submodule_search_locations=[str(ROOT)])
    package = importlib.util.module_from_spec(spec)
    sys.modules[name] = package
    spec.loader.exec_module(package)
    return package


def gl_function(ctx, name: str, restype, *argtypes):
    """A GL entry point of moderngl context `ctx` that moderngl does not wrap, as a ctypes function."""
    loader = ctx.mglo._context
    load = getattr(loader, "load", None) or loader.load_opengl_function
    return ctypes.CFUNCTYPE(restype, *argtypes)(load(name))
