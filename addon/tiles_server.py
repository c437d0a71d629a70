"""The one server of View in Browser: a 3D Tiles export and a CesiumJS viewer page on 127.0.0.1,
served from a thread of Blender's process (hlod_core/export/viewer.py, imported only when a server
starts: enabling the add-on imports no viewer code). The operator starts it (`serve`), the panel
shows its page (`url`), and `stop` closes it: the operator's Stop, its class unregistered (the
add-on disabled) and the load_pre handler (a file loaded), so no thread or port outlives the add-on
or the file.
"""
from __future__ import annotations

_server = None  # the running hlod_core.export.viewer.ViewerServer, or None
_folder = ""  # the absolute folder it serves


def running_server():
    """The running hlod_core.export.viewer.ViewerServer, or None."""
    return _server


def url() -> str | None:
    """The running viewer's page ("http://127.0.0.1:N/"), None when none runs (the panel's line)."""
    return _server.url if _server is not None else None


def stop() -> None:
    """Close the running viewer: its thread ends and its port is free when this returns. Nothing
    when none runs; safe to call from handlers and unregister."""
    global _server, _folder
    server, _server, _folder = _server, None, ""
    if server is not None:
        server.close()


def serve(folder: str) -> str:
    """Serve `folder` (absolute: the running server if it serves it already, else a new one, which
    replaces the running one once it has started); its page's URL. InputError: no tileset.json
    there, CesiumJS not found."""
    global _server, _folder
    if _server is not None and _folder == folder:
        return _server.url
    from ..hlod_core.export import viewer  # here, not above: enabling the add-on imports no viewer code

    server = viewer.serve(folder)
    server.start()
    stop()
    _server, _folder = server, folder
    return server.url
