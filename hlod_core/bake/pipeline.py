"""Bake an octree HLOD from triangles (DESIGN §4), as a pipeline of named phases:

    prepare  -> the origin (the centre of the used vertices' box); file-relative float32
                positions, triangle centroids, the root cell (octree.tight_cube); with appearance, the vertices become attribute rows
                (appearance.pack: a vertex split per material)
    octree   -> top-down partition of the root cell, split at cell centres (octree.build_octree)
    leaves   -> each leaf keeps its original triangles (and their exact attribute rows)
    cache    -> with a cache folder (bake_cache.py): an input it holds the whole result of comes
                back from it at once; otherwise the inner nodes whose subtree it holds take their
                LODs and errors from it
    simplify -> the other inner nodes bottom-up: weld, quadric decimation, Hausdorff MSE
                (simplify.py, `BakeSettings.error`); independent subtrees run in parallel worker
                processes (`jobs`)
    assemble -> one vertex and one index buffer, node ranges; with appearance, UVs, colours and
                triangle materials, each node's triangles sorted by material (one draw per
                (node, material))
    bounds   -> tight nested boxes, nested spheres, monotone MSE, cube sides (vectorised per level)

After Charalambos' dissertation (`../shared/papers/charalambos2007-dissertation-hlod-refinement-hoq.txt`
§3.3, §8: octree, one LOD of ~2000 triangles per node, offline bottom-up simplification).

An edit that keeps the input's box (and its centroids' box) keeps the origin, the float32 positions
of everything the edit does not touch, the octree's cells (octree.py) and the cache keys of their
subtrees; one that changes the box changes them all (a full re-bake). A node's LOD and error depend on its
subtree's input triangles and the settings only: decimation reads the children's LODs, and the
error compares the LOD with the leaves' triangles below the node (each leaf's vertices as that leaf
keeps them). That is what lets a re-bake take the unchanged subtrees from the cache, and the result
is the same file as a bake from scratch except for `VOLATILE_META` (timings and cache statistics);
the bake log lists nodes in id order, whichever way their LODs came.

Appearance (issue 13): a mesh with materials, UVs or colours bakes on attribute rows instead of
vertices; leaves keep them exact, inner nodes keep materials and UVs exact (simplify.py: material
borders and UV seams stay where they are, a LOD vertex takes the row of the input vertex it sits
on) and blend colours only where a colour jumps. Where keeping the UV seams would keep a LOD
above twice its target, that node crosses them (material borders still stay): faces inside one
UV island keep exact UVs, faces spanning two are stretched; the log names such nodes and
meta["uv_seams_crossed_nodes"] counts them. A mesh without any takes the path it always took,
with no attribute arrays. The node error stays the geometric Hausdorff MSE.

Out-of-core bakes (issue 16, `bake_partitioned`, stream_partition.bake_stream): an input bigger
than memory is never loaded whole. A stream of triangle chunks (stream_partition.py: a scene spec
one instance at a time) is read in passes: the origin, the root cell and the counted triangles
(the scan, _prepare's floats), one counting pass per octree depth (octree.build_octree_counted:
build_octree's layout from counts), then a routing pass into per-cell scratch files. Each leaf
reads only its cell's file (its vertices compacted in ascending input order, as _leaf_lods does)
and stays memory-mapped; the exact measure's leaf arrays are concatenated into memory-mapped
files. From there the phases are the ones above, so the file is `bake`'s of the merged input,
byte for byte except VOLATILE_META. What the bake's process still holds in its own memory grows
with the input: the inner nodes' LODs, hausdorff.Clusters.build's sort of the leaves' faces
(exact measure; about 60 bytes a triangle while it runs) and the assembled file (about 40).
Geometry only; no cache.

Error measures (issue 16, `BakeSettings.error`): "exact" measures each inner node's LOD against
every original triangle below it (hausdorff.measure, pruned: hausdorff.measure_clustered over the
leaves' triangles cut into clusters once per bake); "bound" measures it against its children's
LODs only (hausdorff.measure_to_children, h) and adds the largest child error (`_compose_bounds`):
    bound(leaf) = 0;  bound(n) = h(n) + max over children c of bound(c),  h(n) = H(LOD_n, U_c LOD_c).
Proof that bound(n) >= H(LOD_n, O_n) (O_n: the originals below n; by induction, H(LOD_c, O_c) <= bound(c)):
  x on LOD_n: some z on a child LOD_c has |x - z| <= h(n), and z is within bound(c) of O_c, a part of O_n;
  y in O_n lies in some O_c: within bound(c) of a point z of LOD_c, and z is within h(n) of LOD_n.
Both directions are at most h(n) + max bound(c) (triangle inequality); leaves are their originals.
Both figures are measured from samples (hausdorff.measure_to_children samples as measure does), so
the measured ones obey this up to the sampling (tests/test_error_bound.py says how much).
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import heapq
import logging
import multiprocessing
import os
import signal
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, replace
from typing import Callable

import numpy as np

from ..model import appearance
from . import cache as bake_cache, hausdorff as hausdorff_measure, simplify
from ..core.arrays import concat_indexed, segment_ranges
from ..core.errors import BakeCancelled, InputError
from ..model.hierarchy import Hlod, cube_sides, query_box_pad
from ..io.meshes import TriangleMesh
from .octree import OctreeLayout, RootCube, build_octree, tight_cube

log = logging.getLogger(__name__)

#: progress(done_nodes, total_nodes, phase)
ProgressFn = Callable[[int, int, str], None]
CancelFn = Callable[[], bool]

_MAX_LOG_LINES = 200

#: meta entries that differ between two bakes of the same input at the same settings: timings, and
#: what the cache did ("cache": {"nodes", "reused_nodes", "rebuilt_nodes", "reused_tris",
#: "rejected_entries"}, present when the bake had a cache folder). Everything else in the file is
#: the same whether a bake came from scratch or from the cache (`stable_meta`).
VOLATILE_META = ("bake_seconds", "phase_seconds", "cache")


def stable_meta(meta: dict) -> dict:
    """meta without VOLATILE_META: what two bakes of the same input and settings agree on."""
    return {k: v for k, v in meta.items() if k not in VOLATILE_META}


#: BakeSettings.error: the inner nodes' error measures (module docstring).
ERROR_MEASURES = ("exact", "bound")


@dataclass(frozen=True)
class BakeSettings:
    """target_tris: triangles per node (leaf budget and LOD size); max_depth: deepest node level
    (root = 0); jobs: worker processes for decimation (1 = in this process); error: the inner nodes'
    error measure, "exact" (against every original triangle below the node) or "bound" (against
    the children's LODs, plus their largest error: an upper bound, cheaper; module docstring); the
    rest go to simplify.DecimationSettings."""

    target_tris: int = 2000
    max_depth: int = 12
    jobs: int = 1
    quality_threshold: float = 0.3
    preserve_normals: bool = False
    boundary_weight: float = 1.0
    error: str = "exact"

    def __post_init__(self):
        if self.target_tris < 1:
            raise InputError(f"target_tris must be at least 1, got {self.target_tris}")
        if not 0 <= self.max_depth <= 64:
            raise InputError(f"max_depth must be between 0 and 64, got {self.max_depth}")
        if self.jobs < 1:
            raise InputError(f"jobs must be at least 1, got {self.jobs}")
        if not 0.0 <= self.quality_threshold <= 1.0:
            raise InputError(f"quality_threshold must be in [0, 1], got {self.quality_threshold}")
        if self.error not in ERROR_MEASURES:
            raise InputError(f"error must be one of {', '.join(ERROR_MEASURES)}, got {self.error!r}")

    def decimation(self) -> simplify.DecimationSettings:
        return simplify.DecimationSettings(target_tris=self.target_tris, quality_threshold=self.quality_threshold,
                                           preserve_normals=self.preserve_normals,
                                           boundary_weight=self.boundary_weight)


def bake(mesh: TriangleMesh, settings: BakeSettings = BakeSettings(), *,
         progress: ProgressFn | None = None, cancel: CancelFn | None = None,
         sources: list[str] | None = None, extra_meta: dict | None = None,
         cache_dir: str | os.PathLike | None = None, scheduler=None,
         scratch_dir: str | os.PathLike | None = None) -> Hlod:
    """Bake `mesh` into an Hlod. Raises InputError for unusable input, BakeCancelled if `cancel()`
    turns true (checked between nodes). Writes nothing to disk except worker scratch files and,
    with `cache_dir`, once the bake is complete, the cache folder (bake_cache.py: what it did not
    hold is added, the entries this bake did not use are removed).
    extra_meta: JSON-serialisable entries added to the HLOD's meta (the Blender side records the
    UV map and colour attribute names, "uv_map" and "color_attribute"); they may not replace the
    bake's own entries. The HLOD carries uvs / colors / tri_material and mesh.materials exactly
    when the mesh has them.
    scheduler: a Dask scheduler's address ("tcp://host:8786") or a distributed.Client: the simplify
    phase's tasks run on its workers instead of `settings.jobs` local processes (dask_cluster.py),
    for the same file; scratch_dir: a folder every worker reads (shared storage on a cluster;
    default the temporary folder), where the bake writes its shared arrays into a subfolder of its
    own, removed at the end. Neither is a setting: they change where the work runs, not the file."""
    started = time.perf_counter()
    progress, cancel, phases = _begin(progress, cancel, extra_meta)
    cache = result_key = None
    if cache_dir is not None:
        row_layout = appearance.AttributeLayout(material=mesh.material_ids is not None, uv=mesh.uvs is not None,
                                                color=mesh.colors is not None)
        cache = bake_cache.BakeCache(cache_dir, decimation=settings.decimation(), with_normals=mesh.normals is not None,
                                     row_layout=row_layout, error=settings.error)
        result_key = bake_cache.input_key(mesh, max_depth=settings.max_depth, context=cache.context)
        found = cache.load_result(result_key, tuple(mesh.materials) if mesh.has_appearance else ())
        if found is not None:
            hlod, derived = found
            phases.lap("cache")
            inner = ~hlod.is_leaf
            stats = _cache_stats(cache, nodes=int(inner.sum()), reused=int(inner.sum()), whole=True)
            stats["reused_tris"] = int(hlod.tri_count[inner].sum())
            progress(hlod.node_count, hlod.node_count, "done")
            return hlod.replace(meta=_meta(mesh, settings, derived, stats, sources=sources, extra_meta=extra_meta,
                                           seconds=time.perf_counter() - started, phases=phases))

    # Worker processes start now and import pymeshlab while this process prepares; an input of
    # one leaf has no inner node to simplify.
    jobs = settings.jobs if mesh.tri_count > settings.target_tris else 1
    cluster = scheduler if mesh.tri_count > settings.target_tris else None
    with _workers(jobs, scheduler=cluster, scratch_dir=scratch_dir) as workers:
        prepared = _prepare(mesh)
        phases.lap("prepare")
        layout = build_octree(prepared.centroids, target_tris=settings.target_tris, max_depth=settings.max_depth,
                              counted=prepared.counted, root=prepared.root_cell)
        prepared = replace(prepared, centroids=None)  # only the octree reads them: 24 bytes a triangle
        phases.lap("octree")
        n = layout.node_count
        progress(0, n, "octree")
        log.info("octree: %d nodes, %d leaves", n, int(layout.is_leaf.sum()))
        # per node (positions (k,3) f32, faces (m,3) int32, normals (k,3) f32 or None, attribute rows (k,A) f32 or None)
        lods: list[tuple] = [None] * n
        _leaf_lods(layout, lods, prepared)
        phases.lap("leaves")

        hausdorff = np.zeros(n, np.float64)
        made: dict[int, simplify.NodeLod] = {}  # inner node -> its LOD (and what the log says of it)
        inner = np.flatnonzero(~layout.is_leaf)
        keys = None
        if cache is not None:
            keys = bake_cache.node_keys(layout, lods, origin=prepared.origin, context=cache.context)
            for node in inner:
                hit = cache.load(keys[node])
                if hit is not None:
                    made[int(node)], hausdorff[node] = hit
                    lods[node] = (hit[0].positions, hit[0].faces, hit[0].normals, hit[0].attributes)
        from_cache = set(made)
        if cache is not None:
            phases.lap("cache")
        _simplify_phase(layout, lods, hausdorff, made, settings, workers=workers,
                        with_normals=prepared.normals is not None,
                        row_layout=None if prepared.rows is None else prepared.row_layout, cancel=cancel,
                        progress=progress)
        phases.lap("simplify")

    hlod = _assemble(layout, lods, prepared.origin, hausdorff, normals=prepared.normals is not None,
                     row_layout=prepared.row_layout)
    if mesh.has_appearance:
        hlod = hlod.replace(materials=tuple(mesh.materials))
    phases.lap("assemble")
    derived = _derived_meta(layout, made, hausdorff, _counted_per_node(layout, prepared.counted), settings,
                            collapsed_tris=int((~prepared.counted).sum()), with_rows=mesh.has_appearance)
    stats = None
    if cache is not None:
        cache.store({keys[node]: (made[int(node)], float(hausdorff[node])) for node in inner if node not in from_cache})
        cache.store_result(result_key, hlod, derived)
        cache.prune({keys[node] for node in inner}, result_key)
        stats = _cache_stats(cache, nodes=int(inner.size), reused=len(from_cache), whole=False)
        phases.lap("cache_write")
    progress(n, n, "done")
    return hlod.replace(meta=_meta(mesh, settings, derived, stats, sources=sources, extra_meta=extra_meta,
                                   seconds=time.perf_counter() - started, phases=phases))


def bake_partitioned(partition, settings: BakeSettings = BakeSettings(), *, progress: ProgressFn | None = None,
                     cancel: CancelFn | None = None, sources: list[str] | None = None, extra_meta: dict | None = None,
                     scheduler=None, scratch_dir: str | os.PathLike | None = None) -> Hlod:
    """Bake an input bigger than memory (module docstring, "Out-of-core bakes") through
    `partition`, a stream_partition.Partition whose block the caller holds open until this returns
    (stream_partition.bake_stream): its scratch folder holds the cell files and the memory-mapped
    leaves. The result is the file `bake` makes of the merged input, byte for byte except
    VOLATILE_META. Geometry only (normals kept); no cache. progress, cancel, sources, extra_meta,
    scheduler, scratch_dir: as for `bake`."""
    started = time.perf_counter()
    progress, cancel, phases = _begin(progress, cancel, extra_meta)
    scan = partition.scan()
    phases.lap("scan")
    several = scan.tri_count > settings.target_tris
    with _workers(settings.jobs if several else 1, scheduler=scheduler if several else None,
                  scratch_dir=scratch_dir) as workers:
        tree = partition.build_octree(target_tris=settings.target_tris, max_depth=settings.max_depth)
        layout = tree.layout
        phases.lap("octree")
        n = layout.node_count
        progress(0, n, "octree")
        log.info("octree: %d nodes, %d leaves (out of core)", n, int(layout.is_leaf.sum()))
        partition.route()
        phases.lap("route")
        lods: list[tuple] = [None] * n
        for leaf, (positions, faces, normals) in partition.mapped_leaf_lods(np.flatnonzero(layout.is_leaf)).items():
            lods[leaf] = (positions, faces, normals, None)  # memory-mapped from the scratch folder
        phases.lap("leaves")
        hausdorff = np.zeros(n, np.float64)
        made: dict[int, simplify.NodeLod] = {}
        _simplify_phase(layout, lods, hausdorff, made, settings, workers=workers, with_normals=scan.with_normals,
                        row_layout=None, cancel=cancel, progress=progress, mapped_in=partition.folder)
        phases.lap("simplify")
    hlod = _assemble(layout, lods, scan.origin, hausdorff, normals=scan.with_normals,
                     row_layout=appearance.AttributeLayout(False, False, False))
    del lods
    phases.lap("assemble")
    derived = _derived_meta(layout, made, hausdorff, tree.counted, settings,
                            collapsed_tris=scan.tri_count - scan.counted_count, with_rows=False)
    progress(n, n, "done")
    size = _InputSize(tris=scan.tri_count, vertices=scan.vertex_count, name=partition.source.name)
    return hlod.replace(meta=_meta(size, settings, derived, None, sources=sources, extra_meta=extra_meta,
                                   seconds=time.perf_counter() - started, phases=phases))


def _simplify_phase(layout: OctreeLayout, lods: list, hausdorff: np.ndarray, made: dict, settings: BakeSettings, *,
                    workers: "_Workers", with_normals: bool, row_layout: appearance.AttributeLayout | None,
                    cancel: CancelFn, progress: ProgressFn, mapped_in: str | os.PathLike | None = None) -> None:
    """The simplify phase: the inner nodes not in `made` (the cache's are, with their LODs in
    lods and errors in hausdorff) decimated and measured (_simplify_inner_nodes), made[node] set
    as each completes; with the "bound" measure the bounds composed (_compose_bounds). mapped_in:
    a folder for the exact measure's leaf arrays, memory-mapped (an out-of-core bake)."""
    n = layout.node_count
    inner = np.flatnonzero(~layout.is_leaf)
    from_cache = np.fromiter(made, np.int64, count=len(made))
    done = n - inner.size + len(made)
    progress(done, n, "simplify")

    def node_done(node: int, lod: simplify.NodeLod) -> None:
        nonlocal done
        made[node] = lod
        done += 1
        progress(done, n, "simplify")

    _simplify_inner_nodes(layout, lods, hausdorff, settings, workers=workers, with_normals=with_normals,
                          row_layout=row_layout, cancel=cancel, node_done=node_done, mapped_in=mapped_in)
    if cancel():
        raise BakeCancelled("bake cancelled")
    if settings.error == "bound":
        _compose_bounds(layout, hausdorff, rebuilt=np.setdiff1d(inner, from_cache))


def _begin(progress: ProgressFn | None, cancel: CancelFn | None, extra_meta: dict | None):
    """A bake's start: (progress, cancel, a _PhaseClock), the callbacks defaulted; InputError where
    extra_meta would replace the bake's own meta entries."""
    clash = sorted(set(extra_meta or {}) & _OWN_META)
    if clash:
        raise InputError(f"extra_meta may not replace the bake's own meta entries ({', '.join(clash)})")
    return progress or (lambda done, total, phase: None), cancel or (lambda: False), _PhaseClock()


#: The meta entries a bake writes itself (extra_meta may not replace them).
_OWN_META = frozenset({"generator", "input_tris", "input_vertices", "settings", "target_tris", "max_depth", "sources",
                       "bake_seconds", "phase_seconds", "cache", *bake_cache.RESULT_META})


def _counted_per_node(layout: OctreeLayout, counted: np.ndarray) -> np.ndarray:
    """(n,) int64: each node's counted triangles (counted (f,) bool, by input triangle)."""
    counted_below = np.concatenate([[0], np.cumsum(counted[layout.tri_order])])
    return counted_below[layout.tri_end] - counted_below[layout.tri_begin]


def _derived_meta(layout: OctreeLayout, made: dict, hausdorff: np.ndarray, counted_per_node: np.ndarray,
                  settings: BakeSettings, *, collapsed_tris: int, with_rows: bool) -> dict:
    """The meta entries the bake derives (bake_cache.RESULT_META): the log lists inner nodes in id
    order, however their LODs came. counted_per_node (n,) int64; collapsed_tris: the input's
    triangles that are not counted."""
    bake_log: list[str] = []
    inner = np.flatnonzero(~layout.is_leaf)
    for node in inner:
        _note_lod(bake_log, int(node), made[int(node)], hausdorff[node], settings.target_tris)
    derived = {
        "leaves_over_budget": int((layout.is_leaf & (counted_per_node > settings.target_tris)).sum()),
        "collapsed_input_tris": int(collapsed_tris),
        "log": bake_log[:_MAX_LOG_LINES],
        "log_lines_dropped": max(0, len(bake_log) - _MAX_LOG_LINES),
    }
    if with_rows:
        derived["uv_seams_crossed_nodes"] = sum(int(made[int(node)].uv_seams_crossed) for node in inner)
    return derived


def _cache_stats(cache: bake_cache.BakeCache, *, nodes: int, reused: int, whole: bool) -> dict:
    """meta["cache"]: nodes (inner nodes: leaves keep their triangles and are never cached),
    reused_nodes / rebuilt_nodes (decimated and measured in this bake), reused_tris (LOD triangles
    of the reused nodes), rejected_entries (corrupt ones, rebuilt), reused_result (the whole result
    came from the cache: the input had not changed)."""
    cache.report()
    log.info("bake cache %s: %d of %d inner nodes reused%s", cache.folder, reused, nodes,
             " (the whole result: the input is unchanged)" if whole else "")
    return {"nodes": nodes, "reused_nodes": reused, "rebuilt_nodes": nodes - reused, "reused_tris": cache.reused_tris,
            "rejected_entries": len(cache.rejected), "reused_result": whole}


def _meta(mesh: "TriangleMesh | _InputSize", settings: BakeSettings, derived: dict, cache_stats: dict | None, *,
          sources, extra_meta, seconds: float, phases: "_PhaseClock") -> dict:
    """The HLOD's meta, in one order whichever way the bake went (the file's bytes depend on it).
    mesh: the input (a TriangleMesh, or the _InputSize of a streamed one)."""
    size = _InputSize.of(mesh) if isinstance(mesh, TriangleMesh) else mesh
    meta = {
        "generator": "hlod_core",
        "input_tris": size.tris,
        "input_vertices": size.vertices,
        "settings": _settings_meta(settings),
        "target_tris": settings.target_tris,
        "max_depth": settings.max_depth,
        "sources": list(sources or [size.name]),
        "leaves_over_budget": derived["leaves_over_budget"],
        "collapsed_input_tris": derived["collapsed_input_tris"],
        "bake_seconds": seconds,
        "phase_seconds": phases.seconds,
        "log": derived["log"],
        "log_lines_dropped": derived["log_lines_dropped"],
    }
    if "uv_seams_crossed_nodes" in derived:
        meta["uv_seams_crossed_nodes"] = derived["uv_seams_crossed_nodes"]
    if cache_stats is not None:
        meta["cache"] = cache_stats
    meta.update(extra_meta or {})
    return meta


@dataclass(frozen=True)
class _InputSize:
    """What the meta says of the input: tris, vertices (used or not), name."""

    tris: int
    vertices: int
    name: str

    @staticmethod
    def of(mesh: TriangleMesh) -> "_InputSize":
        return _InputSize(tris=mesh.tri_count, vertices=int(mesh.positions.shape[0]), name=mesh.name)


def _settings_meta(settings: BakeSettings) -> dict:
    """meta["settings"]: the settings' fields, but `error` only when it is not "exact": a file
    without it was measured exactly (every file from before issue 16 too), and an exact bake
    writes the bytes it wrote before."""
    fields = asdict(settings)
    if fields["error"] == "exact":
        del fields["error"]
    return fields


def _compose_bounds(layout: OctreeLayout, hausdorff: np.ndarray, *, rebuilt: np.ndarray) -> None:
    """Bound mode: hausdorff[node] holds h(node) (hausdorff.measure_to_children) for the `rebuilt`
    inner nodes and the final bound for the others (leaves 0, cache entries); make the rebuilt ones
    h + the largest child bound, deepest level first (module docstring). A NaN (no distance from
    pymeshlab) stays NaN up the tree, and _assemble bounds each such node by its box diagonal."""
    pending = np.zeros(layout.node_count, bool)
    pending[rebuilt] = True
    for d in range(int(layout.depth.max()) - 1, -1, -1):
        nodes = np.flatnonzero((layout.depth == d) & pending)
        if nodes.size == 0:
            continue
        first, count = layout.child_offset[nodes], layout.child_count[nodes]
        kids = segment_ranges(first, count)
        worst = np.full(nodes.size, -np.inf)
        np.maximum.at(worst, np.repeat(np.arange(nodes.size), count), hausdorff[kids])
        hausdorff[nodes] += worst


@dataclass(frozen=True, eq=False)
class _Prepared:
    """The bake's input as the octree and the leaves see it: root (octree.RootCube, model units)
    and origin (3,) f64, its centre; positions (r,3) f32 relative to it, faces (f,3) int64, normals
    (r,3) f32 or None and attribute rows (r,A) f32 or None (with appearance the rows of
    appearance.pack, else the vertices); centroids (f,3) f64 origin-relative; counted (f,) bool
    (not collapsed: simplify.collapsed)."""

    origin: np.ndarray
    root_cell: RootCube
    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    rows: np.ndarray | None
    row_layout: appearance.AttributeLayout
    centroids: np.ndarray | None  # None once the octree is built
    counted: np.ndarray



def _prepare(mesh: TriangleMesh) -> _Prepared:
    """The origin (centre of the used vertices' box); float32 positions relative to it; triangle
    centroids (f,3) f64 of the float32 positions (what is stored is what is
    split); with appearance, the vertices become attribute rows (_pack_rows)."""
    if mesh.tri_count == 0:
        raise InputError(f"{mesh.name}: the mesh has no triangles")
    used = np.zeros(mesh.positions.shape[0], bool)
    used[mesh.faces.ravel()] = True
    p_used = mesh.positions[used]
    if not np.all(np.isfinite(p_used)):
        raise InputError(f"{mesh.name}: vertices used by faces have NaN or infinite coordinates")
    origin = 0.5 * (p_used.min(axis=0) + p_used.max(axis=0))
    del p_used
    rel = mesh.positions - origin
    rel[~used] = 0.0  # unused vertices may hold anything (even NaN); they are never stored
    positions = rel.astype(np.float32)
    if not np.all(np.isfinite(positions)):
        raise InputError(f"{mesh.name}: coordinates exceed the float32 range after centring")
    faces = mesh.faces
    a, b, c = (positions[faces[:, k]] for k in range(3))
    counted = ~simplify.collapsed_corners(a, b, c)
    centroids = a.astype(np.float64)  # (a + b + c) / 3 in this order: the float mean(axis=1) gives
    centroids += b
    centroids += c
    centroids /= 3.0
    del a, b, c
    root_cell = tight_cube(centroids.min(axis=0), centroids.max(axis=0))
    normals, rows, row_layout = mesh.normals, None, appearance.AttributeLayout(False, False, False)
    if mesh.has_appearance:
        row_layout, positions, faces, normals, rows = _pack_rows(mesh, positions, normals)
    return _Prepared(origin=origin, root_cell=root_cell, positions=positions, faces=faces, normals=normals, rows=rows, row_layout=row_layout,
                     centroids=centroids, counted=counted)


def _leaf_lods(layout: OctreeLayout, lods: list, prepared: _Prepared) -> None:
    """lods[leaf] = (positions, faces local to them, normals, rows) of the vertices the leaf's
    triangles use, in ascending input order (simplify.compact), for every leaf."""
    ordered_faces = prepared.faces[layout.tri_order]
    normals, rows = prepared.normals, prepared.rows
    for node in np.flatnonzero(layout.is_leaf):
        p, f, used = _compact(prepared.positions, ordered_faces[layout.tri_begin[node]:layout.tri_end[node]])
        lods[node] = (p, f, None if normals is None else normals[used], None if rows is None else rows[used])


#: A leaf whose vertex ids span more than this many times its corners is compacted by sorting.
_WINDOW_FACTOR = 16


def _compact(positions: np.ndarray, faces: np.ndarray):
    """simplify.compact, the same result: by a mask over the span of vertex ids the faces use when
    that span is short (a leaf's vertices mostly come from one object), else by sorting."""
    flat = faces.reshape(-1)
    lo = int(flat.min())
    span = int(flat.max()) - lo + 1
    if span > _WINDOW_FACTOR * flat.shape[0]:
        return simplify.compact(positions, faces)
    mask = np.zeros(span, bool)
    shifted = flat - lo
    mask[shifted] = True
    used = np.flatnonzero(mask) + lo
    local = (np.cumsum(mask, dtype=np.int32) - 1)[shifted]
    return positions[used], local.reshape(-1, 3), used


def _pack_rows(mesh: TriangleMesh, positions: np.ndarray, normals):
    """The bake's vertices as attribute rows (appearance.pack): (layout, positions (r,3) f32,
    faces (f,3) int64 rows, normals (r,3) f32 or None, rows (r,A) f32). A vertex used by
    triangles of several materials becomes one row per material, at the vertex's position."""
    layout, vertex, rows, faces = appearance.pack(positions.shape[0], mesh.faces, material_ids=mesh.material_ids,
                                                  uvs=mesh.uvs, colors=mesh.colors)
    rows = rows + np.float32(0.0)  # -0.0 -> 0.0: the weld compares bytes
    log.info("appearance: %d attribute rows of %d columns for %d vertices", rows.shape[0], layout.width,
             positions.shape[0])
    return layout, positions[vertex], faces, None if normals is None else normals[vertex], rows


class _PhaseClock:
    def __init__(self):
        self.seconds: dict[str, float] = {}
        self._last = time.perf_counter()

    def lap(self, phase: str) -> None:
        now = time.perf_counter()
        self.seconds[phase] = now - self._last
        self._last = now


# --- simplify phase: in this process, or in worker processes sharing the input through files ----

#: The shared arrays of the exact error measure, per scratch folder ("" inline: the parent's own
#: arrays), as a worker has loaded them (memory-mapped): positions, and Clusters' arrays. A Dask
#: worker outlives bakes and may run several tasks at once in threads: _SHARED_LOCK guards both
#: dicts, _SHARED_STAMP holds each folder's file identity when loaded (a folder removed and made
#: again under the same name is loaded anew), and at most _SHARED_FOLDERS bakes' maps are kept.
_SHARED: dict[str, dict[str, np.ndarray]] = {}
_SHARED_STAMP: dict[str, tuple] = {}
_SHARED_LOCK = threading.Lock()
_SHARED_FOLDERS = 4
#: Task kinds of the simplify phase; the values order the heap (decimations before measurements).
_TASK_DECIMATE, _TASK_MEASURE = 0, 1
#: How often (seconds) the scheduler wakes while tasks run, to check cancel().
_POLL_SECONDS = 0.25
#: The shared arrays' names: the leaves' positions and the Clusters over their faces.
_SHARED_ARRAYS = ("positions", *hausdorff_measure.Clusters.ARRAYS)


def _init_worker() -> None:
    # Ctrl-C in a terminal (and a hangup) reaches the whole process group: the parent cancels and
    # shuts the pool down, so the workers ignore these and print no tracebacks of their own.
    for name in ("SIGINT", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)


def _warm_up() -> None:
    """A worker's first task, submitted when the pool starts: pymeshlab's import (about half a
    second) then overlaps the bake's prepare, octree and cache phases."""
    import pymeshlab  # noqa: F401


def _shared(folder: str) -> dict[str, np.ndarray]:
    """The shared arrays of `folder` ("" inline), loaded memory-mapped on a worker's first use
    (thread-safe; reloaded when the folder's files are not the ones loaded)."""
    if not folder:
        with _SHARED_LOCK:
            return _SHARED[""]
    first = os.stat(os.path.join(folder, _SHARED_ARRAYS[0] + ".npy"))
    stamp = (first.st_dev, first.st_ino, first.st_size, first.st_mtime_ns)
    with _SHARED_LOCK:
        arrays = _SHARED.get(folder)
        if arrays is None or _SHARED_STAMP.get(folder) != stamp:
            arrays = {name: np.load(os.path.join(folder, name + ".npy"), mmap_mode="r") for name in _SHARED_ARRAYS}
            _SHARED.pop(folder, None)
            _SHARED[folder], _SHARED_STAMP[folder] = arrays, stamp
            while len(_SHARED) > _SHARED_FOLDERS:  # the oldest bake's maps go
                _release_shared(next(iter(_SHARED)), locked=True)
    return arrays


def _release_shared(folder: str, *, locked: bool = False) -> None:
    """Drop `folder`'s arrays (its memory maps close once no task holds them). Runs on every Dask
    worker when a bake ends (dask_cluster.on_cluster)."""
    with contextlib.nullcontext() if locked else _SHARED_LOCK:
        _SHARED.pop(folder, None)
        _SHARED_STAMP.pop(folder, None)


def _measure_task(folder: str, lod_positions, lod_faces, ranges: tuple[int, ...]) -> float:
    """Runs in a worker (or inline): the node's original triangles are the leaves' below it, one
    range of the shared arrays (`_LeafArrays`): ranges = (vertex_begin, vertex_end, cluster_begin,
    cluster_end). Nodes with at least hausdorff.PRUNE_FROM_VERTICES original vertices are measured
    pruned, over their clusters (or whole where the clusters show pruning cannot pay); the others
    whole. Every way gives hausdorff.measure's float."""
    shared = _shared(folder)
    vertex_begin, vertex_end, cluster_begin, cluster_end = ranges
    clusters = hausdorff_measure.Clusters(**{name: shared[name] for name in hausdorff_measure.Clusters.ARRAYS})
    lod = (lod_positions, lod_faces)
    tri_begin, tri_end = int(clusters.start[cluster_begin]), int(clusters.start[cluster_end])

    def original():
        return (np.asarray(shared["positions"][vertex_begin:vertex_end]),
                (np.asarray(clusters.faces[tri_begin:tri_end]) - vertex_begin).astype(np.int32))

    if vertex_end - vertex_begin >= hausdorff_measure.PRUNE_FROM_VERTICES:
        return hausdorff_measure.measure_clustered(lod, shared["positions"], clusters, cluster_begin, cluster_end,
                                                   whole=original)
    return hausdorff_measure.measure(lod, original())


@dataclass(frozen=True, eq=False)
class _LeafArrays:
    """The leaves' triangles as the exact measure reads them: positions (V,3) f32, the leaves'
    vertices concatenated in depth-first order; clusters (hausdorff.Clusters) over their faces, in
    tri_order with each leaf's faces reordered into clusters (a leaf's face set is unchanged, so a
    node's triangles are still rows tri_begin..tri_end); per node (n,) int64 its vertex range and
    cluster range."""

    positions: np.ndarray
    clusters: hausdorff_measure.Clusters
    vertex_begin: np.ndarray
    vertex_end: np.ndarray
    cluster_begin: np.ndarray
    cluster_end: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        return {"positions": self.positions, **self.clusters.arrays()}

    def ranges(self, node: int) -> tuple[int, int, int, int]:
        return (int(self.vertex_begin[node]), int(self.vertex_end[node]), int(self.cluster_begin[node]),
                int(self.cluster_end[node]))


def _leaf_arrays(layout: OctreeLayout, lods: list, *, folder: str | os.PathLike | None = None) -> _LeafArrays:
    """_LeafArrays of the bake's leaves (lods[leaf] = (positions, local faces, ...)). folder: the
    leaves' positions and faces are concatenated into memory-mapped files there (an out-of-core
    bake: _concat_mapped) instead of this process's memory; the same arrays either way."""
    leaves = np.flatnonzero(layout.is_leaf)
    leaves = leaves[np.argsort(layout.tri_begin[leaves], kind="stable")]  # depth-first
    if folder is None:
        positions, faces = concat_indexed((lods[leaf][0], lods[leaf][1]) for leaf in leaves)
    else:
        positions, faces = _concat_mapped([lods[leaf] for leaf in leaves], folder)
    counts = np.array([lods[leaf][0].shape[0] for leaf in leaves], np.int64)
    segments = np.concatenate([[0], np.cumsum([lods[leaf][1].shape[0] for leaf in leaves])]).astype(np.int64)
    clusters = hausdorff_measure.Clusters.build(positions, faces, segments)
    ends = np.cumsum(counts)
    n = layout.node_count
    ranges = np.zeros((4, n), np.int64)  # vertex begin, end; cluster begin, end
    ranges[0, leaves], ranges[1, leaves] = ends - counts, ends
    ranges[2, leaves], ranges[3, leaves] = clusters.first_cluster[:-1], clusters.first_cluster[1:]
    for d in range(int(layout.depth.max()), -1, -1):  # deepest first: children before their parent
        nodes = np.flatnonzero((layout.depth == d) & ~layout.is_leaf)
        first, last = layout.child_offset[nodes], layout.child_offset[nodes] + layout.child_count[nodes] - 1
        ranges[0, nodes], ranges[2, nodes] = ranges[0, first], ranges[2, first]
        ranges[1, nodes], ranges[3, nodes] = ranges[1, last], ranges[3, last]
    return _LeafArrays(positions=positions, clusters=clusters, vertex_begin=ranges[0], vertex_end=ranges[1],
                       cluster_begin=ranges[2], cluster_end=ranges[3])


def _concat_mapped(parts: list[tuple], folder: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """concat_indexed of (positions (k,3) f32, faces (m,3)) parts, written part by part into
    memory-mapped .npy files in `folder`: positions (V,3) float32, faces (F,3) int32 (int64 from
    2**31 vertices), the values concat_indexed gives (Clusters.build stores them as this dtype)."""
    vertex_count = sum(part[0].shape[0] for part in parts)
    face_count = sum(part[1].shape[0] for part in parts)
    index_type = np.int32 if vertex_count < 2**31 else np.int64
    positions = np.lib.format.open_memmap(os.path.join(folder, "leaf-positions.npy"), mode="w+", dtype=np.float32,
                                          shape=(vertex_count, 3))
    faces = np.lib.format.open_memmap(os.path.join(folder, "leaf-faces.npy"), mode="w+", dtype=index_type,
                                      shape=(face_count, 3))
    v = f = 0
    for part in parts:
        k, m = part[0].shape[0], part[1].shape[0]
        positions[v:v + k] = part[0]
        faces[f:f + m] = np.asarray(part[1], index_type) + index_type(v)
        v, f = v + k, f + m
    return positions, faces


#: Signals whose Python handlers may raise (Ctrl-C's KeyboardInterrupt, the command line's SIGTERM
#: and SIGHUP exceptions); `_signals_deferred` holds them while a worker process is being started.
_DEFERRED_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


@contextlib.contextmanager
def _signals_deferred():
    """Hold the signals above while the body runs, then deliver them. Starting a spawned worker
    writes its start-up data down a pipe; an exception raised in the middle of that write leaves
    the child reading half of it, and it dies printing an EOFError traceback. Python runs signal
    handlers in the main thread only, so elsewhere (a Blender bake thread) nothing is deferred."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    held = [sig for sig in _DEFERRED_SIGNALS if signal.getsignal(sig) is not None]  # None: not set from Python
    previous = {sig: signal.signal(sig, lambda number, _frame: caught.append(number)) for sig in held}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for number in dict.fromkeys(caught):
            signal.raise_signal(number)


@contextlib.contextmanager
def _main_module_importable():
    """Spawned workers re-import the parent's __main__ from its __file__. When that is no file
    (python reading stdin, an embedding host), hide it while the pool starts its workers: the
    workers only need hlod_core, which they import by name."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    hide = main is not None and getattr(main, "__spec__", None) is None and path is not None \
        and not os.path.isfile(path)
    if hide:
        del main.__file__
    try:
        yield
    finally:
        if hide:
            main.__file__ = path


class _InlineExecutor:
    """The Executor interface, running each task at submit time (jobs = 1)."""

    def submit(self, fn, *args) -> cf.Future:
        fut: cf.Future = cf.Future()
        fut.set_result(fn(*args))
        return fut


@dataclass
class _Workers:
    """Where the simplify phase's tasks run: executor (submit(fn, *args) -> Future), at most
    `limit` in flight, and `scratch`, a folder every worker reads the shared arrays from ("" inline:
    this process's own arrays, `share` puts them in _SHARED). prioritised: the executor takes
    submit(..., priority=int) (a Dask cluster, whose scheduler orders the tasks it queues)."""

    executor: object
    limit: int
    scratch: str
    prioritised: bool = False

    def submit(self, order: tuple[int, int], fn, *args) -> cf.Future:
        """fn(*args) as a task; order: the scheduling loop's heap key (kind, size), smallest first,
        given to a prioritised executor as its priority (largest first): decimations before
        measurements, then -size (sizes are negative depths and triangle counts, below 2**40)."""
        if not self.prioritised:
            return self.executor.submit(fn, *args)
        kind, size = order
        return self.executor.submit(fn, *args, priority=-(kind << 40) - size)

    def share(self, arrays: dict[str, np.ndarray]) -> None:
        """Make `arrays` (the _SHARED_ARRAYS) readable by every worker, before any task reads them."""
        if not self.scratch:
            with _SHARED_LOCK:
                _SHARED[""] = arrays
            return
        for name, array in arrays.items():
            np.save(os.path.join(self.scratch, name + ".npy"), array)


@contextlib.contextmanager
def _workers(jobs: int, *, scheduler=None, scratch_dir: str | os.PathLike | None = None):
    """_Workers for `jobs`: inline for 1; else a pool of `jobs` spawned worker processes, started at
    once (each imports pymeshlab while the bake prepares: `_warm_up`), and a scratch folder
    (`$TMPDIR/hlod-bake-*`). With a scheduler (an address or a distributed.Client), the Dask
    cluster's workers instead, and a scratch folder inside `scratch_dir` (dask_cluster.on_cluster).
    All are gone when the block exits, however it exits."""
    if scheduler is not None:
        from . import dask_cluster  # only here: Dask is a command-line-only dependency

        with dask_cluster.on_cluster(scheduler, scratch_dir=scratch_dir, release=_release_shared) as cluster:
            yield _Workers(cluster.executor, cluster.limit, cluster.scratch, prioritised=True)
        return
    if jobs == 1:
        try:
            yield _Workers(_InlineExecutor(), 1, "")
        finally:
            _release_shared("")
        return
    with contextlib.ExitStack() as stack:
        scratch = stack.enter_context(tempfile.TemporaryDirectory(prefix="hlod-bake-"))
        stack.enter_context(_main_module_importable())
        executor = cf.ProcessPoolExecutor(max_workers=jobs, initializer=_init_worker,
                                          mp_context=multiprocessing.get_context("spawn"))
        stack.callback(executor.shutdown, wait=True, cancel_futures=True)
        for _ in range(jobs):
            with _signals_deferred():  # a submit starts a worker process
                executor.submit(_warm_up)
        yield _Workers(executor, jobs, scratch)


def _simplify_inner_nodes(layout: OctreeLayout, lods: list, hausdorff: np.ndarray, settings: BakeSettings, *,
                          workers: _Workers, with_normals: bool, row_layout: appearance.AttributeLayout | None,
                          cancel: CancelFn, node_done, mapped_in: str | os.PathLike | None = None) -> None:
    """Fill lods[node] and hausdorff[node] for every inner node whose LOD is not there yet (the
    cache's are); node_done(node, lod) as each completes. Attribute rows (the 4th entry of each
    LOD, None without) travel with the child LODs; row_layout: their columns (None without).

    Two kinds of task: DECIMATE a node once its children's LODs exist, MEASURE its Hausdorff error
    once its own LOD exists. Measuring exactly needs every original triangle below the node, so the
    top nodes' measurements are the big tasks; keeping them off the decimation chain lets them run
    beside other work. Priority: decimations first (deepest first, they unlock the rest), then
    measurements, largest first. At most `workers.limit` tasks are in flight, so the priority holds.
    The exact measure reads the leaves' triangles (_LeafArrays) from `workers.share`, made on a
    thread of this process while the workers run the first decimations (the leaves' LODs are final
    before the phase starts; this process only waits for results meanwhile); inline, first.
    With settings.error "bound" a MEASURE task is h(node) against its children's LODs (a few
    thousand triangles, sent with the task like a decimation's; no leaf arrays are made or shared);
    the caller composes the bounds (`_compose_bounds`). It stays a task of the pool, not inline in
    this process: inline it would run on the scheduling thread, beside `jobs` busy workers.
    """
    todo = np.array([lod is None for lod in lods]) & ~layout.is_leaf
    nodes = np.flatnonzero(todo)
    if nodes.size == 0:
        return
    dec = settings.decimation()
    waiting = np.zeros(layout.node_count, np.int64)
    todo_children = np.flatnonzero(todo & (layout.parent >= 0))
    np.add.at(waiting, layout.parent[todo_children], 1)  # a node waits for its children's LODs still to make
    heap: list[tuple] = []
    decimated: dict[int, simplify.NodeLod] = {}  # LODs made, until their measurement is done
    bound = settings.error == "bound"
    leaf_arrays = None  # the exact measure's tasks wait for it (made beside the first decimations)

    def push(kind: int, node: int) -> None:
        size = -int(layout.depth[node]) if kind == _TASK_DECIMATE else -int(layout.tri_end[node] - layout.tri_begin[node])
        heapq.heappush(heap, (kind, size, node))

    def submit(kind: int, size: int, node: int) -> cf.Future:
        kids = range(layout.child_offset[node], layout.child_offset[node] + layout.child_count[node])
        order = (kind, size)
        if kind == _TASK_DECIMATE:
            return workers.submit(order, simplify.decimate_node, [(lods[k][0], lods[k][1], lods[k][3]) for k in kids],
                                  dec, with_normals, row_layout)
        if bound:
            return workers.submit(order, hausdorff_measure.measure_to_children, (lods[node][0], lods[node][1]),
                                  [(lods[k][0], lods[k][1]) for k in kids])
        return workers.submit(order, _measure_task, workers.scratch, lods[node][0], lods[node][1],
                              leaf_arrays.ranges(node))

    for node in nodes[waiting[nodes] == 0]:
        push(_TASK_DECIMATE, int(node))

    running: dict[cf.Future, tuple[int, int]] = {}
    with contextlib.ExitStack() as stack:
        building = None  # the leaf arrays, made on a thread of this process while workers decimate
        if not bound and workers.scratch:
            builder = stack.enter_context(cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="hlod-leaf-arrays"))
            building = builder.submit(_shared_leaf_arrays, workers, layout, lods, mapped_in)
        elif not bound:  # inline: this thread is the worker
            leaf_arrays = _shared_leaf_arrays(workers, layout, lods, mapped_in)
        while heap or running:
            while heap and len(running) < workers.limit:
                if heap[0][0] == _TASK_MEASURE and leaf_arrays is None and not bound:
                    break  # every decimation that can run is in flight: wait for the leaf arrays
                kind, size, node = heapq.heappop(heap)
                with _signals_deferred():  # a submit may start a worker process
                    running[submit(kind, size, node)] = (kind, node)
            finished, _ = cf.wait([*running, *([building] if leaf_arrays is None and building else [])],
                                  timeout=_POLL_SECONDS, return_when=cf.FIRST_COMPLETED)
            if cancel():
                raise BakeCancelled("bake cancelled")
            for fut in finished:
                if fut is building:
                    leaf_arrays = building.result()
                    continue
                kind, node = running.pop(fut)
                if kind == _TASK_MEASURE:
                    hausdorff[node] = fut.result()
                    node_done(node, decimated.pop(node))
                    continue
                lod = fut.result()
                lods[node] = (lod.positions, lod.faces, lod.normals, lod.attributes)
                decimated[node] = lod
                push(_TASK_MEASURE, node)
                parent = int(layout.parent[node])
                if parent >= 0 and todo[parent]:
                    waiting[parent] -= 1
                    if waiting[parent] == 0:
                        push(_TASK_DECIMATE, parent)


def _shared_leaf_arrays(workers: "_Workers", layout: OctreeLayout, lods: list,
                        mapped_in: str | os.PathLike | None = None) -> "_LeafArrays":
    """_leaf_arrays of the bake, shared with the workers (leaves' entries of lods only: final);
    mapped_in: _leaf_arrays' folder (an out-of-core bake)."""
    arrays = _leaf_arrays(layout, lods, folder=mapped_in)
    workers.share(arrays.arrays())
    return arrays


def _note_lod(bake_log: list[str], node: int, lod: simplify.NodeLod, error: float, target_tris: int) -> None:
    tris = lod.faces.shape[0]
    if not lod.decimated:
        bake_log.append(f"node {node}: children hold {lod.input_tris} <= {target_tris} triangles; kept undecimated")
    elif tris >= lod.input_tris:
        bake_log.append(f"node {node}: LOD has {tris} triangles, not smaller than its children's {lod.input_tris}")
    elif tris > 2 * target_tris:
        bake_log.append(f"node {node}: decimation stopped at {tris} triangles (target {target_tris}); "
                        "boundary preservation keeps the cell's border")
    if lod.uv_seams_crossed:
        bake_log.append(f"node {node}: UV seams crossed to reach {tris} triangles ({lod.seam_kept_tris} keeping "
                        f"them); {lod.island_spanning_faces} faces span two UV islands")
    if lod.zero_area:
        bake_log.append(f"node {node}: every triangle has zero area, which decimation removes; kept "
                        f"{tris} of the children's {lod.input_tris}")
    if lod.kept_in_place:
        bake_log.append(f"node {node}: optimal vertex placement left the node's box; decimated again "
                        "with vertices kept in place")
    if not np.isfinite(error):
        bake_log.append(f"node {node}: Hausdorff distance unavailable; error bounded by the node's box diagonal")


# --- assemble and bounds ------------------------------------------------------------------------

#: Vertices _assemble turns into float64 world coordinates at a time (whole nodes; a node of more
#: vertices is one block): its working memory, 24 bytes a vertex and a few copies.
_ASSEMBLE_BLOCK_VERTICES = 1 << 20


def _concat_nodes(lods, vertex_offset: np.ndarray, tri_offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """concat_indexed of the nodes' (positions, faces), written straight into the file's arrays:
    positions (V,3) float32 and indices (F,3) uint32 (V < 2**32, checked by the caller)."""
    vertices = int(vertex_offset[-1]) + lods[-1][0].shape[0]
    tris = int(tri_offset[-1]) + lods[-1][1].shape[0]
    positions = np.empty((vertices, 3), np.float32)
    indices = np.empty((tris, 3), np.uint32)
    for lod, v, t in zip(lods, vertex_offset, tri_offset):
        positions[v:v + lod[0].shape[0]] = lod[0]
        indices[t:t + lod[1].shape[0]] = lod[1]
        indices[t:t + lod[1].shape[0]] += np.uint32(v)
    return positions, indices


def _vertex_blocks(vertex_offset: np.ndarray, vertex_count: np.ndarray) -> list[tuple[int, int]]:
    """Runs of consecutive nodes [first, last) of about _ASSEMBLE_BLOCK_VERTICES vertices each."""
    ends = vertex_offset + vertex_count
    out, first = [], 0
    n = vertex_count.shape[0]
    while first < n:
        last = int(np.searchsorted(ends, vertex_offset[first] + _ASSEMBLE_BLOCK_VERTICES, side="right"))
        last = max(last, first + 1)
        out.append((first, last))
        first = last
    return out


def _block_world(positions, origin, vertex_offset, vertex_count, first: int, last: int):
    """The vertices of nodes first..last-1 as float64 world coordinates (positions + origin), and
    each node's start in them (for reduceat)."""
    begin, end = int(vertex_offset[first]), int(vertex_offset[last - 1] + vertex_count[last - 1])
    world = positions[begin:end].astype(np.float64)
    world += origin
    return world, vertex_offset[first:last] - begin


def _assemble(layout: OctreeLayout, lods, origin, hausdorff, *, normals: bool,
              row_layout: appearance.AttributeLayout) -> Hlod:
    """lods: per node (positions, faces, normals, attribute rows); row_layout: the rows' columns
    (empty: none). The Hlod's appearance arrays come from the rows; within a node, triangles are sorted
    by material (stable)."""
    n = layout.node_count
    vertex_count = np.array([l[0].shape[0] for l in lods], np.int64)
    tri_count = np.array([l[1].shape[0] for l in lods], np.int64)
    if np.any(tri_count == 0):
        raise InputError("a node's LOD came out empty (pymeshlab removed every triangle)")
    vertex_offset = np.concatenate([[0], np.cumsum(vertex_count)[:-1]])
    tri_offset = np.concatenate([[0], np.cumsum(tri_count)[:-1]])
    if vertex_count.sum() >= 2**32:
        raise InputError(f"the HLOD would need {int(vertex_count.sum())} vertices, more than 32-bit indices address")
    positions, indices = _concat_nodes(lods, vertex_offset, tri_offset)
    node_normals = np.concatenate([l[2] for l in lods]).astype(np.float32) if normals else None
    uvs = colors = tri_material = None
    if not row_layout.empty:
        uvs, colors, face_material = appearance.unpack(row_layout, np.concatenate([l[3] for l in lods]), indices)
        if face_material is not None:
            order = np.lexsort((face_material, np.repeat(np.arange(n), tri_count)))  # node, then material
            indices, tri_material = indices[order], face_material[order].astype(np.uint16)

    blocks = _vertex_blocks(vertex_offset, vertex_count)
    lod_box_min = np.empty((n, 3), np.float64)
    lod_box_max = np.empty((n, 3), np.float64)
    for first, last in blocks:
        world, starts = _block_world(positions, origin, vertex_offset, vertex_count, first, last)
        lod_box_min[first:last] = np.minimum.reduceat(world, starts, axis=0)
        lod_box_max[first:last] = np.maximum.reduceat(world, starts, axis=0)
    box_min, box_max = lod_box_min.copy(), lod_box_max.copy()
    levels = [np.flatnonzero(layout.depth == d) for d in range(int(layout.depth.max()), 0, -1)]
    for nodes in levels:  # deepest first: a child's subtree box is final before its parent's
        np.minimum.at(box_min, layout.parent[nodes], box_min[nodes])
        np.maximum.at(box_max, layout.parent[nodes], box_max[nodes])

    center = 0.5 * (box_min + box_max)
    # |world - centre of its node| per vertex, max per node: sqrt((dx^2 + dy^2) + dz^2) as
    # np.linalg.norm sums it, and the max taken before the root (sqrt is monotone: the same float)
    radius = np.empty(n, np.float64)
    for first, last in blocks:
        world, starts = _block_world(positions, origin, vertex_offset, vertex_count, first, last)
        world -= np.repeat(center[first:last], vertex_count[first:last], axis=0)
        world *= world
        squared = world[:, 0] + world[:, 1]
        squared += world[:, 2]
        radius[first:last] = np.sqrt(np.maximum.reduceat(squared, starts))
    del world, squared
    diag = np.linalg.norm(box_max - box_min, axis=1)
    error = np.where(np.isfinite(hausdorff), hausdorff, diag)
    error[layout.is_leaf] = 0.0
    for nodes in levels:
        parents = layout.parent[nodes]
        np.maximum.at(radius, parents, np.linalg.norm(center[nodes] - center[parents], axis=1) + radius[nodes])
        np.maximum.at(error, parents, error[nodes])

    return Hlod(parent=layout.parent, child_offset=layout.child_offset, child_count=layout.child_count,
                depth=layout.depth, lod_box_min=lod_box_min, lod_box_max=lod_box_max, box_min=box_min,
                box_max=box_max, sphere_center=center, sphere_radius=radius, error=error,
                cube_side=cube_sides(box_min, box_max, query_box_pad(box_min, box_max)),
                tri_offset=tri_offset, tri_count=tri_count, vertex_offset=vertex_offset,
                vertex_count=vertex_count, origin=np.asarray(origin, np.float64), positions=positions,
                indices=indices, normals=node_normals, uvs=uvs, colors=colors, tri_material=tri_material)
