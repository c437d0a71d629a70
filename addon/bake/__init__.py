"""The bake from Blender: the one flow from the chosen objects to a started bake job that the Bake
operator and the background command share (`from_scene`), the job itself, a child process of
Blender's Python (`job`), and the Bake section's count of what a bake would take (`plan`). Gathers
the scene through the scene room and its materials through the materials room.
"""
