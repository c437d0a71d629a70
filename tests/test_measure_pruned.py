"""hausdorff's pruned measure (a re-bake after moving one statue measures its ancestors, up to
the root, against every triangle below them). The pruning must give the very float the unpruned measure
gives, on every inner node of real bakes, and must skip work. Real pymeshlab: each model (and a
herd of cows, whose coarse root is where pruning pays) is baked (jobs = 1, so the measure runs in
this process) with the measure wrapped to keep the (LOD, original) pairs the bake measures, then
both ways are compared, and the bake's own clusters (over every leaf) against one cluster run."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import load_model
from hlod_core.bake.measure import hausdorff
from hlod_core.bake.pipeline import bake
from hlod_core.bake.run import tasks
from hlod_core.bake.settings import BakeSettings
from hlod_core.io import meshes
from sample_meshes import herd_cow

#: The herd: 16 cows (sample_meshes.herd_cow: 10 units long) 12 units apart on a 4 x 4 grid, one mesh of about 93k
#: triangles. Its root's LOD (600 triangles) is far coarser than a cow, the case of the crowd's
#: ancestors, where most original vertices cannot raise the error.
HERD_COWS, HERD_SPACING = 16, 12.0


def _scene(name: str):
    if name != "herd":
        return load_model(name)
    cow, parts = herd_cow(), []
    for k in range(HERD_COWS):
        m = np.eye(4)
        m[:3, 3] = [HERD_SPACING * (k % 4), HERD_SPACING * (k // 4), 0.0]
        parts.append(meshes.transform_mesh(cow, m, name=f"cow{k}"))
    return meshes.merge(parts, name="herd")


def _bake_measuring(name: str, target_tris: int) -> list[tuple]:
    """Every (lod, original, error, pruned_by_the_bake) the bake of `name` measures, error as the
    bake got it (its own clusters over every leaf)."""
    pairs = []
    task = tasks.measure_exact

    def recording(folder, lod, ranges):
        error = task(folder, lod, ranges)
        shared = tasks.shared(folder)
        vertex_begin, vertex_end, cluster_begin, cluster_end = ranges
        tri_begin, tri_end = int(shared["start"][cluster_begin]), int(shared["start"][cluster_end])
        original = (np.asarray(shared["positions"][vertex_begin:vertex_end]),
                    (np.asarray(shared["faces"][tri_begin:tri_end]) - vertex_begin).astype(np.int32))
        pairs.append((lod, original, error, vertex_end - vertex_begin >= hausdorff.PRUNE_FROM_VERTICES))
        return error

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tasks, "measure_exact", recording)
        bake(_scene(name), BakeSettings(jobs=1, target_tris=target_tris))
    return pairs


@pytest.fixture(scope="module")
def measured_pairs():
    """measured_pairs(name, target_tris): `_bake_measuring`'s pairs, each scene baked once for this
    module's tests."""
    baked: dict[tuple[str, int], list[tuple]] = {}

    def pairs_of(name: str, target_tris: int) -> list[tuple]:
        if (name, target_tris) not in baked:
            baked[name, target_tris] = _bake_measuring(name, target_tris)
        return baked[name, target_tris]

    return pairs_of


@pytest.mark.parametrize("name, target_tris",
                         [("cow", 300), pytest.param("bunny", 2000, marks=pytest.mark.slow),
                          ("creased", 500), ("herd", 600)])  # the bunny: the same check, 7 s more
def test_pruned_measure_gives_the_unpruned_float_on_every_inner_node(name, target_tris, measured_pairs):
    """Pruned on every node (measure_pruned, not only the large ones the bake prunes): bit-identical
    to measuring every sample, and what the bake itself stored (pruned over its clusters, which
    cut every leaf separately, where the node is large)."""
    pairs = measured_pairs(name, target_tris)
    assert len(pairs) >= 3
    if name == "herd":
        assert any(by_bake for *_, by_bake in pairs), "the herd's root is pruned by the bake"
    for lod, original, error, _ in pairs:
        unpruned = hausdorff.measure(lod, original)
        pruned = hausdorff.measure_pruned(lod, original)
        assert np.isfinite(unpruned)
        assert pruned == unpruned and error == unpruned, (name, original[0].shape, pruned, unpruned, error)


def test_the_measure_goes_whole_only_where_the_clusters_cannot_prune(monkeypatch, measured_pairs):
    """measure_clustered with `whole`: the herd's big nodes (a coarse LOD far from most clusters)
    are pruned, small cells whose LOD hugs the surface (every cluster's bound above the floor) are
    measured whole; both give the unpruned float."""
    measured_whole = []
    measure = hausdorff.measure
    monkeypatch.setattr(hausdorff, "measure", lambda lod, original: measured_whole.append(1) or measure(lod, original))
    went_whole = {}
    for lod, original, error, _ in measured_pairs("herd", 600):
        measured_whole.clear()
        assert hausdorff.measure_pruned(lod, original, allow_whole=True) == error
        went_whole[original[0].shape[0]] = bool(measured_whole)
    largest = max(went_whole)
    assert not went_whole[largest] and any(went_whole.values()), went_whole


def test_where_pruning_cannot_pay_a_large_node_measures_its_vertices_as_points(monkeypatch, measured_pairs):
    """From POINT_SET_FROM_VERTICES original vertices (here every node: the limit set to 0), a node
    whose clusters cannot prune is not measured whole: its vertices go to the LOD as one point set and
    the LOD's samples only where those points leave them within reach; the unpruned float all the
    same, on the herd's nodes that go that way, and more than one of them does."""
    monkeypatch.setattr(hausdorff, "POINT_SET_FROM_VERTICES", 0)
    measured_whole = []
    measure = hausdorff.measure
    monkeypatch.setattr(hausdorff, "measure", lambda lod, original: measured_whole.append(1) or measure(lod, original))
    as_points = 0
    for lod, original, error, _ in measured_pairs("herd", 600):
        measured_whole.clear()
        whole = []
        faces = np.asarray(original[1])
        clusters = hausdorff.Clusters.build(original[0], faces, np.array([0, faces.shape[0]], np.int64))
        p = np.asarray(original[0], np.float64)
        got = hausdorff.measure_clustered(lod, original[0], clusters, first=0, last=clusters.radius.size,
                                          original_box=(p.min(axis=0), p.max(axis=0)),
                                          whole=lambda: whole.append(1) or original)
        assert got == error and not measured_whole
        as_points += bool(whole)
    assert as_points > 1


def test_pruning_skips_many_samples_of_a_large_node(monkeypatch, measured_pairs):
    """The herd's root (about 55k original vertices): the pruned measure evaluates under 65% of the
    original vertices (34k of 55k: the cow's triangles are large, so a cluster of CLUSTER_FACES of
    them is about half the root's error across, which loosens its bound; on the crowd's root, 1.7k
    of 900k) and under a quarter of the LOD's samples against the original surface (none here),
    and the error is the unpruned one."""
    lod, original, _, _ = max(measured_pairs("herd", 600), key=lambda pair: pair[1][0].shape[0])
    assert original[0].shape[0] >= hausdorff.PRUNE_FROM_VERTICES
    to_lod, to_original = [], []
    hausdorff_max = hausdorff.hausdorff_max

    def counting(ms, *, sampled, target, count, save=False):
        if not save:  # the exact evaluations (save=True: the bounds' centres and surface points)
            (to_lod if target == 0 else to_original).append(count)
        return hausdorff_max(ms, sampled=sampled, target=target, count=count, save=save)

    monkeypatch.setattr(hausdorff, "hausdorff_max", counting)
    pruned = hausdorff.measure_pruned(lod, original)
    samples = hausdorff.surface_samples(*lod).shape[0]
    assert 0 < sum(to_lod) < 0.65 * original[0].shape[0], sum(to_lod)
    assert sum(to_original) < 0.25 * samples, (sum(to_original), samples)
    to_lod.clear(), to_original.clear()
    unpruned = hausdorff.measure(lod, original)
    assert to_lod == [original[0].shape[0]] and to_original == [samples]
    assert pruned == unpruned


def test_lod_to_original_pruning_finds_a_far_sample():
    """A LOD sample far from the original (a spike the original does not have) is the maximum: the
    pruned LOD -> original direction must measure it, not skip it. Literal input: the original is a
    flat 20 x 20 grid in z = 0 (800 triangles), the LOD the same grid's two corner triangles plus a
    vertex lifted to z = 0.3 (its distance to the plane, and the only sample that far)."""
    n = 21
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="ij")
    grid = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1).astype(np.float32)
    ids = np.arange(n * n).reshape(n, n)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[1:, 1:].ravel(), ids[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    lod_p = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0.3]], np.float32)
    lod_f = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]], np.int32)
    unpruned = hausdorff.measure((lod_p, lod_f), (grid, faces))
    assert unpruned == pytest.approx(0.3, rel=1e-5)
    assert hausdorff.measure_pruned((lod_p, lod_f), (grid, faces)) == unpruned


def test_clusters_cut_each_segment_and_bound_their_faces():
    """Clusters.build on two segments of a real mesh: every face lands in exactly one cluster of its
    own segment, each cluster's sphere holds its corners, and the surface vertex is one of them."""
    cow = load_model("cow")
    p, f = cow.positions.astype(np.float32), cow.faces.astype(np.int64)
    split = f.shape[0] // 3
    segments = np.array([0, split, f.shape[0]], np.int64)
    clusters = hausdorff.Clusters.build(p, f, segments, cluster_faces=50)
    for j in range(2):  # the same face set per segment, reordered
        rows = slice(segments[j], segments[j + 1])
        assert sorted(map(tuple, clusters.faces[rows].tolist())) == sorted(map(tuple, f[rows].tolist()))
        first, last = clusters.first_cluster[j], clusters.first_cluster[j + 1]
        assert clusters.start[first] == segments[j] and clusters.start[last] == segments[j + 1]
    sizes = np.diff(clusters.start)
    assert sizes.min() >= 1 and sizes.max() <= 50
    for k in range(clusters.radius.size):
        corners = p[clusters.faces[clusters.start[k]:clusters.start[k + 1]]].reshape(-1, 3).astype(np.float64)
        assert np.linalg.norm(corners - clusters.centre[k], axis=1).max() <= clusters.radius[k]
        assert np.array_equal(corners.min(axis=0), clusters.box_min[k])
        assert clusters.surface_vertex[k] in clusters.faces[clusters.start[k]:clusters.start[k + 1]]
    with pytest.raises(ValueError):
        hausdorff.Clusters.build(p, f, np.array([0, 0, f.shape[0]], np.int64))
