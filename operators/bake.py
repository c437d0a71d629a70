"""Bake and Clear (docs/user-guide.md). Bake gathers the evaluated meshes on Blender's main thread and bakes
them in a child process of Blender's Python with `scene.hlod.jobs` worker processes, through the
flow the background command shares (addon/bake/from_scene.py; modal with progress in the status bar
and the panel, Esc cancels; synchronous in execute(), as in background mode). A bake that fails or
dies is reported; Blender and an earlier .hlod stay as they were.

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

from ..addon.bake.from_scene import SceneBake, start_bake
from ..addon.materials.cycles_bake import cycles_report
from ..addon.preview.live import PREVIEW
from ..addon.properties import stored_path
from ..addon.scene import objects as scene_objects
from ..addon.scene import source_record
from ..addon.settings import bake_settings
from ..hlod_core.core.errors import BakeCancelled, HlodError, InputError

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

    def _recorded_objects(self, context) -> list:
        """Re-bake's objects: those of the scene's record still in the scene (a warning names the others)."""
        objects, missing = scene_objects.recorded_objects(context, context.scene.hlod)
        if missing:
            shown = ", ".join(repr(name) for name in missing[:MISSING_SHOWN])
            shown += " ..." if len(missing) > MISSING_SHOWN else ""
            self.report({"WARNING"}, f"Re-bake: {len(missing)} recorded object(s) renamed or deleted, "
                                     f"left out: {shown}")
        return objects

    def _start(self, context) -> SceneBake:
        """Stop a running preview (module notes), check the output's folder, and run the shared
        flow on the chosen objects: the bake's child process runs when this returns. The objects
        the bake took are recorded (their content keys) while it runs."""
        props = context.scene.hlod
        self._restart = PREVIEW.running()
        if self._restart:
            PREVIEW.stop()
        out = output_path(props)
        folder = os.path.dirname(out) or "."
        if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
            raise InputError(f"Bake: cannot write {out}: folder {folder} is missing or not writable")
        objects = self._recorded_objects(context) if self.recorded else scene_objects.source_objects(context, props)
        bake = start_bake(context, objects, Path(out), bake_settings(props), use_cache=props.use_cache)
        if bake.cycles_bakes:  # colours no node tree reading gives
            self.report({"INFO"}, f"HLOD bake: {cycles_report(bake.cycles_bakes)}")
        if bake.gathered.skipped:  # kinds without triangles, hidden objects: named once (addon/scene/objects.py)
            self.report({"WARNING"}, f"HLOD bake: {bake.gathered.skipped.text()}")
        try:
            self._rows = source_record.record(bake.gathered.taken, context.evaluated_depsgraph_get())
        except BaseException:
            bake.job.cancel()
            bake.job.wait()
            bake.finish()
            raise
        return bake

    def _end(self, context, bake: SceneBake) -> set[str]:
        """Report how the finished bake went (its textures published or dropped: SceneBake.finish);
        the operator's return value."""
        bake.finish()
        job = bake.job
        if job.scratch_left:
            self.report({"WARNING"}, f"HLOD bake: scratch folder {job.scratch_left} not removed (a file in it is "
                                     "still held); the next bake removes it")
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

    def _finish(self, context, job) -> None:
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
            bake = self._start(context)
        except HlodError as exc:
            self.report({"ERROR"}, str(exc))
            self._restart_preview(context)
            return {"CANCELLED"}
        bake.job.join()
        return self._end(context, bake)

    def invoke(self, context, event):
        """Modal with progress in the status bar and the panel; Esc cancels; the UI stays responsive."""
        if bpy.app.background:
            return self.execute(context)
        try:
            self._bake = self._start(context)
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
        job = self._bake.job
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
        return self._end(context, self._bake)


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
