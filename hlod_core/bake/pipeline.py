"""Bake an octree HLOD from triangles (docs/how-it-works.md#the-bake), as one pipeline of named phases over an input
source (sources.py: a mesh in memory, or a stream bigger than memory):

    cache    -> with a cache folder (bake/run/cache.py): an input it holds the whole result of, in the frame
                the last bake left there, comes back from it at once
    prepare  -> the frame (bake/space/frame.py: an earlier bake's while the input fits it, else the input's
                own), file-relative float32 positions, triangle centroids, the root cell (a
                streamed input: the "scan" passes; bake/space/partition.py)
    octree   -> top-down partition of the root cell, split at cell centres (bake/space/octree.py)
    leaves   -> each leaf keeps its original triangles (and their exact attribute rows)
    seams    -> the positions each node shares with the cells around it (bake/decimate/cell_seams.py), which
                its decimation keeps in place
    cache    -> the inner nodes whose subtree the cache holds take their LODs and errors from it
    simplify -> the other inner nodes bottom-up: weld, quadric decimation, error (bake/run/schedule.py), as
                tasks on worker processes or a Dask cluster (bake/run/workers.py)
    assemble -> one vertex and one index buffer, node ranges, appearance arrays, nested bounds
                and monotone errors (assemble.py)

After J. P. Charalambos, "HLOD Refinement Driven by Hardware Occlusion Queries", dissertation, 2007
(sections 3.3 and 8: octree, one LOD of ~2000 triangles per node, offline bottom-up simplification;
docs/how-it-works.md#papers, docs/how-it-works.md#the-bake).
A node's LOD and error depend on its subtree's input triangles, the frame and the settings only, so
a bake from the cache, a streamed bake and a Dask bake all write the file a bake from scratch in the
same frame writes, byte for byte except meta.VOLATILE_META.
Why: docs/how-it-works.md#re-bakes-and-the-cache-keys

Stop signals: the whole bake runs inside core.signals.stop_signals_held; a SIGTERM, SIGHUP or
Ctrl-C is raised at the bake's cancel checks (between tasks, at least every
schedule.POLL_SECONDS, and between phases), never inside a thread or process start.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np

from ..core.signals import deliver_held, stop_signals_held
from ..io import hlod_file
from ..io.meshes import TriangleMesh
from ..model.hierarchy import Hlod
from .appearance.proxy_plan import ProxyPlan, proxy_plan
from .assemble import Assembled, assemble
from .decimate import cell_seams
from .decimate.simplify import NodeLod
from .meta import VOLATILE_META, PhaseClock, bake_meta, check_extra_meta, derived_meta, stable_meta
from .run.cache import DEFAULT_BUDGET_MB, BakeCache
from .run.lod_spill import LodSpill
from .run.schedule import CancelFn, ProgressFn, SimplifyInput, simplify_phase
from .run.workers import open_workers
from .settings import ERROR_MEASURES, BakeSettings
from .sources import BakeSource, InMemorySource, SourceOctree, StreamedSource
from .space.frame import Frame, FrameChoice, Prior
from .space.partition import CHUNK_TRIS, Partition, PartitionStats, TriangleSource

log = logging.getLogger(__name__)

#: The bake's front door: its entry points and what their callers need with them.
__all__ = ["bake", "bake_stream", "BakeSettings", "ERROR_MEASURES", "VOLATILE_META", "stable_meta"]


def bake(mesh: TriangleMesh | list[TriangleMesh], settings: BakeSettings = BakeSettings(), *,
         progress: ProgressFn | None = None, cancel: CancelFn | None = None,
         sources: list[str] | None = None, extra_meta: dict | None = None,
         cache_dir: str | os.PathLike | None = None, scheduler=None,
         scratch_dir: str | os.PathLike | None = None, frame_from: Frame | None = None,
         cache_budget_mb: float = DEFAULT_BUDGET_MB, images: dict | None = None, textures=None,
         output: str | os.PathLike | None = None) -> Hlod:
    """Bake `mesh` into an Hlod (a one-item list holding it: handed over, the bake empties the list
    and, holding the only reference, lets the input go once the leaves are cut). Raises InputError
    for unusable input, BakeCancelled if `cancel()` turns true (checked between nodes). Writes
    nothing to disk except worker scratch files, `output` and, with `cache_dir`, once the bake is
    complete, the cache folder (bake/run/cache.py: what it did not hold is added, with the bake's
    frame; the least recently used entries over `cache_budget_mb` are removed).
    The frame (bake/space/frame.py): `frame_from`'s (an earlier bake's, frame.Frame.from_meta of its file's
    meta["frame"]) while the input fits it, else the cache folder's last one while the input fits
    it, else the input's own; meta["frame"] records it and meta["frame_source"] says which and why.
    extra_meta: JSON-serialisable entries added to the HLOD's meta (the Blender side records the
    UV map and colour attribute names, "uv_map" and "color_attribute"); they may not replace the
    bake's own entries. The HLOD carries uvs / colors / tri_material and mesh.materials exactly
    when the mesh has them.
    scheduler: a Dask scheduler's address ("tcp://host:8786") or a distributed.Client: the simplify
    phase's tasks run on its workers instead of `settings.jobs` local processes (bake/run/dask_cluster.py),
    for the same file; scratch_dir: a folder every worker reads (shared storage on a cluster;
    default the temporary folder), where the bake writes its shared arrays into a subfolder of its
    own, removed at the end. Neither is a setting: they change where the work runs, not the file.
    images: material row -> its texture image ((h,w,4) uint8 sRGB RGBA, top row first), what the
    inner nodes' proxy materials are baked from; None: read from the materials' texture files
    (io.textures.load_material_images)
    (appearance/); textures: where their PNGs go (`scratch`, written, and `final`, what the file's
    materials name: io.texture_folder.EmbeddedTextures; None: a temporary folder of their own, removed
    when the process exits).
    output: the .hlod file to write (io/hlod_file.py's format, atomically): without a cache it is
    written as it is assembled, a block of nodes at a time, never whole in memory, and the Hlod
    returned is mapped from it; None: the Hlod in memory, nothing written."""
    with stop_signals_held():
        check_extra_meta(extra_meta)
        mesh = mesh.pop() if isinstance(mesh, list) else mesh
        plan = proxy_plan(mesh, settings, images=images, textures=textures)
        if plan is not None:
            mesh = plan.mesh
        cache = BakeCache.open(cache_dir, mesh=mesh, settings=settings, budget_mb=cache_budget_mb,
                               plan=None if plan is None else plan.plan)
        prior = Prior(frame_from, "file") if frame_from is not None else cache.prior() if cache is not None else None
        source = InMemorySource(mesh, prior)
        del mesh
        return _bake(source, settings, _Callbacks(progress, cancel), cache=cache,
                     scheduler=scheduler, scratch_dir=scratch_dir, sources=sources, extra_meta=extra_meta, prior=prior,
                     plan=None if plan is None else plan.plan, output=output)


def bake_stream(source: TriangleSource, settings: BakeSettings = BakeSettings(), *,
                progress: ProgressFn | None = None, cancel: CancelFn | None = None, sources: list[str] | None = None,
                extra_meta: dict | None = None, scheduler=None, scratch_dir: str | os.PathLike | None = None,
                chunk_tris: int = CHUNK_TRIS, stats: PartitionStats | None = None,
                output: str | os.PathLike | None = None) -> Hlod:
    """Bake `source` (a partition.TriangleSource) out of core: never loaded whole, streamed through
    per-cell scratch files (bake/space/partition.py) in a folder `hlod-partition-*` inside `scratch_dir`
    (default the temporary folder), removed however the bake ends. The result is the file `bake`
    makes of the merged input, byte for byte except meta.VOLATILE_META. Geometry only (normals
    kept); no cache. chunk_tris: the memory budget (partition.CHUNK_TRIS); stats: filled with what
    the partition did. progress, cancel, sources, extra_meta, scheduler, output: as for `bake`."""
    with stop_signals_held():
        check_extra_meta(extra_meta)
        callbacks = _Callbacks(progress, cancel)
        with Partition(source, scratch_dir=scratch_dir, chunk_tris=chunk_tris, cancel=callbacks.cancel,
                       stats=stats) as partition:
            return _bake(StreamedSource(partition), settings, callbacks, cache=None, scheduler=scheduler,
                         scratch_dir=scratch_dir, sources=sources, extra_meta=extra_meta, output=output)


class _Callbacks:
    """A bake's progress and cancel callbacks (defaulted) and its phase clock. cancel() first
    raises a stop signal recorded since the last check (core.signals.deliver_held)."""

    def __init__(self, progress: ProgressFn | None, cancel: CancelFn | None):
        self.progress: ProgressFn = progress or (lambda done, total, phase: None)
        self._cancel: CancelFn = cancel or (lambda: False)
        self.clock = PhaseClock()

    def cancel(self) -> bool:
        deliver_held()
        return self._cancel()


def _bake(source: BakeSource, settings: BakeSettings, run: _Callbacks, *, cache: BakeCache | None, scheduler,
          scratch_dir: str | os.PathLike | None, sources: list[str] | None, extra_meta: dict | None,
          prior: Prior | None = None, plan: ProxyPlan | None = None,
          output: str | os.PathLike | None = None) -> Hlod:
    """The phases (module docstring), once for every source; scheduler, scratch_dir, output: as for
    `bake`; prior: the frame the bake starts from (None: the input's own)."""
    clock = run.clock
    found = cache.whole_result(prior) if cache is not None else None
    if found is not None:  # the input is unchanged: the cache holds the whole result in the prior frame
        clock.lap("cache")
        hlod, derived, stats, frame = found
        run.progress(hlod.node_count, hlod.node_count, "done")
        which = "that" if frame is prior.frame else "an earlier"
        choice = FrameChoice(prior.source, f"the input is unchanged: its whole result in {which} {prior.source} frame")
        hlod = hlod.replace(meta=bake_meta(source.size, settings, derived, cache_stats=stats, sources=sources,
                                           extra_meta=extra_meta, clock=clock, frame_source=choice.to_meta()))
        if output is not None:
            hlod_file.save(hlod, output)
        return hlod
    nodes = _baked_nodes(source, settings, run, cache=cache, scheduler=scheduler, scratch_dir=scratch_dir, plan=plan)
    layout, n = nodes.tree.layout, nodes.tree.layout.node_count
    proxy_materials = plan.finish(nodes.lods) if plan is not None else ()
    assembled = assemble(layout, nodes.lods, nodes.tree.origin, hausdorff_error=nodes.hausdorff_error,
                         normals=source.with_normals, row_layout=source.row_layout)
    materials = tuple(source.materials) + proxy_materials if source.materials else ()
    # in memory: the whole file's arrays (a cache keeps them); streamed into `output`: only its node table
    hlod = assembled.hlod(materials=materials) if output is None or cache is not None else None
    del nodes.lods
    clock.lap("assemble")
    derived = derived_meta(layout, nodes.made, nodes.hausdorff_error, counted_per_node=nodes.tree.counted_per_node,
                           settings=settings, collapsed_tris=nodes.tree.collapsed_tris,
                           with_rows=not source.row_layout.empty, frame=nodes.tree.frame.to_meta())
    if proxy_materials:
        derived["proxies"] = plan.meta()
        derived["log"] = derived["log"] + plan.log_lines()
    stats = None
    if cache is not None:
        stats = cache.finish(hlod, derived, made=nodes.made, hausdorff_error=nodes.hausdorff_error,
                             frame=nodes.tree.frame)
        clock.lap("cache_write")
    run.progress(n, n, "done")
    log.info("frame from %s: %s", nodes.tree.frame_choice.source, nodes.tree.frame_choice.reason)
    meta = bake_meta(source.size, settings, derived, cache_stats=stats, sources=sources, extra_meta=extra_meta,
                     clock=clock, frame_source=nodes.tree.frame_choice.to_meta())
    return _result(hlod, assembled, meta=meta, materials=materials, output=output)


def _result(hlod: Hlod | None, assembled: Assembled, *, meta: dict, materials: tuple,
            output: str | os.PathLike | None) -> Hlod:
    """The bake's Hlod with its meta: `hlod` (in memory; saved to `output` if given), or, without
    one, `assembled` written to `output` a block of nodes at a time (the same bytes) and mapped
    from it, no array read (hlod_file.load, check=False): the file's arrays never whole in memory."""
    if hlod is not None:
        hlod = hlod.replace(meta=meta)
        if output is not None:
            hlod_file.save(hlod, output)
        return hlod
    assembled.write(output, meta=meta, materials=materials)
    assembled.lods = None
    return hlod_file.load(output, mmap=True, check=False)


@dataclass(eq=False)
class _Nodes:
    """Every node baked: tree (sources.SourceOctree), lods per node (positions, faces, normals,
    rows), hausdorff_error (n,) float64 and made (inner node -> its simplify.NodeLod)."""

    tree: SourceOctree
    lods: list
    hausdorff_error: np.ndarray
    made: dict[int, NodeLod]


def _baked_nodes(source: BakeSource, settings: BakeSettings, run: _Callbacks, *, cache: BakeCache | None,
                 scheduler, scratch_dir: str | os.PathLike | None, plan: ProxyPlan | None = None) -> _Nodes:
    """The phases from the octree to the simplify phase, with the workers running. They start
    first and import pymeshlab while this process prepares; an input of one leaf has no inner
    node to simplify, and runs inline."""
    clock = run.clock
    several = source.count(clock) > settings.target_tris
    with open_workers(settings.jobs if several else 1, scheduler=scheduler if several else None,
                      scratch_dir=scratch_dir) as workers:
        tree = source.octree(settings, clock, workers)
        layout, n = tree.layout, tree.layout.node_count
        run.progress(0, n, "octree")
        log.info("octree: %d nodes, %d leaves%s", n, int(layout.is_leaf.sum()), source.log_note)
        deliver_held()
        nodes = _Nodes(tree=tree, lods=source.leaf_lods(layout, clock), hausdorff_error=np.zeros(n, np.float64),
                       made={})
        clock.lap("leaves")
        seams = cell_seams.build(layout, nodes.lods, workers=workers, folder=source.leaf_folder, cancel=run.cancel)
        clock.lap("seams")
        if cache is not None:
            for node, (lod, error) in cache.reuse(layout, nodes.lods, origin=tree.origin,
                                                  unit_length=tree.unit_length, seams=seams).items():
                nodes.made[node], nodes.hausdorff_error[node] = lod, error
                nodes.lods[node] = (lod.positions, lod.faces, lod.normals, lod.attributes)
            clock.lap("cache")
        what = SimplifyInput(with_normals=source.with_normals,
                             row_layout=None if source.row_layout.empty else source.row_layout,
                             leaf_folder=source.leaf_folder, unit_length=tree.unit_length, seams=seams, proxies=plan,
                             spill=LodSpill(scratch_dir) if cache is None and plan is None else None)
        simplify_phase(layout, nodes.lods, hausdorff_error=nodes.hausdorff_error, made=nodes.made, settings=settings,
                       source=what, workers=workers, cancel=run.cancel, progress=run.progress)
        clock.lap("simplify")
    return nodes
