"""3D Tiles 1.1 export of a baked hierarchy: one tile per node, one GLB per node.

Specification: OGC 3D Tiles 1.1 (tileset JSON, bounding volumes, geometricError, REPLACE
refinement, glTF content) and Khronos glTF 2.0 (GLB container). Nothing else is needed: the GLB
writer is the few lines of the binary format, with numpy arrays as the buffer.

Decisions (README "3D Tiles"):
- **Axes and units.** The bake's model space is Blender's: Z up, metres. Tilesets are Z up; glTF
  is Y up and 3D Tiles runtimes rotate glTF content by +90 degrees about X to bring it to Z up, so
  GLB positions are written as (x, z, -y). Units stay metres. The root tile's `transform`
  translates by the bake's float64 origin; every position and box below it is relative to that
  origin, so a scene placed 1e6 m away keeps float32 precision. There is no geolocation: the
  tileset is in a local frame (add a transform to place it on the globe).
- **geometricError** of a tile is its node's model-space error (the Hausdorff distance of its LOD
  to the original below it, metres): the error of showing this tile and not its children, which
  is what 3D Tiles asks; leaves have 0. The tileset's own geometricError (the error of showing
  nothing) is the root box's diagonal, and at least the root's error: a runtime shows the root as
  soon as the whole scene would cover more than its screen-space-error threshold in pixels.
- **Boxes** are the nodes' subtree boxes (they contain the LOD and every descendant), as
  `boundingVolume.box` (centre and half axes), with half sizes of at least 1e-6 of the root
  diagonal so flat nodes do not give degenerate boxes.
- **Attributes** only where the bake has them: POSITION always, NORMAL when the hierarchy carries
  normals; no UVs or colours (the bake does not carry them yet), and no material (glTF's default).
- Nodes without triangles and without children are left out (the bake makes none; checked anyway).
"""
from __future__ import annotations

import json
import os
import shutil
import struct
import tempfile
from pathlib import Path

import numpy as np

from .atomic import umask_mode
from .errors import InputError
from .hierarchy import Hlod, node_mesh

GLB_MAGIC, GLB_VERSION = 0x46546C67, 2
CHUNK_JSON, CHUNK_BIN = 0x4E4F534A, 0x004E4942
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
FLOAT, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5123, 5125
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)


def glb_bytes(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None) -> bytes:
    """A GLB with one mesh of one indexed triangle primitive; positions/normals given Z up."""
    pos = np.ascontiguousarray((positions.astype(np.float64) @ Z_UP_TO_Y_UP.T).astype(np.float32))
    index_type, index_dtype = (UNSIGNED_SHORT, np.uint16) if pos.shape[0] <= 0xFFFF else (UNSIGNED_INT, np.uint32)
    idx = np.ascontiguousarray(faces.astype(index_dtype)).ravel()
    parts = [pos.tobytes()]
    attributes = {"POSITION": 0}
    accessors = [{"bufferView": 0, "componentType": FLOAT, "count": int(pos.shape[0]), "type": "VEC3",
                  "min": pos.min(0).tolist(), "max": pos.max(0).tolist()}]
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(parts[0]), "target": ARRAY_BUFFER}]
    if normals is not None:
        nrm = np.ascontiguousarray((normals.astype(np.float64) @ Z_UP_TO_Y_UP.T).astype(np.float32))
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(length > 0, nrm / np.where(length > 0, length, 1), [[0.0, 1.0, 0.0]]).astype(np.float32)
        views.append({"buffer": 0, "byteOffset": sum(map(len, parts)), "byteLength": nrm.nbytes, "target": ARRAY_BUFFER})
        parts.append(nrm.tobytes())
        attributes["NORMAL"] = len(accessors)
        accessors.append({"bufferView": len(views) - 1, "componentType": FLOAT, "count": int(nrm.shape[0]),
                          "type": "VEC3"})
    offset = sum(map(len, parts))
    views.append({"buffer": 0, "byteOffset": offset, "byteLength": idx.nbytes, "target": ELEMENT_ARRAY_BUFFER})
    parts.append(idx.tobytes())
    accessors.append({"bufferView": len(views) - 1, "componentType": index_type, "count": int(idx.size),
                      "type": "SCALAR"})
    binary = b"".join(parts)
    binary += b"\0" * (-len(binary) % 4)
    gltf = {"asset": {"version": "2.0", "generator": "HLOD Bake & Preview"},
            "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": attributes, "indices": len(accessors) - 1, "mode": 4}]}],
            "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(binary)}]}
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", GLB_MAGIC, GLB_VERSION, total) + struct.pack("<II", len(text), CHUNK_JSON) + text
            + struct.pack("<II", len(binary), CHUNK_BIN) + binary)


def _box(lo: np.ndarray, hi: np.ndarray, floor: float) -> list[float]:
    centre, half = 0.5 * (lo + hi), np.maximum(0.5 * (hi - lo), floor)
    return [*centre.tolist(), half[0], 0.0, 0.0, 0.0, half[1], 0.0, 0.0, 0.0, half[2]]


def tileset(hlod: Hlod, content_uri) -> dict:
    """The tileset JSON; content_uri(node) names each node's GLB."""
    origin = np.asarray(hlod.origin, np.float64)
    lo_all, hi_all = hlod.box_min - origin, hlod.box_max - origin
    diagonal = float(np.linalg.norm(hi_all[0] - lo_all[0]))
    floor = max(1e-6 * diagonal, 1e-9)

    def tile(node: int) -> dict | None:
        first, count = int(hlod.child_offset[node]), int(hlod.child_count[node])
        children = [t for t in (tile(c) for c in range(first, first + count)) if t is not None] if count else []
        if hlod.tri_count[node] == 0 and not children:
            return None  # an empty node is absent
        out = {"boundingVolume": {"box": _box(lo_all[node], hi_all[node], floor)},
               "geometricError": float(hlod.error[node])}
        if hlod.tri_count[node] > 0:
            out["content"] = {"uri": content_uri(node)}
        if children:
            out["children"] = children
        return out

    root = tile(0)
    if root is None:
        raise InputError("3D Tiles export: the hierarchy has no triangles")
    transform = np.eye(4)
    transform[:3, 3] = origin
    root["refine"] = "REPLACE"
    root["transform"] = transform.T.ravel().tolist()  # column-major
    return {"asset": {"version": "1.1", "generator": "HLOD Bake & Preview"},
            "geometricError": max(diagonal, float(hlod.error[0])), "root": root}


def export(hlod: Hlod, out_dir: str | os.PathLike) -> dict:
    """Write tileset.json and tiles/<node>.glb into out_dir, atomically: everything is written into
    a temporary folder beside it and renamed into place, replacing an earlier export. Folders and
    files get the modes of ordinary ones (0o777 / 0o666 less the umask). Returns a summary (tiles,
    glb files, triangles, bytes)."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        os.chmod(staging, umask_mode(0o777))  # mkdtemp makes it 0700; the export is an ordinary folder
        (staging / "tiles").mkdir()
        written, tris, size = 0, 0, 0
        for node in np.flatnonzero(hlod.tri_count > 0).tolist():
            positions, faces, normals = node_mesh(hlod, node)
            data = glb_bytes(positions, faces, normals)
            (staging / "tiles" / f"{node}.glb").write_bytes(data)
            written, tris, size = written + 1, tris + faces.shape[0], size + len(data)
        document = tileset(hlod, lambda node: f"tiles/{node}.glb")
        (staging / "tileset.json").write_text(json.dumps(document, indent=1))
        old = None
        if out_dir.exists():
            if not (out_dir / "tileset.json").is_file() and any(out_dir.iterdir()):
                raise InputError(f"{out_dir}: exists, is not empty and holds no tileset.json; not replacing it")
            old = out_dir.with_name(f".{out_dir.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            out_dir.rename(old)
        staging.rename(out_dir)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return {"format": "3dtiles", "output": str(out_dir), "tiles": _count(document["root"]), "glb_files": written,
            "triangles": tris, "bytes": size, "tileset_geometric_error": document["geometricError"]}


def _count(tile: dict) -> int:
    return 1 + sum(_count(c) for c in tile.get("children", []))
