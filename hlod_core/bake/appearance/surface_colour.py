"""TEMPORARY stand-in (replaced by the full sampler): what a textured surface shows at given points."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.colour import srgb_to_linear
from ...model.appearance import NO_MATERIAL_BASE_COLOR


@dataclass(frozen=True, eq=False)
class Surface:
    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    colors: np.ndarray | None
    face_material: np.ndarray | None
    materials: tuple
    images: dict


class MipChain:
    def __init__(self, levels):
        self.levels = levels
        self.nbytes = sum(level.nbytes for level in levels)
        self.height, self.width = levels[0].shape[:2]

    @staticmethod
    def of(image):
        h, w, _ = image.shape
        linear = srgb_to_linear(image.reshape(-1, 4) / 255.0).reshape(h, w, 4)[::-1]
        levels = [np.ascontiguousarray(linear)]
        while levels[-1].shape[0] > 1 or levels[-1].shape[1] > 1:
            a = levels[-1]
            hh, ww = max(1, a.shape[0] // 2), max(1, a.shape[1] // 2)
            a = a[:hh * 2 if a.shape[0] > 1 else 1, :ww * 2 if a.shape[1] > 1 else 1]
            a = a.reshape(hh, a.shape[0] // hh, ww, a.shape[1] // ww, 4).mean(axis=(1, 3))
            levels.append(a.astype(np.float32))
        return MipChain(levels)


def colour_at(surface, face, bary, *, footprint):
    f = surface.faces[face]
    out = np.ones((face.size, 4), np.float32)
    if surface.colors is not None:
        out *= np.einsum("sk,skc->sc", bary, surface.colors[f])
    mat = surface.face_material[face] if surface.face_material is not None else np.zeros(face.size, np.int64)
    base = np.array([m.base_color for m in surface.materials] or [NO_MATERIAL_BASE_COLOR], np.float32)
    out *= base[mat]
    if surface.uvs is not None:
        uv = np.einsum("sk,skc->sc", bary, surface.uvs[f].astype(np.float64))
        for m, chain in surface.images.items():
            sel = mat == m
            if not sel.any():
                continue
            level = chain.levels[0]
            h, w, _ = level.shape
            x = np.floor((uv[sel, 0] % 1.0) * w).astype(np.int64) % w
            y = np.floor((uv[sel, 1] % 1.0) * h).astype(np.int64) % h
            out[sel] *= level[y, x]
    return out
