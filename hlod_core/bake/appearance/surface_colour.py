"""What a textured surface shows at given points, averaged over a footprint: the colour a proxy
texture bakes and the quality gate renders (pure numpy: it runs in bake workers and in Blender's
Python).

Data form: a `Surface` (a triangle mesh with its appearance: positions (k,3) model units, faces
(m,3), optional UVs (k,2) in OpenGL's convention, v up, optional linear RGBA vertex colours (k,4),
per-face material rows and per-row `MipChain` of the base-colour texture); points as a face (s,)
and barycentric weights (s,3). Out: (s,4) float32 linear RGBA, straight alpha.

The colour is the renderer's (render/shaders.py PARTS_FS): base colour x vertex colour x texture,
the texture sRGB-decoded to linear, repeat wrap, trilinear between mip levels. The level follows the
sample's footprint (model units, the side of the square of surface it stands for): per face,
texels per model unit t = sqrt(uv_area w h / area_3d) and level = log2(footprint t), clamped to the
chain. Deviations from GL, on purpose: levels are box filters in linear colour with alpha
premultiplied (GL averages straight alpha), so transparent texels do not bleed into a MASK or BLEND
average; a level is the exact area average of the one above also for odd sizes; glTF's OPAQUE (and
no material at all) gives alpha 1 and the colour of the texture's visible texels.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ...core.colour import srgb_to_linear
from ...core.errors import InputError
from ...model.appearance import NO_MATERIAL_BASE_COLOR

#: Source texels decoded at once while a mip level is built: the temporary float32 arrays stay
#: about 16 x this many bytes (32 MiB) even for an 8192 x 8192 image.
BAND_TEXELS = 1 << 21

#: sRGB-encoded byte -> linear value (256,) float32.
_DECODE = srgb_to_linear(np.repeat(np.arange(256, dtype=np.float64)[:, None] / 255.0, 4, axis=1))[:, 0]


class MipChain:
    """One image's mip chain, built once and shared by every material using it.

    Level 0 is the image itself, (h, w, 4) uint8 RGBA, top row first, sRGB-encoded, kept as given
    (not copied, so a broadcast constant costs nothing) and decoded per sample. Levels 1.. are
    (max(1, h >> k), max(1, w >> k), 4) float16 linear RGBA with alpha premultiplied, bottom row
    first, each the area average of the level above; they are built on the first sample that asks
    for them, in order (a level needs the one above), and kept: the whole chain of an 8192 x 8192
    image holds 171 MiB beside the image's 256 MiB.
    """

    def __init__(self, image: np.ndarray):
        self.image = image
        self.height, self.width = int(image.shape[0]), int(image.shape[1])
        self.level_count = int(max(self.width, self.height)).bit_length()  # sizes down to 1 x 1
        #: Every texel has alpha 255: premultiplied and straight alpha are the same.
        self.opaque = bool(image[..., 3].min() == 255)
        self._levels: list[np.ndarray | None] = [None] * self.level_count

    @staticmethod
    def of(image_rgba8_top_first: np.ndarray) -> "MipChain":
        """The chain of an (h, w, 4) uint8 RGBA image, top row first, sRGB-encoded (InputError otherwise)."""
        image = image_rgba8_top_first
        if not (isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3
                and image.shape[2] == 4 and image.shape[0] > 0 and image.shape[1] > 0):
            got = f"{image.dtype}{list(image.shape)}" if isinstance(image, np.ndarray) else type(image).__name__
            raise InputError(f"texture image: expected (h, w, 4) uint8 RGBA, got {got}")
        return MipChain(image)

    @property
    def nbytes(self) -> int:
        """Bytes held: the image (as if dense) and the levels built so far."""
        return int(self.image.nbytes) + sum(int(level.nbytes) for level in self._levels[1:] if level is not None)

    def size(self, level: int) -> tuple[int, int]:
        """(width, height) of `level`."""
        return max(1, self.width >> level), max(1, self.height >> level)

    def sample(self, uv: np.ndarray, level: np.ndarray) -> np.ndarray:
        """(n,4) float32 linear RGBA, alpha premultiplied, at (n,2) UVs (repeat wrap) and (n,)
        fractional mip levels (trilinear; clamped to the chain; NaN counts as 0)."""
        uv = np.asarray(uv, np.float64)
        lam = np.clip(np.nan_to_num(np.asarray(level, np.float64), nan=0.0), 0.0, self.level_count - 1)
        low = np.floor(lam).astype(np.int64)
        frac = (lam - low).astype(np.float32)[:, None]
        out = np.zeros((len(uv), 4), np.float32)
        for k in np.unique(low).tolist():
            sel = np.flatnonzero(low == k)
            out[sel] = self._bilinear(k, uv[sel])
            upper = sel[frac[sel, 0] > 0.0]
            if len(upper):
                out[upper] += frac[upper] * (self._bilinear(k + 1, uv[upper]) - out[upper])
        return out

    def _bilinear(self, k: int, uv: np.ndarray) -> np.ndarray:
        """(n,4) float32 premultiplied linear RGBA of level k at (n,2) UVs, GL's bilinear with
        repeat wrap (texel centres at (i + 0.5) / w)."""
        w, h = self.size(k)
        wrapped = np.nan_to_num(uv - np.floor(uv))  # [0, 1): far-out UVs keep their precision
        x = wrapped[:, 0] * w - 0.5
        y = wrapped[:, 1] * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = (x - x0).astype(np.float32)[:, None], (y - y0).astype(np.float32)[:, None]
        i0, j0 = x0.astype(np.int64) % w, y0.astype(np.int64) % h
        i1, j1 = (i0 + 1) % w, (j0 + 1) % h
        bottom = self._texels(k, j0, i0) * (1 - fx) + self._texels(k, j0, i1) * fx
        top = self._texels(k, j1, i0) * (1 - fx) + self._texels(k, j1, i1) * fx
        return bottom * (1 - fy) + top * fy

    def _texels(self, k: int, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """(n,4) float32 premultiplied linear texels of level k at rows (counted from the bottom) and columns."""
        if k == 0:
            return _decode(self.image[self.height - 1 - row, col], opaque=self.opaque)
        return self._level(k)[row, col].astype(np.float32)

    def _level(self, k: int) -> np.ndarray:
        """Level k >= 1, built (with the levels above it) on first use."""
        if self._levels[k] is None:
            w, h = self.size(k - 1)
            above = None if k == 1 else self._level(k - 1)
            rows = self._decoded_rows if above is None else (lambda a, b: above[a:b].astype(np.float32))
            self._levels[k] = _halve(rows, w, h)
        return self._levels[k]

    def _decoded_rows(self, first: int, stop: int) -> np.ndarray:
        """Level 0's rows first..stop-1 counted from the bottom, as (r, w, 4) float32 premultiplied linear."""
        return _decode(self.image[self.height - stop:self.height - first][::-1], opaque=self.opaque)


def _decode(texels: np.ndarray, *, opaque: bool = False) -> np.ndarray:
    """(..., 4) uint8 sRGB RGBA -> (..., 4) float32 linear RGBA with alpha premultiplied; opaque:
    every alpha is known to be 255."""
    out = _DECODE[texels]
    if opaque:
        out[..., 3] = 1.0
    else:
        out[..., 3] = texels[..., 3] * np.float32(1.0 / 255.0)
        out[..., :3] *= out[..., 3:4]
    return out


def _taps(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-average weights from n texels to max(1, n // 2): (m, t) source indices and weights."""
    m = max(1, n // 2)
    ratio = n / m
    start = np.arange(m) * ratio
    first = np.floor(start).astype(np.int64)
    index = first[:, None] + np.arange(int(math.ceil(ratio)) + 1)[None, :]
    overlap = np.minimum(start[:, None] + ratio, index + 1) - np.maximum(start[:, None], index)
    return np.minimum(index, n - 1), (np.clip(overlap, 0.0, None) / ratio).astype(np.float32)


def _halve(rows, w: int, h: int) -> np.ndarray:
    """The next mip level (max(1, h // 2), max(1, w // 2), 4) float16 of a (h, w, 4) level read in
    bands by rows(first, stop) -> (stop - first, w, 4) float32."""
    w2, h2 = max(1, w // 2), max(1, h // 2)
    out = np.empty((h2, w2, 4), np.float16)
    row_index, row_weight = _taps(h)
    col_index, col_weight = _taps(w)
    band = max(1, BAND_TEXELS // (3 * w))
    for d0 in range(0, h2, band):
        d1 = min(h2, d0 + band)
        if h % 2 == 0:
            src = rows(2 * d0, 2 * d1)
            tall = 0.5 * (src[0::2] + src[1::2])
        else:
            first, stop = int(row_index[d0:d1].min()), int(row_index[d0:d1].max()) + 1
            src = rows(first, stop)
            index, weight = row_index[d0:d1] - first, row_weight[d0:d1]
            tall = sum(weight[:, t, None, None] * src[index[:, t]] for t in range(index.shape[1]))
        if w % 2 == 0:
            out[d0:d1] = 0.5 * (tall[:, 0::2] + tall[:, 1::2])
        else:
            out[d0:d1] = sum(col_weight[None, :, t, None] * tall[:, col_index[:, t]] for t in range(col_index.shape[1]))
    return out


@dataclass(frozen=True, eq=False)
class Surface:
    """A triangle mesh and what it shows (see the module docstring).

    positions (k,3) float model units; faces (m,3) int; uvs (k,2) float32 (v up) or None (no
    texture is drawn); colors (k,4) float32 linear RGBA vertex colours or None (white);
    face_material (m,) int rows of `materials` or None (every face NO_MATERIAL_BASE_COLOR, opaque);
    materials: appearance.Material rows (base_color, alpha_mode used); images: material row ->
    MipChain of its texture (a row without one shows its base colour)."""

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    colors: np.ndarray | None = None
    face_material: np.ndarray | None = None
    materials: tuple = ()
    images: dict | None = None

    @functools.cached_property
    def uv_stretch(self) -> np.ndarray:
        """(m,) float64 UV units per model unit of each face, sqrt(uv_area / area_3d), made once (the
        arrays are not to change after): 0 without UVs or without area."""
        return np.zeros(len(self.faces)) if self.uvs is None else _uv_stretch(self)


def texture_texels_per_unit(surface: Surface) -> np.ndarray:
    """(m,) float64 texels per model unit of each face's texture, sqrt(uv_area w h / area_3d) with
    (w, h) the image's level-0 size; 0 where a face has no texture (no UVs, no image) or no area
    in model space or in UV space."""
    return _density(surface, np.arange(len(surface.faces)))


def colour_at(surface: Surface, face: np.ndarray, bary: np.ndarray, *, footprint: float | np.ndarray) -> np.ndarray:
    """(s,4) float32 linear RGBA, straight alpha, that `surface` shows at the points of faces `face`
    (s,) int with barycentric weights `bary` (s,3): base colour x vertex colour x texture, the
    texture averaged over `footprint` (scalar or (s,), model units: the side of the square of surface
    each point stands for; 0 samples the finest level). Alpha is the product of the three for MASK
    and BLEND materials (the caller applies a MASK cutoff), 1 for OPAQUE ones and without materials."""
    face = np.asarray(face, np.int64).reshape(-1)
    bary = np.asarray(bary, np.float64).reshape(-1, 3)
    if len(face) != len(bary):
        raise InputError(f"colour_at: {len(face)} faces but {len(bary)} barycentric rows")
    if len(face) and (face.min() < 0 or face.max() >= len(surface.faces)):
        raise InputError(f"colour_at: a face index is outside 0..{len(surface.faces) - 1}")
    corners = np.asarray(surface.faces, np.int64)[face]  # (s,3) vertex ids
    if surface.face_material is None:
        material = np.zeros(len(face), np.int64)
        bases, opaque = np.asarray([NO_MATERIAL_BASE_COLOR], np.float32), np.array([True])
    else:
        material = np.asarray(surface.face_material, np.int64)[face]
        bases = np.asarray([m.base_color for m in surface.materials], np.float32).reshape(-1, 4)
        opaque = np.array([m.alpha_mode == "OPAQUE" for m in surface.materials], bool)
    colour = bases[material]
    if surface.colors is not None:
        colour *= np.einsum("sc,scj->sj", bary, np.asarray(surface.colors, np.float64)[corners]).astype(np.float32)
    if surface.uvs is not None and surface.images and surface.face_material is not None:
        footprint = np.broadcast_to(np.asarray(footprint, np.float64), (len(face),))
        for row, chain in surface.images.items():
            sel = np.flatnonzero(material == row)
            if not len(sel):
                continue
            uv = np.einsum("sc,scj->sj", bary[sel], np.asarray(surface.uvs, np.float64)[corners[sel]])
            with np.errstate(divide="ignore", invalid="ignore"):
                level = np.log2(np.maximum(footprint[sel], 0.0) * _density(surface, face[sel], chain=chain))
            colour[sel] *= _straight(chain.sample(uv, np.where(np.isfinite(level), level, np.where(level > 0, 1e9, 0))))
    colour[opaque[material], 3] = 1.0
    return colour


def _straight(premultiplied: np.ndarray) -> np.ndarray:
    """(n,4) premultiplied RGBA -> straight alpha (colour 0 where alpha is 0)."""
    alpha = premultiplied[:, 3:4]
    out = premultiplied.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        out[:, :3] = np.where(alpha > 0.0, premultiplied[:, :3] / alpha, 0.0)
    return out


def _density(surface: Surface, faces: np.ndarray, *, chain: MipChain | None = None) -> np.ndarray:
    """(n,) float64 texels per model unit of `faces` (see texture_texels_per_unit); `chain`: the
    image of all of them (else each face's material's)."""
    out = np.zeros(len(faces), np.float64)
    if surface.uvs is None or surface.face_material is None or not surface.images or not len(faces):
        return out
    texels = np.zeros(len(faces), np.float64)  # w h of each face's image
    if chain is not None:
        texels[:] = chain.width * chain.height
    else:
        material = np.asarray(surface.face_material, np.int64)[faces]
        for row, image in surface.images.items():
            texels[material == row] = image.width * image.height
    return surface.uv_stretch[faces] * np.sqrt(texels)


def _uv_stretch(surface: Surface) -> np.ndarray:
    """(m,) float64 sqrt(uv_area / area_3d) of every face (UV units per model unit); 0 where a face
    has no area in model space or UV space."""
    corners = np.asarray(surface.faces, np.int64)
    p = np.asarray(surface.positions, np.float64)[corners]
    t = np.asarray(surface.uvs, np.float64)[corners]
    area_3d = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    area_uv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    out = np.zeros(len(corners), np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        stretch = np.sqrt(area_uv / area_3d)
    np.copyto(out, stretch, where=np.isfinite(stretch) & (area_3d > 0.0))
    return out
