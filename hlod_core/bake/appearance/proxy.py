"""A proxy material for one inner node (docs/how-it-works.md#proxy-materials-for-the-inner-nodes):
an atlas over its LOD (atlas.py) and one base-colour texture baked from what its sources show,
with a texel of about the node's error over tau.

Data form: the node's LOD (positions (k,3) float32 model units, faces (m,3) int32, normals (k,3)
float32 or None); its sources, the children's LODs with their attribute rows (appearance.pack's
[material, u, v, r, g, b, a], the columns of the bake's AttributeLayout); `SourceLooks`, what a
material id in those rows shows (the scene's materials, and the children's own proxies). Out,
`Proxy`: the LOD split along its charts, with rows [proxy material, atlas u, v, white], and its
texture as (h,w,4) uint8 sRGB RGBA, top row first (as io.textures gives images).

A proxy's material ids in the bake's rows are `proxy_material_id(node, alpha)`: past every scene
material, so they never clash; assemble renumbers them into the file's material table.
Texel size: a node first shows when its error projects to tau pixels, where a texel of
error / tau model units is about one pixel; no finer than the detail its sources hold
(`source_texel_size`). docs/how-it-works.md#proxy-materials-for-the-inner-nodes
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.colour import srgb_from_linear
from ...model.appearance import AttributeLayout, Material
from .atlas import Atlas, node_atlas, surface_area, texture_side
from .quality import DIRECTIONS, node_psnr
from .surface_colour import MipChain, Surface, colour_at, texture_texels_per_unit
from .texels import closest_facing, fill_empty, footprint_samples, texel_samples

#: Alpha (of 1) at or above which a texel is opaque: a face all of whose texels are goes in the
#: proxy's opaque part, the others in its alpha-tested part.
OPAQUE_ALPHA = 1.0 - 0.5 / 255.0
#: A proxy material's base colour: its texture holds every colour.
WHITE = (1.0, 1.0, 1.0, 1.0)
#: Texels a source face without a texture stands for (source_texel_size): its colour is a blend of
#: its corners', which a couple of texels hold.
UNTEXTURED_FACE_TEXELS = 2.0
#: The quality gate's views in the bake: the 6 axis directions (quality.DIRECTIONS' first 6), at
#: 0.4x the cost of all 14; on the tests' spheres the PSNR-Y moved by about 1 dB.
GATE_DIRECTIONS = DIRECTIONS[:6]
#: Packing efficiency assumed before the atlas is packed (xatlas packs 0.65 to 0.76 of the image on
#: the bakes measured in docs/performance.md); the texel size itself is what the pack is asked for.
EXPECTED_PACKING = 0.7
#: How far (x the node's error, at least one texel) a texel looks for a source face facing its way
#: before it takes the nearest point of all (texels.closest_facing): the LOD lies within about its
#: error of its sources, the children's LODs within theirs of the leaves.
FACING_REACH_ERRORS = 3.0


@dataclass(frozen=True)
class ProxySettings:
    """enabled: inner nodes get proxy materials where their sources need it (False: every level keeps
    the source materials); texture_cap, texture_floor: the longest side of a proxy texture is kept
    within [floor, cap] texels; tau_px: the screen-space error, pixels, the texel size is chosen for
    (a texel of error / tau_px model units)."""

    enabled: bool = True
    texture_cap: int = 1024
    texture_floor: int = 16
    tau_px: float = 1.0


def proxy_material_id(node: int, alpha: bool, *, scene_materials: int) -> int:
    """The material id a proxy's rows carry in the bake: scene_materials + 2 node (+1: its
    alpha-tested part). Exact in the rows' float32 below 2**24."""
    return scene_materials + 2 * int(node) + int(alpha)


def proxy_of_id(material_id: np.ndarray, *, scene_materials: int) -> tuple[np.ndarray, np.ndarray]:
    """(node (s,) int64, alpha (s,) bool) of proxy material ids (proxy_material_id's inverse)."""
    offset = np.asarray(material_id, np.int64) - scene_materials
    return offset // 2, (offset % 2).astype(bool)


@dataclass(frozen=True, eq=False)
class SourceLooks:
    """What each material id of a node's source rows shows: materials, id -> appearance.Material
    (a scene material; a child proxy's is white with its alpha mode); chains, id -> MipChain of its
    texture (absent: base colour only)."""

    materials: dict
    chains: dict


@dataclass(frozen=True, eq=False)
class Proxy:
    """The node's LOD split along its atlas charts (positions (j,3) f32, faces (m,3) int32,
    normals (j,3) f32 or None, rows (j,A) f32 with the proxy material ids), its texture image
    (h,w,4) uint8 sRGB RGBA, top row first, texel_size (model units), the atlas's utilization, and
    alpha: whether some faces are in the alpha-tested part (and its alpha mode, "MASK" or "BLEND")."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    rows: np.ndarray
    image: np.ndarray
    texel_size: float
    utilization: float
    alpha_mode: str | None
    psnr_y: float = float("nan")
    psnr_reason: str | None = None


def source_surface(sources: list[tuple], layout: AttributeLayout, looks: SourceLooks) -> Surface:
    """The children's LODs (positions, faces, rows) as one surface_colour.Surface, their material
    ids renumbered 0.. over the ids they use."""
    positions = np.concatenate([np.asarray(s[0], np.float64) for s in sources])
    offsets = np.cumsum([0] + [s[0].shape[0] for s in sources[:-1]])
    faces = np.concatenate([np.asarray(s[1], np.int64) + o for s, o in zip(sources, offsets)])
    rows = np.concatenate([s[2] for s in sources])
    columns = layout.columns()
    uvs = rows[:, columns["uv"]] if "uv" in columns else None
    colors = rows[:, columns["color"]] if "color" in columns else None
    if "material" in columns:
        ids = rows[faces[:, 0], columns["material"].start].astype(np.int64)
        used, local = np.unique(ids, return_inverse=True)
    else:
        used, local = np.zeros(1, np.int64), np.zeros(faces.shape[0], np.int64)
    materials = tuple(looks.materials[int(m)] for m in used)
    images = {i: looks.chains[int(m)] for i, m in enumerate(used) if int(m) in looks.chains}
    return Surface(positions=positions, faces=faces, uvs=uvs, colors=colors, face_material=local.reshape(-1),
                   materials=materials, images=images)


def source_texel_size(surface: Surface) -> float:
    """Model units per texel of the detail the sources hold, sqrt(area / texels): a textured face
    holds its texture's texels over it (texels per unit^2 x area; a repeated texture counts every
    repeat), a face without a texture UNTEXTURED_FACE_TEXELS. A proxy finer than this would only
    magnify its sources. 0 without area."""
    p = np.asarray(surface.positions, np.float64)[np.asarray(surface.faces, np.int64)]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    density = texture_texels_per_unit(surface)
    texels = np.where(density > 0, density * density * area, UNTEXTURED_FACE_TEXELS)
    total_area, total_texels = float(area.sum()), float(texels.sum())
    return float(np.sqrt(total_area / total_texels)) if total_area > 0 and total_texels > 0 else 0.0


def bake_proxy(lod: tuple, error: float, sources: list[tuple], *, node: int, layout: AttributeLayout,
               looks: SourceLooks, scene_materials: int, settings: ProxySettings) -> Proxy:
    """The proxy of one inner node (module docstring). lod: (positions, faces, normals); error: the
    node's error (model units); sources: the children's (positions, faces, rows)."""
    positions, faces, normals = lod
    surface = source_surface(sources, layout, looks)
    texel_size = max(max(float(error), 0.0) / settings.tau_px, source_texel_size(surface))
    area = surface_area(positions, faces)
    side = texture_side(area, texel_size, efficiency=EXPECTED_PACKING, floor=settings.texture_floor,
                        cap=settings.texture_cap)
    density = side * np.sqrt(EXPECTED_PACKING / area) if area > 0 else 1.0
    atlas = node_atlas(positions, faces, texels_per_unit=density, floor=settings.texture_floor,
                       cap=settings.texture_cap)
    width, height = atlas.width, atlas.height
    p = np.asarray(positions, np.float64)[atlas.vertex_of]
    rgba, face, colour, footprint = atlas_texture(atlas, p, surface, error=error, texel_size=texel_size)
    alpha_mode = _alpha_mode(surface)
    face_alpha = np.ones(atlas.faces.shape[0], np.float32)
    if alpha_mode is not None:
        np.minimum.at(face_alpha, face, colour[:, 3])
    alpha_face = face_alpha < OPAQUE_ALPHA
    image = np.empty((height, width, 4), np.uint8)
    image[..., :3] = np.round(srgb_from_linear(rgba[..., :3]) * 255.0)
    image[..., 3] = np.round(np.clip(rgba[..., 3], 0.0, 1.0) * 255.0) if alpha_face.any() else 255
    vertex, split_faces, corner_alpha = _split_parts(atlas.faces, alpha_face)
    columns = layout.columns()
    rows = np.zeros((vertex.size, layout.width), np.float32)
    if "material" in columns:
        rows[:, columns["material"].start] = proxy_material_id(node, False, scene_materials=scene_materials) \
            + corner_alpha
    rows[:, columns["uv"]] = atlas.uvs[vertex]
    if "color" in columns:
        rows[:, columns["color"]] = 1.0
    lod_vertex = atlas.vertex_of[vertex]
    image = np.ascontiguousarray(image[::-1])
    mode = alpha_mode if alpha_face.any() else None
    chain = MipChain.of(image)  # one chain for both parts: its levels are built once
    looks_of_proxy = Surface(positions=p[vertex], faces=split_faces, uvs=atlas.uvs[vertex], colors=None,
                             face_material=corner_alpha[split_faces[:, 0]].astype(np.int64),
                             materials=(Material("proxy", base_color=WHITE),
                                        Material("proxy alpha", base_color=WHITE, alpha_mode=mode or "OPAQUE")),
                             images={0: chain, 1: chain})
    psnr, reason = node_psnr(looks_of_proxy, surface, error=error, tau_px=settings.tau_px,
                             directions=GATE_DIRECTIONS)
    return Proxy(positions=np.asarray(positions, np.float32)[lod_vertex], faces=split_faces,
                 normals=None if normals is None else np.asarray(normals, np.float32)[lod_vertex], rows=rows,
                 image=image, texel_size=footprint, utilization=atlas.utilization, alpha_mode=mode, psnr_y=psnr,
                 psnr_reason=reason)


def atlas_texture(atlas: Atlas, p: np.ndarray, surface: Surface, *, error: float, texel_size: float):
    """The texture of an atlas over a LOD whose atlas vertices lie at p (j,3) float64 model units,
    from the sources' surface: (rgba (h,w,4) float32 linear, row 0 the bottom row; face (s,) int64,
    the atlas face each sample is at; colour (s,4) float32 its colour; footprint, model units per
    texel). The texels whose centres a face covers take the sources' colour at that point, the other
    texels a bilinear read on a face takes (texels.footprint_samples) at the face's point nearest
    them, the rest pull-push (texels.fill_empty)."""
    width, height = atlas.width, atlas.height
    texel, face, bary = texel_samples(atlas.uvs, atlas.faces, width, height)
    if atlas.texels_per_unit > 0:  # the texels a bilinear read on a face takes and no centre sample filled
        centred = np.zeros(height * width, bool)
        centred[texel] = True
        more = footprint_samples(atlas.uvs, atlas.faces, width, height, centred)
        texel, face, bary = (np.concatenate([old, new]) for old, new in zip((texel, face, bary), more))
    if texel.size == 0:  # an atlas of one colour (every UV at its centre): the faces' centroids
        face = np.arange(atlas.faces.shape[0])
        bary = np.full((face.size, 3), 1.0 / 3.0)
        texel = np.zeros(face.size, np.int64)
    points = np.einsum("sk,skd->sd", bary, p[atlas.faces[face]])
    footprint = 1.0 / atlas.texels_per_unit if atlas.texels_per_unit > 0 else texel_size
    if not footprint > 0:
        footprint = 0.0
    t = p[atlas.faces]
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[face]  # the LOD face's at each texel, any length
    reach = max(FACING_REACH_ERRORS * max(float(error), 0.0), footprint)
    source_face, source_bary, _ = closest_facing(points, normal, (surface.positions, surface.faces), reach=reach)
    colour = colour_at(surface, source_face, source_bary, footprint=footprint)
    rgba = np.zeros((height * width, 4), np.float32)
    if atlas.texels_per_unit == 0:  # one colour: the mean of what the faces show
        colour = np.broadcast_to(colour.mean(axis=0), colour.shape)
    rgba[texel] = colour
    filled = np.zeros(height * width, bool)
    filled[texel] = True
    rgba = fill_empty(rgba.reshape(height, width, 4), filled.reshape(height, width))
    return rgba, face, colour, footprint


def _split_parts(faces: np.ndarray, alpha_face: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Atlas vertices split where an opaque and an alpha-tested face meet (each part its own
    material): (atlas vertex of each new vertex (j,), faces (m,3) int32 over them, alpha (j,) of its
    part, 0 or 1)."""
    part = np.repeat(alpha_face.astype(np.int64), 3)
    key = faces.ravel().astype(np.int64) * 2 + part
    unique, inverse = np.unique(key, return_inverse=True)
    return unique // 2, inverse.reshape(-1, 3).astype(np.int32), (unique % 2).astype(np.float32)


def _alpha_mode(surface: Surface) -> str | None:
    """BLEND or MASK when some source material of the surface is (BLEND first), else None."""
    modes = {m.alpha_mode for m in surface.materials}
    return "BLEND" if "BLEND" in modes else "MASK" if "MASK" in modes else None
