"""The colour nodes' formulas as Cycles evaluates them, vectorised over pixels or vertices.

Data form: colours (n,3) float32 linear RGB, factors and scalars (n,1) or (1,1) float32 (they
broadcast); every function returns (n,3). The formulas are Cycles' (intern/cycles/kernel/svm:
svm_mix's blend modes, svm_node_hsv, svm_brightness_contrast, gamma, invert, and the RGB Curves
table lookup), so a texture processed here matches what Cycles and EEVEE draw. Imports no Blender
module: numpy only.
"""
from __future__ import annotations

import numpy as np

#: Blender's default scene luminance (Rec. 709 linear), the weights of a colour read as a number.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722], np.float32)


def grey(rgb: np.ndarray) -> np.ndarray:
    """(n,1) luminance of (n,3) linear colours: a colour socket linked into a number socket."""
    return (np.asarray(rgb, np.float32) @ LUMINANCE)[:, None]


def lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    return a + t * (b - a)


def rgb_to_hsv(rgb: np.ndarray) -> np.ndarray:
    """(n,3) RGB -> (n,3) HSV, hue in [0, 1) (Cycles' rgb_to_hsv: grey has hue 0, saturation 0)."""
    rgb = np.asarray(rgb, np.float32)
    high, low = rgb.max(axis=1), rgb.min(axis=1)
    delta = high - low
    safe_high, safe_delta = np.where(high != 0, high, 1), np.where(delta != 0, delta, 1)
    s = np.where(high != 0, delta / safe_high, 0)
    c = (high[:, None] - rgb) / safe_delta[:, None]
    r, g = rgb[:, 0], rgb[:, 1]
    h = np.where(r == high, c[:, 2] - c[:, 1], np.where(g == high, 2 + c[:, 0] - c[:, 2], 4 + c[:, 1] - c[:, 0]))
    h = np.where(s != 0, (h / 6) % 1.0, 0)
    return np.stack([h, s, high], axis=1).astype(np.float32)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """(n,3) HSV -> (n,3) RGB (Cycles' hsv_to_rgb)."""
    h, s, v = (np.asarray(hsv, np.float32)[:, k] for k in range(3))
    h6 = np.where(h >= 1, 0, h) * 6
    i = np.floor(h6)
    f = h6 - i
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    i = i.astype(np.int64) % 6
    table = np.stack([np.stack(c, axis=1) for c in ((v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q))])
    out = table[i, np.arange(h.size)]
    return np.where((s == 0)[:, None], v[:, None], out).astype(np.float32)


def _per_channel(where: np.ndarray, yes: np.ndarray, no: np.ndarray) -> np.ndarray:
    return np.where(where, yes, no)


def blend(mode: str, t: np.ndarray, c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """The Mix node's colour blend `mode` (Blender's blend_type) of c1 (A) and c2 (B) by factor t
    (Cycles' svm_mix). ValueError for a mode it does not know."""
    c1, c2 = np.broadcast_arrays(np.asarray(c1, np.float32), np.asarray(c2, np.float32))
    tm = 1 - t
    if mode == "MIX":
        return lerp(c1, c2, t)
    if mode == "ADD":
        return c1 + t * c2
    if mode == "MULTIPLY":
        return c1 * (tm + t * c2)
    if mode == "SUBTRACT":
        return c1 - t * c2
    if mode == "SCREEN":
        return 1 - (tm + t * (1 - c2)) * (1 - c1)
    if mode == "DIVIDE":
        return _per_channel(c2 != 0, tm * c1 + t * c1 / np.where(c2 != 0, c2, 1), c1)
    if mode == "DIFFERENCE":
        return lerp(c1, np.abs(c1 - c2), t)
    if mode == "EXCLUSION":
        return np.maximum(lerp(c1, c1 + c2 - 2 * c1 * c2, t), 0)
    if mode == "DARKEN":
        return lerp(c1, np.minimum(c1, c2), t)
    if mode == "LIGHTEN":
        return lerp(c1, np.maximum(c1, c2), t)
    if mode == "OVERLAY":
        return _per_channel(c1 < 0.5, c1 * (tm + 2 * t * c2), 1 - (tm + 2 * t * (1 - c2)) * (1 - c1))
    if mode == "DODGE":
        tmp = 1 - t * c2
        quotient = np.minimum(c1 / np.where(tmp > 0, tmp, 1), 1)
        return _per_channel(c1 != 0, np.where(tmp <= 0, 1, quotient), c1)
    if mode == "BURN":
        tmp = tm + t * c2
        value = np.clip(1 - (1 - c1) / np.where(tmp > 0, tmp, 1), 0, 1)
        return np.where(tmp <= 0, 0, value)
    if mode == "SOFT_LIGHT":
        screen = 1 - (1 - c2) * (1 - c1)
        return tm * c1 + t * ((1 - c1) * c2 * c1 + c1 * screen)
    if mode == "LINEAR_LIGHT":
        return c1 + t * (2 * c2 - 1)
    if mode in ("HUE", "SATURATION", "VALUE", "COLOR"):
        return _blend_hsv(mode, t, c1, c2)
    raise ValueError(f"blend mode {mode}")


def _blend_hsv(mode: str, t: np.ndarray, c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
    """The HSV blend modes (Cycles' svm_mix_hue, _saturation, _value, _color)."""
    hsv1, hsv2 = rgb_to_hsv(c1), rgb_to_hsv(c2)
    t1 = np.broadcast_to(np.asarray(t, np.float32), (c1.shape[0], 1))[:, 0]
    mixed = hsv1.copy()
    if mode == "VALUE":
        mixed[:, 2] = (1 - t1) * hsv1[:, 2] + t1 * hsv2[:, 2]
        return hsv_to_rgb(mixed)
    if mode == "SATURATION":
        mixed[:, 1] = (1 - t1) * hsv1[:, 1] + t1 * hsv2[:, 1]
        return np.where((hsv1[:, 1] != 0)[:, None], hsv_to_rgb(mixed), c1)
    mixed[:, 0] = hsv2[:, 0]
    if mode == "COLOR":
        mixed[:, 1] = hsv2[:, 1]
    return np.where((hsv2[:, 1] != 0)[:, None], lerp(c1, hsv_to_rgb(mixed), t1[:, None]), c1)


def hue_saturation_value(rgb, *, hue, saturation, value, factor) -> np.ndarray:
    """The Hue/Saturation/Value node (Cycles' svm_node_hsv): hue 0.5 and the others 1 change nothing."""
    hsv = rgb_to_hsv(rgb)
    hsv[:, 0] = (hsv[:, 0] + np.broadcast_to(hue, (hsv.shape[0], 1))[:, 0] + 0.5) % 1.0
    hsv[:, 1] = np.clip(hsv[:, 1] * np.broadcast_to(saturation, (hsv.shape[0], 1))[:, 0], 0, 1)
    hsv[:, 2] = hsv[:, 2] * np.broadcast_to(value, (hsv.shape[0], 1))[:, 0]
    return np.maximum(lerp(rgb, hsv_to_rgb(hsv), factor), 0)


def gamma(rgb, exponent) -> np.ndarray:
    """The Gamma node: positive channels raised to `exponent`, the others kept."""
    rgb = np.asarray(rgb, np.float32)
    return np.where(rgb > 0, np.power(np.maximum(rgb, 1e-30), exponent), rgb)


def brightness_contrast(rgb, *, bright, contrast) -> np.ndarray:
    """The Brightness/Contrast node: max((1 + contrast) rgb + bright - contrast / 2, 0)."""
    return np.maximum((1 + contrast) * rgb + bright - 0.5 * contrast, 0)


def invert(rgb, factor) -> np.ndarray:
    """The Invert Color node: lerp(rgb, 1 - rgb, factor)."""
    return lerp(rgb, 1 - rgb, factor)


def curves(rgb, tables: np.ndarray, factor) -> np.ndarray:
    """The RGB Curves node through its tables (3, k) float32: channel c of an input x in [0, 1] is
    tables[c] at x (each table already holds the channel's curve after the combined curve),
    linearly interpolated, clamped at the ends; lerp with the input by `factor`."""
    rgb = np.asarray(rgb, np.float32)
    x = np.linspace(0.0, 1.0, tables.shape[1], dtype=np.float32)
    out = np.stack([np.interp(rgb[:, c], x, tables[c]) for c in range(3)], axis=1).astype(np.float32)
    return lerp(rgb, out, factor)
