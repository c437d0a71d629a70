"""glTF buffer views and accessors read from the file itself (glTF 2.0 spec 3.6): the parts the
mesh decoder (trimesh) does not hand back, an embedded image's bytes and the per-instance
attributes of EXT_mesh_gpu_instancing.

Data form: the file's path, its JSON header and the GLB's BIN chunk (or None) in; bytes, or an
accessor as a (count, components) float64 array (normalized integers divided by their maximum,
signed ones clamped at -1) out. A reference outside the file's lists or a view outside its buffer:
InputError naming the file and the part.
"""
from __future__ import annotations

import base64
import binascii
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ..core.errors import InputError
from .gltf_codes import COMPONENT_DTYPES, ELEMENT_COMPONENTS


def buffer_view(path: Path, header: dict, binary: bytes | None, *, view, what: str) -> bytes:
    """The bytes of a buffer view (the GLB's BIN chunk, a data: URI or a file beside the .gltf)."""
    views, buffers = header.get("bufferViews", []), header.get("buffers", [])
    if not isinstance(view, int) or not 0 <= view < len(views) or not isinstance(views[view], dict):
        raise InputError(f"{path}: {what}.bufferView {view!r} is not one of the {len(views)} buffer views")
    v = views[view]
    buffer, offset, length = v.get("buffer"), v.get("byteOffset", 0), v.get("byteLength")
    if not isinstance(buffer, int) or not 0 <= buffer < len(buffers) or not isinstance(buffers[buffer], dict):
        raise InputError(f"{path}: bufferViews[{view}].buffer {buffer!r} is not one of the {len(buffers)} buffers")
    uri = buffers[buffer].get("uri")
    if uri is None:
        data = binary or b""
    elif uri.startswith("data:"):
        try:
            data = base64.b64decode(uri.partition(",")[2])
        except (binascii.Error, ValueError):
            raise InputError(f"{path}: buffers[{buffer}] has a malformed data URI") from None
    else:
        file = path.parent / unquote(uri)
        try:
            data = file.read_bytes()
        except OSError as exc:
            raise InputError(f"{path}: buffers[{buffer}] file {file}: {exc.strerror or exc}") from None
    if not isinstance(offset, int) or not isinstance(length, int) or offset < 0 or length < 0 \
            or offset + length > len(data):
        raise InputError(f"{path}: bufferViews[{view}] lies outside its buffer of {len(data)} bytes")
    return data[offset:offset + length]


def read_accessor(path: Path, header: dict, binary: bytes | None, *, index, what: str) -> np.ndarray:
    """Accessor `index` as a (count, components) float64 array (module notes); `what` names the
    reference in errors (e.g. "nodes[3].extensions.EXT_mesh_gpu_instancing.attributes.ROTATION")."""
    accessors = header.get("accessors", [])
    if not isinstance(index, int) or not 0 <= index < len(accessors) or not isinstance(accessors[index], dict):
        raise InputError(f"{path}: {what} {index!r} is not one of the {len(accessors)} accessors")
    a = accessors[index]
    where = f"{path}: accessors[{index}]"
    dtype, width = COMPONENT_DTYPES.get(a.get("componentType")), ELEMENT_COMPONENTS.get(a.get("type"))
    count = a.get("count")
    if dtype is None or width is None or not isinstance(count, int) or count < 0:
        raise InputError(f"{where}: componentType {a.get('componentType')!r}, type {a.get('type')!r} and "
                         f"count {count!r} are not an accessor this reader knows")
    if "sparse" in a:
        raise InputError(f"{where} (for {what}) is sparse, which is not read here")
    if "bufferView" not in a:
        values = np.zeros((count, width), np.float64)  # the spec: all zeros
    else:
        data = buffer_view(path, header, binary, view=a["bufferView"], what=f"accessors[{index}]")
        offset = a.get("byteOffset", 0)
        stride = header["bufferViews"][a["bufferView"]].get("byteStride") or width * dtype.itemsize
        element = width * dtype.itemsize
        if not isinstance(offset, int) or not isinstance(stride, int) or offset < 0 or stride < element \
                or (count > 0 and offset + (count - 1) * stride + element > len(data)):
            raise InputError(f"{where}: {count} elements of {element} bytes (stride {stride}) from byte {offset} "
                             f"do not fit its buffer view of {len(data)} bytes")
        raw = np.frombuffer(data, np.uint8, count=max(0, len(data) - offset), offset=offset) if count else None
        rows = (np.lib.stride_tricks.as_strided(raw, (count, element), (stride, 1)) if count
                else np.zeros((0, element), np.uint8))
        values = np.ascontiguousarray(rows).view(dtype).reshape(count, width).astype(np.float64)
        if a.get("normalized") and dtype.kind in "iu":
            values = values / float(np.iinfo(dtype).max)
            if dtype.kind == "i":
                values = np.maximum(values, -1.0)
    if not np.all(np.isfinite(values)):
        raise InputError(f"{where} (for {what}) holds NaN or infinite values")
    return values
