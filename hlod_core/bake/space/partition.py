"""Streamed octree partition: an input bigger than memory, never loaded whole, for
pipeline.bake_stream (sources.StreamedSource).

Data form in: a `TriangleSource`, a re-iterable stream of `TriangleChunk`s (positions (v,3)
float64 model units, faces (f,3) int64 rows of them, normals (v,3) float32 or None), e.g. a scene
spec read one instance at a time (`SceneSource`). Data form out: one scratch file per leaf cell
holding its triangles as `record_dtype` rows (3 global vertex ids int64, 3 corners float32
relative to the origin, 3 corner normals float32 when the input has them), in input order, and
`leaf_lod`, a leaf's compacted vertices and faces read from its file alone (`mapped_leaf_lods`:
all leaves written back into one file per array, each memory-mapped once).

The passes over the stream (each a chunk of at most `chunk_tris` triangles at a time):
    scan     -> the origin and the lattice (the used vertices' box: pass 1), then the float32
                positions relative to it (lattice points), the centroids' box (the root cell) and
                the counted triangles
                (pass 2), as prepare.prepare computes them (prepare.triangle_centroids)
    octree   -> octree.build_octree_counted: one counting pass per depth, build_octree's layout
    route    -> each chunk's triangles go to their leaf (OctantRouter.route) and are buffered; once
                `chunk_tris` triangles are buffered every cell with some is appended to (one file
                open at a time, never one handle per cell)
    leaves   -> `leaf_lod` reads one cell's file: the vertices its triangles use in ascending
                global vertex id, the faces local to them: arrays.compact's order, so the leaves
                equal the in-memory bake's.
A global vertex id is the chunk's offset (the vertices of the chunks before it) plus the vertex's
row: the merged mesh meshes.load_inputs would make, without making it. Nothing here holds an array
of one row per input triangle or vertex.
Why: docs/how-it-works.md#out-of-core-bakes

`Partition` owns its scratch folder (`hlod-partition-*` in the scratch folder or the temporary
folder) and removes it when its block exits, however it exits. Geometry only: an input with
materials, UVs or colours is refused (InputError naming the file). Normals travel with the
corners when every chunk has them (as meshes.merge keeps them).
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, Protocol

import numpy as np

from ...core.errors import BakeCancelled, InputError
from ...io import meshes
from ..prepare import triangle_centroids
from . import lattice, octree

log = logging.getLogger(__name__)

#: Triangles per piece of a chunk a pass works on, and buffered before the cell files are appended
#: to: the partition's memory budget (about 200 bytes a triangle of it at the peak of a pass).
CHUNK_TRIS = 1 << 18


@dataclass(frozen=True, eq=False)
class TriangleChunk:
    """One piece of the input: positions (v,3) float64 model units, faces (f,3) int64 rows of
    them, normals (v,3) float32 or None; name for messages."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None
    name: str


class TriangleSource(Protocol):
    """A stream of chunks that yields the same chunks, in the same order, each time `chunks()` is
    called; name: the input's name for messages."""

    name: str

    def chunks(self) -> Iterator[TriangleChunk]: ...


class SceneSource:
    """The command line's INPUTs (mesh files and JSON scene specs, in order, as
    meshes.load_inputs merges them) as a stream: one chunk per placed instance of a spec, one per
    mesh file. A file placed more than once (a spec's model) is read on the first pass and kept,
    and each instance is made from it when the stream reaches it; a file placed once is read
    again on every pass (kept, many such files would be the whole input). A single file must fit
    in memory. Specs are read and their transforms checked when the source is made."""

    def __init__(self, paths: list[str | os.PathLike]):
        self.name = ", ".join(str(p) for p in paths)
        # (file, transforms or None: as it is, the message prefix of its entry: "SPEC: models[i]")
        self._inputs: list[tuple[Path, list[np.ndarray] | None, str]] = []
        for p in paths:
            if Path(p).suffix.lower() == ".json":
                self._inputs.extend((model, transforms, f"{p}: models[{i}]")
                                    for i, (model, transforms) in enumerate(meshes.scene_spec_models(Path(p))))
            else:
                self._inputs.append((Path(p), None, str(p)))
        self._meshes: dict[Path, meshes.TriangleMesh] = {}
        self._placed: dict[Path, int] = {}  # placements per file
        for path, transforms, _ in self._inputs:
            self._placed[path] = self._placed.get(path, 0) + (1 if transforms is None else len(transforms))

    def chunks(self) -> Iterator[TriangleChunk]:
        for path, transforms, entry in self._inputs:
            mesh = self._mesh(path)
            if transforms is None:
                yield TriangleChunk(mesh.positions, mesh.faces, mesh.normals, str(path))
                continue
            for j, matrix in enumerate(transforms):  # the in-memory reader's names and messages
                placed = meshes.place(mesh, matrix, name=f"{path}#{j}", where=f"{entry}.transforms[{j}]", what=path)
                yield TriangleChunk(placed.positions, placed.faces, placed.normals, placed.name)

    def _mesh(self, path: Path) -> meshes.TriangleMesh:
        mesh = self._meshes.get(path)
        if mesh is None:
            mesh = meshes.load_mesh(path)
            if mesh.has_appearance:
                raise InputError(f"{path}: has materials, UVs or colours; out-of-core bakes take geometry only "
                                 "(bake it without --out-of-core to keep its appearance)")
            if self._placed[path] > 1:
                self._meshes[path] = mesh
        return mesh


class MeshSource:
    """A TriangleMesh as a stream of one chunk (tests; an input already in memory)."""

    def __init__(self, mesh: meshes.TriangleMesh):
        if mesh.has_appearance:
            raise InputError(f"{mesh.name}: has materials, UVs or colours; out-of-core bakes take geometry only")
        self.name, self._mesh = mesh.name, mesh

    def chunks(self) -> Iterator[TriangleChunk]:
        yield TriangleChunk(self._mesh.positions, self._mesh.faces, self._mesh.normals, self._mesh.name)


@dataclass(frozen=True)
class Scan:
    """What the scan passes found: origin (3,) float64, unit_length (the lattice's, lattice.py) and
    root (octree.RootCube, origin-relative) as prepare.prepare makes them; tri_count, vertex_count
    (every vertex of every chunk, used or not),
    counted_count (triangles not collapsed); with_normals: every chunk has normals."""

    origin: np.ndarray
    unit_length: float
    root: octree.RootCube
    tri_count: int
    vertex_count: int
    counted_count: int
    with_normals: bool


@dataclass
class PartitionStats:
    """What a Partition did, for tests and logs: passes over the stream, pieces (chunk pieces
    worked on), largest_piece_tris (the longest per-triangle array of any pass), flushes (times the
    buffered triangles were appended to their cells), cell_appends (file appends), leaf_reads
    (leaf -> triangles read from its file)."""

    passes: int = 0
    pieces: int = 0
    largest_piece_tris: int = 0
    flushes: int = 0
    cell_appends: int = 0
    leaf_reads: dict = field(default_factory=dict)


def record_dtype(with_normals: bool) -> np.dtype:
    """A cell file's row, one triangle: vertex (3,) int64 global vertex ids, corner (3,3) float32
    positions relative to the origin, normal (3,3) float32 (with normals)."""
    fields = [("vertex", "<i8", (3,)), ("corner", "<f4", (3, 3))]
    if with_normals:
        fields.append(("normal", "<f4", (3, 3)))
    return np.dtype(fields)


@dataclass(frozen=True, eq=False)
class _Piece:
    """Some triangles of a chunk: faces (t,3) int64 global vertex ids, corners (t,3,3) float32
    relative to the origin, normals (t,3,3) float32 or None."""

    chunk: TriangleChunk
    faces: np.ndarray
    corners: np.ndarray
    normals: np.ndarray | None


class Partition:
    """The streamed partition of one bake (module docstring); a context manager owning the scratch
    folder. cancel() is checked between pieces (BakeCancelled)."""

    def __init__(self, source: TriangleSource, *, scratch_dir: str | os.PathLike | None = None,
                 chunk_tris: int = CHUNK_TRIS, cancel: Callable[[], bool] | None = None,
                 stats: PartitionStats | None = None):
        if chunk_tris < 1:
            raise InputError(f"chunk_tris must be at least 1, got {chunk_tris}")
        self.source, self.chunk_tris = source, int(chunk_tris)
        self.cancel = cancel or (lambda: False)
        self.scratch_root = Path(tempfile.gettempdir() if scratch_dir is None else scratch_dir)
        if not self.scratch_root.is_dir():
            raise InputError(f"{self.scratch_root}: the scratch folder does not exist")
        self.folder: Path | None = None
        self.stats = PartitionStats() if stats is None else stats
        self.scan_result: Scan | None = None
        self.tree: octree.CountedOctree | None = None

    def __enter__(self) -> "Partition":
        self.folder = Path(tempfile.mkdtemp(prefix="hlod-partition-", dir=self.scratch_root))
        return self

    def __exit__(self, kind, exc, tb) -> None:
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder = None

    # --- passes -----------------------------------------------------------------------------------

    def _pieces(self, origin: np.ndarray, length: float, with_normals: bool = False) -> Iterator[_Piece]:
        """One pass: every chunk cut into pieces of at most chunk_tris triangles, in input order."""
        self.stats.passes += 1
        offset = 0
        for chunk in self.source.chunks():
            f = chunk.faces.shape[0]
            for lo in range(0, f, self.chunk_tris):
                if self.cancel():
                    raise BakeCancelled("bake cancelled")
                faces = chunk.faces[lo:lo + self.chunk_tris]
                # rel = positions - origin, stored as float32 lattice points (prepare.prepare)
                corners = lattice.stored(chunk.positions[faces] - origin, length)
                normals = chunk.normals[faces] if with_normals else None
                self.stats.pieces += 1
                self.stats.largest_piece_tris = max(self.stats.largest_piece_tris, faces.shape[0])
                yield _Piece(chunk, faces + offset, corners, normals)
            offset += chunk.positions.shape[0]

    def scan(self) -> Scan:
        """Passes 1 and 2 (module docstring)."""
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        tris = vertices = 0
        with_normals = True
        for chunk in self.source.chunks():
            if self.cancel():
                raise BakeCancelled("bake cancelled")
            used = np.zeros(chunk.positions.shape[0], bool)
            used[chunk.faces.ravel()] = True
            p_used = chunk.positions[used]
            if p_used.size:
                if not np.all(np.isfinite(p_used)):
                    raise InputError(f"{chunk.name}: vertices used by faces have NaN or infinite coordinates")
                lo, hi = np.minimum(lo, p_used.min(axis=0)), np.maximum(hi, p_used.max(axis=0))
            tris += chunk.faces.shape[0]
            vertices += chunk.positions.shape[0]
            with_normals &= chunk.normals is not None
        self.stats.passes += 1
        if tris == 0:
            raise InputError(f"{self.source.name}: the mesh has no triangles")
        origin, length = 0.5 * (lo + hi), lattice.unit_length(lo, hi)
        c_lo, c_hi = np.full(3, np.inf), np.full(3, -np.inf)
        counted_count = 0
        for piece in self._pieces(origin, length):
            if not np.all(np.isfinite(piece.corners)):
                raise InputError(f"{piece.chunk.name}: coordinates exceed the float32 range after centring")
            centroids, counted = _centroids(piece.corners)
            c_lo, c_hi = np.minimum(c_lo, centroids.min(axis=0)), np.maximum(c_hi, centroids.max(axis=0))
            counted_count += int(counted.sum())
        self.scan_result = Scan(origin=origin, unit_length=length, root=octree.tight_cube(c_lo, c_hi),
                                tri_count=tris,
                                vertex_count=vertices, counted_count=counted_count, with_normals=with_normals)
        log.info("out-of-core scan: %d triangles, %d vertices", tris, vertices)
        return self.scan_result

    def build_octree(self, *, target_tris: int, max_depth: int) -> octree.CountedOctree:
        """octree.build_octree_counted over the stream (after `scan`)."""
        scan = self.scan_result

        def count_pass(query: octree.OctantQuery):
            every = mine = 0
            for piece in self._pieces(scan.origin, scan.unit_length):
                e, m = query.count(*_centroids(piece.corners))
                every, mine = every + e, mine + m
            return every, mine

        self.tree = octree.build_octree_counted(count_pass, root=scan.root, tri_count=scan.tri_count,
                                                counted_count=scan.counted_count, target_tris=target_tris,
                                                max_depth=max_depth)
        return self.tree

    def route(self) -> None:
        """The routing pass (after `build_octree`): every triangle appended to its leaf's file."""
        scan, router = self.scan_result, self.tree.router
        dtype = record_dtype(scan.with_normals)
        buffered: dict[int, list[np.ndarray]] = {}
        count = 0
        for piece in self._pieces(scan.origin, scan.unit_length, scan.with_normals):
            centroids, _ = _centroids(piece.corners)
            leaf = router.route(centroids)
            del centroids
            rows = np.empty(leaf.shape[0], dtype)
            rows["vertex"], rows["corner"] = piece.faces, piece.corners
            if scan.with_normals:
                rows["normal"] = piece.normals
            order = np.argsort(leaf, kind="stable")  # input order within a leaf
            leaves, starts = np.unique(leaf[order], return_index=True)
            rows = rows[order]  # one array per piece; the cells buffer views of it
            ends = np.append(starts[1:], order.size)
            for node, start, end in zip(leaves.tolist(), starts.tolist(), ends.tolist()):
                buffered.setdefault(node, []).append(rows[start:end])
            count += leaf.shape[0]
            if count >= self.chunk_tris:
                self._flush(buffered)
                count = 0
        self._flush(buffered)

    def _flush(self, buffered: dict[int, list[np.ndarray]]) -> None:
        if not buffered:
            return
        self.stats.flushes += 1
        for node in sorted(buffered):
            with open(self._cell_file(node), "ab") as f:
                for part in buffered[node]:
                    f.write(memoryview(part).cast("B"))
            self.stats.cell_appends += 1
        buffered.clear()

    def _cell_file(self, node: int) -> Path:
        return self.folder / f"cell-{node}.bin"

    def leaf_lod(self, node: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(positions (k,3) float32, faces (m,3) int32 local to them, normals (k,3) float32 or None)
        of one leaf, from its cell file alone (removed once read): the vertices in ascending global
        id, as arrays.compact orders them."""
        path = self._cell_file(node)
        rows = np.fromfile(path, record_dtype(self.scan_result.with_normals))
        path.unlink()
        self.stats.leaf_reads[node] = rows.shape[0]
        if rows.shape[0] != self.tree.tri_count[node]:
            raise RuntimeError(f"partition: cell {node} holds {rows.shape[0]} triangles, the octree counted "
                               f"{int(self.tree.tri_count[node])}")
        used, first, local = np.unique(rows["vertex"].reshape(-1), return_index=True, return_inverse=True)
        positions = rows["corner"].reshape(-1, 3)[first]
        normals = rows["normal"].reshape(-1, 3)[first] if self.scan_result.with_normals else None
        return positions, local.reshape(-1, 3).astype(np.int32), normals

    def mapped_leaf_lods(self, leaves) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray | None]]:
        """leaf_lod of each of `leaves`, appended to one file per array (positions, faces, normals)
        in the scratch folder, each file memory-mapped once, and every leaf's arrays read-only
        views of those maps: the bake's process holds no leaf's triangles in its own memory, and
        three maps hold three file descriptors however many leaves there are
        (docs/how-it-works.md#out-of-core-bakes)."""
        names = ("positions", "faces", "normals")
        dtypes = (np.float32, np.int32, np.float32)
        extents: dict[int, list[tuple[int, int] | None]] = {}
        offsets = [0, 0, 0]  # rows written to each file
        files = [open(self.folder / f"leaves-{name}.bin", "wb") for name in names]
        try:
            for node in leaves:
                node = int(node)
                extents[node] = []
                for k, array in enumerate(self.leaf_lod(node)):
                    if array is None:
                        extents[node].append(None)
                        continue
                    files[k].write(memoryview(np.ascontiguousarray(array, dtypes[k])).cast("B"))
                    extents[node].append((offsets[k], offsets[k] + array.shape[0]))
                    offsets[k] += array.shape[0]
        finally:
            for f in files:
                f.close()
        maps = [np.memmap(self.folder / f"leaves-{name}.bin", dtype=dtypes[k], mode="r", shape=(offsets[k], 3))
                if offsets[k] else None for k, name in enumerate(names)]
        return {node: tuple(None if extent is None else np.asarray(maps[k][extent[0]:extent[1]])
                            for k, extent in enumerate(spans)) for node, spans in extents.items()}


def _centroids(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """prepare.triangle_centroids of corners (t,3,3) float32: centroids (t,3) float64 (C-ordered, whose
    min(axis=0) picks the same zero a C-ordered array always did), counted (t,) bool."""
    centroids, counted = triangle_centroids(corners[:, 0], corners[:, 1], corners[:, 2])
    return np.ascontiguousarray(centroids), counted
