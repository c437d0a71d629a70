"""The GL contexts the preview draws with, and the GL objects it may release only in the context
that made them (a GL delete acts on the current context's names).

- Blender's contexts: moderngl attaches once per native context (`attach`), and the attachment is
  reused across file loads and previews, with `gc_mode="context_gc"` so that the garbage collector
  makes no GL call;
- the private context (`private`): a standalone context of the platform's own GL (EGL or GLX on
  Linux, WGL on Windows, CGL on macOS: hlod_core.render.gl_platform), made once and reused, since
  moderngl keeps about 40 KB of every context it creates; when none can be made, GLUnavailable's
  sentence is kept (`private_unavailable`) and not tried again until `retry_private`;
- orphans: GL objects a stopped preview made in a Blender context that was not current when it
  stopped, released at the next draw in that context.
Why: docs/how-it-works.md#gl-contexts-and-releasing-gl-objects
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

from ...hlod_core.core.errors import GLUnavailable
from ...hlod_core.render import gl_platform

log = logging.getLogger(__name__)


def blender_backend() -> str:
    """Blender's GPU backend: "OPENGL", "METAL", "VULKAN" (OPENGL where Blender cannot say)."""
    import gpu

    try:
        return gpu.platform.backend_type_get()
    except (AttributeError, SystemError):
        return "OPENGL"


@dataclass
class Orphan:
    """GL objects (each with an idempotent `release()`) a stopped preview made in Blender's context
    `gl_context`, stopped while another context was current; released in list order."""

    gl_context: int | None
    resources: list = field(default_factory=list)


class GLContexts:
    """The preview's GL contexts (module notes): Blender's, attached; the private one; the orphans."""

    def __init__(self):
        self._attached: dict = {}  # native GL context id -> the moderngl context attached to it
        self._private = None
        self.private_unavailable: str | None = None  # why no private context could be made (GLUnavailable)
        self.orphans: list[Orphan] = []

    def attach(self, current: int | None):
        """The moderngl context on the native context current now, made once per native context. Not
        `moderngl.get_context()` alone: that is moderngl's process-wide default, which every standalone
        context (private mode, the benchmark) replaces while it lives."""
        ctx = self._attached.get(current)
        if ctx is None:
            import moderngl

            # init_context() attaches through moderngl's default loader, which finds the current
            # EGL/GLX/WGL context (create_context() with settings goes through glcontext's detect
            # mode, which on Linux knows GLX only and fails on the bpy module's EGL context)
            moderngl.init_context()
            ctx = moderngl.get_context()
            ctx.gc_mode = "context_gc"
            self._attached[current] = ctx
        return ctx

    def private(self):
        """The private standalone context (gl_platform.standalone_context, as Renderer.create_standalone
        makes one), made once; the context current before is current again after. GLUnavailable when
        none can be made, at once while `private_unavailable` holds the first failure's sentence."""
        if self._private is None:
            if self.private_unavailable is not None:
                raise GLUnavailable(self.private_unavailable)
            try:
                with gl_platform.keep_current():  # a new context is current once made
                    self._private = gl_platform.standalone_context()
            except GLUnavailable as exc:
                self.private_unavailable = str(exc)
                log.warning("HLOD preview: %s", exc)
                raise
        return self._private

    def retry_private(self) -> None:
        """Forget a failure to make the private context: the next `private()` tries again (a new
        preview does, after a driver was installed or a setting changed)."""
        self.private_unavailable = None

    def hand_over(self, gl_context: int | None, resources: list) -> None:
        """Release `resources`, made in `gl_context`, once that context is current
        (`release_orphans`); nothing to do for an empty list."""
        if resources:
            self.orphans.append(Orphan(gl_context, list(resources)))

    def release_orphans(self, current: int | None) -> None:
        """Release the orphans made in `current`, the context current now, and drop moderngl's
        records of objects already released there (they pile up under "context_gc")."""
        kept = []
        for orphan in self.orphans:
            if orphan.gl_context != current:
                kept.append(orphan)
                continue
            for resource in orphan.resources:
                resource.release()  # gpu module objects: Blender frees their buffers here, now
            orphan.resources.clear()
        self.orphans[:] = kept
        ctx = self._attached.get(current)
        if ctx is not None and ctx.objects:
            import moderngl

            unreleased = [obj for obj in ctx.objects if not isinstance(obj, moderngl.InvalidObject)]
            ctx.objects.clear()
            ctx.objects.extend(unreleased)
            ctx.gc()  # objects dropped without release(), made in this context: released here

    def shutdown(self) -> None:
        """Forget the orphans (their contexts are gone by now) and free the private context: for
        unregister, after which nothing is left."""
        if self.orphans:
            log.warning("HLOD preview: %d stopped preview(s) left GL objects in a context that is not current",
                        len(self.orphans))
        self.orphans.clear()
        if self._private is not None:
            with gl_platform.keep_current():
                self._private.release()
            self._private = None
