"""pytest configuration: the fixtures every test module shares, and the `gl` marker enforced.

tests/ is on sys.path, so test modules import the helper modules (helpers, models, sample_meshes,
processes, figure_checks, blender_runs, traversal_runs, ...) by name; a test module never imports another test module.

Fixtures
    gl_ctx          the test run's one OpenGL context (standalone EGL; Mesa llvmpipe without a GPU),
                    current during each test that uses it; a GL error still pending after such a test
                    fails it. Only tests marked `gl` may use it.
    bakes           helpers.SharedBakes: test models (models.py) baked once per test run (bakes.baked(role, ...))
    city_hlod       the default procedural city, baked once per test run
    city_renderer   a renderer of it (traversal_runs.SIZE), for one test (gl)
    cow_file        the cow baked by the command line (target 400 triangles) into a folder of the test run
    extension_zips  the extension's linux-x64 zips, one per Blender line, built once per test run
    repo            that zip installed for the main .venv's bpy, once per test module
    versioned_repo  that zip installed in each Blender of blender_runs.BLENDERS, once per test run
    vulkan_repo     the same installs, for the Blenders of blender_runs.VULKAN_BLENDERS, whose checks
                    run under Blender's Vulkan backend (lavapipe)

The `gl` marker is enforced: a test without it that asks for gl_ctx fails at setup, and from its
setup on (its fixtures of wider scope included), making a moderngl context in this
process fails and child processes find no EGL device (__EGL_VENDOR_LIBRARY_FILENAMES names no vendor
file) and no libX11 for a GLX context, so a command-line or Blender check that draws fails too.
"""
from __future__ import annotations

import os
import re
import signal
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

import blender_runs
import helpers
from processes import hlod

#: Set for tests not marked gl: libglvnd then loads no EGL vendor, and glcontext's GLX backend
#: (gl_platform's second choice on Linux, which tries $DISPLAY and then ":0.0") finds no libX11, so
#: a context cannot be made.
NO_GL = {"__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent/no-gl-marker.json",
         "GLCONTEXT_LINUX_LIBX11": "/nonexistent/no-gl-marker-libX11.so"}
#: Where the config keeps what _allow_gl changes, as it was before the tests ran (the environment's
#: values, moderngl's create_context): restored for `gl` tests and at the end.
GL_ORIGINALS = pytest.StashKey[dict]()
#: What a failure without GL says (moderngl/glcontext in a child, or the in-process refusal).
GL_FAILURE = re.compile(r"GLWithoutMarker|EGL|egl|found 0 devices|OpenGL")


class GLWithoutMarker(RuntimeError):
    """A test without the `gl` marker made an OpenGL context."""


# --- OpenGL ------------------------------------------------------------------------------------------

@pytest.fixture(scope="session")
def gl_ctx():
    """The test run's one standalone EGL context (made current for each test by _gl_guard)."""
    with helpers.standalone_gl() as ctx:
        yield ctx


@pytest.fixture(autouse=True)
def _gl_guard(request):
    """A test that uses gl_ctx: the context is current when the test starts (a test that makes a
    context of its own makes gl_ctx current again with `with gl_ctx:`); after it, no GL error may
    be pending (the fixtures it depends on released first). Whoever makes a GL object releases it:
    the context runs no garbage collection (gc_mode "context_gc", and moderngl 5.13's gc() fails on
    objects released already)."""
    if "gl_ctx" not in request.fixturenames:
        yield
        return
    from hlod_core.render.gl_functions import GLFunctions

    ctx = request.getfixturevalue("gl_ctx")
    with ctx:
        yield
    with ctx:  # current again: the test may have made (and released) a context of its own
        error = GLFunctions(ctx).get_error()
    assert error == 0, f"GL error 0x{error:04x} is pending after the test"


def _refuse_gl_context(*args, **kwargs):
    raise GLWithoutMarker("this test makes an OpenGL context but is not marked gl (@pytest.mark.gl)")


def _allow_gl(originals: dict, allowed: bool) -> None:
    """GL on or off for the test about to run, before any of its fixtures (of any scope) is made:
    off, moderngl.create_context refuses in this process and children find no EGL vendor and no libX11 for GLX."""
    for name, value in NO_GL.items():
        if allowed and originals[name] is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = originals[name] if allowed else value
    try:
        import moderngl
    except ImportError:
        return
    originals.setdefault("create_context", moderngl.create_context)
    moderngl.create_context = originals["create_context"] if allowed else _refuse_gl_context


def pytest_configure(config):
    config.stash[GL_ORIGINALS] = {name: os.environ.get(name) for name in NO_GL}
    # A suite started in the background (nohup, `cmd &` in a script) inherits Ctrl-C's signal
    # ignored, and an ignored signal stays ignored in every process it starts: the bakes the tests
    # interrupt with SIGINT would run on to the end. The command line keeps an inherited ignore, as
    # a program started that way should; the tests start theirs with the default.
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    marked = item.get_closest_marker("gl") is not None
    _allow_gl(item.config.stash[GL_ORIGINALS], marked)
    if "gl_ctx" in item.fixturenames and not marked:
        pytest.fail(f"{item.nodeid} uses the gl_ctx fixture but is not marked gl (@pytest.mark.gl)", pytrace=False)


def pytest_sessionfinish(session):
    _allow_gl(session.config.stash[GL_ORIGINALS], True)


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    if report.failed and item.get_closest_marker("gl") is None and GL_FAILURE.search(report.longreprtext):
        report.sections.append(("gl marker", "This test is not marked gl: it ran without OpenGL (conftest.py "
                                             "_allow_gl). If it draws, in this process or a child, mark it gl."))
    return report


# --- shared bakes ------------------------------------------------------------------------------------

@pytest.fixture(scope="session")
def bakes() -> helpers.SharedBakes:
    return helpers.SharedBakes()


@pytest.fixture(scope="session")
def city_hlod(bakes):
    return bakes.city()


@pytest.fixture
def city_renderer(gl_ctx, city_hlod):
    """A GL renderer of the default city at traversal_runs.SIZE, released after the test."""
    from hlod_core.render.renderer import Renderer
    from traversal_runs import SIZE

    renderer = Renderer(gl_ctx, city_hlod, size=SIZE)
    yield renderer
    renderer.release()


@pytest.fixture(scope="session")
def cow_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cow") / "cow.hlod"
    hlod("-q", "bake", helpers.model("cow"), "-o", out, "--target-tris", "400")
    return out


@pytest.fixture(scope="session")
def textured_scene_bake(tmp_path_factory):
    """The textured test scene (tests/scenes/textured_scene.py, small) read from its GLB, its
    images written to a session folder, baked with jobs 2: (mesh, Hlod), shared by the tests that
    draw or export it. Tests must not modify it."""
    from hlod_core.bake.pipeline import BakeSettings, bake
    from hlod_core.io.meshes import load_inputs

    mesh = load_inputs([helpers.textured_scene("small")["glb"]], texture_dir=tmp_path_factory.mktemp("textured-images"))
    return mesh, bake(mesh, BakeSettings(jobs=2))


# --- the extension in the real bpy module ------------------------------------------------------------

@pytest.fixture(scope="session")
def zip_folder(tmp_path_factory) -> Path:
    """Where this session's zips are built when test.sh does not share one folder between its two
    pytest processes (blender_runs.built_zips)."""
    return tmp_path_factory.mktemp("dist")


@pytest.fixture(scope="session")
def extension_zips(zip_folder) -> dict[str, Path]:
    """The linux-x64 zips of the extension, {python tag: path}, one per Blender line."""
    return blender_runs.build_extension_zips(blender_runs.built_zips([blender_runs.INSTALLED_PLATFORM], zip_folder))


@pytest.fixture(scope="session")
def every_zip(zip_folder) -> list[Path]:
    """Every zip the build makes: each platform, each Blender line (the linux-x64 ones are
    extension_zips's; the others without CesiumJS, blender_runs.INSTALLED_PLATFORM)."""
    return blender_runs.built_zips(list(blender_runs.build_extension_script().PIP_PLATFORMS), zip_folder)


@pytest.fixture(scope="module")
def repo(extension_zips, tmp_path_factory) -> Path:
    """The extension installed for the main .venv's bpy (5.0), fresh for each test module."""
    zip_path = extension_zips[blender_runs.line_of("5.0").python_tag]
    return blender_runs.install_extension(zip_path, Path(sys.executable), tmp_path_factory.mktemp("extension"))


@pytest.fixture(scope="session")
def installed_blenders(extension_zips, tmp_path_factory):
    """version "X.Y" -> blender_runs.Installed: the extension installed in that Blender's own
    environment from its line's zip, on first use, once per test run."""
    installed: dict[str, blender_runs.Installed] = {}

    def get(version: str) -> blender_runs.Installed:
        if version not in installed:
            python = blender_runs.blender_python(version)
            zip_path = extension_zips[blender_runs.line_of(version).python_tag]
            base = blender_runs.install_extension(zip_path, python, tmp_path_factory.mktemp(f"extension-{version}"))
            installed[version] = blender_runs.Installed(version, python, base)
        return installed[version]
    return get


@pytest.fixture(scope="session", params=sorted(blender_runs.BLENDERS), ids=lambda version: f"blender-{version}")
def versioned_repo(request, installed_blenders) -> blender_runs.Installed:
    """The extension installed in Blender `request.param`'s own environment, from its line's zip."""
    return installed_blenders(request.param)


@pytest.fixture(scope="session", params=blender_runs.VULKAN_BLENDERS, ids=lambda version: f"blender-{version}-vulkan")
def vulkan_repo(request, installed_blenders) -> blender_runs.Installed:
    """The extension installed in Blender `request.param`, for checks under its Vulkan backend
    (blender_runs.VULKAN); lavapipe must be installed (scripts/bootstrap.sh ensure_vulkan)."""
    blender_runs.require_lavapipe()
    return installed_blenders(request.param)
