"""The renderer's GLSL programs: nodes in one colour, nodes in their materials, query boxes.

Data form: GLSL 330 source strings (vertex, fragment) for moderngl's `ctx.program`. Positions are
float32 relative to the HLOD's origin; `u_mvp` / `u_mv` are the frame's matrices with the origin
folded in. Every node program lights a face by the shared flat term (glsl.FLAT_LIGHT).
"""
from __future__ import annotations

from .glsl import FLAT_LIGHT, SRGB_FROM_LINEAR

#: The plain program: every node in one linear RGB colour `u_colour` (written as is, not encoded).
NODE_VS = """
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
NODE_FS = """
#version 330
in vec3 v_view;
uniform vec3 u_colour;
out vec4 f_colour;
""" + FLAT_LIGHT + """
void main() {
    f_colour = vec4(u_colour * flat_light(v_view, vec3(0.0, 0.0, 1.0)), 1.0);
}
"""

#: The appearance program (materials.MaterialParts): colour = base colour x vertex colour x
#: base-colour texture, lit, sRGB-encoded unless the framebuffer encodes itself. HAS_UV / HAS_COLOR
#: are defined when the attribute is uploaded (`parts_sources`).
PARTS_VS = """
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
PARTS_FS = """
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

#: The query box program (query_boxes.QueryBoxes): the unit cube stretched to [u_lo, u_hi].
BOX_VS = """
#version 330
in vec3 in_unit;
uniform vec3 u_lo;
uniform vec3 u_hi;
uniform mat4 u_mvp;
void main() { gl_Position = u_mvp * vec4(mix(u_lo, u_hi, in_unit), 1.0); }
"""
BOX_FS = """
#version 330
out vec4 f_colour;
void main() { f_colour = vec4(1.0); }
"""


def parts_sources(*, has_uv: bool, has_color: bool) -> tuple[str, str]:
    """(vertex, fragment) source of the appearance program for the attributes uploaded."""
    defines = "#version 330\n" + "#define HAS_UV\n" * has_uv + "#define HAS_COLOR\n" * has_color
    return defines + PARTS_VS, defines + PARTS_FS
