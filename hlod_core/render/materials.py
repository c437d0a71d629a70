"""The renderer's appearance path: each node drawn as its parts, each part in its material.

Used only for an HLOD with vertex colours or a material table, and only with the overlay off.
Data form: every node's parts (`Hlod.draw_parts`: one ranged draw per (node, material)) as Python
lists; per material a base colour (linear RGBA, the uniform's bytes) and an optional texture. Extra
vertex buffers beside the positions: UVs (only when some material has an image) and colours (when
the HLOD has them); no material table counts as glTF's default material (NO_MATERIAL_BASE_COLOR).

Images (a texture_table.TextureTable of material row -> (h, w, 4) uint8 RGBA, top row first,
sRGB-encoded) become sRGB8_ALPHA8 textures: one per distinct array object, rows uploaded bottom row
first (UV origin bottom-left), mipmapped, repeat wrap, trilinear; all at the start, or under a GPU
budget each with the first resident node that uses it (streamed_geometry.py). Colour spaces:
docs/how-it-works.md#colours-in-the-renderer-linear-in-srgb-out
"""
from __future__ import annotations

import contextlib

import numpy as np

from ..model.appearance import NO_MATERIAL_BASE_COLOR
from ..model.hierarchy import Hlod
from .gl_functions import GL, GLFunctions
from .gl_state import draw_framebuffer_encodes_srgb, restore_texture_unit, save_texture_unit
from .shaders import parts_sources
from .texture_table import TextureTable

#: (height, width) of the textures `MaterialParts.warm_mipmaps` makes: one power-of-two, one not,
#: each with three mip levels (two levels compiled too few of llvmpipe's blits to spare a 512 x 512).
WARM_SHAPES = ((4, 4), (3, 5))

#: The texture unit the appearance program samples; its previous binding is restored after each frame.
TEXTURE_UNIT = 0


class MaterialParts:
    """The appearance program, its extra vertex buffers and textures, and every node's parts:
    node i draws parts part_first[i] .. part_end[i] - 1; part j is index_count[j] indices from
    index_first[j] in material[j]. Per material m: base[m] (the base-colour uniform's bytes) and
    row_texture[m], its texture's number in `textures` (-1: none), textures[t] the
    moderngl.Texture while it is made; with no material table, row 0 is glTF's default material.
    GL objects go to `keep` (the owner releases them); with `vbo` None (streamed geometry) no
    texture is made here: the owner makes and releases them (make_texture, forget_texture)."""

    def __init__(self, ctx, hlod: Hlod, *, vbo, ibo, gl: GLFunctions, textures: TextureTable, keep):
        self.ctx, self.gl = ctx, gl
        self.table = textures
        self.has_uv = textures.count > 0
        self.has_color = hlod.colors is not None
        vertex_shader, fragment_shader = parts_sources(has_uv=self.has_uv, has_color=self.has_color)
        self.program = keep(ctx.program(vertex_shader=vertex_shader, fragment_shader=fragment_shader))
        self.vao = None  # the whole file's; None when node geometry is streamed (vbo None)
        if vbo is not None:
            content = [(vbo, "3f", "in_pos")]
            for present, values, layout, name in ((self.has_uv, hlod.uvs, "2f", "in_uv"),
                                                  (self.has_color, hlod.colors, "4f", "in_color")):
                if present:
                    data = np.ascontiguousarray(values, np.float32).tobytes()
                    content.append((keep(ctx.buffer(data)), layout, name))
            self.vao = keep(ctx.vertex_array(self.program, content, index_buffer=ibo, index_element_size=4))
        parts = hlod.draw_parts()
        self.part_first = parts.first.tolist()
        self.part_end = (parts.first + parts.count).tolist()
        self.index_first = (parts.tri_offset * 3).tolist()
        self.index_count = (parts.tri_count * 3).tolist()
        self.material = parts.material.tolist()
        bases = [m.base_color for m in hlod.materials] or [NO_MATERIAL_BASE_COLOR]
        self.base = [np.asarray(b, np.float32).tobytes() for b in bases]
        self.row_texture = textures.row_texture.tolist()  # material row (-1: none) -> texture number or -1
        self.textures: list = [None] * textures.count  # texture number -> moderngl.Texture while made
        if vbo is not None:  # the whole file at the start; streamed nodes make theirs (make_texture)
            for number in range(textures.count):
                keep(self.make_texture(number))
        self.u_base = self.program["u_base_color"]
        self.u_encode = self.program["u_encode_srgb"]
        self.u_textured = self.program["u_textured"] if self.has_uv else None
        if self.has_uv:
            self.program["u_texture"].value = TEXTURE_UNIT
        self.host_textures = None  # gl_state.TextureUnit saved at the frame's first bind
        self.reset()

    def reset(self) -> None:
        """Forget the per-frame bindings (start of a frame)."""
        self.current_material = None
        self.textured = None
        self.bound = None

    def begin_frame(self, mvp: bytes, mv: bytes, *, own_framebuffer: bool) -> None:
        """The frame's matrices (16 float32 each, column-major) and whether the shader encodes sRGB."""
        self.program["u_mvp"].write(mvp)
        self.program["u_mv"].write(mv)
        self.u_encode.value = own_framebuffer or not draw_framebuffer_encodes_srgb(self.gl)
        self.reset()

    def end_frame(self) -> None:
        """Give the texture unit back to the host."""
        if self.host_textures is not None:
            restore_texture_unit(self.gl, TEXTURE_UNIT, self.host_textures)
            self.host_textures = None

    def use_material(self, material: int) -> None:
        """Set material row `material`'s uniforms and bind its texture (saving the host's first)."""
        self.u_base.write(self.base[material])
        if self.has_uv:
            number = self.row_texture[material]
            texture = self.textures[number] if number >= 0 else None
            if (texture is not None) is not self.textured:
                self.textured = texture is not None
                self.u_textured.value = self.textured
            if texture is not None and texture is not self.bound:
                if self.host_textures is None:
                    self.host_textures = save_texture_unit(self.gl, TEXTURE_UNIT)
                    self.gl.bind_sampler(TEXTURE_UNIT, 0)  # the texture's own filter and wrap
                texture.use(TEXTURE_UNIT)
                self.bound = texture
        self.current_material = material

    def make_texture(self, number: int):
        """Make texture `number` of the table (the host's binding on the default unit kept) and
        return it; the caller owns it and hands it to `forget_texture` before releasing it."""
        with _default_unit_kept(self.ctx, self.gl):
            texture = gl_texture(self.ctx, self.table.images[number])
        self.textures[number] = texture
        return texture

    def warm_mipmaps(self) -> None:
        """Make and free one small texture of each shape class GL drivers generate mipmaps for with
        their own compiled blit (power-of-two sides, other sides), so that streaming's first texture
        of a class does not stall a frame while the driver compiles it (Mesa's llvmpipe: 0.2 to 0.3 s
        each on first use, docs/performance.md#streaming-under-a-gpu-budget). Nothing without textures."""
        if not self.has_uv:
            return
        with _default_unit_kept(self.ctx, self.gl):
            for height, width in WARM_SHAPES:
                gl_texture(self.ctx, np.zeros((height, width, 4), np.uint8)).release()

    def forget_texture(self, number: int) -> None:
        """Texture `number` is being released: draw its materials in their base colours until made again."""
        if self.bound is self.textures[number]:
            self.bound = None
        self.textures[number] = None

    def draw(self, node: int, *, triangles: int, vao=None, index_base: int = 0) -> None:
        """Draw node `node`'s parts, each in its material (`triangles`: moderngl.TRIANGLES); vao:
        the node's own vertex array whose indices start at the file's index `index_base` (streamed
        geometry), else the whole file's."""
        render = (vao or self.vao).render
        for j in range(self.part_first[node], self.part_end[node]):
            material = self.material[j]
            if material != self.current_material:
                self.use_material(material)
            render(triangles, vertices=self.index_count[j], first=self.index_first[j] - index_base)


def gl_texture(ctx, image: np.ndarray):
    """(h, w, 4) uint8 sRGB RGBA, top row first -> an sRGB8_ALPHA8 texture, bottom row first."""
    height, width = image.shape[:2]
    texture = ctx.texture((width, height), 4, np.ascontiguousarray(image[::-1]), internal_format=GL.SRGB8_ALPHA8)
    texture.repeat_x = texture.repeat_y = True
    texture.build_mipmaps()
    texture.filter = (ctx.LINEAR_MIPMAP_LINEAR, ctx.LINEAR)
    return texture


@contextlib.contextmanager
def _default_unit_kept(ctx, gl: GLFunctions):
    """moderngl binds textures it makes or changes on ctx.default_texture_unit: put back the host's
    binding there and its active unit (Blender caches both)."""
    saved = save_texture_unit(gl, ctx.default_texture_unit)
    try:
        yield
    finally:
        restore_texture_unit(gl, ctx.default_texture_unit, saved)
