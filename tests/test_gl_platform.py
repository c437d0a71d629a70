"""hlod_core/render/gl_platform.py: the standalone GL context on every platform and the host's context
kept current around it.

Run for real here: EGL (the first choice on Linux), GLX (the second) on a virtual X server (Xvfb,
installed by test.sh's setup), keeping an EGL context current around a new GLX one and a GLX context
around a new EGL one, and the one-sentence error when neither can be made (the command line, in a
child process without an EGL vendor or an X display). WGL (Windows) and CGL (macOS) can only be
simulated on this machine: `platform` names the branch, a stand-in `glcontext.wgl` /
`glcontext.darwin` module records what the branch asks of it and hands back a real EGL context,
and stand-in ctypes libraries record the get/make-current calls. Only a real Windows machine and a
real Mac prove those two branches end to end.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import types

import numpy as np
import pytest

from helpers import ROOT
from hlod_core.core.errors import GLUnavailable
from hlod_core.render import gl_platform
from hlod_core.render.gl_platform import current, keep_current, native_standalone, standalone_context
from processes import hlod, one_line_error

# --- Linux, for real -------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def x_display():
    """A virtual X server (Xvfb) of this module's own: its DISPLAY string (":N")."""
    xvfb = shutil.which("Xvfb")
    assert xvfb, "Xvfb is not installed: bash test.sh installs it (Debian: apt-get install xvfb libglx-mesa0)"
    read, write = os.pipe()
    server = subprocess.Popen([xvfb, "-displayfd", str(write), "-nolisten", "tcp", "-screen", "0", "64x64x24"],
                              pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write)
    try:
        with os.fdopen(read) as f:
            number = f.readline().strip()  # Xvfb writes its display number once it accepts connections
        assert number.isdigit(), f"Xvfb did not start (exit status {server.poll()})"
        yield f":{number}"
    finally:
        server.terminate()
        server.wait(timeout=10)


def _draws(ctx) -> bool:
    """Whether `ctx` draws: clear a 4x4 framebuffer of its own to a colour and read it back."""
    with ctx:
        bound = ctx.detect_framebuffer()  # bound again after: moderngl rebinds its record of the last one used
        fbo = ctx.simple_framebuffer((4, 4))
        try:
            fbo.use()
            fbo.clear(0.0, 1.0, 0.0, 1.0)
            pixels = np.frombuffer(fbo.read(components=3), np.uint8).reshape(4, 4, 3)
        finally:
            bound.use()
            fbo.release()
    return bool((pixels == [0, 255, 0]).all())


@pytest.mark.gl
def test_linux_makes_an_egl_context_and_gives_the_host_its_context_back(gl_ctx):
    """gl_ctx (EGL) is current, as a host's context would be; a new context made inside
    keep_current is EGL, the first choice, and gl_ctx's is current again after, and draws."""
    host = current()
    assert host is not None and host.system == "EGL"
    with keep_current() as saved:
        assert saved == host
        ctx = standalone_context()
        assert current().system == "EGL" and current().handle != host.handle  # the new one, current once made
    assert current() == host
    with keep_current():  # moderngl's `with ctx:` leaves no context current on exit
        try:
            assert _draws(ctx)
        finally:
            ctx.release()
    assert current() == host and _draws(gl_ctx)


@pytest.mark.gl
def test_linux_falls_back_to_glx_when_egl_cannot_make_a_context(x_display, tmp_path):
    """A process whose libglvnd finds no EGL vendor, with an X display: the context is GLX."""
    code = ("from hlod_core.render.gl_platform import current, standalone_context\n"
            "ctx = standalone_context()\n"
            "print(current().system, ctx.version_code >= 330, ctx.info['GL_RENDERER'])\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "DISPLAY": x_display,
           "__EGL_VENDOR_LIBRARY_FILENAMES": str(tmp_path / "no-vendor.json")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[:2] == ["GLX", "True"], out.stdout


@pytest.mark.gl
def test_a_glx_host_context_is_current_again_after_an_egl_context_is_made(x_display, monkeypatch, gl_ctx):
    """GLX's save, release and restore for real: a GLX context stands for the host's (Blender on
    X11), made inside keep_current around gl_ctx (EGL); an EGL context is made and released inside
    keep_current around the GLX one, which is current again after each and draws; the GLX one is
    released, and gl_ctx is current again and draws. Without the release keep_current does on entry,
    libglvnd refuses to switch between EGL and GLX (module notes)."""
    import moderngl

    monkeypatch.setenv("DISPLAY", x_display)
    with keep_current() as before:
        assert before.system == "EGL"
        host = moderngl.create_context(standalone=True, require=330, context=native_standalone("x11", require=330))
        saved = current()
        assert saved.system == "GLX"
        with keep_current():
            egl = standalone_context()
            assert current().system == "EGL"
        assert current() == saved
        with keep_current():
            egl.release()
        assert current() == saved
        with keep_current():
            assert _draws(host)
        assert current() == saved
        host.release()  # current: the outer block gives gl_ctx back
    assert current() == before
    with keep_current():
        assert _draws(gl_ctx)
    assert current() == before


def test_without_any_gl_the_command_line_says_so_in_one_sentence(cow_file, tmp_path):
    """Not marked gl: this test's processes find no EGL vendor and no X display (conftest), as a
    machine without OpenGL. The run command fails with one line naming what was tried and what to do."""
    proc = hlod("run", cow_file, "--method", "vfc", "--frames", "2", "--size", "64x48", check=False)
    line = one_line_error(proc)
    assert "No OpenGL 3.3 context could be made (tried EGL (" in line and "GLX (" in line, line
    assert "install Mesa's EGL and OpenGL drivers" in line and "Traceback" not in proc.stderr, line


def test_the_error_names_each_window_system_tried_and_what_to_do(monkeypatch):
    """With every backend failing, GLUnavailable lists them in order with their reasons."""
    def refuse(backend, *, require):
        if backend == "x11":
            raise ImportError("no x11", name="glcontext.x11")
        raise Exception(f"{backend}: eglInitialize failed")  # what glcontext raises

    monkeypatch.setattr(gl_platform, "native_standalone", refuse)
    with pytest.raises(GLUnavailable) as err:
        standalone_context(platform="linux")
    assert str(err.value) == (
        "No OpenGL 3.3 context could be made (tried EGL (egl: eglInitialize failed), GLX (glcontext.x11 is not "
        "installed)): install Mesa's EGL and OpenGL drivers (Debian: libegl1 libegl-mesa0 libgl1-mesa-dri) or your "
        "GPU vendor's driver, or run under an X display.")


# --- Windows and macOS, simulated -------------------------------------------------------------------

@pytest.mark.parametrize("platform, module, kwargs", [
    ("win32", "wgl", {"mode": "standalone", "glversion": 330}),
    ("darwin", "darwin", {"mode": "standalone"}),
])
@pytest.mark.gl
def test_windows_and_macos_make_their_context_with_wgl_and_cgl(platform, module, kwargs, monkeypatch, gl_ctx):
    """Simulated: the branch imports glcontext.wgl (Windows) or glcontext.darwin (macOS), the
    modules those platforms' glcontext wheels hold (tests/test_build_extension.py checks the zips),
    with glcontext's own keyword arguments. The stand-in module hands back a real EGL context so
    that the rest of the path (moderngl wrapping it, drawing) runs."""
    calls = []

    def create_context(**given):
        calls.append(given)
        return native_standalone("egl", require=330)

    monkeypatch.setitem(sys.modules, f"glcontext.{module}", types.SimpleNamespace(create_context=create_context))
    with keep_current():
        ctx = standalone_context(platform=platform)
    try:
        assert calls == [kwargs]
        assert _draws(ctx)
    finally:
        ctx.release()


@pytest.mark.parametrize("platform", ["win32", "darwin"])
def test_windows_and_macos_without_their_glcontext_module_say_which_build_to_install(platform):
    """On this machine glcontext has no wgl and no darwin module: the branch's import really fails,
    as it would with a zip of another platform installed."""
    with pytest.raises(GLUnavailable) as err:
        standalone_context(platform=platform)
    system, module = ("WGL", "wgl") if platform == "win32" else ("CGL", "darwin")
    assert str(err.value) == (f"No OpenGL 3.3 context could be made (tried {system} (glcontext.{module} is not "
                              "installed)): install the extension (or glcontext) built for this platform.")


class _FakeWGL:
    """Stand-in for opengl32.dll: one device context and a current context that wglMakeCurrent sets."""

    def __init__(self):
        self.dc, self.context, self.calls = 0xD0, 0x1111, []

    def wglGetCurrentContext(self):  # noqa: N802 - the DLL's names
        return self.context

    def wglGetCurrentDC(self):  # noqa: N802 - the DLL's names
        return self.dc

    def wglMakeCurrent(self, dc, context):  # noqa: N802 - the DLL's names
        self.calls.append((dc, context))
        self.dc, self.context = dc, context
        return 1


class _FakeCGL:
    """Stand-in for OpenGL.framework: CGLSetCurrentContext sets the current context (0: kCGLNoError)."""

    def __init__(self):
        self.context, self.calls = 0x2222, []

    def CGLGetCurrentContext(self):  # noqa: N802 - the framework's names
        return self.context

    def CGLSetCurrentContext(self, context):  # noqa: N802 - the framework's names
        self.calls.append(context)
        self.context = context
        return 0


def test_windows_saves_releases_and_restores_the_current_wgl_device_and_context(monkeypatch):
    """Simulated (ctypes' opengl32 replaced): keep_current reads wglGetCurrentDC/Context on entry and
    releases it (wglMakeCurrent(NULL, NULL)); on exit it releases the context made current inside
    and calls wglMakeCurrent with the saved device and context."""
    fake = _FakeWGL()
    monkeypatch.setattr(gl_platform, "wgl_library", lambda: fake)
    with keep_current("win32") as saved:
        assert (saved.system, saved.handle) == ("WGL", 0x1111)
        assert fake.calls == [(None, None)] and gl_platform.current("win32") is None
        fake.dc, fake.context = 0xD1, 0x3333  # a new context made current, as glcontext.wgl does
    assert fake.calls == [(None, None), (None, None), (0xD0, 0x1111)]
    assert gl_platform.current_id("win32") == 0x1111


def test_macos_saves_releases_and_restores_the_current_cgl_context(monkeypatch):
    """Simulated (OpenGL.framework replaced): CGLGetCurrentContext on entry and CGLSetCurrentContext(NULL);
    on exit CGLSetCurrentContext(NULL) for the context made inside, then CGLSetCurrentContext(saved)."""
    fake = _FakeCGL()
    monkeypatch.setattr(gl_platform, "cgl_library", lambda: fake)
    with keep_current("darwin") as saved:
        assert (saved.system, saved.handle) == ("CGL", 0x2222)
        fake.context = 0x4444
    assert fake.calls == [None, None, 0x2222] and gl_platform.current_id("darwin") == 0x2222


def test_with_nothing_current_on_entry_none_is_current_after(monkeypatch):
    """No context current on entry (the stand-in's current context is NULL): the one made current
    inside is released on exit, and nothing else is made current. On this machine ctypes has no
    opengl32 and no OpenGL.framework: those branches see none."""
    fake = _FakeWGL()
    fake.context = 0
    monkeypatch.setattr(gl_platform, "wgl_library", lambda: fake)
    with keep_current("win32") as saved:
        assert saved is None and fake.calls == []
        fake.context = 0x5555
    assert fake.calls == [(None, None)] and gl_platform.current("win32") is None
    monkeypatch.undo()
    assert gl_platform.wgl_library() is None and gl_platform.cgl_library() is None
    assert current("win32") is None and current("darwin") is None


def test_platform_families_and_their_backends():
    """Which branch each sys.platform takes, and the glcontext modules each tries, in order."""
    assert {p: gl_platform.platform_family(p) for p in ("linux", "freebsd14", "win32", "cygwin", "darwin")} == {
        "linux": "linux", "freebsd14": "linux", "win32": "windows", "cygwin": "windows", "darwin": "macos"}
    assert gl_platform.STANDALONE_BACKENDS == {"linux": ("egl", "x11"), "windows": ("wgl",), "macos": ("darwin",)}
