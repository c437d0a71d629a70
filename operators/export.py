"""Export (docs/user-guide.md): the baked file as a copy of the native .hlod, or as 3D Tiles 1.1
(hlod_core/export/tiles3d.py, imported only when used), placed on the globe as the panel's Place
says (addon/scene/place.py); a 3D Tiles export is what View in Browser serves next."""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, StringProperty

from ..addon.properties import BLEND_RELATIVE_PATH, stored_path
from ..addon.scene.place import export_place
from ..hlod_core.core.errors import HlodError, InputError
from ..hlod_core.io import hlod_file

#: A 3D Tiles export named like a .hlod file goes to this folder instead: NAME.hlod -> NAME_3dtiles.
TILES_SUFFIX = "_3dtiles"
#: Draco-compressed tiles need DracoPy, whose wheels Blender's extension installer cannot take (their
#: .data folders), and re-encoded textures Pillow, which Blender lacks: the command line only
#: (docs/command-line.md, export --mesh draco --textures webp).
DRACO_NOTE = "Draco (3 to 8x smaller) and WebP/JPEG textures: command line only"


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
    mesh: EnumProperty(name="Tile Content", items=[
        ("plain", "Plain", "float32 positions, normals and colours"),
        ("quantized", "Quantized", "positions as 16-bit integers, normals 8-bit, colours 16-bit "
                                   "(KHR_mesh_quantization): 12 to 36% smaller tiles"),
    ], default="plain", description="3D Tiles only: how the tiles' vertices are stored. "
                                     "Draco compression and WebP/JPEG textures are on the command line only "
                                     "(export --mesh draco --textures webp)")
    merge_leaves: BoolProperty(name="Merge Leaves", default=False,
                               description="3D Tiles only: the leaf children of a node share one tile "
                                           "(fewer, bigger tiles: fewer requests and less JSON; culled together)")

    def draw(self, context):
        """The file browser's options: the format, the tile content and where Draco is."""
        layout = self.layout
        layout.prop(self, "format")
        col = layout.column()
        col.active = self.format == "3DTILES"
        col.prop(self, "mesh")
        col.prop(self, "merge_leaves")
        col.label(text=DRACO_NOTE, icon="INFO")

    def invoke(self, context, event):
        if not self.filepath:
            stem = bpy.path.abspath("//hlod_export") if bpy.data.filepath else "hlod_export"
            self.filepath = bpy.path.ensure_ext(stem, ".hlod")
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

                target = target[:-len(".hlod")] + TILES_SUFFIX if target.lower().endswith(".hlod") else target
                tiles3d.export(hlod, target, place=export_place(context.scene), mesh=self.mesh,
                               merge_leaves=self.merge_leaves)
                props.tiles_dir = stored_path(target)  # what View in Browser serves
            else:
                hlod_file.save(hlod, target)
        except (HlodError, OSError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"HLOD exported to {target}")
        return {"FINISHED"}


CLASSES = [HLOD_OT_export]
