"""Operators (docs/user-guide.md; ids fixed: hlod.bake, hlod.clear, hlod.preview_toggle, hlod.materialize,
hlod.export, hlod.benchmark, hlod.tune_psnr, hlod.view_tiles), one module per topic: `bake` (Bake,
Clear), `preview` (Toggle Preview, Materialize), `export`, `evaluation` (Benchmark, Tune to PSNR),
`view_tiles` (View in Browser and its server; its name keeps "viewer" for the server code, which
enabling the add-on does not import). Thin: they read properties, call hlod_core and the addon
modules, and map typed errors (HlodError) to reports. Nothing here changes the source objects.

CLASSES is every operator class, in registration order; the package's top-level `__init__.py`
registers them.
"""
from . import bake, evaluation, export, preview, view_tiles
from .view_tiles import viewer_stop, viewer_url  # noqa: F401 - the load_pre handler and tests use them

CLASSES = [*bake.CLASSES, *preview.CLASSES, *export.CLASSES, *evaluation.CLASSES, *view_tiles.CLASSES]
