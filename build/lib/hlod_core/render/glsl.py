"""GLSL snippets shared by every shader that draws nodes: the moderngl renderer's programs
(hlod_core.render.shaders) and the Blender preview's `gpu` shaders (addon/), so the two paths
light and encode colours with the same code.

Data form: source strings to paste into a fragment shader before its `main`.
"""

#: `vec3 srgb_from_linear(vec3 c)`: IEC 61966-2-1 encoding of linear values (clamped to [0, 1]);
#: the numpy counterpart is hlod_core.core.colour.srgb_from_linear.
SRGB_FROM_LINEAR = """
vec3 srgb_from_linear(vec3 c) {  // IEC 61966-2-1
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(0.0031308, c));
}
"""

#: `float flat_light(vec3 p, vec3 axis)`: the flat lighting term 0.25 + 0.75 |n . axis| of the face
#: through point p, with n the face normal from the screen-space derivatives of p (no vertex normals
#: needed) and axis the view's z axis in p's space (vec3(0, 0, 1) for view-space positions).
FLAT_LIGHT = """
float flat_light(vec3 p, vec3 axis) {
    vec3 n = normalize(cross(dFdx(p), dFdy(p)));
    return 0.25 + 0.75 * abs(dot(n, axis));
}
"""
