"""HLOD Bake & Preview: the Blender extension's entry point (DESIGN §2).

Blender imports this package (as bl_ext.<repo>.hlod) and calls register()/unregister(); both
delegate to addon/, the one place where classes are registered. The imports are deferred so the
package can be imported outside Blender (hlod_core never needs bpy).
"""


def register():
    from .addon import register as register_addon

    register_addon()


def unregister():
    from .addon import unregister as unregister_addon

    unregister_addon()
