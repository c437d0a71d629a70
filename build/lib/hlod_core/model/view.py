"""A camera for one frame: eye, view and projection matrices (OpenGL conventions, float64) and the
viewport in pixels, and the matrices' constructors (look-at, perspective, orthographic).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Below this length of view direction x up, up is taken as parallel to the view direction.
_PARALLEL_UP = 1e-12


@dataclass(frozen=True, eq=False)
class View:
    """eye (3,) float64 world; view (4,4) and projection (4,4) float64 (OpenGL conventions,
    column vectors: clip = projection @ view @ world); width/height: viewport in pixels."""

    eye: np.ndarray
    view: np.ndarray
    projection: np.ndarray
    width: int
    height: int

    @property
    def orthographic(self) -> bool:
        return bool(self.projection[3, 3] == 1.0 and self.projection[3, 2] == 0.0)

    @property
    def pixels_per_unit_y(self) -> float:
        """(H/2) * P[1][1]: pixels per model unit at distance 1 (perspective) or anywhere (ortho)."""
        return 0.5 * self.height * float(self.projection[1, 1])

    @property
    def pixels_per_unit_x(self) -> float:
        return 0.5 * self.width * float(self.projection[0, 0])


def look_at(eye, target, up) -> np.ndarray:
    """OpenGL view matrix (4,4) float64 of an eye (3,) looking at target (3,) with `up` (3,) (any up
    parallel to the view direction is replaced by a perpendicular one)."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    s = np.cross(f, up)
    norm = np.linalg.norm(s)
    if norm < _PARALLEL_UP:  # up parallel to the view direction: pick any perpendicular
        s = np.cross(f, [1.0, 0.0, 0.0] if abs(f[0]) < 0.9 else [0.0, 1.0, 0.0])
        norm = np.linalg.norm(s)
    s /= norm
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fovy_deg: float, aspect: float, *, near: float, far: float) -> np.ndarray:
    """OpenGL perspective projection (4,4) float64: vertical field of view in degrees, aspect =
    width / height, near and far planes in model units (0 < near < far)."""
    f = 1.0 / np.tan(np.radians(fovy_deg) / 2.0)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = (far + near) / (near - far), 2.0 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(height: float, aspect: float, *, near: float, far: float) -> np.ndarray:
    """OpenGL orthographic projection (4,4) float64: `height` model units visible vertically, aspect
    = width / height, near and far planes in model units."""
    m = np.eye(4)
    m[0, 0], m[1, 1] = 2.0 / (height * aspect), 2.0 / height
    m[2, 2], m[2, 3] = -2.0 / (far - near), -(far + near) / (far - near)
    return m
