"""The nodes' query boxes (docs/how-it-works.md#query-boxes): one unit cube, stretched per draw to a node's box.

Data form: a node's query box is its subtree box enlarged by `hierarchy.query_box_pad`, relative to
the file's origin, as float32 corners (n,3) kept as Python tuples (a uniform's value, no conversion
per draw). The cube is 8 corners and 12 triangles, counter-clockwise seen from outside, so with
back faces culled each pixel a box covers is rasterised once. The renderer chooses the state it is
drawn in (`Renderer.set_mode`): `q` with the depth test on, `alpha` with it off.
"""
from __future__ import annotations

import numpy as np

from ..model.hierarchy import Hlod, query_box_pad
from .shaders import BOX_FS, BOX_VS

#: The unit cube's corners (8,3) float32 (corner c has coordinate a = bit a of c) and triangles (12,3) int32.
CUBE_CORNERS = np.array([[(c >> a) & 1 for a in range(3)] for c in range(8)], np.float32)
CUBE_TRIS = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                      [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]], np.int32)


class QueryBoxes:
    """The box program, the cube's buffers and every node's padded box. GL objects go to `keep`
    (the owner releases them)."""

    def __init__(self, ctx, hlod: Hlod, *, keep):
        import moderngl

        self._triangles = moderngl.TRIANGLES
        self.program = keep(ctx.program(vertex_shader=BOX_VS, fragment_shader=BOX_FS))
        vbo = keep(ctx.buffer(CUBE_CORNERS.tobytes()))
        ibo = keep(ctx.buffer(CUBE_TRIS.tobytes()))
        self.vao = keep(ctx.vertex_array(self.program, [(vbo, "3f", "in_unit")], index_buffer=ibo,
                                         index_element_size=4))
        #: model units each box is enlarged by on every side
        self.pad = query_box_pad(hlod.box_min, hlod.box_max)
        lo = (hlod.box_min - self.pad - hlod.origin).astype(np.float32)
        hi = (hlod.box_max + self.pad - hlod.origin).astype(np.float32)
        self._lo = [tuple(row) for row in lo.tolist()]
        self._hi = [tuple(row) for row in hi.tolist()]
        self._u_lo, self._u_hi, self._u_mvp = self.program["u_lo"], self.program["u_hi"], self.program["u_mvp"]

    def set_matrix(self, mvp: bytes) -> None:
        """The model-view-projection matrix: 16 float32, column-major."""
        self._u_mvp.write(mvp)

    def set_corners(self, lo, hi) -> None:
        """The box `draw` draws: (3,) corners in the matrix's input space (calibration: clip space)."""
        self._u_lo.value, self._u_hi.value = tuple(lo), tuple(hi)

    def draw(self) -> None:
        """Draw the box set last (`set_corners` or `draw_node`)."""
        self.vao.render(self._triangles)

    def draw_node(self, node: int) -> None:
        """Draw node `node`'s query box."""
        self._u_lo.value = self._lo[node]
        self._u_hi.value = self._hi[node]
        self.vao.render(self._triangles)
