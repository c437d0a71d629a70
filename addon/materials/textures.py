"""A material's base-colour texture as a file the .hlod and the 3D Tiles can refer to.

An image used as it is (a file on disk in sRGB, its colour unchanged by nodes, alpha unused) is
referred to where it lies. Any other image the base colour comes from (processed by colour nodes,
packed into the .blend, generated, a non-colour or float image) is evaluated through the
material's node function (node_tree) on all its pixels and written as an RGBA PNG (sRGB) into
a scratch folder of this Blender process, named by its content; `place_textures` copies those
into the bake's texture folder (published as OUT.textures/ beside the .hlod once it is written), so
nothing is dropped.

Data form: pixels (h, w, 4) float32 linear RGBA, Blender's row order (bottom row first) while
evaluated; PNG rows top first.
"""
from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import shutil
import tempfile
from pathlib import Path

import bpy
import numpy as np

from ...hlod_core.core.atomic import write_bytes_atomic
from ...hlod_core.core.colour import srgb_from_linear
from ...hlod_core.core.png import png_bytes
from ...hlod_core.io.texture_folder import EmbeddedTextures, unique_file_name
from .images import image_linear

log = logging.getLogger(__name__)

#: The scratch folder's name inside Blender's temporary folder of this process.
SCRATCH_NAME = "hlod_material_textures"
#: Alpha at or above this (of 1) is opaque; a texture whose alpha is only 0 or 1 is glTF's MASK.
OPAQUE_ALPHA = 1.0 - 0.5 / 255.0


def scratch_folder() -> Path:
    """Where written textures wait for the bake's output (Blender removes it when it quits)."""
    return Path(bpy.app.tempdir or tempfile.gettempdir()) / SCRATCH_NAME


def base_colour_texture(material, reading) -> tuple[str, str, str, float] | None:
    """(texture file, image name for the preview, alpha mode, alpha cutoff) of a base colour read
    from an image (`reading`: node_tree.BaseColour); None, with a warning naming the image,
    when the image has no pixels (a missing file)."""
    image = reading.source.image
    if image.source == "TILED":
        _note_udim(material, image)
    file = _file_on_disk(image)
    if reading.identity and file is not None and not image.is_float and image.colorspace_settings.name == "sRGB":
        return file, image.name, "OPAQUE", 0.5
    pixels = image_linear(image)
    if pixels is None:
        log.warning("HLOD bake: material %r: image %r has no pixels (%s); baked with its base colour",
                    material.name_full, image.name, _why_no_file(image))
        return None
    h, w, _ = pixels.shape
    out = reading.function(pixels.reshape(-1, 4)).reshape(h, w, 4)
    mode, cutoff = alpha_mode(out[..., 3])
    return written_texture(out), texture_image_name(material.name_full), mode, cutoff


def written_texture(pixels: np.ndarray) -> str:
    """The file of a texture of `pixels` ((h, w, 4) float32 linear RGBA, bottom row first): an RGBA
    PNG (sRGB, alpha as it is) in the scratch folder, named by its content, written once."""
    h, w, _ = pixels.shape
    rgba8 = np.empty((h, w, 4), np.uint8)
    rgba8[..., :3] = np.round(srgb_from_linear(pixels[..., :3]) * 255.0)
    rgba8[..., 3] = np.round(np.clip(pixels[..., 3], 0.0, 1.0) * 255.0)
    data = png_bytes(rgba8[::-1])
    path = scratch_folder() / f"{hashlib.sha1(data).hexdigest()[:20]}.png"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, data)
    return str(path)


def texture_image_name(name: str) -> str:
    """The image name a written texture of the material row `name` goes by in the preview."""
    return f"{name} (base colour)"


def _note_udim(material, image) -> None:
    """The one note a UDIM image gets: the bake takes its tile 1001 (what Blender's pixels of a
    tiled image are) as the material's one texture, looked up by every UV tile."""
    numbers = [tile.number for tile in image.tiles]
    log.warning("HLOD bake: material %r: image %r is a UDIM image of %d tile(s) (%s); the LODs carry one texture "
                "per material, so tile 1001 stands for every tile", material.name_full, image.name, len(numbers),
                ", ".join(map(str, numbers)))


def alpha_mode(alpha: np.ndarray) -> tuple[str, float]:
    """glTF's (alphaMode, alphaCutoff) of a texture's alpha values: OPAQUE when all are 1, MASK
    (cutoff 0.5) when all are 0 or 1 (a clipped alpha), BLEND otherwise."""
    alpha = np.asarray(alpha, np.float32)
    if np.all(alpha >= OPAQUE_ALPHA):
        return "OPAQUE", 0.5
    if np.all((alpha >= OPAQUE_ALPHA) | (alpha <= 1.0 - OPAQUE_ALPHA)):
        return "MASK", 0.5
    return "BLEND", 0.5


def _file_on_disk(image) -> str | None:
    if image.source != "FILE" or image.packed_file is not None:
        return None
    path = os.path.normpath(bpy.path.abspath(image.filepath, library=image.library))
    return path if os.path.isfile(path) else None


def _why_no_file(image) -> str:
    if image.source == "FILE" and image.packed_file is None:
        return f"its file {os.path.normpath(bpy.path.abspath(image.filepath, library=image.library))} does not exist"
    return "a packed image without data" if image.packed_file is not None else f"a {image.source.lower()} image"


def place_textures(mesh, textures: EmbeddedTextures):
    """The mesh (meshes.TriangleMesh) with every texture written into this process's scratch folder
    copied into the bake's texture folder (`textures`: its private scratch, published as
    OUT.textures once the .hlod is written) as <material name>.png, and its material rows referring
    to where it is published; a mesh without such textures is returned as it is."""
    scratch = str(scratch_folder())
    written = [m for m in mesh.materials if m.texture is not None and os.path.dirname(m.texture) == scratch]
    if not written:
        return mesh
    textures.scratch.mkdir(parents=True, exist_ok=True)
    names, copied = set(), {}
    for material in written:
        name = unique_file_name(material.name, ".png", names)
        shutil.copyfile(material.texture, textures.scratch / name)  # private until published
        copied[material.name] = str((textures.scratch / name).resolve())
    materials = tuple(dataclasses.replace(m, texture=copied[m.name]) if m.name in copied else m for m in mesh.materials)
    log.info("HLOD bake: %d base-colour textures for %s", len(copied), textures.final)
    return textures.relocate(dataclasses.replace(mesh, materials=materials))
