"""Bake and Clear (docs/user-guide.md). Bake gathers the evaluated meshes on Blender's main thread and bakes
them in a child process of Blender's Python with `scene.hlod.jobs` worker processes
(addon/bake/job.py; modal with progress in the status bar and the panel, Esc cancels; synchronous in
execute(), as in background mode). A bake that fails or dies is reported; Blender and an earlier
.hlod stay as they were.

Bake records the objects it took and their content keys on the scene (addon/scene/source_record.py);
`hlod.bake(recorded=True)` is Re-bake: it bakes the recorded objects again. A bake while the
preview runs stops the preview first (its sources are hidden, and hidden objects give the depsgraph
no instances to read), then starts it again on the new file, or on the old one if the bake fails.
"""
from __future__ import annotations

import os
from pathlib import Path

import bpy
from bpy.props import BoolProperty

from ..addon.preview.live import PREVIEW
from ..addon.scene import gather as scene_mesh, objects as scene_objects, source_record
from ..addon.bake.job import BakeJob
from ..addon.materials.cycles_bake import bake_unreadable_materials, cycles_report
from ..addon.materials.textures import place_textures
from ..addon.properties import stored_path
from ..addon.scene.objects import Skipped
from ..addon.settings import bake_settings
from ..hlod_core.bake import cache
from ..hlod_core.core.errors import BakeCancelled, HlodError, InputError
from ..hlod_core.io.texture_folder import EmbeddedTextures

#: Seconds between two looks at the running bake's progress.
POLL_S = 0.1
#: Recorded objects named in the Re-bake warning at most.
MISSING_SHOWN = 5


def output_path(props) -> str:
    """Where Bake writes: the Output setting, else next to the .blend with its name."""
    if props.output_path:
        path = bpy.path.abspath(props.output_path)
        if os.path.isdir(path):  # a folder: the file in it takes the .blend's name, or "scene"
            stem = os.path.splitext(os.path.basename(bpy.data.filepath))[0] or "scene"
            return os.path.join(path, stem + ".hlod")
        return path
    if not bpy.data.filepath:
        raise InputError("Bake: the .blend is not saved; save it first or set an Output path")
    return os.path.splitext(bpy.data.filepath)[0] + ".hlod"


class HLOD_OT_bake(bpy.types.Operator):
    """Bake an octree HLOD of the selected objects or a collection (evaluated: modifiers and instances)"""

    bl_idname = "hlod.bake"
    bl_label = "Bake HLOD"
    bl_options = {"REGISTER", "UNDO"}

    recorded: BoolProperty(name="Recorded Sources", default=False, options={"SKIP_SAVE"},
                           description="Bake the objects the last bake took (Re-bake), not the Source setting")

    def _prepare(self, context):
        """(mesh, output path, settings, record rows, the bake's extra meta: the UV map's and colour
        attribute's names). Stops a running preview first (module notes)."""
        props = context.scene.hlod
        self._restart = PREVIEW.running()
        if self._restart:
            PREVIEW.stop()
        out = output_path(props)
        folder = os.path.dirname(out) or "."
        if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
            raise InputError(f"Bake: cannot write {out}: folder {folder} is missing or not writable")
        objects = self._recorded_objects(context) if self.recorded else scene_objects.source_objects(context, props)
        taken: list = []
        attributes: dict = {}
        skipped = Skipped()
        mesh = scene_mesh.evaluated_mesh(context, objects, taken=taken, attributes=attributes, skipped=skipped)
        mesh, cycles_baked = bake_unreadable_materials(context, mesh)  # node trees that cannot be read
        if cycles_baked:
            self.report({"INFO"}, f"HLOD bake: {cycles_report(cycles_baked)}")
        if skipped:  # kinds without triangles, hidden objects: named once (addon/scene/objects.py)
            self.report({"WARNING"}, f"HLOD bake: {skipped.text()}")
        rows = source_record.record(taken, context.evaluated_depsgraph_get())
        # textures made from node trees, packed images: OUT.textures once the .hlod is written (_end)
        self._textures = EmbeddedTextures(Path(out))
        mesh = place_textures(mesh, self._textures)
        return mesh, out, bake_settings(props), rows, attributes or None

    def _recorded_objects(self, context) -> list:
        """Re-bake's objects: those of the scene's record still in the scene (a warning names the others)."""
        objects, missing = scene_objects.recorded_objects(context, context.scene.hlod)
        if missing:
            shown = ", ".join(repr(name) for name in missing[:MISSING_SHOWN])
            shown += " ..." if len(missing) > MISSING_SHOWN else ""
            self.report({"WARNING"}, f"Re-bake: {len(missing)} recorded object(s) renamed or deleted, "
                                     f"left out: {shown}")
        return objects

    def _start(self, context) -> BakeJob:
        """Gather the mesh here, on Blender's main thread, and start the bake's child process (with
        the cache folder beside the output, unless the Bake Cache setting is off)."""
        mesh, out, settings, self._rows, extra_meta = self._prepare(context)
        try:
            cache_dir = cache.default_folder(out) if context.scene.hlod.use_cache else None
            cache.check_folder(cache_dir)
            return BakeJob(mesh, settings, out, extra_meta=extra_meta, cache_dir=cache_dir)
        except BaseException:
            self._textures.discard()
            raise

    def _end(self, context, job: BakeJob) -> set[str]:
        """Report how the finished job went; the operator's return value. The textures the bake made
        are published as OUT.textures only when the .hlod was written, else dropped."""
        try:
            if job.error is None:
                self._textures.publish()
        except OSError as exc:
            job.error = exc
        finally:
            self._textures.discard()
        if isinstance(job.error, BakeCancelled):
            self.report({"WARNING"}, "HLOD bake cancelled; nothing written")
        elif job.error is not None:
            self.report({"ERROR"}, str(job.error) if isinstance(job.error, HlodError)
                        else f"HLOD bake failed: {type(job.error).__name__}: {job.error}")
        else:
            self._finish(context, job)
            return {"FINISHED"}
        self._restart_preview(context)
        return {"CANCELLED"}

    def _finish(self, context, job: BakeJob) -> None:
        props = context.scene.hlod
        result = job.result
        props.file = stored_path(job.output)
        source_record.store(props, self._rows, props.file)
        props.last_bake = bake_summary(result, job.seconds)
        self.report({"INFO"}, f"HLOD baked: {result.node_count} nodes, {result.input_tris:,} triangles of "
                              f"{len(self._rows)} objects -> {job.output}; {props.last_bake}")
        self._restart_preview(context)

    def _restart_preview(self, context) -> None:
        """Start the preview again if the bake stopped it (on the new file, or the old one)."""
        if not getattr(self, "_restart", False):
            return
        self._restart = False
        try:
            PREVIEW.start(context.scene)
        except (HlodError, OSError) as exc:
            self.report({"WARNING"}, f"HLOD preview not restarted: {exc}")

    def execute(self, context):
        """Synchronous (background mode, scripts): the same child process, waited for here."""
        try:
            job = self._start(context)
        except HlodError as exc:
            self.report({"ERROR"}, str(exc))
            self._restart_preview(context)
            return {"CANCELLED"}
        job.join()
        return self._end(context, job)

    def invoke(self, context, event):
        """Modal with progress in the status bar and the panel; Esc cancels; the UI stays responsive."""
        if bpy.app.background:
            return self.execute(context)
        try:
            self._job = self._start(context)
        except HlodError as exc:
            self.report({"ERROR"}, str(exc))
            self._restart_preview(context)
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(POLL_S, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        context.window_manager.progress_update(job.percent)
        cancelling = " - cancelling" if job.cancelled else " - Esc to cancel"
        context.workspace.status_text_set(job.status_line() + cancelling)
        _redraw_sidebars(context)
        if job.running:
            return {"PASS_THROUGH"}
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        return self._end(context, job)


def bake_summary(result, seconds: float) -> str:
    """One line about a finished bake for the panel: wall time, worker processes, and how much came
    from the bake's cache (its meta["cache"]: inner nodes reused of all inner nodes; leaves are
    never decimated, so they are not counted)."""
    text = f"{seconds:.1f} s, {result.jobs} job{'s' if result.jobs > 1 else ''}"
    reuse = result.cache
    if reuse is None:
        return text + "; no cache"
    return text + f"; cache: {reuse['reused_nodes']} of {reuse['nodes']} inner nodes reused"


def _redraw_sidebars(context) -> None:
    """The panel shows the running bake's progress: redraw the 3D views' sidebars."""
    for area in context.screen.areas if context.screen else ():
        if area.type == "VIEW_3D":
            for region in area.regions:
                if region.type == "UI":
                    region.tag_redraw()


class HLOD_OT_clear(bpy.types.Operator):
    """Stop the preview and forget the baked file (the file on disk is kept)"""

    bl_idname = "hlod.clear"
    bl_label = "Clear HLOD"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        PREVIEW.stop()
        props = context.scene.hlod
        props.file = ""
        source_record.store(props, [], "")  # the record belongs to the file
        return {"FINISHED"}


CLASSES = [HLOD_OT_bake, HLOD_OT_clear]
