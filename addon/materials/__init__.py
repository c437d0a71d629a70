"""Materials between Blender and the core's material table (hlod_core.model.appearance): a
material datablock read as a row and a row made a datablock again (`rows`), the base colour read
from a node tree (`node_tree`, its colour nodes' formulas in `colour_formulas`), the per-corner UV
maps and colour attributes materials read (`corner_attributes`), image pixels (`images`), base-colour
textures as files (`textures`) and the colours Cycles bakes on one object where a tree cannot be
read (`cycles_bake`). Imports nothing of the add-on's other rooms.
"""
