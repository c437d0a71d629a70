"""GL renderer for the traversal (DESIGN §7), on moderngl: draws nodes and their query boxes.

Data form: all node geometry in one vertex buffer (float32 positions relative to the file's
origin) and one index buffer (uint32); node i is the ranged draw of indices
[3 tri_offset[i], 3 (tri_offset[i] + tri_count[i])). Query boxes are one unit cube drawn with
per-node uniforms. Raw GL entry points and enums live in `gl_functions`, the query-id pool and its
result reads in `queries`, the host-state save/restore in `gl_state`. The renderer works on a
standalone EGL context (`create_standalone`, headless: Mesa llvmpipe on machines without a GPU)
or on a context handed in by the caller (Blender's, in the add-on), drawing into the caller's
framebuffer.

Query boxes (DESIGN §5.4): the node's subtree box enlarged by `hierarchy.query_box_pad`, drawn with
colour and depth writes off and back faces culled; `q` with the depth test on, `alpha` (the
`query` estimator) with it off, so both count the same rasterised pixels, clipping included.

Colours are decided here: a node is drawn in DEFAULT_COLOUR, or with `overlay` on, in the
modulation ramp's colour (overlay.modulation_colour) of the ratio P the traversal passes,
looked up in a table of the ramp precomputed at OVERLAY_RAMP_STEPS + 1 values of P.
"""
from __future__ import annotations

import contextlib
import ctypes
import logging

import numpy as np

from .gl_functions import GL, GLFunctions
from .hierarchy import Hlod, query_box_pad
from .overlay import OVERLAY_RAMP_STEPS, overlay_ramp
from .view import View
from .queries import Query, QueryPool

log = logging.getLogger(__name__)

_NODE_VS = """
#version 330
in vec3 in_pos;
uniform mat4 u_mvp;
uniform mat4 u_mv;
out vec3 v_view;
void main() {
    v_view = (u_mv * vec4(in_pos, 1.0)).xyz;
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""
_NODE_FS = """
#version 330
in vec3 v_view;
uniform vec3 u_colour;
out vec4 f_colour;
void main() {
    vec3 n = normalize(cross(dFdx(v_view), dFdy(v_view)));  // flat shading, no normals needed
    f_colour = vec4(u_colour * (0.25 + 0.75 * abs(n.z)), 1.0);
}
"""
_BOX_VS = """
#version 330
in vec3 in_unit;
uniform vec3 u_lo;
uniform vec3 u_hi;
uniform mat4 u_mvp;
void main() { gl_Position = u_mvp * vec4(mix(u_lo, u_hi, in_unit), 1.0); }
"""
_BOX_FS = """
#version 330
out vec4 f_colour;
void main() { f_colour = vec4(1.0); }
"""
# unit cube, 12 triangles counter-clockwise seen from outside
_CUBE_CORNERS = np.array([[(c >> a) & 1 for a in range(3)] for c in range(8)], np.float32)
_CUBE_TRIS = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                       [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]], np.int32)

DEFAULT_COLOUR = (0.82, 0.80, 0.76)  # linear RGB of a node without the overlay
class Renderer:
    """Draws HLOD nodes and issues their occlusion queries into the current or an own framebuffer.

    `overlay`: draw nodes in the modulation colour of the ratio P the traversal passes to
    `draw_node` (else DEFAULT_COLOUR). `time_gpu`: time each frame with a GL timer query (False
    inside a host that may run its own timer queries)."""

    def __init__(self, ctx, hlod: Hlod, *, size: tuple[int, int] | None = None, owns_context: bool = False,
                 time_gpu: bool = True, overlay: bool = False):
        import moderngl

        self._mgl = moderngl
        self.ctx = ctx
        self.hlod = hlod
        self._owns_context = owns_context
        self.time_gpu = time_gpu
        self.overlay = overlay
        self._released = False
        self.gl = GLFunctions(ctx)
        self.queries = QueryPool(self.gl)
        self._resources = []
        self.node_program = self._keep(ctx.program(vertex_shader=_NODE_VS, fragment_shader=_NODE_FS))
        self.box_program = self._keep(ctx.program(vertex_shader=_BOX_VS, fragment_shader=_BOX_FS))
        self.vbo = self._keep(ctx.buffer(np.ascontiguousarray(hlod.positions, np.float32).tobytes()))
        self.ibo = self._keep(ctx.buffer(np.ascontiguousarray(hlod.indices, np.uint32).tobytes()))
        self.vao = self._keep(ctx.vertex_array(self.node_program, [(self.vbo, "3f", "in_pos")],
                                               index_buffer=self.ibo, index_element_size=4))
        self.cube_vbo = self._keep(ctx.buffer(_CUBE_CORNERS.tobytes()))
        self.cube_ibo = self._keep(ctx.buffer(_CUBE_TRIS.tobytes()))
        self.cube_vao = self._keep(ctx.vertex_array(self.box_program, [(self.cube_vbo, "3f", "in_unit")],
                                                    index_buffer=self.cube_ibo, index_element_size=4))
        self.fbo = None
        self._host_fbo = ctx.detect_framebuffer()  # what the caller has bound; refreshed per frame
        if size is not None:
            colour = self._keep(ctx.renderbuffer(size, components=4))
            depth = self._keep(ctx.depth_renderbuffer(size))
            self.fbo = self._keep(ctx.framebuffer(color_attachments=[colour], depth_attachment=depth))
        pad = query_box_pad(hlod.box_min, hlod.box_max)
        self.query_box_min = (hlod.box_min - pad - hlod.origin).astype(np.float32)
        self.query_box_max = (hlod.box_max + pad - hlod.origin).astype(np.float32)
        self.query_box_pad = pad
        self._tri_first = (np.asarray(hlod.tri_offset) * 3).astype(np.int64)
        self._tri_vertices = (np.asarray(hlod.tri_count) * 3).astype(np.int64)
        self._qmin = [tuple(r) for r in self.query_box_min.tolist()]
        self._qmax = [tuple(r) for r in self.query_box_max.tolist()]
        self._u_colour = self.node_program["u_colour"]
        self._u_lo, self._u_hi = self.box_program["u_lo"], self.box_program["u_hi"]
        self._ramp = overlay_ramp()
        self._colour = None
        self._mode = None
        self._timer = None

    @classmethod
    def create_standalone(cls, hlod: Hlod, size: tuple[int, int]) -> "Renderer":
        """A private headless EGL context (llvmpipe where there is no GPU) and an own framebuffer."""
        import moderngl

        ctx = moderngl.create_context(standalone=True, backend="egl", require=330)
        return cls(ctx, hlod, size=size, owns_context=True)

    def _keep(self, resource):
        self._resources.append(resource)
        return resource

    # --- frame ----------------------------------------------------------------------------------

    def begin_frame(self, view: View, *, time_gpu: bool | None = None) -> None:
        """Set matrices (float64 -> float32 with the file origin folded in), bind (and clear an own
        framebuffer), start the GPU timer (`time_gpu` overrides the renderer's setting)."""
        to_origin = np.eye(4)
        to_origin[:3, 3] = self.hlod.origin
        mv = view.view @ to_origin
        mvp = view.projection @ mv
        for program in (self.node_program, self.box_program):
            program["u_mvp"].write(mvp.T.astype(np.float32).tobytes())
        self.node_program["u_mv"].write(mv.T.astype(np.float32).tobytes())
        self._refresh_host_framebuffer()
        if self.fbo is not None:
            self.fbo.use()
        self.ctx.viewport = (0, 0, view.width, view.height)
        if self.fbo is not None:
            self.fbo.clear(1.0, 1.0, 1.0, 1.0, depth=1.0)
        self.ctx.enable(self._mgl.DEPTH_TEST)
        self.ctx.depth_func = "<="
        self._mode = None
        self._colour = None
        self._timer = None
        if self.time_gpu if time_gpu is None else time_gpu:
            self._timer = self.queries.acquire()
            self.gl.begin_query(GL.TIME_ELAPSED, self._timer)

    def end_frame(self) -> float:
        """Finish the frame; GPU milliseconds from the timer query (0 if it was not started)."""
        self._set_mode(None)
        gpu_ms = 0.0
        if self._timer is not None:
            self.gl.end_query(GL.TIME_ELAPSED)
            gpu_ms = self.queries.elapsed_ms(self._timer)
            self.queries.give_back(self._timer)
            self._timer = None
        self.ctx.finish()
        if self.fbo is not None:
            self._host_fbo.use()  # never leave ours bound: moderngl rebinds its last one later
        return gpu_ms

    def _set_mode(self, mode: str | None) -> None:
        """'draw' (and None, the frame's end): colour and depth writes, depth test, no culling;
        'query' / 'alpha': no writes, back faces culled, depth test on / off. Raw GL calls: the
        state must hold for the very next draw, whatever moderngl has cached."""
        if mode == self._mode:
            return
        gl = self.gl
        if mode == "draw" or mode is None:
            gl.color_mask(1, 1, 1, 1)
            gl.depth_mask(1)
            gl.disable(GL.CULL_FACE)
            gl.enable(GL.DEPTH_TEST)
        else:
            gl.color_mask(0, 0, 0, 0)
            gl.depth_mask(0)
            gl.enable(GL.CULL_FACE)
            (gl.enable if mode == "query" else gl.disable)(GL.DEPTH_TEST)
        self._mode = mode

    # --- nodes and queries ----------------------------------------------------------------------

    def draw_node(self, node: int, ratio_p: float = 1.0) -> None:
        """Draw a node chosen by a traversal; ratio_p in [0, 1] is the P that steered its LOD (1 for
        none), shown as its modulation colour when `overlay` is on."""
        if self.overlay:
            step = round(min(1.0, max(0.0, float(ratio_p))) * OVERLAY_RAMP_STEPS)
            self.draw_node_coloured(node, self._ramp[step])
        else:
            self.draw_node_coloured(node, DEFAULT_COLOUR)

    def draw_node_coloured(self, node: int, colour) -> None:
        """Draw a node in `colour`, linear RGB floats (the caller's choice: report figures)."""
        self._set_mode("draw")
        if colour is not self._colour:
            self._u_colour.value = tuple(float(c) for c in colour)
            self._colour = colour
        self.vao.render(self._mgl.TRIANGLES, vertices=int(self._tri_vertices[node]), first=int(self._tri_first[node]))

    def _box(self, node: int) -> None:
        self._u_lo.value = self._qmin[node]
        self._u_hi.value = self._qmax[node]
        self.cube_vao.render(self._mgl.TRIANGLES)

    def issue_query(self, node: int, *, with_alpha: bool) -> Query:
        """Occlusion query of the node's box against the current depth buffer; with_alpha adds
        the depth-test-off query of the same box (the `query` estimator of alpha)."""
        samples_query_id = self.queries.acquire()
        self._set_mode("query")
        self.gl.begin_query(GL.SAMPLES_PASSED, samples_query_id)
        self._box(node)
        self.gl.end_query(GL.SAMPLES_PASSED)
        alpha_query_id = None
        if with_alpha:
            alpha_query_id = self.queries.acquire()
            self._set_mode("alpha")
            self.gl.begin_query(GL.SAMPLES_PASSED, alpha_query_id)
            self._box(node)
            self.gl.end_query(GL.SAMPLES_PASSED)
        return Query(node=node, samples_query_id=samples_query_id, alpha_query_id=alpha_query_id)

    def available(self, query: Query) -> bool:
        """Non-blocking: is the query's result back (see QueryPool.available)?"""
        return self.queries.available(query)

    def result(self, query: Query) -> tuple[int, int | None, float]:
        """(q, alpha or None, stall seconds), blocking if needed (see QueryPool.result)."""
        return self.queries.result(query)

    # --- output and lifetime --------------------------------------------------------------------

    def read_pixels(self) -> np.ndarray:
        """(H, W, 3) uint8, top row first."""
        fbo = self.fbo if self.fbo is not None else self._host_fbo  # ctx.fbo may be a released one
        w, h = fbo.size
        data = np.frombuffer(fbo.read(components=3, alignment=1), np.uint8).reshape(h, w, 3)
        return data[::-1].copy()

    def _refresh_host_framebuffer(self) -> None:
        """Follow the caller's draw framebuffer, which may change between frames. moderngl's
        detect_framebuffer() keeps a few hundred bytes per call while a non-zero framebuffer is
        bound (Blender's viewport always is: tens of MB an hour at 60 fps), so it is asked only
        when the binding has changed."""
        bound = ctypes.c_int32(0)
        self.gl.get_integerv(GL.DRAW_FRAMEBUFFER_BINDING, ctypes.byref(bound))
        if self._host_fbo.glo != bound.value:
            self._host_fbo = self.ctx.detect_framebuffer()

    def release(self) -> None:
        """Free every GL object this renderer made, in reverse creation order, with the context
        that made them current when the renderer owns it (GL names are per context: deleting them
        in another one would delete that context's objects). Idempotent."""
        if self._released:
            return
        self._released = True
        with self.ctx if self._owns_context else contextlib.nullcontext():
            self.queries.release()
            if self.fbo is not None:
                self._host_fbo.use()
            for resource in reversed(self._resources):
                resource.release()
            self._resources.clear()
        if self._owns_context:
            self.ctx.release()
