"""Registration in one place (DESIGN §8, STYLE: one list per UI module, registered in order and
unregistered in reverse; errors are not silenced).

The operators, panels and properties themselves arrive with the Blender-extension issue; this
module is the structure they plug into.
"""
import bpy

from ..operators import CLASSES as OPERATOR_CLASSES
from ..panels import CLASSES as PANEL_CLASSES

CLASSES = [*OPERATOR_CLASSES, *PANEL_CLASSES]


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
