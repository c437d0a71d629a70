"""hlod_core: bake, store, inspect and traverse octree HLODs. Never imports bpy (docs/development.md#layout).

Rooms (subpackages), each importing only the ones listed before it (tests/test_structure.py holds
the layering; tests/test_indexes.py holds this list and each room's own index to the tree):
    core/       typed errors, array helpers, the one atomic write, JSON reading, PNG writing, colour
                conversions and the overlay ramp, stop signals
    model/      the node table (hierarchy.Hlod), appearance (materials), view.View, camera paths
    io/         mesh and scene readers (meshes.TriangleMesh), the .hlod file, textures, built-in scenes
    traversal/  runtime settings, metrics (SSE, P_{s,t}), query boxes, the traversal methods
    render/     GL functions and state, occlusion queries, the moderngl renderer
    bake/       the bake pipeline (octree, simplification, Hausdorff error, cache, workers, Dask)
    report/     evaluation over camera paths, tuning, the report as JSON, Markdown, HTML, figures
    export/     3D Tiles 1.1 (tiles3d, glb), the localhost viewer, export in a chosen format
    cli/        the command line (`python -m hlod_core`, `hlod-core`)

Public API:
    io.meshes.load_inputs / io.meshes.from_arrays -> TriangleMesh
    bake.pipeline.bake(mesh, BakeSettings, progress=, cancel=) -> model.hierarchy.Hlod
    io.hlod_file.save / io.hlod_file.load; bake.checks.check(hlod)
    render.renderer.Renderer (moderngl: standalone EGL or a caller's context)
    traversal.methods.make(method, hlod, renderer, settings=RuntimeSettings).frame(model.view.View) -> FrameStats
        (any renderer with traversal.methods.NodeRenderer's methods; counters in COUNTERS)
    model.camera_path.load_path / inspection_path; report.runner.run_path
    report.evaluate.evaluate (report.json, report.md, report.html, figures); report.tuning.tune
    export.tiles3d.export; export.viewer.serve
"""
__version__ = "0.1.0"
