"""Operators (DESIGN §8; ids fixed: hlod.bake, hlod.clear, hlod.preview_toggle, hlod.materialize,
hlod.export, hlod.benchmark, hlod.tune_psnr, hlod.view_tiles). Thin: they gather input, call
hlod_core / addon modules, and map typed errors (HlodError) to reports. Nothing here changes the
source objects.

Tune to PSNR (issue 15) runs hlod_core.report.tuning on the scene camera's animation (addon/benchmark.py)
and sets scene.hlod.s, t and bias to what it chose; an undo step like the other property edits.

Bake gathers the evaluated meshes on Blender's main thread and bakes them in a child process of
Blender's Python with `scene.hlod.jobs` worker processes (addon/bake_job.py; modal with progress in
the status bar and the panel, Esc cancels; synchronous in execute(), as in background mode). A bake
that fails or dies is reported; Blender and an earlier .hlod stay as they were.

Bake records the objects it took and their content keys on the scene (addon/source_record.py);
`hlod.bake(recorded=True)` is Re-bake: it bakes the recorded objects again. A bake while the
preview runs stops the preview first (its sources are hidden, and hidden objects give the depsgraph
no instances to read), then starts it again on the new file, or on the old one if the bake fails.

View in Browser (`hlod.view_tiles`, issue 17) serves a 3D Tiles export (the last one Export wrote,
`scene.hlod.tiles_dir`, or a folder picked) and a CesiumJS viewer page on 127.0.0.1 from a thread of
Blender's process (hlod_core/export/viewer.py, imported only when the button is used), and opens the page
with `webbrowser`; pressed again it opens the page again; `stop=True` closes the server. One server
at a time, held here (`viewer_url`, `viewer_stop`); it is closed when the operator's class is
unregistered (the add-on disabled) and on file load (the add-on's load_pre handler), so no thread or
port outlives the add-on or the file.
"""
from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ..addon import benchmark, preview, scene_mesh, source_record
from ..addon.bake_job import BakeJob
from ..addon.properties import BLEND_RELATIVE_PATH
from ..addon.settings import bake_settings
from ..hlod_core.bake import cache as bake_cache
from ..hlod_core.io import hlod_file
from ..hlod_core.core.errors import BakeCancelled, HlodError, InputError


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


def _stored_path(path: str) -> str:
    """Relative to the .blend when it is saved (the file moves with the project)."""
    try:
        return bpy.path.relpath(path) if bpy.data.filepath else path
    except ValueError:  # another drive on Windows
        return path


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
        self._restart = preview.running()
        if self._restart:
            preview.stop()
        out = output_path(props)
        folder = os.path.dirname(out) or "."
        if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
            raise InputError(f"Bake: cannot write {out}: folder {folder} is missing or not writable")
        if self.recorded:
            objects, missing = scene_mesh.recorded_objects(context, props)
            if missing:
                shown = ", ".join(repr(name) for name in missing[:5]) + (" ..." if len(missing) > 5 else "")
                self.report({"WARNING"}, f"Re-bake: {len(missing)} recorded object(s) renamed or deleted, "
                                         f"left out: {shown}")
        else:
            objects = scene_mesh.source_objects(context, props)
        taken: list = []
        attributes: dict = {}
        mesh = scene_mesh.evaluated_mesh(context, objects, taken=taken, attributes=attributes)
        rows = source_record.record(taken, context.evaluated_depsgraph_get())
        return mesh, out, bake_settings(props), rows, attributes or None

    def _start(self, context) -> BakeJob:
        """Gather the mesh here, on Blender's main thread, and start the bake's child process (with
        the cache folder beside the output, unless the Bake Cache setting is off)."""
        mesh, out, settings, self._rows, extra_meta = self._prepare(context)
        cache_dir = bake_cache.default_folder(out) if context.scene.hlod.use_cache else None
        bake_cache.check_folder(cache_dir)
        return BakeJob(mesh, settings, out, extra_meta=extra_meta, cache_dir=cache_dir)

    def _end(self, context, job: BakeJob) -> set[str]:
        """Report how the finished job went; the operator's return value."""
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
        props.file = _stored_path(job.output)
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
            preview.start(context.scene)
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
        self._timer = wm.event_timer_add(0.1, window=context.window)
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
    cache = result.cache
    if cache is None:
        return text + "; no cache"
    return text + f"; cache: {cache['reused_nodes']} of {cache['nodes']} inner nodes reused"


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
        preview.stop()
        props = context.scene.hlod
        props.file = ""
        source_record.store(props, [], "")  # the record belongs to the file
        return {"FINISHED"}


class HLOD_OT_preview_toggle(bpy.types.Operator):
    """Show or hide the live HLOD preview in the 3D viewport"""

    bl_idname = "hlod.preview_toggle"
    bl_label = "Toggle HLOD Preview"

    def execute(self, context):
        if preview.running():
            preview.stop()
            return {"FINISHED"}
        try:
            preview.start(context.scene)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        recorded, hidden = preview.sources_in_place()
        if not recorded:
            self.report({"WARNING"}, "HLOD preview: the scene has no record of the objects this file was baked "
                                     "from; they stay visible (bake or re-bake to record them)")
        else:
            self.report({"INFO"}, f"HLOD preview: {hidden} of {recorded} baked objects hidden while it runs")
        return {"FINISHED"}


class HLOD_OT_materialize(bpy.types.Operator):
    """Make Blender mesh objects of the preview's current front, or of every node at a depth"""

    bl_idname = "hlod.materialize"
    bl_label = "Materialize HLOD"
    bl_options = {"REGISTER", "UNDO"}

    depth: IntProperty(name="Depth", default=-1, min=-1, description="-1 = the nodes the preview drew last")

    def execute(self, context):
        props = context.scene.hlod
        try:
            hlod = preview.current_hlod() or (hlod_file.load(bpy.path.abspath(props.file)) if props.file else None)
            if hlod is None:
                raise InputError("Materialize: no baked file; run Bake first")
            if self.depth < 0:
                stats = preview.last_stats()
                if stats is None or not stats.drawn:
                    raise InputError("Materialize: the preview has not drawn a frame yet; start it or choose a depth")
                nodes, label = stats.drawn, "front"
            else:
                nodes, label = scene_mesh.nodes_at_depth(hlod, self.depth), f"depth {self.depth}"
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        collection = scene_mesh.materialize(hlod, nodes, f"HLOD {label}")
        self.report({"INFO"}, f"{len(collection.objects)} objects in collection {collection.name!r}")
        return {"FINISHED"}


class HLOD_OT_export(bpy.types.Operator):
    """Export the baked HLOD"""

    bl_idname = "hlod.export"
    bl_label = "Export HLOD"

    filepath: StringProperty(name="File Path", subtype="FILE_PATH", options=BLEND_RELATIVE_PATH,
                             description="The .hlod file, or for 3D Tiles the folder to write (tileset.json, tiles/)")
    format: EnumProperty(name="Format", items=[
        ("HLOD", "HLOD (native)", "The extension's own memory-mappable format"),
        ("3DTILES", "3D Tiles 1.1", "tileset.json with one GLB per node; geometricError = the node's error"),
    ], default="HLOD")

    def invoke(self, context, event):
        if not self.filepath:
            self.filepath = bpy.path.ensure_ext(bpy.path.abspath("//hlod_export") if bpy.data.filepath else "hlod_export", ".hlod")
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        props = context.scene.hlod
        try:
            if not props.file:
                raise InputError("Export: no baked file; run Bake first")
            if not self.filepath:
                raise InputError("Export: give a file path")
            target = bpy.path.abspath(self.filepath)
            hlod = hlod_file.load(bpy.path.abspath(props.file))
            if self.format == "3DTILES":
                from ..hlod_core.export import tiles3d

                target = target[:-5] + "_3dtiles" if target.lower().endswith(".hlod") else target
                tiles3d.export(hlod, target)
                props.tiles_dir = _stored_path(target)  # what View in Browser serves
            else:
                hlod_file.save(hlod, target)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"HLOD exported to {target}")
        return {"FINISHED"}


class HLOD_OT_benchmark(bpy.types.Operator):
    """Replay the scene camera's animation with every traversal method and write the evaluation report"""

    bl_idname = "hlod.benchmark"
    bl_label = "Benchmark HLOD"

    directory: StringProperty(name="Report Folder", subtype="DIR_PATH", default="//hlod_report",
                              options=BLEND_RELATIVE_PATH)
    repeat: IntProperty(name="Repeats", default=2, min=1, max=10)

    def execute(self, context):
        try:
            report, folder = benchmark.run(context, bpy.path.abspath(self.directory), self.repeat)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        coh, boolean = report["methods"].get("coh_p"), report["methods"].get("bool")
        extra = f"; Coh(P) {coh['dn']:.1f} nodes vs Bool {boolean['dn']:.1f}" if coh and boolean else ""
        if not report["figures"]:
            extra += "; no figures (matplotlib is not installed in Blender's Python)"
        self.report({"INFO"}, f"HLOD report: {os.path.join(folder, 'report.md')}{extra}")
        return {"FINISHED"}


class HLOD_OT_tune_psnr(bpy.types.Operator):
    """Set s and t to the fewest drawn nodes that keep the target PSNR against Bool on the camera's animation"""

    bl_idname = "hlod.tune_psnr"
    bl_label = "Tune to PSNR"
    bl_options = {"REGISTER", "UNDO"}  # s, t and bias change: one undo step

    directory: StringProperty(name="Report Folder", subtype="DIR_PATH", default="//hlod_tuning",
                              options=BLEND_RELATIVE_PATH)
    repeat: IntProperty(name="Repeats", default=1, min=1, max=10, description="Passes over the animation per round")

    def execute(self, context):
        props = context.scene.hlod
        try:
            report, folder = benchmark.tune(context, bpy.path.abspath(self.directory), self.repeat)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        p = report["psnr_target"]
        c = p["chosen"]
        props.bias, props.s, props.t = "P", c["s"], c["t"]  # bias P: s and t take effect
        props.last_tuning = (f"{p['target_db']:g} dB: s {c['s']:g}, t {c['t']:g}, {c['dn']:.1f} nodes "
                             f"(Bool {p['bool_dn']:.1f}), lowest PSNR-Y {c['psnr_y']:.1f} dB"
                             + ("" if p["met"] else " (target not met)"))
        where = os.path.join(folder, "report.md")
        extra = "" if report["figures"] else "; no figures (matplotlib is not installed in Blender's Python)"
        if p["met"]:
            self.report({"INFO"}, f"HLOD tuned: {props.last_tuning}; {len(p['candidates'])} (s, t) tried; "
                                  f"report {where}{extra}")
        else:
            self.report({"WARNING"}, f"HLOD tuning: {p['note']} s and t set to it; report {where}{extra}")
        return {"FINISHED"}


_viewer = None  # the running hlod_core.export.viewer.ViewerServer, or None
_viewer_folder = ""  # the absolute folder it serves


def viewer_url() -> str | None:
    """The running viewer's page ("http://localhost:N/"), None when none runs (the panel's line)."""
    return _viewer.url if _viewer is not None else None


def viewer_stop() -> None:
    """Close the running viewer: its thread ends and its port is free when this returns. Nothing
    when none runs; safe to call from handlers and unregister."""
    global _viewer, _viewer_folder
    server, _viewer, _viewer_folder = _viewer, None, ""
    if server is not None:
        server.close()


def _tiles_folder(props, picked: str) -> str:
    """The folder to serve: the one picked, else the last 3D Tiles export; absolute."""
    folder = picked or props.tiles_dir
    if not folder:
        raise InputError("View in browser: no 3D Tiles export yet; export with format 3D Tiles first, "
                         "or pick a folder holding tileset.json")
    return os.path.normpath(bpy.path.abspath(folder))


def _serve(folder: str) -> str:
    """Serve `folder` (the running server if it serves it already, else a new one, which replaces
    the running one once it has started); its page's URL."""
    global _viewer, _viewer_folder
    if _viewer is not None and _viewer_folder == folder:
        return _viewer.url
    from ..hlod_core.export import viewer  # here, not above: enabling the add-on imports no viewer code

    server = viewer.serve(folder)  # InputError: no tileset.json there, CesiumJS not found
    server.start()
    viewer_stop()
    _viewer, _viewer_folder = server, folder
    return server.url


class HLOD_OT_view_tiles(bpy.types.Operator):
    """Serve the last 3D Tiles export on this computer (localhost) and open it in the web browser with CesiumJS"""

    bl_idname = "hlod.view_tiles"
    bl_label = "View in Browser"

    directory: StringProperty(name="3D Tiles Folder", subtype="DIR_PATH", options={"SKIP_SAVE"} | BLEND_RELATIVE_PATH,
                              description="The folder holding tileset.json; empty = the last 3D Tiles export")
    stop: BoolProperty(name="Stop", default=False, options={"SKIP_SAVE"}, description="Stop serving the viewer")

    @classmethod
    def description(cls, context, properties):
        return "Stop serving the 3D Tiles viewer (frees its port)" if properties.stop else cls.__doc__

    @classmethod
    def unregister(cls):  # Blender calls it when the class is unregistered: the add-on is disabled
        viewer_stop()

    def invoke(self, context, event):
        """Without a folder and with no 3D Tiles export yet: pick a folder first."""
        if not (self.stop or self.directory or context.scene.hlod.tiles_dir):
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def execute(self, context):
        if self.stop:
            viewer_stop()
            return {"FINISHED"}
        props = context.scene.hlod
        try:
            folder = _tiles_folder(props, self.directory)
            url = _serve(folder)
        except (HlodError, OSError) as exc:
            text = str(exc)
            self.report({"ERROR"}, text if text.startswith("View in browser") else f"View in browser: {text}")
            return {"CANCELLED"}
        if self.directory:
            props.tiles_dir = _stored_path(folder)  # pressed again, it serves this folder
        import webbrowser

        opened = webbrowser.open(url)
        self.report({"INFO"}, f"HLOD viewer: {folder} at {url}" + ("" if opened else " (no web browser found)"))
        return {"FINISHED"}


CLASSES = [HLOD_OT_bake, HLOD_OT_clear, HLOD_OT_preview_toggle, HLOD_OT_materialize, HLOD_OT_export,
           HLOD_OT_benchmark, HLOD_OT_tune_psnr, HLOD_OT_view_tiles]
