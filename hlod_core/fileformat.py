"""Native `.hlod` container (DESIGN §3): versioned, no pickle, validated on load, atomic writes.

Layout (all integers little-endian):

    offset 0   8 bytes   magic b"HLODBAKE"
    offset 8   u32       format version (FORMAT_VERSION)
    offset 12  u32       0 (reserved)
    offset 16  u64       header length in bytes (H)
    offset 24  H bytes   UTF-8 JSON header: {"meta": {...}, "arrays": {name: {"dtype": "<f8",
                         "shape": [...], "offset": bytes from file start, "nbytes": ...}}}
    then       arrays, raw C-order, each starting on a 64-byte boundary

Arrays are memory-mapped on load (numpy.memmap, read-only), so opening a ten-million-triangle file
costs the header parse plus the range checks below, not a read of the geometry.
Every array's dtype and shape is checked against the node count; ranges (child/parent links,
triangle and vertex ranges, index bounds, finite bounds, non-negative errors) are checked too.
"""
from __future__ import annotations

import json
import os
import struct
import tempfile
from pathlib import Path

import numpy as np

from .errors import FormatError
from .hierarchy import NODE_ARRAYS, Hlod, segment_ranges

MAGIC = b"HLODBAKE"
FORMAT_VERSION = 1
_PREAMBLE = struct.Struct("<8sIIQ")
_ALIGN = 64
_MAX_HEADER_BYTES = 64 * 1024 * 1024

_GEOMETRY_ARRAYS: dict[str, tuple[str, tuple[int | None, ...]]] = {
    "origin": ("<f8", (3,)),
    "positions": ("<f4", (None, 3)),
    "indices": ("<u4", (None, 3)),
    "normals": ("<f4", (None, 3)),  # optional
}


def _aligned(n: int) -> int:
    return (n + _ALIGN - 1) // _ALIGN * _ALIGN


def save(hlod: Hlod, path: str | os.PathLike) -> Path:
    """Write `hlod` to `path` atomically (temp file in the same folder, fsync, rename)."""
    path = Path(path)
    arrays: dict[str, np.ndarray] = dict(hlod.node_arrays())
    arrays["origin"] = hlod.origin
    arrays["positions"] = hlod.positions
    arrays["indices"] = hlod.indices
    if hlod.normals is not None:
        arrays["normals"] = hlod.normals
    wanted = {**{k: v[0] for k, v in NODE_ARRAYS.items()}, **{k: v[0] for k, v in _GEOMETRY_ARRAYS.items()}}
    arrays = {k: np.ascontiguousarray(v, dtype=np.dtype(wanted[k])) for k, v in arrays.items()}

    table = {}
    header = b""
    # The header size depends on the offsets it records: iterate until the layout is stable.
    data_start = 0
    for _ in range(4):
        cursor = _aligned(_PREAMBLE.size + len(header)) if data_start == 0 else data_start
        table = {}
        for name, arr in arrays.items():
            table[name] = {"dtype": arr.dtype.str, "shape": list(arr.shape), "offset": cursor, "nbytes": arr.nbytes}
            cursor = _aligned(cursor + arr.nbytes)
        header = json.dumps({"meta": hlod.meta, "arrays": table}, sort_keys=True).encode("utf-8")
        needed = _aligned(_PREAMBLE.size + len(header))
        if needed == data_start:
            break
        data_start = needed
    else:
        raise RuntimeError("hlod: header layout did not converge")  # offsets only ever grow by digits

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(_PREAMBLE.pack(MAGIC, FORMAT_VERSION, 0, len(header)))
            f.write(header)
            for name, arr in arrays.items():
                f.seek(table[name]["offset"])
                f.write(memoryview(arr).cast("B"))
            f.truncate(max(e["offset"] + e["nbytes"] for e in table.values()))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
        raise
    return path


def load(path: str | os.PathLike, *, mmap: bool = True) -> Hlod:
    """Open a .hlod file. Raises FormatError naming the file and what is wrong."""
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            pre = f.read(_PREAMBLE.size)
            if len(pre) < _PREAMBLE.size or pre[:8] != MAGIC:
                raise FormatError(f"{path}: not a .hlod file (missing HLODBAKE signature)")
            _, version, _, header_len = _PREAMBLE.unpack(pre)
            if version != FORMAT_VERSION:
                raise FormatError(f"{path}: .hlod format version {version} is not supported "
                                  f"(this build reads version {FORMAT_VERSION})")
            if header_len > min(_MAX_HEADER_BYTES, size - _PREAMBLE.size):
                raise FormatError(f"{path}: truncated .hlod file (header runs past the end of the file)")
            raw = f.read(header_len)
    except OSError as exc:
        raise FormatError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    try:
        header = json.loads(raw.decode("utf-8"))
        table = header["arrays"]
        meta = header["meta"]
    except (ValueError, KeyError, TypeError) as exc:
        raise FormatError(f"{path}: corrupt .hlod header ({exc})") from exc

    arrays = {name: _map_array(path, size, name, table, mmap) for name in table}
    missing = [n for n in list(NODE_ARRAYS) + ["origin", "positions", "indices"] if n not in arrays]
    if missing:
        raise FormatError(f"{path}: .hlod file lacks arrays {', '.join(missing)}")
    hlod = Hlod(**{name: arrays[name] for name in NODE_ARRAYS},
                origin=np.array(arrays["origin"]), positions=arrays["positions"],
                indices=arrays["indices"], normals=arrays.get("normals"), meta=meta)
    validate(hlod, source=str(path))
    return hlod


def _map_array(path: Path, size: int, name: str, table: dict, mmap: bool) -> np.ndarray:
    entry = table[name]
    try:
        dtype = np.dtype(entry["dtype"])
        shape = tuple(int(s) for s in entry["shape"])
        offset, nbytes = int(entry["offset"]), int(entry["nbytes"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"{path}: corrupt entry for array '{name}' ({exc})") from exc
    if dtype.hasobject or any(s < 0 for s in shape) or nbytes != dtype.itemsize * int(np.prod(shape)):
        raise FormatError(f"{path}: array '{name}' has an inconsistent dtype/shape/size")
    if offset < _PREAMBLE.size or offset + nbytes > size:
        raise FormatError(f"{path}: truncated .hlod file (array '{name}' runs past the end of the file)")
    if nbytes == 0:
        return np.zeros(shape, dtype)
    if mmap:
        return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape)
    with open(path, "rb") as f:
        f.seek(offset)
        return np.frombuffer(f.read(nbytes), dtype=dtype).reshape(shape)


def validate(hlod: Hlod, *, source: str = "HLOD") -> None:
    """Check every array's dtype, shape and ranges; raise FormatError naming `source`.

    Cheap enough to run on every load (O(n) over nodes, one max over the index buffer).
    """
    def bad(what: str) -> FormatError:
        return FormatError(f"{source}: invalid .hlod data: {what}")

    n = hlod.parent.shape[0] if hlod.parent.ndim == 1 else -1
    if n <= 0:
        raise bad("the node table is empty or not one-dimensional")
    for name, (dtype, trailing) in NODE_ARRAYS.items():
        arr = getattr(hlod, name)
        if arr.dtype != np.dtype(dtype) or arr.shape != (n, *trailing):
            raise bad(f"array '{name}' is {arr.dtype}{list(arr.shape)}, expected {np.dtype(dtype)}{[n, *trailing]}")
    for name, (dtype, shape) in _GEOMETRY_ARRAYS.items():
        arr = getattr(hlod, name)
        if arr is None and name == "normals":
            continue
        if arr.dtype != np.dtype(dtype) or len(arr.shape) != len(shape) or any(
                want is not None and got != want for got, want in zip(arr.shape, shape)):
            raise bad(f"array '{name}' is {arr.dtype}{list(arr.shape)}, expected {np.dtype(dtype)}{list(shape)}")
    v, t = hlod.positions.shape[0], hlod.indices.shape[0]
    if hlod.normals is not None and hlod.normals.shape[0] != v:
        raise bad("normals and positions differ in length")

    parent, co, cc = hlod.parent, hlod.child_offset, hlod.child_count
    if parent[0] != -1 or hlod.depth[0] != 0 or np.any(parent[1:] < 0) or np.any(parent >= n):
        raise bad("parent links out of range")
    inner = cc > 0
    if np.any(cc < 0) or np.any(co[~inner] != -1) or np.any(co[inner] < 1) or np.any(co[inner] + cc[inner] > n):
        raise bad("child ranges out of range")
    if int(cc.sum()) != n - 1:
        raise bad("child counts do not add up to the node count")
    owner = np.repeat(np.flatnonzero(inner), cc[inner])
    rows = segment_ranges(co[inner], cc[inner])  # every child row, grouped by parent
    if rows.shape[0] != n - 1 or np.any(np.sort(rows) != np.arange(1, n)) or np.any(parent[rows] != owner) \
            or np.any(hlod.depth[rows] != hlod.depth[owner] + 1):
        raise bad("parent and child links disagree")
    for lo, hi, total, what in ((hlod.tri_offset, hlod.tri_count, t, "triangle"),
                                (hlod.vertex_offset, hlod.vertex_count, v, "vertex")):
        if np.any(lo < 0) or np.any(hi <= 0) or np.any(lo + hi > total):
            raise bad(f"{what} ranges out of range (every node needs at least one {what})")
    floats = [hlod.lod_box_min, hlod.lod_box_max, hlod.box_min, hlod.box_max, hlod.sphere_center,
              hlod.sphere_radius, hlod.error, hlod.cube_side, hlod.origin]
    if not all(np.all(np.isfinite(a)) for a in floats):
        raise bad("non-finite bounds, errors or origin")
    if np.any(hlod.error < 0) or np.any(hlod.sphere_radius < 0) or np.any(hlod.box_max < hlod.box_min):
        raise bad("negative error or radius, or inverted box")
    if t and int(hlod.indices.max()) >= v:
        raise bad(f"an index points past the {v} vertices")
