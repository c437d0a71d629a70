"""The add-on between Blender and hlod_core (docs/development.md#layout), in rooms by role: `materials`
(material datablocks and the core's material rows), `scene` (the objects a bake takes, gathered in
one pass), `preview` (the live preview in the viewport), `bake` (the bake from Blender, in a child
process); and at the top `properties` (scene.hlod), `settings` (the property group as the core's
settings), `cli` (the background command), `evaluation` (Benchmark and Tune to PSNR) and
`tiles_server` (View in Browser's server). Each room imports only the rooms below it
(tests/test_structure.py ADDON_LAYERS), and nothing here imports operators/ or panels/;
registration lives in the package's top-level `__init__.py`.
"""
