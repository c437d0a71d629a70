"""glTF 2.0 codes, named once (Khronos glTF 2.0 specification; as Blender's glTF add-on names
them in its constants module): the GLB container, accessor component types and element
types, buffer view targets, primitive modes, sampler codes, and the axis change between glTF (+Y up)
and Blender and the bake (+Z up). The reader (io.gltf, io.gltf_accessors) and the writer
(export.glb) both take them from here.
"""
from __future__ import annotations

import struct
from enum import IntEnum

import numpy as np

#: The GLB header's magic ("glTF", read as the little-endian uint32 0x46546C67) and the version written.
GLB_MAGIC = b"glTF"
GLB_VERSION = 2
#: GLB header: magic, version, total length in bytes; then per chunk: length in bytes, chunk type.
GLB_HEADER = struct.Struct("<4sII")
GLB_CHUNK = struct.Struct("<II")


class ChunkType(IntEnum):
    """GLB chunk types (the ASCII of "JSON" and "BIN\\0", little-endian)."""

    JSON = 0x4E4F534A
    BIN = 0x004E4942


class ComponentType(IntEnum):
    """accessor.componentType."""

    BYTE = 5120
    UNSIGNED_BYTE = 5121
    SHORT = 5122
    UNSIGNED_SHORT = 5123
    UNSIGNED_INT = 5125
    FLOAT = 5126


#: accessor.componentType -> numpy type (little-endian, as glTF stores them).
COMPONENT_DTYPES = {ComponentType.BYTE: np.dtype("<i1"), ComponentType.UNSIGNED_BYTE: np.dtype("<u1"),
                    ComponentType.SHORT: np.dtype("<i2"), ComponentType.UNSIGNED_SHORT: np.dtype("<u2"),
                    ComponentType.UNSIGNED_INT: np.dtype("<u4"), ComponentType.FLOAT: np.dtype("<f4")}
#: accessor.type -> components per element.
ELEMENT_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


class BufferViewTarget(IntEnum):
    """bufferView.target."""

    ARRAY_BUFFER = 34962
    ELEMENT_ARRAY_BUFFER = 34963


class PrimitiveMode(IntEnum):
    """mesh.primitive.mode (TRIANGLES when absent)."""

    POINTS = 0
    LINES = 1
    LINE_LOOP = 2
    LINE_STRIP = 3
    TRIANGLES = 4
    TRIANGLE_STRIP = 5
    TRIANGLE_FAN = 6


class SamplerFilter(IntEnum):
    """sampler.magFilter / minFilter."""

    LINEAR = 9729
    LINEAR_MIPMAP_LINEAR = 9987


class WrapMode(IntEnum):
    """sampler.wrapS / wrapT."""

    REPEAT = 10497


#: glTF's +Y-up axes to Blender's (and the bake's) +Z-up ones, as Blender's glTF importer turns them:
#: (x, y, z) -> (x, -z, y), a rotation (no mirror). 4x4, for world matrices.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
#: Its inverse, for positions and normals written to glTF: (x, y, z) -> (x, z, -y). 3x3.
Z_UP_TO_Y_UP = Y_UP_TO_Z_UP[:3, :3].T.copy()
