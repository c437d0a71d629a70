"""Colour: the sRGB transfer function (IEC 61966-2-1) both ways, the plain node colour, and the
modulation overlay's colour ramp (docs/how-it-works.md#vmsse-and-the-bias-p_st): m = 1 - P from blue (0, weak) through
magenta (0.5, moderate) to red (1, strong), and its lookup table for drawing. Data form: numpy arrays of values
in [0, 1]; the ramp takes (n,) modulation values and gives (n,3) float32 linear RGB. The same sRGB
encoding in GLSL is hlod_core.render.glsl.SRGB_FROM_LINEAR.
"""
from __future__ import annotations

import numpy as np

#: Entries of the overlay's colour table less one: P is rounded to a multiple of 1 / OVERLAY_RAMP_STEPS
#: (the ramp's steepest channel moves 1.7 per unit of P, so a colour errs by at most 2.1e-4, a
#: nineteenth of an 8-bit level).
OVERLAY_RAMP_STEPS = 4096

#: Linear RGB of a node drawn without the overlay and without an appearance.
DEFAULT_COLOUR = (0.82, 0.80, 0.76)


def modulation_colour(m: np.ndarray) -> np.ndarray:
    """(n,3) float32 RGB ramp blue (m=0) -> magenta (0.5) -> red (1)."""
    m = np.clip(np.asarray(m, np.float64), 0.0, 1.0)[..., None]
    blue, magenta, red = np.array([0.1, 0.2, 1.0]), np.array([0.9, 0.1, 0.9]), np.array([1.0, 0.1, 0.05])
    lower = blue + (magenta - blue) * (m / 0.5)
    upper = magenta + (red - magenta) * ((m - 0.5) / 0.5)
    return np.where(m <= 0.5, lower, upper).astype(np.float32)


def overlay_ramp(steps: int = OVERLAY_RAMP_STEPS) -> list[tuple[float, float, float]]:
    """The overlay colour of P = i / steps for i = 0..steps: modulation_colour(1 - P), as
    tuples of Python floats (a uniform's value, no conversion per draw)."""
    ratio_p = np.linspace(0.0, 1.0, steps + 1)
    return [tuple(row) for row in modulation_colour(1.0 - ratio_p).tolist()]  # m = 1 - P


def srgb_to_linear(rgba: np.ndarray) -> np.ndarray:
    """(v,4) sRGB-encoded colours in [0, 1] (clipped) to (v,4) float32 linear; alpha unchanged."""
    c = np.clip(np.asarray(rgba, np.float64), 0.0, 1.0)
    rgb = c[:, :3]
    linear = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
    return np.concatenate([linear, c[:, 3:4]], axis=1).astype(np.float32)


def srgb_from_linear(linear: np.ndarray) -> np.ndarray:
    """Linear values in [0, 1] (clipped), any shape, to float32 sRGB-encoded values."""
    c = np.clip(linear, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1.0 / 2.4) - 0.055).astype(np.float32)
