"""Writes the scene specs in this folder from the shared models (run: python tests/scenes/generate_specs.py).

gallery_1m.json: 8 statues (igea x2, nefertiti x3, bunny x3; 1,045,227 triangles) each scaled to
10 units and centred, in one row along +x, 8 units apart: looking down the row, each statue hides
most of the next (high depth complexity).
"""
import json
from pathlib import Path

import numpy as np
import pymeshlab

HERE = Path(__file__).resolve().parent
MODELS = Path("../../../shared/models")  # relative to this folder, as the spec format wants


def placement(model: str, position: np.ndarray, size: float = 10.0) -> list[float]:
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(str((HERE / MODELS / model).resolve()))
    box = ms.current_mesh().bounding_box()
    scale = size / float(np.max(box.max() - box.min()))
    m = np.eye(4)
    m[:3, :3] *= scale
    m[:3, 3] = position - scale * 0.5 * (box.min() + box.max())
    return [float(x) for x in m.ravel()]


def gallery() -> dict:
    row = ["igea.ply", "nefertiti.obj", "stanford-bunny.obj", "igea.ply",
           "nefertiti.obj", "stanford-bunny.obj", "nefertiti.obj", "stanford-bunny.obj"]
    models: dict[str, list] = {}
    for i, name in enumerate(row):
        models.setdefault(name, []).append(placement(name, np.array([8.0 * i, 0.0, 0.0])))
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
