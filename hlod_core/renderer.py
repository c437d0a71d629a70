"""GL renderer for the traversal (DESIGN §7), on moderngl.

moderngl draws; it has no non-blocking "result available" check, so occlusion and timer queries
go through the GL entry points that moderngl's own loader (glcontext) resolves, called via
ctypes. All node geometry lives in one vertex and one index buffer; a node draw is one ranged
draw. Query objects are pooled and reused. The renderer works on a standalone EGL context
(`create_standalone`, headless: Mesa llvmpipe on machines without a GPU) or on a context handed
in by the caller (Blender's, in the add-on), drawing into the caller's framebuffer.

Query boxes (DESIGN §5.4): the node's subtree box enlarged by `hierarchy.query_box_pad`, drawn with
colour and depth writes off and back faces culled; `q` with the depth test on, `alpha` (the
`query` estimator) with it off, so both count the same rasterised pixels, clipping included.
"""
from __future__ import annotations

import ctypes
import logging
import time
from dataclasses import dataclass

import numpy as np

from .hierarchy import Hlod, query_box_pad
from .metrics import View

log = logging.getLogger(__name__)

GL_SAMPLES_PASSED = 0x8914
GL_TIME_ELAPSED = 0x88BF
GL_QUERY_RESULT = 0x8866
GL_QUERY_RESULT_AVAILABLE = 0x8867
GL_NO_ERROR = 0
GL_DEPTH_TEST = 0x0B71
GL_CULL_FACE = 0x0B44

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

DEFAULT_COLOUR = (0.82, 0.80, 0.76)


class GLFunctions:
    """The query entry points, resolved by moderngl's loader and called through ctypes."""

    def __init__(self, ctx):
        loader = ctx.mglo._context  # glcontext's backend, or moderngl's DefaultLoader for get_context()
        load = getattr(loader, "load", None) or loader.load_opengl_function
        u32p, u64p = ctypes.POINTER(ctypes.c_uint32), ctypes.POINTER(ctypes.c_uint64)

        def fn(name, restype, *argtypes):
            addr = load(name)
            if not addr:
                raise RuntimeError(f"GL function {name} is not available in this context")
            return ctypes.CFUNCTYPE(restype, *argtypes)(addr)

        self.gen_queries = fn("glGenQueries", None, ctypes.c_int32, u32p)
        self.delete_queries = fn("glDeleteQueries", None, ctypes.c_int32, u32p)
        self.begin_query = fn("glBeginQuery", None, ctypes.c_uint32, ctypes.c_uint32)
        self.end_query = fn("glEndQuery", None, ctypes.c_uint32)
        self.get_query_uiv = fn("glGetQueryObjectuiv", None, ctypes.c_uint32, ctypes.c_uint32, u32p)
        self.get_query_ui64v = fn("glGetQueryObjectui64v", None, ctypes.c_uint32, ctypes.c_uint32, u64p)
        self.flush = fn("glFlush", None)
        self.get_error = fn("glGetError", ctypes.c_uint32)
        self.is_query = fn("glIsQuery", ctypes.c_uint8, ctypes.c_uint32)
        self.color_mask = fn("glColorMask", None, ctypes.c_uint8, ctypes.c_uint8, ctypes.c_uint8, ctypes.c_uint8)
        self.depth_mask = fn("glDepthMask", None, ctypes.c_uint8)
        self.enable = fn("glEnable", None, ctypes.c_uint32)
        self.disable = fn("glDisable", None, ctypes.c_uint32)
        i32p, u8p = ctypes.POINTER(ctypes.c_int32), ctypes.POINTER(ctypes.c_uint8)
        self.get_integerv = fn("glGetIntegerv", None, ctypes.c_uint32, i32p)
        self.get_booleanv = fn("glGetBooleanv", None, ctypes.c_uint32, u8p)
        self.is_enabled = fn("glIsEnabled", ctypes.c_uint8, ctypes.c_uint32)
        self.bind_framebuffer = fn("glBindFramebuffer", None, ctypes.c_uint32, ctypes.c_uint32)
        self.use_program = fn("glUseProgram", None, ctypes.c_uint32)
        self.bind_vertex_array = fn("glBindVertexArray", None, ctypes.c_uint32)
        self.bind_buffer = fn("glBindBuffer", None, ctypes.c_uint32, ctypes.c_uint32)
        self.depth_func = fn("glDepthFunc", None, ctypes.c_uint32)
        self.viewport = fn("glViewport", None, ctypes.c_int32, ctypes.c_int32, ctypes.c_int32, ctypes.c_int32)
        self.scissor = fn("glScissor", None, ctypes.c_int32, ctypes.c_int32, ctypes.c_int32, ctypes.c_int32)
        self.active_texture = fn("glActiveTexture", None, ctypes.c_uint32)


class GLState:
    """The host's GL state that a moderngl pass changes, saved before it and restored after it
    (DESIGN §7: Blender caches GL state and does not notice changes made behind its back):
    framebuffer bindings, program, vertex array and array buffer, depth and colour write masks,
    depth function, depth test, blend, cull and scissor flags, viewport, scissor box, active
    texture unit."""

    _INTS = {"draw_fbo": 0x8CA6, "read_fbo": 0x8CAA, "program": 0x8B8D, "vao": 0x85B5, "array_buffer": 0x8894,
             "depth_func": 0x0B74, "active_texture": 0x84E0}
    _FLAGS = {"depth_test": GL_DEPTH_TEST, "blend": 0x0BE2, "cull_face": GL_CULL_FACE, "scissor_test": 0x0C11}

    def __init__(self, gl: GLFunctions):
        self._gl = gl
        self.values: dict = {}

    def save(self) -> "GLState":
        gl, v = self._gl, {}
        one = ctypes.c_int32(0)
        for name, pname in self._INTS.items():
            gl.get_integerv(pname, ctypes.byref(one))
            v[name] = one.value
        four = (ctypes.c_int32 * 4)()
        gl.get_integerv(0x0BA2, four)  # GL_VIEWPORT
        v["viewport"] = tuple(four)
        gl.get_integerv(0x0C10, four)  # GL_SCISSOR_BOX
        v["scissor"] = tuple(four)
        masks = (ctypes.c_uint8 * 4)()
        gl.get_booleanv(0x0C23, masks)  # GL_COLOR_WRITEMASK
        v["color_mask"] = tuple(masks)
        gl.get_booleanv(0x0B72, masks)  # GL_DEPTH_WRITEMASK
        v["depth_mask"] = masks[0]
        for name, cap in self._FLAGS.items():
            v[name] = bool(gl.is_enabled(cap))
        self.values = v
        return self

    def restore(self) -> None:
        gl, v = self._gl, self.values
        gl.bind_framebuffer(0x8CA9, v["draw_fbo"])  # GL_DRAW_FRAMEBUFFER
        gl.bind_framebuffer(0x8CA8, v["read_fbo"])  # GL_READ_FRAMEBUFFER
        gl.use_program(v["program"])
        gl.bind_vertex_array(v["vao"])
        gl.bind_buffer(0x8892, v["array_buffer"])  # GL_ARRAY_BUFFER
        gl.depth_func(v["depth_func"])
        gl.active_texture(v["active_texture"])
        gl.viewport(*v["viewport"])
        gl.scissor(*v["scissor"])
        gl.color_mask(*v["color_mask"])
        gl.depth_mask(v["depth_mask"])
        for name, cap in self._FLAGS.items():
            (gl.enable if v[name] else gl.disable)(cap)


class QueryPool:
    """GL query objects, generated in blocks and reused across frames."""

    def __init__(self, gl: GLFunctions):
        self._gl = gl
        self._free: list[int] = []
        self._all: list[int] = []

    def acquire(self) -> int:
        if not self._free:
            block = (ctypes.c_uint32 * 64)()
            self._gl.gen_queries(64, block)
            self._all.extend(block)
            self._free.extend(block)
        return self._free.pop()

    def give_back(self, query: int) -> None:
        self._free.append(query)

    @property
    def allocated(self) -> int:
        return len(self._all)

    @property
    def ids(self) -> list[int]:
        return list(self._all)

    def release(self) -> None:
        if self._all:
            ids = (ctypes.c_uint32 * len(self._all))(*self._all)
            self._gl.delete_queries(len(self._all), ids)
        self._all, self._free = [], []


@dataclass
class Query:
    """One node's occlusion query: `samples` (q) and optionally `alpha` (unoccluded count)."""

    node: int
    samples: int
    alpha: int | None


class Renderer:
    """Draws HLOD nodes and issues their occlusion queries into the current or an own framebuffer."""

    def __init__(self, ctx, hlod: Hlod, *, size: tuple[int, int] | None = None, owns_context: bool = False,
                 time_gpu: bool = True):
        import moderngl

        self._mgl = moderngl
        self.ctx = ctx
        self.hlod = hlod
        self._owns_context = owns_context
        self.time_gpu = time_gpu  # False inside a host that may run its own timer queries
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

    def begin_frame(self, view: View, *, clear: bool = True, time_gpu: bool | None = None) -> None:
        """Set matrices (float64 -> float32 with the file origin folded in), bind, clear, start the
        GPU timer."""
        to_origin = np.eye(4)
        to_origin[:3, 3] = self.hlod.origin
        mv = view.view @ to_origin
        mvp = view.projection @ mv
        for program in (self.node_program, self.box_program):
            program["u_mvp"].write(mvp.T.astype(np.float32).tobytes())
        self.node_program["u_mv"].write(mv.T.astype(np.float32).tobytes())
        self._host_fbo = self.ctx.detect_framebuffer()  # the caller's, this frame (it may change)
        if self.fbo is not None:
            self.fbo.use()
        self.ctx.viewport = (0, 0, view.width, view.height)
        if clear and self.fbo is not None:
            self.fbo.clear(1.0, 1.0, 1.0, 1.0, depth=1.0)
        self.ctx.enable(self._mgl.DEPTH_TEST)
        self.ctx.depth_func = "<="
        self._mode = None
        self._colour = None
        self._timer = None
        if self.time_gpu if time_gpu is None else time_gpu:
            self._timer = self.queries.acquire()
            self.gl.begin_query(GL_TIME_ELAPSED, self._timer)

    def end_frame(self) -> float:
        """Finish the frame; GPU milliseconds from the timer query (0 if it was not started)."""
        self._set_mode(None)
        gpu_ms = 0.0
        if self._timer is not None:
            self.gl.end_query(GL_TIME_ELAPSED)
            value = ctypes.c_uint64(0)
            self.gl.get_query_ui64v(self._timer, GL_QUERY_RESULT, ctypes.byref(value))
            self.queries.give_back(self._timer)
            self._timer = None
            gpu_ms = value.value / 1e6
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
            gl.disable(GL_CULL_FACE)
            gl.enable(GL_DEPTH_TEST)
        else:
            gl.color_mask(0, 0, 0, 0)
            gl.depth_mask(0)
            gl.enable(GL_CULL_FACE)
            (gl.enable if mode == "query" else gl.disable)(GL_DEPTH_TEST)
        self._mode = mode

    # --- nodes and queries ----------------------------------------------------------------------

    def draw_node(self, node: int, colour=DEFAULT_COLOUR) -> None:
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
        samples = self.queries.acquire()
        self._set_mode("query")
        self.gl.begin_query(GL_SAMPLES_PASSED, samples)
        self._box(node)
        self.gl.end_query(GL_SAMPLES_PASSED)
        alpha = None
        if with_alpha:
            alpha = self.queries.acquire()
            self._set_mode("alpha")
            self.gl.begin_query(GL_SAMPLES_PASSED, alpha)
            self._box(node)
            self.gl.end_query(GL_SAMPLES_PASSED)
        return Query(node=node, samples=samples, alpha=alpha)

    def available(self, query: Query) -> bool:
        """Non-blocking. Flushes once when not yet available, so a deferred rasteriser starts."""
        flag = ctypes.c_uint32(0)
        last = query.alpha if query.alpha is not None else query.samples
        self.gl.get_query_uiv(last, GL_QUERY_RESULT_AVAILABLE, ctypes.byref(flag))
        if not flag.value:
            self.gl.flush()
            self.gl.get_query_uiv(last, GL_QUERY_RESULT_AVAILABLE, ctypes.byref(flag))
        return bool(flag.value)

    def result(self, query: Query) -> tuple[int, int | None, float]:
        """(q, alpha or None, stall seconds). Blocks if the result is not available; the time
        blocked is returned as stall. Gives the query objects back to the pool."""
        stall = 0.0
        if not self.available(query):
            started = time.perf_counter()
            value = self._get(query.samples)
            alpha = self._get(query.alpha) if query.alpha is not None else None
            stall = time.perf_counter() - started
        else:
            value = self._get(query.samples)
            alpha = self._get(query.alpha) if query.alpha is not None else None
        self.queries.give_back(query.samples)
        if query.alpha is not None:
            self.queries.give_back(query.alpha)
        return value, alpha, stall

    def _get(self, query_id: int) -> int:
        value = ctypes.c_uint32(0)
        self.gl.get_query_uiv(query_id, GL_QUERY_RESULT, ctypes.byref(value))
        return int(value.value)

    # --- output and lifetime --------------------------------------------------------------------

    def read_pixels(self) -> np.ndarray:
        """(H, W, 3) uint8, top row first."""
        fbo = self.fbo if self.fbo is not None else self._host_fbo  # ctx.fbo may be a released one
        w, h = fbo.size
        data = np.frombuffer(fbo.read(components=3, alignment=1), np.uint8).reshape(h, w, 3)
        return data[::-1].copy()

    def gl_error(self) -> int:
        return int(self.gl.get_error())

    def release(self) -> None:
        """Free every GL object this renderer made, in reverse creation order. Idempotent."""
        if self._released:
            return
        self._released = True
        self.queries.release()
        if self.fbo is not None:
            self._host_fbo.use()
        for resource in reversed(self._resources):
            resource.release()
        self._resources.clear()
        if self._owns_context:
            self.ctx.release()
