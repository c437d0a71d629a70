"""bpy.types.Operator classes (bake, clear, export, materialize, preview toggle, benchmark).

CLASSES lists them in registration order; addon/ registers them. None exist yet: they come with
the Blender-extension issue.
"""
CLASSES: list = []
