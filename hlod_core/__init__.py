"""hlod_core: bake, store and inspect octree HLODs. Never imports bpy (DESIGN §2).

Public API:
    meshio.load_inputs / meshio.from_arrays -> TriangleMesh
    bake.bake(mesh, BakeSettings, progress=, cancel=) -> Hlod
    fileformat.save / fileformat.load
    checks.check(hlod)
"""
__version__ = "0.1.0"
