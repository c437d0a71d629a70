"""glTF 2.0 binary (GLB) writing: one mesh of indexed triangles per file, with its materials.

Specification: Khronos glTF 2.0 (the GLB container: a 12-byte header, a JSON chunk and a BIN chunk,
each padded to 4 bytes; accessors into buffer views of one buffer). Nothing else is needed: numpy
arrays are the buffer.

Data form: positions (v,3) and normals (v,3) given Z up (Blender's model space) and written Y up as
glTF asks, (x, y, z) -> (x, z, -y); faces (t,3) local rows; uvs (v,2) in Blender's convention
(written as (u, 1 - v): glTF's origin is the image's top-left); colors (v,4) float linear RGBA;
face_material (t,) rows of a tuple of appearance.Material.

Quantized (`mesh="quantized"`, the glTF extension KHR_mesh_quantization): POSITION as normalized int16 in
the mesh's own frame, the node's translation (the positions' box centre) and uniform scale (half its
largest side) taking it back to the tile's frame, each vertex padded to 8 bytes; NORMAL as
normalized int8, padded to 4 bytes (a uniform scale leaves normals as they are); COLOR_0 as
normalized uint16 (glTF core; linear RGBA clamped to 0..1). A position moves at most half a step,
(largest side) / 65534, a colour 1 / 131070; UVs stay float32.

Draco (`mesh="draco"`, the glTF extension KHR_draco_mesh_compression): each material part a Draco
mesh of its own (draco.py: DracoPy, a command-line-only dependency).

A WebP texture (texture_codec) is bound through the glTF extension EXT_texture_webp, required.

Compact content (quantized, draco) writes a lean JSON (_lean): no field at its default, no generator
or material names, float32 bounds as their shortest decimals; plain content's JSON is as it was.
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from ..io.gltf_codes import (
    GLB_CHUNK,
    GLB_HEADER,
    GLB_MAGIC,
    GLB_VERSION,
    Z_UP_TO_Y_UP,
    BufferViewTarget,
    ChunkType,
    ComponentType,
    PrimitiveMode,
    SamplerFilter,
    WrapMode,
)
from ..model.appearance import Material
from . import draco
from .texture_codec import WEBP_EXTENSION

GENERATOR = "HLOD Bake & Preview"
#: The glTF extension each tile content other than plain requires.
EXTENSIONS = {"quantized": "KHR_mesh_quantization", "draco": draco.EXTENSION}


@dataclass(frozen=True)
class TileImage:
    """A texture file a GLB refers to: `uri` relative to the GLB, its mime type."""

    uri: str
    mime_type: str


class _Buffer:
    """The one binary buffer of a GLB as it is built: byte parts, buffer views and accessors."""

    def __init__(self):
        self.parts: list[bytes] = []
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, data: bytes, target: BufferViewTarget | None, stride: int | None = None) -> int:
        row = {"buffer": 0, "byteOffset": sum(map(len, self.parts)), "byteLength": len(data)}
        if target is not None:  # a Draco buffer has none: no GPU buffer is made of it
            row["target"] = int(target)
        if stride is not None:
            row["byteStride"] = stride
        self.views.append(row)
        self.parts.append(data + b"\0" * (-len(data) % 4))  # the next view starts 4-byte aligned
        return len(self.views) - 1

    def accessor(self, fields: dict) -> int:
        self.accessors.append(fields)
        return len(self.accessors) - 1

    def vertex_attribute(self, values: np.ndarray, kind: str) -> int:
        """A float32 attribute (v, k) in a view of its own; its accessor index."""
        view = self.view(values.tobytes(), BufferViewTarget.ARRAY_BUFFER)
        return self.accessor({"bufferView": view, "componentType": int(ComponentType.FLOAT),
                              "count": int(values.shape[0]), "type": kind})

    def binary(self) -> bytes:
        data = b"".join(self.parts)
        return data + b"\0" * (-len(data) % 4)


def glb_bytes(positions: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None, *,
              uvs: np.ndarray | None = None, colors: np.ndarray | None = None,
              face_material: np.ndarray | None = None, materials: tuple[Material, ...] = (),
              images: dict[str, TileImage] | None = None, mesh: str = "plain") -> bytes:
    """A GLB with one mesh of indexed triangles (module docstring for the arrays; each optional one
    may be None). Without face_material: one primitive with glTF's default material. With it: one
    primitive per material used, triangles grouped by material (stable), sharing the vertex
    accessors; a material's texture is bound when its path is a key of `images` and uvs are given.
    `mesh`: "plain" (float32), "quantized" (positions and normals quantized) or "draco" (module notes)."""
    buffer = _Buffer()
    node: dict = {"mesh": 0}
    images = None if uvs is None else images or {}
    if mesh == "draco":
        primitives, document = _draco_primitives(buffer, positions, faces, normals=normals, uvs=uvs, colors=colors,
                                                 face_material=face_material, materials=materials, images=images)
    else:
        if mesh == "quantized":
            attributes = _quantized_attributes(buffer, positions, normals=normals, uvs=uvs, colors=colors, node=node)
        else:
            attributes = _vertex_attributes(buffer, positions, normals=normals, uvs=uvs, colors=colors)
        primitives, document = _primitives(buffer, faces, attributes=attributes, vertex_count=positions.shape[0],
                                           face_material=face_material, materials=materials, images=images)
    binary = buffer.binary()
    gltf = {"asset": {"version": "2.0", "generator": GENERATOR},
            "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [node],
            "meshes": [{"primitives": primitives}],
            "accessors": buffer.accessors, "bufferViews": buffer.views, "buffers": [{"byteLength": len(binary)}],
            **document}
    required = ([EXTENSIONS[mesh]] if mesh in EXTENSIONS else []) + sorted(
        {name for row in document.get("textures", []) for name in row.get("extensions", {})})
    if required:
        gltf["extensionsUsed"] = gltf["extensionsRequired"] = required
    if mesh != "plain":
        _lean(gltf)
    return container(json.dumps(gltf, separators=(",", ":")).encode(), binary)


#: Fields a compact GLB leaves out at their glTF 2.0 defaults (the schema's "default"), by the
#: document's array holding them; a material's pbrMetallicRoughness is checked as its own row.
DEFAULTS = {"bufferViews": {"byteOffset": 0}, "accessors": {"byteOffset": 0, "normalized": False},
            "samplers": {"wrapS": int(WrapMode.REPEAT), "wrapT": int(WrapMode.REPEAT)},
            "materials": {"alphaMode": "OPAQUE", "alphaCutoff": 0.5, "doubleSided": False},
            "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 1.0,
                                     "roughnessFactor": 1.0},
            "primitives": {"mode": int(PrimitiveMode.TRIANGLES)}}


def _lean(gltf: dict) -> None:
    """A compact GLB's JSON, in place: no field at its default (DEFAULTS), no generator and no material
    names (readers draw nothing of them), and a float accessor's bounds as the shortest decimals that
    read back as the same float32 (a whole number without ".0"). Every reader gets the same glTF."""
    gltf["asset"].pop("generator", None)
    rows = {name: gltf.get(name, []) for name in DEFAULTS}
    rows["primitives"] = [p for m in gltf["meshes"] for p in m["primitives"]]
    rows["pbrMetallicRoughness"] = [m["pbrMetallicRoughness"] for m in rows["materials"] if "pbrMetallicRoughness" in m]
    for name, row in ((name, row) for name, table in rows.items() for row in table):
        for key, default in DEFAULTS[name].items():
            if key in row and row[key] == default:
                del row[key]
    for row in rows["materials"]:
        row.pop("name", None)
    for row in gltf["accessors"]:
        if row["componentType"] == ComponentType.FLOAT:
            row.update({key: _float32_decimals(row[key]) for key in ("min", "max") if key in row})


def _float32_decimals(values: list[float]) -> list[float | int]:
    """`values` as float32's shortest round-trip decimals (numpy's), whole ones as ints."""
    out = [float(str(v)) for v in np.asarray(values, np.float32)]
    return [int(v) if v.is_integer() else v for v in out]


def triangle_count(data: bytes) -> int:
    """The triangles a GLB written here holds: its primitives' index counts / 3, from its JSON chunk."""
    json_len = GLB_CHUNK.unpack_from(data, GLB_HEADER.size)[0]
    gltf = json.loads(data[GLB_HEADER.size + GLB_CHUNK.size:GLB_HEADER.size + GLB_CHUNK.size + json_len])
    return sum(gltf["accessors"][p["indices"]]["count"] for p in gltf["meshes"][0]["primitives"]) // 3


def container(json_chunk: bytes, binary: bytes) -> bytes:
    """The GLB file of a JSON chunk (padded here with spaces) and a BIN chunk (4-byte aligned)."""
    json_chunk += b" " * (-len(json_chunk) % 4)
    total = GLB_HEADER.size + GLB_CHUNK.size + len(json_chunk) + GLB_CHUNK.size + len(binary)
    return (GLB_HEADER.pack(GLB_MAGIC, GLB_VERSION, total)
            + GLB_CHUNK.pack(len(json_chunk), ChunkType.JSON) + json_chunk
            + GLB_CHUNK.pack(len(binary), ChunkType.BIN) + binary)


def _vertex_attributes(buffer: _Buffer, positions: np.ndarray, *, normals, uvs, colors) -> dict[str, int]:
    """POSITION (with its bounds) and, where given, NORMAL (unit length; zero ones become +Y),
    TEXCOORD_0 and COLOR_0, each in its own view; attribute name -> accessor index."""
    pos = np.ascontiguousarray((positions.astype(np.float64) @ Z_UP_TO_Y_UP.T).astype(np.float32))
    view = buffer.view(pos.tobytes(), BufferViewTarget.ARRAY_BUFFER)
    attributes = {"POSITION": buffer.accessor({"bufferView": view, "componentType": int(ComponentType.FLOAT),
                                               "count": int(pos.shape[0]), "type": "VEC3",
                                               "min": pos.min(0).tolist(), "max": pos.max(0).tolist()})}
    if normals is not None:
        attributes["NORMAL"] = buffer.vertex_attribute(_unit_normals(normals, np.float32), "VEC3")
    attributes.update(_uv_colour_attributes(buffer, uvs, colors))
    return attributes


def _unit_normals(normals: np.ndarray, dtype) -> np.ndarray:
    """(v,3) normals Y up, unit length in `dtype` arithmetic; zero ones become +Y."""
    nrm = np.ascontiguousarray((normals.astype(np.float64) @ Z_UP_TO_Y_UP.T).astype(dtype))
    length = np.linalg.norm(nrm, axis=1, keepdims=True)
    return np.where(length > 0, nrm / np.where(length > 0, length, 1), [[0.0, 1.0, 0.0]]).astype(dtype)


def _uv_colour_attributes(buffer: _Buffer, uvs, colors) -> dict[str, int]:
    """TEXCOORD_0 (v flipped) and COLOR_0 where given, float32, each in its own view."""
    attributes = {}
    if uvs is not None:
        st = np.asarray(uvs, np.float32).copy()
        st[:, 1] = 1.0 - st[:, 1]  # glTF's v runs down the image, Blender's up
        attributes["TEXCOORD_0"] = buffer.vertex_attribute(np.ascontiguousarray(st), "VEC2")
    if colors is not None:
        attributes["COLOR_0"] = buffer.vertex_attribute(np.ascontiguousarray(colors, np.float32), "VEC4")
    return attributes


def _quantized_attributes(buffer: _Buffer, positions: np.ndarray, *, normals, uvs, colors,
                          node: dict) -> dict[str, int]:
    """As _vertex_attributes, POSITION, NORMAL and COLOR_0 quantized (module notes); the node's translation
    and scale set in `node`."""
    pos = np.asarray(positions, np.float64) @ Z_UP_TO_Y_UP.T
    lo, hi = pos.min(0), pos.max(0)
    centre, half = 0.5 * (lo + hi), 0.5 * float((hi - lo).max())
    half = half if half > 0 else 1.0
    padded = np.zeros((pos.shape[0], 4), np.int16)
    padded[:, :3] = np.clip(np.rint((pos - centre) / half * 32767.0), -32767, 32767)
    view = buffer.view(padded.tobytes(), BufferViewTarget.ARRAY_BUFFER, stride=8)
    attributes = {"POSITION": buffer.accessor({"bufferView": view, "componentType": int(ComponentType.SHORT),
                                               "normalized": True, "count": int(pos.shape[0]), "type": "VEC3",
                                               "min": padded[:, :3].min(0).tolist(),
                                               "max": padded[:, :3].max(0).tolist()})}
    node.update(translation=centre.tolist(), scale=[half] * 3)
    if normals is not None:
        nrm = _unit_normals(normals, np.float64)
        packed = np.zeros((nrm.shape[0], 4), np.int8)
        packed[:, :3] = np.clip(np.rint(nrm * 127.0), -127, 127)
        view = buffer.view(packed.tobytes(), BufferViewTarget.ARRAY_BUFFER, stride=4)
        attributes["NORMAL"] = buffer.accessor({"bufferView": view, "componentType": int(ComponentType.BYTE),
                                                "normalized": True, "count": int(nrm.shape[0]), "type": "VEC3"})
    attributes.update(_uv_colour_attributes(buffer, uvs, None))
    if colors is not None:
        rgba = np.rint(np.clip(np.asarray(colors, np.float64), 0.0, 1.0) * 65535.0).astype(np.uint16)
        view = buffer.view(np.ascontiguousarray(rgba).tobytes(), BufferViewTarget.ARRAY_BUFFER)
        attributes["COLOR_0"] = buffer.accessor({"bufferView": view, "componentType": int(ComponentType.UNSIGNED_SHORT),
                                                 "normalized": True, "count": int(rgba.shape[0]), "type": "VEC4"})
    return attributes


def _primitives(buffer: _Buffer, faces: np.ndarray, *, attributes: dict[str, int], vertex_count: int,
                face_material, materials: tuple[Material, ...], images: dict[str, TileImage] | None):
    """The index buffer (uint16 when the vertices allow, else uint32) in one view, and a primitive per
    material part, each an accessor on its range of that view. Returns (primitives, the document's
    materials, textures, images and samplers)."""
    index_type, index_dtype = ((ComponentType.UNSIGNED_SHORT, np.uint16) if vertex_count <= 0xFFFF
                               else (ComponentType.UNSIGNED_INT, np.uint32))
    parts_by_material = _group_by_material(faces, face_material)
    idx = np.ascontiguousarray(np.concatenate([f for _, f in parts_by_material]).astype(index_dtype)).ravel()
    view = buffer.view(idx.tobytes(), BufferViewTarget.ELEMENT_ARRAY_BUFFER)
    primitives, document, first_index = [], {}, 0
    for material, part_faces in parts_by_material:  # each material once
        accessor = {"bufferView": view, "componentType": int(index_type), "count": int(part_faces.size),
                    "type": "SCALAR"}
        if first_index:
            accessor["byteOffset"] = first_index * idx.itemsize
        first_index += int(part_faces.size)
        primitive = {"attributes": attributes, "indices": buffer.accessor(accessor),
                     "mode": int(PrimitiveMode.TRIANGLES)}
        if material is not None:
            primitive["material"] = _material(materials[material], document, images)
        primitives.append(primitive)
    return primitives, document


def _draco_primitives(buffer: _Buffer, positions: np.ndarray, faces: np.ndarray, *, normals, uvs, colors,
                      face_material, materials: tuple[Material, ...], images: dict[str, TileImage] | None):
    """A Draco-compressed primitive per material part (draco.draco_primitive: each with the vertices
    its triangles use). Returns (primitives, the document's materials, textures, images, samplers)."""
    st = None
    if uvs is not None:
        st = np.asarray(uvs, np.float64).copy()
        st[:, 1] = 1.0 - st[:, 1]  # glTF's v runs down the image, Blender's up
    arrays = {"positions": np.asarray(positions, np.float64) @ Z_UP_TO_Y_UP.T, "uvs": st, "colors": colors,
              "normals": None if normals is None else _unit_normals(normals, np.float64)}
    primitives, document = [], {}
    for material, part_faces in _group_by_material(faces, face_material):
        primitive = draco.draco_primitive(buffer, part_faces, **arrays)
        if material is not None:
            primitive["material"] = _material(materials[material], document, images)
        primitives.append(primitive)
    return primitives, document


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
    """Append `material` to the glTF document's materials (pbrMetallicRoughness: base colour factor,
    metallic, roughness, and baseColorTexture when `images` holds its texture); returns its index."""
    pbr = {"baseColorFactor": [float(c) for c in material.base_color], "metallicFactor": float(material.metallic),
           "roughnessFactor": float(material.roughness)}
    image = None if images is None or material.texture is None else images.get(material.texture)
    if image is not None:
        pbr["baseColorTexture"] = {"index": _texture(image, document)}
    row = {"name": material.name, "pbrMetallicRoughness": pbr}
    if material.alpha_mode != "OPAQUE":
        row["alphaMode"] = material.alpha_mode
        if material.alpha_mode == "MASK":
            row["alphaCutoff"] = float(material.alpha_cutoff)
    if material.double_sided:  # as the preview and Blender draw it (no backface culling)
        row["doubleSided"] = True
    rows = document.setdefault("materials", [])
    rows.append(row)
    return len(rows) - 1


def _texture(image: TileImage, document: dict) -> int:
    """The document's texture of `image` (its image row, the one sampler and the texture made on
    first use); its index."""
    image_rows = document.setdefault("images", [])
    source = next((i for i, row in enumerate(image_rows) if row["uri"] == image.uri), None)
    if source is None:
        image_rows.append({"uri": image.uri, "mimeType": image.mime_type})
        source = len(image_rows) - 1
    document.setdefault("samplers", [{"magFilter": int(SamplerFilter.LINEAR),
                                      "minFilter": int(SamplerFilter.LINEAR_MIPMAP_LINEAR),
                                      "wrapS": int(WrapMode.REPEAT), "wrapT": int(WrapMode.REPEAT)}])
    textures = document.setdefault("textures", [])
    row = ({"sampler": 0, "extensions": {WEBP_EXTENSION: {"source": source}}} if image.mime_type == "image/webp"
           else {"sampler": 0, "source": source})  # WebP: EXT_texture_webp, required, no fallback image
    if row not in textures:
        textures.append(row)
    return textures.index(row)
