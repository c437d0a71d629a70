"""Camera paths: the JSON file format and seeded inspection sequences.

Path file:
    {"fovy_deg": 60, "near": 0.01, "far": 1000,
     "frames": [{"eye": [x, y, z], "target": [x, y, z], "up": [x, y, z]}, ...]}
with "ortho_height": h (model units visible vertically) instead of "fovy_deg" for an
orthographic path. Coordinates are world (model) units, float64. Defaults: fovy_deg 60, near 0.01,
far 1000, up [0, 0, 1]. Optional "parts": [{"name": "orbit", "start": 0}, ...], the path's named
parts in order (a part runs from its start frame to the next part's start; the first starts at
frame 0; the evaluation report marks them on its frame axis). Every number field must be a JSON
number (not null, a string, a list or true/false), finite and at most MAX_MAGNITUDE in size;
unknown keys are refused; any far/near ratio is accepted (traversal.boxes.frustum_planes keeps a
far plane beyond float64's reach at infinity).

Seeded sequences (after the inspection sequences of section 8.1 of J. P. Charalambos' dissertation,
2007, docs/how-it-works.md#papers: rotations and changes from overall views to extreme close-ups):
an orbit around the scene, a fly-through across it, a dolly from the overview down to an extreme
close-up of a surface point, and a rotation in place there;
the parts are recorded as such.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import jsonutil
from ..core.atomic import write_text_atomic
from ..core.errors import InputError
from .hierarchy import MAX_COORDINATE, Hlod
from .view import View, look_at, orthographic, perspective


@dataclass(frozen=True)
class CameraPath:
    """frames: (F, 3, 3) float64 rows eye, target, up; fovy_deg or ortho_height; near, far;
    parts: ((name, start frame), ...), starts rising from 0 (empty: the path is one part)."""

    frames: np.ndarray
    near: float
    far: float
    fovy_deg: float | None = 60.0
    ortho_height: float | None = None
    parts: tuple[tuple[str, int], ...] = ()

    def view(self, i: int, size: tuple[int, int]) -> View:
        w, h = size
        eye, target, up = self.frames[i]
        if self.ortho_height is not None:
            proj = orthographic(self.ortho_height, w / h, near=self.near, far=self.far)
        else:
            proj = perspective(self.fovy_deg, w / h, near=self.near, far=self.far)
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
        if self.parts:
            out["parts"] = [{"name": name, "start": start} for name, start in self.parts]
        return out

    def save(self, path: str | os.PathLike) -> None:
        write_text_atomic(path, json.dumps(self.to_json()))


#: Keys of a path file and of each frame; anything else is refused (a misspelt "fov_deg" would
#: otherwise leave the default in place without a word).
PATH_KEYS = ("fovy_deg", "ortho_height", "near", "far", "frames", "parts")
FRAME_KEYS = ("eye", "target", "up")
PART_KEYS = ("name", "start")
MAX_PART_NAME = 40  # characters of a part's name (a label on a figure's frame axis)
DEFAULT_FOVY_DEG, DEFAULT_NEAR, DEFAULT_FAR = 60.0, 0.01, 1000.0
#: Largest magnitude of a coordinate, near, far or ortho_height (squares and products of such
#: numbers, in look_at's norms and the projection, stay far inside float64).
MAX_MAGNITUDE = MAX_COORDINATE
#: A generated path's radius is at least this fraction of the model's distance from the origin,
#: so that positions one radius apart differ in float64 even for a model without extent.
MIN_RADIUS_RELATIVE = 1e-9


def load_path(path: str | os.PathLike) -> CameraPath:
    """Read and validate a path file (module docstring). Raises InputError naming the file and
    the field at fault: not JSON, nested too deep, a missing or unknown key, a field that is not
    a finite number (null, a string, a list, true/false, 1e999), near/far out of order."""
    path = Path(path)
    return path_from_json(jsonutil.read(path, what="camera path"), source=str(path))


def path_from_json(data, *, source: str) -> CameraPath:
    """A CameraPath from the parsed JSON of a path file; `source` names it in errors."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: a camera path is a JSON object with \"frames\", got {_kind(data)}")
    _known_keys(data, PATH_KEYS, source=source, where="the path")
    frames_data = data.get("frames")
    if not isinstance(frames_data, list) or not frames_data:
        raise InputError(f"{source}: \"frames\" must be a non-empty list of {{eye, target, up}}, "
                         f"got {_kind(frames_data)}")
    frames = np.empty((len(frames_data), 3, 3), np.float64)
    for i, frame in enumerate(frames_data):
        if not isinstance(frame, dict):
            raise InputError(f"{source}: frames[{i}] must be an object with eye, target and up, got {_kind(frame)}")
        _known_keys(frame, FRAME_KEYS, source=source, where=f"frames[{i}]")
        for j, key in enumerate(FRAME_KEYS):
            if key not in frame and key != "up":
                raise InputError(f"{source}: frames[{i}] has no \"{key}\"")
            frames[i, j] = _vector3(frame.get(key, [0.0, 0.0, 1.0]), source, f"frames[{i}].{key}")
    near = _number(data.get("near", DEFAULT_NEAR), source, "near")
    far = _number(data.get("far", DEFAULT_FAR), source, "far")
    if not 0 < near < far:
        raise InputError(f"{source}: near and far must satisfy 0 < near < far, got {near:g}, {far:g}")
    same = np.flatnonzero(np.all(frames[:, 1] == frames[:, 0], axis=1))
    if same.size:
        raise InputError(f"{source}: a frame's eye equals its target (frames[{same[0]}])")
    parts = _parts(data.get("parts", []), len(frames), source)
    if "fovy_deg" in data and "ortho_height" in data:
        raise InputError(f"{source}: give fovy_deg (perspective) or ortho_height (orthographic), not both")
    if "ortho_height" in data:
        height = _number(data["ortho_height"], source, "ortho_height")
        if not height > 0:
            raise InputError(f"{source}: ortho_height must be > 0, got {height:g}")
        return CameraPath(frames=frames, near=near, far=far, fovy_deg=None, ortho_height=height, parts=parts)
    fovy = _number(data.get("fovy_deg", DEFAULT_FOVY_DEG), source, "fovy_deg")
    if not 0 < fovy < 180:
        raise InputError(f"{source}: fovy_deg must lie in (0, 180), got {fovy:g}")
    return CameraPath(frames=frames, near=near, far=far, fovy_deg=fovy, parts=parts)


def _kind(value) -> str:
    """How a JSON value reads in a message."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f"the string {json.dumps(value[:40])}"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "an object"
    return repr(value)


def _known_keys(obj: dict, keys: tuple[str, ...], *, source: str, where: str) -> None:
    """InputError naming the first key of `obj` not in `keys` (sorted), at `where` in `source`."""
    unknown = sorted(set(obj) - set(keys))
    if unknown:
        raise InputError(f"{source}: {where} has unknown key {json.dumps(unknown[0][:40])}; "
                         f"expected some of {', '.join(keys)}")


def _number(value, source: str, where: str) -> float:
    """A JSON number (true/false are not numbers), finite and at most MAX_MAGNITUDE in size."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{source}: {where} must be a number, got {_kind(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer of hundreds of digits
        number = math.inf
    if not abs(number) <= MAX_MAGNITUDE:
        raise InputError(f"{source}: {where} must be a finite number of magnitude at most {MAX_MAGNITUDE:g}, "
                         f"got {str(value)[:40]}")
    return number


def _parts(value, frame_count: int, source: str) -> tuple[tuple[str, int], ...]:
    """The optional "parts" list: objects {name, start}, names non-empty strings of at most
    MAX_PART_NAME characters, starts whole numbers rising from 0 and below frame_count."""
    if not isinstance(value, list):
        raise InputError(f"{source}: \"parts\" must be a list of {{name, start}}, got {_kind(value)}")
    parts = []
    for i, part in enumerate(value):
        where = f"parts[{i}]"
        if not isinstance(part, dict):
            raise InputError(f"{source}: {where} must be an object with name and start, got {_kind(part)}")
        _known_keys(part, PART_KEYS, source=source, where=where)
        name, start = part.get("name"), part.get("start")
        if not isinstance(name, str) or not 0 < len(name) <= MAX_PART_NAME:
            raise InputError(f"{source}: {where}.name must be a string of 1 to {MAX_PART_NAME} characters, "
                             f"got {_kind(name)}")
        if isinstance(start, bool) or not isinstance(start, int):
            raise InputError(f"{source}: {where}.start must be a whole number (a frame index), got {_kind(start)}")
        low = 0 if i == 0 else parts[-1][1] + 1
        high = 0 if i == 0 else frame_count - 1
        if not low <= start <= high:
            expected = "0 (the first part starts the path)" if i == 0 else \
                f"in {low}..{high} (after the previous part's start, within the {frame_count} frames)"
            raise InputError(f"{source}: {where}.start must be {expected}, got {start}")
        parts.append((name, start))
    return tuple(parts)


def _vector3(value, source: str, where: str) -> list[float]:
    if not isinstance(value, list) or len(value) != 3:
        raise InputError(f"{source}: {where} must be a list of 3 numbers, got {_kind(value)}")
    return [_number(x, source, f"{where}[{k}]") for k, x in enumerate(value)]


def inspection_path(hlod: Hlod, *, seed: int, frames: int, up_axis: int = 2) -> CameraPath:
    """Seeded, in four parts of about a quarter each: a 135 degree orbit at a low elevation, a
    straight fly-through across the scene below half its height (it may pass through geometry), a
    dolly from the overview to an extreme close-up of a random leaf's surface, a rotation in place
    there. Scale-free: scaling the model by any factor (1e-9 to 1e9 are tested) scales the path
    by the same factor, near and far included."""
    rng = np.random.default_rng(seed)
    scene = _PathFrame.of(hlod, up_axis)
    n_fly = n_dolly = n_rotate = frames // 4
    n_orbit = frames - n_fly - n_dolly - n_rotate
    start = rng.uniform(0, 2 * np.pi)
    elevation = rng.uniform(0.15, 0.45) * scene.radius
    out = [(scene.orbit_eye(start + 0.75 * np.pi * i / max(n_orbit, 1), 1.6 * scene.radius, elevation), scene.centre,
            scene.up) for i in range(n_orbit)]
    out += _fly_through(scene, rng, count=n_fly)
    leaf = int(rng.choice(np.flatnonzero(hlod.is_leaf)))
    focus = 0.5 * (hlod.lod_box_min[leaf] + hlod.lod_box_max[leaf])
    far_eye = scene.orbit_eye(start + 0.75 * np.pi, 1.6 * scene.radius, elevation)
    close_dist = max(0.02 * scene.radius, 2.0 * float(hlod.sphere_radius[leaf]))
    near_eye = focus + (far_eye - focus) / np.linalg.norm(far_eye - focus) * close_dist
    out += _dolly(scene, from_eye=far_eye, to_eye=near_eye, focus=focus, count=n_dolly)
    out += _rotate(scene, eye=near_eye, look=focus - near_eye, count=n_rotate)
    near = max(1e-4 * scene.radius, 0.01 * close_dist)
    counts = (("orbit", n_orbit), ("fly-through", n_fly), ("dolly", n_dolly), ("rotate", n_rotate))
    starts = np.cumsum([0] + [n for _, n in counts[:-1]])
    parts = tuple((name, int(start)) for (name, n), start in zip(counts, starts) if n > 0)
    return CameraPath(frames=np.array(out, np.float64), near=near, far=8.0 * scene.radius, fovy_deg=60.0,
                      parts=parts)


@dataclass(frozen=True, eq=False)
class _PathFrame:
    """The root box an inspection path moves around: lo, hi, centre (3,) float64; radius, a length
    every distance of the path is a multiple of; the up axis and the two axes across it."""

    lo: np.ndarray
    hi: np.ndarray
    centre: np.ndarray
    radius: float
    up: np.ndarray
    up_axis: int
    a: int
    b: int

    @classmethod
    def of(cls, hlod: Hlod, up_axis: int) -> "_PathFrame":
        lo, hi = hlod.box_min[0], hlod.box_max[0]
        centre = 0.5 * (lo + hi)
        # every length is a multiple of the root radius (or of a leaf's radius), so the path of a
        # model scaled by any factor is the same path scaled; the floor only keeps a model without
        # extent apart from its eye in float64, and one at the origin gets 1 model unit
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), MIN_RADIUS_RELATIVE * float(np.abs(centre).max())) or 1.0
        up = np.zeros(3)
        up[up_axis] = 1.0
        a, b = [ax for ax in range(3) if ax != up_axis]
        return cls(lo=lo, hi=hi, centre=centre, radius=radius, up=up, up_axis=up_axis, a=a, b=b)

    def orbit_eye(self, angle: float, dist: float, elevation: float) -> np.ndarray:
        """The eye at `angle` around the centre, `dist` away across, raised in proportion to dist."""
        eye = self.centre.copy()
        eye[self.a] += dist * np.cos(angle)
        eye[self.b] += dist * np.sin(angle)
        eye[self.up_axis] = self.centre[self.up_axis] + elevation * dist / (1.6 * self.radius)
        return eye


def _fly_through(scene: _PathFrame, rng: np.random.Generator, *, count: int) -> list:
    """Along axis a or b, at a random lateral offset and a height in the lower half, looking ahead."""
    a, b, up_axis, lo, hi = scene.a, scene.b, scene.up_axis, scene.lo, scene.hi
    along, across = (a, b) if rng.uniform() < 0.5 else (b, a)
    fly_from, fly_to = scene.centre.copy(), scene.centre.copy()
    fly_from[along], fly_to[along] = lo[along] - 0.2 * scene.radius, hi[along] + 0.2 * scene.radius
    offset = rng.uniform(-0.35, 0.35) * (hi[across] - lo[across])
    height = lo[up_axis] + rng.uniform(0.1, 0.45) * (hi[up_axis] - lo[up_axis])
    for p in (fly_from, fly_to):
        p[across] += offset
        p[up_axis] = height
    heading = (fly_to - fly_from) / np.linalg.norm(fly_to - fly_from)
    out = []
    for i in range(count):
        eye = fly_from + (fly_to - fly_from) * (i / max(count - 1, 1))
        out.append((eye, eye + heading * scene.radius, scene.up))
    return out


def _dolly(scene: _PathFrame, *, from_eye: np.ndarray, to_eye: np.ndarray, focus: np.ndarray, count: int) -> list:
    """From the overview to the close-up, easing in and out, the target moving from the centre to
    the focus."""
    out = []
    for i in range(count):
        u = (i + 1) / max(count, 1)
        u = u * u * (3 - 2 * u)  # ease in and out
        out.append((from_eye * (1 - u) + to_eye * u, scene.centre * (1 - u) + focus * u, scene.up))
    return out


def _rotate(scene: _PathFrame, *, eye: np.ndarray, look: np.ndarray, count: int) -> list:
    """In place at `eye`: the view direction `look` swung up to 90 degrees each way about the up axis."""
    a, b = scene.a, scene.b
    out = []
    for i in range(count):
        angle = 0.5 * np.pi * np.sin(2 * np.pi * i / max(count, 1))
        c, s = np.cos(angle), np.sin(angle)
        d = look.copy()
        d[a], d[b] = c * look[a] - s * look[b], s * look[a] + c * look[b]
        out.append((eye, eye + d, scene.up))
    return out
