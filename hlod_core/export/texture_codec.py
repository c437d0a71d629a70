"""Texture images of a 3D Tiles export re-encoded smaller: JPEG (glTF 2.0 core) or WebP (the glTF
extension EXT_texture_webp, which CesiumJS, cesium-native and loaders.gl read), with Pillow (a
command-line-only dependency, imported here only when used).

Data form: in, an image file's bytes (PNG or JPEG, as tiles3d.IMAGE_SIGNATURES tells them) and the
encoding (TEXTURE_ENCODINGS); out, (bytes, mime type, suffix). What is kept as it is: everything for
"original"; a JPEG for "jpeg" (no second loss); for "jpeg", an image whose alpha is not all opaque
(JPEG has no alpha; WebP keeps it); and any image whose re-encoding is not smaller than the file.
Lossy at JPEG_QUALITY / WEBP_QUALITY (Pillow's 0..100 scales), sRGB bytes as stored.
"""
from __future__ import annotations

import io

from ..core.errors import InputError

#: The texture images of an export: the files as they are, JPEG, or WebP (EXT_texture_webp).
TEXTURE_ENCODINGS = ("original", "jpeg", "webp")
#: Pillow's quality settings (0..100): high enough that CesiumJS's picture stays within 40 dB PSNR-Y
#: of the original images' (docs/performance.md#3d-tiles-tile-bytes).
JPEG_QUALITY, WEBP_QUALITY = 90, 90
WEBP_EXTENSION = "EXT_texture_webp"


def require_pillow():
    """PIL.Image; InputError with the install line when Pillow is not installed."""
    try:
        from PIL import Image
    except ImportError:
        raise InputError("--textures jpeg|webp needs the Pillow package (pip install -r requirements.txt); "
                         "--textures original needs nothing") from None
    return Image


def encode(data: bytes, mime_type: str, suffix: str, encoding: str) -> tuple[bytes, str, str]:
    """The image file `data` (of `mime_type`, file `suffix`) for the export: (bytes, mime type,
    suffix), re-encoded as `encoding` asks unless the module notes keep it. OSError or ValueError for
    a file Pillow cannot decode (a decompression bomb included)."""
    if encoding == "original" or (encoding == "jpeg" and mime_type == "image/jpeg"):
        return data, mime_type, suffix
    image_module = require_pillow()
    try:
        with image_module.open(io.BytesIO(data)) as image:
            image.load()
            has_alpha = image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info
            rgba = image.convert("RGBA" if has_alpha else "RGB")
    except image_module.DecompressionBombError as exc:  # not an OSError: told as a file it cannot decode
        raise ValueError(str(exc)) from None
    if has_alpha and rgba.getchannel("A").getextrema()[0] == 255:
        rgba, has_alpha = rgba.convert("RGB"), False
    out = io.BytesIO()
    if encoding == "jpeg":
        if has_alpha:
            return data, mime_type, suffix
        rgba.save(out, "JPEG", quality=JPEG_QUALITY)
        encoded, kind = out.getvalue(), ("image/jpeg", ".jpg")
    else:
        rgba.save(out, "WEBP", quality=WEBP_QUALITY, method=4)
        encoded, kind = out.getvalue(), ("image/webp", ".webp")
    return (encoded, *kind) if len(encoded) < len(data) else (data, mime_type, suffix)
