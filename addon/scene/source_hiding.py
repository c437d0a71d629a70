"""Hiding the objects a bake took while the preview draws the HLOD in their place, and giving back
exactly the visibility there was: `Object.hide_set` in the view layer (the eye, the H key), with
each object's selection recorded on the scene (`scene.hlod.hidden_objects`) before anything is
hidden, so no file, undo step or crash leaves them hidden without a record. Every way out shows
them again: stop (`restore`), save (`suspend`/`resume`), load (`restore_leftovers`), undo/redo
(`on_undo`). While Blender runs, objects are found by `session_uid`; in a saved record, by name.
Why: docs/how-it-works.md#hiding-the-sources-while-the-preview-runs
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import bpy

log = logging.getLogger(__name__)


@dataclass
class _Entry:
    uid: int  # Object.session_uid
    name: str
    selected: bool


@dataclass
class HiddenSet:
    """What one preview hid: in the scene with session_uid `scene_uid`, view layer `view_layer`."""

    scene_uid: int
    view_layer: str
    entries: list[_Entry] = field(default_factory=list)
    suspended: bool = False  # between save_pre and save_post


_hidden: HiddenSet | None = None


def hidden() -> HiddenSet | None:
    return _hidden


def hide(scene, view_layer, names) -> HiddenSet:
    """Hide the objects of `view_layer` named in `names` that are visible now; record them."""
    global _hidden
    restore()
    hidden_set = HiddenSet(scene.session_uid, view_layer.name)
    for name in names:
        obj = view_layer.objects.get(name)
        if obj is None or obj.hide_get(view_layer=view_layer):
            continue  # not in this view layer (nothing to hide), or hidden by the user already
        hidden_set.entries.append(_Entry(obj.session_uid, obj.name, obj.select_get(view_layer=view_layer)))
    _hidden = hidden_set
    _hide_entries(scene, view_layer, hidden_set)
    return hidden_set


def restore(only: HiddenSet | None = None) -> int:
    """Show again what was hidden (and reselect what was selected); forget it. `only`: do so only
    if that is the set hidden now (a deferred restore must not undo a later preview's hiding).
    Returns the number of objects shown."""
    global _hidden
    hidden_set = _hidden
    if hidden_set is None or (only is not None and only is not hidden_set):
        return 0
    _hidden = None
    scene, view_layer = _find(hidden_set)
    if view_layer is None:
        return 0
    shown = 0 if hidden_set.suspended else _show_entries(view_layer, hidden_set)
    _clear_record(scene)
    return shown


def suspend() -> None:
    """save_pre: show the hidden objects and clear the record, keeping the set for `resume`."""
    hidden_set = _hidden
    if hidden_set is None or hidden_set.suspended:
        return
    scene, view_layer = _find(hidden_set)
    if view_layer is None:
        return
    _show_entries(view_layer, hidden_set)
    _clear_record(scene)
    hidden_set.suspended = True


def resume() -> None:
    """save_post: hide the set again."""
    hidden_set = _hidden
    if hidden_set is None or not hidden_set.suspended:
        return
    hidden_set.suspended = False
    scene, view_layer = _find(hidden_set)
    if view_layer is not None:
        _hide_entries(scene, view_layer, hidden_set)


def on_undo() -> None:
    """undo_post / redo_post (module notes): re-hide the running preview's objects, or restore a
    record the undo step brought back."""
    hidden_set = _hidden
    if hidden_set is None:
        restore_leftovers()
        return
    scene, view_layer = _find(hidden_set)
    if view_layer is not None:
        _hide_entries(scene, view_layer, hidden_set)
    for other in bpy.data.scenes:  # another scene's leftover record (an older preview's)
        if other != scene:
            _restore_record(other)


def restore_leftovers() -> int:
    """load_post: show the objects of every record found in the data (module notes); returns how many."""
    return sum(_restore_record(scene) for scene in bpy.data.scenes)


# --- helpers -----------------------------------------------------------------------------------------

def _find(hidden_set: HiddenSet):
    scene = next((s for s in bpy.data.scenes if s.session_uid == hidden_set.scene_uid), None)
    view_layer = scene.view_layers.get(hidden_set.view_layer) if scene is not None else None
    return scene, view_layer


def _hide_entries(scene, view_layer, hidden_set: HiddenSet) -> None:
    """Record, then hide: each entry still visible gets its selection noted and is hidden."""
    objects = {obj.session_uid: obj for obj in view_layer.objects}
    for entry in hidden_set.entries:
        obj = objects.get(entry.uid)
        if obj is not None and not obj.hide_get(view_layer=view_layer):
            entry.selected, entry.name = obj.select_get(view_layer=view_layer), obj.name
    _write_record(scene, view_layer, hidden_set)
    for entry in hidden_set.entries:
        obj = objects.get(entry.uid)
        if obj is not None and not obj.hide_get(view_layer=view_layer):
            obj.hide_set(True, view_layer=view_layer)


def _show_entries(view_layer, hidden_set: HiddenSet) -> int:
    objects = {obj.session_uid: obj for obj in view_layer.objects}
    shown = 0
    for entry in hidden_set.entries:
        obj = objects.get(entry.uid)
        if obj is None:
            continue  # deleted (or unlinked from the view layer) since
        obj.hide_set(False, view_layer=view_layer)
        if entry.selected:
            obj.select_set(True, view_layer=view_layer)
        shown += 1
    return shown


def _write_record(scene, view_layer, hidden_set: HiddenSet) -> None:
    props = scene.hlod
    props.hidden_objects.clear()
    for entry in hidden_set.entries:
        item = props.hidden_objects.add()
        item.name, item.selected = entry.name, entry.selected
    props.hidden_view_layer = view_layer.name


def _clear_record(scene) -> None:
    if scene is not None and (len(scene.hlod.hidden_objects) or scene.hlod.hidden_view_layer):
        scene.hlod.hidden_objects.clear()
        scene.hlod.hidden_view_layer = ""


def _restore_record(scene) -> int:
    """Show the objects a saved record names (by name), reselect, clear the record."""
    props = scene.hlod
    if not len(props.hidden_objects):
        _clear_record(scene)
        return 0
    view_layer = scene.view_layers.get(props.hidden_view_layer)
    shown = 0
    if view_layer is not None:
        for item in props.hidden_objects:
            obj = view_layer.objects.get(item.name)
            if obj is None:
                continue
            obj.hide_set(False, view_layer=view_layer)
            if item.selected:
                obj.select_set(True, view_layer=view_layer)
            shown += 1
    log.info("HLOD: %d object(s) a preview had hidden in scene %r shown again (a leftover record)", shown, scene.name)
    _clear_record(scene)
    return shown
