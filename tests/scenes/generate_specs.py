"""Writes the scene specs in this folder from the test models (run: python tests/scenes/generate_specs.py).

The specs name their models relative to this folder: tests/meshes/ for the models kept in the
repository, .cache/models/ for the rest (tests/models.py writes them there on first use:
`models.scene(NAME)` before a spec is read, or `python tests/models.py` once by hand).

gallery_1m.json: 8 statues (statue x2, bust x3, bunny x3; 1,004,268 triangles) each scaled to
10 units and centred, in one row along +x, 8 units apart: looking down the row, each statue hides
most of the next (high depth complexity).

yard_1m.json: 16 statues (the bust; 1,589,952 triangles) each scaled to 10 units, centred and
turned about +z, on a 4 x 4 grid 12 units apart: the re-bake benchmark's scene
(benchmarks/rebake.py --spec tests/scenes/yard_1m.json --move 0 moves the statue at the (0, 0)
corner, at the scene's edge).

open_statues_5m.json: 100 statues with open boundaries (bunny x50, teapot x30, bust x20; about 5M
triangles) on a 10 x 10 grid 12 units apart; open_statues_far_path.json orbits it while pulling back
from 2 to 45 times its side (the coarse levels' benchmark: benchmarks/coarse_levels.py).

crowd_1m.json: 144 statues (cow, airplane, spot, teapot, ring, creased; 1,535,020 triangles) each
scaled to 10 units and turned about +z, packed on a 12 x 12 grid 8 units apart (neighbours nearly
touch): from inside or beside the crowd the nearest statues hide most of the others, which show
only as slivers through the gaps: the high-depth-complexity scene of docs/evaluation.md.
crowd_walk_path.json is a fast 320-frame tour of it (orbit at ground level, aisle walk, turn in
place, dolly to close-up; up to 4.5 degrees or 1.35 units per frame), crowd_inspection_path.json
the evaluation's path (docs/evaluation.md): the same four parts at interactive speeds sampled at 60 frames per
second (1,020 frames). Both paths name their parts ("parts": orbit, walk, turn, dolly with their
start frames), which the evaluation report marks on its frame axis.
"""
import json
import os
import sys
from pathlib import Path

import numpy as np
import pymeshlab

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import models  # tests/models.py: the test models by role

HERE = Path(__file__).resolve().parent


def model_path(role: str) -> str:
    """The role's file relative to this folder, as the spec format wants (written when missing)."""
    return Path(os.path.relpath(models.path(role), HERE)).as_posix()


def box(role: str) -> tuple[np.ndarray, np.ndarray]:
    """The role's box (low, high) as pymeshlab reads the file."""
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str(models.path(role)))
    bounds = ms.current_mesh().bounding_box()
    return bounds.min(), bounds.max()


def placement(role: str, position: np.ndarray, size: float = 10.0, turn_deg: float = 0.0, *,
              boxes: dict | None = None) -> list[float]:
    """Scale the model's box to `size` along its longest side, turn it about +z, centre it at
    `position`; `boxes` keeps the boxes read (role -> box) for the next call."""
    boxes = {} if boxes is None else boxes
    if role not in boxes:
        boxes[role] = box(role)
    low, high = boxes[role]
    scale = size / float(np.max(high - low))
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    m = np.eye(4)
    m[:3, :3] = scale * np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    m[:3, 3] = position - m[:3, :3] @ (0.5 * (low + high))
    return [float(x) for x in m.ravel()]


def gallery() -> dict:
    row = ["statue", "bust", "bunny", "statue", "bust", "bunny", "bust", "bunny"]
    placed: dict[str, list] = {}
    boxes: dict[str, tuple] = {}
    for i, name in enumerate(row):
        placed.setdefault(name, []).append(placement(name, np.array([8.0 * i, 0.0, 0.0]), boxes=boxes))
    return {"models": [{"path": model_path(name), "transforms": t} for name, t in placed.items()]}


YARD_SIDE, YARD_SPACING = 4, 12.0


def yard() -> dict:
    """Instance k (file order) stands at grid cell (k % 4, k // 4): instance 0 at the (0, 0) corner."""
    boxes: dict[str, tuple] = {}
    transforms = [placement("bust", np.array([YARD_SPACING * (k % YARD_SIDE), YARD_SPACING * (k // YARD_SIDE), 0.0]),
                            turn_deg=90.0 * k, boxes=boxes) for k in range(YARD_SIDE * YARD_SIDE)]
    return {"models": [{"path": model_path("bust"), "transforms": transforms}]}


CROWD_SIDE, CROWD_SPACING = 12, 8.0


def crowd() -> dict:
    kinds = ["cow", "airplane", "spot", "teapot", "ring", "creased", "airplane", "cow", "spot", "ring", "creased"]
    placed: dict[str, list] = {}
    boxes: dict[str, tuple] = {}
    for k in range(CROWD_SIDE * CROWD_SIDE):
        i, j = k % CROWD_SIDE, k // CROWD_SIDE
        name = kinds[(k + j) % len(kinds)]
        position = np.array([CROWD_SPACING * i, CROWD_SPACING * j, 0.0])
        placed.setdefault(name, []).append(placement(name, position, turn_deg=37.0 * k, boxes=boxes))
    return {"models": [{"path": model_path(name), "transforms": t} for name, t in placed.items()]}


OPEN_SIDE, OPEN_SPACING = 10, 12.0


def open_statues() -> dict:
    """100 statues with open boundaries, about 5M triangles: 50 bunnies (a scan with holes cut in it),
    30 teapots (open surfaces in 4 pieces) and 20 busts (closed), each scaled to 10 units and turned
    about +z, on a 10 x 10 grid 12 units apart (2 units between neighbours)."""
    kinds = ["bunny", "teapot", "bunny", "bust", "bunny", "teapot", "bunny", "teapot", "bunny", "bust"]
    placed: dict[str, list] = {}
    boxes: dict[str, tuple] = {}
    for k in range(OPEN_SIDE * OPEN_SIDE):
        i, j = k % OPEN_SIDE, k // OPEN_SIDE
        name = kinds[(k + 3 * j) % len(kinds)]
        placed.setdefault(name, []).append(placement(name, np.array([OPEN_SPACING * i, OPEN_SPACING * j, 0.0]),
                                                     turn_deg=29.0 * k, boxes=boxes))
    return {"models": [{"path": model_path(name), "transforms": t} for name, t in placed.items()]}


def open_statues_far(frames: int = 120) -> dict:
    """Far views of open_statues: one orbit around the grid's centre while pulling back from 2 to 45
    times the grid's side (log-spaced), half as high as far, looking at the centre: the coarse
    levels' range (at 640x480 and tau 1 px a node of error e is drawn from about 416 e units away)."""
    side = OPEN_SPACING * (OPEN_SIDE - 1)
    centre = np.array([side / 2, side / 2, 0.0])
    out = []
    for i in range(frames):
        a = 2 * np.pi * i / frames
        r = side * 2.0 * (45.0 / 2.0) ** (i / (frames - 1))
        out.append({"eye": [round(float(c), 6) for c in centre + [r * np.cos(a), r * np.sin(a), 0.5 * r]],
                    "target": [round(float(c), 6) for c in centre], "up": [0, 0, 1]})
    return {"fovy_deg": 60, "near": 1.0, "far": 20000, "frames": out}


def _dolly(centre: np.ndarray, side: float, n: int) -> list:
    """n frames, eased in and out, from an elevated overview to 0.3 units from a statue near the centre."""
    far, focus = centre + [-0.9 * side, -0.9 * side, 0.4 * side], centre + [CROWD_SPACING, 0.0, 0.0]
    near = focus + 0.3 * (far - focus) / np.linalg.norm(far - focus)
    out = []
    for i in range(n):
        u = (i + 1) / n
        u = u * u * (3 - 2 * u)
        out.append((far * (1 - u) + near * u, centre * (1 - u) + focus * u))
    return out


PARTS = ("orbit", "walk", "turn", "dolly")


def _path_json(frames: list, part_frames: list[int]) -> dict:
    """The path file of (eye, target) pairs in PARTS order, `part_frames` frames each."""
    assert len(part_frames) == len(PARTS) and sum(part_frames) == len(frames)
    starts = np.cumsum([0] + part_frames[:-1])
    return {"fovy_deg": 60, "near": 0.01, "far": 400,
            "frames": [{"eye": [round(float(c), 6) for c in e], "target": [round(float(c), 6) for c in t],
                        "up": [0, 0, 1]} for e, t in frames],
            "parts": [{"name": name, "start": int(start)} for name, start in zip(PARTS, starts)]}


def crowd_walk(frames_per_part: int = 80) -> dict:
    """A 4-part inspection of crowd_1m at statue mid-height (z = 0; statues span -5..5): an orbit
    around the crowd at ground level, a walk down the aisle between the first two rows looking
    ahead, a full turn in place at an aisle crossing in the middle, and a dolly from an elevated
    overview to an extreme close-up (0.3 units) of a statue in the middle of the crowd."""
    n, side, gap = frames_per_part, CROWD_SPACING * (CROWD_SIDE - 1), CROWD_SPACING / 2
    centre = np.array([side / 2, side / 2, 0.0])
    frames = []
    for i in range(n):
        a = np.radians(200.0) + np.radians(120.0) * i / n
        frames.append((centre + [1.2 * side * np.cos(a), 1.2 * side * np.sin(a), 0.5], centre))
    for i in range(n):
        x = -10.0 + (side + 20.0) * i / (n - 1)
        frames.append(([x, gap, 0.0], [x + 20.0, gap + 8.0 * np.sin(2 * np.pi * i / n), 0.0]))
    crossing = centre  # an aisle crossing (statues stand at multiples of the spacing)
    for i in range(n):
        a = 2 * np.pi * i / n
        frames.append((crossing, crossing + [10 * np.cos(a), 10 * np.sin(a), 0.0]))
    return _path_json(frames + _dolly(centre, side, n), [n] * len(PARTS))


def crowd_inspection(fps: float = 60.0) -> dict:
    """The same four parts as crowd_walk, played at the speeds of a careful interactive inspection and
    sampled at a viewport's `fps` (the papers' sequences ran at 100-200 frames per second, so frame
    to frame coherence is what their coherent traversal relies on): an orbit at ground level, 36
    degrees at 12 degrees/s; a walk down the first aisle, 36 units at 6 units/s (statues are 10 units
    tall) with the gaze swaying across the rows; a half turn in place at an aisle crossing in the
    middle, 45 degrees/s; a 4 s dolly, eased in and out, from an elevated overview to an extreme
    close-up (0.3 units) of a statue in the middle of the crowd. 17 s in all."""
    side, gap = CROWD_SPACING * (CROWD_SIDE - 1), CROWD_SPACING / 2
    centre = np.array([side / 2, side / 2, 0.0])
    frames = []
    counts = [round(3.0 * fps), round(6.0 * fps), round(4.0 * fps), round(4.0 * fps)]
    n = counts[0]
    for i in range(n):
        a = np.radians(200.0) + np.radians(12.0) * i / fps
        frames.append((centre + [1.2 * side * np.cos(a), 1.2 * side * np.sin(a), 0.5], centre))
    n = counts[1]
    for i in range(n):
        x = -10.0 + 6.0 * i / fps
        frames.append(([x, gap, 0.0], [x + 20.0, gap + 8.0 * np.sin(2 * np.pi * i / n), 0.0]))
    crossing = centre  # an aisle crossing (statues stand at multiples of the spacing)
    for i in range(counts[2]):
        a = np.radians(45.0) * i / fps
        frames.append((crossing, crossing + [10 * np.cos(a), 10 * np.sin(a), 0.0]))
    return _path_json(frames + _dolly(centre, side, counts[3]), counts)


def write_spec(path: Path, spec: dict) -> None:
    """One line per transform, so the file reads as a list of placements."""
    lines = ['{"models": [']
    for i, model in enumerate(spec["models"]):
        rows = ",\n    ".join(json.dumps(t) for t in model["transforms"])
        comma = "," if i + 1 < len(spec["models"]) else ""
        lines.append(f'  {{"path": {json.dumps(model["path"])}, "transforms": [\n    {rows}]}}{comma}')
    lines.append("]}")
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    write_spec(HERE / "gallery_1m.json", gallery())
    write_spec(HERE / "crowd_1m.json", crowd())
    write_spec(HERE / "yard_1m.json", yard())
    (HERE / "crowd_walk_path.json").write_text(json.dumps(crowd_walk()) + "\n")
    (HERE / "crowd_inspection_path.json").write_text(json.dumps(crowd_inspection()) + "\n")
    write_spec(HERE / "open_statues_5m.json", open_statues())
    (HERE / "open_statues_far_path.json").write_text(json.dumps(open_statues_far()) + "\n")
