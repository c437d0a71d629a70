"""The colours Cycles' DIFFUSE COLOR bake gives the surfaces of blender_surface_checks.py, computed
without Blender from the source image's pixels and the shaders' factors, so that the add-on's
colours are held to what the pass means rather than to another call of the same bake.

The pass (Cycles' DIFFUSE bake with only its Color contribution) is the sum of the weights of the
surface's diffuse closures: a Diffuse BSDF's Color, a Toon BSDF's (its Diffuse component); a Mix
Shader weighs its first shader by 1 - factor and its second by factor, an Add Shader keeps both;
Glossy and Emission closures add nothing. A bake shades each point as seen along its normal, so a
Fresnel node there gives its value at normal incidence, ((ior - 1) / (ior + 1))^2 (0.04 at 1.5).
Per surface of the checks (L: the image's linear colour at the point):

- Diffuse, Toon, a material set by geometry nodes, a realised instance's Toon: L;
- Mix Shader (0.3) of a Diffuse and a Glossy BSDF: 0.7 L;
- Add Shader of a Diffuse (L) and a Diffuse of ADD_COLOUR: L + ADD_COLOUR;
- Mix Shader (0.4) of a Diffuse and an Emission: 0.6 L;
- the glTF metallic-roughness group: (1 - metallic) (1 - F) BaseColorFactor L with metallic =
  METALLIC_FACTOR and F the Fresnel at IOR 1.5: 0.7 x 0.96 = 0.672 of the base colour;
- the procedural (a colour ramp over Generated X, no image): the ramp's two colours blended
  linearly by the point's x across the plane.

The image is read as Cycles reads an 8-bit sRGB Image Texture with Linear interpolation and Repeat
extension: bilinear between the four nearest texels of the stored sRGB values (wrapping at the
edges), then converted to linear.

Data form: (side, side, 3) float64 linear RGB at a side x side image's texel centres over the UV
square, bottom row first (as Blender stores pixels); a per-corner colour is (l, 3).
"""
from __future__ import annotations

import numpy as np

from hlod_core.core.colour import srgb_to_linear

SOURCE_PX = 32  # the source image's side
GLOSSY_MIX = 0.3  # the Mix Shader's factor over the Glossy BSDF
EMISSION_MIX = 0.4  # the Mix Shader's factor over the Emission
EMISSION_COLOUR = (1.0, 0.5, 0.1, 1.0)
ADD_COLOUR = (0.15, 0.05, 0.1, 1.0)  # the second Diffuse BSDF's colour under the Add Shader
BASE_COLOR_FACTOR = (0.9, 0.85, 0.7, 1.0)  # the glTF group's inputs
METALLIC_FACTOR, ROUGHNESS_FACTOR = 0.3, 0.6
FRESNEL_IOR = 1.5  # the group's dielectric Fresnel
RAMP = ((0.9, 0.2, 0.1, 1.0), (0.1, 0.4, 0.9, 1.0))  # the procedural's colour ramp, at 0 and 1
#: The share of the image's colour each image-coloured surface bakes to (module notes).
IMAGE_SHARE = {"diffuse": 1.0, "toon": 1.0, "set_material": 1.0, "realised_instance": 1.0, "add_shader": 1.0,
               "mix_shader": 1.0 - GLOSSY_MIX, "emission_mix": 1.0 - EMISSION_MIX}


def source_rgba() -> np.ndarray:
    """(SOURCE_PX, SOURCE_PX, 4) float32 sRGB values of the source image, bottom row first: smooth
    hue ramps (every channel varies)."""
    y, x = np.mgrid[0:SOURCE_PX, 0:SOURCE_PX] / (SOURCE_PX - 1)
    rgba = np.stack([0.1 + 0.8 * x, 0.2 + 0.7 * y, 0.5 + 0.4 * np.sin(5 * x * y), np.ones_like(x)], axis=-1)
    return rgba.astype(np.float32)


def fresnel_at_normal_incidence(ior: float) -> float:
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def texel_centres(side: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v), each (side, side): the UVs of a side x side image's texel centres (row = v)."""
    centre = (np.arange(side) + 0.5) / side
    v, u = np.meshgrid(centre, centre, indexing="ij")
    return u, v


def image_linear(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(..., 3) linear colour of the source image (stored as 8-bit sRGB) at UVs (u, v) (module notes)."""
    stored = np.round(source_rgba()[..., :3].astype(np.float64) * 255.0) / 255.0
    h, w = stored.shape[:2]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    x1, y1 = (x0 + 1) % w, (y0 + 1) % h
    x0, y0 = x0 % w, y0 % h
    srgb = ((stored[y0, x0] * (1 - fx) + stored[y0, x1] * fx) * (1 - fy)
            + (stored[y1, x0] * (1 - fx) + stored[y1, x1] * fx) * fy)
    flat = np.concatenate([srgb.reshape(-1, 3), np.ones((srgb.size // 3, 1))], axis=1)
    return srgb_to_linear(flat)[:, :3].astype(np.float64).reshape(srgb.shape)


def ramp_linear(x: np.ndarray) -> np.ndarray:
    """(..., 3) the procedural's colour at Generated X = `x` in [0, 1]."""
    start, end = (np.array(c[:3], np.float64) for c in RAMP)
    t = np.clip(np.asarray(x, np.float64), 0.0, 1.0)[..., None]
    return start * (1 - t) + end * t


def expected(case: str, side: int) -> np.ndarray:
    """(side, side, 3) linear: what the DIFFUSE COLOR bake of `case`'s surface gives at a side x
    side image's texel centres over its UV map (module notes). The shared procedural's cases: its
    UV layout is the plane's own ("shared_a": u = x) or turned a quarter ("shared_b": v = x)."""
    u, v = texel_centres(side)
    if case in ("shared_a", "shared_b"):
        return ramp_linear(u if case == "shared_a" else v)
    image = image_linear(u, v)
    if case in ("gltf_group", "linked_group"):
        share = (1.0 - METALLIC_FACTOR) * (1.0 - fresnel_at_normal_incidence(FRESNEL_IOR))
        return share * np.array(BASE_COLOR_FACTOR[:3]) * image
    extra = np.array(ADD_COLOUR[:3]) if case == "add_shader" else 0.0
    return IMAGE_SHARE[case] * image + extra
