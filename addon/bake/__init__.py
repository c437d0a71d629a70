"""The bake from Blender: the job, a child process of Blender's Python (`job`), and the Bake
section's count of what a bake would take (`plan`). Gathers the scene through the scene room.
"""
