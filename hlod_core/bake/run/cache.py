"""The bake cache: inner nodes' LODs and errors, keyed by what they were made from, the whole
results of earlier bakes and the last bake's frame. The cache owns its policy: `BakeCache.open` (no
folder: no cache), `prior` (the frame a re-bake starts from, bake/space/frame.py), `whole_result` (an unchanged
input skips the bake), `reuse` (the inner nodes whose subtree is unchanged), `finish` (writing,
evicting, meta["cache"]); `folder_for` says where it lives.

Data form: a folder (by default `OUT.hlod.cache/` beside the output; safe to delete at any time:
the next bake is then a bake from scratch) holding a CACHEDIR.TAG and
- one file per inner node, `<key>.hlodc`: the node's LOD (positions (k,3) float32 origin-relative,
  faces (m,3) int32, normals (k,3) float32 and attribute rows (k,A) float32 when the bake has
  them), its error (float64, model units: the Hausdorff error, or its bound), what the bake log
  says of it (`SUMMARY_FIELDS`) and its proxy material, if it made one;
- one file per whole result, `<result key>.hlodr`: every array of a bake's Hlod, the meta entries
  the bake derives (meta.DERIVED_META) and the keys of the node entries it used, keyed by the whole
  input and the bake's frame (`input_key`, `result_key`), and with proxy materials every texture
  the bake wrote with its node, the proxy materials and meta["proxies"];
- `frame.json`: the frames of the last bakes (frame.Frame.to_meta), the latest first: the next
  bake starts from the latest, and takes a whole result baked in any of them.

Keys (cache_keys.py): a Merkle tree over the octree, equal keys for equal results.
Why: docs/how-it-works.md#re-bakes-and-the-cache-keys

Proxy materials (cache_proxies.py): in a bake that makes them, a node entry also holds the node's
proxy (its texture's PNG bytes and the gate's figures; the atlas UVs are its rows) and its rows
name proxies by their path below the node, so a hit is renumbered into the new bake's nodes. A hit
counts only where every inner node below it is a hit too (a parent's proxy task reads its
children's textures). A whole result holds the bake's textures too, and its key the materials'
digests (pixels included): a hit writes the textures into this bake's texture folder, once the
whole entry has passed its checks, and names them from there.

Integrity: a file starts with magic, CACHE_VERSION, the payload's length and its blake2b digest;
`load` and `load_result` check all of them, the key and kind recorded inside, and every array's
dtype, shape and index range (a result: hlod_file.validate, as a .hlod file is) before using
anything. An entry that fails is ignored (a miss), counted, named once in the log at the end of
the bake, and rebuilt; nothing is read with pickle. Entries are written once a bake is complete
(a cancelled bake writes none), each to a temporary name and renamed into place; they are not
fsynced: a file torn by a crash fails its digest and is rebuilt.

Size: entries are kept across bakes within a budget (`DEFAULT_BUDGET_MB`, settable): after a
complete bake the least recently used entries (file modification times: a bake touches every entry
it reads) are removed until the folder fits, never one the bake used (`prune`). So an undo re-bakes
from the cache, and bakes of different scenes sharing one folder keep each other's entries while
they fit. One bake's entries take about 1.5 times its .hlod, plus its proxies' textures twice (in
the node entries and in the whole result), which the budget counts.
"""
from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ...core.errors import InputError
from ...core.jsonutil import JsonError, loads
from ...io.meshes import TriangleMesh
from ...model.appearance import AttributeLayout
from ...model.hierarchy import Hlod
from ..appearance.proxy import ProxySettings
from ..appearance.proxy_plan import ProxyPlan
from ..decimate.meshlab import DecimationSettings
from ..decimate.simplify import NodeLod
from ..settings import BakeSettings
from ..space.frame import Frame, Prior
from ..space.octree import OctreeLayout
from . import cache_files, cache_proxies
from .cache_files import CorruptEntry
from .cache_keys import context_digest, input_key, material_digests, node_keys, result_key

log = logging.getLogger(__name__)

ENTRY_SUFFIX = ".hlodc"
RESULT_SUFFIX = ".hlodr"
FRAME_FILE = "frame.json"
#: Frames frame.json keeps (an undo finds the whole result of an input baked in any of them).
RECENT_FRAMES = 8
#: The folder's size budget (MB, 2^20 bytes) unless the bake sets one: about 25 bakes of a
#: 1.5M-triangle scene.
DEFAULT_BUDGET_MB = 1024.0
#: Temporary files older than this (seconds) are a crashed writer's: prune removes them.
_STALE_TEMP_SECONDS = 3600.0
_CACHEDIR_TAG = (b"Signature: 8a477f597d28d172789f06886806bc55\n"
                 b"# An HLOD bake cache (hlod_core.bake.run.cache): safe to delete; the next bake rebuilds it.\n")


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


class BakeCache:
    """One bake's view of a cache folder. The pipeline's entry points: `open`, `prior`,
    `whole_result`, `reuse`, `finish` (module docstring). Below them: `load` node entries and `store`
    the bake's new ones, `load_result` / `store_result` whole results, `prune`. with_normals /
    row_layout: what the bake carries (part of the keys; every entry must match it); error: the error
    measure (part of the keys); budget_mb: the folder's size budget (MB); proxies: the proxy
    materials' settings of a bake that makes them (part of the keys). Statistics for the bake's
    meta: reused_nodes, reused_tris, rejected (entries ignored: (file name, why))."""

    def __init__(self, folder: str | os.PathLike, *, decimation: DecimationSettings, with_normals: bool,
                 row_layout: AttributeLayout, error: str = "exact", budget_mb: float = DEFAULT_BUDGET_MB,
                 proxies: ProxySettings | None = None):
        check_folder(folder)
        if not (budget_mb >= 0 and np.isfinite(budget_mb)):
            raise InputError(f"bake cache budget {budget_mb} MB: expected a number of MB >= 0")
        self.folder = Path(folder)
        self.with_normals = with_normals
        self.row_width = row_layout.width
        self.budget_mb = float(budget_mb)
        self.context = context_digest(decimation, with_normals=with_normals, row_layout=row_layout, error=error,
                                      proxies=proxies)
        self.reused_nodes = 0
        self.reused_tris = 0
        self.rejected: list[tuple[str, str]] = []
        # one bake's state (open, reuse): the input's digest and materials, the nodes' keys, the reused nodes
        self._input_digest, self._materials = b"", ()
        self._recent: list[Frame] = []  # frame.json's frames, the latest first
        self._keys: list[bytes] = []
        self._inner = np.zeros(0, np.int64)
        self._reused: set[int] = set()
        # a bake that makes proxy materials (open): its plan, the leaves' material looks, the octree (reuse)
        self._plan: ProxyPlan | None = None
        self._looks: tuple[int, np.ndarray] | None = None
        self._layout: OctreeLayout | None = None

    @classmethod
    def open(cls, folder: str | os.PathLike | None, *, mesh: TriangleMesh, settings: BakeSettings,
             budget_mb: float = DEFAULT_BUDGET_MB, plan: ProxyPlan | None = None) -> "BakeCache | None":
        """The cache of a bake of `mesh` at `settings` in `folder`; None without a folder. plan: the
        bake's proxy materials (module docstring; None: it makes none). InputError when `folder`
        is a file or the budget is not a number of MB >= 0."""
        if folder is None:
            return None
        row_layout = AttributeLayout(material=mesh.material_ids is not None, uv=mesh.uvs is not None,
                                     color=mesh.colors is not None)
        cache = cls(folder, decimation=settings.decimation(), with_normals=mesh.normals is not None,
                    row_layout=row_layout, error=settings.error, budget_mb=budget_mb,
                    proxies=None if plan is None else plan.settings)
        if plan is not None:
            cache._plan = plan
            cache._looks = (plan.material_column, material_digests(plan.scene_materials, plan.images))
        cache._input_digest = input_key(mesh, max_depth=settings.max_depth, context=cache.context,
                                        looks=None if cache._looks is None else cache._looks[1])
        cache._materials = tuple(mesh.materials) if mesh.has_appearance else ()
        cache._recent = cache._read_frames()
        return cache

    def prior(self) -> Prior | None:
        """The last bake's frame (frame.json), which this bake starts from; None when the folder
        holds none."""
        return Prior(self._recent[0], "cache") if self._recent else None

    def _read_frames(self) -> list[Frame]:
        """frame.json's frames, the latest first; none when it is absent (an unreadable one is
        logged and ignored: the bake then takes the input's frame)."""
        path = self.folder / FRAME_FILE
        try:
            text = path.read_bytes()
        except FileNotFoundError:
            return []
        except OSError as exc:
            log.warning("bake cache %s: cannot read %s (%s); the bake takes the input's frame", self.folder,
                        FRAME_FILE, exc.strerror or exc)
            return []
        try:
            return [Frame.from_meta(e, where=str(path)) for e in loads(text)["frames"][:RECENT_FRAMES]]
        except (JsonError, KeyError, TypeError, InputError) as exc:
            log.warning("bake cache %s: %s ignored (%s); the bake takes the input's frame", self.folder, FRAME_FILE,
                        exc)
            return []

    def whole_result(self, prior: Prior | None) -> tuple[Hlod, dict, dict, Frame] | None:
        """The whole result of an unchanged input (the bake is then skipped): in the `prior` frame of
        a file, or in any recent frame of the folder's (`prior`). (Hlod without meta, its derived
        meta entries, meta["cache"], its frame); None when the folder holds none. With proxy
        materials the result's textures are written as the bake writes them (ProxyPlan.restore),
        once the entry has passed every check, and meta["proxies"] is a derived entry."""
        if prior is None:
            return None
        frames = [prior.frame] if prior.source != "cache" else self._recent
        for frame in frames:
            key = result_key(self._input_digest, frame)
            found = self.load_result(key, self._materials)
            if found is not None:
                break
        else:
            return None
        hlod, derived, used, textures = found
        for node, fields, png in textures:
            self._plan.restore(node, fields, png)
        self._touch([self.path(k) for k in used])
        self._record_frame(frame)
        inner = int((~hlod.is_leaf).sum())
        stats = self._stats(nodes=inner, reused=inner, whole=True, folder=self.prune(set(used), key))
        stats["reused_tris"] = int(hlod.tri_count[~hlod.is_leaf].sum())
        return hlod, derived, stats, frame

    def reuse(self, layout: OctreeLayout, lods: list, *, origin: np.ndarray,
              unit_length: float, seams=None) -> dict[int, tuple[NodeLod, float]]:
        """The inner nodes whose subtree the folder holds: node -> (LOD, error). lods: per node, the
        leaves' (positions, faces, normals, rows) (the keys hash them); origin (3,) float64;
        unit_length: the lattice's (bake/space/lattice.py); seams: cell_seams.CellSeams (node_keys). With proxy
        materials, a node whose inner nodes below are not all hits is not one, and each hit's proxy
        goes to the plan (ProxyPlan.restore: its texture is written)."""
        self._keys = node_keys(layout, lods, origin=origin, context=self.context, unit_length=unit_length,
                               seams=seams, looks=self._looks)
        self._inner = np.flatnonzero(~layout.is_leaf)
        self._layout = layout
        hits = {}
        for node in self._inner:
            hit = self._entry(self._keys[node], int(node))
            if hit is not None:
                hits[int(node)] = hit
        if self._plan is not None:
            hits = whole_subtrees(layout, hits)
            for node, (_, _, proxy) in hits.items():
                if proxy is not None:
                    self._plan.restore(node, *proxy)
        self._reused = set(hits)
        self._touch([self.path(self._keys[node]) for node in hits])
        self.reused_nodes += len(hits)
        self.reused_tris += sum(int(lod.faces.shape[0]) for lod, _, _ in hits.values())
        return {node: (lod, error) for node, (lod, error, _) in hits.items()}

    def finish(self, hlod: Hlod, derived: dict, *, made: dict[int, NodeLod], hausdorff_error: np.ndarray,
               frame: Frame) -> dict:
        """Once the bake is complete: write the inner nodes it made (made: node -> LOD, with
        hausdorff_error (n,) float64), its whole result (hlod, derived meta entries) and its frame,
        evict the least recently used entries over the budget; returns meta["cache"]."""
        self.store({self._keys[node]: self._entry_parts(int(node), made[int(node)], float(hausdorff_error[node]))
                    for node in self._inner if int(node) not in self._reused})
        used = [self._keys[node] for node in self._inner]
        key = result_key(self._input_digest, frame)
        proxies = ({}, {}) if self._plan is None else cache_proxies.result_parts(self._plan, hlod.materials,
                                                                               derived.get("proxies"))
        self.store_result(key, hlod, derived, node_keys=used, proxies=proxies)
        self._record_frame(frame)
        folder = self.prune(set(used), key)
        return self._stats(nodes=int(self._inner.size), reused=len(self._reused), whole=False, folder=folder)

    def _stats(self, *, nodes: int, reused: int, whole: bool, folder: dict) -> dict:
        """meta["cache"]: nodes (inner nodes: leaves keep their triangles and are never cached),
        reused_nodes / rebuilt_nodes (decimated and measured in this bake), reused_tris (LOD triangles
        of the reused nodes), rejected_entries (corrupt ones, rebuilt), reused_result (the whole
        result came from the cache: the input had not changed), and the folder's budget_mb,
        size_mb and evicted_entries (`prune`)."""
        self.report()
        log.info("bake cache %s: %d of %d inner nodes reused%s", self.folder, reused, nodes,
                 " (the whole result: the input is unchanged)" if whole else "")
        return {"nodes": nodes, "reused_nodes": reused, "rebuilt_nodes": nodes - reused,
                "reused_tris": self.reused_tris, "rejected_entries": len(self.rejected), "reused_result": whole,
                **folder}

    def _record_frame(self, frame: Frame) -> None:
        """frame.json: `frame` first (the next bake starts from it), then the other recent ones."""
        entry = frame.to_meta()
        frames = [entry] + [f.to_meta() for f in self._recent if f.to_meta() != entry][:RECENT_FRAMES - 1]
        self._write([(self.folder / FRAME_FILE, json.dumps({"frames": frames}).encode())])

    def path(self, key: bytes, suffix: str = ENTRY_SUFFIX) -> Path:
        return self.folder / f"{key.hex()}{suffix}"

    def load(self, key: bytes) -> tuple[NodeLod, float] | None:
        """A node entry's (LOD, Hausdorff error), or None: absent, or rejected (counted)."""
        hit = self._entry(key)
        if hit is None:
            return None
        self._touch([self.path(key)])
        self.reused_nodes += 1
        self.reused_tris += int(hit[0].faces.shape[0])
        return hit[0], hit[1]

    def _entry(self, key: bytes, node: int | None = None) -> tuple[NodeLod, float, tuple | None] | None:
        """A node entry's (LOD, Hausdorff error, its own proxy: (ProxyMade fields, PNG bytes) or None),
        or None: absent, or rejected (recorded). node: where it goes in this bake, with proxy
        materials: its rows' proxies are renumbered (cache_proxies.decode)."""
        found = self._read(key, ENTRY_SUFFIX, "node")
        if found is None:
            return None
        try:
            lod, error = cache_files.node_entry(*found, with_normals=self.with_normals, row_width=self.row_width)
            proxy = None
            if self._plan is not None and node is not None:
                extra, arrays = found
                rows = cache_proxies.decode(lod.attributes, extra.get(cache_proxies.PATHS, []), node, self._layout,
                                            scene_materials=len(self._plan.scene_materials),
                                            column=self._plan.material_column)
                lod, proxy = dataclasses.replace(lod, attributes=rows), cache_proxies.own_proxy(extra, arrays)
        except CorruptEntry as exc:
            self.rejected.append((self.path(key).name, str(exc)))
            return None
        return lod, error, proxy

    def _entry_parts(self, node: int, lod: NodeLod, error: float) -> tuple:
        """What node_entry_bytes writes of a node this bake made: (LOD, error) and, with proxy
        materials, the LOD with its proxies' ids relative to the node, the entry's extra and arrays
        (cache_proxies)."""
        if self._plan is None:
            return lod, error
        plan = self._plan
        rows, paths = cache_proxies.encode(lod.attributes, node, self._layout,
                                           scene_materials=len(plan.scene_materials), column=plan.material_column)
        extra, arrays = {cache_proxies.PATHS: paths}, {}
        made = plan.made_proxies.get(node)
        if made is not None:
            extra[cache_proxies.FIELDS] = cache_proxies.own_extra(made)
            arrays[cache_proxies.PNG] = np.frombuffer(plan.texture_bytes(node), np.uint8)
        return dataclasses.replace(lod, attributes=rows), error, extra, arrays

    def load_result(self, key: bytes, materials: tuple) -> tuple[Hlod, dict, list[bytes], list] | None:
        """A result entry's (Hlod with `materials` and its proxy materials, empty meta; the
        DERIVED_META it keeps, and meta["proxies"]; the keys of the node entries its bake used; its
        textures: [(node, ProxyMade fields but the file, PNG bytes)]), or None. A result read is
        touched (`prune`). Every check passes before anything is written."""
        found = self._read(key, RESULT_SUFFIX, "result")
        if found is None:
            return None
        textures, proxies_meta = [], None
        try:
            if self._plan is not None:
                textures, own, proxies_meta = cache_proxies.result_proxies(*found, reference=self._plan.reference)
                materials = tuple(materials) + own
            hlod, derived, used = cache_files.result_entry(*found, materials=materials, with_normals=self.with_normals,
                                                           has_rows=self.row_width > 0)
            if any(node >= hlod.node_count or hlod.is_leaf[node] for node, _, _ in textures):
                raise CorruptEntry("a proxy texture of a node that is not an inner node")
        except CorruptEntry as exc:
            self.rejected.append((self.path(key, RESULT_SUFFIX).name, str(exc)))
            return None
        if proxies_meta is not None:
            derived["proxies"] = proxies_meta
        self._touch([self.path(key, RESULT_SUFFIX)])
        return hlod, derived, used, textures

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

    def store(self, entries: dict[bytes, tuple]) -> None:
        """Write node entries (key -> (LOD, error[, extra, arrays]): node_entry_bytes), each atomically."""
        self._write((self.path(key), cache_files.node_entry_bytes(key, *parts)) for key, parts in entries.items())

    def store_result(self, key: bytes, hlod: Hlod, meta: dict, *, node_keys: list[bytes],
                     proxies: tuple[dict, dict] = ({}, {})) -> None:
        """Write the result entry of a bake: its arrays, its DERIVED_META entries found in `meta`, the
        keys of the node entries it used and its proxies' (extra, arrays) (cache_proxies.result_parts)."""
        data = cache_files.result_entry_bytes(key, hlod, meta, node_keys=node_keys, extra=proxies[0], more=proxies[1])
        self._write([(self.path(key, RESULT_SUFFIX), data)])

    @staticmethod
    def _touch(paths: list[Path]) -> None:
        """Mark entries as used now (their modification time: `prune` evicts the oldest first)."""
        now = time.time_ns()
        for path in paths:
            with contextlib.suppress(OSError):
                os.utime(path, ns=(now, now))

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

    def prune(self, used: set[bytes], result: bytes) -> dict:
        """Remove temporary files of writers that died, then the least recently used entries (oldest
        modification time first, then by name) until the folder fits the budget, never a node entry
        whose key is in `used` nor `result`'s entry. Returns {"budget_mb", "size_mb" (after),
        "evicted_entries"}."""
        keep = {f"{key.hex()}{ENTRY_SUFFIX}" for key in used} | {f"{result.hex()}{RESULT_SUFFIX}"}
        now = time.time()
        try:
            listing = list(os.scandir(self.folder))
        except OSError:
            return self._folder_stats(0, 0)
        entries, size = [], 0
        for entry in listing:
            if entry.name.startswith(".") and entry.name.endswith(".tmp") and _age(entry, now) > _STALE_TEMP_SECONDS:
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)
                continue
            try:
                stat = entry.stat()
            except OSError:
                continue
            size += stat.st_size
            if entry.name.endswith((ENTRY_SUFFIX, RESULT_SUFFIX)) and entry.name not in keep:
                entries.append((stat.st_mtime_ns, entry.name, stat.st_size, entry.path))
        evicted = 0
        budget = self.budget_mb * 2**20
        for _, _, bytes_, path in sorted(entries):
            if size <= budget:
                break
            with contextlib.suppress(OSError):
                os.unlink(path)
                size -= bytes_
                evicted += 1
        return self._folder_stats(size, evicted)

    def _folder_stats(self, size: int, evicted: int) -> dict:
        return {"budget_mb": self.budget_mb, "size_mb": round(size / 2**20, 3), "evicted_entries": evicted}

    def report(self) -> None:
        """Log the rejected entries once (at the end of a bake)."""
        if self.rejected:
            name, why = self.rejected[0]
            log.warning("bake cache %s: %d entries ignored and rebuilt (first: %s: %s)", self.folder,
                        len(self.rejected), name, why)


def whole_subtrees(layout: OctreeLayout, hits: dict) -> dict:
    """The hits every inner node below which is a hit too (deepest first: children have larger ids)."""
    whole = dict(hits)
    for node in sorted(hits, reverse=True):
        first, count = int(layout.child_offset[node]), int(layout.child_count[node])
        if any(not layout.is_leaf[child] and child not in whole for child in range(first, first + count)):
            del whole[node]
    return whole


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
