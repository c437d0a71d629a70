"""hlod_core: bake, store, inspect and traverse octree HLODs. Never imports bpy (DESIGN §2).

Public API:
    meshio.load_inputs / meshio.from_arrays -> TriangleMesh
    bake.bake(mesh, BakeSettings, progress=, cancel=) -> hierarchy.Hlod
    fileformat.save / fileformat.load; checks.check(hlod)
    renderer.Renderer (moderngl: standalone EGL or a caller's context; GL entry points and enums in
        gl_functions, query objects in queries, host GL state in gl_state)
    traversal.methods.make(method, hlod, renderer, settings=RuntimeSettings).frame(view.View) -> FrameStats
        (any renderer with traversal.protocol.NodeRenderer's methods; counters named in traversal.stats.COUNTERS)
    camera.load_path / camera.inspection_path; runner.run_path
    evaluate.evaluate (report.json, report.md via report_text, figures via report_figures and
        showcase; image error in imagemetrics, alpha estimators in alpha_study)
"""
__version__ = "0.1.0"
