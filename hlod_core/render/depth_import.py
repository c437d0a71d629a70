"""A host's depth in the renderer's depth buffer, so that its queries see the host's objects
(docs/how-it-works.md#occlusion-by-the-hosts-objects).

Data form: a depth image is (h, w) float32 window depth in [0, 1] (1: the far plane, the clear
value), row 0 the bottom row: what glReadPixels(GL_DEPTH_COMPONENT, GL_FLOAT) and Blender's
`GPUFrameBuffer.read_depth(0, 0, w, h)` give (checked in the bpy module: a triangle at NDC z 0.5
over the lower left reads 0.75 in row 0, column 0). It is uploaded as an R32F texture, at the
frame's size or reduced by an integer factor (`reduce_depth`: each reduced pixel is the farthest of
its block, so a query never counts fewer pixels than at full resolution), and written into the
bound framebuffer's depth by a full-screen triangle whose fragments set gl_FragDepth to the texel of
their block (texelFetch; depth test ALWAYS, colour writes off).
"""
from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from .gl_functions import GL, GLFunctions

#: Full-screen triangle from gl_VertexID (no vertex buffer); the fragment reads the depth texel of
#: its window pixel's block.
DEPTH_VS = """
#version 330
void main() {
    vec2 corner = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
    gl_Position = vec4(corner, 0.0, 1.0);
}
"""
DEPTH_FS = """
#version 330
uniform sampler2D u_depth;
uniform int u_factor;  // the reduction: texel (x, y) holds window pixels [x f, (x + 1) f) x [y f, (y + 1) f)
void main() {
    gl_FragDepth = texelFetch(u_depth, ivec2(gl_FragCoord.xy) / u_factor, 0).r;
}
"""


def check_depth(depth, *, where: str = "depth") -> np.ndarray:
    """`depth` as a C-contiguous (h, w) float32 array; InputError naming `where` for another shape,
    NaN or values outside [0, 1]."""
    array = np.ascontiguousarray(depth, np.float32)
    if array.ndim != 2 or min(array.shape) < 1:
        raise InputError(f"{where}: expected a (height, width) depth image, got shape {array.shape}")
    if not (np.all(array >= 0.0) and np.all(array <= 1.0)):  # NaN fails both
        raise InputError(f"{where}: depth values must be window depth in [0, 1] (NaN or a value outside)")
    return array


def reduce_depth(depth: np.ndarray, factor: int) -> np.ndarray:
    """(ceil(h / factor), ceil(w / factor)) float32: the farthest depth of each factor x factor block of
    `depth` (h, w), blocks cut from row 0 and column 0; a block past the edge takes what it covers.
    Columns then rows, one np.maximum per offset in the block (factor - 1 each): a reshape and max
    over the block's axes was 5 to 10 times slower."""
    if factor == 1:
        return depth
    columns = depth[:, 0::factor].copy()
    for k in range(1, factor):
        part = depth[:, k::factor]
        np.maximum(columns[:, :part.shape[1]], part, out=columns[:, :part.shape[1]])
    out = columns[0::factor].copy()
    for k in range(1, factor):
        part = columns[k::factor]
        np.maximum(out[:part.shape[0]], part, out=out[:part.shape[0]])
    return out


class DepthImport:
    """The depth texture and the program that writes it into the bound framebuffer's depth. GL
    objects go to `keep` (the owner releases them, with the texture `release` frees)."""

    def __init__(self, ctx, *, gl: GLFunctions, keep):
        self.ctx = ctx
        self._gl = gl
        self.program = keep(ctx.program(vertex_shader=DEPTH_VS, fragment_shader=DEPTH_FS))
        self.vao = keep(ctx.vertex_array(self.program, []))
        self._u_factor = self.program["u_factor"]
        self.factor = 1
        self.texture = None  # R32F, made for the first image and remade when the size changes

    def upload(self, depth: np.ndarray, *, factor: int = 1) -> None:
        """Upload a checked (h, w) float32 depth image (check_depth), reduced by `factor` already
        (reduce_depth) or not (1)."""
        self.factor = int(factor)
        h, w = depth.shape
        if self.texture is None or self.texture.size != (w, h):
            self.release_texture()
            self.texture = self.ctx.texture((w, h), 1, dtype="f4")
            self.texture.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            self.texture.repeat_x = self.texture.repeat_y = False
        self.texture.write(depth)

    def write(self) -> None:
        """Write the uploaded depth into the bound framebuffer over the viewport: depth writes on,
        test ALWAYS, colour writes and culling off; the depth function is "<=" again after. The
        caller sets its own state again afterwards."""
        gl = self._gl
        gl.color_mask(0, 0, 0, 0)
        gl.depth_mask(1)
        gl.disable(GL.CULL_FACE)
        gl.enable(GL.DEPTH_TEST)
        gl.depth_func(GL.ALWAYS)
        self.texture.use(0)
        self._u_factor.value = self.factor
        self.vao.render(self.ctx.TRIANGLES, vertices=3)
        gl.depth_func(GL.LEQUAL)

    def release_texture(self) -> None:
        if self.texture is not None:
            self.texture.release()
            self.texture = None


def wall_depth(view, *, distance: float, covered: float = 0.5) -> np.ndarray:
    """(h, w) float32 depth image (module notes) of what a host's wall leaves in its depth buffer:
    a plane facing the camera at `distance` model units along the view direction, over the left
    `covered` fraction of the columns, the far plane (1.0) elsewhere. For checks and measurements
    that stand in for a host's objects. Window depth = (z_ndc + 1) / 2 with
    z_ndc = (P[2,2] z + P[2,3]) / (P[3,2] z + P[3,3]) at view-space z = -distance."""
    p = view.projection
    z = -float(distance)
    z_ndc = (p[2, 2] * z + p[2, 3]) / (p[3, 2] * z + p[3, 3])
    depth = np.ones((view.height, view.width), np.float32)
    depth[:, :int(round(covered * view.width))] = np.float32(0.5 * (z_ndc + 1.0))
    return depth
