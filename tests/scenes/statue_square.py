"""The statue square: a scene of many image-textured materials, written from the test models
(tests/models.py) into .cache/models/statue_square_<size>/, deterministically, on first use (again
when this module changes: a stamp in the folder).

On a 6 x 6 grid 12 units apart, on a textured ground: 32 statues and 4 bushes, each its own material
with its own generated PNG texture (37 materials, every one image-textured):
- each statue an OBJ + MTL + PNG of its own: a test model scaled to 10 units along its longest side,
  turned about +z, standing on the ground, with UVs from a box projection (the models have none:
  each triangle maps its two coordinates across its normal's largest axis), a procedural texture of
  its own (stripes, checks, dots, rings, waves or cells in a colour of its own); the statue in grid
  cell 5 has UVs far outside [0, 1] (shifted by (1000, -500) and tripled: the texture repeats);
- each bush a glTF file of three crossed, subdivided cards with a leaf texture whose alpha cuts the
  leaves out, material alphaMode MASK (an MTL has no alpha mode);
- the ground an OBJ grid 76 units square, a seamless tile texture repeated every 8 units (UVs up
  to 9.5).

Sizes: `small` (the tests': cow, spot and teapot statues, about 200k triangles, 128-pixel
textures) and `bench` (benchmarks/proxy_materials.py: bust, bunny, ring and the smaller models,
about 1.2M triangles, 512-pixel textures). Beside the models: scene.json, the scene spec, and
far_path.json, a camera path from far to near (docs/command-line.md#camera-paths).

    .venv/bin/python tests/scenes/statue_square.py small|bench   # writes it, prints paths and counts
"""
from __future__ import annotations

import base64
import hashlib
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE.parents[1]))
import models  # noqa: E402  (tests/models.py, found through the path set above)
from hlod_core.core.png import png_bytes  # noqa: E402  (the repository's root, set above)

SIDE, SPACING, STATUE_SIZE = 6, 12.0, 10.0
BUSH_CELLS = (7, 16, 22, 33)  # grid cells (k = i + SIDE j) of the bushes; the rest hold statues
FAR_UV_CELL = 5  # the statue whose UVs lie far outside [0, 1]
FAR_UV_OFFSET, FAR_UV_SCALE = (1000.0, -500.0), 3.0
GROUND_MARGIN, GROUND_TILE = 8.0, 8.0  # ground beyond the grid, units per texture repeat
#: Per size: the statues' roles in grid order (cycled), ground cells per side, texture pixels.
SIZES = {
    "small": {"roles": ("cow", "spot", "teapot"), "ground_cells": 40, "pixels": 128},
    "bench": {"roles": ("bust", "bunny", "ring", "bust", "bunny", "creased", "bust", "bunny", "airplane",
                        "bust", "bunny", "teapot", "bust", "bunny", "spot", "creased", "bunny", "ring",
                        "airplane", "bunny", "cow", "bunny", "ring", "creased", "ring", "airplane", "ring",
                        "creased", "airplane", "teapot", "spot", "cow"),
              "ground_cells": 100, "pixels": 512},
}
PATTERNS = ("stripes", "checks", "dots", "rings", "waves", "cells")


def folder(size: str) -> Path:
    """Where the scene of `size` is written."""
    return models.GENERATED / f"statue_square_{size}"


def scene(size: str) -> Path:
    """The scene spec of `size` (SIZES), everything it reads written first when missing or stale."""
    if size not in SIZES:
        raise KeyError(f"no statue square {size!r}; the sizes are {', '.join(SIZES)}")
    target = folder(size)
    want = hashlib.sha256(Path(__file__).read_bytes() + size.encode()).hexdigest()
    try:
        if (target / "stamp").read_text() == want:
            return target / "scene.json"
    except OSError:
        pass
    models.GENERATED.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=f".statue_square_{size}-", dir=models.GENERATED))
    os.chmod(scratch, 0o755)
    try:
        write_scene(scratch, **SIZES[size])
        (scratch / "stamp").write_text(want)
        old = target.with_name(f".{target.name}-old-{os.getpid()}")
        if target.exists():
            os.replace(target, old)  # a concurrent writer made the same files: either copy is whole
        os.replace(scratch, target)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return target / "scene.json"


def far_path(size: str) -> Path:
    """The far-to-near camera path of the scene of `size` (written with it)."""
    return scene(size).parent / "far_path.json"


# --- the scene -------------------------------------------------------------------------------------

def write_scene(out: Path, *, roles: tuple, ground_cells: int, pixels: int) -> dict:
    """Every file of the scene into `out`; returns the facts written to facts.json."""
    rng = np.random.default_rng(47)
    entries, tris, names = [], 0, []
    statues = [k for k in range(SIDE * SIDE) if k not in BUSH_CELLS]
    boxes: dict = {}
    for n, k in enumerate(statues):
        role = roles[n % len(roles)]
        if role not in boxes:
            mesh = _load(role)
            boxes[role] = (mesh.positions, mesh.faces)
        positions, faces = boxes[role]
        uvs, corner = box_uvs(positions, faces)
        if k == FAR_UV_CELL:
            uvs = uvs * FAR_UV_SCALE + np.array(FAR_UV_OFFSET)
        name = f"statue_{k:02d}_{role}"
        texture = pattern_pixels(PATTERNS[n % len(PATTERNS)], hue=(0.618034 * n) % 1.0, pixels=pixels, rng=rng)
        write_textured_obj(out, name, positions, faces, uvs, corner, texture)
        entries.append({"path": f"{name}.obj", "transforms": [placement(positions, k, turn_deg=37.0 * k)]})
        tris += faces.shape[0]
        names.append(name)
    positions, faces, uvs = bush_cards()
    for n, k in enumerate(BUSH_CELLS):
        name = f"bush_{k:02d}"
        write_bush_gltf(out, name, positions, faces, uvs, leaf_pixels(hue=0.25 + 0.05 * n, pixels=pixels, rng=rng))
        entries.append({"path": f"{name}.gltf", "transforms": [placement(positions, k, turn_deg=23.0 * k,
                                                                         y_up=True)]})
        tris += faces.shape[0]
        names.append(name)
    positions, faces, uvs = ground(ground_cells)
    write_textured_obj(out, "ground", positions, faces, uvs, faces, tile_pixels(pixels, rng))
    entries.append({"path": "ground.obj"})
    tris += faces.shape[0]
    names.append("ground")
    (out / "scene.json").write_text(json.dumps({"models": entries}, indent=1) + "\n")
    (out / "far_path.json").write_text(json.dumps(far_to_near()) + "\n")
    facts = {"triangles": int(tris), "materials": len(names), "textured_materials": len(names),
             "mask_materials": len(BUSH_CELLS), "texture_pixels": pixels, "names": names}
    (out / "facts.json").write_text(json.dumps(facts, indent=1) + "\n")
    return facts


def _load(role: str):
    from hlod_core.io.meshes import load_mesh

    return load_mesh(models.path(role))


def placement(positions: np.ndarray, k: int, *, turn_deg: float, y_up: bool = False) -> list[float]:
    """Row-major 4x4: scale the box to STATUE_SIZE along its longest side, turn about +z, stand it
    on z = 0 at grid cell k. y_up: the glTF reader has already turned the model Z up."""
    low, high = positions.min(axis=0), positions.max(axis=0)
    if y_up:  # glTF +Y up -> +Z up: (x, y, z) -> (x, -z, y)
        low, high = np.array([low[0], -high[2], low[1]]), np.array([high[0], -low[2], high[1]])
    scale = STATUE_SIZE / float(np.max(high - low))
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    m = np.eye(4)
    m[:3, :3] = scale * np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    centre = 0.5 * (low + high)
    centre[2] = low[2]
    m[:3, 3] = np.array([SPACING * (k % SIDE), SPACING * (k // SIDE), 0.0]) - m[:3, :3] @ centre
    return [round(float(x), 9) for x in m.ravel()]


def box_uvs(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Box-projected UVs: (c,2) float64 UV rows and (f,3) their indices per corner. A triangle maps
    its corners' two coordinates across its normal's largest axis, the model's box scaled to [0, 1];
    a vertex gets one UV row per axis its triangles use."""
    p = positions[faces]
    axis = np.argmax(np.abs(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])), axis=1)
    low, high = positions.min(axis=0), positions.max(axis=0)
    unit = (positions - low) / np.maximum(high - low, 1e-12)
    keys, corner = np.unique((faces * 3 + axis[:, None]).ravel(), return_inverse=True)
    vertex, along = keys // 3, keys % 3
    first = np.array([1, 0, 0])[along]
    second = np.array([2, 2, 1])[along]
    uvs = np.stack([unit[vertex, first], unit[vertex, second]], axis=1)
    return uvs, corner.reshape(-1, 3)


def ground(cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ground grid at z = 0: (v,3) positions, (f,3) faces (counter-clockwise from +z), (v,2) UVs
    of one texture repeat per GROUND_TILE units."""
    low, high = -GROUND_MARGIN, SPACING * (SIDE - 1) + GROUND_MARGIN
    t = np.linspace(low, high, cells + 1)
    x, y = np.meshgrid(t, t)
    positions = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i = np.arange(cells * (cells + 1)).reshape(cells, cells + 1)[:, :-1].ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + cells + 2], 1), np.stack([i, i + cells + 2, i + cells + 1], 1)])
    return positions, faces, positions[:, :2] / GROUND_TILE


def bush_cards(cuts: int = 6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Three vertical cards crossed at 60 degrees, glTF axes (+Y up), each `cuts` x `cuts` squares:
    (v,3) positions, (f,3) faces, (v,2) UVs in OpenGL's convention (v up)."""
    t = np.linspace(0.0, 1.0, cuts + 1)
    u, v = np.meshgrid(t, t)
    i = np.arange(cuts * (cuts + 1)).reshape(cuts, cuts + 1)[:, :-1].ravel()
    card = np.concatenate([np.stack([i, i + 1, i + cuts + 2], 1), np.stack([i, i + cuts + 2, i + cuts + 1], 1)])
    positions, faces, uvs = [], [], []
    for n in range(3):
        a = np.radians(60.0 * n)
        positions.append(np.stack([(u.ravel() - 0.5) * np.cos(a), v.ravel(), (u.ravel() - 0.5) * np.sin(a)], 1))
        faces.append(card + n * u.size)
        uvs.append(np.stack([u.ravel(), v.ravel()], 1))
    return np.concatenate(positions), np.concatenate(faces), np.concatenate(uvs)


def far_to_near(frames: int = 90) -> dict:
    """From 40 times the square's side away down to 2 units from the statue nearest the centre, the
    distance log-spaced, the eye a quarter turn round meanwhile, at half the distance's height."""
    side = SPACING * (SIDE - 1)
    centre = np.array([side / 2, side / 2, 0.0])
    focus = np.array([SPACING * 2, SPACING * 2, STATUE_SIZE / 2])
    out = []
    for i in range(frames):
        u = i / (frames - 1)
        r = 40.0 * side * (2.0 / (40.0 * side)) ** u
        a = np.radians(-120.0 + 90.0 * u)
        look = centre * (1 - u) + focus * u
        eye = look + r * np.array([np.cos(a), np.sin(a), 0.5]) / np.sqrt(1.25)
        out.append({"eye": [round(float(c), 6) for c in eye], "target": [round(float(c), 6) for c in look],
                    "up": [0, 0, 1]})
    return {"fovy_deg": 60, "near": 0.05, "far": 20000, "frames": out,
            "parts": [{"name": "far", "start": 0}, {"name": "near", "start": frames // 2}]}


# --- textures ------------------------------------------------------------------------------------

def _hsv(hue: float, saturation: float, value: float) -> np.ndarray:
    k = (np.array([5.0, 3.0, 1.0]) + hue * 6.0) % 6.0
    return value - value * saturation * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)


def pattern_pixels(kind: str, *, hue: float, pixels: int, rng: np.random.Generator) -> np.ndarray:
    """(pixels, pixels, 4) uint8 RGBA, opaque: a two-colour procedural pattern in `hue` with noise."""
    y, x = (np.mgrid[0:pixels, 0:pixels] + 0.5) / pixels
    f = rng.uniform(4.0, 10.0)
    if kind == "stripes":
        mix = 0.5 + 0.5 * np.sin(2 * np.pi * f * (x + 0.3 * y))
    elif kind == "checks":
        mix = (((x * f).astype(int) + (y * f).astype(int)) % 2).astype(float)
    elif kind == "dots":
        mix = (np.hypot((x * f) % 1.0 - 0.5, (y * f) % 1.0 - 0.5) < 0.3).astype(float)
    elif kind == "rings":
        mix = 0.5 + 0.5 * np.cos(2 * np.pi * f * np.hypot(x - 0.5, y - 0.5))
    elif kind == "waves":
        mix = 0.5 + 0.5 * np.sin(2 * np.pi * (f * x + 0.15 * np.sin(2 * np.pi * 3 * y)))
    else:  # cells: the nearest of a few seeded points
        points = rng.uniform(0.0, 1.0, (24, 2))
        d = np.hypot(x[..., None] - points[:, 0], y[..., None] - points[:, 1])
        mix = (np.argmin(d, axis=-1) % 3) / 2.0
    a, b = _hsv(hue, 0.75, 0.9), _hsv((hue + 0.08) % 1.0, 0.5, 0.35)
    rgb = a * mix[..., None] + b * (1.0 - mix[..., None]) + rng.normal(0.0, 0.03, (pixels, pixels, 3))
    return _rgba8(rgb, np.ones((pixels, pixels)))


def leaf_pixels(*, hue: float, pixels: int, rng: np.random.Generator) -> np.ndarray:
    """A foliage card: leaf ellipses in greens on transparent black (alpha 0 or 1: a MASK's cut-out)."""
    y, x = (np.mgrid[0:pixels, 0:pixels] + 0.5) / pixels
    alpha = np.zeros((pixels, pixels))
    rgb = np.zeros((pixels, pixels, 3))
    for cx, cy, r, turn, shade in zip(*rng.uniform([0.1, 0.05, 0.05, 0.0, 0.5], [0.9, 0.95, 0.12, np.pi, 1.0],
                                                   (40, 5)).T):
        dx, dy = x - cx, y - cy
        u, v = dx * np.cos(turn) + dy * np.sin(turn), -dx * np.sin(turn) + dy * np.cos(turn)
        inside = (u / r) ** 2 + (v / (0.45 * r)) ** 2 < 1.0
        alpha[inside] = 1.0
        rgb[inside] = _hsv(hue, 0.7, shade)
    return _rgba8(rgb, alpha)


def tile_pixels(pixels: int, rng: np.random.Generator) -> np.ndarray:
    """The ground: 4 x 4 paving stones with grout, seamless when repeated."""
    y, x = (np.mgrid[0:pixels, 0:pixels] + 0.5) / pixels
    stone = (x * 4).astype(int) + 4 * (y * 4).astype(int)
    grout = ((x * 4) % 1.0 < 0.05) | ((y * 4) % 1.0 < 0.05)
    shade = rng.uniform(0.75, 1.0, 16)[stone]
    rgb = np.where(grout[..., None], np.array([0.35, 0.33, 0.3]), np.array([0.62, 0.58, 0.5]) * shade[..., None])
    return _rgba8(rgb + rng.normal(0.0, 0.02, rgb.shape), np.ones((pixels, pixels)))


def _rgba8(rgb: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    return np.round(np.clip(np.dstack([rgb, alpha]), 0.0, 1.0) * 255.0).astype(np.uint8)


# --- files ---------------------------------------------------------------------------------------

def write_textured_obj(out: Path, name: str, positions: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                       uv_faces: np.ndarray, texture: np.ndarray) -> None:
    """name.obj (v, vt, `f v/vt`), name.mtl (one material `name`, map_Kd name.png) and name.png."""
    (out / f"{name}.png").write_bytes(png_bytes(texture))
    (out / f"{name}.mtl").write_text(f"newmtl {name}\nKd 1 1 1\nmap_Kd {name}.png\n")
    with open(out / f"{name}.obj", "w") as f:
        f.write(f"# generated by tests/scenes/statue_square.py\nmtllib {name}.mtl\n")
        np.savetxt(f, positions, fmt="v %.7g %.7g %.7g")
        np.savetxt(f, uvs, fmt="vt %.9g %.9g")
        f.write(f"usemtl {name}\n")
        np.savetxt(f, np.stack([faces + 1, uv_faces + 1], axis=2).reshape(-1, 6), fmt="f %d/%d %d/%d %d/%d")


def write_bush_gltf(out: Path, name: str, positions: np.ndarray, faces: np.ndarray, uvs: np.ndarray,
                    texture: np.ndarray) -> None:
    """name.gltf (one mesh, buffers as a data URI, material alphaMode MASK, both sides) and name.png."""
    (out / f"{name}.png").write_bytes(png_bytes(texture))
    p = positions.astype("<f4")
    t = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], axis=1).astype("<f4")  # glTF's v runs down
    i = faces.astype("<u4")
    blob = p.tobytes() + t.tobytes() + i.tobytes()
    views = [(0, p.nbytes, 34962), (p.nbytes, t.nbytes, 34962), (p.nbytes + t.nbytes, i.nbytes, 34963)]
    gltf = {
        "asset": {"version": "2.0", "generator": "tests/scenes/statue_square.py"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0}]}],
        "materials": [{"name": name, "alphaMode": "MASK", "alphaCutoff": 0.5, "doubleSided": True,
                       "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}, "metallicFactor": 0.0,
                                                "roughnessFactor": 0.9}}],
        "textures": [{"source": 0}], "images": [{"uri": f"{name}.png"}],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")}],
        "bufferViews": [{"buffer": 0, "byteOffset": o, "byteLength": n, "target": tg} for o, n, tg in views],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(p), "type": "VEC3",
             "min": p.min(axis=0).tolist(), "max": p.max(axis=0).tolist()},
            {"bufferView": 1, "componentType": 5126, "count": len(t), "type": "VEC2"},
            {"bufferView": 2, "componentType": 5125, "count": i.size, "type": "SCALAR"}],
    }
    (out / f"{name}.gltf").write_text(json.dumps(gltf) + "\n")


if __name__ == "__main__":
    size = sys.argv[1] if len(sys.argv) > 1 else "small"
    spec = scene(size)
    facts = json.loads((spec.parent / "facts.json").read_text())
    print(json.dumps({"spec": str(spec), "path": str(far_path(size)), "triangles": facts["triangles"],
                      "materials": facts["materials"]}))
