"""Which native GL context is current, and keeping Blender's current around a private one (docs/how-it-works.md#gl-queries:
a standalone EGL context made current in Blender's process leaves Blender's context unbound).

Only the window-system libraries' own "get current" and "make current" entry points are used, via
ctypes: EGL (Blender's bpy module headless, Wayland), GLX (X11), WGL (Windows). Unknown platforms
report None, which the preview treats as "cannot tell"."""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import functools
import sys


@functools.lru_cache(maxsize=None)
def _egl():
    name = ctypes.util.find_library("EGL") or "libEGL.so.1"
    try:
        lib = ctypes.CDLL(name)
    except OSError:
        return None
    for fn in ("eglGetCurrentContext", "eglGetCurrentDisplay", "eglGetCurrentSurface"):
        getattr(lib, fn).restype = ctypes.c_void_p
    lib.eglGetCurrentSurface.argtypes = [ctypes.c_int32]
    lib.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
    lib.eglMakeCurrent.restype = ctypes.c_uint32
    return lib


@functools.lru_cache(maxsize=None)
def _other():
    """(library, getter name) of the non-EGL window system: GLX on Linux, WGL on Windows."""
    try:
        if sys.platform == "win32":
            lib, fn = ctypes.WinDLL("opengl32"), "wglGetCurrentContext"
        else:
            lib, fn = ctypes.CDLL(ctypes.util.find_library("GL") or "libGL.so.1"), "glXGetCurrentContext"
        getattr(lib, fn).restype = ctypes.c_void_p
        return lib, fn
    except (OSError, AttributeError):
        return None


def current() -> int | None:
    """An id of the current GL context (EGL first, then GLX/WGL), or None if none is current."""
    egl = _egl()
    if egl is not None and egl.eglGetCurrentContext():
        return int(egl.eglGetCurrentContext())
    other = _other()
    if other is not None:
        handle = getattr(other[0], other[1])()
        return int(handle) if handle else None
    return None


@contextlib.contextmanager
def keep_current():
    """Restore the EGL display/surfaces/context that were current on entry (no-op without EGL)."""
    egl = _egl()
    saved = None
    if egl is not None and egl.eglGetCurrentContext():
        EGL_DRAW, EGL_READ = 0x3059, 0x305A
        saved = (egl.eglGetCurrentDisplay(), egl.eglGetCurrentSurface(EGL_DRAW), egl.eglGetCurrentSurface(EGL_READ),
                 egl.eglGetCurrentContext())
    try:
        yield
    finally:
        if saved is not None:
            egl.eglMakeCurrent(*saved)
