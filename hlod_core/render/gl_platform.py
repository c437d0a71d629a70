"""OpenGL contexts of the project's own, on every platform, and the host's context kept current
around them (docs/how-it-works.md#gl-contexts-on-every-platform).

A standalone context is made with the platform's own GL through glcontext's backend modules, in
order (`STANDALONE_BACKENDS`): on Linux (and other X11/Wayland systems) EGL, then GLX (an X server
is needed); on Windows WGL; on macOS CGL (glcontext's `darwin`). When none can be made,
`standalone_context` raises GLUnavailable saying in one sentence what was tried and what to do.

The context current before (a host's, such as Blender's) is saved, released and made current again
by `keep_current`, with the window system's own "get current" and "make current" entry points, via
ctypes: EGL (eglGetCurrentDisplay / Surface / Context, eglMakeCurrent), GLX (glXGetCurrentDisplay /
Drawable / ReadDrawable / Context, glXMakeContextCurrent), WGL (wglGetCurrentDC / Context,
wglMakeCurrent) and CGL (CGLGetCurrentContext, CGLSetCurrentContext from OpenGL.framework).

Data form: a platform is named by its family, "linux", "windows" or "macos" (`platform_family`
of a `sys.platform` string); a current context is a `CurrentContext` (window system, handle, how
to make it current again). Every function takes `platform` (default: this machine's) so that each
branch can be run on any machine; only the Linux branches can draw here.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import logging
import os
import sys
from dataclasses import dataclass, field
from typing import Callable, Iterator

from ..core.errors import GLUnavailable

log = logging.getLogger(__name__)

#: The OpenGL version every context of the project requires (GLSL 330, GL 3.3 core).
GL_VERSION_REQUIRED = 330
#: glcontext's backend modules tried for a standalone context, in order, per platform family.
STANDALONE_BACKENDS = {"linux": ("egl", "x11"), "windows": ("wgl",), "macos": ("darwin",)}
#: The window system each backend module speaks, as messages name it.
WINDOW_SYSTEMS = {"egl": "EGL", "x11": "GLX", "wgl": "WGL", "darwin": "CGL"}
#: What to do when no context can be made, per platform family (the second half of the message).
ADVICE = {
    "linux": "install Mesa's EGL and OpenGL drivers (Debian: libegl1 libegl-mesa0 libgl1-mesa-dri) "
             "or your GPU vendor's driver, or run under an X display",
    "windows": "update the graphics driver to one with OpenGL 3.3 or later",
    "macos": "use macOS 10.9 or later, whose OpenGL 4.1 core profile the extension draws with",
}
#: What to do when the platform's glcontext modules are not installed at all (a package built for
#: another platform).
MISSING_ADVICE = "install the extension (or glcontext) built for this platform"
#: CGL's framework on macOS.
CGL_FRAMEWORK = "/System/Library/Frameworks/OpenGL.framework/OpenGL"
EGL_DRAW, EGL_READ = 0x3059, 0x305A  # eglGetCurrentSurface's readdraw argument


def platform_family(platform: str | None = None) -> str:
    """"windows", "macos" or "linux" (Linux and the other X11 / Wayland systems) for a
    `sys.platform` string (default: this machine's)."""
    platform = sys.platform if platform is None else platform
    if platform in ("win32", "cygwin"):
        return "windows"
    if platform == "darwin":
        return "macos"
    return "linux"


# --- a standalone context ------------------------------------------------------------------------

def standalone_context(*, require: int = GL_VERSION_REQUIRED, platform: str | None = None):
    """A new standalone moderngl context (no window: it draws into framebuffers of its own), made
    with the first of the platform's STANDALONE_BACKENDS that gives one of version `require` or
    later. It is current once made, as every GL library leaves a new context: inside a host whose
    context must stay current, make and use it within `keep_current()` (which also lets a context
    of another window system be made). GLUnavailable when none can be made."""
    import moderngl

    family = platform_family(platform)
    failures: list[str] = []
    missing = 0  # backends whose glcontext module is not installed
    for backend in STANDALONE_BACKENDS[family]:
        try:
            native = native_standalone(backend, require=require)
        except ImportError:
            missing += 1
            failures.append(f"{WINDOW_SYSTEMS[backend]} (glcontext.{backend} is not installed)")
            continue
        except Exception as exc:  # noqa: BLE001 - glcontext raises plain Exception ("eglInitialize failed")
            failures.append(f"{WINDOW_SYSTEMS[backend]} ({_reason(exc)})")
            continue
        try:
            return moderngl.create_context(standalone=True, require=require, context=native)
        except Exception as exc:  # noqa: BLE001 - an old version (ValueError) or a loader failure
            native.release()
            failures.append(f"{WINDOW_SYSTEMS[backend]} ({_reason(exc)})")
    advice = MISSING_ADVICE if missing == len(failures) else ADVICE[family]
    raise GLUnavailable(f"No OpenGL {require // 100}.{require // 10 % 10} context could be made "
                        f"(tried {', '.join(failures)}): {advice}.")


def native_standalone(backend: str, *, require: int):
    """glcontext's standalone context of one backend module (STANDALONE_BACKENDS), current once
    made; what moderngl wraps (`moderngl.create_context(context=...)`). The keyword arguments are
    those glcontext's own per-platform wrappers pass, its GLCONTEXT_* library overrides included;
    ImportError where the platform's glcontext
    wheel has no such module (glcontext 3.1: egl and x11 on Linux, wgl on Windows, darwin on macOS)."""
    if backend == "egl":
        from glcontext import egl

        return egl.create_context(**_given(mode="standalone", glversion=require, libgl=_library("LINUX_LIBGL", "GL"),
                                           libegl=_library("LINUX_LIBEGL", "EGL")))
    if backend == "x11":  # glcontext tries $DISPLAY, then ":0.0"
        from glcontext import x11

        return x11.create_context(**_given(mode="standalone", glversion=require, libgl=_library("LINUX_LIBGL", "GL"),
                                           libx11=_library("LINUX_LIBX11", "X11")))
    if backend == "wgl":
        from glcontext import wgl

        libgl = os.environ.get("GLCONTEXT_WIN_LIBGL")
        return wgl.create_context(**_given(mode="standalone", glversion=require, libgl=libgl))
    if backend == "darwin":
        from glcontext import darwin

        return darwin.create_context(mode="standalone")  # CGL: the 3.2+ core profile (4.1 on macOS 10.9+)
    raise ValueError(f"unknown glcontext backend {backend!r} (one of {sorted(WINDOW_SYSTEMS)})")


def _library(variable: str, name: str) -> str | None:
    """A window-system library: $GLCONTEXT_<variable> (glcontext's own override, honoured as its
    wrappers do) or the one `ctypes.util.find_library(name)` finds."""
    return os.environ.get(f"GLCONTEXT_{variable}") or ctypes.util.find_library(name)


def _given(**kwargs) -> dict:
    """The keyword arguments that have a value (glcontext refuses None for a library name)."""
    return {key: value for key, value in kwargs.items() if value is not None}


def _reason(exc: Exception) -> str:
    """Why a backend failed, in words: glcontext's or moderngl's message."""
    return str(exc) or "it failed without saying why"


# --- the context current now, and keeping it ---------------------------------------------------

@dataclass(frozen=True)
class CurrentContext:
    """A native GL context current on this thread: its window system ("EGL", "GLX", "WGL",
    "CGL"), its handle, `restore()`, which makes it current again, and `release()`, which leaves
    no context current on the thread (each False if the call failed). Two are equal when they
    name the same context."""

    system: str
    handle: int
    restore: Callable[[], bool] = field(compare=False)
    release: Callable[[], bool] = field(compare=False)


def current(platform: str | None = None) -> CurrentContext | None:
    """The native context current on this thread, or None: on Linux EGL's, else GLX's; on Windows
    WGL's; on macOS CGL's. None too where the window system's library is not there."""
    family = platform_family(platform)
    if family == "linux":
        return _egl_current() or _glx_current()
    if family == "windows":
        return _wgl_current()
    if family == "macos":
        return _cgl_current()
    raise ValueError(f"unknown platform family {family!r}")


def current_id(platform: str | None = None) -> int | None:
    """The handle of the current native context (`current`), or None: an id for "which context"."""
    found = current(platform)
    return None if found is None else found.handle


@contextlib.contextmanager
def keep_current(platform: str | None = None) -> Iterator[CurrentContext | None]:
    """Give the block a thread with no context current, and on exit the context current on entry
    back (yielded; None: none was, and none is current after). Releasing first is what lets the
    block make a context of another window system current: libglvnd refuses eglMakeCurrent while a
    GLX context is current (EGL_BAD_ACCESS, and GL calls then reach the GLX context) and GLX's make
    current while an EGL one is (an X BadAccess error, which ends a process without an X error
    handler); WGL and CGL switch contexts without it. The block must not destroy the context
    current on entry (restoring it would use a freed display)."""
    saved = current(platform)
    if saved is not None:
        _checked(saved.release(), "release", saved)
    try:
        yield saved
    finally:
        now = current(platform)
        if now is not None and now != saved:
            _checked(now.release(), "release", now)
        if saved is not None and now != saved:
            _checked(saved.restore(), "make current again", saved)


def _checked(done: bool, what: str, context: CurrentContext) -> None:
    if not done:
        log.error("could not %s the %s context %#x", what, context.system, context.handle)


def _egl_current() -> CurrentContext | None:
    egl = egl_library()
    if egl is None or not egl.eglGetCurrentContext():
        return None
    display = egl.eglGetCurrentDisplay()
    draw, read = egl.eglGetCurrentSurface(EGL_DRAW), egl.eglGetCurrentSurface(EGL_READ)
    context = egl.eglGetCurrentContext()
    return CurrentContext("EGL", int(context), restore=lambda: bool(egl.eglMakeCurrent(display, draw, read, context)),
                          release=lambda: bool(egl.eglMakeCurrent(display, None, None, None)))


def _glx_current() -> CurrentContext | None:
    glx = glx_library()
    if glx is None or not glx.glXGetCurrentContext():
        return None
    display, draw, read = glx.glXGetCurrentDisplay(), glx.glXGetCurrentDrawable(), glx.glXGetCurrentReadDrawable()
    context = glx.glXGetCurrentContext()
    return CurrentContext("GLX", int(context),
                          restore=lambda: bool(glx.glXMakeContextCurrent(display, draw, read, context)),
                          release=lambda: bool(glx.glXMakeContextCurrent(display, 0, 0, None)))


def _wgl_current() -> CurrentContext | None:
    wgl = wgl_library()
    if wgl is None or not wgl.wglGetCurrentContext():
        return None
    device, context = wgl.wglGetCurrentDC(), wgl.wglGetCurrentContext()
    return CurrentContext("WGL", int(context), restore=lambda: bool(wgl.wglMakeCurrent(device, context)),
                          release=lambda: bool(wgl.wglMakeCurrent(None, None)))


def _cgl_current() -> CurrentContext | None:
    cgl = cgl_library()
    if cgl is None or not cgl.CGLGetCurrentContext():
        return None
    context = cgl.CGLGetCurrentContext()
    return CurrentContext("CGL", int(context), restore=lambda: cgl.CGLSetCurrentContext(context) == 0,  # kCGLNoError
                          release=lambda: cgl.CGLSetCurrentContext(None) == 0)


# --- the window systems' libraries (ctypes), loaded once; None where absent ----------------------
# (public for the tests, which stand in for the ones this machine lacks: opengl32, OpenGL.framework)

def _typed(lib, signatures: dict[str, tuple[list, object]]):
    """`lib` with each named function's argtypes and restype set; None if one is missing."""
    try:
        for name, (argtypes, restype) in signatures.items():
            fn = getattr(lib, name)
            fn.argtypes, fn.restype = argtypes, restype
    except AttributeError:
        return None
    return lib


@functools.lru_cache(maxsize=None)
def egl_library():
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
    except OSError:
        return None
    p = ctypes.c_void_p
    return _typed(lib, {"eglGetCurrentContext": ([], p), "eglGetCurrentDisplay": ([], p),
                        "eglGetCurrentSurface": ([ctypes.c_int32], p),
                        "eglMakeCurrent": ([p, p, p, p], ctypes.c_uint32)})


@functools.lru_cache(maxsize=None)
def glx_library():
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("GL") or "libGL.so.1")
    except OSError:
        return None
    p, xid = ctypes.c_void_p, ctypes.c_ulong  # GLXDrawable is an XID
    return _typed(lib, {"glXGetCurrentContext": ([], p), "glXGetCurrentDisplay": ([], p),
                        "glXGetCurrentDrawable": ([], xid), "glXGetCurrentReadDrawable": ([], xid),
                        "glXMakeContextCurrent": ([p, xid, xid, p], ctypes.c_int)})


@functools.lru_cache(maxsize=None)
def wgl_library():
    try:
        lib = ctypes.WinDLL("opengl32")
    except (AttributeError, OSError):  # ctypes.WinDLL exists on Windows only
        return None
    p = ctypes.c_void_p
    return _typed(lib, {"wglGetCurrentContext": ([], p), "wglGetCurrentDC": ([], p),
                        "wglMakeCurrent": ([p, p], ctypes.c_int)})


@functools.lru_cache(maxsize=None)
def cgl_library():
    try:
        lib = ctypes.CDLL(CGL_FRAMEWORK)
    except OSError:
        return None
    p = ctypes.c_void_p
    return _typed(lib, {"CGLGetCurrentContext": ([], p), "CGLSetCurrentContext": ([p], ctypes.c_int)})
