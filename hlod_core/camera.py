"""Camera paths: the JSON file format and seeded inspection sequences.

Path file:
    {"fovy_deg": 60, "near": 0.01, "far": 1000,
     "frames": [{"eye": [x, y, z], "target": [x, y, z], "up": [x, y, z]}, ...]}
with "ortho_height": h (model units visible vertically) instead of "fovy_deg" for an
orthographic path. Coordinates are world (model) units, float64.

Seeded sequences (after the dissertation's inspection sessions, §8.1: rotations and changes from
overall views to extreme close-ups): an orbit around the scene, a fly-through across it, a dolly
from the overview down to an extreme close-up of a surface point, and a rotation in place there.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .hierarchy import Hlod
from .metrics import View, look_at, orthographic, perspective


@dataclass(frozen=True)
class CameraPath:
    """frames: (F, 3, 3) float64 rows eye, target, up; fovy_deg or ortho_height; near, far."""

    frames: np.ndarray
    near: float
    far: float
    fovy_deg: float | None = 60.0
    ortho_height: float | None = None

    def view(self, i: int, size: tuple[int, int]) -> View:
        w, h = size
        eye, target, up = self.frames[i]
        if self.ortho_height is not None:
            proj = orthographic(self.ortho_height, w / h, self.near, self.far)
        else:
            proj = perspective(self.fovy_deg, w / h, self.near, self.far)
        return View(eye=eye.copy(), view=look_at(eye, target, up), projection=proj, width=w, height=h)

    def __len__(self) -> int:
        return int(self.frames.shape[0])

    def to_json(self) -> dict:
        out = {"near": self.near, "far": self.far,
               "frames": [{"eye": f[0].tolist(), "target": f[1].tolist(), "up": f[2].tolist()} for f in self.frames]}
        if self.ortho_height is not None:
            out["ortho_height"] = self.ortho_height
        else:
            out["fovy_deg"] = self.fovy_deg
        return out

    def save(self, path: str | os.PathLike) -> None:
        Path(path).write_text(json.dumps(self.to_json()))


def load_path(path: str | os.PathLike) -> CameraPath:
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        frames = np.array([[f["eye"], f["target"], f.get("up", [0, 0, 1])] for f in data["frames"]], np.float64)
        near, far = float(data.get("near", 0.01)), float(data.get("far", 1000.0))
    except OSError as exc:
        raise InputError(f"{path}: cannot read camera path ({exc.strerror or exc})") from exc
    except (ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a camera path ({type(exc).__name__}: {exc})") from exc
    if frames.ndim != 3 or frames.shape[1:] != (3, 3) or frames.shape[0] == 0:
        raise InputError(f"{path}: every frame needs eye, target and up as 3 numbers each")
    if not np.all(np.isfinite(frames)):
        raise InputError(f"{path}: a frame has NaN or infinite coordinates")
    if not 0 < near < far:
        raise InputError(f"{path}: near and far must satisfy 0 < near < far, got {near}, {far}")
    if np.any(np.linalg.norm(frames[:, 1] - frames[:, 0], axis=1) == 0):
        raise InputError(f"{path}: a frame's eye equals its target")
    if "ortho_height" in data:
        height = float(data["ortho_height"])
        if not height > 0:
            raise InputError(f"{path}: ortho_height must be > 0")
        return CameraPath(frames=frames, near=near, far=far, fovy_deg=None, ortho_height=height)
    fovy = float(data.get("fovy_deg", 60.0))
    if not 0 < fovy < 180:
        raise InputError(f"{path}: fovy_deg must lie in (0, 180)")
    return CameraPath(frames=frames, near=near, far=far, fovy_deg=fovy)


def inspection_path(hlod: Hlod, *, seed: int, frames: int, up_axis: int = 2) -> CameraPath:
    """Seeded, in four parts of about a quarter each: a 135 degree orbit at a low elevation, a
    straight fly-through across the scene below half its height (it may pass through geometry), a
    dolly from the overview to an extreme close-up of a random leaf's surface, a rotation in place
    there. Scale-free (follows the root box)."""
    rng = np.random.default_rng(seed)
    lo, hi = hlod.box_min[0], hlod.box_max[0]
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
    up = np.zeros(3)
    up[up_axis] = 1.0
    a, b = [ax for ax in range(3) if ax != up_axis]
    n_fly = n_dolly = n_rotate = frames // 4
    n_orbit = frames - n_fly - n_dolly - n_rotate
    start = rng.uniform(0, 2 * np.pi)
    elevation = rng.uniform(0.15, 0.45) * radius

    def orbit_eye(angle, dist):
        eye = centre.copy()
        eye[a] += dist * np.cos(angle)
        eye[b] += dist * np.sin(angle)
        eye[up_axis] = centre[up_axis] + elevation * dist / (1.6 * radius)
        return eye

    out = []
    for i in range(n_orbit):
        angle = start + 0.75 * np.pi * i / max(n_orbit, 1)
        out.append((orbit_eye(angle, 1.6 * radius), centre, up))
    # fly-through: along axis a or b, at a random lateral offset and a height in the lower half
    along, across = (a, b) if rng.uniform() < 0.5 else (b, a)
    fly_from, fly_to = centre.copy(), centre.copy()
    fly_from[along], fly_to[along] = lo[along] - 0.2 * radius, hi[along] + 0.2 * radius
    offset = rng.uniform(-0.35, 0.35) * (hi[across] - lo[across])
    height = lo[up_axis] + rng.uniform(0.1, 0.45) * (hi[up_axis] - lo[up_axis])
    for p in (fly_from, fly_to):
        p[across] += offset
        p[up_axis] = height
    heading = (fly_to - fly_from) / np.linalg.norm(fly_to - fly_from)
    for i in range(n_fly):
        eye = fly_from + (fly_to - fly_from) * (i / max(n_fly - 1, 1))
        out.append((eye, eye + heading * radius, up))
    leaves = np.flatnonzero(hlod.child_count == 0)
    leaf = int(rng.choice(leaves))
    focus = 0.5 * (hlod.lod_box_min[leaf] + hlod.lod_box_max[leaf])
    far_eye = orbit_eye(start + 0.75 * np.pi, 1.6 * radius)
    close_dist = max(0.02 * radius, 2.0 * float(hlod.sphere_radius[leaf]))
    direction = (far_eye - focus) / np.linalg.norm(far_eye - focus)
    near_eye = focus + direction * close_dist
    for i in range(n_dolly):
        u = (i + 1) / max(n_dolly, 1)
        u = u * u * (3 - 2 * u)  # ease in and out
        eye = far_eye * (1 - u) + near_eye * u
        target = centre * (1 - u) + focus * u
        out.append((eye, target, up))
    look = focus - near_eye
    for i in range(n_rotate):
        angle = 0.5 * np.pi * np.sin(2 * np.pi * i / max(n_rotate, 1))
        c, s = np.cos(angle), np.sin(angle)
        d = look.copy()
        d[a], d[b] = c * look[a] - s * look[b], s * look[a] + c * look[b]
        out.append((near_eye, near_eye + d, up))
    near = max(1e-4 * radius, 0.01 * close_dist)
    return CameraPath(frames=np.array(out, np.float64), near=near, far=8.0 * radius, fovy_deg=60.0)
