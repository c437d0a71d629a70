"""Writes the scene specs in this folder from the shared models (run: python tests/scenes/generate_specs.py).

gallery_1m.json: 8 statues (igea x2, nefertiti x3, bunny x3; 1,045,227 triangles) each scaled to
10 units and centred, in one row along +x, 8 units apart: looking down the row, each statue hides
most of the next (high depth complexity).

crowd_1m.json: 20 statues (igea x2, nefertiti x6, bunny x6, rocker-arm x2, homer x2, fandisk x2;
1,644,000 triangles) each scaled to 10 units, turned about +z, on a 5 x 4 grid 10 units apart: from any
low viewpoint the first row hides most of the ones behind, which show only through the gaps (the
README's evaluation scene).
"""
import json
from pathlib import Path

import numpy as np
import pymeshlab

HERE = Path(__file__).resolve().parent
MODELS = Path("../../../shared/models")  # relative to this folder, as the spec format wants


def placement(model: str, position: np.ndarray, size: float = 10.0, turn_deg: float = 0.0) -> list[float]:
    """Scale the model's box to `size` along its longest side, turn it about +z, centre it at `position`."""
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str((HERE / MODELS / model).resolve()))
    box = ms.current_mesh().bounding_box()
    scale = size / float(np.max(box.max() - box.min()))
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    m = np.eye(4)
    m[:3, :3] = scale * np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    m[:3, 3] = position - m[:3, :3] @ (0.5 * (box.min() + box.max()))
    return [float(x) for x in m.ravel()]


def gallery() -> dict:
    row = ["igea.ply", "nefertiti.obj", "stanford-bunny.obj", "igea.ply",
           "nefertiti.obj", "stanford-bunny.obj", "nefertiti.obj", "stanford-bunny.obj"]
    models: dict[str, list] = {}
    for i, name in enumerate(row):
        models.setdefault(name, []).append(placement(name, np.array([8.0 * i, 0.0, 0.0])))
    return {"models": [{"path": str(MODELS / name), "transforms": t} for name, t in models.items()]}


def crowd() -> dict:
    kinds = ["nefertiti.obj", "cow.obj", "homer.obj", "spot.obj", "stanford-bunny.obj", "teapot.obj",
             "rocker-arm.obj", "fandisk.obj", "nefertiti.obj", "cow.obj", "spot.obj", "homer.obj",
             "stanford-bunny.obj", "teapot.obj", "fandisk.obj", "rocker-arm.obj"]
    models: dict[str, list] = {}
    for k in range(64):
        i, j = k % 8, k // 8
        name = kinds[(k + j) % len(kinds)]
        models.setdefault(name, []).append(placement(name, np.array([10.0 * i, 10.0 * j, 0.0]), turn_deg=37.0 * k))
    return {"models": [{"path": str(MODELS / name), "transforms": t} for name, t in models.items()]}


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
