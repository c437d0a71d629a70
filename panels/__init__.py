"""bpy.types.Panel classes of the 3D viewport's "HLOD" sidebar tab.

CLASSES lists them in registration order; addon/ registers them. None exist yet: they come with
the Blender-extension issue.
"""
CLASSES: list = []
