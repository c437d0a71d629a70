"""Out-of-core bakes (bounded memory): the streamed partition against the in-memory bake.

The main check: a scene spec baked from memory (meshes.load_inputs + bake) and out of core
(partition.SceneSource + bake_stream, a small chunk forcing many pieces and flushes) gives
the same .hlod bytes once the volatile meta (timings) is left out. Then that it really is out of
core: no array of one row per input triangle in the partition (tracemalloc's peak stays below one
(f,) int64 array), every leaf reads its own cell's file and nothing else, and the scratch folder
is empty after a bake, an error and a cancel.
"""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import ROOT, file_bytes, model
from hlod_core.bake.pipeline import bake, bake_stream
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space import octree, octree_passes, partition
from hlod_core.cli import main as cli
from hlod_core.core.errors import BakeCancelled, InputError
from hlod_core.io import hlod_file, meshes


def _transform(scale, x, y, *, z=0.0, turn_deg=0.0, mirror=False) -> list[float]:
    c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
    m = np.eye(4)
    m[:3, :3] = scale * np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    if mirror:
        m[0, :3] *= -1.0  # a mirroring instance: transform_mesh flips its winding
    m[:3, 3] = (x, y, z)
    return m.ravel().tolist()


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    """40,848 triangles: three models, six instances (one mirrored, one far smaller than the rest)."""
    path = tmp_path_factory.mktemp("spec") / "scene.json"
    path.write_text(json.dumps({"models": [
        {"path": str(model("cow")), "transforms": [_transform(1, 0, 0), _transform(1.5, 3, 0, turn_deg=40),
                                                         _transform(1, 0, 3, z=0.5, mirror=True)]},
        {"path": str(model("teapot")),
         "transforms": [_transform(0.1, -3, -2, turn_deg=10), _transform(0.05, 2, -3)]},
        {"path": str(model("airplane")), "transforms": [_transform(1, -2, 2, turn_deg=90)]}]}))
    return path


# --- the octree from counts ------------------------------------------------------------------

def _counted_octree(c, counted, *, target_tris, max_depth, chunk, levels):
    root = octree.tight_cube(c.min(axis=0), c.max(axis=0))

    def count_pass(query):
        total = 0, 0
        for lo in range(0, c.shape[0], chunk):
            every, mine = query.count(c[lo:lo + chunk], counted[lo:lo + chunk])
            total = total[0] + every, total[1] + mine
        return total

    return root, octree.build_octree_counted(count_pass, root=root, tri_count=c.shape[0],
                                             counted_count=int(counted.sum()), target_tris=target_tris,
                                             max_depth=max_depth, levels=levels)


@pytest.mark.parametrize("seed", range(12))
def test_octree_from_counts_is_build_octree_float_for_float(seed, monkeypatch):
    """Clusters at scales from 1e-6 to 10 (cells shrink many times before they split), centroids
    on splitting planes (rounded), coincident ones (an unsplittable leaf), uncounted ones; chunks
    and levels per pass varied: every node, cell and range equal, and every centroid routes to
    the leaf build_octree put it in. build_octree's own passes (octree_passes) run in chunks of
    a few dozen rows in odd seeds (in some over centroids in the order of their leaves, so that
    many chunks lie in one cell), with their sort by leaf as a wide-key sort in some, and read
    F-ordered centroids in others (as prepare makes them)."""
    if seed % 2:
        monkeypatch.setattr(octree_passes, "CHUNK", 37 + seed)
    if seed % 4 == 1:
        monkeypatch.setattr(octree_passes, "RADIX_KEYS", 3)
    rng = np.random.default_rng(seed)
    parts = [rng.normal(size=(int(rng.integers(50, 1500)), 3)) * 10.0 ** rng.uniform(-6, 1) + rng.uniform(-50, 50, 3)
             for _ in range(int(rng.integers(1, 5)))]
    c = np.concatenate(parts)
    if seed % 4 == 0:
        c[:150] = c[0]
    if seed % 3 == 0:
        c = np.round(c, 1)
    counted = rng.random(c.shape[0]) > 0.1
    target, depth = int(rng.integers(5, 200)), int(rng.integers(0, 14))
    if seed % 4 == 3:  # each leaf's centroids in a row, as an object's come: many chunks of one cell, deep down too
        c = c[octree.build_octree(c, target_tris=target, max_depth=depth, counted=counted).tri_order]
    root, got = _counted_octree(c, counted, target_tris=target, max_depth=depth, chunk=int(rng.integers(7, 400)),
                                levels=int(rng.integers(1, 9)))
    ref = octree.build_octree(np.asfortranarray(c) if seed % 3 == 1 else c, target_tris=target, max_depth=depth,
                              counted=counted, root=root)
    for name in ("parent", "child_offset", "child_count", "depth", "tri_begin", "tri_end", "cell_center",
                 "cell_half", "cell_level"):
        a, b = getattr(ref, name), getattr(got.layout, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    leaf_of = np.empty(c.shape[0], np.int64)
    for leaf in np.flatnonzero(ref.is_leaf):
        leaf_of[ref.tri_order[ref.tri_begin[leaf]:ref.tri_end[leaf]]] = leaf
    assert np.array_equal(got.router.route(c), leaf_of)
    assert np.array_equal(got.tri_count, ref.tri_end - ref.tri_begin)


# --- byte-identical bakes ----------------------------------------------------------------------

@pytest.mark.parametrize("error, jobs", [("exact", 1), ("bound", 2)])
def test_spec_bakes_to_the_same_file_out_of_core(spec, tmp_path, error, jobs):
    settings = BakeSettings(target_tris=500, jobs=jobs, error=error)
    in_memory = bake(meshes.load_inputs([spec]), settings, sources=[str(spec)])
    stats = partition.PartitionStats()
    streamed = bake_stream(partition.SceneSource([spec]), settings, sources=[str(spec)], chunk_tris=4096,
                           scratch_dir=tmp_path, stats=stats)
    assert in_memory.node_count > 100  # several levels of leaves and inner nodes
    assert file_bytes(streamed, tmp_path / "b.hlod") == file_bytes(in_memory, tmp_path / "a.hlod")
    assert stats.pieces > stats.passes and stats.flushes > 1  # pieces and flushes, not one go
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.hlod", "b.hlod"]  # the partition's folder is gone


class _Chunks:
    """A TriangleSource of given meshes, one chunk each."""

    def __init__(self, parts):
        self.name, self.parts = "chunks", parts

    def chunks(self):
        for m in self.parts:
            yield partition.TriangleChunk(m.positions, m.faces, m.normals, m.name)


def _with_normals(mesh, *, unused: int = 0) -> meshes.TriangleMesh:
    """mesh with unit vertex normals and `unused` extra vertices no face uses (far away, even NaN)."""
    p = mesh.positions
    normals = p - p.mean(axis=0)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    extra = np.full((unused, 3), 1e9)
    extra[:1] = np.nan
    return meshes.TriangleMesh(positions=np.concatenate([p, extra]), faces=mesh.faces,
                               normals=np.concatenate([normals, np.ones((unused, 3))]).astype(np.float32),
                               name=mesh.name)


def test_normals_unused_vertices_and_chunks_cut_in_pieces(tmp_path):
    """Chunks with normals and unused vertices, each cut into pieces that share vertices (chunk_tris
    far below a chunk): the same file as the merged mesh baked in memory, normals included."""
    cow, teapot = (meshes.load_mesh(model(name)) for name in ("cow", "teapot"))
    parts = [_with_normals(cow, unused=3),
             _with_normals(meshes.transform_mesh(teapot, np.array(_transform(0.1, 1.5, 0)).reshape(4, 4), name="t")),
             _with_normals(meshes.transform_mesh(
                 cow, np.array(_transform(1, -1, 1, turn_deg=30, mirror=True)).reshape(4, 4), name="c"))]
    settings = BakeSettings(target_tris=400)
    in_memory = bake(meshes.merge(parts), settings, sources=["chunks"])
    streamed = bake_stream(_Chunks(parts), settings, sources=["chunks"], chunk_tris=777, scratch_dir=tmp_path)
    assert streamed.normals is not None
    assert file_bytes(streamed, tmp_path / "b.hlod") == file_bytes(in_memory, tmp_path / "a.hlod")


# --- bounded memory -----------------------------------------------------------------------------

#: The partition's scan, octree and routing with tracemalloc on, then every leaf read, in a process of
#: its own: tracemalloc counts every thread's allocations, and a test run's earlier tests leave threads
#: behind (a Dask client's) that allocate while it traces. Prints one JSON object.
PARTITION_MEMORY = """
import json, sys, tracemalloc
import numpy as np
from hlod_core.bake.space import partition

spec, scratch, chunk = sys.argv[1], sys.argv[2], int(sys.argv[3])
source = partition.SceneSource([spec])
next(source.chunks())  # the model file read (and kept) before tracing
with partition.Partition(source, scratch_dir=scratch, chunk_tris=chunk) as part:
    tracemalloc.start()
    try:
        scan = part.scan()
        tree = part.build_octree(target_tris=2000, max_depth=12)
        part.route()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    layout = tree.layout
    leaves = np.flatnonzero(layout.is_leaf)
    files = sorted(p.name for p in part.folder.iterdir())
    read = []
    for leaf in leaves:
        positions, faces, _ = part.leaf_lod(int(leaf))
        read.append([int(faces.shape[0]), int(layout.tri_end[leaf] - layout.tri_begin[leaf]),
                     int(faces.max()) < positions.shape[0]])
    reads = {int(leaf): int(n) for leaf, n in part.stats.leaf_reads.items()}
    print(json.dumps({"tris": int(scan.tri_count), "peak": int(peak),
                      "largest_piece": int(part.stats.largest_piece_tris),
                      "files": files, "cells": sorted(f"cell-{leaf}.bin" for leaf in leaves), "read": read,
                      "reads_are_the_cells": reads == {int(leaf): int(tree.tri_count[leaf]) for leaf in leaves},
                      "reads": sum(reads.values()), "folder": str(part.folder)}))
"""


def test_the_partition_holds_no_array_of_every_triangle(tmp_path):
    """60 placed cows (348,240 triangles), 2,048 at a time: tracemalloc's peak over the scan, the
    octree's counting passes and the routing stays below one (f,) int64 array (numpy reports its
    allocations to tracemalloc); no piece is longer than the chunk; each leaf reads its own cell's
    file, exactly its triangles, and together the leaves read every triangle once. Measured in a
    process of its own (PARTITION_MEMORY): a third of the bound (120 cows, 4,096 at a time: 0.6)."""
    spec = tmp_path / "herd.json"
    transforms = [_transform(1, 1.2 * (k % 12), 1.2 * (k // 12), turn_deg=17 * k) for k in range(60)]
    spec.write_text(json.dumps({"models": [{"path": str(model("cow")), "transforms": transforms}]}))
    chunk = 2048
    proc = subprocess.run([sys.executable, "-c", PARTITION_MEMORY, str(spec), str(tmp_path), str(chunk)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    f = out["tris"]
    assert f == 60 * 5804 and f > 100 * chunk
    assert out["peak"] < 8 * f, f"partition peak {out['peak']} bytes for {f} triangles"
    assert out["largest_piece"] <= chunk
    assert len(out["cells"]) > 100 and out["files"] == out["cells"]
    assert all(faces == cell_tris and in_range for faces, cell_tris, in_range in out["read"])
    assert out["reads_are_the_cells"] and out["reads"] == f
    assert not Path(out["folder"]).exists()


# --- cancel, errors, refusals ---------------------------------------------------------------------

def test_scratch_is_removed_after_a_cancel_and_an_error(spec, tmp_path):
    """A cancel and an error while the routing pass has written cell files: nothing is left."""

    def cells_written() -> bool:
        return any(tmp_path.glob("hlod-partition-*/cell-*.bin"))

    with pytest.raises(BakeCancelled):
        bake_stream(partition.SceneSource([spec]), BakeSettings(target_tris=500), chunk_tris=2048,
                    scratch_dir=tmp_path, cancel=cells_written)
    assert list(tmp_path.iterdir()) == []

    class Failing(_Chunks):
        def chunks(self):
            for chunk in super().chunks():
                if cells_written():
                    raise OSError("disk gone")
                yield chunk

    cow = meshes.load_mesh(model("cow"))
    with pytest.raises(OSError, match="disk gone"):
        bake_stream(Failing([cow, cow]), BakeSettings(target_tris=300), chunk_tris=1000, scratch_dir=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_appearance_is_refused_naming_the_file(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl red\nKd 1 0 0\n")
    obj = tmp_path / "quad.obj"
    obj.write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl red\nf 1 2 3\nf 1 3 4\n")
    with pytest.raises(InputError, match=r"quad\.obj: .*out-of-core bakes take geometry only"):
        bake_stream(partition.SceneSource([obj]), BakeSettings(), scratch_dir=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.mtl", "quad.obj"]


def test_command_line_out_of_core_writes_the_same_file(spec, tmp_path, capsys):
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    common = ["-q", "bake", str(spec), "--target-tris", "800"]
    assert cli.main([*common, "-o", str(tmp_path / "a.hlod"), "--no-cache"]) == 0
    assert cli.main([*common, "-o", str(tmp_path / "b.hlod"), "--out-of-core", "--scratch", str(scratch),
                     "--chunk-tris", "5000"]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["out_of_core"] is True and summary["cache"] is None
    a, b = (hlod_file.load(tmp_path / name) for name in ("a.hlod", "b.hlod"))
    assert file_bytes(b, tmp_path / "b2.hlod") == file_bytes(a, tmp_path / "a2.hlod")
    assert list(scratch.iterdir()) == [] and not (tmp_path / "b.hlod.cache").exists()
    assert cli.main([*common, "-o", str(tmp_path / "c.hlod"), "--out-of-core", "--cache", str(tmp_path / "c")]) == 2
    assert cli.main([*common, "-o", str(tmp_path / "c.hlod"), "--chunk-tris", "5"]) == 2
    assert "out-of-core bakes keep no bake cache" in capsys.readouterr().err


@pytest.mark.parametrize("target_tris, max_depth", [(10_000, 12), (100, 0)])
def test_one_leaf_inputs(tmp_path, target_tris, max_depth):
    """An input within one leaf's budget, and max_depth 0: the root is the only node, in both ways."""
    cow = meshes.load_mesh(model("cow"))
    settings = BakeSettings(target_tris=target_tris, max_depth=max_depth)
    in_memory = bake(cow, settings)
    streamed = bake_stream(partition.MeshSource(cow), settings, chunk_tris=1000, scratch_dir=tmp_path)
    assert streamed.node_count == 1
    assert file_bytes(streamed, tmp_path / "b.hlod") == file_bytes(in_memory, tmp_path / "a.hlod")


@pytest.mark.slow  # a bake of several hundred leaves in its own process (about 10 s): a limit, beside the core path
def test_open_files_stay_few_however_many_leaves(spec, tmp_path):
    """The leaves' arrays are views of three memory maps, not maps of their own (a map holds a file
    descriptor: at 10M triangles, one map per leaf array ran past the limit of 20,000). With the
    process's descriptor limit at 128, an out-of-core bake of several hundred leaves still runs."""
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    limited = ("import resource, sys; resource.setrlimit(resource.RLIMIT_NOFILE, (128, resource.getrlimit("
               "resource.RLIMIT_NOFILE)[1])); from hlod_core.cli.main import main; sys.exit(main(sys.argv[1:]))")
    run = subprocess.run([sys.executable, "-c", limited, "bake", str(spec), "-o", str(tmp_path / "a.hlod"),
                          "--target-tris", "60", "--jobs", "1", "--out-of-core", "--scratch", str(scratch)],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    hlod = hlod_file.load(tmp_path / "a.hlod")
    assert int(hlod.is_leaf.sum()) > 300 and list(scratch.iterdir()) == []


def test_a_bad_transform_is_named_as_the_in_memory_reader_names_it(tmp_path):
    """A transform that moves a model out of the float range: the same one-line error both ways,
    naming the spec, the model entry and the transform."""
    spec = tmp_path / "far.json"
    spec.write_text(json.dumps({"models": [
        {"path": str(model("cow")), "transforms": [_transform(1, 0, 0), _transform(1e308, 0, 0, z=1e308)]}]}))
    with pytest.raises(InputError) as in_memory:
        meshes.load_inputs([spec])
    with pytest.raises(InputError) as streamed:
        bake_stream(partition.SceneSource([spec]), BakeSettings(target_tris=500), scratch_dir=tmp_path)
    assert str(streamed.value) == str(in_memory.value)
    assert f"{spec}: models[0].transforms[1] moves" in str(streamed.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.json"]
