"""HLOD nodes drawn with Blender's gpu module (the private-context and CPU modes): per node, one
batch in one colour (the modulation overlay, or the default grey), or one batch per material in
base colour x vertex colour x texture, both lit as the renderer lights, so that these modes draw
what the Blender-context mode's renderer draws. Positions are float32, relative to the HLOD's
origin: the caller translates by it.
"""
from __future__ import annotations

import bpy
import numpy as np

from ...hlod_core.core.colour import DEFAULT_COLOUR
from ...hlod_core.model.appearance import NO_MATERIAL_BASE_COLOR
from ...hlod_core.model.hierarchy import Hlod, node_geometry
from ...hlod_core.render.glsl import FLAT_LIGHT, SRGB_FROM_LINEAR
from ..materials.images import WRITTEN_TEXTURE_KEY

# The one-colour shader: u_colour lit by the renderer's flat term (shaders.NODE_FS), the colour
# written as the renderer writes it (and Blender's UNIFORM_COLOR shader), as is into a framebuffer
# that does not encode, decoded from sRGB into one that encodes (srgbTarget), which encodes it back.
_FLAT_VS = """
void main() {
    v_pos = pos;
    gl_Position = ModelViewProjectionMatrix * vec4(pos, 1.0);
}
"""
_FLAT_FS = FLAT_LIGHT + """
vec3 linear_from_srgb(vec3 c) {  // IEC 61966-2-1 decoding
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(0.04045, c));
}
void main() {
    vec3 lit = clamp(u_colour.rgb * flat_light(v_pos, u_view_z), 0.0, 1.0);
    FragColor = vec4(srgbTarget ? linear_from_srgb(lit) : lit, 1.0);
}
"""

# The appearance shader: colour = base colour x vertex colour (per vertex, linear) x the material's
# texture (a white texel without one), lit by the renderer's flat term 0.25 + 0.75 |n_z| (n in view
# space: the face normal in world space dotted with the view's z axis), written sRGB-encoded unless
# the framebuffer encodes itself (srgbTarget: set by Blender for every shader that declares it).
_LOOK_VS = """
void main() {
    v_pos = pos;
    v_color = color;
    v_uv = uv;
    gl_Position = ModelViewProjectionMatrix * vec4(pos, 1.0);
}
"""
_LOOK_FS = SRGB_FROM_LINEAR + FLAT_LIGHT + """
void main() {
    vec3 lit = (v_color * texture(u_image, v_uv)).rgb * flat_light(v_pos, u_view_z);
    FragColor = vec4(srgbTarget ? lit : srgb_from_linear(lit), 1.0);
}
"""


class NodeBatches:
    """The gpu module objects of one preview, made in Blender's context at first use and kept: the
    nodes' batches, the appearance shader with its white 1x1 texture and the materials' textures
    (each made when a node drawn with it is first drawn). `images`: material row -> (h, w, 4)
    uint8, the rows whose bpy image becomes a texture. release() drops them all (Blender frees
    their GPU objects then: its context must be current)."""

    def __init__(self, hlod: Hlod, *, images: dict[int, np.ndarray]):
        self.hlod = hlod
        self.images = images
        self._flat: dict[int, object] = {}  # node -> batch (the one-colour shader)
        self._flat_shader = None
        self._looks: dict[int, list] = {}  # node -> [(material row or -1, batch)]
        self._look = None  # (shader, white texture)
        self._textures: dict[int, object] = {}  # material row -> gpu texture of its bpy image

    @property
    def empty(self) -> bool:
        return (not self._flat and self._flat_shader is None and not self._looks and self._look is None
                and not self._textures)

    def draw_flat(self, nodes, colours: np.ndarray | None, view_z: tuple[float, float, float]) -> None:
        """`nodes` in one colour each, lit: colours (n, 3) float RGB as the renderer takes them, or
        None for DEFAULT_COLOUR; view_z: the view matrix's third row (x, y, z), as draw_looks."""
        if self._flat_shader is None:
            self._flat_shader = _flat_shader()
        shader = self._flat_shader
        shader.bind()
        shader.uniform_float("u_view_z", view_z)
        for i, node in enumerate(nodes):
            batch = self._flat.get(node) or self._flat.setdefault(node, _flat_batch(shader, self.hlod, node))
            colour = tuple(float(c) for c in colours[i]) if colours is not None else DEFAULT_COLOUR
            shader.uniform_float("u_colour", (*colour, 1.0))
            batch.draw(shader)

    def draw_looks(self, nodes, view_z: tuple[float, float, float]) -> None:
        """`nodes` in their materials, vertex colours and textures; view_z: the view matrix's third
        row (x, y, z), the view's z axis in world space (the flat lighting term)."""
        if self._look is None:
            self._look = _look_shader()
        shader, white = self._look
        shader.bind()
        shader.uniform_float("u_view_z", view_z)
        for node in nodes:
            node = int(node)
            if node not in self._looks:
                self._looks[node] = _look_batches(shader, self.hlod, node)
            for material, batch in self._looks[node]:
                shader.uniform_sampler("u_image", self._texture(material) or white)
                batch.draw(shader)

    def _texture(self, row: int):
        """The gpu texture of material row `row`'s bpy image (None for a row `images` does not hold)."""
        if row not in self._textures and row in self.images:
            import gpu

            self._textures[row] = gpu.texture.from_image(bpy.data.images[self.hlod.materials[row].image])
        return self._textures.get(row)

    def keep_only(self, resident: np.ndarray, rows_resident: np.ndarray) -> None:
        """Drop the batches of nodes not `resident` ((n,) bool) and the textures of material rows
        not `rows_resident` ((m,) bool): what the GPU budget's bookkeeping no longer holds. An image
        the bake wrote (a proxy's, loaded by the preview) is freed from the GPU at once; Blender
        keeps a scene image's texture while it draws it elsewhere, and frees it on its time-out."""
        for cache in (self._flat, self._looks):
            for node in [node for node in cache if not resident[node]]:
                del cache[node]
        dropped = [row for row in self._textures if not rows_resident[row]]
        for row in dropped:
            del self._textures[row]
        names = {self.hlod.materials[row].image for row in self._textures}
        for name in {self.hlod.materials[row].image for row in dropped} - names:
            image = bpy.data.images.get(name)
            if image is not None and WRITTEN_TEXTURE_KEY in image:
                image.gl_free()

    def release(self) -> None:
        """Drop every gpu object, the latest made first. Idempotent. Blender's builtin shader is
        bound first when one of ours was made: with OpenGL a program deleted while it is in use
        lives on until another is used (glDeleteProgram), and Blender leaves the last shader drawn
        with in use (gpu.shader.unbind() changes nothing in release builds)."""
        if self._flat_shader is not None or self._look is not None:
            import gpu

            gpu.shader.from_builtin("UNIFORM_COLOR").bind()
        self._looks.clear()
        self._textures.clear()
        self._look = None
        self._flat.clear()
        self._flat_shader = None


def _flat_batch(shader, hlod: Hlod, node: int):
    from gpu_extras.batch import batch_for_shader

    geometry = node_geometry(hlod, node)
    return batch_for_shader(shader, "TRIS", {"pos": geometry.positions}, indices=geometry.faces.astype(np.int32))


def _flat_shader():
    """The one-colour shader (the notes above)."""
    import gpu

    info = gpu.types.GPUShaderCreateInfo()
    info.push_constant("MAT4", "ModelViewProjectionMatrix")
    info.push_constant("VEC3", "u_view_z")
    info.push_constant("VEC4", "u_colour")
    info.push_constant("BOOL", "srgbTarget")
    info.vertex_in(0, "VEC3", "pos")
    varyings = gpu.types.GPUStageInterfaceInfo("hlod_flat")
    varyings.smooth("VEC3", "v_pos")
    info.vertex_out(varyings)
    info.fragment_out(0, "VEC4", "FragColor")
    info.vertex_source(_FLAT_VS)
    info.fragment_source(_FLAT_FS)
    return gpu.shader.create_from_info(info)


def _look_shader():
    """(shader, white 1x1 texture) of the appearance drawing (the notes above)."""
    import gpu

    info = gpu.types.GPUShaderCreateInfo()
    info.push_constant("MAT4", "ModelViewProjectionMatrix")
    info.push_constant("VEC3", "u_view_z")
    info.push_constant("BOOL", "srgbTarget")
    info.sampler(0, "FLOAT_2D", "u_image")
    for slot, (kind, name) in enumerate((("VEC3", "pos"), ("VEC4", "color"), ("VEC2", "uv"))):
        info.vertex_in(slot, kind, name)
    varyings = gpu.types.GPUStageInterfaceInfo("hlod_look")
    for kind, name in (("VEC3", "v_pos"), ("VEC4", "v_color"), ("VEC2", "v_uv")):
        varyings.smooth(kind, name)
    info.vertex_out(varyings)
    info.fragment_out(0, "VEC4", "FragColor")
    info.vertex_source(_LOOK_VS)
    info.fragment_source(_LOOK_FS)
    white = gpu.types.GPUTexture((1, 1), format="RGBA8", data=gpu.types.Buffer("FLOAT", 4, [1.0, 1.0, 1.0, 1.0]))
    return gpu.shader.create_from_info(info), white


def _look_batches(shader, hlod: Hlod, node: int) -> list:
    """[(material row or -1, batch)] of one node: its triangles per material, each vertex coloured
    base colour x vertex colour (linear), with its UVs (0 without)."""
    from gpu_extras.batch import batch_for_shader

    g = node_geometry(hlod, node)
    face_material = g.face_material if g.face_material is not None else np.full(g.faces.shape[0], -1, np.int32)
    bases = np.array([m.base_color for m in hlod.materials] + [NO_MATERIAL_BASE_COLOR], np.float32)  # row -1: none
    out = []
    for material in np.unique(face_material).tolist():
        used, faces = np.unique(g.faces[face_material == material], return_inverse=True)
        colour = np.broadcast_to(bases[material], (used.size, 4))
        if g.colors is not None:
            colour = colour * g.colors[used]
        uvs = g.uvs[used] if g.uvs is not None else np.zeros((used.size, 2), np.float32)
        content = {"pos": g.positions[used], "color": np.ascontiguousarray(colour, np.float32), "uv": uvs}
        out.append((material, batch_for_shader(shader, "TRIS", content, indices=faces.reshape(-1, 3).astype(np.int32))))
    return out
