"""hlod_core: bake, store, inspect and traverse octree HLODs. Never imports bpy (DESIGN §2).

Public API:
    meshio.load_inputs / meshio.from_arrays -> TriangleMesh
    bake.bake(mesh, BakeSettings, progress=, cancel=) -> hierarchy.Hlod
    fileformat.save / fileformat.load; checks.check(hlod)
    renderer.Renderer (moderngl: standalone EGL or a caller's context)
    traversal.make(method, hlod, renderer, RuntimeSettings).frame(metrics.View) -> FrameStats
    camera.load_path / camera.inspection_path; runner.run_path
"""
__version__ = "0.1.0"
