"""The same model in other units bakes to the same LODs, scaled: every position the bake stores is a
point of one lattice fixed by the input's box (hlod_core/bake/space/lattice.py), so pymeshlab sees the
same numbers in the same order at every scale."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import load_model
from hlod_core.bake.pipeline import bake
from hlod_core.bake.settings import BakeSettings
from hlod_core.bake.space import lattice
from hlod_core.io import meshes
from hlod_core.model.hierarchy import node_geometry

SCALES = (1e-3, 1.0, 1e3)


def _scaled(mesh: meshes.TriangleMesh, scale: float) -> meshes.TriangleMesh:
    m = np.eye(4) * scale
    m[3, 3] = 1.0
    return meshes.transform_mesh(mesh, m, name=f"{mesh.name} x{scale:g}")


def _unit_length(mesh: meshes.TriangleMesh) -> float:
    """The bake's lattice unit: the longest extent of the used vertices' box, from the float64 input."""
    used = mesh.positions[np.unique(mesh.faces)]
    return lattice.unit_length(used.min(axis=0), used.max(axis=0))


def _canonical(hlod, node: int, length: float) -> tuple[np.ndarray, np.ndarray]:
    """A node's geometry as canonical coordinates (the bake's lattice) and faces."""
    g = node_geometry(hlod, node)
    return lattice.canonical(g.positions, length), g.faces


def test_lattice_round_trip_is_exact_and_scale_free():
    # float32(u * L) keeps the 22-bit u apart from its neighbours: canonical() recovers it exactly,
    # and u computed at another scale in float64 rounds to the same bits.
    rng = np.random.default_rng(7)
    rel = (rng.random((50_000, 3)) - 0.5) * 1.717909
    rel[:100] *= 1e-9  # coordinates near the origin keep their relative precision
    stored = lattice.stored(rel, 1.717909)
    u = lattice.snap(rel / 1.717909)
    assert np.array_equal(lattice.canonical(stored, 1.717909), u)
    assert np.array_equal(lattice.canonical(lattice.stored(rel * 1e3, 1717.909), 1717.909), u)
    assert np.abs(stored - rel).max() <= 2.0 ** -23 * 1.717909  # half a step of 22 bits at |u| <= 0.5
    assert not np.array_equal(stored, rel.astype(np.float32))  # 2 bits coarser than plain float32


def test_snap_on_the_bits_is_snap_by_frexp_ties_and_edges_included():
    """snap rounds the float64 bits; snap_frexp is the definition. Exact ties at random exponents and
    signs, every decade of magnitude, zeros, subnormals, the largest double (rounds up to inf), inf
    and NaN: the same bits."""
    rng = np.random.default_rng(3)
    dropped = 52 - (lattice.CANONICAL_BITS - 1)
    kept = rng.integers(0, 1 << 52, 50_000, dtype=np.uint64) >> np.uint64(dropped) << np.uint64(dropped)
    ties = kept | np.uint64(1 << (dropped - 1)) | rng.integers(1, 2046, 50_000).astype(np.uint64) << np.uint64(52) \
        | rng.integers(0, 2, 50_000).astype(np.uint64) << np.uint64(63)
    u = np.concatenate([ties.view(np.float64), rng.standard_normal(50_000) * 10.0 ** rng.integers(-300, 300, 50_000),
                        [0.0, -0.0, 5e-324, -1e-310, 2.2250738585072014e-308, 1.7976931348623157e308, np.inf,
                         -np.inf, np.nan, 0.5, -0.5, 1 - 2**-53]])
    with np.errstate(over="ignore", invalid="ignore"):
        fast, slow = lattice.snap(u.reshape(-1, 2)).ravel(), lattice.snap_frexp(u)
        in_place = u.reshape(-1, 2).copy()
        assert lattice.snap(in_place, out=in_place) is in_place
    assert np.array_equal(fast.view(np.uint64), slow.view(np.uint64))
    assert np.array_equal(in_place.ravel().view(np.uint64), slow.view(np.uint64))
    assert fast[-7] == np.inf and fast[-6] == np.inf and fast[-5] == -np.inf and fast[-2] == -0.5


def test_unique_by_first_numbers_keys_by_first_appearance():
    first, inverse = lattice.unique_by_first(np.array([5.0, 2.0, 5.0, 9.0, 2.0]))
    assert first.tolist() == [0, 1, 3] and inverse.tolist() == [0, 1, 0, 2, 1]


@pytest.mark.parametrize("name, target", [("spot", 200), ("creased", 500), ("creased", 200),
                                          ("cow", 200), ("teapot", 200), ("bunny", 2000)])
def test_root_error_over_scale_is_the_same_at_every_scale(name, target):
    # Before the lattice: spot 0.108 / 0.081 / 0.050 and fandisk (500) 0.030 / 0.024 / 0.024 at
    # x1e-3 / x1 / x1e3. Wanted within 10%; the lattice gives the same LODs, so within 1e-5, or
    # within float32 rounding at the model's size (2^-23 of its box diagonal) where the error is
    # that small: the creased part's flat faces leave its root error at 200 triangles at 7e-4 of
    # its diagonal, and the same LODs measure 0.0055874, 0.0055875, 0.0055875 (1.4e-7 apart).
    mesh = load_model(name)
    scaled = {s: _scaled(mesh, s) for s in SCALES}
    hlods = {s: bake(scaled[s], BakeSettings(target_tris=target)) for s in SCALES}
    errors = np.array([hlods[s].error[0] / s for s in SCALES])
    diagonal = float(np.linalg.norm(np.ptp(mesh.positions, axis=0)))
    assert errors.max() - errors.min() <= max(1e-5 * errors.min(), 2.0 ** -23 * diagonal), errors
    base = hlods[1.0]
    inner = np.flatnonzero(~base.is_leaf)
    for s in (1e-3, 1e3):
        assert hlods[s].node_count == base.node_count
        same = 0  # LODs with the same canonical vertices and faces
        for node in inner:
            u, f = _canonical(hlods[s], int(node), _unit_length(scaled[s]))
            u1, f1 = _canonical(base, int(node), _unit_length(scaled[1.0]))
            same += bool(np.array_equal(u, u1) and np.array_equal(f, f1))
        # A coordinate very near the origin can still round to other bits (float64's error of
        # p - origin relative to a tiny coordinate): the bunny at x1e-3 keeps 22 of 28 LODs identical.
        assert same >= 0.75 * inner.size, (s, same, inner.size)
