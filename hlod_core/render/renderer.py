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

Query batches (issue 15, CHC++): `issue_queries` issues several nodes' queries with one switch to
the query state for all q queries and one to the alpha state for all alpha queries (issue_query
switches twice per node); `issue_multiquery` is one q query around the boxes of several nodes.
`state_changes` counts the switches between the draw, query and alpha states (`_set_mode`: masks,
culling, depth test; the program changes with them), since the renderer was made.

Cost model (issue 15): `cost_model` times synthetic query boxes and real node draws in this
renderer's framebuffer once, on first use, and fits query_cost's linear costs (per query and box
pixel, per draw call and triangle); Bool and Coh use it to leave out queries that do not pay.

Colours are decided here: a node is drawn in DEFAULT_COLOUR, or with `overlay` on, in the
modulation ramp's colour (overlay.modulation_colour) of the ratio P the traversal passes,
looked up in a table of the ramp precomputed at OVERLAY_RAMP_STEPS + 1 values of P.

Appearance (issue 13), only for an HLOD with vertex colours or a material table and only with the
overlay off: a second program draws each node as its parts (`Hlod.draw_parts`: one ranged draw per
(node, material)) in colour = material base colour x vertex colour x base-colour texture, lit by
the same flat term. Extra vertex buffers beside the positions: UVs (only when some material has an
image) and colours (when the HLOD has them); no material table counts as glTF's default material
(base colour 1). Base and vertex colours are linear; images (`images`: material index -> (h, w, 4)
uint8 RGBA, top row first, sRGB-encoded) become sRGB8_ALPHA8 textures, so samples are linear, one
texture per distinct array object, rows uploaded bottom row first (UV origin bottom-left), mipmapped,
repeat wrap, trilinear. The result is written sRGB-encoded: by the shader, unless the target
framebuffer encodes itself (GL_FRAMEBUFFER_SRGB on and an sRGB colour attachment, as Blender's
viewport has). The untextured path (DEFAULT_COLOUR, one draw per node) and the overlay are
unchanged: their output is written as it always was.
"""
from __future__ import annotations

import contextlib
import ctypes
import logging
import time

import numpy as np

from ..core.errors import InputError
from .gl_functions import GL, GLFunctions
from ..model.hierarchy import Hlod, query_box_pad
from ..core.colour import OVERLAY_RAMP_STEPS, overlay_ramp
from ..traversal.query_cost import CostModel, fit_linear
from ..model.view import View, look_at, perspective
from .glsl import FLAT_LIGHT, SRGB_FROM_LINEAR
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
""" + FLAT_LIGHT + """
void main() {
    f_colour = vec4(u_colour * flat_light(v_view, vec3(0.0, 0.0, 1.0)), 1.0);
}
"""
# The appearance program; HAS_UV / HAS_COLOR are defined when the attribute is uploaded.
_PARTS_VS = """
in vec3 in_pos;
uniform mat4 u_mvp;
uniform mat4 u_mv;
out vec3 v_view;
#ifdef HAS_UV
in vec2 in_uv;
out vec2 v_uv;
#endif
#ifdef HAS_COLOR
in vec4 in_color;
out vec4 v_color;
#endif
void main() {
    v_view = (u_mv * vec4(in_pos, 1.0)).xyz;
#ifdef HAS_UV
    v_uv = in_uv;
#endif
#ifdef HAS_COLOR
    v_color = in_color;
#endif
    gl_Position = u_mvp * vec4(in_pos, 1.0);
}
"""
_PARTS_FS = """
in vec3 v_view;
#ifdef HAS_UV
in vec2 v_uv;
uniform sampler2D u_texture;  // sRGB8_ALPHA8: samples are linear
uniform bool u_textured;
#endif
#ifdef HAS_COLOR
in vec4 v_color;
#endif
uniform vec4 u_base_color;    // linear RGBA
uniform bool u_encode_srgb;   // false when the framebuffer encodes itself
out vec4 f_colour;
""" + SRGB_FROM_LINEAR + FLAT_LIGHT + """
void main() {
    vec4 colour = u_base_color;
#ifdef HAS_COLOR
    colour *= v_color;
#endif
#ifdef HAS_UV
    if (u_textured) colour *= texture(u_texture, v_uv);
#endif
    vec3 lit = colour.rgb * flat_light(v_view, vec3(0.0, 0.0, 1.0));
    f_colour = vec4(u_encode_srgb ? srgb_from_linear(lit) : lit, 1.0);
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
#: Base colour of parts without a material table: glTF's default material, so vertex colours show as they are.
NO_MATERIAL_BASE_COLOR = (1.0, 1.0, 1.0, 1.0)
#: The texture unit the appearance program samples; its previous binding is restored after each frame.
TEXTURE_UNIT = 0

# Cost calibration (Renderer.cost_model): query boxes as centred squares of these NDC half-sides
# (so their pixel counts span a dot to the whole framebuffer), each size timed as a batch of
# CALIBRATION_QUERIES queries, every sample taken CALIBRATION_ROUNDS times (the median kept);
# node draws of CALIBRATION_DRAW_NODES real nodes of spread triangle counts, each drawn often
# enough to reach about CALIBRATION_DRAW_TRIANGLES triangles (at most CALIBRATION_MAX_REPEATS
# draws), seen from outside the root box. A renderer without an own framebuffer calibrates in a
# temporary one of CALIBRATION_SIZE pixels.
CALIBRATION_BOX_HALF_SIDES = (0.01, 0.1, 0.25, 0.5)
CALIBRATION_QUERIES = 4
CALIBRATION_ROUNDS = 3
CALIBRATION_DRAW_NODES = 4
CALIBRATION_DRAW_TRIANGLES = 4_000
CALIBRATION_MAX_REPEATS = 16
CALIBRATION_SIZE = (256, 256)
#: Distance of the calibration eye from the root box's centre, in root-box diagonals.
CALIBRATION_EYE_DIAGONALS = 1.2
#: The default clock: "wall" (seconds between two glFinish: what a frame pays, the Python and driver
#: work of each call included). llvmpipe's GL_TIME_ELAPSED leaves the rasterisation of draws out
#: (measured: 0-3 us for batches of 10,000 triangles that take 2 ms between two glFinish).
CALIBRATION_CLOCK = "wall"


class _Parts:
    """The appearance program (module docstring), its extra vertex buffers and textures, and every
    node's parts as Python lists: node i draws parts part_first[i] .. part_end[i] - 1; part j is
    index_count[j] indices from index_first[j] in material[j]. Per material m: base[m] (the
    base-colour uniform's bytes) and texture[m] (moderngl.Texture or None); row -1 (the last) is
    the no-material entry when the HLOD has no material table. GL objects go to `keep` (the
    renderer releases them)."""

    def __init__(self, ctx, hlod: Hlod, *, vbo, ibo, gl: GLFunctions, images: dict | None, keep):
        self.gl = gl
        materials = hlod.materials
        textures = self._textures(ctx, hlod, images or {}, keep)
        self.has_uv = any(t is not None for t in textures)
        has_color = hlod.colors is not None
        defines = "#version 330\n" + "#define HAS_UV\n" * self.has_uv + "#define HAS_COLOR\n" * has_color
        self.program = keep(ctx.program(vertex_shader=defines + _PARTS_VS, fragment_shader=defines + _PARTS_FS))
        content = [(vbo, "3f", "in_pos")]
        for present, values, layout, name in ((self.has_uv, hlod.uvs, "2f", "in_uv"),
                                              (has_color, hlod.colors, "4f", "in_color")):
            if present:
                content.append((keep(ctx.buffer(np.ascontiguousarray(values, np.float32).tobytes())), layout, name))
        self.vao = keep(ctx.vertex_array(self.program, content, index_buffer=ibo, index_element_size=4))
        parts = hlod.draw_parts()
        self.part_first = parts.first.tolist()
        self.part_end = (parts.first + parts.count).tolist()
        self.index_first = (parts.tri_offset * 3).tolist()
        self.index_count = (parts.tri_count * 3).tolist()
        self.material = parts.material.tolist()
        bases = [m.base_color for m in materials] or [NO_MATERIAL_BASE_COLOR]
        self.base = [np.asarray(b, np.float32).tobytes() for b in bases]
        self.texture = textures or [None]
        self.u_base = self.program["u_base_color"]
        self.u_encode = self.program["u_encode_srgb"]
        self.u_textured = self.program["u_textured"] if self.has_uv else None
        if self.has_uv:
            self.program["u_texture"].value = TEXTURE_UNIT
        self.host_textures = None  # (active unit, texture, sampler) saved at the frame's first bind
        self.reset()

    def reset(self) -> None:
        """Forget the per-frame bindings (start of a frame)."""
        self.current_material = None
        self.textured = None
        self.bound = None

    def _textures(self, ctx, hlod: Hlod, images: dict, keep) -> list:
        """Per material row: its moderngl.Texture (one per distinct image array) or None."""
        n = len(hlod.materials)
        out = [None] * n
        bad = [k for k in images if not isinstance(k, (int, np.integer)) or not 0 <= k < n]
        if bad:
            raise InputError(f"images: key {bad[0]!r} is not a material row of this HLOD (it has {n} materials)")
        given = {int(k): v for k, v in images.items() if v is not None}
        if not given:
            return out
        if hlod.uvs is None:
            log.warning("%d material images given but the HLOD has no UVs: drawn in base colours", len(given))
            return out
        max_side = int(ctx.info["GL_MAX_TEXTURE_SIZE"])
        made = {}
        with self._default_unit_kept(ctx):
            for index, image in given.items():
                name = hlod.materials[index].name
                if not (isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3
                        and image.shape[2] == 4 and image.shape[0] > 0 and image.shape[1] > 0):
                    got = f"{image.dtype}{list(image.shape)}" if isinstance(image, np.ndarray) else type(image).__name__
                    raise InputError(f"image of material {index} ({name!r}): expected (h, w, 4) uint8 RGBA, got {got}")
                if max(image.shape[:2]) > max_side:
                    log.warning("image of material %d (%r) is %dx%d, larger than this GL's %d: drawn in its base "
                                "colour", index, name, image.shape[1], image.shape[0], max_side)
                    continue
                if id(image) not in made:
                    made[id(image)] = self._texture(ctx, image, keep)
                out[index] = made[id(image)]
        return out

    def _texture(self, ctx, image: np.ndarray, keep):
        """(h, w, 4) uint8 sRGB RGBA, top row first -> an sRGB8_ALPHA8 texture, bottom row first."""
        height, width = image.shape[:2]
        texture = keep(ctx.texture((width, height), 4, np.ascontiguousarray(image[::-1]),
                                   internal_format=GL.SRGB8_ALPHA8))
        texture.repeat_x = texture.repeat_y = True
        texture.build_mipmaps()
        texture.filter = (ctx.LINEAR_MIPMAP_LINEAR, ctx.LINEAR)
        return texture

    @contextlib.contextmanager
    def _default_unit_kept(self, ctx):
        """moderngl binds textures it makes or changes on ctx.default_texture_unit: put back the
        host's binding there and its active unit (Blender caches both)."""
        saved = self._save_unit(ctx.default_texture_unit)
        try:
            yield
        finally:
            self._restore_unit(ctx.default_texture_unit, saved)

    def _save_unit(self, unit: int) -> tuple[int, int, int]:
        gl, value = self.gl, ctypes.c_int32(0)
        gl.get_integerv(GL.ACTIVE_TEXTURE, ctypes.byref(value))
        active = value.value
        gl.active_texture(GL.TEXTURE0 + unit)
        gl.get_integerv(GL.TEXTURE_BINDING_2D, ctypes.byref(value))
        texture = value.value
        gl.get_integerv(GL.SAMPLER_BINDING, ctypes.byref(value))
        return active, texture, value.value

    def _restore_unit(self, unit: int, saved: tuple[int, int, int]) -> None:
        active, texture, sampler = saved
        self.gl.active_texture(GL.TEXTURE0 + unit)
        self.gl.bind_texture(GL.TEXTURE_2D, texture)
        self.gl.bind_sampler(unit, sampler)
        self.gl.active_texture(active)

    def begin_frame(self, mvp: bytes, mv: bytes, *, own_framebuffer: bool) -> None:
        self.program["u_mvp"].write(mvp)
        self.program["u_mv"].write(mv)
        self.u_encode.value = own_framebuffer or not self._target_encodes_srgb()
        self.reset()

    def end_frame(self) -> None:
        """Give the texture unit back to the host."""
        if self.host_textures is not None:
            self._restore_unit(TEXTURE_UNIT, self.host_textures)
            self.host_textures = None

    def _target_encodes_srgb(self) -> bool:
        """Does the bound draw framebuffer convert linear output to sRGB itself (GL_FRAMEBUFFER_SRGB
        on and an sRGB first draw buffer)?"""
        gl, value = self.gl, ctypes.c_int32(0)
        if not gl.is_enabled(GL.FRAMEBUFFER_SRGB):
            return False
        gl.get_integerv(GL.DRAW_BUFFER0, ctypes.byref(value))
        attachment = {GL.BACK: GL.BACK_LEFT, GL.FRONT: GL.FRONT_LEFT}.get(value.value, value.value)
        if attachment == GL.NONE:
            return False
        gl.get_framebuffer_attachment_parameteriv(GL.DRAW_FRAMEBUFFER, attachment,
                                                   GL.FRAMEBUFFER_ATTACHMENT_OBJECT_TYPE, ctypes.byref(value))
        if value.value == GL.NONE:
            return False
        gl.get_framebuffer_attachment_parameteriv(GL.DRAW_FRAMEBUFFER, attachment,
                                                   GL.FRAMEBUFFER_ATTACHMENT_COLOR_ENCODING, ctypes.byref(value))
        return value.value == GL.SRGB

    def use_material(self, material: int) -> None:
        self.u_base.write(self.base[material])
        if self.has_uv:
            texture = self.texture[material]
            if (texture is not None) is not self.textured:
                self.textured = texture is not None
                self.u_textured.value = self.textured
            if texture is not None and texture is not self.bound:
                if self.host_textures is None:
                    self.host_textures = self._save_unit(TEXTURE_UNIT)
                    self.gl.bind_sampler(TEXTURE_UNIT, 0)  # the texture's own filter and wrap
                texture.use(TEXTURE_UNIT)
                self.bound = texture
        self.current_material = material


class Renderer:
    """Draws HLOD nodes and issues their occlusion queries into the current or an own framebuffer.

    `overlay`: draw nodes in the modulation colour of the ratio P the traversal passes to
    `draw_node` (else DEFAULT_COLOUR, or the HLOD's appearance where it has one). `time_gpu`: time
    each frame with a GL timer query (False inside a host that may run its own timer queries).
    `images`: material row -> (h, w, 4) uint8 RGBA, top row first, sRGB-encoded (module docstring);
    materials given the same array object share one texture; a material without one draws in its
    base colour. InputError for an image of another form or a key that is no material row."""

    def __init__(self, ctx, hlod: Hlod, *, size: tuple[int, int] | None = None, owns_context: bool = False,
                 time_gpu: bool = True, overlay: bool = False, images: dict[int, np.ndarray] | None = None):
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
        self._parts = None
        if hlod.colors is not None or hlod.materials:
            self._parts = _Parts(ctx, hlod, vbo=self.vbo, ibo=self.ibo, gl=self.gl, images=images, keep=self._keep)
        elif images:
            log.warning("%d material images given but the HLOD has no materials: not drawn", len(images))
        self._ramp = overlay_ramp()
        self._colour = None
        self._mode = None
        self.state_changes = 0  # _set_mode switches so far (module docstring)
        self._timer = None
        self._cost_model: CostModel | None = None

    @classmethod
    def create_standalone(cls, hlod: Hlod, size: tuple[int, int], *,
                          images: dict[int, np.ndarray] | None = None) -> "Renderer":
        """A private headless EGL context (llvmpipe where there is no GPU) and an own framebuffer."""
        import moderngl

        ctx = moderngl.create_context(standalone=True, backend="egl", require=330)
        try:
            return cls(ctx, hlod, size=size, owns_context=True, images=images)
        except BaseException:
            ctx.release()
            raise

    def _keep(self, resource):
        self._resources.append(resource)
        return resource

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
        mvp = view.projection @ mv
        mvp_bytes, mv_bytes = mvp.T.astype(np.float32).tobytes(), mv.T.astype(np.float32).tobytes()
        for program in (self.node_program, self.box_program):
            program["u_mvp"].write(mvp_bytes)
        self.node_program["u_mv"].write(mv_bytes)
        self._refresh_host_framebuffer()
        if self.fbo is not None:
            self.fbo.use()
        if self._parts is not None:
            self._parts.begin_frame(mvp_bytes, mv_bytes, own_framebuffer=self.fbo is not None)
        self.ctx.viewport = (0, 0, view.width, view.height)
        if self.fbo is not None:
            self.fbo.clear(1.0, 1.0, 1.0, 1.0, depth=1.0)
        self.ctx.enable(self._mgl.DEPTH_TEST)
        self.ctx.depth_func = "<="
        self._mode = None
        self._colour = None
        self._timer = None
        if self.time_gpu if time_gpu is None else time_gpu:
            self._timer = self.queries.acquire(GL.TIME_ELAPSED)
            self.gl.begin_query(GL.TIME_ELAPSED, self._timer)

    def end_frame(self) -> float:
        """Finish the frame; GPU milliseconds from the timer query (0 if it was not started)."""
        self._set_mode(None)
        if self._parts is not None:
            self._parts.end_frame()
        gpu_ms = 0.0
        if self._timer is not None:
            self.gl.end_query(GL.TIME_ELAPSED)
            gpu_ms = self.queries.elapsed_ms(self._timer)
            self.queries.give_back(self._timer, GL.TIME_ELAPSED)
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

    # --- nodes and queries ----------------------------------------------------------------------

    def draw_node(self, node: int, ratio_p: float = 1.0) -> None:
        """Draw a node chosen by a traversal; ratio_p in [0, 1] is the P that steered its LOD (1 for
        none), shown as its modulation colour when `overlay` is on."""
        if self.overlay:
            step = round(min(1.0, max(0.0, float(ratio_p))) * OVERLAY_RAMP_STEPS)
            self.draw_node_coloured(node, self._ramp[step])
        elif self._parts is not None:
            self._draw_parts(node)
        else:
            self.draw_node_coloured(node, DEFAULT_COLOUR)

    def _draw_parts(self, node: int) -> None:
        """The node's parts, each in its material (module docstring)."""
        self._set_mode("draw")
        parts, render, triangles = self._parts, self._parts.vao.render, self._mgl.TRIANGLES
        for j in range(parts.part_first[node], parts.part_end[node]):
            material = parts.material[j]
            if material != parts.current_material:
                parts.use_material(material)
            render(triangles, vertices=parts.index_count[j], first=parts.index_first[j])

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

    def issue_queries(self, nodes, *, with_alpha: bool) -> list[Query]:
        """`issue_query` of each of `nodes`, batched: every q query in the query state, then every
        alpha query in the alpha state (two state changes for the batch instead of two a node).
        The alpha query has the depth test off, so it counts the same pixels wherever it is issued."""
        samples_ids = self._query_each(nodes, "query")
        if not with_alpha:
            return [Query(node=node, samples_query_id=q, alpha_query_id=None) for node, q in zip(nodes, samples_ids)]
        alpha_ids = self._query_each(nodes, "alpha")
        return [Query(node=node, samples_query_id=q, alpha_query_id=a) for node, q, a in zip(nodes, samples_ids, alpha_ids)]

    def _query_each(self, nodes, mode: str) -> list[int]:
        """One GL_SAMPLES_PASSED query around each node's box, all in `mode` ("query": depth test
        on, "alpha": off); the query ids in node order."""
        acquire, begin_query, end_query, box = self.queries.acquire, self.gl.begin_query, self.gl.end_query, self._box
        ids = [acquire() for _ in nodes]
        self._set_mode(mode)
        for node, query_id in zip(nodes, ids):
            begin_query(GL.SAMPLES_PASSED, query_id)
            box(node)
            end_query(GL.SAMPLES_PASSED)
        return ids

    def issue_multiquery(self, nodes) -> Query:
        """One occlusion query around the boxes of all `nodes` (CHC++'s multiquery): its q is the sum
        of the q each box's own query would give now, so 0 exactly when each would be 0. No alpha."""
        query_id = self.queries.acquire()
        self._set_mode("query")
        self.gl.begin_query(GL.SAMPLES_PASSED, query_id)
        for node in nodes:
            self._box(node)
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
        use and kept (`calibrate_costs`)."""
        if self._cost_model is None:
            self._cost_model = self.calibrate_costs()
        return self._cost_model

    def calibrate_costs(self, *, clock: str | None = None) -> CostModel:
        """Time synthetic work and fit query_cost's linear models: query boxes of a few sizes
        (module constants), issued as the traversal issues them, and real nodes of the HLOD drawn as
        the traversal draws them. clock "wall" (default, CALIBRATION_CLOCK) times between two
        glFinish, "gpu" with GL_TIME_ELAPSED (not inside a host whose own timer query may be running). Call between
        frames: it uses the own framebuffer (or a temporary one), clears it, and leaves the draw
        state, the host's framebuffer and the viewport as a frame's end leaves them. Logs the fit."""
        clock = clock or CALIBRATION_CLOCK
        if clock not in ("gpu", "wall"):
            raise InputError(f"clock must be 'gpu' or 'wall', got {clock!r}")
        saved_viewport = self.ctx.viewport
        # the caller's binding now, restored after (not the one bound when the renderer was made), and
        # made moderngl's record of the bound framebuffer: making a framebuffer rebinds that record,
        # which in a host such as Blender may name a framebuffer since deleted (GL_INVALID_OPERATION)
        self._refresh_host_framebuffer()
        self._host_fbo.use()
        fbo = self.fbo
        if fbo is None:
            colour = self.ctx.renderbuffer(CALIBRATION_SIZE, components=4)
            depth = self.ctx.depth_renderbuffer(CALIBRATION_SIZE)
            fbo = self.ctx.framebuffer(color_attachments=[colour], depth_attachment=depth)
        try:
            fbo.use()
            self.ctx.viewport = (0, 0, *fbo.size)
            self._mode = None
            queries = self._time_queries(fbo, clock)
            draws = self._time_draws(fbo, clock)
        finally:
            self._set_mode(None)
            self._colour = None
            if fbo is not self.fbo:
                for resource in (fbo, colour, depth):
                    resource.release()
            self._host_fbo.use()
            self.ctx.viewport = saved_viewport
        model = CostModel(query=fit_linear(*queries), draw=fit_linear(*draws), clock=clock)
        log.info("renderer cost model: %s", model.describe())
        return model

    def _timed(self, clock: str, work) -> float:
        """Seconds `work()` takes on `clock`."""
        if clock == "gpu":
            timer = self.queries.acquire(GL.TIME_ELAPSED)
            self.gl.begin_query(GL.TIME_ELAPSED, timer)
            work()
            self.gl.end_query(GL.TIME_ELAPSED)
            seconds = self.queries.elapsed_ms(timer) / 1e3
            self.queries.give_back(timer, GL.TIME_ELAPSED)
            return seconds
        self.ctx.finish()
        started = time.perf_counter()
        work()
        self.ctx.finish()
        return time.perf_counter() - started

    def _time_queries(self, fbo, clock: str) -> tuple[list, list, list]:
        """(queries, pixels, seconds) per sample: CALIBRATION_QUERIES boxes of one size, each in its
        own occlusion query with the depth test on against a cleared depth buffer (every pixel
        passes: the pixels counted are the pixels rasterised), results read as the traversal reads."""
        self.box_program["u_mvp"].write(np.eye(4, dtype=np.float32).tobytes())
        counts, pixels, seconds = [], [], []
        for half in CALIBRATION_BOX_HALF_SIDES:
            self._u_lo.value, self._u_hi.value = (-half, -half, -0.5), (half, half, 0.5)
            rounds, covered = [], 0
            for _ in range(CALIBRATION_ROUNDS):
                fbo.clear(1.0, 1.0, 1.0, 1.0, depth=1.0)
                self._mode = None  # moderngl's clear puts its own depth mask back: set the query state again
                issued = []

                def work():
                    self._set_mode("query")
                    for _ in range(CALIBRATION_QUERIES):
                        query_id = self.queries.acquire()
                        self.gl.begin_query(GL.SAMPLES_PASSED, query_id)
                        self.cube_vao.render(self._mgl.TRIANGLES)
                        self.gl.end_query(GL.SAMPLES_PASSED)
                        issued.append(query_id)
                    covered_now = 0
                    for query_id in issued:
                        covered_now += self.queries.result(Query(-1, query_id, None))[0]
                    issued.clear()
                    issued.append(covered_now)

                rounds.append(self._timed(clock, work))
                covered = issued[0]
            counts.append(CALIBRATION_QUERIES)
            pixels.append(covered)
            seconds.append(float(np.median(rounds)))
        return counts, pixels, seconds

    def _time_draws(self, fbo, clock: str) -> tuple[list, list, list]:
        """(draw calls, triangles, seconds) per sample: one real node drawn repeatedly, seen from
        outside the root box, for nodes of spread triangle counts."""
        h = self.hlod
        lo, hi = h.box_min[0] - h.origin, h.box_max[0] - h.origin
        centre, diagonal = 0.5 * (lo + hi), max(float(np.linalg.norm(hi - lo)), 1e-30)
        eye = centre + CALIBRATION_EYE_DIAGONALS * diagonal * np.array([0.6, -0.7, 0.4])
        width, height = fbo.size
        mv = look_at(eye, centre, [0.0, 0.0, 1.0])
        mvp = perspective(60.0, width / height, 0.05 * diagonal, 4.0 * diagonal) @ mv
        self.node_program["u_mvp"].write(mvp.T.astype(np.float32).tobytes())
        self.node_program["u_mv"].write(mv.T.astype(np.float32).tobytes())
        tris = np.asarray(h.tri_count, np.int64)
        drawable = np.flatnonzero(tris > 0)
        if drawable.size == 0:
            raise InputError("the HLOD has no triangles: no draw cost to calibrate")
        by_count = drawable[np.argsort(tris[drawable], kind="stable")]
        picks = np.unique(by_count[np.linspace(0, by_count.size - 1, CALIBRATION_DRAW_NODES).round().astype(int)])
        calls, triangles, seconds = [], [], []
        for divisor in (2, 1):  # each node at two repeat counts
            for node in picks.tolist():
                full = int(np.clip(CALIBRATION_DRAW_TRIANGLES // int(tris[node]), 1, CALIBRATION_MAX_REPEATS))
                repeats = max(1, full // divisor)
                rounds = []
                for _ in range(CALIBRATION_ROUNDS):
                    fbo.clear(1.0, 1.0, 1.0, 1.0, depth=1.0)
                    self._mode = None

                    def work():
                        for _ in range(repeats):
                            self.draw_node_coloured(node, DEFAULT_COLOUR)

                    rounds.append(self._timed(clock, work))
                calls.append(repeats)
                triangles.append(repeats * int(tris[node]))
                seconds.append(float(np.median(rounds)))
        return calls, triangles, seconds

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
