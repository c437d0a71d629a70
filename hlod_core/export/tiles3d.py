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
  normals, TEXCOORD_0 (u, 1 - v: glTF's origin is the image's top-left, ours Blender's bottom-left)
  when it carries UVs, COLOR_0 (float RGBA, linear) when it carries colours. An HLOD without
  appearance writes exactly what it wrote before issue 13: one primitive, glTF's default material.
- **Materials** (issue 13): one primitive per (node, material), all of a node's primitives sharing
  its vertex accessors, each with its own range of the one index buffer view. A glTF material per
  material used in the tile: pbrMetallicRoughness with baseColorFactor, metallicFactor,
  roughnessFactor and, when the material has a texture and the HLOD has UVs, baseColorTexture.
- **Images** are written once per tileset, in `textures/` beside `tiles/` (the original bytes,
  under a unique name; PNG or JPEG as glTF 2.0 allows, told by their first bytes), and every GLB
  refers to them by a URI relative to itself (`../textures/NAME`), not embedded per tile. A texture
  that cannot be read or is neither PNG nor JPEG gives one warning naming the file and its
  materials, and those materials are exported without texture.
- Nodes without triangles and without children are left out (the bake makes none; checked anyway).
"""
from __future__ import annotations

import json
import logging
import os
import re
import shutil
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

import numpy as np

from ..model.appearance import Material
from ..core.atomic import umask_mode
from ..core.errors import InputError
from ..model.hierarchy import Hlod, node_geometry

log = logging.getLogger(__name__)

GLB_MAGIC, GLB_VERSION = 0x46546C67, 2
CHUNK_JSON, CHUNK_BIN = 0x4E4F534A, 0x004E4942
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
FLOAT, UNSIGNED_SHORT, UNSIGNED_INT = 5126, 5123, 5125
LINEAR, LINEAR_MIPMAP_LINEAR, REPEAT = 9729, 9987, 10497  # glTF sampler filters and wrap mode
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)

TILE_FOLDER, TEXTURE_FOLDER = "tiles", "textures"
#: The image formats of glTF 2.0 core, told by their first bytes: signature -> (mime type, suffix).
IMAGE_SIGNATURES = {b"\x89PNG\r\n\x1a\n": ("image/png", ".png"), b"\xff\xd8\xff": ("image/jpeg", ".jpg")}


@dataclass(frozen=True)
class TileImage:
    """A texture file copied into the tileset: `uri` relative to a tile's GLB, its mime type."""

    uri: str
    mime_type: str


def glb_bytes(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None, *,
              uvs: np.ndarray | None = None, colors: np.ndarray | None = None,
              face_material: np.ndarray | None = None, materials: tuple[Material, ...] = (),
              images: dict[str, TileImage] | None = None) -> bytes:
    """A GLB with one mesh of indexed triangles; positions/normals given Z up.

    positions (v,3), faces (t,3) local rows, normals (v,3) or None; uvs (v,2) in Blender's
    convention, colors (v,4) linear RGBA, face_material (t,) rows of `materials`, each or None.
    Without face_material: one primitive with glTF's default material. With it: one primitive per
    material used, triangles grouped by material (stable), sharing the vertex accessors; a
    material's texture is bound when its path is a key of `images` and uvs are given."""
    pos = np.ascontiguousarray((positions.astype(np.float64) @ Z_UP_TO_Y_UP.T).astype(np.float32))
    index_type, index_dtype = (UNSIGNED_SHORT, np.uint16) if pos.shape[0] <= 0xFFFF else (UNSIGNED_INT, np.uint32)
    parts_by_material = _group_by_material(faces, face_material)
    idx = np.ascontiguousarray(np.concatenate([f for _, f in parts_by_material]).astype(index_dtype)).ravel()
    parts = [pos.tobytes()]
    attributes = {"POSITION": 0}
    accessors = [{"bufferView": 0, "componentType": FLOAT, "count": int(pos.shape[0]), "type": "VEC3",
                  "min": pos.min(0).tolist(), "max": pos.max(0).tolist()}]
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": len(parts[0]), "target": ARRAY_BUFFER}]

    def vertex_attribute(name: str, values: np.ndarray, kind: str) -> None:
        views.append({"buffer": 0, "byteOffset": sum(map(len, parts)), "byteLength": values.nbytes,
                      "target": ARRAY_BUFFER})
        parts.append(values.tobytes())
        attributes[name] = len(accessors)
        accessors.append({"bufferView": len(views) - 1, "componentType": FLOAT, "count": int(values.shape[0]),
                          "type": kind})

    if normals is not None:
        nrm = np.ascontiguousarray((normals.astype(np.float64) @ Z_UP_TO_Y_UP.T).astype(np.float32))
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(length > 0, nrm / np.where(length > 0, length, 1), [[0.0, 1.0, 0.0]]).astype(np.float32)
        vertex_attribute("NORMAL", nrm, "VEC3")
    if uvs is not None:
        st = np.asarray(uvs, np.float32).copy()
        st[:, 1] = 1.0 - st[:, 1]  # glTF's v runs down the image, Blender's up
        vertex_attribute("TEXCOORD_0", np.ascontiguousarray(st), "VEC2")
    if colors is not None:
        vertex_attribute("COLOR_0", np.ascontiguousarray(colors, np.float32), "VEC4")
    offset = sum(map(len, parts))
    views.append({"buffer": 0, "byteOffset": offset, "byteLength": idx.nbytes, "target": ELEMENT_ARRAY_BUFFER})
    parts.append(idx.tobytes())
    primitives, document, first_index = [], {}, 0  # document: materials, textures, images, samplers
    for material, part_faces in parts_by_material:  # each material once
        accessor = {"bufferView": len(views) - 1, "componentType": index_type, "count": int(part_faces.size),
                    "type": "SCALAR"}
        if first_index:
            accessor["byteOffset"] = first_index * idx.itemsize
        first_index += int(part_faces.size)
        accessors.append(accessor)
        primitive = {"attributes": attributes, "indices": len(accessors) - 1, "mode": 4}
        if material is not None:
            primitive["material"] = _material(materials[material], document, None if uvs is None else images or {})
        primitives.append(primitive)
    binary = b"".join(parts)
    binary += b"\0" * (-len(binary) % 4)
    gltf = {"asset": {"version": "2.0", "generator": "HLOD Bake & Preview"},
            "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": primitives}],
            "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(binary)}], **document}
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<III", GLB_MAGIC, GLB_VERSION, total) + struct.pack("<II", len(text), CHUNK_JSON) + text
            + struct.pack("<II", len(binary), CHUNK_BIN) + binary)


def _group_by_material(faces: np.ndarray, face_material: np.ndarray | None) -> list[tuple[int | None, np.ndarray]]:
    """[(material row or None, faces (k,3))]: all faces as one part without materials, else one part
    per material in ascending order, triangles keeping their order within it."""
    if face_material is None:
        return [(None, np.asarray(faces))]
    face_material = np.asarray(face_material)
    order = np.argsort(face_material, kind="stable")
    used, start = np.unique(face_material[order], return_index=True)
    ends = np.append(start[1:], order.shape[0])
    return [(int(m), np.asarray(faces)[order[a:b]]) for m, a, b in zip(used, start, ends)]


def _material(material: Material, document: dict, images: dict[str, TileImage] | None) -> int:
    """Append `material` to the glTF document's materials (and its texture, image and sampler when
    `images` holds its texture); returns its index."""
    pbr = {"baseColorFactor": [float(c) for c in material.base_color], "metallicFactor": float(material.metallic),
           "roughnessFactor": float(material.roughness)}
    image = None if images is None or material.texture is None else images.get(material.texture)
    if image is not None:
        image_rows = document.setdefault("images", [])
        source = next((i for i, row in enumerate(image_rows) if row["uri"] == image.uri), None)
        if source is None:
            image_rows.append({"uri": image.uri, "mimeType": image.mime_type})
            source = len(image_rows) - 1
        document.setdefault("samplers", [{"magFilter": LINEAR, "minFilter": LINEAR_MIPMAP_LINEAR, "wrapS": REPEAT,
                                          "wrapT": REPEAT}])
        textures = document.setdefault("textures", [])
        texture = next((i for i, row in enumerate(textures) if row["source"] == source), None)
        if texture is None:
            textures.append({"sampler": 0, "source": source})
            texture = len(textures) - 1
        pbr["baseColorTexture"] = {"index": texture}
    rows = document.setdefault("materials", [])
    rows.append({"name": material.name, "pbrMetallicRoughness": pbr})
    return len(rows) - 1


def copy_textures(hlod: Hlod, folder: Path) -> tuple[dict[str, TileImage], list[str]]:
    """Copy each distinct texture of the materials the HLOD's triangles use into `folder` (made
    here), once, under a unique name. Returns ({texture path: TileImage}, warnings); a texture that
    cannot be read or is not PNG/JPEG is left out with one warning naming it and its materials."""
    if hlod.tri_material is None or not hlod.materials:
        return {}, []
    used = [hlod.materials[m] for m in np.unique(np.asarray(hlod.tri_material)).tolist()]
    users: dict[str, list[str]] = {}
    for material in used:
        if material.texture is not None:
            users.setdefault(material.texture, []).append(material.name)
    if not users:
        return {}, []
    if hlod.uvs is None:
        return {}, [f"3D Tiles export: the HLOD has no UVs; the textures of materials "
                    f"{', '.join(repr(n) for names in users.values() for n in names)} are left out"]
    images, warnings, names, by_file = {}, [], set(), {}
    for path, material_names in users.items():
        which = f"material{'s' if len(material_names) > 1 else ''} {', '.join(repr(n) for n in material_names)}"
        real = os.path.realpath(path)
        if real in by_file:  # the same file under another spelling
            images[path] = by_file[real]
            continue
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            warnings.append(f"{path}: texture of {which} cannot be read ({exc.strerror or exc}); "
                            "exported without texture")
            continue
        kind = next((v for sig, v in IMAGE_SIGNATURES.items() if data.startswith(sig)), None)
        if kind is None:
            warnings.append(f"{path}: texture of {which} is neither PNG nor JPEG (glTF 2.0 has only those); "
                            "exported without texture")
            continue
        mime_type, suffix = kind
        stem = re.sub(r"[^A-Za-z0-9_-]+", "_", Path(path).stem).strip("_") or "texture"
        name, k = f"{stem}{suffix}", 1
        while name.lower() in names:
            k += 1
            name = f"{stem}_{k}{suffix}"
        names.add(name.lower())
        folder.mkdir(exist_ok=True)
        (folder / name).write_bytes(data)
        images[path] = by_file[real] = TileImage(uri=f"../{TEXTURE_FOLDER}/{quote(name)}", mime_type=mime_type)
    for line in warnings:
        log.warning("%s", line)
    return images, warnings


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
    """Write tileset.json, tiles/<node>.glb and, for textured materials, textures/ into out_dir,
    atomically: everything is written into a temporary folder beside it and renamed into place,
    replacing an earlier export. Folders and files get the modes of ordinary ones (0o777 / 0o666
    less the umask). Returns a summary (tiles, glb files, triangles, bytes, image files, warnings)."""
    out_dir = Path(out_dir)
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        os.chmod(staging, umask_mode(0o777))  # mkdtemp makes it 0700; the export is an ordinary folder
        (staging / TILE_FOLDER).mkdir()
        images, warnings = copy_textures(hlod, staging / TEXTURE_FOLDER)
        written, tris, size = 0, 0, 0
        for node in np.flatnonzero(hlod.tri_count > 0).tolist():
            mesh = node_geometry(hlod, node)
            data = glb_bytes(mesh.positions, mesh.faces, mesh.normals, uvs=mesh.uvs, colors=mesh.colors,
                             face_material=mesh.face_material, materials=hlod.materials, images=images)
            (staging / TILE_FOLDER / f"{node}.glb").write_bytes(data)
            written, tris, size = written + 1, tris + mesh.faces.shape[0], size + len(data)
        document = tileset(hlod, lambda node: f"{TILE_FOLDER}/{node}.glb")
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
            "triangles": tris, "bytes": size, "tileset_geometric_error": document["geometricError"],
            "image_files": len(set(images.values())), "warnings": warnings}


def _count(tile: dict) -> int:
    return 1 + sum(_count(c) for c in tile.get("children", []))
