"""Draco-compressed tile content: the glTF extension KHR_draco_mesh_compression, encoded with DracoPy
(Google's Draco library; a command-line-only dependency, imported here only when used).

Specification: Khronos glTF extension KHR_draco_mesh_compression. Each primitive's vertices and
triangles are one Draco mesh in a buffer view of its own; the primitive's extension names that view
and, for each attribute, the Draco attribute's unique id; its accessors have no buffer view, only
the counts, types and (POSITION) bounds of what the decoder returns, which are read back here by
decoding the buffer just made (Draco reorders vertices and drops triangles with a repeated vertex).

Data form: as glb.glb_bytes (positions, normals Z up, written Y up; uvs Blender's; colors float
linear RGBA). A primitive per material part (glb._group_by_material), each with the vertices its
triangles use. Quantization (Draco's, per attribute, over the attribute's own range): positions
POSITION_BITS, normals NORMAL_BITS, UVs UV_BITS; colours as normalized uint8 (DracoPy takes uint8
colours only).
"""
from __future__ import annotations

import numpy as np

from ..core.errors import InputError
from ..io.gltf_codes import ComponentType, PrimitiveMode

#: Draco's quantization bits. Positions: a step of 1/16383 of the primitive's largest side, more than
#: a pixel only where the tile spans more than 16,383 pixels on screen (glTF-Pipeline's default is
#: 11 bits); 16 bits cost 8% more bytes on the statue square. Normals 10 bits (octahedral); UVs 12
#: bits of their range (a 4096-texel texture's texel).
POSITION_BITS, NORMAL_BITS, UV_BITS = 14, 10, 12
#: Draco's compression level (0 fastest .. 10 smallest): 7, the draco_encoder tool's default (10 was no smaller
#: on mid's tiles).
COMPRESSION_LEVEL = 7
EXTENSION = "KHR_draco_mesh_compression"
#: Draco's attribute types (draco::GeometryAttribute::Type) -> glTF attribute names.
DRACO_ATTRIBUTES = {0: "POSITION", 1: "NORMAL", 2: "COLOR_0", 3: "TEXCOORD_0"}


def require_dracopy():
    """The DracoPy module; InputError with the install line when it is not installed."""
    try:
        import DracoPy
    except ImportError:
        raise InputError("--mesh draco needs the DracoPy package (pip install DracoPy==2.2.0); "
                         "--mesh plain and quantized need nothing") from None
    return DracoPy


def draco_primitive(buffer, faces: np.ndarray, *, positions: np.ndarray, normals: np.ndarray | None,
                    uvs: np.ndarray | None, colors: np.ndarray | None) -> dict:
    """One Draco-compressed primitive of `faces` (k,3) rows of the vertex arrays (positions Y up,
    unit normals Y up, uvs with v flipped, colors float RGBA; each optional one None): its buffer
    view (no target) in `buffer` (glb._Buffer), its accessors, and the primitive without material."""
    draco = require_dracopy()
    used, local = np.unique(np.asarray(faces).ravel(), return_inverse=True)
    kwargs = {}
    if normals is not None:
        kwargs.update(normals=np.asarray(normals[used], np.float64), normal_quantization_bits=NORMAL_BITS)
    if uvs is not None:
        kwargs.update(tex_coord=np.asarray(uvs[used], np.float64), tex_coord_quantization_bits=UV_BITS)
    if colors is not None:
        kwargs["colors"] = np.rint(np.clip(np.asarray(colors[used], np.float64), 0.0, 1.0) * 255.0).astype(np.uint8)
    data = draco.encode(np.asarray(positions[used], np.float64), local.reshape(-1, 3).astype(np.uint32),
                        quantization_bits=POSITION_BITS, compression_level=COMPRESSION_LEVEL, **kwargs)
    decoded = draco.decode(data)
    view = buffer.view(data, None)
    ids, attributes = {}, {}
    for attribute in decoded.attributes:
        name = DRACO_ATTRIBUTES[attribute["attribute_type"]]
        values = np.asarray(attribute["data"])
        ids[name] = int(attribute["unique_id"])
        fields = {"componentType": int(ComponentType.FLOAT), "count": int(values.shape[0]),
                  "type": f"VEC{values.shape[1]}"}
        if name == "POSITION":
            fields.update(min=values.min(0).astype(float).tolist(), max=values.max(0).astype(float).tolist())
        elif name == "COLOR_0":
            fields.update(componentType=int(ComponentType.UNSIGNED_BYTE), normalized=True)
        attributes[name] = buffer.accessor(fields)
    vertex_count = int(np.asarray(decoded.points).shape[0])
    index_type = ComponentType.UNSIGNED_SHORT if vertex_count <= 0xFFFF else ComponentType.UNSIGNED_INT
    indices = buffer.accessor({"componentType": int(index_type), "count": int(np.asarray(decoded.faces).size),
                               "type": "SCALAR"})
    return {"attributes": dict(sorted(attributes.items())), "indices": indices, "mode": int(PrimitiveMode.TRIANGLES),
            "extensions": {EXTENSION: {"bufferView": view, "attributes": dict(sorted(ids.items()))}}}

