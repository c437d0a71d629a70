"""HLOD Bake & Preview: the Blender extension's entry point, and its registration in one place
(each UI module exports its classes in one list, registered here in order and unregistered in
reverse; registration errors are not silenced; docs/development.md#layout).

Imports run one way: hlod_core (no bpy) <- addon/ (the adapters, in rooms: addon/__init__.py) <-
operators/, panels/ (UI) <- this module. Adapters never import UI code. Blender imports this
package as bl_ext.<repo>.hlod and calls register()/unregister(). Both are reversible and safe to
run twice: register() on a registered add-on unregisters first; unregister() on an unregistered one
does nothing. unregister() and loading a .blend stop the preview, which removes its draw handler and
frees its GL objects. The imports are deferred so the package (and hlod_core below it) can be
imported outside Blender.

Application handlers (all persistent, listed once in `_HANDLERS`, removed in unregister; the preview
hides the objects the bake took, and no way out may leave them hidden):
- load_pre: stop the preview (it shows the sources it hid in the file being left) and the 3D Tiles
  viewer's server (View in Browser);
- load_post: a record of hidden objects in the loaded file is a leftover (an autosave or
  quit.blend written while a preview ran): show those objects again;
- save_pre / save_post: show the hidden sources for the write, hide them again after it;
- undo_post / redo_post: hide the running preview's sources again (or restore a leftover record),
  and recount the sources changed since the bake;
- depsgraph_update_post / frame_change_post: recount the changed sources from the update, and
  (on a timer) what a bake of the Source setting would take.
"""
_registered = False


def _classes() -> list:
    from .addon import properties
    from .operators import CLASSES as OPERATOR_CLASSES
    from .panels import CLASSES as PANEL_CLASSES

    return [*properties.CLASSES, *OPERATOR_CLASSES, *PANEL_CLASSES]


def _on_load_pre(*_args) -> None:
    from .addon import tiles_server
    from .addon.preview import live

    live.PREVIEW.stop(reason="a file was loaded")
    tiles_server.stop()


def _on_load_post(*_args) -> None:
    from .addon.scene import source_hiding

    source_hiding.restore_leftovers()


def _on_save_pre(*_args) -> None:
    from .addon.scene import source_hiding

    source_hiding.suspend()


def _on_save_post(*_args) -> None:
    from .addon.scene import source_hiding

    source_hiding.resume()


def _on_undo_redo(*_args) -> None:
    from .addon.preview import live
    from .addon.scene import source_hiding, source_record

    source_hiding.on_undo()
    source_record.on_undo()
    live.redraw()


def _on_depsgraph_update(scene, depsgraph=None, *_args) -> None:
    from .addon.bake import plan as bake_plan
    from .addon.preview import live
    from .addon.scene import source_record

    bake_plan.schedule()  # the Bake section's count of what a bake would take
    if depsgraph is not None and source_record.on_depsgraph_update(scene, depsgraph):
        live.redraw()  # the panel and the corner text show the new count


_HANDLERS = (("load_pre", _on_load_pre), ("load_post", _on_load_post), ("save_pre", _on_save_pre),
             ("save_post", _on_save_post), ("undo_post", _on_undo_redo), ("redo_post", _on_undo_redo),
             ("depsgraph_update_post", _on_depsgraph_update), ("frame_change_post", _on_depsgraph_update))


def register() -> None:
    global _registered
    import bpy
    from bpy.app.handlers import persistent

    from .addon import cli, properties

    if _registered:
        unregister()
    for cls in _classes():
        bpy.utils.register_class(cls)
    properties.register()
    for event, handler in _HANDLERS:
        getattr(bpy.app.handlers, event).append(persistent(handler))  # persistent returns the function itself
    cli.register()  # blender -b --command hlod ...
    _registered = True


def unregister() -> None:
    global _registered
    if not _registered:
        return
    import bpy

    from .addon import cli, properties
    from .addon.bake import plan as bake_plan
    from .addon.preview.live import PREVIEW

    PREVIEW.shutdown()  # stops the preview (the hidden sources are shown) and frees the private context too
    cli.unregister()
    for event, handler in reversed(_HANDLERS):
        handlers = getattr(bpy.app.handlers, event)
        if handler in handlers:
            handlers.remove(handler)
    bake_plan.clear()
    properties.unregister()
    for cls in reversed(_classes()):
        bpy.utils.unregister_class(cls)
    _registered = False

