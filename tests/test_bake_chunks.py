"""The bake's work outside the simplify phase as tasks over chunks: the cell seams over buckets of
positions (cell_seams.build) on one bucket in this process (the serial way), on many buckets inline,
from a file, and as tasks on a pool of 2 workers, the CellSeams a plain reference computes from
every leaf vertex; the exact measure's clusters over runs of whole leaves (leaf_arrays.cut_clusters)
on the pool, the clusters of all leaves at once; and a bake through both chunked ways, at jobs 1
and jobs 2, the file of the serial way byte for byte. The cow at 500 triangles a node: about 3,900
leaf vertices and 5,800 faces in 12 leaves, cut into buckets of 500 vertices and runs of about 1,000
faces here so that the chunked ways run on a scene this small."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import file_bytes, load_model
from hlod_core.bake import prepare
from hlod_core.bake.decimate import cell_seams
from hlod_core.bake.measure import leaf_arrays
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run.workers import open_workers
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space.octree import build_octree

#: Leaf vertices a bucket holds in the chunked runs here (the cow's leaves: 8 buckets).
SMALL_BUCKET = 500
#: Faces a cluster task cuts at least in the chunked runs here (the cow's 12 leaves: about 5 runs).
SMALL_RUN = 1000
FIELDS = ("positions", "first_leaf", "last_leaf", "pair_leaf", "pair_position", "pair_start", "leaf_begin",
          "leaf_end")


@pytest.fixture(scope="module")
def cow():
    return load_model("cow")


@pytest.fixture(scope="module")
def cow_leaves(cow):
    """(layout, lods) of the cow's octree at 500 triangles a node: the leaves' entries only."""
    prepared = prepare.prepare(cow)
    layout = build_octree(prepared.centroids, target_tris=500, max_depth=12, counted=prepared.counted,
                          root=prepared.root_cell)
    return layout, prepare.leaf_lods(layout, prepared)


def _chunked(monkeypatch) -> None:
    """The chunked ways for any input: small buckets and runs of leaves, as tasks from the start."""
    monkeypatch.setattr(cell_seams, "BUCKET_VERTICES", SMALL_BUCKET)
    monkeypatch.setattr(cell_seams, "PARALLEL_FROM_VERTICES", 0)
    monkeypatch.setattr(leaf_arrays, "TASK_FACES", SMALL_RUN)
    monkeypatch.setattr(leaf_arrays, "PARALLEL_FROM_FACES", 0)


def _reference(layout, lods) -> dict[str, np.ndarray]:
    """CellSeams' arrays (but the node ranges) by their definition, one np.unique over every leaf
    vertex: a position is shared when more than one leaf uses it; numbered by first use (depth
    first); a leaf's uses in its vertex order, a repeat next to itself dropped."""
    leaves = np.flatnonzero(layout.is_leaf)
    leaves = leaves[np.argsort(layout.tri_begin[leaves], kind="stable")]
    points = np.concatenate([lods[leaf][0] for leaf in leaves])
    leaf = np.repeat(np.arange(leaves.size), [lods[k][0].shape[0] for k in leaves])
    _, first, key = np.unique(points.view(np.dtype((np.void, 12))).ravel(), return_index=True, return_inverse=True)
    key = key.ravel()
    low, high = np.full(first.size, leaves.size), np.full(first.size, -1)
    np.minimum.at(low, key, leaf)
    np.maximum.at(high, key, leaf)
    shared = np.flatnonzero(low != high)
    shared = shared[np.argsort(first[shared])]  # by first use
    number = np.full(first.size, -1)
    number[shared] = np.arange(shared.size)
    rows = np.flatnonzero(number[key] >= 0)
    pair_leaf, pair_position = leaf[rows], number[key[rows]]
    keep = np.ones(rows.size, bool)
    keep[1:] = (np.diff(pair_leaf) != 0) | (np.diff(pair_position) != 0)
    pair_leaf, pair_position = pair_leaf[keep], pair_position[keep]
    return {"positions": points[first[shared]], "first_leaf": low[shared], "last_leaf": high[shared],
            "pair_leaf": pair_leaf, "pair_position": pair_position,
            "pair_start": np.searchsorted(pair_leaf, np.arange(leaves.size + 1))}


def test_seams_from_buckets_inline_from_a_file_and_on_workers_are_the_reference_seams(cow_leaves, monkeypatch,
                                                                                       tmp_path):
    layout, lods = cow_leaves
    expected = _reference(layout, lods)
    made = {"serial": cell_seams.build(layout, lods)}
    assert expected["positions"].shape[0] > 500 and int(layout.is_leaf.sum()) > 8
    _chunked(monkeypatch)
    made.update(inline=cell_seams.build(layout, lods), file=cell_seams.build(layout, lods, folder=tmp_path))
    assert (tmp_path / cell_seams.SEAM_POSITIONS).is_file()
    with open_workers(2) as workers:
        tasks = []
        submit = workers.submit
        workers.submit = lambda order, fn, *args, **kwargs: tasks.append(kwargs) or submit(order, fn, *args, **kwargs)
        made["workers"] = cell_seams.build(layout, lods, workers=workers)
    assert len(tasks) >= 4 and {t["bucket"] for t in tasks} == set(range(tasks[0]["buckets"]))
    for way, seams in made.items():
        for name, array in expected.items():
            assert np.array_equal(getattr(seams, name), array), (way, name)


def test_clusters_cut_in_runs_of_leaves_on_workers_are_the_clusters_of_all_leaves(cow_leaves, monkeypatch):
    layout, lods = cow_leaves
    whole = leaf_arrays.build(layout, lods)
    _chunked(monkeypatch)
    with open_workers(2) as workers:
        runs = []
        submit = workers.submit
        workers.submit = lambda order, fn, *args, **kwargs: runs.append(args[1].shape[0]) or submit(order, fn, *args,
                                                                                                  **kwargs)
        chunked = leaf_arrays.build(layout, lods, workers=workers)
    assert len(runs) >= 3 and sum(runs) == whole.clusters.faces.shape[0]
    for name, array in whole.arrays().items():
        assert array.dtype == chunked.arrays()[name].dtype and np.array_equal(array, chunked.arrays()[name]), name
    for name in ("vertex_begin", "vertex_end", "cluster_begin", "cluster_end"):
        assert np.array_equal(getattr(whole, name), getattr(chunked, name)), name


def test_a_bake_through_the_chunked_seams_is_the_serial_bake_byte_for_byte(cow, monkeypatch, tmp_path):
    settings = BakeSettings(target_tris=500)
    serial = file_bytes(bake(cow, settings), tmp_path / "serial.hlod")
    _chunked(monkeypatch)
    assert file_bytes(bake(cow, settings), tmp_path / "chunked.hlod") == serial
    two = bake(cow, BakeSettings(target_tris=500, jobs=2))
    two = two.replace(meta={**two.meta, "settings": {**two.meta["settings"], "jobs": 1}})
    assert file_bytes(two, tmp_path / "jobs2.hlod") == serial
