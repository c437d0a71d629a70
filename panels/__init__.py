"""The 3D viewport's sidebar tab "HLOD" (N panel): sections Bake (with a running bake's progress and
the last bake's summary), Preview (with Export and View in Browser, and the viewer's address and Stop
while it serves; Benchmark and Tune to PSNR with its target and last result), Overlay, Statistics.
Draw code reads state only: the count of changed sources is kept current by the depsgraph handler
(addon/scene/source_record.py), not computed here."""
import bpy

from ..addon import tiles_server
from ..addon.bake import job as bake_job
from ..addon.bake import plan as bake_plan
from ..addon.preview import corner_text
from ..addon.preview.live import PREVIEW
from ..addon.scene import source_record
from ..addon.scene.place import place_line


class _HlodPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "HLOD"


class _HlodSection(_HlodPanel):
    """A section of the HLOD tab, below its main panel."""

    bl_parent_id = "HLOD_PT_main"


#: The read-only statistics the Statistics section shows, in order (scene.hlod's properties).
STATISTICS = ("stat_drawn", "stat_tris", "stat_queries", "stat_rarn", "stat_d", "stat_stall_ms", "stat_frame_ms",
              "stat_resident_mb", "stat_waiting", "stat_changed")


class HLOD_PT_main(_HlodPanel, bpy.types.Panel):
    bl_label = "HLOD"

    def draw(self, context):
        props = context.scene.hlod
        self.layout.label(text=props.file or "nothing baked yet", icon="FILE")
        self.layout.label(text=props.status)


class HLOD_PT_bake(_HlodSection, bpy.types.Panel):
    bl_label = "Bake"

    def draw(self, context):
        props, layout = context.scene.hlod, self.layout
        layout.prop(props, "source")
        if props.source == "COLLECTION":
            layout.prop(props, "collection")
        layout.prop(props, "target_tris")
        layout.prop(props, "max_depth")
        layout.prop(props, "quality_threshold")
        layout.prop(props, "error")
        row = layout.row()
        row.prop(props, "proxy_materials")
        sub = row.row()
        sub.active = props.proxy_materials
        sub.prop(props, "texture_cap")
        row = layout.row()
        row.prop(props, "jobs")
        row.prop(props, "use_cache")
        layout.prop(props, "output_path")
        row = layout.row(align=True)
        row.operator("hlod.bake", icon="MOD_DECIM")
        row.operator("hlod.clear", icon="X", text="")
        _draw_bake_state(layout, context, props)
        layout.prop(props, "file")


def _draw_bake_state(layout, context, props) -> None:
    """The running bake's progress (read from its child process's progress lines), else what a bake
    would take (addon/bake/plan.py) and how the last bake went (time, jobs, and how much of it came
    from the cache)."""
    job = bake_job.active()
    if job is not None:
        layout.progress(factor=job.percent / 100.0, type="BAR", text=job.status_line())  # Blender 4.0+
        layout.label(text="Esc cancels", icon="CANCEL")
        return
    plan = bake_plan.line(context.scene)
    if plan:
        layout.label(text=plan, icon="MESH_DATA")
    if props.last_bake:
        layout.label(text=props.last_bake, icon="INFO")


class HLOD_PT_preview(_HlodSection, bpy.types.Panel):
    bl_label = "Preview"

    def draw(self, context):
        props, layout = context.scene.hlod, self.layout
        on = PREVIEW.running()
        layout.operator("hlod.preview_toggle", text="Stop Preview" if on else "Start Preview",
                        icon="HIDE_OFF" if on else "HIDE_ON", depress=on)
        if on:
            _draw_sources(layout)
        layout.prop(props, "method")
        col = layout.column(align=True)
        col.prop(props, "tau")
        col.prop(props, "bias")
        sub = col.column(align=True)
        sub.enabled = props.bias == "P"
        sub.prop(props, "s")
        sub.prop(props, "t")
        sub.prop(props, "step")
        if not props.step:
            sub.prop(props, "k")
        col.prop(props, "alpha")
        col.prop(props, "skip_queries")
        col.prop(props, "multiquery")
        col.prop(props, "batch_queries")
        row = col.row()
        row.active = props.method == "coh"  # the prediction is Coh's
        row.prop(props, "predict_new")
        layout.prop(props, "gpu_budget_mb")
        layout.prop(props, "private_context")
        layout.operator("hlod.materialize", icon="OUTLINER_OB_MESH")
        row = layout.row(align=True)
        row.operator("hlod.export", icon="EXPORT")
        row.operator("hlod.view_tiles", icon="URL")
        _draw_place(layout, context.scene)
        _draw_viewer(layout)
        row = layout.row(align=True)
        row.operator("hlod.benchmark", icon="TIME")
        row.operator("hlod.tune_psnr", icon="PREFERENCES")
        layout.prop(props, "psnr_target")
        if props.last_tuning:
            layout.label(text=props.last_tuning, icon="INFO")


def _draw_place(layout, scene) -> None:
    """Where a 3D Tiles export stands on the globe: the mode, the fields of a typed place, and the
    place the next export takes (or why it cannot)."""
    props = scene.hlod
    col = layout.column(align=True)
    col.prop(props, "place_mode")
    if props.place_mode == "MANUAL":
        row = col.row(align=True)
        row.prop(props, "place_longitude")
        row.prop(props, "place_latitude")
        row = col.row(align=True)
        row.prop(props, "place_height")
        row.prop(props, "place_heading")
    col.label(text=place_line(scene), icon="WORLD_DATA")


def _draw_viewer(layout) -> None:
    """While the 3D Tiles viewer serves: its address, and Stop."""
    url = tiles_server.url()
    if url is None:
        return
    row = layout.row(align=True)
    row.label(text=f"Serving at {url}", icon="WORLD")
    row.operator("hlod.view_tiles", text="Stop", icon="CANCEL").stop = True


def _draw_sources(layout) -> None:
    """What the preview stands in for: hidden sources, and those changed since the bake (Re-bake)."""
    recorded, hidden = PREVIEW.sources_in_place()
    if not recorded:
        layout.label(text="Sources not recorded for this file: they stay visible", icon="INFO")
        layout.operator("hlod.bake", text="Bake to Record Them", icon="MOD_DECIM")
        return
    layout.label(text=f"{hidden} of {recorded} baked objects hidden", icon="HIDE_ON")
    tracker = source_record.tracker()
    if tracker is not None and tracker.changed:
        layout.label(text=corner_text.stale_message(len(tracker.changed), recorded), icon="ERROR")
        layout.operator("hlod.bake", text="Re-bake", icon="FILE_REFRESH").recorded = True


class HLOD_PT_overlay(_HlodSection, bpy.types.Panel):
    bl_label = "Overlay"

    def draw(self, context):
        props, layout = context.scene.hlod, self.layout
        layout.prop(props, "show_modulation")
        layout.label(text="blue weak, magenta moderate, red strong")
        layout.prop(props, "show_boxes")
        layout.prop(props, "show_delayed")
        layout.prop(props, "show_rarn")
        layout.prop(props, "show_corner_text")


class HLOD_PT_statistics(_HlodSection, bpy.types.Panel):
    bl_label = "Statistics"

    def draw(self, context):
        props, col = context.scene.hlod, self.layout.column(align=True)
        for name in STATISTICS:
            row = col.row()
            row.enabled = False
            row.prop(props, name)


CLASSES = [HLOD_PT_main, HLOD_PT_bake, HLOD_PT_preview, HLOD_PT_overlay, HLOD_PT_statistics]
