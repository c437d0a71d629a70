"""Save and restore the host's GL state around a moderngl pass (docs/how-it-works.md#gl-queries: Blender caches GL state
and does not notice changes made behind its back), and read what the host's framebuffer does.

Data form: `GLState.values`, a dict of plain Python values read with raw GL calls: name -> int
(bindings, depth function, active texture unit), tuple (viewport, scissor box, colour mask) or
bool (depth mask, capability flags); `TextureUnit`, one texture unit's bindings as GL names.
"""
from __future__ import annotations

import ctypes
from typing import NamedTuple

from .gl_functions import GL, GLFunctions

# value name -> the glGetIntegerv parameter that reads it
_INTEGERS = {"draw_fbo": GL.DRAW_FRAMEBUFFER_BINDING, "read_fbo": GL.READ_FRAMEBUFFER_BINDING,
             "program": GL.CURRENT_PROGRAM, "vao": GL.VERTEX_ARRAY_BINDING, "array_buffer": GL.ARRAY_BUFFER_BINDING,
             "depth_func": GL.DEPTH_FUNC, "active_texture": GL.ACTIVE_TEXTURE}
# value name -> capability (glIsEnabled / glEnable / glDisable)
_CAPABILITIES = {"depth_test": GL.DEPTH_TEST, "blend": GL.BLEND, "cull_face": GL.CULL_FACE,
                 "scissor_test": GL.SCISSOR_TEST}


class GLState:
    """Framebuffer bindings, program, vertex array and array buffer, depth and colour write masks,
    depth function, depth test, blend, cull and scissor flags, viewport, scissor box and active
    texture unit: `save()` before a pass, `restore()` after it."""

    def __init__(self, gl: GLFunctions):
        self._gl = gl
        self.values: dict = {}

    def save(self) -> "GLState":
        gl, v = self._gl, {}
        one = ctypes.c_int32(0)
        for name, pname in _INTEGERS.items():
            gl.get_integerv(pname, ctypes.byref(one))
            v[name] = one.value
        four = (ctypes.c_int32 * 4)()
        gl.get_integerv(GL.VIEWPORT, four)
        v["viewport"] = tuple(four)
        gl.get_integerv(GL.SCISSOR_BOX, four)
        v["scissor"] = tuple(four)
        masks = (ctypes.c_uint8 * 4)()
        gl.get_booleanv(GL.COLOR_WRITEMASK, masks)
        v["color_mask"] = tuple(masks)
        gl.get_booleanv(GL.DEPTH_WRITEMASK, masks)
        v["depth_mask"] = masks[0]
        for name, cap in _CAPABILITIES.items():
            v[name] = bool(gl.is_enabled(cap))
        self.values = v
        return self

    def restore(self) -> None:
        gl, v = self._gl, self.values
        gl.bind_framebuffer(GL.DRAW_FRAMEBUFFER, v["draw_fbo"])
        gl.bind_framebuffer(GL.READ_FRAMEBUFFER, v["read_fbo"])
        gl.use_program(v["program"])
        gl.bind_vertex_array(v["vao"])
        gl.bind_buffer(GL.ARRAY_BUFFER, v["array_buffer"])
        gl.depth_func(v["depth_func"])
        gl.active_texture(v["active_texture"])
        gl.viewport(*v["viewport"])
        gl.scissor(*v["scissor"])
        gl.color_mask(*v["color_mask"])
        gl.depth_mask(v["depth_mask"])
        for name, cap in _CAPABILITIES.items():
            (gl.enable if v[name] else gl.disable)(cap)


class TextureUnit(NamedTuple):
    """What `save_texture_unit` read: the active unit (GL_TEXTURE0 + i) and, on the unit saved,
    the bound 2D texture and sampler (GL names, 0 for none)."""

    active: int
    texture: int
    sampler: int


def save_texture_unit(gl: GLFunctions, unit: int) -> TextureUnit:
    """The active texture unit, and texture unit `unit`'s 2D texture and sampler bindings. Leaves
    `unit` active (restore_texture_unit puts the active one back)."""
    value = ctypes.c_int32(0)
    gl.get_integerv(GL.ACTIVE_TEXTURE, ctypes.byref(value))
    active = value.value
    gl.active_texture(GL.TEXTURE0 + unit)
    gl.get_integerv(GL.TEXTURE_BINDING_2D, ctypes.byref(value))
    texture = value.value
    gl.get_integerv(GL.SAMPLER_BINDING, ctypes.byref(value))
    return TextureUnit(active, texture, value.value)


def restore_texture_unit(gl: GLFunctions, unit: int, saved: TextureUnit) -> None:
    """Bind `saved`'s texture and sampler on unit `unit` again and make its active unit active."""
    gl.active_texture(GL.TEXTURE0 + unit)
    gl.bind_texture(GL.TEXTURE_2D, saved.texture)
    gl.bind_sampler(unit, saved.sampler)
    gl.active_texture(saved.active)


def draw_framebuffer_encodes_srgb(gl: GLFunctions) -> bool:
    """Does the bound draw framebuffer convert linear output to sRGB itself (GL_FRAMEBUFFER_SRGB
    on and an sRGB first draw buffer, as Blender's viewport has)?"""
    value = ctypes.c_int32(0)
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
