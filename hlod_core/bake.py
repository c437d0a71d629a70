"""Bake an octree HLOD from triangles (DESIGN §4), as a pipeline of named phases:

    prepare  -> file-relative float32 positions, triangle centroids; with appearance, the
                vertices become attribute rows (appearance.pack: a vertex split per material)
    octree   -> top-down partition (octree.build_octree)
    leaves   -> each leaf keeps its original triangles (and their exact attribute rows)
    simplify -> inner nodes bottom-up: weld, quadric decimation, Hausdorff MSE (simplify.py);
                independent subtrees run in parallel worker processes (`jobs`)
    assemble -> one vertex and one index buffer, node ranges; with appearance, UVs, colours and
                triangle materials, each node's triangles sorted by material (one draw per
                (node, material))
    bounds   -> tight nested boxes, nested spheres, monotone MSE, cube sides (vectorised per level)

After Charalambos' dissertation (`../shared/papers/charalambos2007-dissertation-hlod-refinement-hoq.txt`
§3.3, §8: octree, one LOD of ~2000 triangles per node, offline bottom-up simplification).

Appearance (issue 13): a mesh with materials, UVs or colours bakes on attribute rows instead of
vertices; leaves keep them exact, inner nodes keep materials and UVs exact (simplify.py: material
borders and UV seams stay where they are, a LOD vertex takes the row of the input vertex it sits
on) and blend colours only where a colour jumps. Where keeping the UV seams would keep a LOD
above twice its target, that node crosses them (material borders still stay): faces inside one
UV island keep exact UVs, faces spanning two are stretched; the log names such nodes and
meta["uv_seams_crossed_nodes"] counts them. A mesh without any takes the path it always took,
with no attribute arrays. The node error stays the geometric Hausdorff MSE.
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
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from . import appearance, simplify
from .arrays import concat_indexed
from .errors import BakeCancelled, InputError
from .hierarchy import Hlod, cube_sides, query_box_pad
from .meshio import TriangleMesh
from .octree import OctreeLayout, build_octree

log = logging.getLogger(__name__)

#: progress(done_nodes, total_nodes, phase)
ProgressFn = Callable[[int, int, str], None]
CancelFn = Callable[[], bool]

_MAX_LOG_LINES = 200


@dataclass(frozen=True)
class BakeSettings:
    """target_tris: triangles per node (leaf budget and LOD size); max_depth: deepest node level
    (root = 0); jobs: worker processes for decimation (1 = in this process); the rest go to
    simplify.DecimationSettings."""

    target_tris: int = 2000
    max_depth: int = 12
    jobs: int = 1
    quality_threshold: float = 0.3
    preserve_normals: bool = False
    boundary_weight: float = 1.0

    def __post_init__(self):
        if self.target_tris < 1:
            raise InputError(f"target_tris must be at least 1, got {self.target_tris}")
        if not 0 <= self.max_depth <= 64:
            raise InputError(f"max_depth must be between 0 and 64, got {self.max_depth}")
        if self.jobs < 1:
            raise InputError(f"jobs must be at least 1, got {self.jobs}")
        if not 0.0 <= self.quality_threshold <= 1.0:
            raise InputError(f"quality_threshold must be in [0, 1], got {self.quality_threshold}")

    def decimation(self) -> simplify.DecimationSettings:
        return simplify.DecimationSettings(target_tris=self.target_tris, quality_threshold=self.quality_threshold,
                                           preserve_normals=self.preserve_normals,
                                           boundary_weight=self.boundary_weight)


def bake(mesh: TriangleMesh, settings: BakeSettings = BakeSettings(), *,
         progress: ProgressFn | None = None, cancel: CancelFn | None = None,
         sources: list[str] | None = None, extra_meta: dict | None = None) -> Hlod:
    """Bake `mesh` into an Hlod. Raises InputError for unusable input, BakeCancelled if `cancel()`
    turns true (checked between nodes). Writes nothing to disk except worker scratch files.
    extra_meta: JSON-serialisable entries added to the HLOD's meta (the Blender side records the
    UV map and colour attribute names, "uv_map" and "color_attribute"); they may not replace the
    bake's own entries. The HLOD carries uvs / colors / tri_material and mesh.materials exactly
    when the mesh has them."""
    started = time.perf_counter()
    progress = progress or (lambda done, total, phase: None)
    cancel = cancel or (lambda: False)
    bake_log: list[str] = []
    phases = _PhaseClock()

    origin, positions, faces, centroids = _prepare(mesh)
    normals_in = mesh.normals
    row_layout, rows = appearance.AttributeLayout(False, False, False), None
    if mesh.has_appearance:
        row_layout, positions, faces, normals_in, rows = _pack_rows(mesh, positions, normals_in)
    counted = ~simplify.collapsed(positions, faces)
    phases.lap("prepare")
    layout = build_octree(centroids, target_tris=settings.target_tris, max_depth=settings.max_depth,
                          counted=counted)
    del centroids
    phases.lap("octree")
    n = layout.node_count
    progress(0, n, "octree")
    log.info("octree: %d nodes, %d leaves", n, int(layout.is_leaf.sum()))

    ordered_faces = faces[layout.tri_order]
    # per node (positions (k,3) f32, faces (m,3) int32, normals (k,3) f32 or None, attribute rows (k,A) f32 or None)
    lods: list[tuple] = [None] * n
    hausdorff = np.zeros(n, np.float64)
    for node in np.flatnonzero(layout.is_leaf):
        p, f, used = simplify.compact(positions, ordered_faces[layout.tri_begin[node]:layout.tri_end[node]])
        lods[node] = (p, f, None if normals_in is None else normals_in[used], None if rows is None else rows[used])
    done = int(layout.is_leaf.sum())
    phases.lap("leaves")
    progress(done, n, "simplify")

    uv_seams_crossed_nodes = 0

    def node_done(node: int, lod: simplify.NodeLod) -> None:
        nonlocal done, uv_seams_crossed_nodes
        _note_lod(bake_log, node, lod, hausdorff[node], settings.target_tris)
        uv_seams_crossed_nodes += int(lod.uv_seams_crossed)
        done += 1
        progress(done, n, "simplify")

    _simplify_inner_nodes(layout, lods, hausdorff, positions, ordered_faces, settings,
                          with_normals=normals_in is not None, row_layout=None if rows is None else row_layout,
                          cancel=cancel, node_done=node_done)
    if cancel():
        raise BakeCancelled("bake cancelled")
    phases.lap("simplify")

    hlod = _assemble(layout, lods, origin, hausdorff, normals=normals_in is not None, row_layout=row_layout)
    if mesh.has_appearance:
        hlod = hlod.replace(materials=tuple(mesh.materials))
    phases.lap("assemble")
    seconds = time.perf_counter() - started
    counted_below = np.concatenate([[0], np.cumsum(counted[layout.tri_order])])
    counted_per_node = counted_below[layout.tri_end] - counted_below[layout.tri_begin]
    over_budget = int((layout.is_leaf & (counted_per_node > settings.target_tris)).sum())
    meta = {
        "generator": "hlod_core",
        "input_tris": mesh.tri_count,
        "input_vertices": int(mesh.positions.shape[0]),
        "settings": asdict(settings),
        "target_tris": settings.target_tris,
        "max_depth": settings.max_depth,
        "sources": list(sources or [mesh.name]),
        "leaves_over_budget": over_budget,
        "collapsed_input_tris": int((~counted).sum()),
        "bake_seconds": seconds,
        "phase_seconds": phases.seconds,
        "log": bake_log[:_MAX_LOG_LINES],
        "log_lines_dropped": max(0, len(bake_log) - _MAX_LOG_LINES),
    }
    if mesh.has_appearance:
        meta["uv_seams_crossed_nodes"] = uv_seams_crossed_nodes
    clash = sorted(set(meta) & set(extra_meta or {}))
    if clash:
        raise InputError(f"extra_meta may not replace the bake's own meta entries ({', '.join(clash)})")
    meta.update(extra_meta or {})
    progress(n, n, "done")
    return hlod.replace(meta=meta)


def _prepare(mesh: TriangleMesh):
    """origin (3,) f64 = centre of the used vertices' box; positions (v,3) f32 relative to it;
    faces (f,3) int64; centroids (f,3) f64 of the float32 positions (what is stored is what is split)."""
    if mesh.tri_count == 0:
        raise InputError(f"{mesh.name}: the mesh has no triangles")
    used = np.zeros(mesh.positions.shape[0], bool)
    used[mesh.faces.ravel()] = True
    p_used = mesh.positions[used]
    if not np.all(np.isfinite(p_used)):
        raise InputError(f"{mesh.name}: vertices used by faces have NaN or infinite coordinates")
    origin = 0.5 * (p_used.min(axis=0) + p_used.max(axis=0))
    rel = mesh.positions - origin
    rel[~used] = 0.0  # unused vertices may hold anything (even NaN); they are never stored
    positions = rel.astype(np.float32)
    if not np.all(np.isfinite(positions)):
        raise InputError(f"{mesh.name}: coordinates exceed the float32 range after centring")
    tri = positions[mesh.faces].astype(np.float64)
    centroids = tri.mean(axis=1)
    return origin, positions, mesh.faces, centroids


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

_SHARED: dict[str, np.ndarray] = {}
#: Task kinds of the simplify phase; the values order the heap (decimations before measurements).
_TASK_DECIMATE, _TASK_MEASURE = 0, 1
#: How often (seconds) the scheduler wakes while tasks run, to check cancel().
_POLL_SECONDS = 0.25


def _init_worker(positions_path: str, faces_path: str) -> None:
    # Ctrl-C in a terminal (and a hangup) reaches the whole process group: the parent cancels and
    # shuts the pool down, so the workers ignore these and print no tracebacks of their own.
    for name in ("SIGINT", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    _SHARED["positions"] = np.load(positions_path, mmap_mode="r")
    _SHARED["faces"] = np.load(faces_path, mmap_mode="r")


def _measure_task(lod_positions, lod_faces, tri_begin: int, tri_end: int) -> float:
    """Runs in a worker (or inline): the node's original triangles come from the shared arrays."""
    original = simplify.compact(_SHARED["positions"], np.asarray(_SHARED["faces"][tri_begin:tri_end]))
    return simplify.measure((lod_positions, lod_faces), original[:2])


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


def _simplify_inner_nodes(layout: OctreeLayout, lods: list, hausdorff: np.ndarray, positions, ordered_faces,
                          settings: BakeSettings, *, with_normals: bool,
                          row_layout: appearance.AttributeLayout | None, cancel: CancelFn, node_done) -> None:
    """Fill lods[node] and hausdorff[node] for every inner node; node_done(node, lod) as each completes.
    Attribute rows (the 4th entry of each LOD, None without) travel with the child LODs; row_layout:
    their columns (None without).

    Two kinds of task: DECIMATE a node once its children's LODs exist, MEASURE its Hausdorff error
    once its own LOD exists. Measuring needs every original triangle below the node, so the top
    nodes' measurements are the big tasks; keeping them off the decimation chain lets them run
    beside other work. Priority: decimations first (deepest first, they unlock the rest), then
    measurements, largest first. At most `jobs` tasks are in flight, so the priority holds.
    """
    inner = np.flatnonzero(~layout.is_leaf)
    if inner.size == 0:
        return
    dec = settings.decimation()
    waiting = np.zeros(layout.node_count, np.int64)
    inner_children = np.flatnonzero(~layout.is_leaf & (layout.parent >= 0))
    np.add.at(waiting, layout.parent[inner_children], 1)  # a node waits for its inner children's LODs
    heap: list[tuple] = []
    decimated: dict[int, simplify.NodeLod] = {}  # LODs made, until their measurement is done

    def push(kind: int, node: int) -> None:
        size = -int(layout.depth[node]) if kind == _TASK_DECIMATE else -int(layout.tri_end[node] - layout.tri_begin[node])
        heapq.heappush(heap, (kind, size, node))

    def submit(executor, kind: int, node: int) -> cf.Future:
        if kind == _TASK_DECIMATE:
            kids = range(layout.child_offset[node], layout.child_offset[node] + layout.child_count[node])
            return executor.submit(simplify.decimate_node, [(lods[k][0], lods[k][1], lods[k][3]) for k in kids], dec,
                                   with_normals, row_layout)
        return executor.submit(_measure_task, lods[node][0], lods[node][1],
                               int(layout.tri_begin[node]), int(layout.tri_end[node]))

    for node in inner[waiting[inner] == 0]:
        push(_TASK_DECIMATE, int(node))

    with contextlib.ExitStack() as stack:
        if settings.jobs == 1:
            executor, limit = _InlineExecutor(), 1
            _SHARED.update(positions=positions, faces=ordered_faces)
            stack.callback(_SHARED.clear)
        else:
            scratch = stack.enter_context(tempfile.TemporaryDirectory(prefix="hlod-bake-"))
            paths = os.path.join(scratch, "positions.npy"), os.path.join(scratch, "faces.npy")
            np.save(paths[0], positions)
            np.save(paths[1], ordered_faces)
            stack.enter_context(_main_module_importable())
            executor = cf.ProcessPoolExecutor(max_workers=settings.jobs, initializer=_init_worker, initargs=paths,
                                              mp_context=multiprocessing.get_context("spawn"))
            stack.callback(executor.shutdown, wait=True, cancel_futures=True)
            limit = settings.jobs
        running: dict[cf.Future, tuple[int, int]] = {}
        while heap or running:
            while heap and len(running) < limit:
                kind, _, node = heapq.heappop(heap)
                with _signals_deferred():  # a submit may start a worker process
                    running[submit(executor, kind, node)] = (kind, node)
            finished, _ = cf.wait(running, timeout=_POLL_SECONDS, return_when=cf.FIRST_COMPLETED)
            if cancel():
                raise BakeCancelled("bake cancelled")
            for fut in finished:
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
                if parent >= 0:
                    waiting[parent] -= 1
                    if waiting[parent] == 0:
                        push(_TASK_DECIMATE, parent)


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
    positions, indices = concat_indexed((l[0], l[1]) for l in lods)
    positions, indices = positions.astype(np.float32), indices.astype(np.uint32)
    node_normals = np.concatenate([l[2] for l in lods]).astype(np.float32) if normals else None
    uvs = colors = tri_material = None
    if not row_layout.empty:
        uvs, colors, face_material = appearance.unpack(row_layout, np.concatenate([l[3] for l in lods]), indices)
        if face_material is not None:
            order = np.lexsort((face_material, np.repeat(np.arange(n), tri_count)))  # node, then material
            indices, tri_material = indices[order], face_material[order].astype(np.uint16)

    world = positions.astype(np.float64) + origin
    lod_box_min = np.minimum.reduceat(world, vertex_offset, axis=0)
    lod_box_max = np.maximum.reduceat(world, vertex_offset, axis=0)
    box_min, box_max = lod_box_min.copy(), lod_box_max.copy()
    levels = [np.flatnonzero(layout.depth == d) for d in range(int(layout.depth.max()), 0, -1)]
    for nodes in levels:  # deepest first: a child's subtree box is final before its parent's
        np.minimum.at(box_min, layout.parent[nodes], box_min[nodes])
        np.maximum.at(box_max, layout.parent[nodes], box_max[nodes])

    center = 0.5 * (box_min + box_max)
    owner = np.repeat(np.arange(n), vertex_count)
    radius = np.maximum.reduceat(np.linalg.norm(world - center[owner], axis=1), vertex_offset)
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
