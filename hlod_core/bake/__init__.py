"""The bake (docs/how-it-works.md): triangles in, an HLOD node table out. Octree partition, quadric
decimation and Hausdorff errors with pymeshlab, worker processes or a Dask cluster, the bake cache,
out-of-core partitions, the bake in a child process, and the baked file's invariant checks."""
