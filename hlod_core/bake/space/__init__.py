"""The bake's space (docs/how-it-works.md#the-bake): the frame every position is made in and the octree that cuts
it.

Modules: chunk_store, frame, lattice, octree, octree_passes, partition, root_cube.
"""
