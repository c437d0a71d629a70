"""The textures a renderer makes for an HLOD's material images and what each takes on the GPU: the
GPU budget's view of textures (docs/how-it-works.md#streaming-node-geometry). No GL here:
materials.py makes the textures, residency.py counts them.

Data form: `images`: material row -> (h, w, 4) uint8 RGBA, top row first (what
`Renderer(images=...)` takes); one texture per distinct array object, k textures, numbered in
the order of their first row. `row_texture` (m + 1,) int64: material row -> texture number or -1
(the last entry, -1, for parts without a material); `texture_bytes` (k,) int64: what each takes as
the renderer allocates it, RGBA8 (sRGB8_ALPHA8) with its full mip chain (`mip_chain_bytes`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..model.hierarchy import Hlod

log = logging.getLogger(__name__)

RGBA8_BYTES = 4


def mip_chain_bytes(width: int, height: int) -> int:
    """Bytes of a width x height RGBA8 texture and every mip level below it, as GL makes them
    (glGenerateMipmap: each level floor(half) of the one above, at least 1, down to 1 x 1)."""
    total = 0
    while True:
        total += width * height * RGBA8_BYTES
        if width == 1 and height == 1:
            return total
        width, height = max(1, width // 2), max(1, height // 2)


@dataclass(frozen=True)
class TextureTable:
    """The textures of one HLOD's images (module docstring): `images` (k,) the distinct arrays,
    `row_texture` (m + 1,) int64, `texture_bytes` (k,) int64."""

    images: tuple
    row_texture: np.ndarray
    texture_bytes: np.ndarray

    @property
    def count(self) -> int:
        return len(self.images)

    @classmethod
    def none(cls, hlod: Hlod) -> "TextureTable":
        """No textures (every material in its base colour)."""
        return cls((), np.full(len(hlod.materials) + 1, -1, np.int64), np.zeros(0, np.int64))

    @classmethod
    def of(cls, hlod: Hlod, images: dict | None, *, max_side: int | None = None) -> "TextureTable":
        """The textures of `images` for `hlod`'s material rows. InputError for a key that is no
        material row or an image of another form. Left out, with a warning: every image when the
        HLOD has no UVs, and an image over `max_side` texels a side (the GL's GL_MAX_TEXTURE_SIZE;
        None: no limit); their materials draw in their base colours."""
        table = cls.none(hlod)
        n = len(hlod.materials)
        images = images or {}
        bad = [k for k in images if not isinstance(k, (int, np.integer)) or not 0 <= k < n]
        if bad:
            raise InputError(f"images: key {bad[0]!r} is not a material row of this HLOD (it has {n} materials)")
        given = {int(k): v for k, v in images.items() if v is not None}
        if not given:
            return table
        if hlod.uvs is None:
            log.warning("%d material images given but the HLOD has no UVs: drawn in base colours", len(given))
            return table
        distinct: dict[int, int] = {}  # id(image array) -> texture number
        kept, sizes = [], []
        for row, image in sorted(given.items()):
            name = hlod.materials[row].name
            _check_image(row, name, image)
            height, width = image.shape[:2]
            if max_side is not None and max(height, width) > max_side:
                log.warning("image of material %d (%r) is %dx%d, larger than this GL's %d: drawn in its base "
                            "colour", row, name, width, height, max_side)
                continue
            if id(image) not in distinct:
                distinct[id(image)] = len(kept)
                kept.append(image)
                sizes.append(mip_chain_bytes(width, height))
            table.row_texture[row] = distinct[id(image)]
        return cls(tuple(kept), table.row_texture, np.asarray(sizes, np.int64))

    def node_textures(self, hlod: Hlod) -> list[tuple[int, ...]]:
        """Per node, the texture numbers its draw parts use (each once, ascending)."""
        n = hlod.node_count
        if self.count == 0:
            return [()] * n
        parts = hlod.draw_parts()
        texture = self.row_texture[parts.material]  # material -1 takes the last entry, -1
        node = np.repeat(np.arange(n, dtype=np.int64), parts.count)
        pairs = np.unique(np.stack([node, texture], 1)[texture >= 0], axis=0)
        out: list[tuple[int, ...]] = [()] * n
        if pairs.size:
            starts = np.flatnonzero(np.r_[True, pairs[1:, 0] != pairs[:-1, 0]])
            for begin, end in zip(starts.tolist(), np.r_[starts[1:], pairs.shape[0]].tolist()):
                out[int(pairs[begin, 0])] = tuple(pairs[begin:end, 1].tolist())
        return out

    def rows_resident(self, texture_resident: np.ndarray) -> np.ndarray:
        """(m,) bool per material row: it has a texture and that texture is resident
        (`texture_resident` (k,) bool)."""
        rows = self.row_texture[:-1]
        out = np.zeros(rows.shape[0], bool)
        has = rows >= 0
        out[has] = np.asarray(texture_resident, bool)[rows[has]]
        return out


def _check_image(row: int, name: str, image) -> None:
    """InputError unless `image` is (h, w, 4) uint8 with h, w > 0."""
    if not (isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3
            and image.shape[2] == 4 and image.shape[0] > 0 and image.shape[1] > 0):
        got = f"{image.dtype}{list(image.shape)}" if isinstance(image, np.ndarray) else type(image).__name__
        raise InputError(f"image of material {row} ({name!r}): expected (h, w, 4) uint8 RGBA, got {got}")
