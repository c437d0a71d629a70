"""The bake's decimation (docs/how-it-works.md#decimating-a-node): one inner node's LOD from its children's, with
pymeshlab.

Modules: cell_seams, collapse, meshlab, pieces, seams, simplify.
"""
