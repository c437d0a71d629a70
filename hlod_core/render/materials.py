"""The renderer's appearance path: each node drawn as its parts, each part in its material.

Used only for an HLOD with vertex colours or a material table, and only with the overlay off.
Data form: every node's parts (`Hlod.draw_parts`: one ranged draw per (node, material)) as Python
lists; per material a base colour (linear RGBA, the uniform's bytes) and an optional texture. Extra
vertex buffers beside the positions: UVs (only when some material has an image) and colours (when
the HLOD has them); no material table counts as glTF's default material (NO_MATERIAL_BASE_COLOR).

Images (`images`: material row -> (h, w, 4) uint8 RGBA, top row first, sRGB-encoded) become
sRGB8_ALPHA8 textures: one per distinct array object, rows uploaded bottom row first (UV origin
bottom-left), mipmapped, repeat wrap, trilinear. Colour spaces:
docs/how-it-works.md#colours-in-the-renderer-linear-in-srgb-out
"""
from __future__ import annotations

import contextlib
import logging

import numpy as np

from ..core.errors import InputError
from ..model.appearance import NO_MATERIAL_BASE_COLOR
from ..model.hierarchy import Hlod
from .gl_functions import GL, GLFunctions
from .gl_state import draw_framebuffer_encodes_srgb, restore_texture_unit, save_texture_unit
from .shaders import parts_sources

log = logging.getLogger(__name__)

#: The texture unit the appearance program samples; its previous binding is restored after each frame.
TEXTURE_UNIT = 0


class MaterialParts:
    """The appearance program, its extra vertex buffers and textures, and every node's parts:
    node i draws parts part_first[i] .. part_end[i] - 1; part j is index_count[j] indices from
    index_first[j] in material[j]. Per material m: base[m] (the base-colour uniform's bytes) and
    texture[m] (moderngl.Texture or None); with no material table, row 0 is glTF's default
    material. GL objects go to `keep` (the owner releases them)."""

    def __init__(self, ctx, hlod: Hlod, *, vbo, ibo, gl: GLFunctions, images: dict | None, keep):
        self.gl = gl
        textures = _textures(ctx, hlod, images=images or {}, gl=gl, keep=keep)
        self.has_uv = any(t is not None for t in textures)
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
        self.texture = textures or [None]
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
            texture = self.texture[material]
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


def _textures(ctx, hlod: Hlod, *, images: dict, gl: GLFunctions, keep) -> list:
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
    with _default_unit_kept(ctx, gl):
        for index, image in given.items():
            name = hlod.materials[index].name
            _check_image(index, name, image)
            if max(image.shape[:2]) > max_side:
                log.warning("image of material %d (%r) is %dx%d, larger than this GL's %d: drawn in its base "
                            "colour", index, name, image.shape[1], image.shape[0], max_side)
                continue
            if id(image) not in made:
                made[id(image)] = _texture(ctx, image, keep=keep)
            out[index] = made[id(image)]
    return out


def _check_image(index: int, name: str, image) -> None:
    """InputError unless `image` is (h, w, 4) uint8 with h, w > 0."""
    if not (isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3
            and image.shape[2] == 4 and image.shape[0] > 0 and image.shape[1] > 0):
        got = f"{image.dtype}{list(image.shape)}" if isinstance(image, np.ndarray) else type(image).__name__
        raise InputError(f"image of material {index} ({name!r}): expected (h, w, 4) uint8 RGBA, got {got}")


def _texture(ctx, image: np.ndarray, *, keep):
    """(h, w, 4) uint8 sRGB RGBA, top row first -> an sRGB8_ALPHA8 texture, bottom row first."""
    height, width = image.shape[:2]
    texture = keep(ctx.texture((width, height), 4, np.ascontiguousarray(image[::-1]),
                               internal_format=GL.SRGB8_ALPHA8))
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
