"""The bake (docs/how-it-works.md): triangles in, an HLOD node table out.

Entry points: pipeline.bake (a mesh in memory) and pipeline.bake_stream (an input bigger than
memory), with settings.BakeSettings. The phases: sources (prepare; every position on the input's
lattice), then the bake's rooms, each a folder:
- space/: the frame (an earlier bake's while the input fits it), the lattice, the octree and its
  root cube, the streamed partition of an input bigger than memory;
- decimate/: one inner node's LOD (simplify, collapse, seams, pieces, cell_seams: what a node
  shares with the cells around it; meshlab, pymeshlab in the unit frame);
- measure/: the inner nodes' errors (hausdorff, and leaf_arrays, the leaves as the exact measure
  reads them);
- appearance/: the inner nodes' proxy materials (atlases, texture bakes, their quality gate);
- run/: where the tasks run (schedule, workers, tasks, dask_cluster), the cache (cache, cache_keys,
  cache_files, cache_proxies) and child, a bake in a child process.
Then assemble and meta; checks verifies a baked file's invariants.
"""
