"""Adapters between Blender and hlod_core (docs/development.md#layout, §8): scene properties (`properties`), the
viewport preview (`preview`), Blender meshes in and out (`scene_mesh`), the bake's child process, whose
progress the modal operator polls (`bake_job`), the Benchmark's camera path (`benchmark`), property group to core
settings (`settings`), the background command (`cli`) and the current GL context (`glcontext`).
Nothing here imports operators/ or panels/; registration lives in the package's top-level
`__init__.py`.
"""
