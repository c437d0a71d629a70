"""HLOD Bake & Preview: the Blender extension's entry point, and its registration in one place
(DESIGN §2, §8; STYLE: each UI module exports its classes in one list, registered here in order
and unregistered in reverse; registration errors are not silenced).

Imports run one way: hlod_core (no bpy) <- addon/ (adapters: properties, preview, scene_mesh,
bake_job, benchmark, settings, cli) <- operators/, panels/ (UI) <- this module. Adapters never import
UI code. Blender imports this package as bl_ext.<repo>.hlod and calls register()/unregister().
Both are reversible and safe to run twice: register() on a registered add-on unregisters first;
unregister() on an unregistered one does nothing. unregister() and loading a .blend stop the
preview, which removes its draw handler and frees its GL objects. The imports are deferred so the
package (and hlod_core below it) can be imported outside Blender.
"""
_registered = False


def _classes() -> list:
    from .addon import properties
    from .operators import CLASSES as OPERATOR_CLASSES
    from .panels import CLASSES as PANEL_CLASSES

    return [*properties.CLASSES, *OPERATOR_CLASSES, *PANEL_CLASSES]


def _on_load_pre(*_args) -> None:
    from .addon import preview

    preview.stop(reason="a file was loaded")


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
    bpy.app.handlers.load_pre.append(persistent(_on_load_pre))  # persistent returns the function itself
    cli.register()  # blender -b --command hlod ...
    _registered = True


def unregister() -> None:
    global _registered
    if not _registered:
        return
    import bpy

    from .addon import cli, preview, properties

    preview.shutdown()  # stops the preview and frees the private context too
    cli.unregister()
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    properties.unregister()
    for cls in reversed(_classes()):
        bpy.utils.unregister_class(cls)
    _registered = False

