"""GL renderer for the traversal (docs/how-it-works.md#gl-queries), on moderngl: frames, node draws, occlusion queries,
read-back and release.

Data form: all node geometry in one vertex buffer (float32 positions relative to the file's
origin) and one index buffer (uint32); node i is the ranged draw of indices
[3 tri_offset[i], 3 (tri_offset[i] + tri_count[i])). Under a GPU budget (`streaming`) node geometry
and textures are uploaded node by node instead, as the traversal wants them (streamed_geometry.py,
residency.py): `residency` then says which nodes are resident and holds the traversal back where
they are not.
The renderer works on a standalone context (`create_standalone`, the platform's own GL:
gl_platform.py; Mesa llvmpipe on machines without a GPU) or on a context handed in by the caller
(Blender's, in the add-on), drawing into the caller's framebuffer.

States (`set_mode`): "draw" (colour and depth writes, depth test), "query" and "alpha" (no writes,
back faces culled, depth test on / off: both count the same rasterised pixels, clipping included).
`state_changes` counts the switches since the renderer was made. Batched queries (CHC++):
`issue_queries` switches to each query state once for the whole batch; `issue_multiquery` is one
q query around the boxes of several nodes.

Scene depth (`set_scene_depth`): a host's depth image written into the frame's depth buffer after
the clear (depth_import.py), so that the queries and draws are hidden by the host's objects.

Colours: a node is drawn in DEFAULT_COLOUR or, with `overlay` on, in the modulation ramp's colour of
the ratio P the traversal passes (a table of OVERLAY_RAMP_STEPS + 1 colours); an HLOD with an
appearance, overlay off, is drawn in its materials (`materials`).
"""
from __future__ import annotations

import contextlib
import ctypes
import logging
import time

import numpy as np

from ..core.colour import DEFAULT_COLOUR, OVERLAY_RAMP_STEPS, overlay_ramp
from ..core.errors import InputError
from ..model.hierarchy import Hlod
from ..model.view import View
from ..traversal.query_cost import CostModel
from . import calibration, gl_platform
from .depth_import import DepthImport, check_depth, reduce_depth
from .gl_functions import GL, GLFunctions
from .materials import MaterialParts
from .queries import Query, QueryPool
from .query_boxes import QueryBoxes
from .residency import Residency, StreamingSettings
from .resources import GLObjects
from .shaders import NODE_FS, NODE_VS
from .streamed_geometry import StreamedGeometry, node_bytes
from .texture_table import TextureTable

log = logging.getLogger(__name__)

#: The background a frame starts from in an own framebuffer: colour (RGBA) and depth.
CLEAR_COLOUR, CLEAR_DEPTH = (1.0, 1.0, 1.0, 1.0), 1.0


def _gl_matrix(matrix: np.ndarray) -> bytes:
    """(4,4) float64 row-major -> 16 float32 column-major, a mat4 uniform's bytes."""
    return matrix.T.astype(np.float32).tobytes()


class Renderer:
    """Draws HLOD nodes and issues their occlusion queries into the current or an own framebuffer.

    `size`: (width, height) of an own framebuffer (None: draw into the caller's). `overlay`: draw
    nodes in the modulation colour of the ratio P passed to `draw_node`. `time_gpu`: time each
    frame with a GL timer query (False inside a host that may run its own timer queries).
    `images`: material row -> (h, w, 4) uint8 RGBA, top row first, sRGB-encoded (materials.py);
    InputError for an image of another form or a key that is no material row. `streaming`: a GPU
    budget for node geometry and textures (None or an unlimited one: everything uploaded at the
    start). `counted_images`: instead of `images`, images someone else draws for these nodes (the
    preview's gpu batches): the budget counts their textures as this renderer's; none is made."""

    def __init__(self, ctx, hlod: Hlod, *, size: tuple[int, int] | None = None, owns_context: bool = False,
                 time_gpu: bool = True, overlay: bool = False, images: dict[int, np.ndarray] | None = None,
                 streaming: StreamingSettings | None = None, counted_images: dict[int, np.ndarray] | None = None):
        import moderngl

        self._triangles, self._depth_test = moderngl.TRIANGLES, moderngl.DEPTH_TEST
        self.ctx = ctx
        self.hlod = hlod
        self._owns_context = owns_context
        self.time_gpu = time_gpu
        self.overlay = overlay
        self._released = False
        self.gl = GLFunctions(ctx)
        self.queries = QueryPool(self.gl)
        self._gl_objects = GLObjects()
        self.streamed: StreamedGeometry | None = None
        try:
            self._make_gl_objects(ctx, hlod, size=size, images=images, streaming=streaming, counted=counted_images)
        except BaseException:
            self._release_geometry()
            raise
        self._tri_first = (np.asarray(hlod.tri_offset) * 3).astype(np.int64)
        self._tri_vertices = (np.asarray(hlod.tri_count) * 3).astype(np.int64)
        self._ramp = overlay_ramp()
        self._colour = None
        self._mode = None
        self.state_changes = 0  # set_mode's switches so far
        self._timer = None
        self._cost_model: CostModel | None = None
        self._depth_import: DepthImport | None = None
        self._scene_depth: tuple[np.ndarray, int] | None = None  # (depth, reduction), uploaded at begin_frame
        self.depth_import_ms = 0.0  # the last begin_frame's upload and write of the scene depth

    def _make_gl_objects(self, ctx, hlod: Hlod, *, size, images, streaming, counted) -> None:
        """Programs, buffers, the query boxes, the own framebuffer, the appearance and (under a
        budget) the streamed node geometry, in that order."""
        keep = self._gl_objects.keep
        self.node_program = keep(ctx.program(vertex_shader=NODE_VS, fragment_shader=NODE_FS))
        streamed = streaming is not None and not streaming.unlimited
        self.vbo = self.ibo = self.vao = None
        if not streamed:
            self.vbo = keep(ctx.buffer(np.ascontiguousarray(hlod.positions, np.float32).tobytes()))
            self.ibo = keep(ctx.buffer(np.ascontiguousarray(hlod.indices, np.uint32).tobytes()))
            self.vao = keep(ctx.vertex_array(self.node_program, [(self.vbo, "3f", "in_pos")],
                                             index_buffer=self.ibo, index_element_size=4))
        self._u_colour, self._u_mvp, self._u_mv = (self.node_program[u] for u in ("u_colour", "u_mvp", "u_mv"))
        self.boxes = QueryBoxes(ctx, hlod, keep=keep)
        self.query_box_pad = self.boxes.pad  # model units (hierarchy.query_box_pad)
        self.fbo = None
        self._host_fbo = ctx.detect_framebuffer()  # what the caller has bound; refreshed per frame
        if size is not None:
            colour = keep(ctx.renderbuffer(size, components=4))
            depth = keep(ctx.depth_renderbuffer(size))
            self.fbo = keep(ctx.framebuffer(color_attachments=[colour], depth_attachment=depth))
        self.appearance: MaterialParts | None = None
        self.texture_table = TextureTable.none(hlod)  # the textures made (images) or counted (counted_images)
        if hlod.colors is not None or hlod.materials:
            self.texture_table = TextureTable.of(hlod, images or counted,
                                                 max_side=int(ctx.info["GL_MAX_TEXTURE_SIZE"]))
            drawn = self.texture_table if images else TextureTable.none(hlod)
            self.appearance = MaterialParts(ctx, hlod, vbo=self.vbo, ibo=self.ibo, gl=self.gl, textures=drawn,
                                            keep=keep)
        elif images:
            log.warning("%d material images given but the HLOD has no materials: not drawn", len(images))
        if streamed:
            self.streamed = StreamedGeometry(ctx, hlod, node_program=self.node_program, appearance=self.appearance,
                                             textures=self.texture_table, settings=streaming)

    @property
    def residency(self) -> Residency | None:
        """Which nodes' geometry is resident under the GPU budget (None: no budget, all of it)."""
        return None if self.streamed is None else self.streamed.residency

    @property
    def gpu_bytes(self) -> int:
        """GPU bytes of node geometry and textures now: the resident nodes' under a budget, else all of them."""
        if self.streamed is not None:
            return self.streamed.residency.resident_bytes
        look = self.appearance
        geometry = node_bytes(self.hlod, with_uv=look is not None and look.has_uv, with_colour=look is not None
                              and look.has_color)
        return int(geometry.sum() + self.texture_table.texture_bytes.sum())

    @classmethod
    def create_standalone(cls, hlod: Hlod, size: tuple[int, int], *, images: dict[int, np.ndarray] | None = None,
                          streaming: StreamingSettings | None = None) -> "Renderer":
        """A private headless context of the platform's own GL (gl_platform.standalone_context: EGL or
        GLX on Linux, llvmpipe where there is no GPU; WGL on Windows; CGL on macOS) and an own
        framebuffer. GLUnavailable when no context can be made."""
        ctx = gl_platform.standalone_context()
        try:
            return cls(ctx, hlod, size=size, owns_context=True, images=images, streaming=streaming)
        except BaseException:
            ctx.release()
            raise

    @property
    def gl_objects(self) -> tuple:
        """The GL objects this renderer made and has not released, in creation order."""
        return self._gl_objects.objects

    # --- frame ----------------------------------------------------------------------------------

    def begin_frame(self, view: View, *, time_gpu: bool | None = None) -> None:
        """Set matrices (float64 -> float32 with the file origin folded in), bind (and clear an own
        framebuffer), start the GPU timer (`time_gpu` overrides the renderer's setting). A frame
        that raised before its end_frame left its timer running: it is ended and given back first
        (a second glBeginQuery on an active target is GL_INVALID_OPERATION)."""
        if self._timer is not None:
            self.gl.end_query(GL.TIME_ELAPSED)
            self.queries.elapsed_ms(self._timer)  # read: the pool hands out only ids whose result was read
            self.queries.give_back(self._timer, GL.TIME_ELAPSED)
            self._timer = None
        to_origin = np.eye(4)
        to_origin[:3, 3] = self.hlod.origin
        mv = view.view @ to_origin
        mvp_bytes, mv_bytes = _gl_matrix(view.projection @ mv), _gl_matrix(mv)
        self._u_mvp.write(mvp_bytes)
        self.boxes.set_matrix(mvp_bytes)
        self._u_mv.write(mv_bytes)
        self._refresh_host_framebuffer()
        if self.streamed is not None:
            self.streamed.begin_frame()
        if self.fbo is not None:
            self.fbo.use()
        if self.appearance is not None:
            self.appearance.begin_frame(mvp_bytes, mv_bytes, own_framebuffer=self.fbo is not None)
        self.ctx.viewport = (0, 0, view.width, view.height)
        if self.fbo is not None:
            self.clear_framebuffer(self.fbo)
        self.ctx.enable(self._depth_test)
        self.ctx.depth_func = "<="
        self._import_depth(view)
        self._mode = None
        self._colour = None
        if self.time_gpu if time_gpu is None else time_gpu:
            self._timer = self.queries.acquire(GL.TIME_ELAPSED)
            self.gl.begin_query(GL.TIME_ELAPSED, self._timer)

    def set_scene_depth(self, depth: np.ndarray | None, *, reduce: int = 1) -> None:
        """The host's depth (h, w) float32 window depth, row 0 the bottom row (depth_import.py), for
        the next frame's queries and draws to test against: at its begin_frame it is uploaded
        (reduced by the integer factor `reduce`, keeping each block's farthest depth) and blitted
        into the own framebuffer after the clear (InputError there for a renderer without one); `depth_import_ms` is
        then what both cost. It must have the frame's size. Kept for later frames until set again; None: none.
        InputError for another form."""
        if depth is None:
            self._scene_depth = None
            return
        if type(reduce) is not int or reduce < 1:
            raise InputError(f"scene depth: the reduction must be a whole number >= 1, got {reduce!r}")
        self._scene_depth = (check_depth(depth, where="scene depth"), reduce)
        self._depth_uploaded = False

    def _import_depth(self, view: View) -> None:
        """begin_frame's step: upload the scene depth if it is new, and write it (set_scene_depth)."""
        self.depth_import_ms = 0.0
        if self._scene_depth is None:
            return
        started = time.perf_counter()
        depth, reduce = self._scene_depth
        if depth.shape != (view.height, view.width):
            raise InputError(f"scene depth: {depth.shape[1]}x{depth.shape[0]} pixels for a "
                             f"{view.width}x{view.height} frame")
        if self.fbo is None:
            raise InputError("scene depth: only a renderer with its own framebuffer imports a depth image")
        if self._depth_import is None:
            self._depth_import = DepthImport(self.ctx, gl=self.gl)
        if not self._depth_uploaded:
            self._depth_import.upload(reduce_depth(depth, reduce), factor=reduce)
            self._depth_uploaded = True
        self._depth_import.write(self.fbo)
        self.depth_import_ms = (time.perf_counter() - started) * 1e3

    def end_frame(self) -> float:
        """Finish the frame; GPU milliseconds from the timer query (0 if it was not started)."""
        self.set_mode(None)
        if self.appearance is not None:
            self.appearance.end_frame()
        gpu_ms = 0.0
        if self._timer is not None:
            self.gl.end_query(GL.TIME_ELAPSED)
            gpu_ms = self.queries.elapsed_ms(self._timer)
            self.queries.give_back(self._timer, GL.TIME_ELAPSED)
            self._timer = None
        if self.streamed is not None:
            self.streamed.end_frame()  # evictions and this frame's uploads, for the next frames
        self.ctx.finish()
        if self.fbo is not None:
            self._host_fbo.use()  # never leave ours bound: moderngl rebinds its last one later
        return gpu_ms

    def set_mode(self, mode: str | None) -> None:
        """Switch the GL state to 'draw' (and None, the frame's end): colour and depth writes,
        depth test, no culling; 'query' / 'alpha': no writes, back faces culled, depth test on /
        off. Raw GL calls: the state must hold for the very next draw, whatever moderngl has cached."""
        if mode == self._mode:
            return
        self.state_changes += 1
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

    def clear_framebuffer(self, fbo) -> None:
        """Clear `fbo` to the background (CLEAR_COLOUR, CLEAR_DEPTH); the state is set again at
        the next `set_mode` (moderngl's clear puts its own depth mask back)."""
        fbo.clear(*CLEAR_COLOUR, depth=CLEAR_DEPTH)
        self._mode = None

    def forget_mode(self) -> None:
        """Set the state again at the next `set_mode`: for after a call that changes GL state behind
        the renderer (moderngl's framebuffer clear puts its own depth mask back)."""
        self._mode = None

    def set_node_matrices(self, *, mvp: np.ndarray, mv: np.ndarray) -> None:
        """The node program's (4,4) float64 model-view-projection and model-view matrices, for
        positions relative to the file's origin (begin_frame sets them from the frame's view)."""
        self._u_mvp.write(_gl_matrix(mvp))
        self._u_mv.write(_gl_matrix(mv))

    # --- nodes and queries ----------------------------------------------------------------------

    def draw_node(self, node: int, ratio_p: float = 1.0) -> None:
        """Draw a node chosen by a traversal; ratio_p in [0, 1] is the P that steered its LOD (1 for
        none), shown as its modulation colour when `overlay` is on."""
        if self.streamed is not None:
            node = self.streamed.drawable(node)
        if self.overlay:
            step = round(min(1.0, max(0.0, float(ratio_p))) * OVERLAY_RAMP_STEPS)
            self.draw_node_coloured(node, self._ramp[step])
        elif self.appearance is not None:
            self.set_mode("draw")
            if self.streamed is None:
                self.appearance.draw(node, triangles=self._triangles)
            elif self.streamed.parts_vao(node) is not None:
                self.appearance.draw(node, triangles=self._triangles, vao=self.streamed.parts_vao(node),
                                     index_base=self.streamed.index_base(node))
        else:
            self.draw_node_coloured(node, DEFAULT_COLOUR)

    def draw_node_coloured(self, node: int, colour) -> None:
        """Draw a node in `colour`, linear RGB floats (the caller's choice: report figures)."""
        self.set_mode("draw")
        if colour is not self._colour:
            self._u_colour.value = tuple(float(c) for c in colour)
            self._colour = colour
        if self.streamed is None:
            self.vao.render(self._triangles, vertices=int(self._tri_vertices[node]), first=int(self._tri_first[node]))
        else:
            node = self.streamed.drawable(node)
            vao = self.streamed.vao(node)
            if vao is not None:
                vao.render(self._triangles, vertices=int(self._tri_vertices[node]), first=0)

    def issue_query(self, node: int, *, with_alpha: bool) -> Query:
        """Occlusion query of the node's box against the current depth buffer; with_alpha adds
        the depth-test-off query of the same box (the `query` estimator of alpha)."""
        samples_query_id = self.queries.acquire()
        self.set_mode("query")
        self.gl.begin_query(GL.SAMPLES_PASSED, samples_query_id)
        self.boxes.draw_node(node)
        self.gl.end_query(GL.SAMPLES_PASSED)
        alpha_query_id = None
        if with_alpha:
            alpha_query_id = self.queries.acquire()
            self.set_mode("alpha")
            self.gl.begin_query(GL.SAMPLES_PASSED, alpha_query_id)
            self.boxes.draw_node(node)
            self.gl.end_query(GL.SAMPLES_PASSED)
        return Query(node=node, samples_query_id=samples_query_id, alpha_query_id=alpha_query_id)

    def issue_queries(self, nodes, *, with_alpha: bool) -> list[Query]:
        """`issue_query` of each of `nodes`, batched: every q query in the query state, then every
        alpha query in the alpha state (two state changes for the batch instead of two a node).
        The alpha query has the depth test off, so it counts the same pixels wherever it is issued."""
        samples_ids = self._query_each(nodes, "query")
        if not with_alpha:
            return [Query(node=node, samples_query_id=q, alpha_query_id=None) for node, q in zip(nodes, samples_ids)]
        alpha_ids = self._query_each(nodes, "alpha")
        return [Query(node=node, samples_query_id=q, alpha_query_id=a)
                for node, q, a in zip(nodes, samples_ids, alpha_ids)]

    def _query_each(self, nodes, mode: str) -> list[int]:
        """One GL_SAMPLES_PASSED query around each node's box, all in `mode` ("query": depth test
        on, "alpha": off); the query ids in node order."""
        acquire, begin_query, end_query = self.queries.acquire, self.gl.begin_query, self.gl.end_query
        box = self.boxes.draw_node
        ids = [acquire() for _ in nodes]
        self.set_mode(mode)
        for node, query_id in zip(nodes, ids):
            begin_query(GL.SAMPLES_PASSED, query_id)
            box(node)
            end_query(GL.SAMPLES_PASSED)
        return ids

    def issue_multiquery(self, nodes) -> Query:
        """One occlusion query around the boxes of all `nodes` (CHC++'s multiquery): its q is the sum
        of the q each box's own query would give now, so 0 exactly when each would be 0. No alpha."""
        query_id = self.queries.acquire()
        self.set_mode("query")
        self.gl.begin_query(GL.SAMPLES_PASSED, query_id)
        for node in nodes:
            self.boxes.draw_node(node)
        self.gl.end_query(GL.SAMPLES_PASSED)
        members = tuple(nodes)
        return Query(node=members[0], samples_query_id=query_id, alpha_query_id=None, members=members)

    def available(self, query: Query) -> bool:
        """Non-blocking: is the query's result back (see QueryPool.available)?"""
        return self.queries.available(query)

    def result(self, query: Query) -> tuple[int, int | None, float]:
        """(q, alpha or None, stall seconds), blocking if needed (see QueryPool.result)."""
        return self.queries.result(query)

    # --- cost model ------------------------------------------------------------------------------

    @property
    def cost_model(self) -> CostModel:
        """This renderer's fitted query and draw costs (query_cost.CostModel), calibrated on first
        use (`calibrate_costs`) and kept; assign one to use it instead (a scripted model in tests)."""
        if self._cost_model is None:
            self._cost_model = self.calibrate_costs()
        return self._cost_model

    @cost_model.setter
    def cost_model(self, model: CostModel) -> None:
        self._cost_model = model

    @property
    def calibrated(self) -> bool:
        """Whether a cost model is there (calibrated or assigned), without calibrating one."""
        return self._cost_model is not None

    def calibrate_costs(self, *, clock: str | None = None) -> CostModel:
        """Time query boxes and node draws and fit query_cost's linear costs (calibration.py).
        clock: "wall" (default) or "gpu" (calibration.CLOCKS). Call between frames: it uses the own
        framebuffer (or a temporary one), clears it, and leaves the draw state, the host's
        framebuffer and the viewport as a frame's end leaves them. Logs the fit."""
        clock = calibration.check_clock(clock or calibration.CALIBRATION_CLOCK)
        with self._calibration_framebuffer() as fbo:
            model = calibration.calibrate(self, fbo, clock=clock)
        log.info("renderer cost model: %s", model.describe())
        return model

    @contextlib.contextmanager
    def _calibration_framebuffer(self):
        """The own framebuffer, or a temporary one of calibration.CALIBRATION_SIZE, bound with the
        viewport over it; afterwards the caller's framebuffer and viewport are back."""
        saved_viewport = self.ctx.viewport
        # the caller's binding now, restored after (not the one bound when the renderer was made), and
        # made moderngl's record of the bound framebuffer: making a framebuffer rebinds that record,
        # which in a host such as Blender may name a framebuffer since deleted (GL_INVALID_OPERATION)
        self._refresh_host_framebuffer()
        self._host_fbo.use()
        temporary = GLObjects()
        try:
            fbo = self.fbo
            if fbo is None:
                colour = temporary.keep(self.ctx.renderbuffer(calibration.CALIBRATION_SIZE, components=4))
                depth = temporary.keep(self.ctx.depth_renderbuffer(calibration.CALIBRATION_SIZE))
                fbo = temporary.keep(self.ctx.framebuffer(color_attachments=[colour], depth_attachment=depth))
            fbo.use()
            self.ctx.viewport = (0, 0, *fbo.size)
            self.forget_mode()
            yield fbo
        finally:
            self.set_mode(None)
            self._colour = None
            temporary.release()
            self._host_fbo.use()
            self.ctx.viewport = saved_viewport

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
        when the binding has changed. Our own framebuffer bound is no caller's: a frame that raised
        left it bound, and taken for the host's it would stay bound after release (deleted: the
        next renderer's detect_framebuffer() reads a framebuffer that is gone, GL_INVALID_OPERATION)."""
        bound = ctypes.c_int32(0)
        self.gl.get_integerv(GL.DRAW_FRAMEBUFFER_BINDING, ctypes.byref(bound))
        if self._host_fbo.glo != bound.value and (self.fbo is None or self.fbo.glo != bound.value):
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
            self._release_geometry()
        if self._owns_context:
            self.ctx.release()

    def _release_geometry(self) -> None:
        """The streamed nodes' buffers and the depth texture, then every other GL object, newest first."""
        if self.streamed is not None:
            self.streamed.release()
        if getattr(self, "_depth_import", None) is not None:
            self._depth_import.release()
        self._gl_objects.release()
