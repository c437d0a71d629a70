"""The artist's scene: which objects and instances a bake takes and what it skips (`objects`), the
one pass that gathers their evaluated triangles into one mesh (`gather`; each instance's triangles
read by `parts`, the colours Cycles bakes where no node tree reading gives them by
`surface_bakes`), the record of the objects
a bake took with their content keys (`source_record`), hiding them while the preview draws in their
place (`source_hiding`), Blender mesh objects made of HLOD nodes (`node_objects`), and where a 3D
Tiles export of the scene stands on the globe (`place`: its georeference or the panel's). Reads
materials through the materials room; imports nothing of the preview or the bake.
"""
