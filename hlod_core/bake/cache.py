"""The bake cache (issue 14): inner nodes' LODs and errors, keyed by what they were made from.

Data form: a folder (by default `OUT.hlod.cache/` beside the output; safe to delete at any time:
the next bake is then a bake from scratch) holding a CACHEDIR.TAG and
- one file per inner node, `<key>.hlodc`: the node's LOD (positions (k,3) float32 origin-relative,
  faces (m,3) int32, normals (k,3) float32 and attribute rows (k,A) float32 when the bake has
  them), its error (float64, model units: the Hausdorff error, or its bound with --error bound) and what the bake log says of it
  (`SUMMARY_FIELDS`);
- one file for the whole result of the last bake, `<input key>.hlodr`: every array of its Hlod and
  the meta entries the bake derives (`RESULT_META`), keyed by the whole input (`input_key`: the
  mesh's arrays and materials, max_depth and the context below). A re-bake of an unchanged input
  takes it and skips even the octree (the per-node entries serve every other re-bake).

Keys (blake2b, 32 bytes) are a Merkle tree over the octree (`node_keys`):
- a leaf's key hashes its triangles as the bake sees them: float32 origin-relative positions of the
  vertices its triangles use, its faces local to them in octree order, their normals and attribute
  rows when present (bake.py: leaves keep these exactly), and its cell (the origin, the cell's
  centre, half side and grid level);
- an inner node's key hashes its cell and its children's keys, in order;
- both hash `context_digest`: the cache format (CACHE_VERSION), the .hlod format version, every
  setting that changes a LOD or an error (target_tris, quality_threshold, preserve_normals,
  boundary_weight, the error measure: exact or bound), whether the bake carries normals and which attribute columns, the versions of
  pymeshlab and numpy, and the source of the modules that compute LODs and errors (`RESULT_MODULES`:
  editing them retires every entry).
A node's LOD and error are functions of its subtree's input triangles and these settings alone
(bake.py: decimation sees the children's LODs, the error the leaves' triangles below the node), so
equal keys mean equal results. max_depth and target_tris act on the subtree's shape too, and the
shape is in the key (a leaf hashes triangles, an inner node its children). An edit changes the
keys of the cells it touches and of their ancestors only (octree.py: cells do not move).

Integrity: a file starts with magic, CACHE_VERSION, the payload's length and its blake2b digest;
`load` and `load_result` check all of them, the key and kind recorded inside, and every array's
dtype, shape and index range (a result: hlod_file.validate, as a .hlod file is) before using
anything. An entry that fails is ignored (a miss), counted, named once in the log at
the end of the bake, and rebuilt; nothing is read with pickle. Entries are written once a bake is
complete (a cancelled bake writes none), each to a temporary name and renamed into place; they are
not fsynced: a file torn by a crash fails its digest and is rebuilt.

Size: after a complete bake, entries it did not use are removed (`prune`), so the folder holds the
last bake's inner nodes and its result: about 1.5 times its .hlod (crowd_1m: the inner LODs are
40% of the file's triangles, and the result is the file again). Bakes of different scenes that
share one folder evict each other's entries (still correct, only slower).
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import importlib.metadata
import json
import logging
import os
import struct
import tempfile
import time
from pathlib import Path

import numpy as np

from ..io import hlod_file
from . import simplify
from ..model.appearance import AttributeLayout
from ..core.errors import FormatError, InputError
from ..model.hierarchy import NODE_ARRAYS, Hlod
from .octree import OctreeLayout

log = logging.getLogger(__name__)

#: Version of the entry format and of the keys' recipe; any change to either bumps it.
CACHE_VERSION = 1
MAGIC = b"HLODCACH"
ENTRY_SUFFIX = ".hlodc"
RESULT_SUFFIX = ".hlodr"
#: magic, CACHE_VERSION, reserved (0), payload length, blake2b-256 digest of the payload.
_PREAMBLE = struct.Struct("<8sIIQ32s")
_HEADER_LENGTH = struct.Struct("<I")
_MAX_HEADER_BYTES = 1024 * 1024
_KEY_BYTES = 32
#: Modules whose code computes LODs and errors (their source is part of every key).
RESULT_MODULES = ("bake.simplify", "bake.hausdorff", "model.appearance", "core.arrays", "bake.octree",
                  "bake.pipeline", "bake.cache")
#: NodeLod fields the bake log reads, stored per entry as one int64 each.
SUMMARY_FIELDS = ("decimated", "input_tris", "kept_in_place", "zero_area", "uv_seams_crossed", "seam_kept_tris",
                  "island_spanning_faces")
_FLAG_FIELDS = ("decimated", "kept_in_place", "zero_area", "uv_seams_crossed")
#: meta entries a result entry keeps (what the bake derives; the rest comes from the call).
RESULT_META = {"leaves_over_budget": int, "collapsed_input_tris": int, "log": list, "log_lines_dropped": int,
               "uv_seams_crossed_nodes": int}
#: The Hlod arrays of a result entry (the appearance ones only when the bake has them).
_RESULT_ARRAYS = (*NODE_ARRAYS, "origin", "positions", "indices", "normals", "uvs", "colors", "tri_material")
#: Temporary files older than this (seconds) are a crashed writer's: prune removes them.
_STALE_TEMP_SECONDS = 3600.0
_CACHEDIR_TAG = (b"Signature: 8a477f597d28d172789f06886806bc55\n"
                 b"# An HLOD bake cache (hlod_core.bake.cache): safe to delete; the next bake rebuilds it.\n")


def default_folder(output: str | os.PathLike) -> Path:
    """The cache folder of a bake writing `output`: OUT.hlod.cache beside it."""
    output = Path(output)
    return output.with_name(output.name + ".cache")


def check_folder(folder: str | os.PathLike | None) -> None:
    """Raise InputError when `folder` (None: no cache) names something that is not a folder."""
    if folder is not None and os.path.lexists(folder) and not os.path.isdir(folder):
        raise InputError(f"{folder}: is a file; the bake cache is a folder (give another with --cache, or --no-cache)")


def context_digest(settings: simplify.DecimationSettings, *, with_normals: bool,
                   row_layout: AttributeLayout | None, error: str = "exact") -> bytes:
    """32 bytes: everything besides a subtree's triangles that its LODs and errors depend on;
    error: the error measure (bake.BakeSettings.error), so a bound is never served for an exact
    error nor the other way round."""
    core = Path(__file__).resolve().parent.parent
    code = hashlib.blake2b(digest_size=_KEY_BYTES)
    for name in RESULT_MODULES:
        try:
            code.update((core / f"{name.replace('.', '/')}.py").read_bytes())
        except OSError:  # not installed as source files: the versions below still key it
            code.update(name.encode())
    described = {
        "cache_version": CACHE_VERSION,
        "hlod_format": hlod_file.FORMAT_VERSION,
        "decimation": dataclasses.asdict(settings),
        "with_normals": bool(with_normals),
        "error": str(error),
        "rows": None if row_layout is None or row_layout.empty else [row_layout.material, row_layout.uv,
                                                                     row_layout.color],
        "pymeshlab": _version("pymeshlab"),
        "numpy": np.__version__,
        "code": code.hexdigest(),
    }
    return hashlib.blake2b(json.dumps(described, sort_keys=True).encode(), digest_size=_KEY_BYTES).digest()


def _version(package: str) -> str:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _hash_array(h, part: np.ndarray | None) -> None:
    if part is None:
        h.update(b"\0")
        return
    part = np.ascontiguousarray(part)
    h.update(part.dtype.str.encode() + np.asarray(part.shape, "<i8").tobytes())
    h.update(memoryview(part).cast("B"))


def input_key(mesh, *, max_depth: int, context: bytes) -> bytes:
    """32 bytes keying a bake's whole result: the mesh's arrays and materials, max_depth and
    `context` (the settings and versions)."""
    h = hashlib.blake2b(context, digest_size=_KEY_BYTES, person=b"hlod input")
    h.update(np.asarray([max_depth], "<i8").tobytes())
    for part in (mesh.positions, mesh.faces, mesh.normals, mesh.uvs, mesh.colors, mesh.material_ids):
        _hash_array(h, part)
    h.update(json.dumps([m.to_json() for m in mesh.materials], sort_keys=True).encode())
    return h.digest()


def node_keys(layout: OctreeLayout, lods: list, *, origin: np.ndarray, context: bytes) -> list[bytes]:
    """(n,) 32-byte keys, one per node (module docstring). lods: per node (positions, faces,
    normals or None, attribute rows or None); only the leaves' are read."""
    n = layout.node_count
    keys: list[bytes] = [b""] * n
    cells = np.zeros(n, [("origin", "<f8", 3), ("center", "<f8", 3), ("half", "<f8"), ("level", "<i8")])
    cells["origin"], cells["center"] = origin, layout.cell_center
    cells["half"], cells["level"] = layout.cell_half, layout.cell_level
    for node in range(n - 1, -1, -1):  # children have larger ids than their parent
        if layout.child_count[node] == 0:
            h = hashlib.blake2b(context, digest_size=_KEY_BYTES, person=b"hlod leaf")
            h.update(cells[node].tobytes())
            for part in lods[node]:
                _hash_array(h, part)
        else:
            h = hashlib.blake2b(context, digest_size=_KEY_BYTES, person=b"hlod node")
            h.update(cells[node].tobytes())
            first = int(layout.child_offset[node])
            h.update(b"".join(keys[first:first + int(layout.child_count[node])]))
        keys[node] = h.digest()
    return keys


class BakeCache:
    """One bake's view of a cache folder: `load` node entries and `store` the bake's new ones,
    `load_result` / `store_result` the whole result, `prune`. with_normals / row_layout: what the
    bake carries (part of the keys; every entry must match it); error: the error measure (part of
    the keys). Statistics for the bake's meta:
    reused_nodes, reused_tris, rejected (entries ignored: (file name, why))."""

    def __init__(self, folder: str | os.PathLike, *, decimation: simplify.DecimationSettings, with_normals: bool,
                 row_layout: AttributeLayout, error: str = "exact"):
        check_folder(folder)
        self.folder = Path(folder)
        self.with_normals = with_normals
        self.row_width = row_layout.width
        self.context = context_digest(decimation, with_normals=with_normals, row_layout=row_layout, error=error)
        self.reused_nodes = 0
        self.reused_tris = 0
        self.rejected: list[tuple[str, str]] = []

    def path(self, key: bytes, suffix: str = ENTRY_SUFFIX) -> Path:
        return self.folder / f"{key.hex()}{suffix}"

    def load(self, key: bytes) -> tuple[simplify.NodeLod, float] | None:
        """A node entry's (LOD, Hausdorff error), or None: absent, or rejected (counted)."""
        found = self._read(key, ENTRY_SUFFIX, "node")
        if found is None:
            return None
        try:
            lod, error = _node_from(*found, with_normals=self.with_normals, row_width=self.row_width)
        except _Corrupt as exc:
            self.rejected.append((self.path(key).name, str(exc)))
            return None
        self.reused_nodes += 1
        self.reused_tris += int(lod.faces.shape[0])
        return lod, error

    def load_result(self, key: bytes, materials: tuple) -> tuple[Hlod, dict] | None:
        """A result entry's (Hlod with `materials`, empty meta; the RESULT_META it keeps), or None."""
        found = self._read(key, RESULT_SUFFIX, "result")
        if found is None:
            return None
        try:
            return _result_from(*found, materials=materials, with_normals=self.with_normals,
                                has_rows=self.row_width > 0)
        except _Corrupt as exc:
            self.rejected.append((self.path(key, RESULT_SUFFIX).name, str(exc)))
            return None

    def _read(self, key: bytes, suffix: str, kind: str):
        path = self.path(key, suffix)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            self.rejected.append((path.name, f"unreadable ({exc.strerror or exc})"))
            return None
        try:
            return _unpack(data, key, kind)
        except _Corrupt as exc:
            self.rejected.append((path.name, str(exc)))
            return None

    def store(self, entries: dict[bytes, tuple[simplify.NodeLod, float]]) -> None:
        """Write node entries (key -> (LOD, error)), each atomically."""
        self._write((self.path(key), _node_bytes(key, lod, error)) for key, (lod, error) in entries.items())

    def store_result(self, key: bytes, hlod: Hlod, meta: dict) -> None:
        """Write the result entry of a bake: its arrays and its RESULT_META entries found in `meta`."""
        self._write([(self.path(key, RESULT_SUFFIX), _result_bytes(key, hlod, meta))])

    def _write(self, files) -> None:
        """Write (path, bytes) pairs. A failed write (disk full, no permission) is logged once and
        ends the writing: the cache only saves time."""
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            tag = self.folder / "CACHEDIR.TAG"
            if not tag.exists():
                _write_replacing(tag, _CACHEDIR_TAG)
            for path, data in files:
                _write_replacing(path, data)
        except OSError as exc:
            log.warning("bake cache %s: cannot write entries (%s: %s); this bake is not cached", self.folder,
                        exc.filename or self.folder, exc.strerror or exc)

    def prune(self, used: set[bytes], result: bytes) -> int:
        """Remove the node entries whose key is not in `used`, result entries but `result`'s, and
        temporary files of writers that died; returns how many files were removed."""
        keep = {f"{key.hex()}{ENTRY_SUFFIX}" for key in used} | {f"{result.hex()}{RESULT_SUFFIX}"}
        removed = 0
        now = time.time()
        try:
            listing = list(os.scandir(self.folder))
        except OSError:
            return 0
        for entry in listing:
            stale_entry = entry.name.endswith((ENTRY_SUFFIX, RESULT_SUFFIX)) and entry.name not in keep
            stale_temp = entry.name.startswith(".") and entry.name.endswith(".tmp") \
                and _age(entry, now) > _STALE_TEMP_SECONDS
            if stale_entry or stale_temp:
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)
                    removed += 1
        return removed

    def report(self) -> None:
        """Log the rejected entries once (at the end of a bake)."""
        if self.rejected:
            name, why = self.rejected[0]
            log.warning("bake cache %s: %d entries ignored and rebuilt (first: %s: %s)", self.folder,
                        len(self.rejected), name, why)


def _age(entry: os.DirEntry, now: float) -> float:
    try:
        return now - entry.stat().st_mtime
    except OSError:
        return 0.0


def _write_replacing(path: Path, data: bytes) -> None:
    """Write to a temporary name beside `path` and rename it over `path` (no fsync: see the module
    docstring). The temporary file is removed on any failure."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


# --- the container: preamble, JSON header, raw little-endian arrays -------------------------------

class _Corrupt(Exception):
    """An entry that must not be used; the message says why."""


def _pack(key: bytes, kind: str, arrays: dict[str, np.ndarray], extra: dict | None = None) -> bytes:
    table, offset = [], 0
    arrays = {name: np.ascontiguousarray(a, a.dtype.newbyteorder("<")) for name, a in arrays.items()}
    for name, a in arrays.items():
        table.append([name, a.dtype.str, list(a.shape), offset])
        offset += a.nbytes
    header = json.dumps({"key": key.hex(), "kind": kind, "arrays": table, "extra": extra or {}}).encode()
    payload = b"".join([_HEADER_LENGTH.pack(len(header)), header, *(a.tobytes() for a in arrays.values())])
    digest = hashlib.blake2b(payload, digest_size=_KEY_BYTES).digest()
    return _PREAMBLE.pack(MAGIC, CACHE_VERSION, 0, len(payload), digest) + payload


def _unpack(data: bytes, key: bytes, kind: str) -> tuple[dict, dict[str, np.ndarray]]:
    """(extra, arrays) of an entry that passes the preamble, digest, key, kind and table checks."""
    if len(data) < _PREAMBLE.size:
        raise _Corrupt(f"truncated ({len(data)} bytes)")
    magic, version, _, length, digest = _PREAMBLE.unpack_from(data)
    if magic != MAGIC:
        raise _Corrupt("not a bake cache entry (bad magic)")
    if version != CACHE_VERSION:
        raise _Corrupt(f"cache format {version}, this bake reads {CACHE_VERSION}")
    payload = memoryview(data)[_PREAMBLE.size:]
    if length != len(payload):
        raise _Corrupt(f"payload of {len(payload)} bytes, the entry says {length}")
    if hashlib.blake2b(payload, digest_size=_KEY_BYTES).digest() != digest:
        raise _Corrupt("payload digest mismatch")
    (header_bytes,) = _HEADER_LENGTH.unpack_from(payload)
    if header_bytes > min(_MAX_HEADER_BYTES, len(payload) - _HEADER_LENGTH.size):
        raise _Corrupt("bad header length")
    try:
        header = json.loads(bytes(payload[_HEADER_LENGTH.size:_HEADER_LENGTH.size + header_bytes]))
        if header["key"] != key.hex() or header["kind"] != kind:
            raise _Corrupt(f"the entry records another key or kind ({header['kind']})")
        table = [(str(name), np.dtype(str(dtype)), tuple(int(x) for x in shape), int(offset))
                 for name, dtype, shape, offset in header["arrays"]]
        extra = dict(header["extra"])
    except (ValueError, KeyError, TypeError) as exc:
        raise _Corrupt(f"bad header ({exc})") from None
    base = _HEADER_LENGTH.size + header_bytes
    arrays = {}
    for name, dtype, shape, offset in table:
        if dtype.hasobject or any(x < 0 for x in shape):
            raise _Corrupt(f"{name}: dtype {dtype} shape {list(shape)}")
        count = int(np.prod(shape, dtype=object))
        if offset < 0 or base + offset + count * dtype.itemsize > len(payload):
            raise _Corrupt(f"{name}: outside the entry")
        arrays[name] = np.frombuffer(payload, dtype, count, base + offset).reshape(shape).copy()
    return extra, arrays


def _expect(arrays: dict[str, np.ndarray], name: str, dtype: str, shape: tuple) -> np.ndarray:
    """arrays[name], checked: dtype, and shape with None for any length."""
    a = arrays.get(name)
    if a is None or a.dtype != np.dtype(dtype) or len(a.shape) != len(shape) \
            or any(want is not None and got != want for got, want in zip(a.shape, shape)):
        got = "absent" if a is None else f"{a.dtype}{list(a.shape)}"
        raise _Corrupt(f"{name}: {got}, expected {np.dtype(dtype)}{list(shape)}")
    return a


# --- node entries ---------------------------------------------------------------------------------

def _node_bytes(key: bytes, lod: simplify.NodeLod, error: float) -> bytes:
    arrays = {"positions": np.asarray(lod.positions, "<f4"), "faces": np.asarray(lod.faces, "<i4"),
              "hausdorff": np.array([error], "<f8"),
              "summary": np.array([int(getattr(lod, name)) for name in SUMMARY_FIELDS], "<i8")}
    if lod.normals is not None:
        arrays["normals"] = np.asarray(lod.normals, "<f4")
    if lod.attributes is not None:
        arrays["attributes"] = np.asarray(lod.attributes, "<f4")
    return _pack(key, "node", arrays)


def _node_from(extra: dict, arrays: dict, *, with_normals: bool, row_width: int) -> tuple[simplify.NodeLod, float]:
    expected = {"positions", "faces", "hausdorff", "summary"} | ({"normals"} if with_normals else set()) \
        | ({"attributes"} if row_width else set())
    if set(arrays) != expected:
        raise _Corrupt(f"arrays {sorted(arrays)}, expected {sorted(expected)}")
    positions = _expect(arrays, "positions", "<f4", (None, 3))
    k = positions.shape[0]
    faces = _expect(arrays, "faces", "<i4", (None, 3))
    normals = _expect(arrays, "normals", "<f4", (k, 3)) if with_normals else None
    rows = _expect(arrays, "attributes", "<f4", (k, row_width)) if row_width else None
    error = float(_expect(arrays, "hausdorff", "<f8", (1,))[0])
    summary = dict(zip(SUMMARY_FIELDS, (int(v) for v in _expect(arrays, "summary", "<i8", (len(SUMMARY_FIELDS),)))))
    if k == 0 or faces.shape[0] == 0:
        raise _Corrupt("empty LOD")
    if faces.min() < 0 or faces.max() >= k:
        raise _Corrupt("a face refers to a vertex outside the LOD")
    if not np.all(np.isfinite(positions)):
        raise _Corrupt("non-finite positions")
    if error < 0 or np.isinf(error):  # NaN is allowed: pymeshlab gave no distance (bake.py bounds it)
        raise _Corrupt(f"bad error {error}")
    if any(summary[name] not in (0, 1) for name in _FLAG_FIELDS) or any(v < 0 for v in summary.values()):
        raise _Corrupt(f"bad summary {summary}")
    lod = simplify.NodeLod(positions=positions, faces=faces, normals=normals, attributes=rows,
                           **{name: bool(summary[name]) if name in _FLAG_FIELDS else summary[name]
                              for name in SUMMARY_FIELDS})
    return lod, error


# --- result entries -------------------------------------------------------------------------------

def _result_bytes(key: bytes, hlod: Hlod, meta: dict) -> bytes:
    arrays = {name: getattr(hlod, name) for name in _RESULT_ARRAYS if getattr(hlod, name) is not None}
    return _pack(key, "result", arrays, {name: meta[name] for name in RESULT_META if name in meta})


def _result_from(extra: dict, arrays: dict, *, materials: tuple, with_normals: bool,
                 has_rows: bool) -> tuple[Hlod, dict]:
    required = set(NODE_ARRAYS) | {"origin", "positions", "indices"} | ({"normals"} if with_normals else set())
    if not required <= set(arrays) <= set(_RESULT_ARRAYS) or (not has_rows and set(arrays) - required):
        raise _Corrupt(f"arrays {sorted(arrays)}")
    try:
        hlod = Hlod(**arrays, materials=tuple(materials))
        hlod_file.validate(hlod, source="bake cache result")
    except (FormatError, TypeError, ValueError) as exc:
        raise _Corrupt(str(exc)) from None
    for name, kind in RESULT_META.items():
        value = extra.get(name)
        if name not in extra and name == "uv_seams_crossed_nodes" and not has_rows:
            continue
        if not isinstance(value, kind) or (kind is int and value < 0) \
                or (kind is list and not all(isinstance(line, str) for line in value)):
            raise _Corrupt(f"meta entry {name!r} is {value!r}")
    return hlod, {name: extra[name] for name in RESULT_META if name in extra}
