"""The bake cache's files (cache.py): one container for node entries and result entries, read
without pickle and checked before anything in it is used.

Data form: preamble (magic, CACHE_VERSION, reserved 0, payload length, blake2b-256 digest of the
payload), then the payload: a JSON header (the key, the kind, the arrays' table, extra entries)
and the raw little-endian arrays. A node entry holds a LOD (positions, faces, normals, attribute
rows), its error, SUMMARY_FIELDS and, in a bake with proxy materials, the node's proxy
(cache_proxies.py); a result entry an Hlod's arrays, the meta.DERIVED_META entries and, in a
bake with proxy materials, every texture it wrote (cache_proxies.py). An entry that fails a check
raises `CorruptEntry`, whose message says why.
"""
from __future__ import annotations

import hashlib
import json
import struct

import numpy as np

from ...core.errors import FormatError
from ...io import hlod_file
from ...model.hierarchy import NODE_ARRAYS, Hlod
from ..decimate.simplify import NodeLod
from ..meta import DERIVED_META

#: Version of the entry format and of the keys' recipe; any change to either bumps it.
CACHE_VERSION = 4
MAGIC = b"HLODCACH"
#: Bytes of a key and of a digest (blake2b).
KEY_BYTES = 32
#: magic, CACHE_VERSION, reserved (0), payload length, blake2b-256 digest of the payload.
_PREAMBLE = struct.Struct("<8sIIQ32s")
_HEADER_LENGTH = struct.Struct("<I")
_MAX_HEADER_BYTES = 1024 * 1024

#: NodeLod fields the bake log reads, stored per entry as one int64 each.
SUMMARY_FIELDS = ("decimated", "input_tris", "kept_in_place", "zero_area", "uv_seams_crossed", "seam_kept_tris",
                  "island_spanning_faces", "locked_vertices", "open_boundaries_freed", "pieces", "pruned_pieces",
                  "pruned_tris")
_FLAG_FIELDS = ("decimated", "kept_in_place", "zero_area", "uv_seams_crossed", "open_boundaries_freed")
#: The Hlod arrays of a result entry (the appearance ones only when the bake has them).
_RESULT_ARRAYS = (*NODE_ARRAYS, "origin", "positions", "indices", "normals", "uvs", "colors", "tri_material")

class CorruptEntry(Exception):
    """An entry that must not be used; the message says why."""


def pack(key: bytes, kind: str, arrays: dict[str, np.ndarray], *, extra: dict | None = None) -> bytes:
    """The bytes of an entry of `kind` ("node", "result") under `key`: its arrays and extra entries
    (module docstring's data form); `unpack` reads it back."""
    table, offset = [], 0
    arrays = {name: np.ascontiguousarray(a, a.dtype.newbyteorder("<")) for name, a in arrays.items()}
    for name, a in arrays.items():
        table.append([name, a.dtype.str, list(a.shape), offset])
        offset += a.nbytes
    header = json.dumps({"key": key.hex(), "kind": kind, "arrays": table, "extra": extra or {}}).encode()
    payload = b"".join([_HEADER_LENGTH.pack(len(header)), header, *(a.tobytes() for a in arrays.values())])
    digest = hashlib.blake2b(payload, digest_size=KEY_BYTES).digest()
    return _PREAMBLE.pack(MAGIC, CACHE_VERSION, 0, len(payload), digest) + payload


def unpack(data: bytes, key: bytes, kind: str) -> tuple[dict, dict[str, np.ndarray]]:
    """(extra, arrays) of an entry that passes the preamble, digest, key, kind and table checks."""
    if len(data) < _PREAMBLE.size:
        raise CorruptEntry(f"truncated ({len(data)} bytes)")
    magic, version, _, length, digest = _PREAMBLE.unpack_from(data)
    if magic != MAGIC:
        raise CorruptEntry("not a bake cache entry (bad magic)")
    if version != CACHE_VERSION:
        raise CorruptEntry(f"cache format {version}, this bake reads {CACHE_VERSION}")
    payload = memoryview(data)[_PREAMBLE.size:]
    if length != len(payload):
        raise CorruptEntry(f"payload of {len(payload)} bytes, the entry says {length}")
    if hashlib.blake2b(payload, digest_size=KEY_BYTES).digest() != digest:
        raise CorruptEntry("payload digest mismatch")
    (header_bytes,) = _HEADER_LENGTH.unpack_from(payload)
    if header_bytes > min(_MAX_HEADER_BYTES, len(payload) - _HEADER_LENGTH.size):
        raise CorruptEntry("bad header length")
    try:
        header = json.loads(bytes(payload[_HEADER_LENGTH.size:_HEADER_LENGTH.size + header_bytes]))
        if header["key"] != key.hex() or header["kind"] != kind:
            raise CorruptEntry(f"the entry records another key or kind ({header['kind']})")
        table = [(str(name), np.dtype(str(dtype)), tuple(int(x) for x in shape), int(offset))
                 for name, dtype, shape, offset in header["arrays"]]
        extra = dict(header["extra"])
    except (ValueError, KeyError, TypeError) as exc:
        raise CorruptEntry(f"bad header ({exc})") from None
    base = _HEADER_LENGTH.size + header_bytes
    arrays = {}
    for name, dtype, shape, offset in table:
        if dtype.hasobject or any(x < 0 for x in shape):
            raise CorruptEntry(f"{name}: dtype {dtype} shape {list(shape)}")
        count = int(np.prod(shape, dtype=object))
        if offset < 0 or base + offset + count * dtype.itemsize > len(payload):
            raise CorruptEntry(f"{name}: outside the entry")
        arrays[name] = np.frombuffer(payload, dtype, count, base + offset).reshape(shape).copy()
    return extra, arrays


def _expect(arrays: dict[str, np.ndarray], name: str, *, dtype: str, shape: tuple) -> np.ndarray:
    """arrays[name], checked: dtype, and shape with None for any length."""
    a = arrays.get(name)
    if a is None or a.dtype != np.dtype(dtype) or len(a.shape) != len(shape) \
            or any(want is not None and got != want for got, want in zip(a.shape, shape)):
        got = "absent" if a is None else f"{a.dtype}{list(a.shape)}"
        raise CorruptEntry(f"{name}: {got}, expected {np.dtype(dtype)}{list(shape)}")
    return a


# --- node entries ---------------------------------------------------------------------------------

def node_entry_bytes(key: bytes, lod: NodeLod, error: float, extra: dict | None = None,
                     more: dict | None = None) -> bytes:
    """The bytes of a node entry under `key`: the LOD and its error (model units); extra, more: the
    header's extra entries and arrays of its proxy material (cache_proxies.py)."""
    arrays = {"positions": np.asarray(lod.positions, "<f4"), "faces": np.asarray(lod.faces, "<i4"),
              "hausdorff": np.array([error], "<f8"),
              "summary": np.array([int(getattr(lod, name)) for name in SUMMARY_FIELDS], "<i8")}
    if lod.normals is not None:
        arrays["normals"] = np.asarray(lod.normals, "<f4")
    if lod.attributes is not None:
        arrays["attributes"] = np.asarray(lod.attributes, "<f4")
    return pack(key, "node", {**arrays, **(more or {})}, extra=extra)


def node_entry(extra: dict, arrays: dict, *, with_normals: bool, row_width: int) -> tuple[NodeLod, float]:
    """(LOD, error) of an unpacked node entry, checked against what the bake carries (normals,
    row_width attribute columns); CorruptEntry otherwise."""
    expected = {"positions", "faces", "hausdorff", "summary"} | ({"normals"} if with_normals else set()) \
        | ({"attributes"} if row_width else set())
    if set(arrays) - {"proxy_png"} != expected:
        raise CorruptEntry(f"arrays {sorted(arrays)}, expected {sorted(expected)}")
    positions = _expect(arrays, "positions", dtype="<f4", shape=(None, 3))
    k = positions.shape[0]
    faces = _expect(arrays, "faces", dtype="<i4", shape=(None, 3))
    normals = _expect(arrays, "normals", dtype="<f4", shape=(k, 3)) if with_normals else None
    rows = _expect(arrays, "attributes", dtype="<f4", shape=(k, row_width)) if row_width else None
    error = float(_expect(arrays, "hausdorff", dtype="<f8", shape=(1,))[0])
    summary_row = _expect(arrays, "summary", dtype="<i8", shape=(len(SUMMARY_FIELDS),))
    summary = dict(zip(SUMMARY_FIELDS, (int(v) for v in summary_row)))
    if k == 0 or faces.shape[0] == 0:
        raise CorruptEntry("empty LOD")
    if faces.min() < 0 or faces.max() >= k:
        raise CorruptEntry("a face refers to a vertex outside the LOD")
    if not np.all(np.isfinite(positions)):
        raise CorruptEntry("non-finite positions")
    if error < 0 or np.isinf(error):  # NaN is allowed: pymeshlab gave no distance (bake/assemble.py bounds it)
        raise CorruptEntry(f"bad error {error}")
    if any(summary[name] not in (0, 1) for name in _FLAG_FIELDS) or any(v < 0 for v in summary.values()):
        raise CorruptEntry(f"bad summary {summary}")
    lod = NodeLod(positions=positions, faces=faces, normals=normals, attributes=rows,
                  **{name: bool(summary[name]) if name in _FLAG_FIELDS else summary[name] for name in SUMMARY_FIELDS})
    return lod, error


# --- result entries -------------------------------------------------------------------------------

def result_entry_bytes(key: bytes, hlod: Hlod, meta: dict, *, node_keys: list[bytes], extra: dict | None = None,
                       more: dict | None = None) -> bytes:
    """The bytes of a result entry under `key`: the Hlod's arrays, meta's DERIVED_META entries and
    the keys of the node entries the bake used (a whole result taken from the cache keeps them);
    extra, more: the header's extra entries and arrays of its proxy materials (cache_proxies.py)."""
    arrays = {name: getattr(hlod, name) for name in _RESULT_ARRAYS if getattr(hlod, name) is not None}
    entries = {name: meta[name] for name in DERIVED_META if name in meta}
    entries["node_keys"] = [k.hex() for k in node_keys]
    return pack(key, "result", {**arrays, **(more or {})}, extra={**entries, **(extra or {})})


def result_entry(extra: dict, arrays: dict, *, materials: tuple, with_normals: bool,
                 has_rows: bool) -> tuple[Hlod, dict, list[bytes]]:
    """(Hlod with `materials`, its DERIVED_META entries, the node entries' keys) of an unpacked
    result entry, validated as a .hlod file is; CorruptEntry otherwise."""
    required = set(NODE_ARRAYS) | {"origin", "positions", "indices"} | ({"normals"} if with_normals else set())
    if not required <= set(arrays) <= set(_RESULT_ARRAYS) or (not has_rows and set(arrays) - required):
        raise CorruptEntry(f"arrays {sorted(arrays)}")
    try:
        hlod = Hlod(**arrays, materials=tuple(materials))
        hlod_file.validate(hlod, source="bake cache result")
    except (FormatError, TypeError, ValueError) as exc:
        raise CorruptEntry(str(exc)) from None
    for name, kind in DERIVED_META.items():
        value = extra.get(name)
        if name not in extra and name == "uv_seams_crossed_nodes" and not has_rows:
            continue
        if not isinstance(value, kind) or (kind is int and value < 0) \
                or (kind is list and not all(isinstance(line, str) for line in value)):
            raise CorruptEntry(f"meta entry {name!r} is {value!r}")
    try:
        node_keys = [bytes.fromhex(k) for k in extra["node_keys"]]
    except (KeyError, TypeError, ValueError):
        raise CorruptEntry("node_keys: absent or not hex") from None
    if any(len(k) != KEY_BYTES for k in node_keys):
        raise CorruptEntry("node_keys: a key of the wrong length")
    return hlod, {name: extra[name] for name in DERIVED_META if name in extra}, node_keys
