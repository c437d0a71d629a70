"""Ownership of GL objects: whoever creates one releases it, in reverse creation order, once.

Data form: `GLObjects`, a list of moderngl objects (programs, buffers, vertex arrays, textures,
renderbuffers, framebuffers: anything with `release()`) in the order they were made.
"""
from __future__ import annotations


class GLObjects:
    """The GL objects one owner made (`keep` each as it is made); `release()` frees them newest
    first (a vertex array before its buffers and program, a framebuffer before its attachments).
    Idempotent."""

    def __init__(self):
        self._objects: list = []

    def keep(self, resource):
        """Record `resource` (made just now) and return it."""
        self._objects.append(resource)
        return resource

    @property
    def objects(self) -> tuple:
        """The objects kept and not yet released, oldest first."""
        return tuple(self._objects)

    def release(self) -> None:
        """Release every object kept, newest first; the record is emptied, so a second call does nothing."""
        while self._objects:
            self._objects.pop().release()
