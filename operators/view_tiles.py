"""View in Browser (`hlod.view_tiles`): serves a 3D Tiles export (the last one Export wrote,
`scene.hlod.tiles_dir`, or a folder picked) and a CesiumJS viewer page on 127.0.0.1 from a thread
of Blender's process (hlod_core/export/viewer.py, imported only when the button is used), and opens
the page with `webbrowser`; pressed again it opens the page again; `stop=True` closes the server.

One server at a time, held here (`viewer_url`, `viewer_stop`); it is closed when the operator's
class is unregistered (the add-on disabled) and on file load (the add-on's load_pre handler), so no
thread or port outlives the add-on or the file.
"""
from __future__ import annotations

import os

import bpy
from bpy.props import BoolProperty, StringProperty

from ..addon.properties import BLEND_RELATIVE_PATH, stored_path
from ..hlod_core.core.errors import HlodError, InputError

ERROR_PREFIX = "View in browser: "

_viewer = None  # the running hlod_core.export.viewer.ViewerServer, or None
_viewer_folder = ""  # the absolute folder it serves


def running_server():
    """The running hlod_core.export.viewer.ViewerServer, or None."""
    return _viewer


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
        raise InputError(f"{ERROR_PREFIX}no 3D Tiles export yet; export with format 3D Tiles first, "
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
            self.report({"ERROR"}, text if text.startswith(ERROR_PREFIX) else ERROR_PREFIX + text)
            return {"CANCELLED"}
        if self.directory:
            props.tiles_dir = stored_path(folder)  # pressed again, it serves this folder
        import webbrowser

        opened = webbrowser.open(url)
        self.report({"INFO"}, f"HLOD viewer: {folder} at {url}" + ("" if opened else " (no web browser found)"))
        return {"FINISHED"}


CLASSES = [HLOD_OT_view_tiles]
