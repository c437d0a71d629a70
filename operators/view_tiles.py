"""View in Browser (`hlod.view_tiles`): serves a 3D Tiles export (the last one Export wrote,
`scene.hlod.tiles_dir`, or a folder picked) and a CesiumJS viewer page on 127.0.0.1 through the
add-on's one server (addon/tiles_server.py), and opens the page with `webbrowser`; pressed again it
opens the page again; `stop=True` closes the server, as unregistering the class does.
"""
from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, StringProperty

from ..addon import tiles_server
from ..addon.properties import BLEND_RELATIVE_PATH, stored_path
from ..hlod_core.core.errors import HlodError, InputError

ERROR_PREFIX = "View in browser: "


def _tiles_folder(props, picked: str) -> str:
    """The folder to serve: the one picked, else the last 3D Tiles export; absolute."""
    folder = picked or props.tiles_dir
    if not folder:
        raise InputError(f"{ERROR_PREFIX}no 3D Tiles export yet; export with format 3D Tiles first, "
                         "or pick a folder holding tileset.json")
    return os.path.normpath(bpy.path.abspath(folder))


class HLOD_OT_view_tiles(bpy.types.Operator):
    """Serve the last 3D Tiles export on this computer (127.0.0.1) and open it in the web browser with CesiumJS"""

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
        tiles_server.stop()

    def invoke(self, context, event):
        """Without a folder and with no 3D Tiles export yet: pick a folder first."""
        if not (self.stop or self.directory or context.scene.hlod.tiles_dir):
            context.window_manager.fileselect_add(self)
            return {"RUNNING_MODAL"}
        return self.execute(context)

    def execute(self, context):
        if self.stop:
            tiles_server.stop()
            return {"FINISHED"}
        props = context.scene.hlod
        try:
            folder = _tiles_folder(props, self.directory)
            url = tiles_server.serve(folder)
        except (HlodError, OSError) as exc:
            text = str(exc)
            self.report({"ERROR"}, text if text.startswith(ERROR_PREFIX) else ERROR_PREFIX + text)
            return {"CANCELLED"}
        if self.directory:
            props.tiles_dir = stored_path(folder)  # pressed again, it serves this folder
        import webbrowser

        opened = webbrowser.open(url)
        self.report({"INFO"}, f"HLOD viewer: {folder} at {url}" + ("" if opened else " (no web browser found)"))
        return {"FINISHED"}


CLASSES = [HLOD_OT_view_tiles]
