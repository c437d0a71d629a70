"""The simplify phase's task scheduler: every inner node without a LOD yet is decimated once its
children's LODs exist and then measured, as tasks on `workers.Workers`.

Three kinds of task: DECIMATE a node (simplify.decimate_node), MEASURE its error (exact:
tasks.measure_exact over the leaves' shared arrays; bound: hausdorff.measure_to_children against
its children's LODs, the bounds composed after the phase, `compose_bounds`) and, where the node's
sources need one, bake its PROXY material (bake/appearance/proxy_task.py; `ProxyPlan`). Priority:
decimations first, deepest first (they unlock the rest), then measurements, largest first, then
proxies; at most `workers.limit` tasks are in flight, so the priority holds. With proxies, a node is
decimated once its children are complete (their proxies made: its sources and its decision whether
to decimate freely depend on them); without, once they are decimated.
Why: docs/how-it-works.md#scheduling-the-simplify-phase

The task functions are looked up on their modules at each submit (simplify.decimate_node,
tasks.measure_exact, hausdorff.measure_to_children), and leaf_arrays.build when it runs: a jobs-1
bake runs them all in this process, where a profiler or a test may wrap them
(benchmarks/rebake.py, benchmarks/dask_bake.py, tests/test_bake_cache.py).

Data form: lods, per node (positions (k,3) f32, faces (m,3) int32, normals (k,3) f32 or None,
attribute rows (k,A) f32 or None), None where not made yet; hausdorff (n,) float64 model units.
"""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import dataclasses
import heapq
import os
import threading
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ...core.arrays import segment_ranges
from ...core.errors import BakeCancelled
from ...core.signals import deliver_held
from ...model.appearance import AttributeLayout
from ..appearance import proxy_task
from ..appearance.proxy_plan import ProxyPlan
from ..decimate import simplify
from ..decimate.cell_seams import CellSeams
from ..measure import hausdorff, leaf_arrays
from ..measure.leaf_arrays import LeafArrays
from ..settings import BakeSettings
from ..space.octree import OctreeLayout
from . import tasks
from .lod_spill import LodSpill
from .workers import Workers

#: progress(done_nodes, total_nodes, phase)
ProgressFn = Callable[[int, int, str], None]
#: cancel() -> True to stop the bake (checked between tasks)
CancelFn = Callable[[], bool]

#: Task kinds of the simplify phase; the values order the heap (decimations before measurements).
TASK_DECIMATE, TASK_MEASURE, TASK_PROXY = 0, 1, 2
#: How often (seconds) the scheduler wakes while tasks run, to check cancel().
POLL_SECONDS = 0.25


@dataclass(frozen=True)
class SimplifyInput:
    """What the phase decimates: with_normals (the LODs carry normals), row_layout (the attribute
    rows' columns; None without rows), leaf_folder (a folder for the exact measure's leaf
    arrays, memory-mapped: an out-of-core bake; None: in memory), unit_length (the lattice the
    positions are points of, bake/space/lattice.py; 0: none) and seams (what each node shares with the cells
    around it, kept in place; None: every open boundary is kept); spill (lod_spill.LodSpill): where
    a node's children's LODs go once the node is complete, no task reading them again (None: they
    stay in memory; only without proxies, whose plan rewrites the LODs after the phase, and without
    a cache, which stores them)."""

    with_normals: bool
    row_layout: AttributeLayout | None
    leaf_folder: str | os.PathLike | None = None
    unit_length: float = 0.0
    seams: CellSeams | None = None
    proxies: ProxyPlan | None = None
    spill: LodSpill | None = None


def simplify_phase(layout: OctreeLayout, lods: list, *, hausdorff_error: np.ndarray, made: dict,
                   settings: BakeSettings, source: SimplifyInput, workers: Workers, cancel: CancelFn,
                   progress: ProgressFn) -> None:
    """The inner nodes not in `made` (the cache's are, with their LODs in lods and errors in
    hausdorff_error) decimated and measured, made[node] (a simplify.NodeLod) set as each completes
    and progress reported per node; with the "bound" measure the bounds composed. BakeCancelled
    once cancel() turns true."""
    n = layout.node_count
    inner = np.flatnonzero(~layout.is_leaf)
    from_cache = np.fromiter(made, np.int64, count=len(made))
    done = n - inner.size + len(made)
    progress(done, n, "simplify")

    complete = layout.is_leaf.copy()  # decimated and measured (leaves: from the start)
    complete[from_cache] = True

    def node_done(node: int, lod: simplify.NodeLod) -> None:
        nonlocal done
        made[node] = lod
        complete[node] = True
        if source.spill is not None:
            _spill_finished(node, layout, lods, made, source.spill, complete)
        done += 1
        progress(done, n, "simplify")

    _Scheduler(layout, lods, hausdorff_error, settings=settings, source=source, workers=workers).run(
        cancel=cancel, node_done=node_done)
    if cancel():
        raise BakeCancelled("bake cancelled")
    if settings.error == "bound":
        compose_bounds(layout, hausdorff_error, rebuilt=np.setdiff1d(inner, from_cache))


def _spill_finished(node: int, layout: OctreeLayout, lods: list, made: dict, spill: LodSpill,
                    complete: np.ndarray) -> None:
    """`node` is now decimated and measured (complete[node]): every LOD no task reads again goes to
    the spill file: a complete node's, once its parent is complete too (the parent's decimation and
    measurement, the bound measure's included, are the last tasks to read it); so `node` itself if
    its parent is complete, and its complete children. In lods and, for inner nodes, in made (whose
    NodeLod holds the same arrays)."""
    first = int(layout.child_offset[node])
    parent = int(layout.parent[node])
    done = [child for child in range(first, first + int(layout.child_count[node])) if complete[child]]
    for finished in done + ([node] if parent >= 0 and complete[parent] else []):
        lods[finished] = spill.put(lods[finished])
        if finished in made:
            made[finished] = dataclasses.replace(made[finished], positions=lods[finished][0],
                                                 faces=lods[finished][1], normals=lods[finished][2],
                                                 attributes=lods[finished][3])


def compose_bounds(layout: OctreeLayout, hausdorff_error: np.ndarray, *, rebuilt: np.ndarray) -> None:
    """Bound measure: hausdorff_error[node] holds h(node) (hausdorff.measure_to_children) for the
    `rebuilt` inner nodes and the final bound for the others (leaves 0, cache entries); make the
    rebuilt ones h + the largest child bound, deepest level first:
        bound(leaf) = 0;  bound(n) = h(n) + max over children c of bound(c).
    A NaN (no distance from pymeshlab) stays NaN up the tree (assemble bounds such a node by its
    box diagonal). Why: docs/how-it-works.md#the-error-bound"""
    pending = np.zeros(layout.node_count, bool)
    pending[rebuilt] = True
    for d in range(int(layout.depth.max()) - 1, -1, -1):
        nodes = np.flatnonzero((layout.depth == d) & pending)
        if nodes.size == 0:
            continue
        first, count = layout.child_offset[nodes], layout.child_count[nodes]
        kids = segment_ranges(first, count)
        worst = np.full(nodes.size, -np.inf)
        np.maximum.at(worst, np.repeat(np.arange(nodes.size), count), hausdorff_error[kids])
        hausdorff_error[nodes] += worst


class _Scheduler:
    """One simplify phase's tasks (module docstring): the heap of tasks ready to run, the ones in
    flight, the LODs decimated but not yet measured, and the leaf arrays of the exact measure."""

    def __init__(self, layout: OctreeLayout, lods: list, hausdorff_error: np.ndarray, *, settings: BakeSettings,
                 source: SimplifyInput, workers: Workers):
        self.layout, self.lods, self.hausdorff_error = layout, lods, hausdorff_error
        self.source, self.workers = source, workers
        self.decimation = settings.decimation()
        self.bound = settings.error == "bound"
        self.todo = np.array([lod is None for lod in lods]) & ~layout.is_leaf
        self.waiting = np.zeros(layout.node_count, np.int64)  # children whose LODs are still to make
        todo_children = np.flatnonzero(self.todo & (layout.parent >= 0))
        np.add.at(self.waiting, layout.parent[todo_children], 1)
        self.heap: list[tuple[int, int, int]] = []  # (kind, size, node), smallest first
        self.running: dict[cf.Future, tuple[int, int]] = {}  # future -> (kind, node)
        self.decimated: dict[int, simplify.NodeLod] = {}  # LODs made, until their measurement is done
        self.leaves: LeafArrays | None = None  # the exact measure's tasks wait for them
        self.plan = source.proxies if source.row_layout is not None else None
        if self.plan is not None:
            self.plan.share(workers)

    def run(self, *, cancel: CancelFn, node_done: Callable[[int, simplify.NodeLod], None]) -> None:
        """Run every task; node_done(node, lod) once a node is decimated and measured. The exact
        measure's leaf arrays are made on a thread of this process while the workers run the first
        decimations (inline: first, in this thread)."""
        nodes = np.flatnonzero(self.todo)
        if nodes.size == 0:
            return
        for node in nodes[self.waiting[nodes] == 0]:
            self._push(TASK_DECIMATE, int(node))
        with contextlib.ExitStack() as stack:
            building = None
            if not self.bound and self.workers.scratch:
                builder = stack.enter_context(cf.ThreadPoolExecutor(max_workers=1,
                                                                    thread_name_prefix="hlod-leaf-arrays"))
                leaving = threading.Event()  # set first when the loop ends: the builder stops waiting on its tasks
                stack.callback(leaving.set)
                building = builder.submit(self._shared_leaf_arrays, leaving.is_set)
            elif not self.bound:
                self.leaves = self._shared_leaf_arrays()
            while self.heap or self.running:
                self._submit_ready()
                waits = [*self.running, *([building] if self.leaves is None and building else [])]
                finished, _ = cf.wait(waits, timeout=POLL_SECONDS, return_when=cf.FIRST_COMPLETED)
                if cancel():
                    raise BakeCancelled("bake cancelled")
                for fut in finished:
                    if fut is building:
                        self.leaves = building.result()
                    else:
                        self._finish(fut, node_done=node_done)

    def _shared_leaf_arrays(self, cancel: CancelFn | None = None) -> LeafArrays:
        """The leaf arrays (the leaves' entries of lods only: final), their clusters cut on the
        workers (leaf_arrays.cut_clusters), shared with the workers; where the workers read them
        from a scratch folder, this process keeps only each node's ranges."""
        arrays = leaf_arrays.build(self.layout, self.lods, folder=self.source.leaf_folder, workers=self.workers,
                                   cancel=cancel)
        self.workers.share(arrays.arrays())
        # the workers map their own copy from the scratch folder: this process keeps the ranges only
        return arrays.ranges_only() if self.workers.scratch else arrays

    def _push(self, kind: int, node: int) -> None:
        layout = self.layout
        if kind == TASK_DECIMATE:
            size = -int(layout.depth[node])
        elif kind == TASK_PROXY:
            size = -int(layout.depth[node])
        else:
            size = -int(layout.tri_end[node] - layout.tri_begin[node])
        heapq.heappush(self.heap, (kind, size, node))

    def _submit_ready(self) -> None:
        """Submit tasks from the heap while fewer than workers.limit run."""
        while self.heap and len(self.running) < self.workers.limit:
            if self.heap[0][0] == TASK_MEASURE and self.leaves is None and not self.bound:
                return  # every decimation that can run is in flight: wait for the leaf arrays
            kind, size, node = heapq.heappop(self.heap)
            self.running[self._submit(kind, size, node)] = (kind, node)

    def _submit(self, kind: int, size: int, node: int) -> cf.Future:
        layout, lods = self.layout, self.lods
        kids = range(layout.child_offset[node], layout.child_offset[node] + layout.child_count[node])
        order = (kind, size)
        if kind == TASK_PROXY:
            plan = self.plan
            return self.workers.submit(order, proxy_task.make_proxy, self.workers.scratch,
                                       (lods[node][0], lods[node][1], lods[node][2]),
                                       float(self.hausdorff_error[node]),
                                       [(lods[k][0], lods[k][1], lods[k][3]) for k in kids], node=node,
                                       layout=self.source.row_layout, scene_materials=plan.scene_materials,
                                       child_proxies=plan.child_proxies([lods[k][3] for k in kids]),
                                       settings=plan.settings, free=node in plan.free)
        if kind == TASK_DECIMATE:
            children = [(lods[k][0], lods[k][1], lods[k][3]) for k in kids]
            if self.plan is not None and self.plan.decimate_freely(node, [c[2] for c in children]):
                children = [(c[0], c[1]) for c in children]
            seams = None if self.source.seams is None else self.source.seams.locked(node)
            return self.workers.submit(order, simplify.decimate_node, children, self.decimation,
                                       with_normals=self.source.with_normals, layout=self.source.row_layout,
                                       unit_length=self.source.unit_length, seams=seams)
        if self.bound:
            return self.workers.submit(order, hausdorff.measure_to_children, (lods[node][0], lods[node][1]),
                                       [(lods[k][0], lods[k][1]) for k in kids])
        return self.workers.submit(order, tasks.measure_exact, self.workers.scratch, (lods[node][0], lods[node][1]),
                                   self.leaves.ranges(node))

    def _finish(self, fut: cf.Future, *, node_done) -> None:
        """A task's result: a measurement completes its node; a decimation queues its measurement
        and, once all siblings are done, the parent's decimation."""
        kind, node = self.running.pop(fut)
        try:
            result = fut.result()
        except Exception:
            deliver_held()  # a stop signal that also ended the workers wins over their failure
            raise
        if kind == TASK_MEASURE:
            self.hausdorff_error[node] = result
            if self.plan is not None and self.plan.wants_proxy(node, self.lods[node][3]):
                self._push(TASK_PROXY, node)
            else:
                self._complete(node, node_done=node_done)
            return
        if kind == TASK_PROXY:
            if result is not None:
                self.lods[node] = (result.positions, result.faces, result.normals, result.rows)
                self.decimated[node] = self.plan.made(node, result, self.decimated[node])
            self.plan.release_children(node, self.layout, self.lods)
            self._complete(node, node_done=node_done)
            return
        self.lods[node] = (result.positions, result.faces, result.normals, result.attributes)
        self.decimated[node] = result
        self._push(TASK_MEASURE, node)
        if self.plan is None:
            self._unlock_parent(node)

    def _complete(self, node: int, *, node_done) -> None:
        """`node` decimated, measured and (with proxies) its proxy made: hand it over, and with
        proxies unlock its parent."""
        node_done(node, self.decimated.pop(node))
        if self.plan is not None:
            self._unlock_parent(node)

    def _unlock_parent(self, node: int) -> None:
        """One child of node's parent fewer to wait for; the parent's decimation once none is left."""
        parent = int(self.layout.parent[node])
        if parent >= 0 and self.todo[parent]:
            self.waiting[parent] -= 1
            if self.waiting[parent] == 0:
                self._push(TASK_DECIMATE, parent)
