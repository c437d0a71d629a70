"""Registration in one place (DESIGN §8, STYLE: one list per UI module, registered in order and
unregistered in reverse; errors are not silenced). Reversible and safe to run twice: register()
on a registered add-on unregisters first; unregister() on an unregistered one does nothing.
unregister() and loading a .blend stop the preview, which removes its draw handler and frees its
GL objects. The command-line command `hlod` (addon/cli.py) is registered here too."""
import bpy
from bpy.app.handlers import persistent

from ..operators import CLASSES as OPERATOR_CLASSES
from ..panels import CLASSES as PANEL_CLASSES
from . import cli, preview, properties

CLASSES = [*properties.CLASSES, *OPERATOR_CLASSES, *PANEL_CLASSES]
_registered = False
_cli_command = None


@persistent
def _on_load_pre(*_args) -> None:
    preview.stop(reason="a file was loaded")


def register() -> None:
    global _registered
    if _registered:
        unregister()
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    properties.register()
    bpy.app.handlers.load_pre.append(_on_load_pre)
    global _cli_command
    _cli_command = bpy.utils.register_cli_command("hlod", cli.execute)  # blender -b --command hlod ...
    _registered = True


def unregister() -> None:
    global _registered
    if not _registered:
        return
    preview.stop()
    global _cli_command
    if _cli_command is not None:
        bpy.utils.unregister_cli_command(_cli_command)
        _cli_command = None
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    properties.unregister()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    _registered = False
