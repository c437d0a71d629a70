"""A glTF file's material table (glTF 2.0 spec 3.9, pbrMetallicRoughness) and its base-colour
images as files.

Data form: the file's JSON header (and a GLB's BIN chunk) in; a tuple of appearance.Material out.
Per material: baseColorFactor (linear RGBA), metallicFactor, roughnessFactor (glTF's defaults 1,
1, 1), clipped to [0, 1], alphaMode and alphaCutoff (defaults OPAQUE, 0.5; trimesh refuses another
mode, this module a cutoff outside [0, 1]), doubleSided (default false), and baseColorTexture as an
image file: an image given by URI is the file itself; one embedded in the file (a bufferView or a
data: URI) is written once, with its original bytes, into the caller's texture folder as
NAME-<sha256 prefix>.png/.jpg/.webp
(content-named, so equal images are one file) and referenced there. No folder given, or a missing
image: the material is read without its texture, with a warning naming the file.
"""
from __future__ import annotations

import base64
import binascii
import hashlib
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ..core.errors import InputError
from ..model.appearance import Material
from .gltf_accessors import buffer_view

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = {"image/png": ".png", "image/jpeg": ".jpg", "image/webp": ".webp"}
#: glTF's default material (spec 3.9.1): white, fully metallic, fully rough.
GLTF_DEFAULT_FACTORS = {"baseColorFactor": (1.0, 1.0, 1.0, 1.0), "metallicFactor": 1.0, "roughnessFactor": 1.0}


def read_materials(path: Path, header: dict, *, binary: bytes | None, texture_dir: Path | None) -> tuple[Material, ...]:
    """The material table of the glTF file `path` (JSON `header`, GLB `binary` chunk or None);
    embedded images are written into `texture_dir` (None: left out, with a warning)."""
    return _materials(_Images(path=path, header=header, binary=binary, texture_dir=texture_dir))


@dataclass
class _Images:
    """A glTF file's images as files (see the module docstring), each resolved once."""

    path: Path
    header: dict
    binary: bytes | None
    texture_dir: Path | None
    files: dict = field(default_factory=dict)

    def of_texture(self, info, where: str) -> str | None:
        """The image file of a baseColorTexture, or None with a warning."""
        textures = self.header.get("textures", [])
        index = info.get("index") if isinstance(info, dict) else None
        if not isinstance(index, int) or not 0 <= index < len(textures) or not isinstance(textures[index], dict):
            raise InputError(f"{where}.baseColorTexture.index {index!r} is not one of the {len(textures)} textures")
        if info.get("texCoord", 0) != 0:
            log.warning("%s: baseColorTexture uses TEXCOORD_%s; only TEXCOORD_0 is read", where, info.get("texCoord"))
        texture = textures[index]
        source = texture.get("source")
        for extension in (texture.get("extensions") or {}).values():  # EXT_texture_webp and the like
            if isinstance(extension, dict) and isinstance(extension.get("source"), int) and source is None:
                source = extension["source"]
        images = self.header.get("images", [])
        if not isinstance(source, int) or not 0 <= source < len(images) or not isinstance(images[source], dict):
            log.warning("%s: textures[%d] has no image; the material is read without it", where, index)
            return None
        if source not in self.files:
            self.files[source] = self._file(source)
        return self.files[source]

    def _file(self, index: int) -> str | None:
        """Image `index` as a file (written into texture_dir if embedded), or None with a warning."""
        path, image = self.path, self.header["images"][index]
        uri, mime = image.get("uri"), image.get("mimeType")
        name = image.get("name") if isinstance(image.get("name"), str) else f"image{index}"
        if isinstance(uri, str) and not uri.startswith("data:"):
            file = (path.parent / unquote(uri)).resolve()
            if not file.is_file():
                log.warning("%s: texture image %s is missing; the material is read without it", path, file)
                return None
            return str(file)
        if isinstance(uri, str):  # data:[mime][;base64],payload
            head, _, payload = uri.partition(",")
            mime = head[5:].split(";")[0] or mime
            try:
                data = base64.b64decode(payload, validate=True) if head.endswith(";base64") \
                    else unquote(payload).encode()
            except (binascii.Error, ValueError):
                raise InputError(f"{path}: images[{index}] has a malformed data URI") from None
        else:
            data = buffer_view(path, self.header, self.binary, view=image.get("bufferView"), what=f"images[{index}]")
        suffix = IMAGE_SUFFIXES.get(mime) or _sniff_suffix(data)
        if suffix is None:
            log.warning("%s: images[%d] (%s) is not PNG, JPEG or WebP; the material is read without it", path, index,
                        mime)
            return None
        if self.texture_dir is None:
            log.warning("%s: images[%d] (%s) is embedded and no texture folder was given; the material is read "
                        "without it", path, index, name)
            return None
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._")[:60] or "image"
        file = Path(self.texture_dir) / f"{stem}-{hashlib.sha256(data).hexdigest()[:12]}{suffix}"
        if not file.is_file():
            file.parent.mkdir(parents=True, exist_ok=True)
            file.write_bytes(data)
        return str(file.resolve())


def _materials(images: _Images) -> tuple[Material, ...]:
    """The file's material table (factors clipped to [0, 1]; a non-number is refused)."""
    out = []
    for i, mat in enumerate(images.header.get("materials", [])):
        where = f"{images.path}: materials[{i}]"
        if not isinstance(mat, dict):
            raise InputError(f"{where} is not an object")
        pbr = mat.get("pbrMetallicRoughness", {})
        if not isinstance(pbr, dict):
            raise InputError(f"{where}.pbrMetallicRoughness is not an object")
        color = _factor(where, pbr, "baseColorFactor", size=4)
        metallic = _factor(where, pbr, "metallicFactor", size=1)
        roughness = _factor(where, pbr, "roughnessFactor", size=1)
        info = pbr.get("baseColorTexture")
        texture = None if info is None else images.of_texture(info, where)
        name = mat.get("name")
        alpha_mode, cutoff = mat.get("alphaMode", "OPAQUE"), mat.get("alphaCutoff", 0.5)
        if isinstance(cutoff, bool) or not isinstance(cutoff, (int, float)) or not 0.0 <= cutoff <= 1.0:
            raise InputError(f"{where}.alphaCutoff must be a number in [0, 1]")
        double_sided = mat.get("doubleSided", False)
        if not isinstance(double_sided, bool):
            raise InputError(f"{where}.doubleSided must be true or false")
        out.append(Material(name=name if isinstance(name, str) and name else f"material.{i}",
                            base_color=tuple(float(c) for c in color), metallic=float(metallic[0]),
                            roughness=float(roughness[0]), texture=texture, alpha_mode=alpha_mode,
                            alpha_cutoff=float(cutoff), double_sided=double_sided))
    return tuple(out)


def _factor(where: str, pbr: dict, key: str, *, size: int) -> np.ndarray:
    """`size` finite numbers of `pbr[key]` (or glTF's default), clipped to [0, 1]; InputError otherwise."""
    value = pbr.get(key, GLTF_DEFAULT_FACTORS[key])
    try:
        out = np.atleast_1d(np.asarray(value, np.float64))
    except (TypeError, ValueError):
        out = np.zeros(0)
    if out.shape != (size,) or not np.all(np.isfinite(out)):
        raise InputError(f"{where}.pbrMetallicRoughness.{key} must be {size} finite number(s)")
    return np.clip(out, 0.0, 1.0)


def _sniff_suffix(data: bytes) -> str | None:
    """The file suffix of PNG, JPEG or WebP image bytes, by their signature; None for another."""
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return ".png"
    if data.startswith(b"\xff\xd8\xff"):
        return ".jpg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return ".webp"
    return None
