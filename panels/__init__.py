"""The 3D viewport's sidebar tab "HLOD" (N panel): sections Bake, Preview, Overlay, Statistics."""
import bpy

from ..addon import preview


class _HlodPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "HLOD"


class HLOD_PT_main(_HlodPanel, bpy.types.Panel):
    bl_label = "HLOD"

    def draw(self, context):
        props = context.scene.hlod
        self.layout.label(text=props.file or "nothing baked yet", icon="FILE")
        self.layout.label(text=props.status)


class HLOD_PT_bake(_HlodPanel, bpy.types.Panel):
    bl_label = "Bake"
    bl_parent_id = "HLOD_PT_main"

    def draw(self, context):
        props, layout = context.scene.hlod, self.layout
        layout.prop(props, "source")
        if props.source == "COLLECTION":
            layout.prop(props, "collection")
        layout.prop(props, "target_tris")
        layout.prop(props, "max_depth")
        layout.prop(props, "quality_threshold")
        layout.prop(props, "output_path")
        row = layout.row(align=True)
        row.operator("hlod.bake", icon="MOD_DECIM")
        row.operator("hlod.clear", icon="X", text="")
        layout.prop(props, "file")


class HLOD_PT_preview(_HlodPanel, bpy.types.Panel):
    bl_label = "Preview"
    bl_parent_id = "HLOD_PT_main"

    def draw(self, context):
        props, layout = context.scene.hlod, self.layout
        on = preview.running()
        layout.operator("hlod.preview_toggle", text="Stop Preview" if on else "Start Preview",
                        icon="HIDE_OFF" if on else "HIDE_ON", depress=on)
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
        layout.prop(props, "private_context")
        row = layout.row(align=True)
        row.operator("hlod.materialize", icon="OUTLINER_OB_MESH")
        row.operator("hlod.export", icon="EXPORT")
        layout.operator("hlod.benchmark", icon="TIME")


class HLOD_PT_overlay(_HlodPanel, bpy.types.Panel):
    bl_label = "Overlay"
    bl_parent_id = "HLOD_PT_main"

    def draw(self, context):
        props, layout = context.scene.hlod, self.layout
        layout.prop(props, "show_modulation")
        layout.label(text="blue weak, magenta moderate, red strong")
        layout.prop(props, "show_boxes")
        layout.prop(props, "show_delayed")
        layout.prop(props, "show_rarn")


class HLOD_PT_statistics(_HlodPanel, bpy.types.Panel):
    bl_label = "Statistics"
    bl_parent_id = "HLOD_PT_main"

    def draw(self, context):
        props, col = context.scene.hlod, self.layout.column(align=True)
        for name in ("stat_drawn", "stat_tris", "stat_queries", "stat_rarn", "stat_d", "stat_stall_ms", "stat_frame_ms"):
            row = col.row()
            row.enabled = False
            row.prop(props, name)


CLASSES = [HLOD_PT_main, HLOD_PT_bake, HLOD_PT_preview, HLOD_PT_overlay, HLOD_PT_statistics]
