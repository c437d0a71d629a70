"""What a bake of the current Source would take, for the Bake section before it starts: "Will bake
12 objects, 1,234,567 triangles" (and what it would skip). Counted by
scene/objects.py planned_count (the bake's own instances, no mesh copied) on a timer at most every
REFRESH_S after a depsgraph update, never in draw code; background mode (no panel) counts nothing.
"""
from __future__ import annotations

import bpy

from ...hlod_core.core.errors import InputError
from ..scene.objects import Skipped, note_hidden, planned_count, source_objects

#: Seconds between a depsgraph update and the recount (updates in between are counted once).
REFRESH_S = 0.5

_lines: dict[str, str] = {}  # scene name_full -> the Bake section's line
_pending = False


def line(scene) -> str:
    """The Bake section's line for `scene` ("" before the first count)."""
    return _lines.get(scene.name_full, "")


def schedule() -> None:
    """Recount after REFRESH_S (the depsgraph handler calls this on every update)."""
    global _pending
    if _pending or bpy.app.background:
        return
    _pending = True
    bpy.app.timers.register(_refresh, first_interval=REFRESH_S, persistent=True)  # a file load would drop it


def _refresh() -> None:
    global _pending
    _pending = False
    context = bpy.context
    if context.scene is None or not hasattr(context.scene, "hlod"):
        return
    _lines[context.scene.name_full] = count_line(context)
    for window in context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def count_line(context) -> str:
    """'Will bake N objects, T triangles' for the scene's Source setting, with what it would skip,
    or why it cannot bake."""
    try:
        objects = source_objects(context, context.scene.hlod)
    except InputError as exc:
        return str(exc)
    depsgraph = context.evaluated_depsgraph_get()
    skipped = Skipped()
    note_hidden(objects, depsgraph, skipped)
    givers, triangles = planned_count(depsgraph, objects, skipped)
    text = f"Will bake {givers} object{'s' * (givers != 1)}, {triangles:,} triangles"
    return f"{text}; {skipped.text()}" if skipped else text


def clear() -> None:
    """Forget the counts and drop a pending recount (unregister)."""
    global _pending
    _lines.clear()
    if bpy.app.timers.is_registered(_refresh):
        bpy.app.timers.unregister(_refresh)
    _pending = False
