"""The bake cache: inner nodes' LODs and errors, keyed by what they were made from, and the
whole result of the last bake. The cache owns its policy: `BakeCache.open` (no folder: no cache),
`whole_result` (an unchanged input skips the bake), `reuse` (the inner nodes whose subtree is
unchanged), `finish` (writing, pruning, meta["cache"]); `folder_for` says where it lives.

Data form: a folder (by default `OUT.hlod.cache/` beside the output; safe to delete at any time:
the next bake is then a bake from scratch) holding a CACHEDIR.TAG and
- one file per inner node, `<key>.hlodc`: the node's LOD (positions (k,3) float32 origin-relative,
  faces (m,3) int32, normals (k,3) float32 and attribute rows (k,A) float32 when the bake has
  them), its error (float64, model units: the Hausdorff error, or its bound) and what the bake log
  says of it (`SUMMARY_FIELDS`);
- one file for the whole result of the last bake, `<input key>.hlodr`: every array of its Hlod and
  the meta entries the bake derives (meta.DERIVED_META), keyed by the whole input (`input_key`).

Keys (blake2b, 32 bytes) are a Merkle tree over the octree (`node_keys`): a leaf's key hashes its
triangles as the bake sees them and its cell; an inner node's, its cell and its children's keys;
both hash `context_digest` (the formats, every setting that changes a LOD or an error, the
versions of pymeshlab and numpy, and the source of RESULT_MODULES). Equal keys mean equal results.
Why: docs/how-it-works.md#re-bakes-and-the-cache-keys

Integrity: a file starts with magic, CACHE_VERSION, the payload's length and its blake2b digest;
`load` and `load_result` check all of them, the key and kind recorded inside, and every array's
dtype, shape and index range (a result: hlod_file.validate, as a .hlod file is) before using
anything. An entry that fails is ignored (a miss), counted, named once in the log at the end of
the bake, and rebuilt; nothing is read with pickle. Entries are written once a bake is complete
(a cancelled bake writes none), each to a temporary name and renamed into place; they are not
fsynced: a file torn by a crash fails its digest and is rebuilt.

Size: after a complete bake, entries it did not use are removed (`prune`), so the folder holds the
last bake's inner nodes and its result: about 1.5 times its .hlod. Bakes of different scenes that
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
import tempfile
import time
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..io import hlod_file
from ..io.meshes import TriangleMesh
from ..model.appearance import AttributeLayout
from ..model.hierarchy import Hlod
from . import cache_files
from .cache_files import KEY_BYTES, CorruptEntry
from .meshlab import DecimationSettings
from .octree import OctreeLayout
from .settings import BakeSettings
from .simplify import NodeLod

log = logging.getLogger(__name__)

ENTRY_SUFFIX = ".hlodc"
RESULT_SUFFIX = ".hlodr"
#: Modules whose code computes LODs, errors or the result's arrays and meta (their source is part
#: of every key: editing one retires every entry).
RESULT_MODULES = ("bake.simplify", "bake.collapse", "bake.meshlab", "bake.seams", "bake.cell_seams", "bake.pieces",
                  "bake.hausdorff", "model.appearance", "model.hierarchy", "core.arrays", "bake.octree", "bake.settings",
                  "bake.prepare", "bake.sources", "bake.partition", "bake.leaf_arrays", "bake.tasks", "bake.schedule",
                  "bake.assemble", "bake.meta", "bake.pipeline", "bake.cache", "bake.cache_files", "bake.lattice")
#: Temporary files older than this (seconds) are a crashed writer's: prune removes them.
_STALE_TEMP_SECONDS = 3600.0
_CACHEDIR_TAG = (b"Signature: 8a477f597d28d172789f06886806bc55\n"
                 b"# An HLOD bake cache (hlod_core.bake.cache): safe to delete; the next bake rebuilds it.\n")


def default_folder(output: str | os.PathLike) -> Path:
    """The cache folder of a bake writing `output`: OUT.hlod.cache beside it."""
    output = Path(output)
    return output.with_name(output.name + ".cache")


def folder_for(output: str | os.PathLike, *, folder: str | os.PathLike | None = None,
               enabled: bool = True) -> Path | None:
    """The cache folder of a bake writing `output` (every front end asks here): `folder` if given,
    else OUT.hlod.cache beside the output (`default_folder`); None when the cache is not enabled.
    InputError (check_folder) when it names a file."""
    if not enabled:
        return None
    chosen = Path(folder) if folder else default_folder(output)
    check_folder(chosen)
    return chosen


def check_folder(folder: str | os.PathLike | None) -> None:
    """Raise InputError when `folder` (None: no cache) names something that is not a folder."""
    if folder is not None and os.path.lexists(folder) and not os.path.isdir(folder):
        raise InputError(f"{folder}: is a file; the bake cache is a folder (give another with --cache, or --no-cache)")


def context_digest(settings: DecimationSettings, *, with_normals: bool,
                   row_layout: AttributeLayout | None, error: str = "exact") -> bytes:
    """32 bytes: everything besides a subtree's triangles that its LODs and errors depend on;
    error: the error measure (BakeSettings.error), so a bound is never served for an exact error
    nor the other way round."""
    core = Path(__file__).resolve().parent.parent
    code = hashlib.blake2b(digest_size=KEY_BYTES)
    for name in RESULT_MODULES:
        try:
            code.update((core / f"{name.replace('.', '/')}.py").read_bytes())
        except OSError:  # not installed as source files: the versions below still key it
            code.update(name.encode())
    described = {
        "cache_version": cache_files.CACHE_VERSION,
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
    return hashlib.blake2b(json.dumps(described, sort_keys=True).encode(), digest_size=KEY_BYTES).digest()


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
    h = hashlib.blake2b(context, digest_size=KEY_BYTES, person=b"hlod input")
    h.update(np.asarray([max_depth], "<i8").tobytes())
    for part in (mesh.positions, mesh.faces, mesh.normals, mesh.uvs, mesh.colors, mesh.material_ids):
        _hash_array(h, part)
    h.update(json.dumps([m.to_json() for m in mesh.materials], sort_keys=True).encode())
    return h.digest()


def node_keys(layout: OctreeLayout, lods: list, *, origin: np.ndarray, context: bytes,
              unit_length: float = 0.0, seams=None) -> list[bytes]:
    """(n,) 32-byte keys, one per node (module docstring). lods: per node (positions, faces,
    normals or None, attribute rows or None); only the leaves' are read; unit_length: the lattice
    the positions are points of (lattice.py), which the decimations snap to; seams
    (cell_seams.CellSeams or None): an inner node's key hashes the positions it shares with the
    cells around it too, which its decimation keeps in place."""
    n = layout.node_count
    keys: list[bytes] = [b""] * n
    cells = np.zeros(n, [("origin", "<f8", 3), ("unit", "<f8"), ("center", "<f8", 3), ("half", "<f8"),
                         ("level", "<i8")])
    cells["origin"], cells["unit"], cells["center"] = origin, unit_length, layout.cell_center
    cells["half"], cells["level"] = layout.cell_half, layout.cell_level
    for node in range(n - 1, -1, -1):  # children have larger ids than their parent
        if layout.child_count[node] == 0:
            h = hashlib.blake2b(context, digest_size=KEY_BYTES, person=b"hlod leaf")
            h.update(cells[node].tobytes())
            for part in lods[node]:
                _hash_array(h, part)
        else:
            h = hashlib.blake2b(context, digest_size=KEY_BYTES, person=b"hlod node")
            h.update(cells[node].tobytes())
            first = int(layout.child_offset[node])
            h.update(b"".join(keys[first:first + int(layout.child_count[node])]))
            if seams is not None:
                h.update(seams.digest(node))
        keys[node] = h.digest()
    return keys


class BakeCache:
    """One bake's view of a cache folder. The pipeline's entry points: `open`, `whole_result`,
    `reuse`, `finish` (module docstring). Below them: `load` node entries and `store` the bake's
    new ones, `load_result` / `store_result` the whole result, `prune`. with_normals / row_layout:
    what the bake carries (part of the keys; every entry must match it); error: the error measure
    (part of the keys). Statistics for the bake's meta: reused_nodes, reused_tris, rejected
    (entries ignored: (file name, why))."""

    def __init__(self, folder: str | os.PathLike, *, decimation: DecimationSettings, with_normals: bool,
                 row_layout: AttributeLayout, error: str = "exact"):
        check_folder(folder)
        self.folder = Path(folder)
        self.with_normals = with_normals
        self.row_width = row_layout.width
        self.context = context_digest(decimation, with_normals=with_normals, row_layout=row_layout, error=error)
        self.reused_nodes = 0
        self.reused_tris = 0
        self.rejected: list[tuple[str, str]] = []
        # one bake's state (open, reuse): the input's key and materials, the nodes' keys, the reused nodes
        self._result_key, self._materials = b"", ()
        self._keys: list[bytes] = []
        self._inner = np.zeros(0, np.int64)
        self._reused: set[int] = set()

    @classmethod
    def open(cls, folder: str | os.PathLike | None, *, mesh: TriangleMesh,
             settings: BakeSettings) -> "BakeCache | None":
        """The cache of a bake of `mesh` at `settings` in `folder`; None without a folder.
        InputError when `folder` is a file."""
        if folder is None:
            return None
        row_layout = AttributeLayout(material=mesh.material_ids is not None, uv=mesh.uvs is not None,
                                     color=mesh.colors is not None)
        cache = cls(folder, decimation=settings.decimation(), with_normals=mesh.normals is not None,
                    row_layout=row_layout, error=settings.error)
        cache._result_key = input_key(mesh, max_depth=settings.max_depth, context=cache.context)
        cache._materials = tuple(mesh.materials) if mesh.has_appearance else ()
        return cache

    def whole_result(self) -> tuple[Hlod, dict, dict] | None:
        """The whole result of an unchanged input (the bake is then skipped): (Hlod without meta,
        its derived meta entries, meta["cache"]); None when the folder holds none."""
        found = self.load_result(self._result_key, self._materials)
        if found is None:
            return None
        hlod, derived = found
        inner = int((~hlod.is_leaf).sum())
        stats = self._stats(nodes=inner, reused=inner, whole=True)
        stats["reused_tris"] = int(hlod.tri_count[~hlod.is_leaf].sum())
        return hlod, derived, stats

    def reuse(self, layout: OctreeLayout, lods: list, *, origin: np.ndarray,
              unit_length: float, seams=None) -> dict[int, tuple[NodeLod, float]]:
        """The inner nodes whose subtree the folder holds: node -> (LOD, error). lods: per node, the
        leaves' (positions, faces, normals, rows) (the keys hash them); origin (3,) float64;
        unit_length: the lattice's (lattice.py); seams: cell_seams.CellSeams (node_keys)."""
        self._keys = node_keys(layout, lods, origin=origin, context=self.context, unit_length=unit_length,
                               seams=seams)
        self._inner = np.flatnonzero(~layout.is_leaf)
        hits = {}
        for node in self._inner:
            hit = self.load(self._keys[node])
            if hit is not None:
                hits[int(node)] = hit
        self._reused = set(hits)
        return hits

    def finish(self, hlod: Hlod, derived: dict, *, made: dict[int, NodeLod], hausdorff_error: np.ndarray) -> dict:
        """Once the bake is complete: write the inner nodes it made (made: node -> LOD, with
        hausdorff_error (n,) float64) and its whole result (hlod, derived meta entries), remove the
        entries it did not use; returns meta["cache"]."""
        self.store({self._keys[node]: (made[int(node)], float(hausdorff_error[node])) for node in self._inner
                    if int(node) not in self._reused})
        self.store_result(self._result_key, hlod, derived)
        self.prune({self._keys[node] for node in self._inner}, self._result_key)
        return self._stats(nodes=int(self._inner.size), reused=len(self._reused), whole=False)

    def _stats(self, *, nodes: int, reused: int, whole: bool) -> dict:
        """meta["cache"]: nodes (inner nodes: leaves keep their triangles and are never cached),
        reused_nodes / rebuilt_nodes (decimated and measured in this bake), reused_tris (LOD triangles
        of the reused nodes), rejected_entries (corrupt ones, rebuilt), reused_result (the whole
        result came from the cache: the input had not changed)."""
        self.report()
        log.info("bake cache %s: %d of %d inner nodes reused%s", self.folder, reused, nodes,
                 " (the whole result: the input is unchanged)" if whole else "")
        return {"nodes": nodes, "reused_nodes": reused, "rebuilt_nodes": nodes - reused,
                "reused_tris": self.reused_tris, "rejected_entries": len(self.rejected), "reused_result": whole}

    def path(self, key: bytes, suffix: str = ENTRY_SUFFIX) -> Path:
        return self.folder / f"{key.hex()}{suffix}"

    def load(self, key: bytes) -> tuple[NodeLod, float] | None:
        """A node entry's (LOD, Hausdorff error), or None: absent, or rejected (counted)."""
        found = self._read(key, ENTRY_SUFFIX, "node")
        if found is None:
            return None
        try:
            lod, error = cache_files.node_entry(*found, with_normals=self.with_normals, row_width=self.row_width)
        except CorruptEntry as exc:
            self.rejected.append((self.path(key).name, str(exc)))
            return None
        self.reused_nodes += 1
        self.reused_tris += int(lod.faces.shape[0])
        return lod, error

    def load_result(self, key: bytes, materials: tuple) -> tuple[Hlod, dict] | None:
        """A result entry's (Hlod with `materials`, empty meta; the DERIVED_META it keeps), or None."""
        found = self._read(key, RESULT_SUFFIX, "result")
        if found is None:
            return None
        try:
            return cache_files.result_entry(*found, materials=materials, with_normals=self.with_normals,
                                            has_rows=self.row_width > 0)
        except CorruptEntry as exc:
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
            return cache_files.unpack(data, key, kind)
        except CorruptEntry as exc:
            self.rejected.append((path.name, str(exc)))
            return None

    def store(self, entries: dict[bytes, tuple[NodeLod, float]]) -> None:
        """Write node entries (key -> (LOD, error)), each atomically."""
        self._write((self.path(key), cache_files.node_entry_bytes(key, lod, error))
                    for key, (lod, error) in entries.items())

    def store_result(self, key: bytes, hlod: Hlod, meta: dict) -> None:
        """Write the result entry of a bake: its arrays and its DERIVED_META entries found in `meta`."""
        self._write([(self.path(key, RESULT_SUFFIX), cache_files.result_entry_bytes(key, hlod, meta))])

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
