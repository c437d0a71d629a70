"""The inputs a bake reads, behind one protocol (`BakeSource`), so that the pipeline writes its
phases once: a TriangleMesh in memory (`InMemorySource`) and a stream of triangle chunks bigger
than memory, partitioned through scratch files (`StreamedSource`, over partition.Partition).
Where the tasks run (this process, worker processes, a Dask cluster) is not a source's business
but the workers' (bake/run/workers.py).

Each source computes the same floats from the same triangles (the origin, the root cell, the
octree, each leaf's compacted vertices), so both bake the same file, byte for byte except
meta.VOLATILE_META. A source serves one bake.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from ..io.meshes import TriangleMesh
from ..model.appearance import AttributeLayout
from . import prepare
from .meta import InputSize, PhaseClock, counted_per_node
from .settings import BakeSettings
from .space.chunk_store import open_store
from .space.frame import FROM_SCRATCH, Frame, FrameChoice, Prior
from .space.octree import OctreeLayout, build_octree
from .space.partition import Partition

log = logging.getLogger(__name__)

#: The attribute layout of a bake without appearance.
NO_ROWS = AttributeLayout(False, False, False)


@dataclass(frozen=True, eq=False)
class SourceOctree:
    """A source's octree: layout; frame (frame.Frame: its origin (3,) float64, model units, which
    positions are stored relative to, its unit_length, model units, whose lattice the stored
    positions are points of (bake/space/lattice.py), its root cube) and frame_choice (where the frame came
    from); counted_per_node (n,) int64 (each node's triangles that are not collapsed) and
    collapsed_tris (the input's collapsed triangles)."""

    layout: OctreeLayout
    frame: Frame
    frame_choice: FrameChoice
    counted_per_node: np.ndarray
    collapsed_tris: int

    @property
    def origin(self) -> np.ndarray:
        return self.frame.origin

    @property
    def unit_length(self) -> float:
        return self.frame.unit_length


class BakeSource(Protocol):
    """What the pipeline reads an input through, in this order: `count` (before any worker
    starts), `octree`, `leaf_lods`; each names the phases it runs on the clock. After `count`:
    size (for meta) and with_normals; after `octree`: row_layout (attribute rows' columns, empty
    without). materials: the input's (empty without appearance); leaf_folder: where the exact
    measure's leaf arrays are memory-mapped (None: in memory); log_note: said after the octree's
    size in the log."""

    size: InputSize
    with_normals: bool
    row_layout: AttributeLayout
    materials: tuple
    leaf_folder: Path | None
    log_note: str

    def count(self, clock: PhaseClock) -> int:
        """The input's triangles."""

    def octree(self, settings: BakeSettings, clock: PhaseClock, workers=None) -> SourceOctree:
        """The octree of the input at `settings`; workers (bake/run/workers.Workers or None): where
        its passes over the triangles may run as tasks."""

    def leaf_lods(self, layout: OctreeLayout, clock: PhaseClock) -> list[tuple | None]:
        """Per node, None for inner nodes, for each leaf (positions (k,3) f32, faces (m,3) int32,
        normals (k,3) f32 or None, attribute rows (k,A) f32 or None): its original triangles."""


class InMemorySource:
    """A TriangleMesh (prepare.py), in the frame of `prior` while it fits (bake/space/frame.py): phases
    "prepare" and "octree", then the leaves from its arrays (the "leaves" phase: made by `octree`,
    while the chunk store its tasks read is open; handed over by `leaf_lods`, after which it lets the
    mesh and its prepared arrays go: freed where the caller handed the mesh over, pipeline.bake)."""

    log_note = ""
    leaf_folder = None

    def __init__(self, mesh: TriangleMesh, prior: Prior | None = None):
        self.mesh = mesh
        self.prior = prior
        self.size = InputSize(tris=mesh.tri_count, vertices=int(mesh.positions.shape[0]), name=mesh.name)
        self.with_normals = mesh.normals is not None
        self.materials = tuple(mesh.materials) if mesh.has_appearance else ()
        self._prepared: prepare.Prepared | None = None
        self._leaves: list | None = None

    @property
    def row_layout(self) -> AttributeLayout:
        return self._prepared.row_layout

    def count(self, clock: PhaseClock) -> int:
        return self.mesh.tri_count

    def octree(self, settings: BakeSettings, clock: PhaseClock, workers=None) -> SourceOctree:
        with open_store(workers, rows=self.mesh.tri_count) as store:  # the arrays the tasks share
            prepared = prepare.prepare(self.mesh, self.prior, store=store)
            clock.lap("prepare")
            layout = build_octree(prepared.centroids, target_tris=settings.target_tris, max_depth=settings.max_depth,
                                  counted=prepared.counted, root=prepared.root_cell, store=store)
            self._prepared = prepared = replace(prepared, centroids=None)  # only the octree reads them
            clock.lap("octree")
            self._leaves = prepare.leaf_lods(layout, prepared, store)  # the "leaves" phase, while the store is open
        return SourceOctree(layout=layout, frame=prepared.frame, frame_choice=prepared.frame_choice,
                            counted_per_node=counted_per_node(layout, prepared.counted),
                            collapsed_tris=int((~prepared.counted).sum()))

    def leaf_lods(self, layout: OctreeLayout, clock: PhaseClock) -> list[tuple | None]:
        leaves, self._leaves = self._leaves, None
        # the leaves hold what the bake reads from here on: the input goes with this source's references
        self.mesh = None
        self._prepared = replace(self._prepared, positions=None, faces=None, normals=None, rows=None)
        return leaves


class StreamedSource:
    """A partition.Partition the caller holds open (its scratch folder holds the cell files and
    the memory-mapped leaves): phases "scan", "octree" and "route". Geometry only (normals kept)."""

    log_note = " (out of core)"
    row_layout = NO_ROWS
    materials = ()

    def __init__(self, partition: Partition):
        self.partition = partition
        self.size: InputSize | None = None
        self.with_normals = False

    @property
    def leaf_folder(self) -> Path:
        return self.partition.folder

    def count(self, clock: PhaseClock) -> int:
        scan = self.partition.scan()
        clock.lap("scan")
        self.size = InputSize(tris=scan.tri_count, vertices=scan.vertex_count, name=self.partition.source.name)
        self.with_normals = scan.with_normals
        return scan.tri_count

    def octree(self, settings: BakeSettings, clock: PhaseClock, workers=None) -> SourceOctree:
        tree = self.partition.build_octree(target_tris=settings.target_tris, max_depth=settings.max_depth)
        clock.lap("octree")
        scan = self.partition.scan_result
        frame = Frame(origin=scan.origin, unit_length=scan.unit_length, root=scan.root)
        return SourceOctree(layout=tree.layout, frame=frame, frame_choice=FROM_SCRATCH,
                            counted_per_node=tree.counted,
                            collapsed_tris=scan.tri_count - scan.counted_count)

    def leaf_lods(self, layout: OctreeLayout, clock: PhaseClock) -> list[tuple | None]:
        self.partition.route()
        clock.lap("route")
        lods: list[tuple | None] = [None] * layout.node_count
        mapped = self.partition.mapped_leaf_lods(np.flatnonzero(layout.is_leaf))
        for leaf, (positions, faces, normals) in mapped.items():
            lods[leaf] = (positions, faces, normals, None)  # memory-mapped from the scratch folder
        return lods
