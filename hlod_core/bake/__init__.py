"""The bake (docs/how-it-works.md): triangles in, an HLOD node table out.

Entry points: pipeline.bake (a mesh in memory) and pipeline.bake_stream (an input bigger than
memory), with settings.BakeSettings. The phases: sources (prepare, partition; every position on
the input's lattice, in the frame of frame: an earlier bake's while the input fits it), octree
(its root_cube, which may grow; octree_passes, its per-triangle passes in chunks), cell_seams
(the positions each node shares with cells outside it),
schedule (simplify, seams, collapse, pieces and meshlab for the LODs, hausdorff,
leaf_arrays and tasks for the errors, on workers or a Dask cluster: dask_cluster), assemble, meta;
the cache (cache, cache_keys, cache_files, cache_proxies) beside them; appearance/ (the inner
nodes' proxy materials: atlases, texture bakes, their quality gate); child runs a bake in a child
process, checks verifies a baked file's invariants.
"""
