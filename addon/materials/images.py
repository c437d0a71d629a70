"""Material images read from Blender for the preview's renderer: bpy images (`Material.image`, the
datablock of the material's Image Texture node) as (h, w, 4) uint8 RGBA, sRGB-encoded, top row
first, the form `Renderer(images=...)` takes.
"""
from __future__ import annotations

import logging
import os

import bpy
import numpy as np

from ...hlod_core.core.colour import srgb_from_linear, srgb_to_linear

log = logging.getLogger(__name__)

#: Custom property of an image datablock loaded from a texture the bake wrote: the file it came from.
WRITTEN_TEXTURE_KEY = "hlod_written_texture"


def material_images(materials) -> dict[int, np.ndarray]:
    """material row -> its image (`Material.image`, a bpy.data.images name) as the renderer takes
    it: (h, w, 4) uint8 RGBA, sRGB-encoded, top row first. Each datablock is read once; materials
    sharing it share the array (one texture). A name that is not in bpy.data.images, or an image
    without pixels (a missing file), logs a warning: the material draws in its base colour."""
    out, read = {}, {}
    for row, material in enumerate(materials):
        if not material.image:
            continue
        if material.image not in read:
            image = _fresh(bpy.data.images.get(material.image), material) or _load_texture(material)
            read[material.image] = image_rgba8(image) if image is not None else None
            if read[material.image] is None:
                log.warning("HLOD preview: material %r: image %r %s; drawn in its base colour", material.name,
                            material.image, "is not in this .blend" if image is None else "has no pixels")
        if read[material.image] is not None:
            out[row] = read[material.image]
    return out


def image_rgba8(image) -> np.ndarray | None:
    """A bpy image's pixels as (h, w, 4) uint8 RGBA, sRGB-encoded, top row first (Blender's rows are
    bottom row first); None when it has none. Byte images hold their file's (sRGB) values, float
    images (is_float) linear ones, which are encoded here."""
    rgba = _rgba(image)
    if rgba is None:
        return None
    if image.is_float:
        rgba[..., :3] = srgb_from_linear(rgba[..., :3])
    return np.ascontiguousarray(np.round(np.clip(rgba[::-1], 0.0, 1.0) * 255.0).astype(np.uint8))


def _load_texture(material):
    """The material's texture file loaded as the image datablock `material.image` (a texture the
    bake wrote, whose datablock this Blender session does not have); None without a file."""
    if not material.texture or not os.path.isfile(material.texture):
        return None
    image = bpy.data.images.load(material.texture, check_existing=False)
    image.name = material.image
    image[WRITTEN_TEXTURE_KEY] = material.texture
    return image


def _fresh(image, material):
    """`image` as it is, or, for one loaded from a texture the bake wrote, read again from the
    material's file (a re-bake writes new pixels under the same name)."""
    if (image is None or WRITTEN_TEXTURE_KEY not in image or not material.texture
            or not os.path.isfile(material.texture)):
        return image
    image.filepath = material.texture
    image[WRITTEN_TEXTURE_KEY] = material.texture
    image.reload()
    return image


def _rgba(image) -> np.ndarray | None:
    """(h, w, 4) float32 pixels of a bpy image as stored (bottom row first), grey expanded; None
    when it has none."""
    width, height = (int(v) for v in image.size)
    channels = int(image.channels)
    if width < 1 or height < 1 or channels not in (1, 2, 3, 4):
        return None
    values = np.empty(width * height * channels, np.float32)
    image.pixels.foreach_get(values)
    values = values.reshape(height, width, channels)
    rgba = np.ones((height, width, 4), np.float32)
    if channels >= 3:
        rgba[..., :channels] = values
    else:  # grey, grey + alpha
        rgba[..., :3] = values[..., :1]
        rgba[..., 3] = values[..., -1] if channels == 2 else 1.0
    return rgba


def image_linear(image) -> np.ndarray | None:
    """A bpy image's pixels as the shader reads them: (h, w, 4) float32 linear RGBA, bottom row
    first; None without pixels. Byte images in sRGB are decoded; byte images of any other colour
    space (Non-Color, linear) and float images give their values as they are."""
    rgba = _rgba(image)
    if rgba is None:
        return None
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        h, w, _ = rgba.shape
        rgba = srgb_to_linear(rgba.reshape(-1, 4)).reshape(h, w, 4)
    return rgba
