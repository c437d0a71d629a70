"""Native `.hlod` container (docs/how-it-works.md#the-node-table): versioned, no pickle, validated on load,
atomic writes.

Layout (all integers little-endian):

    offset 0   8 bytes   magic b"HLODBAKE"
    offset 8   u32       format version (FORMAT_VERSION)
    offset 12  u32       0 (reserved)
    offset 16  u64       header length in bytes (H)
    offset 24  H bytes   UTF-8 JSON header: {"meta": {...}, "arrays": {name: {"dtype": "<f8",
                         "shape": [...], "offset": bytes from file start, "nbytes": ...}},
                         "materials": [...]}  (version 2; absent when the scene has none)
    then       arrays, raw C-order, each starting on a 64-byte boundary

Arrays are memory-mapped on load (numpy.memmap, read-only) except on Windows (`maps_files`): opening
a file costs the header parse and the range checks, not a read of the geometry. What `load` accepts, the renderer can
draw without reading outside its buffers. Why: docs/how-it-works.md#what-a-hlod-file-must-pass-to-load

Versions: 2 adds appearance: the optional arrays `uvs` (v,2) <f4, `colors` (v,4) <f4 and
`tri_material` (t,) <u2, and the header's material table (appearance.Material.to_json; texture
paths relative to the file's folder where they can be); a scene without appearance writes none of
them. A version 1 file is a version 2 file without them, and loads as an HLOD without appearance.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import struct
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core import jsonutil
from ..core.arrays import segment_ranges
from ..core.atomic import atomic_file
from ..core.errors import FormatError, InputError
from ..model.appearance import materials_from_json
from ..model.hierarchy import MAX_COORDINATE, NODE_ARRAYS, Hlod

MAGIC = b"HLODBAKE"
FORMAT_VERSION = 2
#: Versions this build reads (1: before appearance; it loads as an HLOD without appearance).
READABLE_VERSIONS = (1, 2)
_PREAMBLE = struct.Struct("<8sIIQ")
_ALIGN = 64
_MAX_HEADER_BYTES = 64 * 1024 * 1024
_MAX_HEADER_DEPTH = 16  # ours nests 4 deep (header, arrays, entry, shape); meta's settings 3

#: meta fields read as numbers (Hlod.summary, checks, the CLI): when present, integers in 0..2**63-1.
META_COUNTS = ("input_tris", "input_vertices", "target_tris", "max_depth", "leaves_over_budget",
               "collapsed_input_tris", "log_lines_dropped", "uv_seams_crossed_nodes", "nodes_over_budget",
               "pruned_pieces", "pruned_tris")
#: meta fields read as seconds: when present, finite numbers >= 0 (phase_seconds: an object of them).
META_SECONDS = ("bake_seconds",)
_INT64_MAX = 2**63 - 1

_GEOMETRY_ARRAYS: dict[str, tuple[str, tuple[int | None, ...]]] = {
    "origin": ("<f8", (3,)),
    "positions": ("<f4", (None, 3)),
    "indices": ("<u4", (None, 3)),
    "normals": ("<f4", (None, 3)),  # optional
    "uvs": ("<f4", (None, 2)),  # optional, version 2
    "colors": ("<f4", (None, 4)),  # optional, version 2
    "tri_material": ("<u2", (None,)),  # optional, version 2
}
_OPTIONAL_ARRAYS = ("normals", "uvs", "colors", "tri_material")


def _aligned(n: int) -> int:
    return (n + _ALIGN - 1) // _ALIGN * _ALIGN


def save(hlod: Hlod, path: str | os.PathLike) -> Path:
    """Write `hlod` to `path` atomically (atomic.atomic_file: temp file in the same folder, fsync,
    the umask's mode, rename). A failed write raises OSError naming `path`."""
    arrays: dict[str, np.ndarray] = dict(hlod.node_arrays())
    arrays["origin"] = hlod.origin
    arrays["positions"] = hlod.positions
    arrays["indices"] = hlod.indices
    for name in _OPTIONAL_ARRAYS:
        if getattr(hlod, name) is not None:
            arrays[name] = getattr(hlod, name)
    with StreamedWriter(path, {k: v.shape for k, v in arrays.items()}, meta=hlod.meta,
                        materials=hlod.materials) as out:
        for name, arr in arrays.items():
            out.append(name, arr)
    return Path(path)


class StreamedWriter:
    """A .hlod written array by array, a chunk at a time, atomically (`save` is one chunk an array):
    the header from the arrays' shapes (name -> shape, in the file's order: the node arrays, origin,
    positions, indices, then the optional ones present), `meta` and `materials`; then `append(name,
    rows)` any number of times, in any order across arrays, each array's rows in order. Used as a
    context manager: on a clean exit every array must be complete (else RuntimeError) and the file
    replaces `path`; on an exception the temporary file is removed and no file is left. Two writes
    of the same arrays, however chunked, are the same bytes."""

    def __init__(self, path: str | os.PathLike, shapes: dict[str, tuple[int, ...]], *, meta: dict,
                 materials: tuple = ()):
        self.path = Path(path)
        wanted = {**{k: v[0] for k, v in NODE_ARRAYS.items()}, **{k: v[0] for k, v in _GEOMETRY_ARRAYS.items()}}
        self.dtypes = {name: np.dtype(wanted[name]) for name in shapes}
        self.table = _table(self.path, {name: (self.dtypes[name], tuple(shape)) for name, shape in shapes.items()},
                            meta=meta, materials=materials)
        self.header = self.table.pop("")
        self.written = dict.fromkeys(shapes, 0)
        self._stack = contextlib.ExitStack()
        self._file = None

    def __enter__(self) -> "StreamedWriter":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self._stack.enter_context(atomic_file(self.path))
        self._file.write(_PREAMBLE.pack(MAGIC, FORMAT_VERSION, 0, len(self.header)))
        self._file.write(self.header)
        return self

    def append(self, name: str, rows: np.ndarray) -> None:
        """The next rows of array `name` (any dtype numpy casts to the file's: float32 positions,
        uint32 indices, ...)."""
        data = np.ascontiguousarray(rows, dtype=self.dtypes[name])
        entry = self.table[name]
        if self.written[name] + data.nbytes > entry["nbytes"]:
            raise RuntimeError(f"hlod: more rows of '{name}' than its {entry['shape']} in the header")
        self._file.seek(entry["offset"] + self.written[name])
        self._file.write(data.reshape(-1).view(np.uint8))
        self.written[name] += data.nbytes

    def __exit__(self, kind, value, traceback) -> bool:
        if kind is None:
            short = [name for name, done in self.written.items() if done != self.table[name]["nbytes"]]
            if short:
                error = RuntimeError(f"hlod: arrays {', '.join(short)} written short of their header's shapes")
                self._stack.__exit__(RuntimeError, error, None)
                raise error
            self._file.truncate(max(e["offset"] + e["nbytes"] for e in self.table.values()))
        return self._stack.__exit__(kind, value, traceback)


def _table(path: Path, arrays: dict[str, tuple[np.dtype, tuple[int, ...]]], *, meta: dict,
           materials: tuple) -> dict:
    """name -> {"dtype", "shape", "offset", "nbytes"} of every array, and "" -> the header's bytes.
    The header's size depends on the offsets it records: iterated until the layout is stable."""
    table, header, data_start = {}, b"", 0
    for _ in range(4):
        cursor = _aligned(_PREAMBLE.size + len(header)) if data_start == 0 else data_start
        table = {}
        for name, (dtype, shape) in arrays.items():
            nbytes = dtype.itemsize * math.prod(shape)
            table[name] = {"dtype": dtype.str, "shape": list(shape), "offset": cursor, "nbytes": nbytes}
            cursor = _aligned(cursor + nbytes)
        try:  # allow_nan=False: what is written must load (the reader refuses NaN and Infinity)
            content = {"meta": meta, "arrays": table}
            if materials:
                folder = path.resolve().parent
                content["materials"] = [m.to_json(relative_to=folder) for m in materials]
            header = json.dumps(content, sort_keys=True, allow_nan=False).encode("utf-8")
        except (TypeError, ValueError) as exc:
            raise FormatError(f"{path}: cannot write the HLOD's meta as JSON ({exc})") from None
        needed = _aligned(_PREAMBLE.size + len(header))
        if needed == data_start:
            break
        data_start = needed
    else:
        raise RuntimeError("hlod: header layout did not converge")  # offsets only ever grow by digits
    return {**table, "": header}


def maps_files(platform: str | None = None) -> bool:
    """Whether `load` memory-maps a file's arrays by default on `platform` (a sys.platform string,
    default this machine's). POSIX: yes, and a re-bake that replaces the file (an atomic rename)
    leaves a loaded HLOD reading the old one's pages. Windows: no, the arrays are read into memory
    and the file closed: Windows refuses to replace or delete a file while a view of it is mapped,
    so a preview holding a mapped .hlod would make every re-bake of it fail."""
    return (sys.platform if platform is None else platform) != "win32"


def load(path: str | os.PathLike, *, mmap: bool | None = None, check: bool = True) -> Hlod:
    """Open a .hlod file, its arrays memory-mapped or read into memory (`mmap`; None: `maps_files()`).
    Raises FormatError naming the file and what is wrong. check=False: the header's checks only, not
    `validate` (which reads every array): for a file this process has just written, mapped and
    nothing read (the bake's streamed write, bake/pipeline.py)."""
    mmap = maps_files() if mmap is None else mmap
    path = Path(path)
    size, header_end, raw = _read_header(path)
    meta, table, materials = _parse_header(path, raw)
    entries = _array_entries(path, table, size=size, header_end=header_end)
    arrays = {name: _map_array(path, entry, mmap) for name, entry in entries.items()}
    hlod = Hlod(**{name: arrays[name] for name in NODE_ARRAYS},
                origin=np.array(arrays["origin"]), positions=arrays["positions"],
                indices=arrays["indices"], normals=arrays.get("normals"), meta=meta,
                uvs=arrays.get("uvs"), colors=arrays.get("colors"), tri_material=arrays.get("tri_material"),
                materials=materials)
    if check:
        validate(hlod, source=str(path))
    return hlod


def _read_header(path: Path) -> tuple[int, int, bytes]:
    """(file size, first byte after the header, raw header bytes)."""
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            pre = f.read(_PREAMBLE.size)
            if len(pre) < _PREAMBLE.size or pre[:8] != MAGIC:
                raise FormatError(f"{path}: not a .hlod file (missing HLODBAKE signature)")
            _, version, _, header_len = _PREAMBLE.unpack(pre)
            if version not in READABLE_VERSIONS:
                raise FormatError(f"{path}: .hlod format version {version} is not supported (this build reads "
                                  f"versions {', '.join(map(str, READABLE_VERSIONS))}; re-bake the scene with it)")
            if header_len > min(_MAX_HEADER_BYTES, size - _PREAMBLE.size):
                raise FormatError(f"{path}: truncated .hlod file (header runs past the end of the file)")
            raw = f.read(header_len)
    except OSError as exc:
        raise FormatError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    if len(raw) != header_len:
        raise FormatError(f"{path}: truncated .hlod file (header runs past the end of the file)")
    return size, _PREAMBLE.size + header_len, raw


def _parse_header(path: Path, raw: bytes) -> tuple[dict, dict, tuple]:
    """(meta, arrays table, materials) of the JSON header, types checked before anything reads them."""
    try:
        header = jsonutil.loads(raw, max_depth=_MAX_HEADER_DEPTH)
    except jsonutil.JsonError as exc:
        raise FormatError(f"{path}: corrupt .hlod header ({exc})") from None
    if not isinstance(header, dict) or not isinstance(header.get("meta"), dict) \
            or not isinstance(header.get("arrays"), dict):
        raise FormatError(f"{path}: corrupt .hlod header (expected an object with objects 'meta' and 'arrays')")
    try:
        materials = materials_from_json(header.get("materials", []), where="materials",
                                        relative_to=path.resolve().parent)
    except InputError as exc:
        raise FormatError(f"{path}: corrupt .hlod header ({exc})") from None
    return header["meta"], header["arrays"], materials


@dataclass(frozen=True, order=True)
class _Entry:
    """One array's place in the file (bytes from the file start)."""

    offset: int
    nbytes: int
    name: str
    dtype: str
    shape: tuple[int, ...]


def _array_entries(path: Path, table: dict, *, size: int, header_end: int) -> dict[str, _Entry]:
    """Every array's table entry, checked with Python integers (no overflow): known name, the
    expected dtype, shape (node arrays share one row count), nbytes = itemsize * product(shape),
    64-byte aligned, after the header, inside the file, no two arrays overlapping."""
    expected = {**NODE_ARRAYS, **_GEOMETRY_ARRAYS}
    unknown = sorted(set(table) - set(expected))
    if unknown:
        raise FormatError(f"{path}: corrupt .hlod header (unknown array {unknown[0][:64]!r})")
    missing = [n for n in list(NODE_ARRAYS) + ["origin", "positions", "indices"] if n not in table]
    if missing:
        raise FormatError(f"{path}: .hlod file lacks arrays {', '.join(missing)}")
    entries = {name: _entry(path, name, table[name], expected=expected[name], size=size, header_end=header_end)
               for name in expected if name in table}
    rows = {name: entries[name].shape[0] for name in NODE_ARRAYS}
    if len(set(rows.values())) != 1:
        raise FormatError(f"{path}: node arrays differ in length ({rows['parent']} parents, "
                          f"{next(f'{v} {k}' for k, v in rows.items() if v != rows['parent'])})")
    placed = sorted(e for e in entries.values() if e.nbytes)
    for before, after in zip(placed, placed[1:]):
        if before.offset + before.nbytes > after.offset:
            raise FormatError(f"{path}: corrupt .hlod header (arrays '{before.name}' and '{after.name}' overlap)")
    return entries


def _entry(path: Path, name: str, entry, *, expected: tuple[str, tuple], size: int, header_end: int) -> _Entry:
    dtype, trailing = expected
    want_shape = (None, *trailing) if name in NODE_ARRAYS else trailing  # None: any row count

    def bad(what: str) -> FormatError:
        return FormatError(f"{path}: corrupt entry for array '{name}' ({what[:200]})")

    if not isinstance(entry, dict):
        raise bad("not an object")
    if entry.get("dtype") != dtype:
        raise bad(f"dtype {str(entry.get('dtype'))[:32]!r}, expected {dtype!r}")
    shape, offset, nbytes = entry.get("shape"), entry.get("offset"), entry.get("nbytes")
    if not isinstance(shape, list) or len(shape) != len(want_shape) or not all(map(_is_count, shape)):
        raise bad(f"shape must be a list of {len(want_shape)} non-negative integers")
    if any(want is not None and got != want for got, want in zip(shape, want_shape)):
        raise bad(f"shape {shape}, expected {[('n' if w is None else w) for w in want_shape]}")
    if not _is_count(offset) or not _is_count(nbytes):
        raise bad("offset and nbytes must be non-negative integers")
    if nbytes != np.dtype(dtype).itemsize * math.prod(shape):  # Python integers: no wrap-around
        raise bad(f"{nbytes} bytes do not hold {dtype}{shape}")
    if offset + nbytes > size:
        raise FormatError(f"{path}: truncated .hlod file (array '{name}' runs past the end of the file)")
    if nbytes and (offset % _ALIGN or offset < header_end):
        raise bad(f"offset {offset} is not a {_ALIGN}-byte boundary after the header (ends at {header_end})")
    return _Entry(offset=offset, nbytes=nbytes, name=name, dtype=dtype, shape=tuple(shape))


def _is_count(value) -> bool:
    """A JSON integer (not a bool, not a float) >= 0."""
    return type(value) is int and value >= 0


def _map_array(path: Path, entry: _Entry, mmap: bool) -> np.ndarray:
    dtype = np.dtype(entry.dtype)
    if entry.nbytes == 0:
        return np.zeros(entry.shape, dtype)
    if mmap:
        return np.memmap(path, dtype=dtype, mode="r", offset=entry.offset, shape=entry.shape)
    with open(path, "rb") as f:
        f.seek(entry.offset)
        data = f.read(entry.nbytes)
    if len(data) != entry.nbytes:  # the file shrank since it was measured
        raise FormatError(f"{path}: truncated .hlod file (array '{entry.name}' runs past the end of the file)")
    return np.frombuffer(data, dtype=dtype).reshape(entry.shape)


def validate(hlod: Hlod, *, source: str = "HLOD") -> None:
    """Check every array's dtype, shape and ranges, and meta's numeric fields; raise FormatError
    naming `source`. Integer arithmetic in int64 on values already bounded (no wrap-around).

    Cheap enough to run on every load (O(n log n) over nodes, one max over the index buffer).
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
        if arr is None and name in _OPTIONAL_ARRAYS:
            continue
        if arr.dtype != np.dtype(dtype) or len(arr.shape) != len(shape) or any(
                want is not None and got != want for got, want in zip(arr.shape, shape)):
            raise bad(f"array '{name}' is {arr.dtype}{list(arr.shape)}, expected {np.dtype(dtype)}{list(shape)}")
    v, t = hlod.positions.shape[0], hlod.indices.shape[0]
    for name in ("normals", "uvs", "colors"):
        if getattr(hlod, name) is not None and getattr(hlod, name).shape[0] != v:
            raise bad(f"{name} and positions differ in length")
    _validate_appearance(hlod, t, bad)
    _validate_tree(hlod, bad)
    for lo, count, total, what in ((hlod.tri_offset, hlod.tri_count, t, "triangle"),
                                   (hlod.vertex_offset, hlod.vertex_count, v, "vertex")):
        _validate_ranges(np.asarray(lo), np.asarray(count), total=total, what=what, bad=bad)
    floats = [hlod.lod_box_min, hlod.lod_box_max, hlod.box_min, hlod.box_max, hlod.sphere_center,
              hlod.sphere_radius, hlod.error, hlod.cube_side, hlod.origin]
    if not all(np.all(np.isfinite(a)) for a in floats):
        raise bad("non-finite bounds, errors or origin")
    if not all(np.all(np.abs(a) <= MAX_COORDINATE) for a in floats):
        raise bad(f"bounds, errors or origin beyond {MAX_COORDINATE:g} model units")
    if np.any(hlod.error < 0) or np.any(hlod.sphere_radius < 0) or np.any(hlod.box_max < hlod.box_min):
        raise bad("negative error or radius, or inverted box")
    if t and int(hlod.indices.max()) >= v:
        raise bad(f"an index points past the {v} vertices")
    _validate_meta(hlod.meta, bad)


def _validate_appearance(hlod: Hlod, t: int, bad) -> None:
    """Material ids index the material table; UVs finite; colours in [0, 1]."""
    if hlod.tri_material is not None:
        if hlod.tri_material.shape[0] != t:
            raise bad("tri_material and indices differ in length")
        if t and int(hlod.tri_material.max()) >= len(hlod.materials):
            raise bad(f"a triangle's material id is past the {len(hlod.materials)} materials")
    elif hlod.materials:
        raise bad(f"{len(hlod.materials)} materials but no per-triangle material ids")
    if hlod.uvs is not None and not np.all(np.isfinite(hlod.uvs)):
        raise bad("non-finite UVs")
    if hlod.colors is not None and not (np.all(hlod.colors >= 0.0) and np.all(hlod.colors <= 1.0)):
        raise bad("vertex colours outside [0, 1] (or NaN)")


def _validate_tree(hlod: Hlod, bad) -> None:
    """Parent/child links and depths (int64: a wrapped int32 sum cannot pass). With every child row
    listed once and depth = parent's depth + 1, the links form one tree rooted at row 0."""
    n = hlod.node_count
    parent = hlod.parent.astype(np.int64)
    co, cc = hlod.child_offset.astype(np.int64), hlod.child_count.astype(np.int64)
    depth = hlod.depth.astype(np.int64)
    if parent[0] != -1 or depth[0] != 0 or np.any(parent[1:] < 0) or np.any(parent >= n):
        raise bad("parent links out of range")
    inner = cc > 0
    if np.any(cc < 0) or np.any(co[~inner] != -1) or np.any(co[inner] < 1) or np.any(co[inner] > n - cc[inner]):
        raise bad("child ranges out of range")
    if int(cc.sum()) != n - 1:
        raise bad("child counts do not add up to the node count")
    owner = np.repeat(np.flatnonzero(inner), cc[inner])
    rows = segment_ranges(co[inner], cc[inner])  # every child row, grouped by parent
    if rows.shape[0] != n - 1 or np.any(np.sort(rows) != np.arange(1, n)) or np.any(parent[rows] != owner) \
            or np.any(depth[rows] != depth[owner] + 1):
        raise bad("parent and child links disagree")


def _validate_ranges(first: np.ndarray, count: np.ndarray, *, total: int, what: str, bad) -> None:
    """Each node's [first, first + count) is non-empty and inside 0..total, and no two overlap.
    first, count: (n,) int64; compared one at a time against total, so first + count never wraps."""
    inside = (first >= 0) & (count >= 1) & (first <= total)
    inside[inside] &= count[inside] <= total - first[inside]
    if not np.all(inside):
        node = int(np.flatnonzero(~inside)[0])
        raise bad(f"node {node}'s {what} range (offset {int(first[node])}, count {int(count[node])}) is empty "
                  f"or runs past the {total} {what}s")
    order = np.argsort(first, kind="stable")
    ends = first[order] + count[order]  # <= total: no overflow after the check above
    overlap = np.flatnonzero(ends[:-1] > first[order][1:])
    if overlap.size:
        a, b = sorted((int(order[overlap[0]]), int(order[overlap[0] + 1])))
        raise bad(f"the {what} ranges of nodes {a} and {b} overlap")


def _validate_meta(meta, bad) -> None:
    """meta is an object; the fields other code reads as numbers hold numbers it can use."""
    if not isinstance(meta, dict):
        raise bad(f"meta is {type(meta).__name__}, expected an object")
    for key in META_COUNTS:
        value = meta.get(key, 0)
        if type(value) is not int or not 0 <= value <= _INT64_MAX:
            raise bad(f"meta field '{key}' is {_show(value)}, expected an integer in 0..{_INT64_MAX}")
    seconds = {key: meta[key] for key in META_SECONDS if key in meta}
    phases = meta.get("phase_seconds", {})
    if not isinstance(phases, dict):
        raise bad(f"meta field 'phase_seconds' is {_show(phases)}, expected an object of seconds")
    seconds.update({f"phase_seconds.{k}": v for k, v in phases.items()})
    for key, value in seconds.items():
        if type(value) not in (int, float) or value < 0 or (type(value) is float and not math.isfinite(value)):
            raise bad(f"meta field '{key}' is {_show(value)}, expected seconds >= 0")
    for key in ("sources", "log"):
        value = meta.get(key, [])
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            raise bad(f"meta field '{key}' is {_show(value)}, expected a list of strings")


def _show(value) -> str:
    """A short, printable form of a JSON value for a message."""
    text = json.dumps(value) if isinstance(value, (int, float, str, bool, type(None))) else type(value).__name__
    return text if len(text) <= 40 else text[:37] + "..."
