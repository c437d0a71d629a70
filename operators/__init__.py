"""Operators (docs/user-guide.md; ids fixed: hlod.bake, hlod.clear, hlod.preview_toggle, hlod.materialize,
hlod.export, hlod.benchmark, hlod.tune_psnr, hlod.view_tiles), one module per topic: `bake` (Bake,
Clear), `preview` (Toggle Preview, Materialize), `export`, `evaluation` (Benchmark, Tune to PSNR),
`view_tiles` (View in Browser; its server is addon/tiles_server.py). Thin: they read properties,
call into the add-on (addon/) and the core's files, and map typed errors (HlodError) to reports.
Nothing here changes the source objects.

CLASSES is every operator class, in registration order; the package's top-level `__init__.py`
registers them.
"""
from . import bake, evaluation, export, preview, view_tiles

CLASSES = [*bake.CLASSES, *preview.CLASSES, *export.CLASSES, *evaluation.CLASSES, *view_tiles.CLASSES]
