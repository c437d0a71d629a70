"""Toggle Preview and Materialize (docs/user-guide.md): the live preview in the 3D viewport (addon/preview/live.py),
and Blender mesh objects of its current front or of every node at a depth (addon/scene/node_objects.py)."""
from __future__ import annotations

import bpy
from bpy.props import IntProperty

from ..addon.preview.live import PREVIEW
from ..addon.scene import node_objects as materialize
from ..hlod_core.core.errors import HlodError, InputError
from ..hlod_core.io import hlod_file


class HLOD_OT_preview_toggle(bpy.types.Operator):
    """Show or hide the live HLOD preview in the 3D viewport"""

    bl_idname = "hlod.preview_toggle"
    bl_label = "Toggle HLOD Preview"

    def execute(self, context):
        if PREVIEW.running():
            PREVIEW.stop()
            return {"FINISHED"}
        try:
            PREVIEW.start(context.scene)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        recorded, hidden = PREVIEW.sources_in_place()
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
            hlod = PREVIEW.current_hlod() or (hlod_file.load(bpy.path.abspath(props.file)) if props.file else None)
            if hlod is None:
                raise InputError("Materialize: no baked file; run Bake first")
            if self.depth < 0:
                stats = PREVIEW.last_stats()
                if stats is None or not stats.drawn:
                    raise InputError("Materialize: the preview has not drawn a frame yet; start it or choose a depth")
                nodes, label = stats.drawn, "front"
            else:
                nodes, label = materialize.nodes_at_depth(hlod, self.depth), f"depth {self.depth}"
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        collection = materialize.materialize(hlod, nodes, f"HLOD {label}")
        self.report({"INFO"}, f"{len(collection.objects)} objects in collection {collection.name!r}")
        return {"FINISHED"}


CLASSES = [HLOD_OT_preview_toggle, HLOD_OT_materialize]
