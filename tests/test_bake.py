"""Bakes with real pymeshlab on the test models (tests/models.py), and the degenerate inputs of
docs/how-it-works.md#numerical-stability."""
import os
import signal
import threading

import numpy as np
import pytest

from helpers import load_model
from hlod_core.bake import checks
from hlod_core.bake.decimate import meshlab, simplify
from hlod_core.bake.measure import hausdorff
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space import lattice
from hlod_core.core import arrays
from hlod_core.core.errors import BakeCancelled, InputError
from hlod_core.core.signals import Terminated, deliver_held, signals_as_exceptions, stop_signals_held
from hlod_core.io import meshes

ALL_TRUE = {"leaf_tris_equal_input": True, "nested_bounds": True, "monotone_error": True, "leaf_budget": True}


def _leaf_triangles(hlod) -> np.ndarray:
    """Every leaf triangle as its 9 world coordinates, rows sorted: a multiset to compare with the input."""
    leaves = np.flatnonzero(hlod.is_leaf)
    tris = np.concatenate([hlod.indices[hlod.tri_offset[i]:hlod.tri_offset[i] + hlod.tri_count[i]] for i in leaves])
    world = (hlod.positions[tris.ravel()].astype(np.float64) + hlod.origin).reshape(-1, 9)
    return world[np.lexsort(world.T[::-1])]


def _input_triangles(mesh, origin) -> np.ndarray:
    rel = lattice.stored_input(mesh.positions, mesh.faces, origin).astype(np.float64) + origin  # what is stored
    world = rel[mesh.faces.ravel()].reshape(-1, 9)
    return world[np.lexsort(world.T[::-1])]


@pytest.mark.parametrize("name, jobs", [("bunny", 1), pytest.param("statue", 2, marks=pytest.mark.slow),
                                        ("bust", 1)])
def test_test_models_bake_with_every_invariant(bakes, name, jobs):
    mesh, hlod = bakes.baked(name, jobs=jobs)
    assert checks.check(hlod)["checks"] == ALL_TRUE
    assert hlod.meta["input_tris"] == mesh.tri_count
    # leaves hold exactly the input triangles (as a multiset of stored coordinates)
    assert np.array_equal(_leaf_triangles(hlod), _input_triangles(mesh, hlod.origin))
    # nothing the scene does not need: no empty nodes, no single-child nodes, LODs coarser than their children
    assert np.all(hlod.tri_count > 0)
    inner = np.flatnonzero(~hlod.is_leaf)
    assert np.all(hlod.child_count[inner] >= 2)
    for node in inner:
        kids = slice(hlod.child_offset[node], hlod.child_offset[node] + hlod.child_count[node])
        assert hlod.tri_count[node] < hlod.tri_count[kids].sum()
    assert hlod.tri_count[0] <= 2000 and hlod.error[0] > 0
    assert hlod.tri_count[inner].max() <= 1.25 * 2000 and hlod.meta["nodes_over_budget"] == 0  # every inner node
    assert hlod.normals is None  # files carry no normals into the bake: none invented


def test_triangle_strips_are_read_as_triangles():
    """The statue is a binary PLY of triangle strips (tests/models.py): 300 strips of its six
    150 x 150 grids, 270,000 triangles, wound alike (a closed surface of positive volume)."""
    mesh = load_model("statue")
    assert mesh.tri_count == 270_000
    p = mesh.positions[mesh.faces]
    volume = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    edges = np.sort(mesh.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    assert np.all(np.unique(edges, axis=0, return_counts=True)[1] == 2)  # closed: every edge twice
    assert volume > 0.25 * np.prod(mesh.positions.max(axis=0) - mesh.positions.min(axis=0))  # 0.48 of its box


@pytest.mark.slow
def test_model_far_from_origin_keeps_its_precision(bakes):
    """The bust (coordinates in the hundreds) and a copy 1e6 away bake to the same hierarchy."""
    mesh, near = bakes.baked("bust")
    _, far = bakes.baked("bust", offset=1e6)
    assert checks.check(far)["checks"] == ALL_TRUE
    assert np.array_equal(near.tri_count, far.tri_count) and np.array_equal(near.child_count, far.child_count)
    np.testing.assert_allclose(far.box_min - 1e6, near.box_min, atol=1e-6)
    # Leaf geometry: float32 relative to a float64 origin keeps ~1e-5 units here; absolute float32
    # coordinates at 1e6 would be quantised to 0.0625.
    np.testing.assert_allclose(_leaf_triangles(far) - 1e6, _leaf_triangles(near), atol=1e-4)
    # The 1e6 shift moves relative coordinates by ~1e-10, which can flip a float32 rounding and send
    # quadric decimation down another path for a node or two; the errors agree in aggregate.
    assert abs(far.error.max() - near.error.max()) <= 0.01 * near.error.max()
    assert np.mean(np.isclose(far.error, near.error, rtol=1e-5)) > 0.95
    assert np.all(np.abs(far.error - near.error) <= 0.25 * near.error.max())


def test_parallel_and_serial_bakes_are_identical(bakes):
    _, serial = bakes.baked("bunny", jobs=1)
    _, parallel = bakes.baked("bunny", jobs=2)
    for name, arr in serial.node_arrays().items():
        assert np.array_equal(arr, getattr(parallel, name)), name
    assert np.array_equal(serial.positions, parallel.positions)
    assert np.array_equal(serial.indices, parallel.indices)


def test_normals_are_carried_only_when_given():
    mesh = load_model("cow")
    n = np.zeros_like(mesh.positions)
    n[:, 2] = 1.0
    with_normals = bake(meshes.from_arrays(mesh.positions, mesh.faces, n, name="cow"), BakeSettings(target_tris=500))
    assert with_normals.normals is not None and with_normals.normals.shape == with_normals.positions.shape
    leaves = np.flatnonzero(with_normals.is_leaf)
    leaf_rows = np.concatenate([np.arange(with_normals.vertex_offset[i], with_normals.vertex_offset[i]
                                          + with_normals.vertex_count[i]) for i in leaves])
    assert np.all(with_normals.normals[leaf_rows] == [0, 0, 1])  # leaves keep the source normals
    assert np.allclose(np.linalg.norm(with_normals.normals, axis=1), 1.0, atol=1e-3)


# --- degenerate input (docs/how-it-works.md#numerical-stability) -------------------------------------------------

def test_empty_mesh_is_a_clear_error():
    with pytest.raises(InputError, match="empty-thing: the mesh has no triangles"):
        meshes.from_arrays(np.zeros((0, 3)), np.zeros((0, 3), int), name="empty-thing")


def test_one_triangle_is_one_leaf():
    hlod = bake(meshes.from_arrays([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], name="one"))
    assert hlod.node_count == 1 and hlod.error[0] == 0.0 and hlod.tri_count[0] == 1
    assert checks.check(hlod)["checks"] == ALL_TRUE
    np.testing.assert_allclose(hlod.sphere_radius[0], np.sqrt(0.5))


def test_all_vertices_at_one_point_give_one_finite_unsplittable_leaf():
    faces = np.random.default_rng(0).integers(0, 10, size=(5000, 3))
    hlod = bake(meshes.from_arrays(np.full((10, 3), 7.5), faces, name="point"), BakeSettings(target_tris=100))
    assert hlod.node_count == 1 and hlod.sphere_radius[0] == 0.0 and hlod.error[0] == 0.0
    assert np.all(np.isfinite(hlod.cube_side)) and hlod.cube_side[0] > 0
    report = checks.check(hlod)
    assert report["checks"] == ALL_TRUE


def test_unsplittable_leaf_over_budget_is_counted():
    # 300 distinct triangles (a, b, -(a+b)) on integer coordinates and their mirror images (-a, -b,
    # a+b), with one more pair reaching x = +-64: the box is centred on 0 with a longest extent of
    # 128, so every stored position is the integer itself (lattice.py) and every centroid is exactly
    # 0: the cell cannot be split, but they are real triangles and count toward the budget.
    i, j = np.meshgrid(np.arange(1, 21), np.arange(1, 16), indexing="ij")
    a = np.stack([i.ravel(), j.ravel(), np.ones(i.size)], 1)
    b = np.stack([j.ravel(), -i.ravel(), np.full(i.size, 2.0)], 1)
    half = np.concatenate([np.stack([a, b, -(a + b)], 1), [[[64, 0, 0], [-32, 1, 0], [-32, -1, 0]]]])
    p = np.concatenate([half, -half]).reshape(-1, 3)
    hlod = bake(meshes.from_arrays(p, np.arange(p.shape[0]).reshape(-1, 3), name="fan"), BakeSettings(target_tris=100))
    assert hlod.node_count == 1
    report = checks.check(hlod)
    assert report["checks"] == ALL_TRUE
    assert report["leaves_over_budget"] == 1 and report["leaves_unsplittable"] == 1


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinates_are_a_clear_error(bad):
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [bad, 0, 0]], float)
    with pytest.raises(InputError, match=r"scan\.obj: 1 vertices used by faces have NaN or infinite"):
        meshes.from_arrays(p, [[0, 1, 2], [1, 2, 3]], name="scan.obj")


def test_non_finite_unused_vertex_is_ignored():
    p = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0]], float)
    hlod = bake(meshes.from_arrays(p, [[0, 1, 2]], name="ok"))
    assert np.all(np.isfinite(hlod.positions))


def test_face_index_out_of_range_is_a_clear_error():
    with pytest.raises(InputError, match="broken: a face refers to a vertex outside 0..2"):
        meshes.from_arrays(np.eye(3), [[0, 1, 3]], name="broken")


def test_zero_area_duplicate_and_non_manifold_faces_bake_to_finite_results():
    """bunny plus a zero-area copy of every fifth face, every vertex duplicated (half the faces use
    the copies), and a fin of three triangles sharing one edge: finite, every invariant holds, and
    the duplicates weld back into one surface that decimates to the budget."""
    mesh = load_model("bunny")
    v = mesh.positions.shape[0]
    f = mesh.faces.copy()
    f[1::2] += v  # half the faces use the duplicated vertices
    slivers = mesh.faces[::5].copy()
    slivers[:, 2] = slivers[:, 1]  # zero area: two corners on one vertex
    fin_p = np.array([[0, 0, 0], [0, 0, 0.01], [0.01, 0, 0], [-0.01, 0, 0], [0, 0.01, 0]])
    fin_f = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]]) + 2 * v
    p = np.concatenate([mesh.positions, mesh.positions, fin_p])
    hlod = bake(meshes.from_arrays(p, np.concatenate([f, slivers, fin_f]), name="messy"))
    report = checks.check(hlod)
    assert report["checks"] == ALL_TRUE
    assert np.all(np.isfinite(hlod.error)) and np.all(np.isfinite(hlod.sphere_radius))
    assert hlod.meta["collapsed_input_tris"] == slivers.shape[0]
    assert hlod.tri_count[0] <= 2000


def test_bad_settings_are_clear_errors():
    with pytest.raises(InputError, match="target_tris"):
        BakeSettings(target_tris=0)
    with pytest.raises(InputError, match="jobs"):
        BakeSettings(jobs=0)


# --- progress and cancellation --------------------------------------------------------------------

@pytest.mark.parametrize("jobs", [1, 2])
def test_cancelled_bake_raises_and_leaves_no_scratch_files(jobs, tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", None)  # re-read TMPDIR
    mesh = load_model("bunny")
    calls = []

    def progress(done, total, phase):
        calls.append((done, total, phase))

    def cancel():
        return len([c for c in calls if c[2] == "simplify"]) >= 3

    with pytest.raises(BakeCancelled):
        bake(mesh, BakeSettings(jobs=jobs), progress=progress, cancel=cancel)
    assert calls[0][2] == "octree" and all(c[1] == calls[0][1] for c in calls)
    assert os.listdir(tmp_path) == []


# --- stop signals ---------------------------------------------------------------------------------

def test_a_stop_signal_inside_a_held_block_waits_for_a_safe_point():
    """Inside stop_signals_held a SIGTERM is only recorded: a thread starts untouched (a handler
    raising inside Thread.start broke its lock: "release unlocked lock", exit 1), and the signal's
    own handler raises Terminated where the code delivers it."""
    with signals_as_exceptions():
        with pytest.raises(Terminated) as info:
            with stop_signals_held() as held:
                signal.raise_signal(signal.SIGTERM)
                assert held.pending
                thread = threading.Thread(target=lambda: None)
                thread.start()
                thread.join()
                deliver_held()
                pytest.fail("the recorded signal was not delivered")
        assert info.value.signum == signal.SIGTERM
        with stop_signals_held():  # later signals are ignored, held or not: they cannot cut a cleanup short
            signal.raise_signal(signal.SIGHUP)
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


def test_a_sigterm_during_a_bake_surfaces_at_its_next_check():
    """The bake holds stop signals: a SIGTERM sent from its progress callback is raised by the
    bake at its next check (right after the octree), not inside the callback."""
    phases = []

    def progress(done, total, phase):
        phases.append(phase)
        if phase == "octree":
            os.kill(os.getpid(), signal.SIGTERM)
            phases.append("callback returned")

    with signals_as_exceptions(), pytest.raises(Terminated):
        bake(load_model("cow"), BakeSettings(target_tris=300), progress=progress)
    assert phases == ["octree", "callback returned"]


def test_progress_reaches_every_node():
    mesh = load_model("cow")
    seen = []
    hlod = bake(mesh, BakeSettings(target_tris=300), progress=lambda d, t, p: seen.append((d, t, p)))
    assert seen[-1] == (hlod.node_count, hlod.node_count, "done")
    assert [d for d, _, _ in seen] == sorted(d for d, _, _ in seen)


# --- units: pymeshlab's quadric collapse has absolute thresholds -----------------------

def _scaled(mesh, factor: float):
    return meshes.transform_mesh(mesh, np.diag([factor, factor, factor, 1.0]), name=f"{mesh.name}x{factor:g}")


def test_power_of_two_units_bake_to_bit_identical_hierarchies():
    """spot scaled by 2^-10 and 2^10 is the same float32 model up to an exact scale, so the bake must
    be the same up to that scale, bit for bit. Before decimation ran in each node's unit frame the
    root error / scale was 0.068 at x1, 0.354 at x2^-10, 0.081 at x2^10 (pymeshlab's absolute thresholds)."""
    spot = load_model("spot")
    one = bake(spot, BakeSettings(target_tris=200))
    for k in (-10, 10):
        scaled = bake(_scaled(spot, 2.0 ** k), BakeSettings(target_tris=200))
        assert np.array_equal(scaled.tri_count, one.tri_count) and np.array_equal(scaled.parent, one.parent)
        assert np.array_equal(scaled.error, one.error * 2.0 ** k), k
        assert np.array_equal(scaled.positions, one.positions * np.float32(2.0 ** k)), k
        assert np.array_equal(scaled.origin, one.origin * 2.0 ** k)


def test_millimetres_metres_and_kilometres_bake_alike():
    """cow at x1e-3, x1, x1e3 (not powers of two: float32 rounds each differently): the same
    hierarchy, root error / scale within 10%, and nearly every node's error the same. Before: the
    root error / scale was 2.20 at x1e-3 against 0.86 at x1, and no node's error agreed."""
    cow = load_model("cow")
    one = bake(cow, BakeSettings(target_tris=200))
    inner = ~one.is_leaf
    for factor in (1e-3, 1e3):
        scaled = bake(_scaled(cow, factor), BakeSettings(target_tris=200))
        assert np.array_equal(scaled.child_count, one.child_count) and np.array_equal(scaled.tri_count[one.is_leaf],
                                                                                     one.tri_count[one.is_leaf])
        assert abs(scaled.error[0] / factor / one.error[0] - 1.0) <= 0.10, factor
        agree = np.isclose(scaled.error[inner] / factor, one.error[inner], rtol=1e-3)
        assert agree.mean() >= 0.9, (factor, agree.mean())


def test_decimated_node_returns_its_fixed_vertices_bit_identical():
    """Half a cow in millimetres, cut at x = 0, its border vertices pushed to x ~ 1e-16 (coordinates
    near 0 in a node centred away from 0: the unit frame's inverse transform rounds them to other
    float32 values). Every border vertex, fixed by boundary preservation, still comes back
    bit-identical, so the exact weld one level up works."""
    cow = load_model("cow")
    p = (cow.positions * 1e-3).astype(np.float32)
    half = cow.faces[np.all(p[cow.faces, 0] < 0, axis=1)]
    edges = np.sort(half[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, count = np.unique(edges, axis=0, return_counts=True)
    border = np.unique(unique[count == 1])
    p[border, 0] *= np.float32(1e-13)
    quarters = [half[: half.shape[0] // 2], half[half.shape[0] // 2:]]
    children = [arrays.compact(p, f)[:2] for f in quarters]
    lod = simplify.decimate_node(children, meshlab.DecimationSettings(target_tris=200), with_normals=False)
    assert lod.decimated and lod.faces.shape[0] <= 220 and border.size > 30
    frame = meshlab.NodeFrame.of(p[np.unique(half)])
    naive = (frame.to_local(p[border]) / frame.scale + frame.center).astype(np.float32)
    assert np.any(naive != p[border])  # the inverse alone would move them: NodeFrame.to_model looks them up
    out = {row.tobytes() for row in lod.positions}
    assert all(row.tobytes() in out for row in p[border])


def test_hausdorff_error_is_unit_free():
    """measure() in a power-of-two scaled frame gives the error scaled exactly, and in
    millimetres the same error up to rounding."""
    spot = load_model("spot")
    p, f = spot.positions.astype(np.float32), spot.faces.astype(np.int32)
    lod = simplify.decimate_node([(p, f)], meshlab.DecimationSettings(target_tris=300), with_normals=False)
    error = hausdorff.measure((lod.positions, lod.faces), (p, f))
    assert error > 0
    for factor in (2.0 ** -20, 2.0 ** 20):
        s = np.float32(factor)
        assert hausdorff.measure((lod.positions * s, lod.faces), (p * s, f)) == error * factor
    mm = hausdorff.measure(((lod.positions * 1e-3).astype(np.float32), lod.faces), ((p * 1e-3).astype(np.float32), f))
    assert mm / 1e-3 == pytest.approx(error, rel=1e-4)
