"""Base-colour texture images for the standalone renderer (`run`, `evaluate`): the command line's
counterpart of the images the Blender preview takes from bpy.

Data form: in, an Hlod whose material table names image files (`Material.texture`, absolute paths
once loaded); out, material row -> (h, w, 4) uint8 RGBA, top row first, sRGB-encoded as stored in
the file (what `renderer.Renderer(images=...)` takes). Each distinct path is read once and its
array is shared by every material naming it (the renderer makes one texture per array object).
Pillow is a command-line-only dependency (requirements.txt): imported here, inside the function,
and without it the materials are drawn in their base colours after one warning.
"""
from __future__ import annotations

import logging

import numpy as np

from ..model.appearance import texture_paths
from ..model.hierarchy import Hlod

log = logging.getLogger(__name__)


def load_images(hlod: Hlod) -> dict[int, np.ndarray]:
    """material row -> RGBA image of its texture file, for every material of `hlod` with a readable
    one (load_material_images)."""
    return load_material_images(hlod.materials)


def load_material_images(materials) -> dict[int, np.ndarray]:
    """material row -> RGBA image of its texture file, for every material (appearance.Material) with
    a readable one. PNG/JPEG (anything Pillow reads); palette, grey and RGB images become RGBA (alpha
    255). A file that is missing or unreadable logs one warning naming it and the first material
    using it, and its materials are left out (drawn in their base colours)."""
    materials = tuple(materials)
    paths = texture_paths(materials)
    if not paths:
        return {}
    try:
        from PIL import Image, UnidentifiedImageError
    except ImportError:
        log.warning("%d texture image(s) not loaded: Pillow is not installed (pip install -r requirements.txt); "
                    "materials are drawn in their base colours", len(paths))
        return {}
    images: dict[str, np.ndarray] = {}
    for path in paths:
        user = next(m.name for m in materials if m.texture == path)
        try:
            with Image.open(path) as image:
                images[path] = np.asarray(image.convert("RGBA"), dtype=np.uint8)
        except (OSError, UnidentifiedImageError, ValueError, Image.DecompressionBombError) as exc:
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or type(exc).__name__
            log.warning("texture %s of material %r not loaded (%s): drawn in its base colour", path, user, reason)
    return {row: images[m.texture] for row, m in enumerate(materials) if m.texture in images}
