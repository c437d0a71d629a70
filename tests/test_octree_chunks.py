"""The in-memory octree's passes as tasks over index chunks of the triangles (octree_passes,
chunk_store): every cut of the rows into task regions gives the layout of the octree from counts
(build_octree_counted, which shares none of the passes' code), float for float: one region, an
uneven last one, regions of a few rows (cells split across regions, regions left empty as their
triangles reach leaves, shrinking cells whose rows lie in some regions only); on a pool of 2 worker
processes through mapped files, the layout of the passes in this process; and a bake of the cow
with regions of 700 triangles at jobs 1 and 2, the file of a bake in one region, byte for byte."""
from __future__ import annotations

import os

import numpy as np
import pytest

from helpers import file_bytes, load_model
from hlod_core.bake import prepare
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run.workers import open_workers
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space import chunk_store, octree_passes
from hlod_core.bake.space.octree import build_octree, build_octree_counted, tight_cube
from hlod_core.core.errors import InputError
from hlod_core.io.meshes import TriangleMesh

FIELDS = ("parent", "child_offset", "child_count", "depth", "tri_begin", "tri_end", "cell_center", "cell_half",
          "cell_level")


def _cloud(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Centroids (f,3): clusters at scales from 1e-6 to 10 (cells shrink many times before they
    split), some coincident (an unsplittable leaf), rounded onto splitting planes in some seeds;
    counted (f,) bool with about a tenth uncounted."""
    rng = np.random.default_rng(seed)
    parts = [rng.normal(size=(int(rng.integers(50, 900)), 3)) * 10.0 ** rng.uniform(-6, 1) + rng.uniform(-50, 50, 3)
             for _ in range(int(rng.integers(2, 5)))]
    c = np.concatenate(parts)
    c[:120] = c[0]
    if seed % 2:
        c = np.round(c, 1)
    return c, rng.random(c.shape[0]) > 0.1


def _from_counts(c: np.ndarray, counted: np.ndarray, *, target: int, depth: int):
    root = tight_cube(c.min(axis=0), c.max(axis=0))
    return root, build_octree_counted(lambda query: query.count(c, counted), root=root, tri_count=c.shape[0],
                                      counted_count=int(counted.sum()), target_tris=target, max_depth=depth).layout


def _same(got, want) -> None:
    for name in FIELDS:
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name


def _leaf_of(layout, f: int) -> np.ndarray:
    leaf_of = np.full(f, -1, np.int64)
    for leaf in np.flatnonzero(layout.is_leaf):
        leaf_of[layout.tri_order[layout.tri_begin[leaf]:layout.tri_end[leaf]]] = leaf
    return leaf_of


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("task_rows", [1 << 30, 997, 64, 5])
def test_any_cut_into_regions_gives_the_octree_from_counts(seed, task_rows, monkeypatch):
    """Regions of every size (one; an uneven last one; a few rows, most emptied as their triangles
    reach leaves, cells and shrinking cells across many regions), passes of 16 rows within a task:
    the layout of the octree from counts, and the triangles in each leaf in input order."""
    c, counted = _cloud(seed)
    monkeypatch.setattr(chunk_store, "TASK_ROWS", task_rows)
    monkeypatch.setattr(octree_passes, "CHUNK", 16)
    root, want = _from_counts(c, counted, target=25, depth=12)
    got = build_octree(c, target_tris=25, max_depth=12, counted=counted, root=root)
    assert want.node_count > 50
    _same(got, want)
    assert np.array_equal(np.sort(got.tri_order), np.arange(c.shape[0]))
    for leaf in np.flatnonzero(got.is_leaf):  # input order within a leaf
        assert np.all(np.diff(got.tri_order[got.tri_begin[leaf]:got.tri_end[leaf]]) > 0)


def test_regions_of_one_row_and_a_root_that_never_splits(monkeypatch):
    """A region per triangle, every count; and a root at max_depth 0 (no pass; every triangle its leaf)."""
    c, counted = _cloud(7)
    c, counted = c[:300], counted[:300]
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 1)
    root, want = _from_counts(c, counted, target=10, depth=12)
    _same(build_octree(c, target_tris=10, max_depth=12, counted=counted, root=root), want)
    flat = build_octree(c, target_tris=10, max_depth=0, counted=counted, root=root)
    assert flat.node_count == 1 and np.array_equal(flat.tri_order, np.arange(300))


def test_regions_split_on_a_pool_through_mapped_files_give_the_inline_layout(tmp_path, monkeypatch):
    """The passes as tasks on 2 spawned workers (their arrays mapped from the store's files) and
    inline: the same layout and tri_order; the store's folder removed when it closes."""
    c, counted = _cloud(2)
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 211)
    root = tight_cube(c.min(axis=0), c.max(axis=0))
    inline = build_octree(c, target_tris=25, max_depth=12, counted=counted, root=root)
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", 0)
    with open_workers(2, scratch_dir=tmp_path) as workers:
        with chunk_store.open_store(workers) as store:
            assert store.folder and os.path.isdir(store.folder)
            folder = store.folder
            pooled = build_octree(c, target_tris=25, max_depth=12, counted=counted, root=root, store=store)
        assert not os.path.exists(folder)
    _same(pooled, inline)
    assert np.array_equal(pooled.tri_order, inline.tri_order)
    assert not isinstance(pooled.tri_order, np.memmap)  # copied out before the files go


def test_a_small_input_keeps_its_tasks_in_the_bake_process(monkeypatch):
    """Below WORKERS_FROM_ROWS triangles a pool's bake runs the chunk tasks inline, on its own arrays
    (no store folder, in shared memory or elsewhere); from it on, on the pool in shared memory."""
    cow = load_model("cow")
    where, run = [], chunk_store.ChunkStore.run

    def spied(store, fn, calls):
        where.append(store.folder)
        return run(store, fn, calls)

    monkeypatch.setattr(chunk_store.ChunkStore, "run", spied)
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", cow.tri_count + 1)
    bake(cow, BakeSettings(target_tris=500, jobs=2))
    assert where and not any(where)
    where.clear()
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", cow.tri_count)
    bake(cow, BakeSettings(target_tris=500, jobs=2))
    assert where and all(where)
    if os.path.isdir("/dev/shm"):
        assert all(folder.startswith("/dev/shm/hlod-chunks-") for folder in where)


@pytest.mark.parametrize("jobs", [1, 2])
def test_bake_in_regions_is_the_bake_in_one_region(jobs, tmp_path, monkeypatch):
    """The cow at 500 triangles a node (about 5,800 triangles): its octree's passes in regions of
    700 triangles (9 tasks a pass, the last one shorter), at jobs 1 and jobs 2: the file of the
    passes over all triangles at once, byte for byte."""
    cow = load_model("cow")
    settings = BakeSettings(target_tris=500, jobs=jobs)
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 1 << 30)
    whole = file_bytes(bake(cow, BakeSettings(target_tris=500)), tmp_path / "whole.hlod")
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 700)
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", 0)  # on the workers at this size too
    assert len(chunk_store.regions(cow.tri_count)) > 5
    where, run = [], chunk_store.ChunkStore.run

    def spied(store, fn, calls):
        where.append(store.folder)
        return run(store, fn, calls)

    monkeypatch.setattr(chunk_store.ChunkStore, "run", spied)
    got = bake(cow, settings)
    assert where and all(bool(folder) == (jobs > 1) for folder in where)  # on the pool's workers at jobs 2
    got = got.replace(meta={**got.meta, "settings": {**got.meta["settings"], "jobs": 1}})  # the one setting apart
    assert file_bytes(got, tmp_path / "regions.hlod") == whole


def test_prepare_on_a_pool_through_mapped_files_gives_the_inline_arrays(tmp_path, monkeypatch):
    """Prepare's centroids as tasks of 400 triangles on 2 spawned workers (the faces and corners
    copied into the store's files, the centroids and counted written there): the floats, counted
    and root cube of prepare in this process, bit for bit."""
    cow = load_model("cow")
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 400)
    inline = prepare.prepare(cow)
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", 0)
    with open_workers(2, scratch_dir=tmp_path) as workers:
        with chunk_store.open_store(workers) as store:
            pooled = prepare.prepare(cow, store=store)
            assert isinstance(store.get("centroids"), np.memmap)
            for name in ("positions", "faces", "centroids", "counted"):
                a, b = getattr(inline, name), getattr(pooled, name)
                assert a.dtype == b.dtype, name
                assert np.ascontiguousarray(a).tobytes() == np.ascontiguousarray(b).tobytes(), name
    assert not isinstance(pooled.counted, np.memmap)
    assert np.array_equal(inline.root_cell.corner, pooled.root_cell.corner)
    assert inline.root_cell.side == pooled.root_cell.side


@pytest.mark.parametrize("task_rows", [1 << 30, 900, 37])
def test_leaves_made_by_tasks_over_runs_of_leaves_are_the_leaves_made_here(task_rows, tmp_path, monkeypatch):
    """The cow (with normals) at 300 triangles a node, its leaves made on 2 workers in runs of the
    leaves whose first triangle lies in one region (one run; runs of a few leaves, the last one
    shorter; regions of fewer triangles than a leaf, a run per leaf): every leaf's positions, faces
    and normals those made here leaf by leaf, dtype and bytes; inner nodes None."""
    cow = load_model("cow")
    cow = TriangleMesh(positions=cow.positions, faces=cow.faces, name="cow",
                       normals=np.random.default_rng(0).random(cow.positions.shape).astype(np.float32))
    monkeypatch.setattr(chunk_store, "TASK_ROWS", task_rows)
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", 0)
    with open_workers(2, scratch_dir=tmp_path) as workers:
        with chunk_store.open_store(workers) as store:
            prepared = prepare.prepare(cow, store=store)
            layout = build_octree(prepared.centroids, target_tris=300, max_depth=12, counted=prepared.counted,
                                  root=prepared.root_cell, store=store)
            made = prepare.leaf_lods(layout, prepared, store)
    here = prepare.leaf_lods(layout, prepared)
    assert layout.is_leaf.sum() > 10
    for node, (got, want) in enumerate(zip(made, here)):
        assert (got is None) == (want is None) == (not layout.is_leaf[node])
        if want is None:
            continue
        assert got[3] is None and want[3] is None
        for a, b in zip(got[:3], want[:3]):
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), node


@pytest.mark.parametrize("jobs", [1, 2])
def test_bad_input_met_by_the_tasks_gets_the_errors_of_the_bake_in_one_process(jobs, monkeypatch):
    """A used vertex at NaN in the last region of vertices, and one so far out that its coordinates
    exceed float32 after centring: prepare's tasks (regions of 500 rows, on 2 workers at jobs 2)
    find them, and the bake raises the one-process bake's InputError naming the mesh; an unused NaN
    vertex is no error."""
    cow = load_model("cow")
    monkeypatch.setattr(chunk_store, "TASK_ROWS", 500)
    monkeypatch.setattr(chunk_store, "WORKERS_FROM_ROWS", 0)
    settings = BakeSettings(target_tris=500, jobs=jobs)
    nan = cow.positions.copy()
    nan[cow.faces[-1, 2]] = np.nan
    with pytest.raises(InputError, match="^bad: vertices used by faces have NaN or infinite coordinates$"):
        bake(TriangleMesh(positions=nan, faces=cow.faces, name="bad"), settings)
    far = cow.positions.copy()
    far[cow.faces[-1, 2]] = 1e300
    with pytest.raises(InputError, match="^far: coordinates exceed the float32 range after centring$"):
        bake(TriangleMesh(positions=far, faces=cow.faces, name="far"), settings)
    unused = np.concatenate([cow.positions, [[np.nan, np.nan, np.nan]]])
    assert bake(TriangleMesh(positions=unused, faces=cow.faces, name="unused"), settings).node_count > 1
