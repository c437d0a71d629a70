"""A host's depth in the renderer's depth buffer, so that its queries see the host's objects
(docs/how-it-works.md#occlusion-by-the-hosts-objects).

Data form: a depth image is (h, w) float32 window depth in [0, 1] (1: the far plane, the clear
value), row 0 the bottom row: what glReadPixels(GL_DEPTH_COMPONENT, GL_FLOAT) and Blender's
`GPUFrameBuffer.read_depth(0, 0, w, h)` give (checked in the bpy module: a triangle at NDC z 0.5
over the lower left reads 0.75 in row 0, column 0). It is uploaded at the frame's size or reduced
by an integer factor (`reduce_depth`: each reduced pixel is the farthest of
its block, so a query never counts fewer pixels than at full resolution), into a DEPTH_COMPONENT24
texture, and blitted into the renderer's own framebuffer's depth (glBlitFramebuffer, nearest, each
texel over its block). On llvmpipe the blit cost a quarter of a full-screen pass writing
gl_FragDepth at 1920x1080 (12 against 48 ms; docs/performance.md#depth-import).
"""
from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from .gl_functions import GL, GLFunctions


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
    """The depth texture (DEPTH_COMPONENT24, the renderer's depth format) and the framebuffer it is
    attached to, blitted into the renderer's depth. Made for the first image and remade when the
    uploaded size changes; `release` frees both (idempotent)."""

    def __init__(self, ctx, *, gl: GLFunctions):
        self.ctx = ctx
        self._gl = gl
        self.texture = self.framebuffer = None
        self.factor = 1

    def upload(self, depth: np.ndarray, *, factor: int = 1) -> None:
        """Upload a checked (h, w) float32 depth image (check_depth), reduced by `factor` already
        (reduce_depth) or not (1)."""
        self.factor = int(factor)
        h, w = depth.shape
        if self.texture is None or self.texture.size != (w, h):
            self.release()
            self.texture = self.ctx.depth_texture((w, h))
            self.framebuffer = self.ctx.framebuffer(depth_attachment=self.texture)
        self.texture.write(depth)

    def write(self, target) -> None:
        """Blit the uploaded depth into the depth of the moderngl framebuffer `target` (a
        DEPTH_COMPONENT24 attachment, as the renderer's own), each texel over its factor x factor
        block (nearest: pixel x of the target reads texel floor((x + 0.5) / factor) = x // factor);
        `target` is bound again after."""
        w, h = self.texture.size
        gl = self._gl
        gl.bind_framebuffer(GL.READ_FRAMEBUFFER, self.framebuffer.glo)
        gl.bind_framebuffer(GL.DRAW_FRAMEBUFFER, target.glo)
        gl.blit_framebuffer(0, 0, w, h, 0, 0, w * self.factor, h * self.factor, GL.DEPTH_BUFFER_BIT, GL.NEAREST)
        target.use()

    def release(self) -> None:
        for resource in (self.framebuffer, self.texture):
            if resource is not None:
                resource.release()
        self.texture = self.framebuffer = None


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
