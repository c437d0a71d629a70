"""What a frame's drawn nodes cost beyond their triangles: draw calls and texture memory (the
evaluation's `draws` and `texture_bytes` columns, docs/evaluation.md#draws-and-texture-memory).

- draws: the ranged draws the renderer issues for the drawn nodes, one per (node, material run)
  (`Hlod.draw_parts`); a node of an HLOD without materials is one draw.
- texture bytes: the distinct texture images the drawn nodes' parts refer to, each counted as RGBA8
  with a full mip chain, 4/3 x width x height x 4 bytes (`texture_bytes`), whatever its file's
  format: what a GPU holds for it uncompressed.

Data form: in, an Hlod and the images the renderer draws (material row -> (h, w, 4) uint8,
io.textures.load_images; one array object per distinct file) and per frame the drawn node ids;
out, per frame (draws, texture bytes) as COLUMNS, vectorised over the drawn nodes' parts.
"""
from __future__ import annotations

import numpy as np

from ..core.arrays import segment_ranges
from ..model.hierarchy import Hlod

#: The per-frame columns, in `DrawCost.frame`'s order.
COLUMNS = ("draws", "texture_bytes")
RGBA8_BYTES = 4
MIP_CHAIN = 4.0 / 3.0  # a full mip chain adds a third to the base level


def texture_bytes(width: int, height: int) -> float:
    """Bytes of one texture as RGBA8 with a full mip chain: 4/3 x width x height x 4."""
    return MIP_CHAIN * width * height * RGBA8_BYTES


class DrawCost:
    """Per frame, the draws and texture bytes of a list of drawn nodes (module docstring)."""

    def __init__(self, hlod: Hlod, images: dict[int, np.ndarray]):
        parts = hlod.draw_parts()
        self._first, self._count = parts.first, parts.count
        distinct: dict[int, int] = {}  # id(image array) -> texture number
        sizes = []
        material_texture = np.full(len(hlod.materials) + 1, -1, np.int64)  # last row: parts without a material
        for row, image in sorted(images.items()):
            if id(image) not in distinct:
                distinct[id(image)] = len(sizes)
                sizes.append(texture_bytes(image.shape[1], image.shape[0]))
            material_texture[row] = distinct[id(image)]
        self._part_texture = material_texture[parts.material]  # material -1 takes the last row
        self._texture_bytes = np.asarray(sizes, np.float64)

    def frame(self, drawn) -> tuple[int, float]:
        """(draws, texture bytes) of the nodes `drawn` (node ids, each drawn once)."""
        nodes = np.asarray(drawn, np.int64)
        if nodes.size == 0:
            return 0, 0.0
        textures = self._part_texture[segment_ranges(self._first[nodes], self._count[nodes])]
        used = np.unique(textures[textures >= 0])
        return int(self._count[nodes].sum()), float(self._texture_bytes[used].sum())


def cost_row(costs: np.ndarray) -> dict:
    """A method's figures from `costs` (repeat, frames, len(COLUMNS)): per frame the median over
    repeats, then the mean and the largest over frames: draws, draws_max, texture_bytes,
    texture_bytes_max."""
    median = np.median(costs, axis=0)
    out = {}
    for j, name in enumerate(COLUMNS):
        out[name] = float(np.mean(median[:, j]))
        out[f"{name}_max"] = float(np.max(median[:, j]))
    return out
