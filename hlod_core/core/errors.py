"""Typed errors raised by the core; front ends (CLI, Blender operators) map them to messages.

Every message names the object or file at fault and says what is wrong with it.
"""


class HlodError(Exception):
    """Base class of every error the core raises on purpose."""


class InputError(HlodError):
    """The input geometry or scene description cannot be baked (empty, NaN, bad indices, ...)."""


class FormatError(HlodError):
    """A .hlod file is truncated, foreign, of an unknown version or internally inconsistent."""


class BakeCancelled(HlodError):
    """The caller cancelled a bake; nothing was written."""


class GLUnavailable(HlodError):
    """No OpenGL context could be made on this machine (no driver, a driver that refuses, a
    platform without OpenGL): the message says what was tried and what to do."""
